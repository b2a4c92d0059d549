"""T_AC / T_DC: steady temperature channels with noise (carry no slip information)."""
from __future__ import annotations

import numpy as np

from . import kernels


def temperature_counts(rng: np.random.Generator, n: int, p: dict,
                       out: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return (tac, tdc) unquantized counts, n samples each (into `out` when given)."""
    w = rng.standard_normal((2, n))
    tac, tdc = (np.empty(n), np.empty(n)) if out is None else out
    kernels.level_plus_noise(float(p["tac_counts"]), w[0], float(p["noise_counts"]), tac)
    kernels.level_plus_noise(float(p["tdc_counts"]), w[1], float(p["noise_counts"]), tdc)
    return tac, tdc
