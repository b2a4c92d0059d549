"""Motion capture of the object at 120 Hz with position noise."""
from __future__ import annotations

import numpy as np


def mocap_samples(rng: np.random.Generator, y_true_mm: np.ndarray, noise_mm: float) -> np.ndarray:
    """Return measured travel (mm): true travel plus Gaussian jitter."""
    return y_true_mm + rng.standard_normal(y_true_mm.shape) * noise_mm
