"""The static feasibility check of simulator v3 (docs/calibration.md, amendment 2): at the fitted
point the end-of-travel load can be held within 1.5 mm below the 6 kPa limit, per material."""
import math

import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.sim.feasibility import end_load_travel_mm, material_mu, min_holding_force_kpa
from incipient_slip.sim.scene import load_scene, with_values

SCENE = load_scene("mechanics")


@pytest.mark.parametrize("material", SCENE.materials)
def test_the_fitted_point_can_hold_the_end_load_within_the_papers_limits(material):
    fn = min_holding_force_kpa(SCENE, material)
    assert math.isfinite(fn) and fn < 6.0, f"{material}: no F_N <= 6 kPa holds the end load within 1.5 mm"
    y = end_load_travel_mm(SCENE, material, fn)
    assert 0.0 < y <= 1.5


def test_v2s_soft_pad_could_not_hold_it_which_is_what_the_check_must_catch():
    # simulator v2's fitted point (k_b 0.204 N/mm at 1 N, beta 0.5, k_s 0.0241 N/mm, spread 1.0)
    v2 = with_values(SCENE, {("pre_slip", "bulk_shear_n_per_mm"): 0.203822, ("pre_slip", "bulk_stiffening_exponent"): 0.5,
                             ("stick_slip", "spring_n_per_mm"): 0.0241457, ("stick_slip", "mu_spread_scale"): 1.0})
    assert math.isnan(min_holding_force_kpa(v2, "pla"))
    assert end_load_travel_mm(v2, "pla", 5.99) > 1.5


def test_too_little_grip_cannot_hold_at_all():
    # friction mu F_N below the spring's end load: no stuck state exists
    q_end = SCENE.params["stick_slip"]["spring_n_per_mm"] * 21.5
    f_small = 0.5 * q_end / material_mu(SCENE.params, "nylon") / SCENE.params["contact"]["newton_per_kpa"]
    assert math.isnan(end_load_travel_mm(SCENE, "nylon", f_small))


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(SCENE.materials), st.floats(0.0, 8.0), st.floats(0.0, 40.0))
def test_a_held_travel_is_finite_and_consistent_with_the_spring(material, fn, u):
    y = end_load_travel_mm(SCENE, material, fn, u)
    if math.isfinite(y):
        # the stuck object sits between its rest position and the actuator, pulled by the spring
        assert 0.0 <= y <= u + 1e-9
