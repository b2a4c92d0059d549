"""P_DC: the static pressure that the paper uses as its normal-force measure (kPa)."""
from __future__ import annotations

import numpy as np

from . import kernels


def pdc_counts(rng: np.random.Generator, n: int, normal_force_kpa: float, p: dict, pa_per_count: float,
               out: np.ndarray | None = None) -> np.ndarray:
    """Return n P_DC samples in (unquantized) counts for F_N in kPa (into `out` when given):
    baseline + (F_N + noise) 1000 / pa_per_count."""
    out = np.empty(n) if out is None else out
    kernels.pdc_counts(float(normal_force_kpa), rng.standard_normal(n), float(p["noise_kpa"]),
                       float(p["baseline_counts"]), float(pa_per_count), out)
    return out
