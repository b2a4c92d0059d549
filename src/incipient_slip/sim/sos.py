"""Second-order-section filtering with carried state, one call per 500 ms period.

`sosfilt_state` gives exactly scipy.signal.sosfilt(sos, x, zi=zi) for 1-D float64 input. The
public wrapper costs ~100 us per call in argument handling (array-API dispatch, moveaxis),
which at 3 filters x 450 periods x 1000 series dominates a data set; the compiled kernel it
calls takes ~5 us for 1100 samples, so we call the kernel directly when it is available and
fall back to the public function otherwise (tests check both give identical output).
"""
from __future__ import annotations

import numpy as np
from scipy import signal

try:  # private kernel of scipy.signal.sosfilt (signature stable since scipy 1.4)
    from scipy.signal._sosfilt import _sosfilt as _kernel
except ImportError:  # pragma: no cover
    _kernel = None


def sosfilt_state(sos: np.ndarray, x: np.ndarray, zi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (y, zf): x filtered by the sections `sos` (n, 6) from state `zi` (n, 2)."""
    if _kernel is None:
        return signal.sosfilt(sos, x, zi=zi)
    y = np.array(x, dtype=np.float64, order="C").reshape(1, -1)
    z = np.array(zi, dtype=np.float64, order="C").reshape(1, -1, 2)
    _kernel(np.ascontiguousarray(sos, dtype=np.float64), y, z)
    return y.reshape(-1), z.reshape(-1, 2)


def filter_pair(a: "SosFilter", x: np.ndarray, b: "SosFilter", y: np.ndarray) -> None:
    """Filter x by a and y by b in place, each from its own state, in one compiled loop: the same
    numbers as a.filter_inplace(x) and b.filter_inplace(y) (`kernels.sosfilt_pair`; tests), in
    about the time of one of them (each recursion waits on its own previous sample)."""
    if x.shape != y.shape:
        raise ValueError(f"filter_pair: signals of one length, got {x.shape} and {y.shape}")
    from . import kernels
    kernels.sosfilt_pair(a.sos, x, a.z[0], b.sos, y, b.z[0])


class SosFilter:
    """Sections with carried state for repeated calls; filters a float64 buffer in place."""

    def __init__(self, sos: np.ndarray):
        self.sos = np.ascontiguousarray(sos, dtype=np.float64)
        self.z = np.zeros((1, self.sos.shape[0], 2))

    @property
    def zi(self) -> np.ndarray:
        """Return the current section states (n_sections, 2)."""
        return self.z[0]

    def filter_inplace(self, x: np.ndarray, sos: np.ndarray | None = None) -> np.ndarray:
        """Filter the contiguous float64 1-D array x in place (optionally with new coefficients
        `sos` of the same shape; the state carries over) and return it."""
        if sos is not None:
            self.sos = np.ascontiguousarray(sos, dtype=np.float64)
        if _kernel is None:
            x[:], self.z[0] = signal.sosfilt(self.sos, x, zi=self.z[0])
            return x
        _kernel(self.sos, x.reshape(1, -1), self.z)
        return x
