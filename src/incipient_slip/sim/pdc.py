"""P_DC: the static pressure that the paper uses as its normal-force measure (kPa)."""
from __future__ import annotations

import numpy as np


def pdc_counts(rng: np.random.Generator, n: int, normal_force_kpa: float, p: dict, pa_per_count: float) -> np.ndarray:
    """Return n P_DC samples in (unquantized) counts for F_N in kPa."""
    kpa = normal_force_kpa + rng.standard_normal(n) * p["noise_kpa"]
    return p["baseline_counts"] + kpa * 1000.0 / pa_per_count
