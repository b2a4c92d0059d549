"""Grip control law, the controller's and supervisor's period bookkeeping, supervisor rules and
the paper's score: pure code, no sockets, no clock of its own (callers pass the time).

The paper (eq. "action") changes the normal force each sampling period by a(s) = k (s - s_d).
We apply it with the sign that makes a *lower* stick ratio *raise* the normal force:

    F_N[k+1] = clamp(F_N[k] - a(s_k), F_min, F_max),  a(s) = k (s - s_d),  k > 0

rate limited to ``max_step_kpa`` per period and clamped so F_N never exceeds the safety limit
(6.0 kPa, RIG.md). An estimate that is missing, stale, marked invalid, NaN, outside [0, 1], of
another period or of another method never moves the force: the controller holds the last safe
force and says why (``hold=True``, ``reason``).

The supervisor's rules (:func:`judge_step`) end a run on the paper's failure conditions
(y > 1.5 mm; F_N reaching the 6.0 kPa safety limit), on a fault (repeated holds: the estimate
stream is gone) or after 450 steps (success). The grip controller node wires
:class:`PeriodAnswerer` (each period answered once, deadline holds), the supervisor node
:class:`RunJudge` (its own count of periods, traces by period); :func:`applied_force` is the
clamp of the node that moves the hardware. The score is the paper's eq. "reward",
(w1 + success rate)(w2 / y + w3 / F_N) with (w1, w2, w3) = (0.1, 10, 1).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from incipient_slip.errors import EXIT_FAILURE, EXIT_FAULT, EXIT_SUCCESS
from incipient_slip.messages import MOCAP_RATE_HZ, PERIOD_NS

SAFETY_LIMIT_KPA = 6.0          # paper: failure when F_N > 6.0 kPa (the robot's safety limit)
FAILURE_TRAVEL_MM = 1.5         # paper: failure when y > 1.5 mm (mean travel at gross slip)
MAX_STEPS = 450                 # paper: 23 mm in 450 actuator steps, one per period
SCORE_WEIGHTS = (0.1, 10.0, 1.0)
DEFAULT_TARGET_STICK_RATIO = 0.3
# Chosen once on the simulated rig for the injection method and used for every method
# (docs/stabilization.md, "Choice of k"): kPa of normal-force change per unit of stick-ratio
# error per 500 ms period.
DEFAULT_GAIN_KPA = 2.0
DEFAULT_MAX_STEP_KPA = 0.5      # rate limit per period (the collection grid moved 0.4 kPa steps)
DEFAULT_INITIAL_FORCE_KPA = 2.9  # paper: "no action" ends at 2.94 kPa, i.e. the initial grip
DEFAULT_MIN_FORCE_KPA = 1.1     # lowest F_N of the paper's collection grid: contact is kept

# The simulated scene each closed-loop method runs on: the PZT on only for injection, no
# vibration path for the electrode methods, mechanics only for no action (the rig's physics
# streams are the same). The one table: rig_sim and emulated_rig read it (scene:="" follows
# method:=, as stabilize.yaml and collect.yaml leave it) and so do the experiments.
SCENE_OF_METHOD = {"injection": "paper", "vibrotactile": "no_injection", "e19": "electrodes_only",
                   "e10": "electrodes_only", "e4": "electrodes_only", "e1": "electrodes_only",
                   "none": "mechanics"}


def scene_of(scene: str, method: str) -> str:
    """`scene`, or when it is "" the scene of `method` (SCENE_OF_METHOD); ValueError for an
    unknown method."""
    if scene:
        return scene
    if method not in SCENE_OF_METHOD:
        raise ValueError(f"no scene for method {method!r} (known: {', '.join(SCENE_OF_METHOD)}); "
                         f"name one with scene:=")
    return SCENE_OF_METHOD[method]


@dataclass(frozen=True)
class ControlParams:
    """Parameters of the grip law; forces in kPa of P_DC (the paper's F_N unit)."""

    target_stick_ratio: float = DEFAULT_TARGET_STICK_RATIO
    gain_kpa: float = DEFAULT_GAIN_KPA
    max_step_kpa: float = DEFAULT_MAX_STEP_KPA
    min_force_kpa: float = DEFAULT_MIN_FORCE_KPA
    max_force_kpa: float = SAFETY_LIMIT_KPA
    safety_limit_kpa: float = SAFETY_LIMIT_KPA

    def __post_init__(self):
        checks = {
            "target_stick_ratio": 0.0 <= self.target_stick_ratio <= 1.0,
            "gain_kpa": math.isfinite(self.gain_kpa) and self.gain_kpa >= 0.0,
            "max_step_kpa": math.isfinite(self.max_step_kpa) and self.max_step_kpa > 0.0,
            "min_force_kpa": 0.0 <= self.min_force_kpa <= self.max_force_kpa,
            "max_force_kpa": self.max_force_kpa <= self.safety_limit_kpa,
            "safety_limit_kpa": math.isfinite(self.safety_limit_kpa) and self.safety_limit_kpa > 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"ControlParams: invalid {', '.join(bad)} in {self!r} "
                             f"(need 0<=s_d<=1, k>=0, step>0, 0<=min<=max<=safety limit)")


@dataclass(frozen=True)
class ControlDecision:
    """The force to command for the next period, and whether it is a hold (with the reason)."""

    normal_force_kpa: float
    hold: bool
    reason: str = ""


def action(stick_ratio: float, target_stick_ratio: float, gain_kpa: float) -> float:
    """The paper's a(s) = k (s - s_d) in kPa; the force changes by -a (low s raises F_N)."""
    return gain_kpa * (stick_ratio - target_stick_ratio)


def clamp_force(force_kpa: float, params: ControlParams) -> float:
    """The force limited to [min_force, max_force]; never above the safety limit, never NaN."""
    if not math.isfinite(force_kpa):
        raise ValueError(f"clamp_force: non-finite force {force_kpa!r}")
    return min(max(force_kpa, params.min_force_kpa), params.max_force_kpa)


def estimate_problem(stick_ratio, valid: bool = True, period: int | None = None,
                     expected_period: int | None = None, method: str | None = None,
                     expected_method: str | None = None) -> str:
    """Why an estimate must not drive the force ("" when it is usable).

    Rejects: marked invalid, not a number, NaN/inf, outside [0, 1], a period other than the one
    being answered, a method other than the controller's.
    """
    if not valid:
        return "estimate marked invalid"
    if isinstance(stick_ratio, bool) or not isinstance(stick_ratio, (int, float)):
        return f"stick ratio is not a number ({type(stick_ratio).__name__})"
    if not math.isfinite(stick_ratio):
        return f"stick ratio {stick_ratio} is not finite"
    if not 0.0 <= stick_ratio <= 1.0:
        return f"stick ratio {stick_ratio:.4g} outside [0, 1]"
    if expected_period is not None and period != expected_period:
        return f"estimate for period {period}, expected {expected_period}"
    if expected_method is not None and method != expected_method:
        return f"estimate of method {method!r}, controller runs {expected_method!r}"
    return ""


def hold(current_force_kpa: float, reason: str, params: ControlParams) -> ControlDecision:
    """Keep the last safe force (clamped, in case the caller's force was never safe)."""
    return ControlDecision(clamp_force(current_force_kpa, params), True, reason)


def next_force(current_force_kpa: float, stick_ratio, params: ControlParams,
               problem: str = "") -> ControlDecision:
    """The decision for one period: the law on a usable estimate, otherwise a hold.

    `problem` is the caller's reason the estimate is unusable (stale, wrong period, ...);
    the stick ratio is checked here as well, so a bad number can never ramp the force.
    """
    problem = problem or estimate_problem(stick_ratio)
    if problem:
        return hold(current_force_kpa, problem, params)
    current = clamp_force(current_force_kpa, params)
    change = -action(float(stick_ratio), params.target_stick_ratio, params.gain_kpa)
    change = min(max(change, -params.max_step_kpa), params.max_step_kpa)
    return ControlDecision(clamp_force(current + change, params), False, "")


def applied_force(command_kpa: float, current_kpa: float, limit_kpa: float = SAFETY_LIMIT_KPA,
                  max_step_kpa: float = math.inf) -> float:
    """The force a node that moves the hardware applies for a command: at most `max_step_kpa` from
    the current force (the law's own rate limit, kept where the force is applied), within [0, limit].

    The second line of defence (the controller limits first): a non-finite command keeps the
    current force.
    """
    if not math.isfinite(command_kpa):
        return min(max(current_kpa, 0.0), limit_kpa)
    # a hair of slack: the controller's own steps of exactly max_step pass unchanged
    if math.isfinite(current_kpa) and abs(command_kpa - current_kpa) > max_step_kpa * (1.0 + 1e-9):
        command_kpa = min(max(command_kpa, current_kpa - max_step_kpa), current_kpa + max_step_kpa)
    return min(max(command_kpa, 0.0), limit_kpa)


@dataclass(frozen=True)
class Answer:
    """The grip command for one period."""

    period: int
    normal_force_kpa: float
    hold: bool
    reason: str = ""


MAX_TICK_SKIP = 5          # ticks lost in a row that the controller follows; a bigger jump is refused


class PeriodAnswerer:
    """Answers each period the rig starts exactly once, in order (the grip controller's core).

    `tick(k)` says the rig started period k; `estimate(...)` brings the estimate of a period;
    `clock(now_s)` passes wall-clock time. Each returns the answers now due and a warning ("" if
    none). Period k is answered on its estimate (the law, or a hold naming the problem when the
    estimate is invalid, NaN, outside [0, 1] or of another method), at once when the method is
    "none", or with a hold of the last safe force, reason "stale estimate", once
    `estimate_timeout_s` passed after its tick. An estimate may come before its tick (another
    publisher); one for a period the rig has not started (beyond the next one, or skipped) or
    already answered is rejected and counted. Ticks advance by one (up to MAX_TICK_SKIP lost ones); a tick that
    jumps further or goes back is refused and counted, so a forged period cannot end the run.

    `lockstep`: the rig waits for each answer, so a period waits for its estimate however long
    it takes: `clock()` answers nothing and the answers are a function of the messages only
    (never of the CPU load); `overdue(now_s)` names the periods waiting longer than the timeout,
    for a liveness warning.
    """

    def __init__(self, params: ControlParams, initial_force_kpa: float, method: str,
                 estimate_timeout_s: float, lockstep: bool = False):
        self.params, self.method, self.timeout_s = params, method, estimate_timeout_s
        self.lockstep = lockstep
        self.force_kpa = clamp_force(initial_force_kpa, params)
        self.last_tick: int | None = None
        self.last_answered = -1
        self.waiting: dict[int, float] = {}       # ticked period -> wall-clock deadline
        self.rejected = self.refused_ticks = self.holds = 0

    def tick(self, period: int, now_s: float) -> tuple[list[Answer], str]:
        """Return (answers, warning) after the rig's tick for `period`."""
        if self.last_tick is not None and not self.last_tick < period <= self.last_tick + 1 + MAX_TICK_SKIP:
            self.refused_ticks += 1
            return [], f"refused tick for period {period}: the rig was at period {self.last_tick}"
        self.last_tick = period
        if period <= self.last_answered:          # its estimate came first
            return [], ""
        if self.method == "none":
            return self._answer(period, ControlDecision(self.force_kpa, False, "no action")), ""
        self.waiting[period] = now_s + self.timeout_s
        return [], ""

    def estimate(self, period: int, stick_ratio, valid: bool, method: str,
                 reason: str = "") -> tuple[list[Answer], str]:
        """Return (answers, warning) after an estimate for `period`."""
        if self.method == "none":
            return [], ""
        # the rig starts period k+1 once k is answered, maybe before its tick for k reached us
        rig_next = max(-1 if self.last_tick is None else self.last_tick, self.last_answered) + 1
        if period <= self.last_answered:
            return self._reject(f"estimate for period {period} arrived after it was answered")
        if period not in self.waiting and period != rig_next:   # not started, or skipped
            return self._reject(f"estimate for period {period} while the rig is at period {rig_next}")
        problem = estimate_problem(stick_ratio, valid, method=method, expected_method=self.method)
        if problem:
            problem = f"{problem} ({reason})" if reason else problem
            self.rejected += 1
        answers = self._answer(period, next_force(self.force_kpa, stick_ratio, self.params, problem))
        return answers, f"period {period}: {problem}" if problem else ""

    def clock(self, now_s: float) -> list[Answer]:
        """Return the holds of the periods whose estimate is overdue at `now_s` (none in lock-step)."""
        late = [] if self.lockstep else self.overdue(now_s)
        return self._answer(max(late), hold(self.force_kpa, "stale estimate", self.params)) if late else []

    def overdue(self, now_s: float) -> list[int]:
        """The periods still waiting for their estimate `estimate_timeout_s` after their tick."""
        return [k for k, deadline in self.waiting.items() if now_s >= deadline]

    def _reject(self, why: str) -> tuple[list[Answer], str]:
        self.rejected += 1
        return [], why

    def _answer(self, period: int, decision: ControlDecision) -> list[Answer]:
        """Answers the waiting periods before `period` with holds (their estimate never came), then it."""
        held = hold(self.force_kpa, "stale estimate", self.params)
        answers = [Answer(k, held.normal_force_kpa, True, held.reason)
                   for k in sorted(self.waiting) if k < period]
        answers.append(Answer(period, decision.normal_force_kpa, decision.hold, decision.reason))
        self.waiting = {k: t for k, t in self.waiting.items() if k > period}
        self.last_answered = period
        self.force_kpa = decision.normal_force_kpa
        self.holds += sum(a.hold for a in answers)
        return answers


# --- supervisor ----------------------------------------------------------------------------

@dataclass(frozen=True)
class SupervisorRules:
    """When a run ends, by the paper's protocol: "The stabilization continues until F_N reaches a
    safety limit", at most 450 steps, and the Table reports y and F_N "in the last sampling step".
    So a run stops at the F_N limit (failure) or after max_steps, and is judged on its end state:
    success when the final y <= 1.5 mm and F_N is below the limit. `stop_on_travel` also ends a
    run at the first y > 1.5 mm (the project's earlier rule; a safety habit on hardware)."""

    max_travel_mm: float = FAILURE_TRAVEL_MM
    safety_limit_kpa: float = SAFETY_LIMIT_KPA
    max_steps: int = MAX_STEPS
    max_consecutive_holds: int = 3
    end_on_failure: bool = True   # False for "no action": run all steps, report the final y
    stop_on_travel: bool = False  # True: end at the first y > max_travel_mm instead of judging the end state


@dataclass(frozen=True)
class Verdict:
    """The end of a run: kind is "success", "failure" or "fault"; empty kind = keep going."""

    kind: str = ""
    detail: str = ""

    @property
    def ended(self) -> bool:
        return bool(self.kind)


EXIT_CODES = {"success": EXIT_SUCCESS, "failure": EXIT_FAILURE, "fault": EXIT_FAULT}


def judge_step(steps_done: int, travel_mm: float, force_kpa: float, consecutive_holds: int,
               rules: SupervisorRules) -> Verdict:
    """The supervisor's verdict after a completed step (faults and failures before success).

    A force *at* the safety limit counts as a failure: the controller clamps at the limit, so
    reaching it is the paper's "the stabilization continues until F_N reaches a safety limit".
    """
    if consecutive_holds >= rules.max_consecutive_holds:
        return Verdict("fault", f"{consecutive_holds} consecutive holds: no usable estimate")
    if not (math.isfinite(travel_mm) and math.isfinite(force_kpa)):
        return Verdict("fault", f"non-finite measurement y={travel_mm} F_N={force_kpa}")
    if rules.end_on_failure:
        if rules.stop_on_travel and travel_mm > rules.max_travel_mm:
            return Verdict("failure", f"y = {travel_mm:.3f} mm > {rules.max_travel_mm} mm (the paper's travel limit)")
        if force_kpa >= rules.safety_limit_kpa - 1e-9:
            return Verdict("failure", f"F_N = {force_kpa:.3f} kPa reached the safety limit "
                                      f"{rules.safety_limit_kpa} kPa")
    if steps_done >= rules.max_steps:
        ok = travel_mm <= rules.max_travel_mm and force_kpa < rules.safety_limit_kpa - 1e-9
        return (Verdict("success", f"{steps_done} steps without failure") if ok else
                Verdict("failure", f"{steps_done} steps; final y = {travel_mm:.3f} mm, "
                                   f"F_N = {force_kpa:.3f} kPa"))
    return Verdict()


TRACES = ("step", "period", "travel_mm", "force_kpa", "command_kpa", "hold", "stick_ratio_estimate")
# the simulated rig's truth by period (NaN where none came: replay, hardware), in the summary's traces
TRUTH_TRACES = ("stick_ratio_true", "tangential_force_n")
MOCAP_SAMPLE_NS = 1_000_000_000 // MOCAP_RATE_HZ   # the last pose of period k is within one sample of its end
_KEEP_AHEAD = 8                          # periods of data kept ahead of the one being judged
NAN = float("nan")


class RunJudge:
    """Judges a run period by period from each period's own messages (the supervisor's core).

    The run's clock is its own count of periods: the first `command()` starts it, and each
    later command must be for the next period; one that jumps or goes back is dropped and
    counted (a forged period is never progress). A period is judged once its command, the
    rig's F_N of that period (or a later one: a robot node starved through a whole period
    stamps none in it; the period is then judged on the last F_N and counted in the summary's
    `periods_without_force`) and its last pose are in (and, for a command that acted on an
    estimate, that estimate), or `data_wait_s` after its command when only the estimate is
    missing (lost with a killed estimator), or once `data_wait_s` passed both since its command
    and since the rig's last message when the rig's data are missing (`close(now_s)`). Commands may overtake the rig's
    data (other publishers, fair-queued: a backlog of poses drains slower than commands), so
    any number of periods can wait at once, each for its own data. Traces are recorded by period: two identical runs
    give identical traces whatever order the messages arrived in.

    `lockstep` (the simulated rig waits for each command): no wall-clock wait at all. The rig's
    tick k (`rig_tick`) comes after all of period k's data (its truth included) on the same
    connection, so a period is judged once its command, its tick and its estimate (when it acted
    on one) are in: verdict and traces are a function of the messages, never of the CPU load.
    """

    def __init__(self, rules: SupervisorRules, max_missing_periods: int = 3,
                 estimates_drive: bool = True, data_wait_s: float = 3.0, period_ns: int = PERIOD_NS,
                 lockstep: bool = False):
        self.rules, self.max_missing, self.period_ns = rules, max_missing_periods, period_ns
        self.estimates_drive = estimates_drive     # False for "no action": no estimate to wait for
        self.data_wait_s = data_wait_s
        self.lockstep = lockstep
        self.rig_ticked = -1                       # the rig's last tick (lock-step: period k's data are all out)
        self.next_period: int | None = None
        self.pending: deque = deque()              # (period, hold, command_kpa, deadline_s)
        self.rig_heard_s = float("-inf")          # when the rig's last pose or F_N arrived
        self.travel: dict[int, tuple[int, float]] = {}         # period -> (stamp, y) of its last pose
        self.force: dict[int, float] = {}
        self.estimates: dict[int, float] = {}
        self.truth: dict[int, tuple[float, float]] = {}       # period -> (s, F_T), simulated rig
        self.travel_mm = self.force_kpa = NAN                  # as last judged
        self.steps = self.holds = self.consecutive_holds = self.missing = self.dropped = 0
        self.force_carried = 0                     # periods judged on an earlier period's F_N
        self.traces: dict[str, list] = {key: [] for key in TRACES}
        self.verdict = Verdict()

    def pose(self, stamp_ns: int, travel_mm: float, now_s: float) -> None:
        """Records a tracked pose: the y of its period is its last one."""
        self.rig_heard_s = now_s
        k = stamp_ns // self.period_ns
        if self._wanted(self.travel, k) and stamp_ns >= self.travel.get(k, (-1, NAN))[0]:
            self.travel[k] = (stamp_ns, travel_mm)

    def robot(self, stamp_ns: int, force_kpa: float, now_s: float) -> None:
        """Records the F_N the rig applied in the period that starts at `stamp_ns`."""
        self.rig_heard_s = now_s
        k = stamp_ns // self.period_ns
        if self._wanted(self.force, k):
            self.force[k] = force_kpa

    def rig_tick(self, period: int) -> None:
        """The rig's tick for `period` (its ActuatorState): the last message of that period."""
        self.rig_ticked = max(self.rig_ticked, period)

    def estimate(self, period: int, stick_ratio: float, valid: bool) -> None:
        if self._wanted(self.estimates, period):
            self.estimates[period] = stick_ratio if valid else NAN

    def truth_of(self, period: int, stick_ratio: float, tangential_force_n: float) -> None:
        """Records the simulated rig's truth of a period: kept for the summary's traces, never
        judged (it may come after its period is judged; periods far ahead are refused)."""
        if 0 <= period <= (self.next_period or 0) + _KEEP_AHEAD:
            self.truth[period] = (stick_ratio, tangential_force_n)

    def command(self, period: int, hold_: bool, command_kpa: float, now_s: float) -> str:
        """Takes the command that closes `period`; returns why it was dropped ("" if taken)."""
        if self.verdict.ended:
            return ""
        if self.next_period is not None and period != self.next_period:
            self.dropped += 1
            return f"dropped GripCommand(period={period}): the next period is {self.next_period}"
        self.pending.append((period, hold_, command_kpa, now_s + self.data_wait_s))
        self.next_period = period + 1
        return ""

    def close(self, now_s: float) -> Verdict:
        """Judges the waiting periods whose data are in (or whose wait is over), in order."""
        while self.pending and not self.verdict.ended:
            k, hold_, command_kpa, deadline = self.pending[0]
            wants_estimate = self.estimates_drive and not hold_
            # lock-step: the tick is the rig's last message of period k (its truth, F_N and
            # poses came before it on the same connection), so the trace never depends on
            # which of them happened to be read first
            rig_done = k <= self.rig_ticked if self.lockstep else (self._force_done(k) and self._pose_done(k))
            # an estimate lost with its publisher (killed) waits only data_wait_s; the rig's
            # data wait as long as the rig is still sending (a backlog draining)
            late = not self.lockstep and now_s >= (
                deadline if rig_done else max(deadline, self.rig_heard_s + self.data_wait_s))
            if not ((rig_done and (not wants_estimate or k in self.estimates)) or late):
                break
            self.pending.popleft()
            self._judge(k, hold_, command_kpa, self.estimates.get(k, NAN) if wants_estimate else NAN)
        return self.verdict

    def _judge(self, k: int, hold_: bool, command_kpa: float, estimate: float) -> None:
        past = [j for j in self.travel if j <= k]
        if past:
            self.travel_mm = self.travel[max(past)][1]
        if k not in self.force and math.isfinite(self.force_kpa):
            self.force_carried += 1       # judged on the last F_N: none was stamped in period k
        self.force_kpa = self.force.get(k, self.force_kpa)
        for d in (self.travel, self.force, self.estimates):
            for j in [j for j in d if j <= k]:
                del d[j]
        self.steps += 1
        self.holds += hold_
        self.consecutive_holds = self.consecutive_holds + 1 if hold_ else 0
        for key, value in zip(TRACES, (self.steps, k, self.travel_mm, self.force_kpa, command_kpa,
                                       hold_, estimate)):
            self.traces[key].append(value)
        known = math.isfinite(self.travel_mm) and math.isfinite(self.force_kpa)
        # y or F_N not heard yet (e.g. this node joined after the rig's first period): not a
        # verdict until it lasts `max_missing_periods`; the last period is always judged.
        self.missing = 0 if known else self.missing + 1
        if known or self.missing >= self.max_missing or self.steps >= self.rules.max_steps:
            self.verdict = judge_step(self.steps, self.travel_mm, self.force_kpa,
                                      self.consecutive_holds, self.rules)

    def end(self, verdict: Verdict) -> None:
        """Ends the run from outside (a silent graph, an interruption)."""
        if not self.verdict.ended:
            self.verdict = verdict

    def summary(self, **recorded) -> dict:
        """Return the run summary: verdict, final y and F_N, counts, `recorded` and the traces
        (one entry per judged period, with the simulated rig's truth of that period)."""
        v = self.verdict
        truth = [self.truth.get(k, (NAN, NAN)) for k in self.traces["period"]]
        traces = {**self.traces, **{key: [t[i] for t in truth] for i, key in enumerate(TRUTH_TRACES)}}
        return {"outcome": v.kind, "success": v.kind == "success", "detail": v.detail,
                "steps": self.steps, "max_steps": self.rules.max_steps,
                "final_travel_mm": self.travel_mm, "final_force_kpa": self.force_kpa,
                "holds": self.holds, "dropped_commands": self.dropped,
                "periods_without_force": self.force_carried, **recorded, "traces": traces}

    def _force_done(self, k: int) -> bool:
        """Period k's F_N is in, or never will be: the robot's next one is in (its states come in
        order; a robot node starved for a whole period stamps none in it)."""
        return any(j >= k for j in self.force)

    def _pose_done(self, k: int) -> bool:
        """The last pose of period k is in: one within a sample of its end, or a later one
        (the rig's messages come in order)."""
        end = (k + 1) * self.period_ns
        return any(j > k for j in self.travel) or any(j > k for j in self.force) or (
            k in self.travel and self.travel[k][0] >= end - MOCAP_SAMPLE_NS - 1_000_000)

    def _wanted(self, data: dict, k: int) -> bool:
        """Data of a period not judged yet and not far ahead (forged stamps cannot grow memory)."""
        if self.next_period is not None:
            first = self.pending[0][0] if self.pending else self.next_period
            return first <= k <= self.next_period + _KEEP_AHEAD
        if len(data) > _KEEP_AHEAD:       # before the first command: the newest periods
            del data[min(data)]
        return k >= 0


def format_summary(summary: dict, path: str = "") -> str:
    """One screen: the verdict, final y and F_N against the paper's limits, steps, where the JSON is."""
    finite = lambda key: [v for v in summary["traces"][key] if isinstance(v, float) and math.isfinite(v)]  # noqa: E731
    trace_y, trace_f = finite("travel_mm"), finite("force_kpa")
    lines = [
        f"stabilization run ({summary.get('rig', 'sim')} rig): {summary['outcome'].upper()} - {summary['detail']}",
        f"  method {summary['method']}  s_d {summary['s_d']}  k {summary['k']}  "
        f"material {summary['material'] or '(scene default)'}  seed {summary['seed']}",
        f"  steps  {summary['steps']} / {summary.get('max_steps', MAX_STEPS)}",
        f"  y      {summary['final_travel_mm']:.3f} mm (failure > {FAILURE_TRAVEL_MM} mm; "
        f"max {max(trace_y, default=NAN):.3f})",
        f"  F_N    {summary['final_force_kpa']:.3f} kPa (safety limit {SAFETY_LIMIT_KPA} kPa; "
        f"range {min(trace_f, default=NAN):.2f}-{max(trace_f, default=NAN):.2f})",
        ("  rule   stop at the first y > 1.5 mm (stop_on_travel)" if summary.get("stop_on_travel") else
         f"  rule   the paper's: stop at the F_N limit or after {summary.get('max_steps', MAX_STEPS)} steps; "
         "success when the final y <= 1.5 mm and F_N < 6.0 kPa"),
        f"  holds  {summary['holds']}   dropped commands {summary.get('dropped_commands', 0)}   "
        f"wall {summary['wall_s']:.1f} s",
    ]
    if path:
        lines.append(f"  summary {path}")
    return "\n".join(lines)


# --- score ---------------------------------------------------------------------------------

def score(success_rate: float, travel_mm: float, force_kpa: float,
          weights: tuple[float, float, float] = SCORE_WEIGHTS) -> float:
    """The paper's achievement score (w1 + success)(w2 / y + w3 / F_N); higher is better."""
    w1, w2, w3 = weights
    if travel_mm <= 0 or force_kpa <= 0:
        raise ValueError(f"score: y and F_N must be positive, got y={travel_mm}, F_N={force_kpa}")
    return (w1 + success_rate) * (w2 / travel_mm + w3 / force_kpa)


PERIOD_ORIGINS = ("stamps", "tick")


class PeriodOrigin:
    """Maps message stamps onto the run's period clock, where period k is [k T, (k+1) T).

    `stamps`: the stamps already are that clock (the simulated rig's start at 0). `tick`: device
    clocks (host time, rig:=emulated and hardware): period k ends at the actuator's tick k, so the
    first tick sets the origin (its stamp less (k + 1) T). Until then messages are held (at most
    `held_max`, oldest dropped first) and `tick()` hands them back to be replayed; a stamp at or
    before the origin is before period 0 (`relative` returns None).
    """

    def __init__(self, mode: str = "stamps", held_max: int = 1000, period_ns: int = PERIOD_NS):
        if mode not in PERIOD_ORIGINS:
            raise ValueError(f"period origin {mode!r}; expected one of {', '.join(PERIOD_ORIGINS)}")
        self.mode, self.period_ns = mode, period_ns
        self.origin_ns: int | None = 0 if mode == "stamps" else None
        self.held: deque = deque(maxlen=max(1, held_max))
        self.before_origin = 0             # messages stamped before period 0 (counted, dropped)

    def hold(self, item) -> bool:
        """True (and keeps `item`) while the origin is not known yet."""
        if self.origin_ns is not None:
            return False
        self.held.append(item)
        return True

    def tick(self, step_index: int, stamp_ns: int) -> list:
        """Sets the origin from the first tick; returns the held messages, in arrival order."""
        if self.origin_ns is not None:
            return []
        self.origin_ns = stamp_ns - (step_index + 1) * self.period_ns
        held, self.held = list(self.held), deque()
        return held

    def relative(self, stamp_ns: int) -> int | None:
        """Return the stamp on the period clock; None before period 0 (counted) or before the origin is known."""
        if self.origin_ns is None:
            return None
        if self.mode == "stamps":
            return stamp_ns
        rel = stamp_ns - self.origin_ns
        if rel <= 0:
            self.before_origin += 1
            return None
        return rel
