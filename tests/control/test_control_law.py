"""Specification of the grip law, the controller's and supervisor's period bookkeeping
(`PeriodAnswerer`, `RunJudge`), the supervisor rules and the score: pure code, no sockets."""
import json
import math

import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.control import (
    MAX_TICK_SKIP, SAFETY_LIMIT_KPA, ControlParams, PeriodAnswerer, RunJudge,
    SupervisorRules, action, applied_force, estimate_problem, judge_step, next_force, score,
)
from incipient_slip.control import LockstepCloser, RealTimeCloser, problem_of
from incipient_slip.messages import GRIP_CAUSES, PERIOD_NS, GripCommand

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


def test_supervisor_follows_the_papers_protocol_stop_at_the_force_limit_judge_the_end_state():
    rules = SupervisorRules()
    assert judge_step(10, 1.51, 3.0, 0, rules).kind == ""            # y past 1.5 mm mid-run: keep going
    assert judge_step(10, 1.0, 6.0, 0, rules).kind == "failure"      # the F_N limit stops the run
    assert judge_step(10, 1.0, 3.0, 0, rules).kind == ""
    assert judge_step(450, 1.0, 3.0, 0, rules).kind == "success"
    assert judge_step(450, 1.5, 5.99, 0, rules).kind == "success"    # the limits are inclusive of 1.5 mm
    end = judge_step(450, 1.52, 4.5, 0, rules)                       # judged on the end state
    assert end.kind == "failure" and "final y = 1.520" in end.detail


def test_stop_on_travel_ends_at_the_first_y_past_the_limit():
    rules = SupervisorRules(stop_on_travel=True)
    v = judge_step(10, 1.51, 3.0, 0, rules)
    assert v.kind == "failure" and "travel limit" in v.detail
    assert judge_step(10, 1.0, 6.0, 0, rules).kind == "failure"
    assert judge_step(450, 1.0, 3.0, 0, rules).kind == "success"


@given(st.integers(1, 450), st.floats(-10, 50), st.floats(0, 6.5))
def test_a_run_that_ended_early_ended_at_the_force_limit(steps, y, fn):
    v = judge_step(steps, y, fn, 0, SupervisorRules())
    if v.ended and steps < 450:
        assert v.kind == "failure" and fn >= 6.0 - 1e-9


def test_supervisor_faults_on_repeated_holds():
    assert judge_step(10, 1.0, 3.0, 3, SupervisorRules()).kind == "fault"


def test_no_action_rules_run_to_the_end():
    rules = SupervisorRules(end_on_failure=False)
    assert judge_step(200, 2.4, 3.0, 0, rules).kind == ""
    assert judge_step(450, 2.4, 3.0, 0, rules).kind == "failure"


def test_score_matches_the_paper_formula():
    assert score(1.0, 1.38, 4.50) == pytest.approx(1.1 * (10 / 1.38 + 1 / 4.50))
    assert score(0.0, 2.48, 2.94) == pytest.approx(0.1 * (10 / 2.48 + 1 / 2.94))


# --- the force applied by the node that moves the hardware ---------------------------------

@given(ANY_FLOAT, st.floats(0.0, SAFETY_LIMIT_KPA))
def test_applied_force_never_exceeds_the_safety_limit(command, current):
    force = applied_force(command, current)
    assert 0.0 <= force <= SAFETY_LIMIT_KPA
    assert applied_force(99.0, current) == SAFETY_LIMIT_KPA


# --- PeriodAnswerer: each period the rig starts is answered exactly once ---------------------

EVENT = st.one_of(
    st.tuples(st.just("tick"), st.integers(-1, 2 ** 64 - 1)),      # -1: the rig's next period
    st.tuples(st.just("estimate"), st.integers(-3, 2), ESTIMATE, st.booleans(),
              st.sampled_from(["injection", "injection", "e19"])),
    st.tuples(st.just("clock"), st.floats(0.0, 1.0)),
)


def run_answerer(events, method="injection", params=PARAMS):
    """Feeds the events to a PeriodAnswerer; returns (answerer, answers, accepted tick periods)."""
    core = PeriodAnswerer(params, 2.9, method, estimate_timeout_s=0.4)
    now, answers, ticked, nexts = 0.0, [], [], set()
    for event in events:
        nexts.add(max(-1 if core.last_tick is None else core.last_tick, core.last_answered) + 1)
        if event[0] == "tick":
            k = (core.last_tick if core.last_tick is not None else -1) + 1 if event[1] == -1 else event[1]
            out, _ = core.tick(k, now)
            if core.last_tick == k and k not in ticked:
                ticked.append(k)
        elif event[0] == "estimate":
            base = core.last_tick if core.last_tick is not None else 0
            out, _ = core.estimate(max(base + event[1], 0), event[2], event[3], event[4])
        else:
            now += event[1]
            out = core.clock(now)
        answers += out
    return core, answers + core.clock(now + 10.0), ticked, nexts


@settings(max_examples=300, deadline=None)
@given(st.lists(EVENT, max_size=80), st.sampled_from(["injection", "none"]))
def test_every_started_period_is_answered_exactly_once_in_order(events, method):
    core, answers, ticked, nexts = run_answerer(events, method)
    periods = [a.period for a in answers]
    assert periods == sorted(set(periods))                  # in order, never twice
    assert set(ticked) <= set(periods)                      # every tick answered
    assert set(periods) <= set(ticked) | nexts              # only started (or starting) periods


@settings(max_examples=300, deadline=None)
@given(st.lists(EVENT, max_size=80), st.floats(0.0, 1.0), st.floats(0.0, 50.0))
def test_answers_stay_within_the_force_range_and_the_rate_limit(events, s_d, k):
    params = ControlParams(target_stick_ratio=s_d, gain_kpa=k)
    _, answers, _, _ = run_answerer(events, params=params)
    forces = [2.9] + [a.normal_force_kpa for a in answers]
    assert all(params.min_force_kpa <= f <= params.max_force_kpa for f in forces)
    assert all(abs(b - a) <= params.max_step_kpa + 1e-12 for a, b in zip(forces, forces[1:]))
    for before, a in zip(forces, answers):
        if a.hold:
            assert a.normal_force_kpa == before and a.reason    # a hold keeps the last safe force


def test_no_estimate_by_the_deadline_holds_the_last_safe_force_as_stale():
    core = PeriodAnswerer(PARAMS, 2.9, "injection", estimate_timeout_s=0.4)
    assert core.tick(0, now_s=0.0) == ([], "")
    assert core.clock(0.39) == []
    [answer] = core.clock(0.4)
    assert (answer.period, answer.hold, answer.reason, answer.normal_force_kpa) == (0, True, "stale estimate", 2.9)
    assert core.estimate(0, 0.1, True, "injection")[1].endswith("arrived after it was answered")


@pytest.mark.parametrize("ratio, valid, method, why", [
    (float("nan"), True, "injection", "not finite"), (1.5, True, "injection", "outside [0, 1]"),
    (0.2, False, "injection", "marked invalid"), (0.2, True, "e19", "method 'e19'"),
])
def test_unusable_estimate_answers_its_period_with_a_hold_and_is_counted(ratio, valid, method, why):
    core = PeriodAnswerer(PARAMS, 2.9, "injection", estimate_timeout_s=0.4)
    core.tick(0, 0.0)
    [answer], warning = core.estimate(0, ratio, valid, method)
    assert answer.hold and why in answer.reason and why in warning and core.rejected == 1
    assert answer.normal_force_kpa == 2.9


def test_a_forged_tick_far_ahead_is_refused_and_the_run_goes_on():
    core = PeriodAnswerer(PARAMS, 2.9, "none", estimate_timeout_s=0.4)
    assert [a.period for a in core.tick(0, 0.0)[0]] == [0]
    answers, warning = core.tick(2 ** 63, 0.0)
    assert answers == [] and "refused tick for period 9223372036854775808" in warning
    assert core.refused_ticks == 1
    assert [a.period for a in core.tick(1, 0.0)[0]] == [1]
    assert [a.period for a in core.tick(2 + MAX_TICK_SKIP, 0.0)[0]] == [2 + MAX_TICK_SKIP]   # lost ticks


# --- RunJudge: the supervisor's own count, records by period ---------------------------------

def period_messages(k, y=0.5, force=3.0, estimate=0.3):
    """The rig's messages of period k (F_N at its start, three poses, the last one sample before
    its end), the estimate and the command that answers it, as judge calls."""
    start = k * PERIOD_NS
    rig = [("robot", max(start, 1), force, 0.0)] + [
        ("pose", start + t, y + 0.01 * i, 0.0) for i, t in enumerate((1, 250_000_000, PERIOD_NS - 8_333_333))]
    return rig, ("estimate", k, estimate + 0.001 * k, True), ("command", k, False, force, 0.0)


def feed(judge, message):
    kind, *args = message
    if kind == "command":
        return judge.command(*args)
    getattr(judge, kind)(*args)
    return ""


def test_a_forged_period_is_dropped_and_never_counts_as_progress():
    judge = RunJudge(SupervisorRules(max_steps=3))
    for k in range(3):
        rig, estimate, command = period_messages(k)
        for m in rig + [estimate]:
            feed(judge, m)
        assert feed(judge, command) == ""
        if k == 0:
            assert "dropped GripCommand(period=9223372036854775808)" in feed(judge, ("command", 2 ** 63, False, 3.0, 0.0))
        verdict = judge.close(0.0)
        assert (verdict.kind == "success") == (k == 2)
    assert judge.steps == 3 and judge.traces["step"] == [1, 2, 3] and judge.dropped == 1


@settings(max_examples=200, deadline=None)
@given(st.randoms(use_true_random=False), st.integers(1, 6))
def test_traces_are_by_period_whatever_the_arrival_order(rnd, periods):
    """Each publisher's messages keep their order (one pipe each); between the rig, the
    estimator and the controller anything goes: a command may overtake the rig's data."""
    streams = {"rig": [], "estimator": [], "controller": []}
    for k in range(periods):
        rig, estimate, command = period_messages(k, y=0.1 * k, force=2.0 + 0.1 * k)
        streams["rig"] += rig + [("truth_of", k, 0.9 - 0.01 * k, 0.1 * k)]   # the sim's truth last
        streams["estimator"].append(estimate)
        streams["controller"].append(command)

    def run(order):
        judge = RunJudge(SupervisorRules(max_steps=100))
        for message in order:
            feed(judge, message)
            judge.close(0.0)
        return json.dumps(judge.summary()["traces"])

    in_order = [m for k in range(periods) for m in
                streams["rig"][5 * k:5 * k + 5] + [streams["estimator"][k], streams["controller"][k]]]
    shuffled, heads = [], {name: 0 for name in streams}
    while any(heads[n] < len(streams[n]) for n in streams):
        name = rnd.choice([n for n in streams if heads[n] < len(streams[n])])
        shuffled.append(streams[name][heads[name]])
        heads[name] += 1
    reference = json.loads(run(in_order))
    assert run(shuffled) == run(in_order)
    assert reference["stick_ratio_estimate"] == [0.3 + 0.001 * k for k in range(periods)]
    assert reference["travel_mm"] == [0.1 * k + 0.02 for k in range(periods)]     # the last pose of each
    # one entry per judged period in every trace, finite, the truth of its own period (even
    # when it came after its period was judged)
    assert reference["period"] == list(range(periods))
    assert reference["stick_ratio_true"] == [0.9 - 0.01 * k for k in range(periods)]
    assert reference["tangential_force_n"] == [0.1 * k for k in range(periods)]
    assert {len(trace) for trace in reference.values()} == {periods}
    assert all(math.isfinite(v) for key, trace in reference.items() if key != "hold" for v in trace)


def test_without_the_simulated_rig_the_truth_traces_are_nan_and_far_periods_are_refused():
    judge = RunJudge(SupervisorRules(max_steps=100))
    judge.truth_of(10 ** 9, 0.5, 1.0)                 # forged: far ahead, never kept
    judge.truth_of(-1, 0.5, 1.0)
    for k in range(3):
        for m in [m for part in period_messages(k) for m in (part if isinstance(part, list) else [part])]:
            feed(judge, m)
        judge.close(0.0)
    traces = judge.summary()["traces"]
    assert judge.truth == {} and traces["period"] == [0, 1, 2]
    assert len(traces["stick_ratio_true"]) == 3 and all(math.isnan(v) for v in traces["stick_ratio_true"])


def test_a_period_whose_data_never_come_is_judged_after_the_wait():
    judge = RunJudge(SupervisorRules(max_steps=100), data_wait_s=3.0)
    judge.robot(1, 3.0, now_s=10.0)
    judge.command(0, False, 3.0, now_s=10.0)          # no pose, no estimate
    judge.pose(2, 0.1, now_s=11.0)                    # the rig still talks: keep waiting
    assert judge.close(13.9).kind == "" and judge.steps == 0
    judge.close(14.0)
    assert judge.steps == 1 and math.isnan(judge.traces["stick_ratio_estimate"][0])


def test_commands_far_ahead_of_a_backlog_of_rig_data_wait_for_it():
    """A command overtakes the rig's data by many periods (fair queuing under load): each
    period is still judged with its own data."""
    judge = RunJudge(SupervisorRules(max_steps=100))
    messages = [period_messages(k, y=0.05 * k) for k in range(20)]
    for _, estimate, command in messages:
        feed(judge, estimate)
        feed(judge, command)
        judge.close(0.0)
    assert judge.steps == 0 and len(judge.pending) == 20
    for rig, _, _ in messages:
        for m in rig:
            feed(judge, m)
    judge.close(0.0)
    assert judge.traces["travel_mm"] == [0.05 * k + 0.02 for k in range(20)]


def test_an_estimate_lost_with_its_publisher_is_waited_for_only_data_wait_s():
    """The rig goes on (holds keep it going) but the estimate of period 0 never comes."""
    judge = RunJudge(SupervisorRules(max_steps=100), data_wait_s=3.0)
    rig, _, command = period_messages(0)
    for m in rig:
        feed(judge, m)
    feed(judge, command)                               # acted on an estimate we never got
    for t in (1.0, 2.0, 2.9):
        judge.robot(PERIOD_NS, 3.0, now_s=t)            # the rig keeps talking
        assert judge.close(t).kind == "" and judge.steps == 0
    judge.close(3.0)
    assert judge.steps == 1 and math.isnan(judge.traces["stick_ratio_estimate"][0])


# --- lock-step: no wall-clock decision ---------------------------------------------------------

def test_in_lockstep_a_late_estimate_is_waited_for_not_held():
    params = ControlParams(0.3, 2.0, 0.5, 0.0, SAFETY_LIMIT_KPA)
    core = PeriodAnswerer(params, 2.9, "injection", estimate_timeout_s=0.4, lockstep=True)
    assert core.tick(0, now_s=0.0) == ([], "")
    assert core.clock(now_s=1e6) == [] and core.overdue(1e6) == [0]     # a liveness warning only
    answers, _ = core.estimate(0, 0.5, True, "injection")
    assert [(a.period, a.hold) for a in answers] == [(0, False)] and core.holds == 0


def test_in_lockstep_a_period_is_judged_on_its_messages_never_on_the_wall_clock():
    judge = RunJudge(SupervisorRules(max_steps=5), data_wait_s=3.0, lockstep=True)
    judge.robot(0, 2.9, now_s=0.0)
    judge.command(0, False, 2.9, now_s=0.0)
    assert not judge.close(now_s=1e6).ended and judge.steps == 0      # its estimate and pose: not yet
    judge.estimate(0, 0.4, True)
    judge.pose(PERIOD_NS - 1, 0.1, now_s=0.0)
    assert judge.close(now_s=1e6) is judge.verdict and judge.steps == 0   # data in, tick not yet
    judge.rig_tick(0)          # the rig's tick ends period 0: its data (and truth) are all in
    judge.close(now_s=0.0)
    assert judge.steps == 1 and judge.traces["stick_ratio_estimate"] == [0.4]


def test_a_period_the_robot_stamped_no_force_in_is_judged_once_a_later_force_comes():
    """Real time: the robot node starved through period 1 publishes no F_N stamped in it. Its
    next F_N (period 2) says none will come: period 1 is judged on the last F_N and counted,
    not waited for while the mocap keeps streaming poses."""
    judge = RunJudge(SupervisorRules(max_steps=100), data_wait_s=3.0)
    for k in range(3):
        rig, estimate, command = period_messages(k, force=2.0 + k)
        for m in ([m for m in rig if m[0] != "robot" or k != 1]) + [estimate, command]:
            feed(judge, m)
    for t in range(100):              # poses go on; without period 2's F_N period 1 would wait
        judge.pose(3 * PERIOD_NS + t, 0.5, now_s=float(t))
        judge.close(float(t))
    assert judge.steps == 3 and judge.traces["force_kpa"] == [2.0, 2.0, 4.0]
    assert judge.summary()["periods_without_force"] == 1


def test_one_table_gives_each_method_its_scene():
    """control.SCENE_OF_METHOD is the one method-to-scene table (rig_sim, emulated_rig and the
    experiments read it; stabilize.yaml's nested $(eval) is gone): every method has a scene."""
    from incipient_slip.control import SCENE_OF_METHOD, scene_of
    from incipient_slip.models.features import METHODS
    assert set(SCENE_OF_METHOD) == set(METHODS) | {"none"}
    assert [scene_of("", m) for m in ("injection", "vibrotactile", "e19", "e1", "none")] == [
        "paper", "no_injection", "electrodes_only", "electrodes_only", "mechanics"]
    assert scene_of("paper", "e19") == "paper"          # a scene named wins
    with pytest.raises(ValueError, match="known: injection"):
        scene_of("", "e20")


@given(ANY_FLOAT, st.floats(0.0, SAFETY_LIMIT_KPA), st.floats(1e-3, SAFETY_LIMIT_KPA))
def test_applied_force_moves_at_most_one_rate_step_from_the_current_force(command, current, step):
    force = applied_force(command, current, SAFETY_LIMIT_KPA, step)
    assert 0.0 <= force <= SAFETY_LIMIT_KPA
    assert abs(force - current) <= step * (1 + 1e-9) + 1e-12
    if math.isfinite(command) and abs(command - current) <= step and 0.0 <= command <= SAFETY_LIMIT_KPA:
        assert force == command                     # a step the law itself takes passes unchanged


# --- the answerer's commands are the wire's; causes are a closed set --------------------------

def test_the_answerer_returns_the_wire_commands_with_the_latest_input_stamp():
    core = PeriodAnswerer(PARAMS, 2.9, "injection", estimate_timeout_s=0.4)
    assert core.tick(0, 0.0, stamp_ns=500) == ([], "")
    [command], notice = core.estimate(0, 0.1, True, "injection", stamp_ns=400)
    assert type(command) is GripCommand and not notice
    assert (command.period, command.hold, command.cause, command.stamp_ns) == (0, False, "law", 500)
    assert command.normal_force_kpa == next_force(2.9, 0.1, PARAMS).normal_force_kpa


@pytest.mark.parametrize("reason, cause, filling", [
    ("filling", "filling", True),
    ("filling", "seq_gap", False),       # the words alone never decide: before, this text was a log line
    ("window not full", "filling", True),
])
def test_the_window_filling_is_told_by_the_estimates_cause(reason, cause, filling):
    core = PeriodAnswerer(PARAMS, 2.9, "injection", estimate_timeout_s=0.4)
    core.tick(0, 0.0)
    [command], notice = core.estimate(0, float("nan"), False, "injection", reason, cause)
    assert command.hold and command.cause == "estimate_invalid" and reason in command.reason
    assert notice and notice.filling is filling


def test_a_usable_estimate_of_the_filling_kind_is_no_notice():
    core = PeriodAnswerer(PARAMS, 2.9, "injection", estimate_timeout_s=0.4)
    core.tick(0, 0.0)
    _, notice = core.estimate(0, 0.3, True, "injection", "ok", "ok")
    assert notice == "" and not notice.filling


@pytest.mark.parametrize("args, cause", [
    ((0.3,), ""), ((0.3, False), "estimate_invalid"), ((float("nan"),), "estimate_not_finite"),
    (("0.3",), "estimate_not_finite"), ((1.5,), "estimate_out_of_range"),
    ((0.3, True, 4, 5), "estimate_other_period"), ((0.3, True, None, None, "e1", "injection"), "estimate_other_method"),
])
def test_every_problem_has_a_cause_of_the_wire_set(args, cause):
    problem = problem_of(*args)
    assert problem.cause == cause and bool(problem) == bool(cause) and bool(problem.text) == bool(cause)
    assert not cause or cause in GRIP_CAUSES


def test_each_mode_has_its_period_closer():
    assert type(RunJudge(SupervisorRules(), lockstep=True).closer) is LockstepCloser
    judge = RunJudge(SupervisorRules(), data_wait_s=2.5)
    assert type(judge.closer) is RealTimeCloser and judge.closer.data_wait_s == 2.5 and not judge.lockstep
