"""supervisor: ends a stabilization run on the paper's rules, writes its summary, exits with the verdict.

Watches `/object/pose` (travel y), `/robot/state` (applied F_N) and `/grip/command`, which
closes each period: the controller answers period k exactly once, right after the rig's tick for
k. (It does not read `/actuator/state` itself, so that the grip controller is that topic's only
reader and rig_sim's subscriber handshake cannot start period 0 before the controller listens.)
A period is judged once its command and the rig's pose and force for it have arrived (the
command comes from another publisher and may overtake them), by `control.judge_step`:
y > 1.5 mm or F_N at the 6.0 kPa safety limit fails, repeated holds are a fault (the estimate
stream is gone), 450 steps succeed. A silent graph (no command within a wall-clock timeout) is
also a fault. It publishes `RunEvent`s, writes the JSON run summary (success, final y, final
F_N, steps, traces), prints a one-screen summary and exits 0 (success), 1 (failure) or
3 (fault); it is `required` in the launch file, so the launch ends with its code.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

from incipient_slip import control
from incipient_slip.messages import (
    MOCAP_RATE_HZ, PERIOD_NS, BiotacSlow, GripCommand, ObjectPose, PztState, RobotState, RunEvent, SlipEstimate,
)
from incipient_slip.graph.runtime import Node, run_node

NAN = float("nan")
MOCAP_SAMPLE_NS = 1_000_000_000 // MOCAP_RATE_HZ


class Supervisor(Node):
    """Judges each period of a run and writes the run summary when it ends."""

    PARAMS = {
        "summary_path": "runs/stabilize_summary.json",
        "max_travel_mm": control.FAILURE_TRAVEL_MM,
        "safety_limit_kpa": control.SAFETY_LIMIT_KPA,
        "max_steps": control.MAX_STEPS,
        "max_consecutive_holds": 3,
        "max_missing_periods": 3,         # periods in a row without y or F_N before a fault
        "end_on_failure": True,           # false: run all steps and report (the paper's no action)
        "startup_timeout_s": 60.0,        # wall clock until the first grip command
        "silence_timeout_s": 5.0,         # wall clock between two grip commands
        "data_wait_s": 1.0,               # longest wait for a period's pose and force after its command
        "quiet": False,                   # true: no one-screen summary (batch runs)
        # recorded in the summary only
        "method": "", "s_d": NAN, "k": NAN, "seed": 0, "material": "", "rig": "sim",
    }

    def __init__(self, **kwargs):
        super().__init__("supervisor", **kwargs)
        self.rules = control.SupervisorRules(
            max_travel_mm=self.param("max_travel_mm"), safety_limit_kpa=self.param("safety_limit_kpa"),
            max_steps=self.param("max_steps"), max_consecutive_holds=self.param("max_consecutive_holds"),
            end_on_failure=self.param("end_on_failure"))
        self.travel_mm = NAN
        self.force_kpa = NAN
        self.estimate = NAN
        self.consecutive_holds = 0
        self.holds = 0
        self.steps = 0
        self.pzt_on = None
        self.traces = {k: [] for k in ("step", "travel_mm", "force_kpa", "command_kpa", "hold",
                                       "stick_ratio_estimate")}
        self.started_wall = time.monotonic()
        self.last_command_wall = None
        self.pending = None               # (GripCommand, wall deadline) of the period to judge
        self.pose_stamp_ns = self.robot_stamp_ns = -1
        self.missing = 0                  # consecutive periods judged without y or F_N
        self.done = False
        self.event_pub = self.create_publisher(RunEvent)
        self.create_subscription(ObjectPose, self.on_pose)
        self.create_subscription(RobotState, self.on_robot)
        self.create_subscription(SlipEstimate, self.on_estimate)
        self.create_subscription(GripCommand, self.on_command)
        self.create_subscription(PztState, self.on_pzt)
        # rig_sim starts period 0 once every topic it publishes has a subscriber (handshake);
        # the slow channels may have no other reader (injection), so count them here, undecoded.
        self.slow_frames = 0
        self.create_raw_subscription(self.on_slow_frame, BiotacSlow.TOPIC)
        self.create_timer(0.01, self.watchdog)

    def on_pose(self, msg: ObjectPose):
        if msg.tracking_valid:
            self.travel_mm = msg.travel_mm
            self.pose_stamp_ns = msg.stamp_ns
            self.close_period()

    def on_robot(self, msg: RobotState):
        self.force_kpa = msg.normal_force_kpa
        self.robot_stamp_ns = msg.stamp_ns
        self.close_period()

    def on_slow_frame(self, topic: str, body: bytes, recv_ns: int):
        self.slow_frames += 1

    def on_estimate(self, msg: SlipEstimate):
        self.estimate = msg.stick_ratio if msg.valid else NAN

    def on_pzt(self, msg: PztState):
        self.pzt_on = msg.enabled

    def on_command(self, msg: GripCommand):
        # One GripCommand answers each period, right after the rig's tick for it. It comes from
        # another publisher than the rig's pose and force, so it may overtake them: the period is
        # judged once the rig's data of that period are in (or after `data_wait_s`).
        if self.done or msg.period < 0:
            return
        self.last_command_wall = time.monotonic()
        if self.pending is not None:           # a newer period's command: judge the older now
            self.close_period(force=True)
        self.pending = (msg, self.last_command_wall + self.param("data_wait_s"))
        self.close_period()

    def close_period(self, force: bool = False):
        if self.pending is None or self.done:
            return
        msg, deadline = self.pending
        k = msg.period
        end_ns = (k + 1) * PERIOD_NS
        complete = (self.robot_stamp_ns >= k * PERIOD_NS
                    and self.pose_stamp_ns >= end_ns - MOCAP_SAMPLE_NS - 1_000_000)
        if not (complete or force or time.monotonic() >= deadline):
            return
        self.pending = None
        if self.steps == 0:
            self.event_pub.publish(RunEvent(kind="start", detail=f"method {self.param('method')}"))
        self.steps = k + 1
        self.consecutive_holds = self.consecutive_holds + 1 if msg.hold else 0
        self.holds += msg.hold
        for key, value in (("step", self.steps), ("travel_mm", self.travel_mm),
                           ("force_kpa", self.force_kpa), ("command_kpa", msg.normal_force_kpa),
                           ("hold", msg.hold), ("stick_ratio_estimate", self.estimate)):
            self.traces[key].append(value)
        self.event_pub.publish(RunEvent(kind="step", step=self.steps, object_travel_mm=self.travel_mm,
                                        normal_force_kpa=self.force_kpa))
        known = math.isfinite(self.travel_mm) and math.isfinite(self.force_kpa)
        # y or F_N not heard yet (e.g. this node joined after the rig's first period): not a
        # verdict until it lasts `max_missing_periods`; the last period is always judged.
        self.missing = 0 if known else self.missing + 1
        if not known and self.missing < self.param("max_missing_periods") and self.steps < self.rules.max_steps:
            return
        verdict = control.judge_step(self.steps, self.travel_mm, self.force_kpa,
                                     self.consecutive_holds, self.rules)
        if verdict.ended:
            self.finish(verdict)

    def watchdog(self):
        self.close_period()
        if self.done:
            return
        now = time.monotonic()
        if self.last_command_wall is None:
            if now - self.started_wall > self.param("startup_timeout_s"):
                self.finish(control.Verdict("fault", f"no grip command within "
                                                     f"{self.param('startup_timeout_s')} s of start"))
        elif now - self.last_command_wall > self.param("silence_timeout_s"):
            self.finish(control.Verdict("fault", f"graph silent: no grip command for "
                                                 f"{self.param('silence_timeout_s')} s after step {self.steps} "
                                                 f"(rig, estimator or controller stopped)"))

    def finish(self, verdict: control.Verdict):
        self.done = True
        self.event_pub.publish(RunEvent(kind=verdict.kind, step=self.steps, detail=verdict.detail,
                                        object_travel_mm=self.travel_mm, normal_force_kpa=self.force_kpa))
        summary = self.summary(verdict)
        path = Path(self.param("summary_path"))
        if str(path):
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(path.suffix + f".tmp{os.getpid()}")
            tmp.write_text(json.dumps(summary, indent=1, allow_nan=True))
            tmp.replace(path)       # readers never see a half-written summary
        if not self.param("quiet"):
            print(format_summary(summary, str(path)), flush=True)
        self.event_pub.publish(RunEvent(kind="end", step=self.steps, detail=verdict.kind))
        self.shutdown(verdict.detail, exit_code=control.EXIT_CODES[verdict.kind])

    def summary(self, verdict: control.Verdict) -> dict:
        keys = ("method", "s_d", "k", "seed", "material", "rig")
        return {
            "outcome": verdict.kind, "success": verdict.kind == "success", "detail": verdict.detail,
            "steps": self.steps, "max_steps": self.rules.max_steps,
            "final_travel_mm": self.travel_mm, "final_force_kpa": self.force_kpa,
            "holds": self.holds, "pzt_on": self.pzt_on,
            "wall_s": round(time.monotonic() - self.started_wall, 3),
            **{key: self.param(key) for key in keys},
            "traces": self.traces,
        }


def format_summary(summary: dict, path: str = "") -> str:
    """One screen: the verdict, final y and F_N against the paper's limits, steps, where the JSON is."""
    trace_y = [v for v in summary["traces"]["travel_mm"] if isinstance(v, float) and math.isfinite(v)]
    trace_f = [v for v in summary["traces"]["force_kpa"] if isinstance(v, float) and math.isfinite(v)]
    lines = [
        f"stabilization run ({summary.get('rig', 'sim')} rig): {summary['outcome'].upper()} - {summary['detail']}",
        f"  method {summary['method']}  s_d {summary['s_d']}  k {summary['k']}  "
        f"material {summary['material'] or '(scene default)'}  seed {summary['seed']}",
        f"  steps  {summary['steps']} / {summary.get('max_steps', control.MAX_STEPS)}",
        f"  y      {summary['final_travel_mm']:.3f} mm (failure > {control.FAILURE_TRAVEL_MM} mm; "
        f"max {max(trace_y, default=NAN):.3f})",
        f"  F_N    {summary['final_force_kpa']:.3f} kPa (safety limit {control.SAFETY_LIMIT_KPA} kPa; "
        f"range {min(trace_f, default=NAN):.2f}-{max(trace_f, default=NAN):.2f})",
        f"  holds  {summary['holds']}   wall {summary['wall_s']:.1f} s",
    ]
    if path:
        lines.append(f"  summary {path}")
    return "\n".join(lines)


def main(argv=None):
    return run_node(Supervisor, argv)


if __name__ == "__main__":
    raise SystemExit(main())
