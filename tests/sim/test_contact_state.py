"""Physics of the one contact state (issue: simulated rig v2): reversible bulk shear, interfacial
memory, creep-like sliding, one stick ratio for truth, modes and electrodes, no NaN over the
parameters' plausible ranges, the electrodes' stiction dead zone, the friction-limit lag."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from incipient_slip.sim import Rig, contact, load_scene
from incipient_slip.sim.electrodes import play
from incipient_slip.sim.scene import scene_from_dict
from incipient_slip.sim.stick_slip import ContactState, positions, step_contact

MECH = ["contact", "stick_slip", "mocap"]
ALL = ["contact", "stick_slip", "fingertip_modes", "injection", "vibrotactile", "ambient_noise",
       "electrodes", "pdc", "temperature", "mocap", "adc"]


def _scene(effects, **overrides):
    return scene_from_dict({"effects": effects, "overrides": overrides}, "test-scene")


def _load(rig, kpa, periods):
    return [rig.step_period(kpa) for _ in range(periods)]


def test_bulk_shear_springs_back_when_fn_rises_and_returns_when_it_falls():
    rig = Rig(_scene(MECH, stick_slip={"mu_period_jitter": 0.0}), "pla", 3)
    outs = _load(rig, 2.0, 150)                       # load the spring in stick at 2 kPa
    assert not any(o.gross_slip for o in outs)
    y_low = outs[-1].object_y_mm
    up = rig.step_period(5.9, actuator_step=False)
    assert not up.gross_slip
    assert up.object_y_mm < y_low - 0.05              # the pad stiffens: the object moves back, no slip
    assert up.stick_area_ratio > outs[-1].stick_area_ratio   # the stick region grows with F_N
    down = rig.step_period(2.0, actuator_step=False)
    # back at the same F_N and actuator: the bulk part returns; only the small interfacial memory can differ
    assert down.object_y_mm == pytest.approx(y_low, abs=rig.state.interfacial_max_mm + 1e-9)


def test_sliding_is_creep_like_at_constant_force():
    rig = Rig(_scene(MECH, stick_slip={"mu_period_jitter": 0.0}), "nylon", 1)
    outs = _load(rig, 1.5, 450)
    k = next(i for i, o in enumerate(outs) if o.gross_slip)
    y = np.array([o.object_y_mm for o in outs])
    step = 23.0 / 450
    # after the onset the object creeps with the actuator: no period moves it much more than one step
    assert np.diff(y[k + 2:]).max() < 2 * step
    assert np.diff(y[k:]).min() > -1e-9
    # within a period the creep is smooth and monotone (no stick-slip oscillation)
    t = outs[-1].mocap_t_s - outs[-1].t_start_s
    yt = positions(rig.state, rig.spring_n_per_mm, t)
    assert np.all(np.diff(yt) >= -1e-12)


@settings(max_examples=40, deadline=None)
@given(q_excess=st.floats(1e-6, 50.0), f=st.floats(0.05, 3.0), b=st.floats(0.005, 0.05),
       k_s=st.floats(0.005, 10.0), k_b=st.floats(0.01, 5.0))
def test_a_slide_never_overshoots_the_friction_limit(q_excess, f, b, k_s, k_b):
    mu = 0.5
    st_ = ContactState()
    # place the actuator so that the stuck load would be mu F + q_excess
    st_.actuator_mm = (mu * f + q_excess) * (1 / k_s + 1 / k_b) + 0.1
    step_contact(st_, friction_force_n=f, mu_s=mu, dmax_int=0.1, k_spring=k_s, k_bulk=k_b,
                 rate_b=b, v_ref=1.0, v_stick=0.005, period_s=0.5, step=0)
    q = st_.tangential_force_n
    assert math.isfinite(q) and math.isfinite(st_.y_mm)
    assert q >= mu * f * (1 - 1e-12)                 # relaxes towards the limit from above, never below
    assert q <= mu * f + q_excess + 1e-9
    assert st_.y_mm <= st_.actuator_mm                # never past the actuator
    assert st_.y_mm == pytest.approx(st_.actuator_mm - q / k_s, abs=1e-9)


def test_the_reported_stick_ratio_is_the_one_modes_and_electrodes_see():
    rig = Rig(load_scene("paper"), "pla", 5)
    fns = np.random.default_rng(0).choice([1.1, 2.3, 3.5, 4.7, 5.9], 300)
    seen = 0
    for fn in fns:
        out = rig.step_period(float(fn))
        st_ = rig.state
        expect = 0.0 if st_.sliding else 1.0 - min(1.0, abs(st_.interfacial_mm) / st_.interfacial_max_mm)
        assert out.stick_area_ratio == pytest.approx(expect, abs=1e-12)
        if not out.gross_slip:
            assert rig.modes.last_state[1] == out.stick_area_ratio     # the modes got the same number
            seen += 1
        # the electrodes' shift is the play of the same bulk shear the mechanics hold
        fn_n = float(fn) * rig.p["contact"]["newton_per_kpa"]
        ps = rig.p["pre_slip"]
        k_b = contact.bulk_shear_stiffness_n_per_mm(ps["bulk_shear_n_per_mm"], fn_n, ps["bulk_ref_force_n"],
                                                    ps["bulk_stiffening_exponent"], 1e-4)
        assert st_.bulk_mm == pytest.approx(st_.tangential_force_n / k_b, rel=1e-9, abs=1e-12)
        stiction_mm = rig.p["electrodes"]["core_stiction_ratio"] * fn_n / k_b
        assert abs(st_.bulk_mm - rig.electrodes.inner_mm) <= stiction_mm + 1e-9
    assert seen > 50


def test_electrodes_see_nothing_inside_the_stiction_band_and_follow_beyond_it():
    assert play(0.0, 0.2, 0.3) == 0.0 and play(0.0, 0.5, 0.3) == pytest.approx(0.2)
    assert play(0.2, 0.4, 0.3) == 0.2 and play(0.2, -0.2, 0.3) == pytest.approx(0.1)
    base = {"contact_offset_counts": 0.0, "noise_counts": 0.0, "drift_counts": 0.0}
    for fn in (2.0, 5.0):
        rig = Rig(_scene(["contact", "stick_slip", "electrodes", "adc"], electrodes=base,
                         stick_slip={"mu_period_jitter": 0.0}), "pla", 2)
        band = rig.p["electrodes"]["core_stiction_ratio"] * fn * rig.p["contact"]["newton_per_kpa"]
        for _ in range(450):
            rig.step_period(fn)
            if abs(rig.state.tangential_force_n) < band * 0.999:
                assert rig.electrodes.inner_mm == 0.0       # dead zone: threshold proportional to F_N
            if rig.state.tangential_force_n > band * 1.5:
                break
        assert rig.electrodes.inner_mm > 0.0


def test_electrode_drift_does_not_restart_at_zero_and_offsets_differ_per_series():
    scene = _scene(["contact", "stick_slip", "electrodes", "adc"])
    a = Rig(scene, "pla", 1).electrodes
    b = Rig(scene, "pla", 2).electrodes
    assert np.any(a.drift != 0.0) and not np.allclose(a.drift, b.drift)
    assert not np.allclose(a.offset, b.offset)


def test_friction_limit_follows_fn_at_once_without_lag_and_exponentially_with_it():
    for lag in (0.0, 1.0):
        rig = Rig(_scene(MECH, stick_slip={"friction_limit_lag_s": lag, "mu_period_jitter": 0.0}), "pla", 0)
        rig.step_period(5.0, actuator_step=False)
        rig.step_period(1.0, actuator_step=False)
        f = rig.friction_force_n / rig.p["contact"]["newton_per_kpa"]
        expect = 1.0 if lag == 0 else 1.0 + 4.0 * math.exp(-0.5 / lag)
        assert f == pytest.approx(expect, rel=1e-12)


PLAUSIBLE = {
    ("pre_slip", "bulk_stiffening_exponent"): (0.0, 1.0),
    ("pre_slip", "bulk_shear_n_per_mm"): (0.05, 2.0),
    ("stick_slip", "spring_n_per_mm"): (0.005, 1.0),
    ("stick_slip", "friction_limit_lag_s"): (0.0, 2.0),
    ("stick_slip", "mu_spread_scale"): (0.0, 1.5),
    ("stick_slip", "rate_strengthening"): (0.005, 0.05),
    ("stick_slip", "creep_reference_velocity_mm_s"): (0.1, 10.0),
    ("contact", "contact_saturation_radius_mm"): (3.0, 7.0),
    ("contact", "interfacial_shear_modulus_mpa"): (0.05, 1.0),
    ("electrodes", "core_stiction_ratio"): (0.0, 0.5),
    ("electrodes", "settling_time_s"): (0.0, 2.0),
    ("fingertip_modes", "fn_channel_gain"): (0.0, 2.0),
}


@settings(max_examples=25, deadline=None)
@given(u=st.lists(st.floats(0.0, 1.0), min_size=len(PLAUSIBLE), max_size=len(PLAUSIBLE)),
       fns=st.lists(st.sampled_from([0.0, 0.01, 1.1, 2.3, 3.5, 5.9, 12.0]), min_size=30, max_size=30),
       material=st.sampled_from(["pla", "tpu", "nylon"]))
def test_no_nan_anywhere_over_the_plausible_parameter_range(u, fns, material):
    over: dict = {}
    for (sec, key), (lo, hi), x in zip(PLAUSIBLE, PLAUSIBLE.values(), u):
        over.setdefault(sec, {})[key] = lo + (hi - lo) * x
    rig = Rig(_scene(ALL, **over), material, 0)
    for k, fn in enumerate(fns):
        o = rig.step_period(fn)
        for arr in (o.pac_counts, o.electrode_counts, o.mocap_y_mm):
            assert np.all(np.isfinite(arr.astype(float)))
        assert all(math.isfinite(v) for v in (o.object_y_mm, o.tangential_force_n, o.stick_area_ratio,
                                              o.load_ratio_stick))
        assert 0.0 <= o.stick_area_ratio <= 1.0 and 0.0 <= o.load_ratio_stick <= 1.0
