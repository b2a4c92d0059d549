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

# the formulas the rig evaluates every period are compiled with the rest of its mechanics (one file,
# sim/mechanics.py); they are re-exported here under their documented names:
# hertz_radius_mm a_H = (3 F R / 4 E*)^(1/3); contact_radius_mm a = a_sat (1 - exp(-a_H / a_sat));
# bulk_shear_stiffness_n_per_mm k_b = k_ref (F_N / F_ref)^beta, F_N clamped at the no-contact
# threshold (the finger pad's tangential stiffness grows with normal force: Pataky, Latash &
# Zatsiorsky 2005, J. Biomech. 38:1533-1540; for the BioTac the fluid pressure tensions the skin;
# beta is not identified by the paper's open-loop data and is swept, docs/calibration.md);
# interfacial_max_mm 3 mu F_N / (16 G* a), the interfacial Mindlin displacement at full slip.
from .mechanics import (bulk_shear_stiffness_n_per_mm, contact_radius_mm, hertz_radius_mm,  # noqa: F401
                        interfacial_max_mm)


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


