"""Hertz contact of the fingertip (sphere) on the convex object (sphere)."""
from __future__ import annotations

import numpy as np


def effective_radius_mm(p: dict) -> float:
    """Return the effective radius R = (1/R1 + 1/R2)^-1 in mm."""
    return 1.0 / (1.0 / p["finger_radius_mm"] + 1.0 / p["object_radius_mm"])


def effective_moduli_mpa(p: dict, object_modulus_mpa: float) -> tuple[float, float]:
    """Return (E*, G*) in MPa (= N/mm^2) for the skin on the object, same Poisson ratio."""
    nu = p["skin_poisson"]
    e_skin = p["skin_modulus_mpa"]
    e_star = 1.0 / ((1 - nu**2) / e_skin + (1 - nu**2) / object_modulus_mpa)
    g_skin = e_skin / (2 * (1 + nu))
    g_obj = object_modulus_mpa / (2 * (1 + nu))
    g_star = 1.0 / ((2 - nu) / g_skin + (2 - nu) / g_obj)
    return e_star, g_star


def contact_radius_mm(normal_force_n: float, radius_mm: float, e_star_mpa: float) -> float:
    """Return the Hertz contact radius a = (3 F R / 4 E*)^(1/3) in mm (0 without contact)."""
    return float(np.cbrt(3.0 * max(normal_force_n, 0.0) * radius_mm / (4.0 * e_star_mpa)))


def tangential_shear_modulus_mpa(g_star_ref_mpa: float, normal_force_n: float, ref_force_n: float,
                                 exponent: float, min_force_n: float) -> float:
    """Return the effective tangential shear modulus G*_t = G*_ref (F_N / F_ref)^beta in MPa.

    Used only in the tangential (Mindlin) compliance; the Hertz normal contact keeps E*. F_N is
    clamped at the no-contact threshold min_force_n so G*_t stays positive and finite as F_N -> 0.
    With beta = 2/3, delta_max = 3 mu F_N / (16 G*_t a) does not depend on F_N (a ~ F_N^(1/3))."""
    f = max(float(normal_force_n), float(min_force_n))
    return float(g_star_ref_mpa * (f / ref_force_n) ** exponent)
