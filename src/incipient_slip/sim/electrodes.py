"""The 19 BioTac electrodes: impedance follows local skin compression over each electrode.

Local compression is the Hertz load spread over the fluid layer, p_e = P (w^2 / (w^2 + r_e^2))^(3/2)
with w^2 = a^2 + h^2, centred on the contact point shifted by the skin's tangential displacement;
impedance Z = Z0 (1 + kappa p_e); counts = 4095 / (1 + Z / 10 kOhm) (BioTac formula inverted).
"""
from __future__ import annotations

import numpy as np


def electrode_counts_mean(p: dict, normal_force_kpa: float, a_mm: float, shift_mm: float) -> np.ndarray:
    """Return the noise-free counts (19,) for F_N (kPa), contact radius a and tangential shift."""
    pos = np.asarray(p["positions_mm"], float)
    c = np.asarray(p["contact_center_mm"], float) + np.array([p["displacement_coupling"] * shift_mm, 0.0, 0.0])
    r2 = np.sum((pos - c) ** 2, axis=1)
    w2 = a_mm**2 + p["fluid_depth_mm"] ** 2
    local_kpa = normal_force_kpa * (w2 / (w2 + r2)) ** 1.5
    z_kohm = p["baseline_kohm"] * (1.0 + p["kpa_sensitivity"] * local_kpa)
    return 4095.0 / (1.0 + z_kohm / 10.0)


class Electrodes:
    """Electrode sampler with a slow per-electrode baseline drift (random walk)."""

    def __init__(self, p: dict, n: int = 50, block: int = 32):
        self.p = p
        self.n, self.block = n, block
        self.buf_drift = np.empty((0, 19))
        self.i = 0
        self.drift = np.zeros(19)
        self.pos = np.asarray(p["positions_mm"], float)
        self.center = np.asarray(p["contact_center_mm"], float)
        self.h2 = p["fluid_depth_mm"] ** 2

    def __call__(self, rng: np.random.Generator, n: int, normal_force_kpa: float, a_mm: float, shift_mm: float) -> np.ndarray:
        if n != self.n:
            raise ValueError(f"electrodes: built for {self.n} samples per period, asked for {n}")
        if self.i >= len(self.buf_drift):   # noise drawn in blocks of periods (fewer generator calls)
            self.buf_drift = rng.standard_normal((self.block, 19)) * self.p["drift_counts_per_period"]
            self.buf_noise = rng.standard_normal((self.block, n, 19)) * self.p["noise_counts"]
            self.i = 0
        self.drift += self.buf_drift[self.i]
        noise = self.buf_noise[self.i]
        self.i += 1
        p = self.p
        d = self.pos - self.center
        d[:, 0] -= p["displacement_coupling"] * shift_mm
        r2 = np.einsum("ij,ij->i", d, d)
        w2 = a_mm * a_mm + self.h2
        z_kohm = p["baseline_kohm"] * (1.0 + p["kpa_sensitivity"] * normal_force_kpa * (w2 / (w2 + r2)) ** 1.5)
        mean = 4095.0 / (1.0 + z_kohm / 10.0) + self.drift      # = electrode_counts_mean(...) + drift
        return mean + noise
