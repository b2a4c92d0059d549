"""Judging a run: the supervisor's rules, its verdict by period, the run summary and the score.

The supervisor's rules (:func:`judge_step`) end a run on the paper's failure conditions
(y > 1.5 mm; F_N reaching the 6.0 kPa safety limit), on a fault (repeated holds: the estimate
stream is gone) or after 450 steps (success). :class:`RunJudge` keeps the run's data by period
and judges each period once its period closer (`closers`, one per mode) says its data are in.
The score is the paper's eq. "reward", (w1 + success rate)(w2 / y + w3 / F_N) with
(w1, w2, w3) = (0.1, 10, 1). Pure: no sockets, no clock of its own (callers pass the time).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from incipient_slip.control.closers import LockstepCloser, RealTimeCloser
from incipient_slip.control.law import FAILURE_TRAVEL_MM, MAX_STEPS, SAFETY_LIMIT_KPA
from incipient_slip.errors import EXIT_FAILURE, EXIT_FAULT, EXIT_SUCCESS
from incipient_slip.messages import PERIOD_NS

SCORE_WEIGHTS = (0.1, 10.0, 1.0)
TRACES = ("step", "period", "travel_mm", "force_kpa", "command_kpa", "hold", "stick_ratio_estimate")
# the simulated rig's truth by period (NaN where none came: replay, hardware), in the summary's traces
TRUTH_TRACES = ("stick_ratio_true", "tangential_force_n")
_KEEP_AHEAD = 8                          # periods of data kept ahead of the one being judged
NAN = float("nan")


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


class RunJudge:
    """Judges a run period by period from each period's own messages (the supervisor's core).

    The run's clock is its own count of periods: the first `command()` starts it, and each
    later command must be for the next period; one that jumps or goes back is dropped and
    counted (a forged period is never progress). A period is judged once its command is in and
    the period closer of the mode says its data are in (`closers`: `lockstep`, by the rig's
    tick; real time, by the data or the deadlines of `data_wait_s`); `close(now_s)` judges
    every such period, in order. A period judged on an earlier period's F_N (none was stamped
    in it) is counted in the summary's `periods_without_force`. Commands may overtake the rig's
    data (other publishers, fair-queued: a backlog of poses drains slower than commands), so
    any number of periods can wait at once, each for its own data. Traces are recorded by
    period: two identical runs give identical traces whatever order the messages arrived in.
    """

    def __init__(self, rules: SupervisorRules, max_missing_periods: int = 3,
                 estimates_drive: bool = True, data_wait_s: float = 3.0, period_ns: int = PERIOD_NS,
                 lockstep: bool = False):
        self.rules, self.max_missing, self.period_ns = rules, max_missing_periods, period_ns
        self.estimates_drive = estimates_drive     # False for "no action": no estimate to wait for
        self.closer = LockstepCloser() if lockstep else RealTimeCloser(data_wait_s, period_ns)
        self.next_period: int | None = None
        self.pending: deque = deque()              # (period, hold, command_kpa, command_s)
        self.travel: dict[int, tuple[int, float]] = {}         # period -> (stamp, y) of its last pose
        self.force: dict[int, float] = {}
        self.estimates: dict[int, float] = {}
        self.truth: dict[int, tuple[float, float]] = {}       # period -> (s, F_T), simulated rig
        self.travel_mm = self.force_kpa = NAN                  # as last judged
        self.steps = self.holds = self.consecutive_holds = self.missing = self.dropped = 0
        self.force_carried = 0                     # periods judged on an earlier period's F_N
        self.traces: dict[str, list] = {key: [] for key in TRACES}
        self.verdict = Verdict()

    @property
    def lockstep(self) -> bool:
        return self.closer.lockstep

    def pose(self, stamp_ns: int, travel_mm: float, now_s: float) -> None:
        """Records a tracked pose: the y of its period is its last one."""
        self.closer.heard(now_s)
        period = stamp_ns // self.period_ns
        if self._wanted(self.travel, period) and stamp_ns >= self.travel.get(period, (-1, NAN))[0]:
            self.travel[period] = (stamp_ns, travel_mm)

    def robot(self, stamp_ns: int, force_kpa: float, now_s: float) -> None:
        """Records the F_N the rig applied in the period that starts at `stamp_ns`."""
        self.closer.heard(now_s)
        period = stamp_ns // self.period_ns
        if self._wanted(self.force, period):
            self.force[period] = force_kpa

    def rig_tick(self, period: int) -> None:
        """The rig's tick for `period` (its ActuatorState): the last message of that period."""
        self.closer.rig_tick(period)

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
        self.pending.append((period, hold_, command_kpa, now_s))
        self.next_period = period + 1
        return ""

    def close(self, now_s: float) -> Verdict:
        """Judges the waiting periods whose data are in (or whose wait is over), in order."""
        while self.pending and not self.verdict.ended:
            period, hold_, command_kpa, command_s = self.pending[0]
            wants_estimate = self.estimates_drive and not hold_
            if not self.closer.closed(period, wants_estimate, command_s, now_s, self):
                break
            self.pending.popleft()
            self._judge(period, hold_, command_kpa, self.estimates.get(period, NAN) if wants_estimate else NAN)
        return self.verdict

    def _judge(self, period: int, hold_: bool, command_kpa: float, estimate: float) -> None:
        self._take_measurements(period)
        self.steps += 1
        self.holds += hold_
        self.consecutive_holds = self.consecutive_holds + 1 if hold_ else 0
        for key, value in zip(TRACES, (self.steps, period, self.travel_mm, self.force_kpa, command_kpa,
                                       hold_, estimate)):
            self.traces[key].append(value)
        known = math.isfinite(self.travel_mm) and math.isfinite(self.force_kpa)
        # y or F_N not heard yet (e.g. this node joined after the rig's first period): not a
        # verdict until it lasts `max_missing_periods`; the last period is always judged.
        self.missing = 0 if known else self.missing + 1
        if known or self.missing >= self.max_missing or self.steps >= self.rules.max_steps:
            self.verdict = judge_step(self.steps, self.travel_mm, self.force_kpa,
                                      self.consecutive_holds, self.rules)

    def _take_measurements(self, period: int) -> None:
        """y and F_N of `period` (the latest y so far; the last F_N when none was stamped in
        it, counted), and the data up to it dropped."""
        past = [earlier for earlier in self.travel if earlier <= period]
        if past:
            self.travel_mm = self.travel[max(past)][1]
        if period not in self.force and math.isfinite(self.force_kpa):
            self.force_carried += 1       # judged on the last F_N: none was stamped in this period
        self.force_kpa = self.force.get(period, self.force_kpa)
        for data in (self.travel, self.force, self.estimates):
            for done in [done for done in data if done <= period]:
                del data[done]

    def end(self, verdict: Verdict) -> None:
        """Ends the run from outside (a silent graph, an interruption)."""
        if not self.verdict.ended:
            self.verdict = verdict

    def summary(self, **recorded) -> dict:
        """Return the run summary: verdict, final y and F_N, counts, `recorded` and the traces
        (one entry per judged period, with the simulated rig's truth of that period)."""
        v = self.verdict
        truth = [self.truth.get(period, (NAN, NAN)) for period in self.traces["period"]]
        traces = {**self.traces, **{key: [t[i] for t in truth] for i, key in enumerate(TRUTH_TRACES)}}
        return {"outcome": v.kind, "success": v.kind == "success", "detail": v.detail,
                "steps": self.steps, "max_steps": self.rules.max_steps,
                "final_travel_mm": self.travel_mm, "final_force_kpa": self.force_kpa,
                "holds": self.holds, "dropped_commands": self.dropped,
                "periods_without_force": self.force_carried, **recorded, "traces": traces}

    def _wanted(self, data: dict, period: int) -> bool:
        """Data of a period not judged yet and not far ahead (forged stamps cannot grow memory)."""
        if self.next_period is not None:
            first = self.pending[0][0] if self.pending else self.next_period
            return first <= period <= self.next_period + _KEEP_AHEAD
        if len(data) > _KEEP_AHEAD:       # before the first command: the newest periods
            del data[min(data)]
        return period >= 0


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


def score(success_rate: float, travel_mm: float, force_kpa: float,
          weights: tuple[float, float, float] = SCORE_WEIGHTS) -> float:
    """The paper's achievement score (w1 + success)(w2 / y + w3 / F_N); higher is better."""
    w1, w2, w3 = weights
    if travel_mm <= 0 or force_kpa <= 0:
        raise ValueError(f"score: y and F_N must be positive, got y={travel_mm}, F_N={force_kpa}")
    return (w1 + success_rate) * (w2 / travel_mm + w3 / force_kpa)
