"""BioTac ADC: scaling, quantization and clipping."""
from __future__ import annotations

import numpy as np

_kernels = None


def _compiled():
    """The compiled conversions (`sim.kernels`), imported on first use: importing this module
    stays light (numpy only; no numba)."""
    global _kernels
    if _kernels is None:
        from . import kernels
        _kernels = kernels
    return _kernels


def pac_to_counts(pac_pa: np.ndarray, pa_per_count: float, range_pa: float) -> np.ndarray:
    """Return int16 P_AC counts: round(P / pa_per_count), clipped at +/- range_pa."""
    return pac_to_counts_finite(pac_pa, pa_per_count, range_pa)[0]


def pac_to_counts_finite(pac_pa: np.ndarray, pa_per_count: float, range_pa: float,
                         plus: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
    """Return (pac_to_counts' counts of pac_pa (+ plus, added first, when given), whether every P
    was finite); a non-finite P's count is 0."""
    x = np.ascontiguousarray(pac_pa, dtype=np.float64)
    out = np.empty(x.shape, np.int16)
    if plus is not None:
        plus = np.ascontiguousarray(plus, dtype=np.float64).reshape(-1)
    finite = _compiled().pac_counts(x.reshape(-1), plus, 1.0 / pa_per_count,
                                    float(np.floor(range_pa / pa_per_count)), out.reshape(-1))
    return out, finite


def to_uint12(x: np.ndarray, full_scale: int = 4095) -> np.ndarray:
    """Return uint16 counts rounded and clipped to [0, full_scale]."""
    x = np.asarray(x, dtype=np.float64)
    out = np.empty(x.shape, np.uint16)
    _compiled().uint12_counts(x.reshape(x.shape[0] if x.ndim else 1, -1), float(full_scale),
                              out.reshape(x.shape[0] if x.ndim else 1, -1))
    return out
