"""grip_controller: the paper's law a(s) = k (s - s_d) on the normal force, one command per period.

    python -m incipient_slip.nodes.grip_controller method:=injection s_d:=0.3 k:=2.0

Answers each period the rig starts (`/actuator/state`) with exactly one `GripCommand`: on the
period's estimate, at once for `method:=none`, or with a hold of the last safe force ("stale
estimate") when no usable estimate came within `estimate_timeout_s` (wall clock). In lock-step
(`lockstep: true`, the simulated rig waits for each command) there is no such hold: a period
waits for its estimate, so the run is a function of the seed and the parameters, not of the CPU
load; `estimate_timeout_s` is then a liveness limit only (a warning; the rig's own
`lockstep_timeout_s` ends a run whose estimator stopped). The bookkeeping is
`control.PeriodAnswerer`, which returns the `GripCommand`s published here as they are; the law,
clamps and rate limit are `control.next_force`. An invalid estimate whose cause is `filling`
(the estimator's window not full yet, the start of every run) is logged; any other unusable
estimate is a warning. Whoever
applies the command (rig_sim, the UR5 node) reads `/grip/command`.
"""
from __future__ import annotations

import time

from incipient_slip import control
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.messages import METHODS, ActuatorState, GripCommand, SlipEstimate

FORCE = dict(lo=0.0, hi=control.SAFETY_LIMIT_KPA)


class GripController(Node):
    """Turns stick-ratio estimates into normal-force commands, holding on bad input."""

    INPUTS = {SlipEstimate.TOPIC: SlipEstimate, ActuatorState.TOPIC: ActuatorState}
    OUTPUTS = {GripCommand.TOPIC: GripCommand}
    PARAMS = {
        "method": Param("injection", choices=METHODS, help="estimates of this method drive the force"),
        "s_d": Param(control.DEFAULT_TARGET_STICK_RATIO, lo=0.0, hi=1.0, help="target stick ratio"),
        "k": Param(control.DEFAULT_GAIN_KPA, lo=0.0, help="gain, kPa per unit stick-ratio error per period"),
        "max_step_kpa": Param(control.DEFAULT_MAX_STEP_KPA, lo=1e-6, hi=control.SAFETY_LIMIT_KPA, help="rate limit per period"),
        "initial_force_kpa": Param(control.DEFAULT_INITIAL_FORCE_KPA, **FORCE, help="F_N before the first estimate"),
        "min_force_kpa": Param(control.DEFAULT_MIN_FORCE_KPA, **FORCE, help="lowest commanded F_N"),
        "max_force_kpa": Param(control.SAFETY_LIMIT_KPA, **FORCE, help="highest commanded F_N"),
        "estimate_timeout_s": Param(0.4, lo=1e-3, help="real time: hold when no estimate this long after the tick; lock-step: warn only (s)"),
        "lockstep": Param(False, help="true: the rig waits for each command; a period waits for its estimate"),
        "wait_subscribers": Param(1, lo=0, help="started by hand: readers of /grip/command to wait for"),
        "wait_timeout_s": Param(10.0, lo=0.0, help="longest wait for them (s)"),
    }

    def __init__(self, **kwargs):
        super().__init__("grip_controller", **kwargs)
        p = self.param
        if p("min_force_kpa") > p("max_force_kpa"):
            raise ParamError(f"node {self.name!r}: min_force_kpa:={p('min_force_kpa')} is above "
                             f"max_force_kpa:={p('max_force_kpa')}")
        law = control.ControlParams(p("s_d"), p("k"), p("max_step_kpa"), p("min_force_kpa"), p("max_force_kpa"))
        self.core = control.PeriodAnswerer(law, p("initial_force_kpa"), p("method"), p("estimate_timeout_s"),
                                           lockstep=p("lockstep"))
        self.command_pub = self.create_publisher(GripCommand)
        self.create_subscription(SlipEstimate, self.on_estimate)
        self.create_subscription(ActuatorState, self.on_tick)
        self.create_timer(0.01, self.clock)
        self.readers_ready = p("wait_subscribers") == 0

    def clock(self) -> None:
        now = time.monotonic()
        if self.core.lockstep:          # liveness only: the answer still waits for the estimate
            late = self.core.overdue(now)
            if late:
                self.warn(f"lock-step: no estimate for period {min(late)} after "
                          f"{self.param('estimate_timeout_s')} s; waiting (a liveness warning, the "
                          f"answer does not change)", throttle_s=5.0)
            return
        commands = self.core.clock(now)
        if commands:
            self.warn(f"period {commands[-1].period}: no estimate {self.param('estimate_timeout_s')} s after "
                      f"its tick: hold ({self.core.holds} holds)", throttle_s=1.0, key="late")
        self.send(commands)

    def on_tick(self, msg: ActuatorState) -> None:
        self.send(*self.core.tick(msg.period, time.monotonic(), msg.stamp_ns))

    def on_estimate(self, msg: SlipEstimate) -> None:
        commands, notice = self.core.estimate(msg.period, msg.stick_ratio, msg.valid, msg.method, msg.reason,
                                              msg.cause, msg.stamp_ns)
        if notice.filling:
            # expected at the start of every run: the estimator's window is not full yet
            self.log(f"{notice}: the force holds until the estimator's window is full")
            notice = control.Notice()
        self.send(commands, notice)

    def send(self, commands: list[GripCommand], warning: str = "") -> None:
        if warning:
            self.warn(f"{warning} ({self.core.rejected} estimates rejected, "
                      f"{self.core.refused_ticks} ticks refused so far)", throttle_s=1.0)
        if commands and not self.readers_ready:   # once: period 0's answer must not be lost
            self.readers_ready = True
            self.wait_before_first(self.command_pub, self.param("wait_subscribers"), self.param("wait_timeout_s"))
        for command in commands:
            self.command_pub.publish(command)


def main(argv=None):
    return run_node(GripController, argv)


if __name__ == "__main__":
    raise SystemExit(main())
