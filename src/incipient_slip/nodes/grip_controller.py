"""grip_controller: the paper's law a(s) = k(s - s_d) on the normal force, one command per period.

Answers period k with exactly one `GripCommand(period=k)` (docs/design.md, lock-step protocol):
on the estimate for k, or on the actuator tick for k when `method: none`. When the tick for k
has arrived and no usable estimate for k follows within `estimate_timeout_s` (wall clock), it
answers `hold=True, reason="stale estimate"`: the last safe force, never a ramp. Estimates that
are invalid, NaN, outside [0, 1], of another method or of an answered period are rejected and
counted. The law, clamps and rate limit are `incipient_slip.control`.

`robot: sim` sends the command to the simulated rig (which applies it); `robot: ur5` is the
UR5 (ur-rtde) backend, which comes with the hardware drivers.
"""
from __future__ import annotations

import time

from incipient_slip import control
from incipient_slip.messages import METHODS, ActuatorState, GripCommand, SlipEstimate
from incipient_slip.graph.params import ParamError
from incipient_slip.graph.runtime import Node, run_node

ROBOTS = ("sim", "ur5")


class GripController(Node):
    """Turns stick-ratio estimates into normal-force commands, holding on bad input."""

    PARAMS = {
        "method": "injection",
        "s_d": control.DEFAULT_TARGET_STICK_RATIO,
        "k": control.DEFAULT_GAIN_KPA,
        "max_step_kpa": control.DEFAULT_MAX_STEP_KPA,
        "initial_force_kpa": control.DEFAULT_INITIAL_FORCE_KPA,
        "min_force_kpa": control.DEFAULT_MIN_FORCE_KPA,
        "max_force_kpa": control.SAFETY_LIMIT_KPA,
        "estimate_timeout_s": 0.4,        # < one 500 ms period: hold within one period
        "robot": "sim",
        # before the first command: wait (once) until this many nodes subscribe to it (the rig
        # applying it and the supervisor), so period 0's answer is not lost to a slow joiner
        "wait_subscribers": 1,
        "wait_timeout_s": 10.0,
    }

    def __init__(self, **kwargs):
        super().__init__("grip_controller", **kwargs)
        robot = self.param("robot")
        if robot == "ur5":
            raise ParamError(
                "robot:=ur5 is not available yet: the UR5 (ur-rtde) backend "
                "comes with the hardware drivers; use robot:=sim (the simulated rig)")
        if robot not in ROBOTS:
            raise ParamError(f"robot:={robot!r} is unknown; use one of {', '.join(ROBOTS)}")
        self.law = control.ControlParams(
            target_stick_ratio=self.param("s_d"), gain_kpa=self.param("k"),
            max_step_kpa=self.param("max_step_kpa"), min_force_kpa=self.param("min_force_kpa"),
            max_force_kpa=self.param("max_force_kpa"))
        self.method = self.param("method")
        if self.method not in METHODS:
            raise ParamError(f"method:={self.method!r} is unknown; use one of {', '.join(METHODS)}")
        self.force_kpa = control.clamp_force(self.param("initial_force_kpa"), self.law)
        self.last_answered = -1
        self.last_tick = -1
        self.waiting = {}                 # period -> wall-clock deadline for its estimate
        self.rejected = 0                 # estimates that could not drive the force
        self.holds = 0
        self.handshake_done = False
        self.command_pub = self.create_publisher(GripCommand)
        self.estimate_sub = self.create_subscription(SlipEstimate, self.on_estimate)
        self.create_subscription(ActuatorState, self.on_tick)
        self.create_timer(0.01, self.check_deadlines)

    def on_tick(self, msg: ActuatorState):
        k = msg.step_index
        self.last_tick = max(self.last_tick, k)
        if k <= self.last_answered:
            return
        if self.method == "none":
            self.answer(k, control.ControlDecision(self.force_kpa, False, "no action"))
        else:
            self.waiting.setdefault(k, time.monotonic() + self.param("estimate_timeout_s"))

    def on_estimate(self, msg: SlipEstimate):
        if self.method == "none":
            return
        k = msg.period
        if k <= self.last_answered:
            self.reject(f"estimate for period {k} arrived after it was answered")
            return
        if k > self.last_tick + 1:     # the rig has not started that period: not a real estimate
            self.reject(f"estimate for period {k} while the rig is at period {self.last_tick + 1}")
            return
        problem = control.estimate_problem(msg.stick_ratio, msg.valid, method=msg.method,
                                           expected_method=self.method)
        if problem and msg.reason:
            problem = f"{problem} ({msg.reason})"
        if problem:
            self.reject(f"period {k}: {problem}")
        self.answer(k, control.next_force(self.force_kpa, msg.stick_ratio, self.law, problem))

    def check_deadlines(self):
        now = time.monotonic()
        for k in sorted(self.waiting):
            if k > self.last_answered and now >= self.waiting[k]:
                self.answer(k, control.hold(self.force_kpa, "stale estimate", self.law))

    def answer(self, period: int, decision: control.ControlDecision):
        if not self.handshake_done:
            self.handshake_done = True
            n = self.param("wait_subscribers")
            if n > 0 and not self.command_pub.wait_for_subscribers(n, self.param("wait_timeout_s")):
                self.warn(f"fewer than {n} subscriber(s) to {self.command_pub.topic} after "
                          f"{self.param('wait_timeout_s')} s; sending anyway")
        # Periods answered out of order (a late estimate) are never answered twice.
        self.last_answered = max(self.last_answered, period)
        self.waiting = {k: t for k, t in self.waiting.items() if k > self.last_answered}
        self.force_kpa = decision.normal_force_kpa
        if decision.hold:
            self.holds += 1
        self.command_pub.publish(GripCommand(normal_force_kpa=decision.normal_force_kpa,
                                             hold=decision.hold, period=period,
                                             reason=decision.reason))

    def reject(self, why: str):
        self.rejected += 1
        if self.rejected <= 5 or self.rejected % 100 == 0:
            self.warn(f"rejected estimate #{self.rejected}: {why}")


def main(argv=None):
    return run_node(GripController, argv)


if __name__ == "__main__":
    raise SystemExit(main())
