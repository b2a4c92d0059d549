"""Contact of the fingertip pad on the convex object: contact radius, moduli, pad shear stiffness.

The contact radius follows Hertz at small loads and saturates at the pad's flat-contact size:
a = a_sat (1 - exp(-a_H / a_sat)), a_H = (3 F R / 4 E*)^(1/3). Hertz alone reaches a/R ~ 0.9 at
the paper's largest grip, far outside small-strain theory; a fingertip's contact area grows
quickly at small forces and then levels off as the pad flattens against the object (finger pad
contact area saturating near 1 N: Serina, Mote & Rempel 1997, J. Biomech. 30:1035-1040; for the
BioTac the skin over the fluid behaves the same way). The saturating form is an assumption with
a stated range for a_sat; it is Hertz to first order as F -> 0 and never exceeds a_sat (tests).
"""
from __future__ import annotations

import math


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


def interfacial_shear_modulus_mpa(p: dict, object_modulus_mpa: float) -> float:
    """Return G* (MPa) of the skin's surface layer on the object, for the interfacial Mindlin part."""
    nu = p["skin_poisson"]
    g_obj = object_modulus_mpa / (2 * (1 + nu))
    return 1.0 / ((2 - nu) / p["interfacial_shear_modulus_mpa"] + (2 - nu) / g_obj)


def hertz_radius_mm(normal_force_n: float, radius_mm: float, e_star_mpa: float) -> float:
    """Return the Hertz contact radius a_H = (3 F R / 4 E*)^(1/3) in mm (0 without contact)."""
    return float(math.cbrt(3.0 * max(normal_force_n, 0.0) * radius_mm / (4.0 * e_star_mpa)))


def contact_radius_mm(normal_force_n: float, radius_mm: float, e_star_mpa: float, saturation_mm: float) -> float:
    """Return the contact radius a = a_sat (1 - exp(-a_H / a_sat)) in mm: Hertz at small loads, < a_sat always."""
    a_h = hertz_radius_mm(normal_force_n, radius_mm, e_star_mpa)
    return float(-saturation_mm * math.expm1(-a_h / saturation_mm))


def bulk_shear_stiffness_n_per_mm(ref_n_per_mm: float, normal_force_n: float, ref_force_n: float,
                                  exponent: float, min_force_n: float) -> float:
    """Return the pad's bulk shear stiffness k_b = k_ref (F_N / F_ref)^beta in N/mm.

    The finger pad's tangential stiffness grows with normal force (Pataky, Latash & Zatsiorsky 2005,
    J. Biomech. 38:1533-1540; for the BioTac the fluid pressure tensions the skin). beta is not
    identified by the paper's open-loop data and is swept (docs/calibration.md). F_N is clamped at
    the no-contact threshold so k_b stays positive and finite as F_N -> 0."""
    f = max(float(normal_force_n), float(min_force_n))
    return float(ref_n_per_mm * (f / ref_force_n) ** exponent)


def interfacial_max_mm(mu_fn_n: float, g_star_mpa: float, a_mm: float) -> float:
    """Return the interfacial Mindlin displacement at full slip, 3 mu F_N / (16 G* a), in mm."""
    if a_mm <= 0.0:
        return 0.0
    return 3.0 * mu_fn_n / (16.0 * g_star_mpa * a_mm)
