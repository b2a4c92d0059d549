"""Specification of the grip law, supervisor rules and score (pure functions)."""
import math

import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.control import (
    ControlParams, SupervisorRules, action, estimate_problem, judge_step, next_force, score,
)

PARAMS = ControlParams()
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
ESTIMATE = st.one_of(ANY_FLOAT, st.none(), st.text(max_size=3), st.booleans())


def test_lower_stick_ratio_raises_normal_force():
    up = next_force(3.0, 0.1, PARAMS)
    down = next_force(3.0, 0.6, PARAMS)
    assert up.normal_force_kpa > 3.0 > down.normal_force_kpa
    assert not up.hold and not down.hold


def test_force_is_unchanged_at_the_target():
    assert next_force(3.0, PARAMS.target_stick_ratio, PARAMS).normal_force_kpa == pytest.approx(3.0)


def test_action_is_the_paper_law():
    assert action(0.5, 0.3, 2.0) == pytest.approx(0.4)


def test_rate_limit_bounds_one_step():
    p = ControlParams(gain_kpa=100.0, max_step_kpa=0.2)
    assert next_force(3.0, 0.0, p).normal_force_kpa == pytest.approx(3.2)
    assert next_force(3.0, 1.0, p).normal_force_kpa == pytest.approx(2.8)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -0.01, 1.01, -5.0, None, "0.3"])
def test_nan_or_out_of_range_estimate_is_rejected_and_held(bad):
    decision = next_force(3.0, bad, PARAMS)
    assert decision.hold and decision.reason
    assert decision.normal_force_kpa == 3.0


def test_invalid_or_wrong_period_estimate_is_a_problem():
    assert estimate_problem(0.3, valid=False)
    assert estimate_problem(0.3, period=4, expected_period=5)
    assert estimate_problem(0.3, method="e1", expected_method="injection")
    assert estimate_problem(0.3, period=5, expected_period=5) == ""


def test_params_refuse_a_limit_above_safety():
    with pytest.raises(ValueError, match="max_force_kpa"):
        ControlParams(max_force_kpa=7.0)


@settings(max_examples=300, deadline=None)
@given(st.lists(ESTIMATE, max_size=200),
       st.floats(0.0, 6.0), st.floats(0.0, 1.0), st.floats(0.0, 50.0), st.floats(0.01, 3.0))
def test_force_never_exceeds_the_safety_limit(estimates, start, s_d, k, step):
    params = ControlParams(target_stick_ratio=s_d, gain_kpa=k, max_step_kpa=step)
    force = start
    for s in estimates:
        force = next_force(force, s, params).normal_force_kpa
        assert params.min_force_kpa <= force <= params.safety_limit_kpa
        assert math.isfinite(force)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(ESTIMATE, st.booleans()), max_size=100), st.floats(1.1, 6.0))
def test_never_ramps_on_stale_input(sequence, start):
    force = start
    for s, stale in sequence:
        decision = next_force(force, s, PARAMS, problem="stale estimate" if stale else "")
        if stale:
            assert decision.hold and decision.normal_force_kpa == force
        force = decision.normal_force_kpa


@settings(max_examples=200, deadline=None)
@given(ANY_FLOAT, st.floats(1.1, 6.0))
def test_unusable_numbers_never_move_the_force(s, start):
    decision = next_force(start, s, PARAMS)
    if not (math.isfinite(s) and 0.0 <= s <= 1.0):
        assert decision.hold and decision.normal_force_kpa == start


def test_supervisor_fails_on_travel_and_force_and_succeeds_at_450():
    rules = SupervisorRules()
    assert judge_step(10, 1.51, 3.0, 0, rules).kind == "failure"
    assert judge_step(10, 1.0, 6.0, 0, rules).kind == "failure"
    assert judge_step(10, 1.0, 3.0, 0, rules).kind == ""
    assert judge_step(450, 1.0, 3.0, 0, rules).kind == "success"


def test_supervisor_faults_on_repeated_holds():
    assert judge_step(10, 1.0, 3.0, 3, SupervisorRules()).kind == "fault"


def test_no_action_rules_run_to_the_end():
    rules = SupervisorRules(end_on_failure=False)
    assert judge_step(200, 2.4, 3.0, 0, rules).kind == ""
    assert judge_step(450, 2.4, 3.0, 0, rules).kind == "failure"


def test_score_matches_the_paper_formula():
    assert score(1.0, 1.38, 4.50) == pytest.approx(1.1 * (10 / 1.38 + 1 / 4.50))
    assert score(0.0, 2.48, 2.94) == pytest.approx(0.1 * (10 / 2.48 + 1 / 2.94))
