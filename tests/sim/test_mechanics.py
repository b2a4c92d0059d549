"""The compiled mechanics (sim/mechanics.py) are the Python physics they replaced, bit for bit: the
stick solve is scipy's brentq on the same function, the contact formulas are CPython's libm calls,
a whole series in one call (`Rig.run_mechanics`) equals as many `step_period` calls, the slip rule
equals the array rule, and the committed stage-1 calibration summary comes out unchanged.
Every comparison is `==`, never approx."""
import json
import math
import re
from unittest import mock

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from incipient_slip.models.labels import EARLY_S, GROSS_SLIP_MM, GROSS_SLIP_SPAN_S, LATE_S, gross_slip_travel_mm
from incipient_slip.paths import repo_root
from incipient_slip.sim import Rig, SimulationError, contact, load_scene, mechanics
from incipient_slip.sim.scene import scene_from_dict
from incipient_slip.sim.stick_slip import cattaneo_mm, solve_stick

MECH = ["contact", "stick_slip", "mocap"]
RULE = (GROSS_SLIP_SPAN_S, EARLY_S, LATE_S)
FINITE = {"allow_nan": False, "allow_infinity": False}


# --- oracles: the same source run by CPython, and scipy's own brentq ------------------------------

def _scipy_brentq(xa, xb, anchor, u, k, comp, locked, mu_fn, dmax, *_settings):
    """scipy.optimize.brentq on the stick equation, in place of the compiled port, with the
    settings the Python stick solve used (commit 123b40e)."""
    def g(y):
        return mechanics._stick_gap.py_func(y, anchor, u, k, comp, locked, mu_fn, dmax)
    return brentq(g, xa, xb, xtol=1e-13, rtol=4 * np.finfo(float).eps, maxiter=200), True


def _py_solve_stick(*args):
    """solve_stick's source run by CPython with scipy's brentq: the Python the compiled code replaced."""
    with mock.patch.object(mechanics, "_brentq_stick", _scipy_brentq):
        return mechanics.solve_stick.py_func(*args)


def _same(a, b):
    return a == b or (math.isnan(a) and math.isnan(b))


@settings(max_examples=400, deadline=None)
@given(anchor=st.floats(-5.0, 30.0), u=st.floats(-5.0, 30.0), k=st.floats(0.005, 1.0),
       mu_fn=st.one_of(st.just(0.0), st.floats(1e-4, 5.0)), dmax=st.one_of(st.just(0.0), st.floats(1e-6, 0.5)),
       locked=st.one_of(st.just(-math.inf), st.floats(-0.5, 0.5)),
       k_bulk=st.one_of(st.just(math.inf), st.floats(0.01, 10.0)), near=st.floats(0.8, 1.2))
# found by this test: brentq.c before scipy 1.11 compared signs by product, which underflows here
@example(anchor=0.0, u=0.0, k=1.0, mu_fn=1.0, dmax=0.0, locked=2.225073858507e-311, k_bulk=math.inf, near=1.0)
def test_the_stick_solve_is_scipys_brentq_bit_for_bit(anchor, u, k, mu_fn, dmax, locked, k_bulk, near):
    solve_stick(anchor, u, k, mu_fn, dmax, locked, k_bulk)     # compiled before the oracle patches a global
    for uu in (u, anchor + near * mu_fn * (1.0 / k + (0.0 if math.isinf(k_bulk) else 1.0 / k_bulk))):
        want = _py_solve_stick(anchor, uu, k, mu_fn, dmax, locked, k_bulk)
        got = solve_stick(anchor, uu, k, mu_fn, dmax, locked, k_bulk)
        assert got[0] == want[0] and _same(got[1], want[1]), (got, want)


@settings(max_examples=300, deadline=None)
@given(f=st.floats(0.0, 10.0, **FINITE), r=st.floats(1.0, 200.0), e=st.floats(0.005, 5.0), sat=st.floats(1.0, 10.0),
       ref=st.floats(0.05, 2.0), fref=st.floats(0.1, 3.0), beta=st.one_of(st.integers(-1, 3), st.floats(-0.5, 2.0)),
       q=st.floats(-5.0, 5.0), mu_fn=st.floats(0.0, 5.0), dmax=st.floats(0.0, 0.5), g=st.floats(0.01, 1.0))
def test_the_contact_formulas_are_cpythons_arithmetic(f, r, e, sat, ref, fref, beta, q, mu_fn, dmax, g):
    a_h = float(math.cbrt(3.0 * max(f, 0.0) * r / (4.0 * e)))
    assert contact.hertz_radius_mm(f, r, e) == a_h
    a = contact.contact_radius_mm(f, r, e, sat)
    assert a == float(-sat * math.expm1(-a_h / sat))
    ff = max(float(f), float(1e-4))
    assert contact.bulk_shear_stiffness_n_per_mm(ref, f, fref, beta, 1e-4) == float(ref * (ff / fref) ** beta)
    assert contact.interfacial_max_mm(mu_fn, g, a) == (0.0 if a <= 0.0 else 3.0 * mu_fn / (16.0 * g * a))
    assert cattaneo_mm(q, mu_fn, dmax) == mechanics.cattaneo_mm.py_func(q, mu_fn, dmax)


@settings(max_examples=300, deadline=None)
@given(f=st.one_of(st.just(0.0), st.floats(0.01, 3.0)), mu=st.floats(0.3, 1.0), dmax=st.floats(0.0, 0.3),
       k_s=st.floats(0.005, 1.0), k_b=st.floats(0.05, 5.0), b=st.floats(0.005, 0.05), v_ref=st.floats(0.1, 10.0),
       v_stick=st.floats(0.001, 0.01), u=st.floats(-5.0, 60.0), anchor=st.floats(-5.0, 30.0),
       y=st.floats(-5.0, 30.0), locked=st.floats(-0.3, 0.3), lag=st.one_of(st.just(0.0), st.floats(0.05, 2.0)),
       fn=st.sampled_from([0.0, 5e-5, 1.1, 2.94, 5.9]), prev_f=st.floats(0.0, 3.0), draw=st.floats(-3.0, 3.0))
def test_the_compiled_contact_step_period_and_positions_are_their_python(
        f, mu, dmax, k_s, k_b, b, v_ref, v_stick, u, anchor, y, locked, lag, fn, prev_f, draw):
    """The same source run by CPython (py_func; the creep through numpy either way) gives the same
    state and numbers: stick, gross slip forward and back, slides that end or go on, no contact."""
    s = mechanics.new_state()
    s[[mechanics.ACTUATOR, mechanics.ANCHOR, mechanics.Y, mechanics.INTERFACIAL]] = u, anchor, y, locked
    args = (f, mu, dmax, k_s, k_b, b, v_ref, v_stick, 0.5)
    a, c = s.copy(), s.copy()
    assert mechanics.step_contact(a, *args) == mechanics.step_contact.py_func(c, *args)
    assert np.array_equal(a, c, equal_nan=True)
    t = np.arange(60) / 120.0
    ya, yc = np.empty(60), np.empty(60)
    mechanics.positions(a, k_s, t, ya)
    mechanics.positions.py_func(c, k_s, t, yc)
    assert ya.tolist() == yc.tolist()
    p = np.array([mechanics._WARM_PARAMS[name] for name in mechanics.PARAMS])
    p[[mechanics.P_LAG, mechanics.P_K_SPRING, mechanics.P_BULK_REF, mechanics.P_RATE_B]] = lag, k_s, k_b, b
    s[mechanics.F_EFF] = prev_f
    a, c = s.copy(), s.copy()
    assert mechanics.period(a, p, fn, draw, True) == mechanics.period.py_func(c, p, fn, draw, True)
    assert np.array_equal(a, c, equal_nan=True)


# --- a series in one call == as many step_period calls ------------------------------------------

def _columns(rig, forces, actuator_step, stop):
    """What run_mechanics returns, built from step_period and the array slip rule."""
    rows = {name: [] for name in (*mechanics.COLUMNS, "normal_force_kpa")}
    for fn in forces:
        out = rig.step_period(float(fn), actuator_step)
        travel = gross_slip_travel_mm(out.mocap_t_s, out.mocap_y_mm, np.array([out.t_start_s + rig.period_s]))[0]
        for name, v in (("object_y_mm", out.object_y_mm), ("tangential_force_n", out.tangential_force_n),
                        ("stick_area_ratio", out.stick_area_ratio), ("load_ratio_stick", out.load_ratio_stick),
                        ("gross_slip", out.gross_slip), ("sliding", rig.state.sliding),
                        ("slide_q0_n", rig.state.slide_q0_n), ("actuator_mm", out.actuator_mm),
                        ("friction_force_n", rig.friction_force_n), ("travel_mm", travel),
                        ("normal_force_kpa", out.normal_force_kpa)):
            rows[name].append(v)
        if travel >= stop:
            break
    return rows


def _assert_same_run(scene, material, seed, chunks, actuator_step, stop, offset_mm=0.0):
    a, b = Rig(scene, material, seed), Rig(scene, material, seed)
    a.state.actuator_mm = b.state.actuator_mm = offset_mm
    runs = []
    for forces in chunks:
        want = _columns(a, forces, actuator_step, stop)
        got = b.run_mechanics(forces, RULE, actuator_step=actuator_step, stop_travel_mm=stop)
        runs.append(got)
        for name, values in want.items():
            assert got[name].tolist() == values, name
        assert (b.state.values.tobytes() == a.state.values.tobytes() or
                np.array_equal(b.state.values, a.state.values, equal_nan=True))
        assert b.period == a.period and b.prev_sar == a.prev_sar
        for stream in ("friction", "mocap"):                # the streams stand where step_period leaves them
            assert b.rng[stream].bit_generator.state == a.rng[stream].bit_generator.state
        if len(got["travel_mm"]) < len(forces):
            break
    return {name: np.concatenate([r[name] for r in runs]) for name in runs[0]}


FORCES = st.one_of(st.sampled_from([0.0, 5e-5, 1.1, 1.5, 2.3, 2.94, 3.5, 4.7, 5.9]), st.floats(0.0, 8.0))


@settings(max_examples=60, deadline=None)
@given(k_b=st.floats(0.1, 1.0), k_s=st.floats(0.01, 0.2), beta=st.floats(-0.5, 2.0),
       lag=st.one_of(st.just(0.0), st.floats(0.05, 2.0)), jitter=st.floats(0.0, 0.03),
       material=st.sampled_from(["pla", "abs", "petg", "nylon", "tpu"]), seed=st.integers(0, 2**40),
       chunks=st.lists(st.lists(FORCES, min_size=1, max_size=80), min_size=1, max_size=3),
       actuator_step=st.booleans(), stop=st.sampled_from([math.inf, GROSS_SLIP_MM]), offset=st.floats(0.0, 25.0))
def test_a_series_in_one_call_is_step_period_bit_for_bit(k_b, k_s, beta, lag, jitter, material, seed, chunks,
                                                          actuator_step, stop, offset):
    scene = scene_from_dict({"effects": MECH, "overrides": {
        "pre_slip": {"bulk_shear_n_per_mm": k_b, "bulk_stiffening_exponent": beta},
        "stick_slip": {"spring_n_per_mm": k_s, "friction_limit_lag_s": lag, "mu_period_jitter": jitter}}}, "t")
    _assert_same_run(scene, material, seed, chunks, actuator_step, stop, offset)


def test_the_property_runs_reach_slides_restick_and_no_contact():
    """A fixed case that must hold every regime: stick, slides that end within the period and that
    go on, free moves without contact, F_N steps, with the lag on."""
    scene = scene_from_dict({"effects": MECH, "overrides": {"stick_slip": {"friction_limit_lag_s": 0.7,
                                                                           "spring_n_per_mm": 0.2}}}, "t")
    forces = np.random.default_rng(4).choice([0.0, 1.1, 1.1, 1.5, 2.3, 5.9], 400)
    got = _assert_same_run(scene, "nylon", 9, [forces[:150], forces[150:]], True, math.inf, offset_mm=12.0)
    assert got["gross_slip"].any() and got["sliding"].any() and not got["gross_slip"].all()
    assert (got["normal_force_kpa"] == 0.0).any() and (got["travel_mm"] >= GROSS_SLIP_MM).any()


def test_an_early_stop_leaves_the_rig_where_step_period_would():
    scene = load_scene("mechanics")
    got = _assert_same_run(scene, "pla", 3, [np.full(2000, 1.1)], True, GROSS_SLIP_MM)
    assert 0 < len(got["travel_mm"]) < 2000 and got["travel_mm"][-1] >= GROSS_SLIP_MM


def test_run_mechanics_refuses_other_scenes_and_bad_forces():
    with pytest.raises(ValueError, match="contact, stick_slip, mocap"):
        Rig(load_scene("paper"), "pla", 1).run_mechanics([1.0], RULE)
    rig = Rig(load_scene("mechanics"), "pla", 1)
    with pytest.raises(ValueError, match="step 2: normal_force_kpa must be finite"):
        rig.run_mechanics([1.0, 2.0, math.nan], RULE)
    assert rig.period == 0


def test_a_non_finite_state_is_the_same_named_simulation_error_on_both_paths():
    errors = []
    for run in (lambda rig: rig.step_period(2.0), lambda rig: rig.run_mechanics([2.0], RULE)):
        rig = Rig(load_scene("mechanics"), "pla", 1)
        rig.state.anchor_mm = math.inf
        with pytest.raises(SimulationError, match="step 0: non-finite contact state") as err:
            run(rig)
        errors.append(str(err.value).split(" (")[0])
    assert errors[0] == errors[1]


# --- the slip rule, one period compiled == the array rule -----------------------------------------

def test_one_period_travel_is_bit_for_bit_the_array_rule():
    """On a simulated collection series and on sparse mocap where an interval holds no sample."""
    from incipient_slip.sim.protocols import run_collection
    rig = Rig(load_scene("mechanics"), "pla", 3)
    cases = [(o.mocap_t_s, o.mocap_y_mm, o.t_start_s + rig.period_s) for o in run_collection(rig, 120)]
    rng = np.random.default_rng(1)
    for _ in range(200):
        t = np.sort(rng.uniform(0.0, 0.5, rng.integers(1, 6)))      # few samples: empty intervals
        cases.append((t, rng.normal(size=len(t)).cumsum(), float(rng.uniform(0.2, 0.7))))
    for t, y, end in cases:
        got = mechanics.period_travel_mm(t, y, end, GROSS_SLIP_SPAN_S, EARLY_S, LATE_S)
        assert got == gross_slip_travel_mm(t, y, np.array([end]))[0]


# --- end to end: the committed calibration ---------------------------------------------------------

def test_the_committed_stage1_summary_comes_out_bit_for_bit():
    """The stage-1 summary at the committed fit (docs/figures/calibration_results.json), recomputed
    with the sizes and seed its provenance names, equals the committed one exactly. (A change of the
    physics fails this until the calibration is rerun and committed.)"""
    from incipient_slip.experiments import mechanics_fit
    from incipient_slip.sim.scene import with_values
    res = json.loads((repo_root() / "docs" / "figures" / "calibration_results.json").read_text())
    prov = next(iter(res["provenance"].values()))
    m = re.search(r"seed (\d+), (\d+) collection series, (\d+) no-action runs per material", prov)
    assert m, f"the calibration's provenance no longer names its seed and sizes: {prov}"
    seed, n_series, runs = map(int, m.groups())
    values = {tuple(k.split(".")): v for k, v in res["mechanics"]["values"].items()}
    summary = mechanics_fit.mechanics_summary(with_values(load_scene("paper"), values), n_series, runs, seed, 1)
    assert json.loads(json.dumps(summary)) == res["mechanics"]["summary"]
