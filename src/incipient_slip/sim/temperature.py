"""T_AC / T_DC: steady temperature channels with noise (carry no slip information)."""
from __future__ import annotations

import numpy as np


def temperature_counts(rng: np.random.Generator, n: int, p: dict) -> tuple[np.ndarray, np.ndarray]:
    """Return (tac, tdc) unquantized counts, n samples each."""
    w = rng.standard_normal((2, n)) * p["noise_counts"]
    return p["tac_counts"] + w[0], p["tdc_counts"] + w[1]
