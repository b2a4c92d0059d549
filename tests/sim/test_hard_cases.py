"""Hard cases of the physics and numerics (issue 4, item 7): finite, bounded, physically ordered."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from incipient_slip.sim import Rig, load_scene
from incipient_slip.sim import contact
from incipient_slip.sim.mechanics import cattaneo_mm, load_ratio_stick, stick_area_ratio
from incipient_slip.sim.scene import scene_from_dict
from incipient_slip.sim.sos import sosfilt_state
from incipient_slip.sim.stick_slip import solve_stick

FAST = settings(max_examples=60, deadline=None)


@FAST
@given(mu_fn=st.floats(0.01, 5.0), frac=st.lists(st.floats(0.0, 1.0), min_size=2, max_size=20))
def test_stick_ratio_never_rises_as_q_rises(mu_fn, frac):
    # the compiled formulas the rig runs (mechanics.period and step_contact), not a copy: the load
    # ratio s, the Cattaneo displacement and the stick-area ratio (c/a)^2 = 1 - delta / delta_max
    q = np.sort(np.array(frac)) * mu_fn
    s = np.array([load_ratio_stick(v, mu_fn) for v in q])
    d = np.array([cattaneo_mm(v, mu_fn, 1.5) for v in q])
    sar = np.array([stick_area_ratio(v, 1.5) for v in d])
    assert np.allclose(sar, s ** (2 / 3), atol=1e-12)      # on the monotonic path (c/a)^2 = s^(2/3)
    assert np.all(np.diff(s) <= 1e-12) and np.all(np.diff(sar) <= 1e-12)
    assert np.all(np.diff(d) >= -1e-12) and np.all((d >= 0) & (d <= 1.5 + 1e-12))
    assert np.all(sar >= s - 1e-12)  # (c/a)^2 = s^(2/3) >= s: the label and the truth differ


@FAST
@given(eps=st.floats(1e-18, 1e-3), dmax=st.floats(0.01, 3.0), k=st.floats(0.01, 100.0))
def test_q_approaching_mu_fn_stays_finite_and_bounded(eps, dmax, k):
    mu_fn = 1.0
    # actuator placed so that the stuck solution sits within eps of the limit
    u = mu_fn * (1 - eps) / k + dmax * (1 - eps ** (2 / 3))
    direction, y = solve_stick(0.0, u, k, mu_fn, dmax)
    if eps < 1e-10 and direction == 1:
        return                    # within rounding of the limit either answer is right; no exception
    assert direction == 0 and math.isfinite(y)
    q = k * (u - y)
    assert 0 <= q <= mu_fn * (1 + 1e-9) and -1e-12 <= y <= dmax + 1e-9


def test_q_exactly_at_the_limit_sticks_with_zero_ratio():
    k, mu_fn, dmax = 0.5, 1.0, 1.25   # binary-exact numbers: the limit is hit exactly
    u = mu_fn / k + dmax              # y = dmax makes Q = mu F_N exactly
    direction, y = solve_stick(0.0, u, k, mu_fn, dmax)
    assert direction == 0 and y == pytest.approx(dmax)
    assert load_ratio_stick(k * (u - y), mu_fn) == pytest.approx(0.0, abs=1e-12)
    assert solve_stick(0.0, u + 1e-9, k, mu_fn, dmax)[0] == 1   # a hair more: gross slip


@FAST
@given(fn_n=st.floats(0.0, 50.0), a_sat=st.floats(2.0, 8.0), e_star=st.floats(0.005, 1.0))
def test_contact_radius_is_hertz_at_small_loads_and_never_exceeds_saturation(fn_n, a_sat, e_star):
    r = 6.7
    a = contact.contact_radius_mm(fn_n, r, e_star, a_sat)
    a_h = contact.hertz_radius_mm(fn_n, r, e_star)
    assert math.isfinite(a) and 0.0 <= a < a_sat + 1e-12 and a <= a_h + 1e-12
    if a_h < 0.01 * a_sat:
        assert a == pytest.approx(a_h, rel=0.01)
    assert contact.contact_radius_mm(fn_n * 1.1 + 1e-6, r, e_star, a_sat) >= a


def test_contact_radius_over_the_grip_range_stays_well_inside_the_fingertip():
    rig = Rig(load_scene("mechanics"), "pla", 0)
    c = rig.p["contact"]
    for kpa in (1.1, 5.9):
        a = contact.contact_radius_mm(kpa * c["newton_per_kpa"], rig.radius_mm, rig.e_star, c["contact_saturation_radius_mm"])
        assert a / rig.radius_mm < 0.6, (kpa, a)     # Hertz alone gives a/R ~ 0.65..1.15 here


@pytest.mark.parametrize("fn_n", [0.0, 1e-300, 1e-12])
def test_bulk_shear_stiffness_is_clamped_at_the_no_contact_threshold(fn_n):
    k = contact.bulk_shear_stiffness_n_per_mm(0.2, fn_n, 1.0, 0.5, 1e-4)
    assert k == pytest.approx(0.2 * 1e-4 ** 0.5) and k > 0

@pytest.mark.parametrize("fn_kpa", [2.51e-4, 1e-3, 1e-2])   # 2.51e-4 kPa x 0.4 N/kPa: just above 1e-4 N
def test_contact_just_above_the_threshold_is_finite_and_bounded(fn_kpa):
    rig = Rig(load_scene("mechanics"), "pla", 0)
    for _ in range(20):
        out = rig.step_period(fn_kpa)
        assert math.isfinite(out.object_y_mm) and 0.0 <= out.stick_area_ratio <= 1.0
        assert np.all(np.isfinite(out.mocap_y_mm)) and abs(out.object_y_mm - out.actuator_mm) < 3.0


def _scene(effects, **overrides):
    return scene_from_dict({"effects": effects, "overrides": overrides}, "test-scene")


ALL = ["contact", "stick_slip", "fingertip_modes", "injection", "vibrotactile", "ambient_noise",
       "electrodes", "pdc", "temperature", "mocap", "adc"]


@pytest.mark.parametrize("fn", [0.0, 1e-12, 1e-6])
def test_no_contact_is_finite_with_zero_stick_ratio(fn):
    rig = Rig(_scene(ALL), "pla", 0)
    for _ in range(5):
        out = rig.step_period(fn)
    assert out.stick_area_ratio == 0.0 and math.isfinite(out.object_y_mm)
    assert np.all(np.isfinite(out.mocap_y_mm))
    # free object (no friction) is pulled towards the actuator, never past bounded overshoot
    assert abs(out.object_y_mm - out.actuator_mm) < 1.0


def test_very_stiff_spring_with_tiny_mass_is_exact_and_cheap():
    scene = _scene(["contact", "stick_slip", "mocap"], stick_slip={"spring_n_per_mm": 1e4})
    rig = Rig(scene, "pla", 0)
    ys = [rig.step_period(2.0).object_y_mm for _ in range(60)]
    assert np.all(np.isfinite(ys)) and np.all(np.diff(ys) >= -1e-9)
    assert max(ys) < 60 * 23 / 450 + 1e-6      # never ahead of the actuator


def test_stick_slip_switch_at_every_step_stays_bounded():
    rig = Rig(_scene(["contact", "stick_slip", "mocap"]), "nylon", 1)
    for _ in range(150):          # pre-load the spring
        rig.step_period(3.0)
    # contact released every other period: slide, then re-grip (often mid-slide) at 5.9 kPa
    outs = [rig.step_period(5.9 if k % 2 else 0.0) for k in range(120)]
    ys = np.array([o.object_y_mm for o in outs])
    slips = np.array([o.gross_slip for o in outs])
    assert slips[::2].all()                               # slides at every released step
    assert np.all(ys <= np.array([o.actuator_mm for o in outs]) + 1.0)   # bounded overshoot
    assert np.all(np.isfinite(np.concatenate([o.mocap_y_mm for o in outs])))
    assert all(0.0 <= o.stick_area_ratio <= 1.0 for o in outs)


def test_band_edge_transfer_function_fails_where_sections_do_not():
    fs, x = 2200.0, np.random.default_rng(0).standard_normal(50_000)
    b, a = signal.butter(10, [10, 1000], btype="bandpass", fs=fs)
    assert np.abs(np.roots(a)).max() > 1.0                 # rounding moved poles outside the unit circle
    with np.errstate(all="ignore"):
        y_tf = signal.lfilter(b, a, x)
    sos = signal.butter(10, [10, 1000], btype="bandpass", fs=fs, output="sos")
    y_sos, _ = sosfilt_state(sos, x, np.zeros((sos.shape[0], 2)))
    assert not np.all(np.isfinite(y_tf)) or np.abs(y_tf).max() > 1e6
    assert np.all(np.isfinite(y_sos)) and np.abs(y_sos).max() < 10
    w, h = signal.sosfreqz(sos, worN=[10.0, 200.0], fs=fs)
    assert abs(h[1]) == pytest.approx(1.0, abs=1e-3) and abs(h[0]) == pytest.approx(2 ** -0.5, abs=1e-2)


def test_clipping_at_extreme_intensity_stays_in_range():
    rig = Rig(load_scene("paper"), "pla", 0)
    rig.set_injection(True, 40.0)
    pac = np.concatenate([rig.step_period(3.0).pac_counts for _ in range(4)])
    assert pac.dtype == np.int16
    assert pac.max() == 2054 and pac.min() == -2054 and np.abs(pac).max() <= 2054


def test_million_sample_run_has_no_drift_or_state_growth():
    rig = Rig(_scene(["contact", "stick_slip", "fingertip_modes", "injection", "adc"]), "pla", 4)
    pac, zmax = [], []
    for _ in range(910):          # 910 x 1100 > 10^6 samples
        pac.append(rig.step_period(3.0, actuator_step=False).pac_counts)
        zmax.append(max(np.abs(rig.band.zi).max(), np.abs(rig.modes.zi).max()))
    pac = np.concatenate(pac).astype(float)
    assert pac.size >= 1_000_000
    first, last = pac[: pac.size // 2], pac[pac.size // 2:]
    assert abs(first.mean()) < 1.0 and abs(last.mean()) < 1.0
    assert last.std() == pytest.approx(first.std(), rel=0.05)
    assert max(zmax[-100:]) < 3 * max(zmax[:100])


def test_non_finite_normal_force_is_an_error_naming_the_step():
    rig = Rig(_scene(["contact", "stick_slip"]), "pla", 0)
    rig.step_period(2.0)
    with pytest.raises(ValueError, match="step 1: normal_force_kpa"):
        rig.step_period(float("nan"))


@pytest.mark.parametrize("key,value", [("rate_strengthening", 0.0), ("friction_limit_lag_s", -1.0),
                                       ("spring_n_per_mm", float("nan"))])
def test_unphysical_friction_parameters_are_a_scene_error(key, value):
    from incipient_slip.sim import SceneError
    with pytest.raises(SceneError, match=key):
        _scene(["contact", "stick_slip"], stick_slip={key: value})


@settings(max_examples=8, deadline=None)
@given(fn=st.sampled_from([1.1, 2.3, 3.5, 4.7, 5.9]), material=st.sampled_from(["pla", "abs", "petg", "nylon", "tpu"]),
       seed=st.integers(0, 2**32))
def test_stick_ratio_falls_while_the_spring_loads_at_fixed_force(fn, material, seed):
    # friction held constant within the series (no per-period jitter): the ordering is exact
    scene = _scene(["contact", "stick_slip", "mocap"], stick_slip={"mu_period_jitter": 0.0})
    rig = Rig(scene, material, seed)
    outs = []
    for _ in range(450):
        o = rig.step_period(fn)
        if o.gross_slip:
            break
        outs.append(o)
    q = np.array([o.tangential_force_n for o in outs])
    s = np.array([o.load_ratio_stick for o in outs])
    sar = np.array([o.stick_area_ratio for o in outs])
    y = np.array([o.object_y_mm for o in outs])
    assert np.all(np.diff(y) >= -1e-9) and np.all(np.diff(q) > 0)
    assert np.all(np.diff(s) <= 1e-12) and np.all(np.diff(sar) <= 1e-12)
    assert np.all((sar >= 0) & (sar <= 1)) and s[-1] < s[0]
