"""The grip controller's bookkeeping: each period the rig starts answered exactly once, in order,
with the wire `GripCommand` the node publishes as it is (one path from the law to the wire).

Pure: no sockets, no clock of its own (callers pass the time).
"""
from __future__ import annotations

from incipient_slip.control.law import ControlDecision, ControlParams, Problem, clamp_force, hold, next_force, problem_of
from incipient_slip.messages import GripCommand
from incipient_slip.messages.types import STEP_LIMIT

MAX_TICK_SKIP = 5          # ticks lost in a row that the controller follows; a bigger jump is refused
STALE = "stale estimate"


class Notice(str):
    """What the node should say about an input ("" for nothing), and whether it is the expected
    start of a run: `filling`, the estimator's window not full yet (a log line, not a warning).
    The node switches on `filling` (the estimate's cause), never on the words."""

    filling: bool

    def __new__(cls, text: str = "", filling: bool = False):
        notice = super().__new__(cls, text)
        notice.filling = filling
        return notice


QUIET = Notice()


class PeriodAnswerer:
    """Answers each period the rig starts exactly once, in order (the grip controller's core).

    `tick(k, now_s)` says the rig started period k; `estimate(...)` brings the estimate of a
    period; `clock(now_s)` passes wall-clock time. Each returns the `GripCommand`s now due (and
    `tick` and `estimate` a :class:`Notice`, falsy when there is nothing to say). Period k is
    answered on its estimate (the law, or a hold naming the problem when the estimate is
    invalid, NaN, outside [0, 1] or of another method), at once when the method is "none", or
    with a hold of the last safe force, cause "stale_estimate", once `estimate_timeout_s` passed
    after its tick. An estimate may come before its tick (another publisher); one for a period
    the rig has not started (beyond the next one, or skipped) or already answered is rejected
    and counted. Ticks advance by one (up to MAX_TICK_SKIP lost ones); a tick that jumps further
    or goes back, and a period no command can carry (outside [0, 2^32 - 1]), is refused and
    counted, so a forged period cannot end the run. A command
    carries the latest stamp of the inputs (`stamp_ns=` of `tick` and `estimate`: one time base).

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
        self.input_ns = 0                         # the latest stamp of an input

    def tick(self, period: int, now_s: float, stamp_ns: int = 0) -> tuple[list[GripCommand], Notice]:
        """Return (commands, notice) after the rig's tick for `period`."""
        self.input_ns = max(self.input_ns, stamp_ns)
        if not 0 <= period <= STEP_LIMIT or (
                self.last_tick is not None and not self.last_tick < period <= self.last_tick + 1 + MAX_TICK_SKIP):
            self.refused_ticks += 1
            return [], Notice(f"refused tick for period {period}: the rig was at period {self.last_tick}")
        self.last_tick = period
        if period <= self.last_answered:          # its estimate came first
            return [], QUIET
        if self.method == "none":
            return self._answer(period, ControlDecision(self.force_kpa, False, "no action", "no_action")), QUIET
        self.waiting[period] = now_s + self.timeout_s
        return [], QUIET

    def estimate(self, period: int, stick_ratio, valid: bool, method: str, reason: str = "",
                 cause: str = "unknown", stamp_ns: int = 0) -> tuple[list[GripCommand], Notice]:
        """Return (commands, notice) after an estimate for `period`; `reason` and `cause` are the
        estimate's own (`ESTIMATE_CAUSES`): an invalid one while the window fills is expected."""
        self.input_ns = max(self.input_ns, stamp_ns)
        if self.method == "none":
            return [], QUIET
        # the rig starts period k+1 once k is answered, maybe before its tick for k reached us
        rig_next = max(-1 if self.last_tick is None else self.last_tick, self.last_answered) + 1
        if period <= self.last_answered:
            return self._reject(f"estimate for period {period} arrived after it was answered")
        if period > STEP_LIMIT:
            return self._reject(f"estimate for period {period}: beyond the periods a command can carry")
        if period not in self.waiting and period != rig_next:   # not started, or skipped
            return self._reject(f"estimate for period {period} while the rig is at period {rig_next}")
        problem = problem_of(stick_ratio, valid, method=method, expected_method=self.method)
        if problem:
            problem = Problem(problem.cause, f"{problem.text} ({reason})" if reason else problem.text)
            self.rejected += 1
        commands = self._answer(period, next_force(self.force_kpa, stick_ratio, self.params, problem))
        if not problem:
            return commands, QUIET
        return commands, Notice(f"period {period}: {problem.text}",
                                filling=problem.cause == "estimate_invalid" and cause == "filling")

    def clock(self, now_s: float) -> list[GripCommand]:
        """Return the holds of the periods whose estimate is overdue at `now_s` (none in lock-step)."""
        late = [] if self.lockstep else self.overdue(now_s)
        return self._answer(max(late), hold(self.force_kpa, STALE, self.params)) if late else []

    def overdue(self, now_s: float) -> list[int]:
        """The periods still waiting for their estimate `estimate_timeout_s` after their tick."""
        return [waiting for waiting, deadline in self.waiting.items() if now_s >= deadline]

    def _reject(self, why: str) -> tuple[list[GripCommand], Notice]:
        self.rejected += 1
        return [], Notice(why)

    def _command(self, period: int, decision: ControlDecision) -> GripCommand:
        return GripCommand(normal_force_kpa=decision.normal_force_kpa, hold=decision.hold, period=period,
                           reason=decision.reason, cause=decision.cause, stamp_ns=self.input_ns)

    def _answer(self, period: int, decision: ControlDecision) -> list[GripCommand]:
        """Answers the waiting periods before `period` with holds (their estimate never came), then it."""
        held = hold(self.force_kpa, STALE, self.params)
        commands = [self._command(waiting, held) for waiting in sorted(self.waiting) if waiting < period]
        commands.append(self._command(period, decision))
        self.waiting = {later: t for later, t in self.waiting.items() if later > period}
        self.last_answered = period
        self.force_kpa = decision.normal_force_kpa
        self.holds += sum(c.hold for c in commands)
        return commands
