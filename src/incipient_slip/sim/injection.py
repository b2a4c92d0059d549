"""PZT vibration injection: Gaussian noise 10^(I/20) N(0,1), band-limited 10-1100 Hz."""
from __future__ import annotations

import numpy as np
from scipy import signal

from .sos import sosfilt_state


def band_sos(p: dict, fs_hz: float) -> np.ndarray:
    """Return the injection band filter as second-order sections (high-pass at band_low_hz,
    plus a low-pass only when band_high_hz is below Nyquist)."""
    order = int(p["band_order"])
    sos = signal.butter(order, p["band_low_hz"], btype="highpass", fs=fs_hz, output="sos")
    if p["band_high_hz"] < 0.5 * fs_hz * 0.999:
        sos = np.vstack([sos, signal.butter(order, p["band_high_hz"], btype="lowpass", fs=fs_hz, output="sos")])
    return sos


def noise_pa(rng: np.random.Generator, n: int, intensity_db: float, pa_per_unit: float) -> np.ndarray:
    """Return n samples of the unfiltered PZT drive in Pa: pa_per_unit 10^(I/20) N(0, 1)."""
    return rng.standard_normal(n) * (pa_per_unit * 10.0 ** (intensity_db / 20.0))


class BandFilter:
    """A second-order-section filter with carried state, one call per period."""

    def __init__(self, sos: np.ndarray):
        self.sos = sos
        self.zi = np.zeros((sos.shape[0], 2))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        y, self.zi = sosfilt_state(self.sos, x, self.zi)
        return y
