"""Cattaneo-Mindlin partial slip: stick ratio and pre-slip displacement under Q < mu F_N."""
from __future__ import annotations

import numpy as np


def load_ratio_stick(q_n, mu_fn_n):
    """Return s = 1 - |Q| / (mu F_N), clipped to [0, 1] (the paper's pseudo-stick ratio)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = 1.0 - np.abs(q_n) / mu_fn_n
    return np.clip(np.where(mu_fn_n > 0, s, 0.0), 0.0, 1.0)


def stick_area_ratio(s):
    """Return the true stick-area ratio (c/a)^2 = s^(2/3) for load ratio s."""
    return np.power(np.clip(s, 0.0, 1.0), 2.0 / 3.0)


def max_displacement_mm(mu_fn_n: float, g_star_mpa: float, a_mm: float) -> float:
    """Return delta_max = 3 mu F_N / (16 G* a) in mm, the displacement at the onset of gross slip."""
    if a_mm <= 0.0:
        return 0.0
    return 3.0 * mu_fn_n / (16.0 * g_star_mpa * a_mm)


def displacement_mm(q_n, mu_fn_n: float, delta_max_mm: float):
    """Return the pre-slip displacement delta(Q) = sign(Q) delta_max (1 - s^(2/3)) in mm."""
    s = load_ratio_stick(q_n, mu_fn_n)
    return np.sign(q_n) * delta_max_mm * (1.0 - stick_area_ratio(s))
