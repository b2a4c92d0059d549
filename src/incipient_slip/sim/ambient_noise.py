"""Ambient robot/actuator vibration and P_AC electronics noise (added after the fingertip modes)."""
from __future__ import annotations

import numpy as np
from scipy import signal

from . import kernels
from .sos import SosFilter


class AmbientNoise:
    """Low-pass filtered machine noise (rms_pa) plus white sensor noise (sensor_noise_pa), in Pa."""

    def __init__(self, p: dict, fs_hz: float, n: int, block: int = 32):
        self.sos = signal.butter(2, p["corner_hz"], btype="lowpass", fs=fs_hz, output="sos")
        impulse = signal.sosfilt(self.sos, np.r_[1.0, np.zeros(8191)])
        self.scale = p["rms_pa"] / np.sqrt(np.sum(impulse**2))   # white unit noise -> rms_pa
        self.sensor_pa = p["sensor_noise_pa"]
        self.filter = SosFilter(self.sos)
        self.n, self.block = n, block
        self.buf = np.empty((0, n))
        self.i = 0

    @property
    def due(self) -> bool:
        """Whether the next period starts a new block (`draw`, filter, `fill`)."""
        return self.i >= len(self.buf)

    def draw(self, rng: np.random.Generator) -> np.ndarray:
        """Draw the next block's machine and sensor noise; return the machine noise, for
        `self.filter` and then `fill`."""
        self.white = rng.standard_normal((2, self.block * self.n))
        return self.white[0]                                         # a contiguous row

    def fill(self, filtered: np.ndarray) -> None:
        """Take the drawn block's machine noise, filtered, plus its sensor noise as the next periods'."""
        kernels.scaled_sum(filtered, self.scale, self.white[1], self.sensor_pa, filtered)  # y scale + w sensor
        self.buf = filtered.reshape(self.block, self.n)
        self.white = None
        self.i = 0

    def next(self, rng: np.random.Generator) -> np.ndarray:
        """Return the next period's ambient + sensor noise (n,) in Pa; generated in blocks of
        periods (LTI filter with carried state: identical to period-by-period filtering)."""
        if self.due:
            self.fill(self.filter.filter_inplace(self.draw(rng)))
        self.i += 1
        return self.buf[self.i - 1]
