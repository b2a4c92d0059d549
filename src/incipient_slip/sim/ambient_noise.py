"""Ambient robot/actuator vibration and P_AC electronics noise (added after the fingertip modes)."""
from __future__ import annotations

import numpy as np
from scipy import signal

from .sos import sosfilt_state


class AmbientNoise:
    """Low-pass filtered machine noise (rms_pa) plus white sensor noise (sensor_noise_pa), in Pa."""

    def __init__(self, p: dict, fs_hz: float):
        self.sos = signal.butter(2, p["corner_hz"], btype="lowpass", fs=fs_hz, output="sos")
        impulse = signal.sosfilt(self.sos, np.r_[1.0, np.zeros(8191)])
        self.scale = p["rms_pa"] / np.sqrt(np.sum(impulse**2))   # white unit noise -> rms_pa
        self.sensor_pa = p["sensor_noise_pa"]
        self.zi = np.zeros((self.sos.shape[0], 2))

    def __call__(self, rng: np.random.Generator, n: int) -> np.ndarray:
        w = rng.standard_normal((2, n))
        y, self.zi = sosfilt_state(self.sos, w[0], self.zi)
        return y * self.scale + w[1] * self.sensor_pa
