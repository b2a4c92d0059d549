"""identifier: runs the rig identification protocols (`identify.run_protocol`) against a rig.

    python -m incipient_slip.nodes.identifier out_dir:=runs/identify spring_n_per_mm:=0.0327

Two period clocks. `clock: tick_end` (rig_sim `protocol:=commanded`, lock-step): period k ends at
the rig's tick k (`/actuator/state`); once its mocap samples are in (`/object/pose`, stamps in
[k T, (k+1) T)) the period's `Observation` (F_N applied from `/robot/state`, the actuator's
position, y) goes to the protocol, and its answer goes out as `ActuatorCommand(period=k)` (a
position from the zero-load origin) and `GripCommand(period=k)`, which the rig applies from
period k+1 (it waits for both). `clock: tick_start` (device nodes, real time; linear_actuator
`mode:=commanded`): the identifier sends period k's commands, the stage's tick k says the move is
done, and the period is the window [tick + settle_s, tick + settle_s + T) of host-time stamps (the
pad, the robot's press and an emulated rig's own 500 ms step settle first); then period k+1's
commands go out; a window with under half its mocap samples (a hole in the stream) is observed
again over the next T, counted (a fault after `max_window_retries`). `actuator_origin_mm` is the stage position of zero spring load (start_mm).
When the protocols end it writes `identify_results.json` (every period), `identify_overlay.yaml`
(the params overlay) and one picture per protocol into `out_dir`, and exits 0. Interrupted
(SIGINT/SIGTERM) it first commands zero spring load (the actuator onto the object) and writes what
it has. No tick or mocap within `silence_timeout_s` (wall clock, liveness only) is a fault: exit 3.

Safety of its own: every F_N is clamped to the safety limit, rises at most `max_rise_kpa` a period
(a press loop overshoots a big step) and every position stays in [0, max_travel_mm], by the
protocol; a robot that reports a stop ends the identification (exit 3, unloaded, what was measured
written); the nodes that move the hardware clamp again.
"""
from __future__ import annotations

import math
import time

from incipient_slip import identify
from incipient_slip.errors import EXIT_FAULT
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.messages import PERIOD_NS, ActuatorCommand, ActuatorState, GripCommand, ObjectPose, RobotState

T_S = PERIOD_NS / 1e9


class Identifier(Node):
    """Drives the identification protocols period by period and writes the overlay."""

    INPUTS = {t.TOPIC: t for t in (ObjectPose, RobotState, ActuatorState)}
    OUTPUTS = {GripCommand.TOPIC: GripCommand, ActuatorCommand.TOPIC: ActuatorCommand}
    PARAMS = {
        "out_dir": Param("runs/identify", help="where the results, the overlay and the pictures go"),
        "rig": Param("sim", help="the rig's name, recorded as the overlay's provenance"),
        "material": Param("pla", help="the object's material (its mu goes into the overlay under this name)"),
        "spring_n_per_mm": Param(0.0327175, lo=1e-6, help="spring constant k_s, measured by hand (N/mm)"),
        "spring_rel_sd": Param(0.03, lo=0.0, hi=0.99, help="its relative standard uncertainty"),
        "newton_per_kpa": Param(0.4, lo=1e-6, help="kPa -> N gain of P_DC, measured by hand (N/kPa)"),
        "gain_rel_sd": Param(0.1, lo=0.0, hi=0.99, help="its relative standard uncertainty"),
        "levels_kpa": Param("5.9,4.7,3.5,2.3,1.1", help="F_N levels of the stiffness ramps, highest first (kPa, comma-separated)"),
        "step_mm": Param(0.1, lo=1e-3, hi=1.0, help="actuator step per period on a ramp (mm)"),
        "max_rise_kpa": Param(1.0, lo=1e-3, hi=6.0, help="F_N rises at most this per period (kPa)"),
        "lag_high_kpa": Param(5.9, lo=0.1, hi=6.0, help="the lag trials' F_N before the step (kPa)"),
        "lag_low_kpa": Param(2.3, lo=0.1, hi=6.0, help="the lag trials' F_N after the step (kPa)"),
        "slide_rise_mm": Param(0.02, lo=1e-3, hi=1.0, help="a ramp slid when y rises this much above its stuck steps (mm)"),
        "slide_needs_rise": Param(False, choices=(False, True),
                                  help="true (real-time rigs): only that rise ends a ramp, not the paper's within-period rule"),
        "max_travel_mm": Param(48.0, lo=0.0, hi=50.0, help="the actuator never goes past this (mm)"),
        "protocols": Param("stiffness,lag,no_action", help="which protocols to run, in this order (comma-separated)"),
        "no_action_steps": Param(450, lo=1, help="steps of the no-action check (paper: 450)"),
        "mocap_rate_hz": Param(120.0, lo=1.0, help="a period is complete with 90 % of its mocap samples"),
        "silence_timeout_s": Param(60.0, lo=0.1, help="liveness: no tick or mocap this long is a fault (s)"),
        "clock": Param("tick_end", choices=("tick_end", "tick_start"),
                       help="tick_end: rig_sim lock-step; tick_start: device nodes in real time"),
        "settle_s": Param(0.5, lo=0.0, hi=10.0, help="tick_start: wait this long after a move before the period's window (s)"),
        "actuator_origin_mm": Param(0.0, lo=-1000.0, hi=1000.0, help="stage position at zero spring load (mm)"),
        "max_window_retries": Param(20, lo=0, help="tick_start: windows re-observed after mocap holes before a fault"),
        "wait_timeout_s": Param(300.0, lo=0.0, help="tick_start: the first command waits for the readers at most this long (s)"),
    }

    def __init__(self, **kwargs):
        super().__init__("identifier", **kwargs)
        p = self.param
        try:
            self.plan = identify.Plan(levels_kpa=tuple(float(x) for x in str(p("levels_kpa")).split(",")),
                                      step_mm=p("step_mm"), max_travel_mm=p("max_travel_mm"),
                                      slide_rise_mm=p("slide_rise_mm"), slide_needs_rise=p("slide_needs_rise"),
                                      max_rise_kpa=p("max_rise_kpa"),
                                      lag_high_kpa=p("lag_high_kpa"), lag_low_kpa=p("lag_low_kpa"),
                                      protocols=tuple(x.strip() for x in str(p("protocols")).split(",")),
                                      no_action_steps=p("no_action_steps"))
            self.inputs = identify.Inputs(spring_n_per_mm=p("spring_n_per_mm"), spring_rel_sd=p("spring_rel_sd"),
                                          newton_per_kpa=p("newton_per_kpa"), gain_rel_sd=p("gain_rel_sd"),
                                          material=p("material"), rig=p("rig"))
            self.plan.check()
            self.inputs.check()
        except (identify.IdentificationError, TypeError, ValueError) as exc:
            raise ParamError(f"node {self.name!r}: {exc}") from None
        self.records: list[identify.Record] = []
        self.protocol = identify.run_protocol(self.plan, self.inputs, self.records)
        self.command = next(self.protocol)          # for period 0, which the rig runs at its own start
        self.grip_pub = self.create_publisher(GripCommand)
        self.actuator_pub = self.create_publisher(ActuatorCommand)
        self.create_subscription(ObjectPose, self.on_pose)
        self.create_subscription(RobotState, self.on_robot)
        self.create_subscription(ActuatorState, self.on_tick)
        self.real_time = p("clock") == "tick_start"
        self.windows = identify.PeriodWindows(self.real_time, p("mocap_rate_hz"), p("settle_s"),
                                              p("actuator_origin_mm"), p("max_window_retries"))
        self.last_news = time.monotonic()
        self.finished = False
        self.last_phase = ""                    # of the last command: one progress line per phase
        self.on_shutdown(self.finish)
        self.create_timer(0.5, self.check_liveness)
        if self.real_time:
            self.started = False
            self.create_timer(0.05, self.start)

    def start(self) -> None:
        """tick_start: send period 0's commands once the readers the launch names are subscribed."""
        if self.started:
            return
        self.started = True
        if self.readers:
            self.wait_for_readers(self.param("wait_timeout_s"))
        self.last_news = time.monotonic()
        self.publish(self.command, 0)

    def on_pose(self, msg: ObjectPose) -> None:
        self.windows.pose(msg.stamp_ns, msg.travel_mm)
        self.last_news = time.monotonic()
        self.try_period()

    def on_robot(self, msg: RobotState) -> None:
        self.windows.force(msg.stamp_ns, msg.normal_force_kpa)
        if (msg.protective_stop or msg.emergency_stop or msg.state == "stopped") and not self.finished:
            # a stopped robot presses nothing the protocol assumes: end, unloaded, with what was measured
            self.warn(f"the robot stopped (state {msg.state}, protective stop {msg.protective_stop}, emergency "
                      f"stop {msg.emergency_stop}) in period {self.next_period}; ending the identification")
            self.shutdown("robot stopped", EXIT_FAULT)

    def on_tick(self, msg: ActuatorState) -> None:
        self.windows.tick(msg.period, msg.stamp_ns, msg.position_mm)
        self.last_news = time.monotonic()
        self.try_period()

    @property
    def next_period(self) -> int:
        return self.windows.next_period

    def try_period(self) -> None:
        """Answer every period whose window is complete (`identify.PeriodWindows`), in order."""
        while not self.finished:
            got = self.windows.next()
            if got is None:
                return
            if isinstance(got, identify.WindowRetry):
                if got.give_up:
                    self.warn(f"period {got.period}: {got.samples} mocap samples in its window, "
                              f"{got.retried} windows retried; giving up")
                    self.shutdown("mocap missing", EXIT_FAULT)
                    return
                # a hole in the mocap stream (a loaded host, a lost marker): the same state is
                # observed over the next window instead of reading a period from a few samples
                self.warn(f"period {got.period}: only {got.samples} mocap samples in its window; observing the "
                          f"next {T_S:g} s instead ({got.retried} retried so far)", throttle_s=1.0)
                continue
            self.answer(got)

    def answer(self, obs: identify.Observation) -> None:
        """Send a period's observation to the protocol and publish its answer for the next period."""
        k = obs.period
        try:
            self.command = self.protocol.send(obs)
        except StopIteration:
            self.log(f"the protocols are done after {k + 1} periods")
            self.shutdown("identification done")
            return
        except identify.IdentificationError as exc:
            self.warn(f"period {k}: {exc}")
            self.shutdown("bad measurement", EXIT_FAULT)
            return
        self.publish(self.command, k + 1 if self.real_time else k)

    def publish(self, cmd: identify.Command, k: int) -> None:
        if cmd.phase != self.last_phase:       # progress: one line per phase, not per period
            self.last_phase = cmd.phase
            self.log(f"period {k}: {cmd.phase} (F_N {cmd.normal_force_kpa:.2f} kPa)")
        self.actuator_pub.publish(ActuatorCommand(position_mm=cmd.actuator_mm, period=k))
        self.grip_pub.publish(GripCommand(normal_force_kpa=cmd.normal_force_kpa, period=k, reason=cmd.phase,
                                          cause="schedule"))

    def check_liveness(self) -> None:
        limit = self.param("silence_timeout_s")
        if not self.finished and time.monotonic() - self.last_news > limit:
            self.warn(f"no tick or mocap for {limit} s after period {self.next_period - 1}")
            self.shutdown("rig silent", EXIT_FAULT)

    def finish(self) -> None:
        """Leave the rig unloaded and write what was measured (also when interrupted)."""
        if self.finished:
            return
        self.finished = True
        if self.records and self.next_period > 0:
            last = self.records[-1]
            self.publish(identify.Command(last.fn_kpa, max(0.0, min(last.y_mm, self.plan.max_travel_mm)),
                                          "unload", -1), self.next_period + 1 if self.real_time else self.next_period - 1)
        if not self.records:
            return
        try:
            results = identify.analyze(self.records, self.inputs)
            paths = identify.write_outputs(results, self.records, self.param("out_dir"))
        except (OSError, identify.IdentificationError, KeyError, ValueError) as exc:
            self.warn(f"could not write the identification: {exc}")
            return
        st, lag = results["stiffness"], results["lag"]
        parts = []
        if "k_ref" in st:
            lo, hi = st["k_ref_interval"]
            bound = (f"[{lo:.3f}, {hi:.3f}]" if math.isfinite(lo) and math.isfinite(hi)
                     else "(no interval: too few levels)")
            parts.append(f"k_b {st['k_ref']:.3f} N/mm at 1 N {bound}, beta {st['beta']:.2f}")
        if "mu" in st:
            parts.append(f"mu {st['mu']:.3f}")
        if lag:
            parts.append(f"lag {lag['tau_s']:.2f} s [{lag['tau_interval'][0]:.2f}, {lag['tau_interval'][1]:.2f}]")
        self.log("identified: " + ", ".join(parts or ["nothing (too few periods)"]) + f"; overlay {paths['overlay']}")
        if "k_ref" in st and not all(math.isfinite(v) for v in st["k_ref_interval"] + st["beta_interval"]):
            self.warn(f"k_b and beta have no interval: {st['levels']} F_N level(s) after the run-in fit "
                      f"exactly; the overlay gives their values only ({identify.UNBOUNDED})")


def main(argv=None):
    return run_node(Identifier, argv)


if __name__ == "__main__":
    raise SystemExit(main())
