"""Static feasibility: can any grip within the safety limit hold the end-of-travel load with the
object's travel within the paper's 1.5 mm? A check on the physics, not on any controller.

At the end of the actuator's travel u the spring pulls with Q = k_s (u - y); a stuck contact holds
it at y = Q / k_b(F_N) + delta_int(Q; F_N) (the pad's bulk shear plus the interfacial Mindlin part,
`stick_slip.solve_stick`). If no F_N <= 6 kPa gives a stuck contact with y <= 1.5 mm, no controller
can succeed on the simulated rig, the oracle included (simulator v2's failure, docs/validation.md).
The material's mean friction is used (no series or period jitter).
"""
from __future__ import annotations

import math

import numpy as np

from . import contact, stick_slip
from .scene import Scene


def material_mu(params: dict, material: str) -> float:
    """Return the material's friction coefficient after the friction spread (`Rig` adds its jitter to it)."""
    mats = params["materials"]
    if "mu_identified" in mats[material]:       # measured on a rig (docs/identification.md): no spread
        return float(mats[material]["mu_identified"])
    mu_mean = float(np.mean([m["mu_static"] for m in mats.values()]))
    return mu_mean + params["stick_slip"]["mu_spread_scale"] * (mats[material]["mu_static"] - mu_mean)


def end_load_travel_mm(scene: Scene, material: str, force_kpa: float, travel_mm: float | None = None) -> float:
    """Return the travel y (mm) at which a stuck contact at F_N holds the spring at actuator position
    `travel_mm` (default: the full travel, 23 mm), or nan when friction cannot hold it there."""
    p = scene.params
    c, ss, ps = p["contact"], p["stick_slip"], p["pre_slip"]
    u = float(ss["actuator_travel_mm"] if travel_mm is None else travel_mm)
    f = float(force_kpa) * c["newton_per_kpa"]
    if not (math.isfinite(f) and f >= c["min_contact_force_n"]):
        return math.nan
    mat = p["materials"][material]
    mu = material_mu(p, material)
    g_star = contact.interfacial_shear_modulus_mpa(c, mat["object_modulus_mpa"])
    e_star, _ = contact.effective_moduli_mpa(c, mat["object_modulus_mpa"])
    a = contact.contact_radius_mm(f, contact.effective_radius_mm(c), e_star, c["contact_saturation_radius_mm"])
    k_b = contact.bulk_shear_stiffness_n_per_mm(ps["bulk_shear_n_per_mm"], f, ps["bulk_ref_force_n"],
                                                ps["bulk_stiffening_exponent"], c["min_contact_force_n"])
    dmax = contact.interfacial_max_mm(mu * f, g_star, a)
    direction, y = stick_slip.solve_stick(0.0, u, ss["spring_n_per_mm"], mu * f, dmax, -math.inf, k_b)
    return float(y) if direction == 0 else math.nan


def min_holding_force_kpa(scene: Scene, material: str, max_travel_mm: float = 1.5, limit_kpa: float = 6.0,
                          step_kpa: float = 0.01) -> float:
    """Return the smallest F_N (kPa, on a `step_kpa` grid up to the limit) that holds the end-of-travel
    load with y <= max_travel_mm, or nan when none within the limit does."""
    for fn in np.arange(step_kpa, limit_kpa + 1e-9, step_kpa):
        y = end_load_travel_mm(scene, material, float(fn))
        if math.isfinite(y) and y <= max_travel_mm:
            return float(fn)
    return math.nan
