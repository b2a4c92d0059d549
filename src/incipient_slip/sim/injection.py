"""PZT vibration injection: Gaussian noise eps ~ 10^(I/20) N(0,1), band-limited 10-1100 Hz.

The rig scales the band-limited unit noise by pa_per_unit * 10^(I/20) each period.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from .sos import SosFilter


def band_sos(p: dict, fs_hz: float) -> np.ndarray:
    """Return the injection band filter as second-order sections (high-pass at band_low_hz,
    plus a low-pass only when band_high_hz is below Nyquist)."""
    order = int(p["band_order"])
    sos = signal.butter(order, p["band_low_hz"], btype="highpass", fs=fs_hz, output="sos")
    if p["band_high_hz"] < 0.5 * fs_hz * 0.999:
        sos = np.vstack([sos, signal.butter(order, p["band_high_hz"], btype="lowpass", fs=fs_hz, output="sos")])
    return sos


class PztSource:
    """Band-limited unit noise, generated and filtered `block` periods at a time (the band
    filter is linear and time-invariant with carried state, so one call over a block equals
    period-by-period calls); the PZT amplifier gain 10^(I/20) is applied per period after it."""

    def __init__(self, p: dict, fs_hz: float, n: int, block: int = 32):
        self.filter = SosFilter(band_sos(p, fs_hz))
        self.n, self.block = n, block
        self.buf = np.empty((0, n))
        self.i = 0

    @property
    def zi(self) -> np.ndarray:
        return self.filter.zi

    @property
    def due(self) -> bool:
        """Whether the next period starts a new block (`draw`, filter, `fill`)."""
        return self.i >= len(self.buf)

    def draw(self, rng: np.random.Generator) -> np.ndarray:
        """Return the next block's white noise, for `self.filter` and then `fill`."""
        return rng.standard_normal(self.block * self.n)

    def fill(self, filtered: np.ndarray) -> None:
        """Take the drawn block, filtered, as the next periods' noise."""
        self.buf = filtered.reshape(self.block, self.n)
        self.i = 0

    def next(self, rng: np.random.Generator) -> np.ndarray:
        """Return the next period's band-limited unit noise (n,)."""
        if self.due:
            self.fill(self.filter.filter_inplace(self.draw(rng)))
        self.i += 1
        return self.buf[self.i - 1]
