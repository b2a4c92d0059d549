"""Micro-slip bursts (the vibrotactile signal without injection): impulses into the fingertip modes."""
from __future__ import annotations

import numpy as np

from . import kernels


def bursts_pa(rng: np.random.Generator, n: int, fs_hz: float, p: dict, annulus_growth: float,
              slide_s: float, slide_start_s: float, roughness: float, pa_per_unit: float) -> np.ndarray:
    """Return n samples of burst excitation (Pa): a Poisson number of impulses whose rate grows
    with the growth of the slip annulus this period and with the time spent sliding."""
    x = np.zeros(n)
    n_micro = rng.poisson(p["annulus_bursts_per_unit"] * max(annulus_growth, 0.0))
    n_slide = rng.poisson(p["slide_bursts_per_s"] * slide_s) if slide_s > 0 else 0
    amp = p["burst_amplitude"] * roughness * pa_per_unit
    if n_micro:
        kernels.add_at(x, rng.integers(0, n, n_micro), rng.standard_normal(n_micro) * amp)
    if n_slide:
        i0 = int(slide_start_s * fs_hz)
        i1 = max(i0 + 1, min(n, int((slide_start_s + slide_s) * fs_hz)))
        kernels.add_at(x, rng.integers(i0, i1, n_slide), rng.standard_normal(n_slide) * amp)
    return x
