"""When a period's data are all in: one period closer per mode, asked by `judge.RunJudge`.

A period is judged once its command is in and its closer says the period is closed. The two
modes are two algorithms:

* :class:`LockstepCloser` (the simulated rig waits for each command): no wall-clock wait at all.
  The rig's tick k (`rig_tick`) comes after all of period k's data (its truth included) on the
  same connection, so period k is closed once its tick and its estimate (when its command acted
  on one) are in: verdict and traces are a function of the messages, never of the CPU load.
* :class:`RealTimeCloser` (the rig does not wait): period k is closed once the rig's F_N of that
  period (or a later one: a robot node starved through a whole period stamps none in it) and
  its last pose are in (and, for a command that acted on an estimate, that estimate), or
  `data_wait_s` after its command when only the estimate is missing (lost with a killed
  estimator), or once `data_wait_s` passed both since its command and since the rig's last
  message when the rig's data are missing (a backlog still draining keeps it open).
"""
from __future__ import annotations

from typing import Protocol

from incipient_slip.messages import MOCAP_RATE_HZ, PERIOD_NS

MOCAP_SAMPLE_NS = 1_000_000_000 // MOCAP_RATE_HZ   # the last pose of period k is within one sample of its end


class Records(Protocol):
    """The data a closer reads, by period (the judge's)."""

    travel: dict[int, tuple[int, float]]     # period -> (stamp, y) of its last pose
    force: dict[int, float]
    estimates: dict[int, float]


class LockstepCloser:
    """Lock-step: period k is closed by the rig's tick k (and its estimate, when it drives)."""

    lockstep = True

    def __init__(self):
        self.rig_ticked = -1        # the rig's last tick: period k's data are all out

    def rig_tick(self, period: int) -> None:
        self.rig_ticked = max(self.rig_ticked, period)

    def heard(self, now_s: float) -> None:
        """The rig spoke (a pose or F_N): nothing to note, time plays no part."""

    def closed(self, period: int, wants_estimate: bool, command_s: float, now_s: float, data: Records) -> bool:
        return period <= self.rig_ticked and (not wants_estimate or period in data.estimates)


class RealTimeCloser:
    """Real time: period k is closed by its data, or by the deadlines of `data_wait_s`."""

    lockstep = False

    def __init__(self, data_wait_s: float = 3.0, period_ns: int = PERIOD_NS):
        self.data_wait_s, self.period_ns = data_wait_s, period_ns
        self.rig_heard_s = float("-inf")          # when the rig's last pose or F_N arrived
        self.rig_ticked = -1                       # kept for the record; real time never waits on it

    def rig_tick(self, period: int) -> None:
        self.rig_ticked = max(self.rig_ticked, period)

    def heard(self, now_s: float) -> None:
        self.rig_heard_s = now_s

    def closed(self, period: int, wants_estimate: bool, command_s: float, now_s: float, data: Records) -> bool:
        deadline = command_s + self.data_wait_s
        rig_done = self._force_done(period, data) and self._pose_done(period, data)
        if rig_done and (not wants_estimate or period in data.estimates):
            return True
        # an estimate lost with its publisher (killed) waits only data_wait_s; the rig's
        # data wait as long as the rig is still sending (a backlog draining)
        return now_s >= (deadline if rig_done else max(deadline, self.rig_heard_s + self.data_wait_s))

    @staticmethod
    def _force_done(period: int, data: Records) -> bool:
        """The period's F_N is in, or never will be: the robot's next one is in (its states come
        in order; a robot node starved for a whole period stamps none in it)."""
        return any(later >= period for later in data.force)

    def _pose_done(self, period: int, data: Records) -> bool:
        """The last pose of the period is in: one within a sample of its end, or a later one
        (the rig's messages come in order)."""
        end = (period + 1) * self.period_ns
        return any(later > period for later in data.travel) or any(later > period for later in data.force) or (
            period in data.travel and data.travel[period][0] >= end - MOCAP_SAMPLE_NS - 1_000_000)
