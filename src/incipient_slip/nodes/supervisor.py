"""supervisor: ends a stabilization run on the paper's rules, writes its summary, exits with the verdict.

    python -m incipient_slip.nodes.supervisor max_steps:=450 summary_path:=runs/run.json

Feeds `/object/pose` (travel y), `/robot/state` (applied F_N), `/slip/estimate` and
`/grip/command` (which closes each period) to `control.RunJudge`, which judges by its own count
of periods: y > 1.5 mm or F_N at the 6.0 kPa limit fails, repeated holds are a fault, `max_steps`
periods succeed; a command whose period is not the next one is dropped. No command within a
wall-clock timeout is a fault ("graph silent"); before the first command that clock starts at the
rig's first message (readiness), not at this node's start. `lockstep: true` (the simulated rig waits for
each command): a period is judged once its command, the rig's tick that ends it (after all its
data) and its estimate are in, never on `data_wait_s`; the wall-clock timeouts are liveness limits only. `period_origin: tick` (device clocks, host-time
stamps; a replayed recording): pose and F_N stamps are taken on the period clock that the actuator's first tick sets
(`control.PeriodOrigin`), as the estimator does. It publishes `RunEvent`s, writes the JSON run
summary (also when interrupted) with the per-period traces (`/sim/truth`, the simulated rig's true
stick ratio and F_T, goes into the traces only, never into a verdict; in lock-step the summary waits
for the last period's truth, at most TRUTH_WAIT_S; `slip run plot` draws them),
prints one screen and exits 0 (success), 1 (failure) or 3 (fault); 2 when `summary_path` cannot be
written (checked before start, its folder created; at the end: after the verdict is printed).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from incipient_slip import control
from incipient_slip.errors import EXIT_USAGE
from incipient_slip.graph.params import Param, checked_output
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.models.labels import DEFAULT_LABEL
from incipient_slip.paths import output_error, written_atomically
from incipient_slip.messages import RUN_EVENT_KINDS, ActuatorState, BiotacSlow, GripCommand, ObjectPose, PztState, RobotState, RunEvent, SimTruth, SlipEstimate

POSITIVE = dict(lo=1e-3)
TRUTH_WAIT_S = 5.0          # lock-step: longest wait for the last period's /sim/truth before the summary
# params copied into the summary: what a run was, so that a summary says which model, rig
# params overlay and recording it came from
RECORDED = ("method", "s_d", "k", "seed", "material", "rig", "stop_on_travel", "model", "label", "rig_params", "recording")


class Supervisor(Node):
    """Judges each period of a run and writes the run summary when it ends."""

    INPUTS = {t.TOPIC: t for t in (ObjectPose, RobotState, SlipEstimate, GripCommand, PztState, ActuatorState, SimTruth)}
    OPTIONAL_INPUTS = frozenset({SimTruth.TOPIC})     # only the simulated rig knows the truth
    OUTPUTS = {RunEvent.TOPIC: RunEvent}
    PARAMS = {
        "summary_path": Param("runs/stabilize_summary.json", help='run summary JSON ("": none)'),
        "max_travel_mm": Param(control.FAILURE_TRAVEL_MM, lo=0.0, help="failure when y exceeds it"),
        "safety_limit_kpa": Param(control.SAFETY_LIMIT_KPA, lo=0.0, hi=control.SAFETY_LIMIT_KPA, help="failure when F_N reaches it"),
        "max_steps": Param(control.MAX_STEPS, lo=1, help="periods of a successful run"),
        "max_consecutive_holds": Param(3, lo=1, help="holds in a row that are a fault"),
        "max_missing_periods": Param(3, lo=1, help="periods in a row without y or F_N before a verdict"),
        "end_on_failure": Param(True, help="false: run all steps and report (the paper's no action)"),
        "stop_on_travel": Param(False, help="true: end at the first y > max_travel_mm; false (the paper's "
                                            "protocol): run to the F_N limit or max_steps and judge the end state"),
        "startup_timeout_s": Param(60.0, **POSITIVE, help="wall clock from the rig's first message until the first grip command (s)"),
        "silence_timeout_s": Param(5.0, **POSITIVE, help="wall clock between two grip commands (s)"),
        "data_wait_s": Param(3.0, **POSITIVE, help="longest wait for a period's data after its command (s)"),
        "quiet": Param(False, help="true: no one-screen summary (batch runs)"),
        "lockstep": Param(False, help="true: the rig waits for each command; periods are judged on messages only, never on data_wait_s"),
        "period_origin": Param("stamps", choices=control.PERIOD_ORIGINS,
                               help="stamps: period k is stamp // T; tick: from the actuator's first tick (device clocks)"),
        # recorded in the summary only
        "method": "", "s_d": Param(float("nan"), finite=False), "k": Param(float("nan"), finite=False),
        "seed": 0, "material": "", "rig": "sim",
        "model": Param("", help="the estimator's model file, recorded in the summary ('' = the shipped one)"),
        "label": Param("", help="the training label of the model (label:=), recorded in the summary ('' = the shipped "
                       "default, or model:='s own)"),
        "rig_params": Param("", help="the simulated rig's params overlay, recorded in the summary"),
        "recording": Param("", help="the replayed recording (rig:=replay), recorded in the summary"),
    }

    @classmethod
    def check_inputs(cls, params: dict, name: str = "supervisor"):
        """The summary's folder created and writable (a launch: before any node starts; an
        unwritable summary_path was found only at the run's end); ParamError naming it."""
        if params["summary_path"]:
            checked_output(name, "summary_path", params["summary_path"], "the summary")

    def __init__(self, **kwargs):
        super().__init__("supervisor", **kwargs)
        self.check_inputs(self.params, self.name)
        p = self.param
        rules = control.SupervisorRules(p("max_travel_mm"), p("safety_limit_kpa"), p("max_steps"),
                                        p("max_consecutive_holds"), p("end_on_failure"), p("stop_on_travel"))
        self.judge = control.RunJudge(rules, p("max_missing_periods"), estimates_drive=p("method") != "none",
                                      data_wait_s=p("data_wait_s"), lockstep=p("lockstep"))
        self.force_carried = 0
        self.started = time.monotonic()
        # start-up waits on readiness: the clock until the first command starts at the rig's
        # first message (a loaded machine may take a minute to start the rig; the launch ends
        # if a required node dies meanwhile, and rig_sim starts on its own readiness rules)
        self.last_command: float | None = None
        self.pzt_on = self.summary = None
        self.steps_sent = 0
        self.verdict_sent = False
        self.events = self.create_publisher(RunEvent)
        self.input_ns = 0       # the latest stamp of an input: events carry it (one time base)
        self.origin = control.PeriodOrigin(p("period_origin"), held_max=2000)
        self.create_subscription(ActuatorState, self.on_tick)
        self.create_subscription(ObjectPose, lambda m: m.tracking_valid and self.on_rig(self.judge.pose, m.stamp_ns, m.travel_mm))
        self.create_subscription(RobotState, lambda m: self.on_rig(self.judge.robot, m.stamp_ns, m.normal_force_kpa))
        self.create_subscription(SlipEstimate, lambda m: self.judge.estimate(m.period, m.stick_ratio, m.valid))
        self.create_subscription(PztState, lambda m: setattr(self, "pzt_on", m.enabled))
        self.create_subscription(SimTruth, lambda m: self.judge.truth_of(m.period, m.stick_ratio, m.tangential_force_n))
        self.create_subscription(GripCommand, self.on_command)
        # rig_sim starts period 0 once every topic it publishes has a subscriber (handshake);
        # the slow channels may have no other reader (injection), so count them here, undecoded
        self.create_raw_subscription(lambda *_: None, BiotacSlow.TOPIC)
        self.truth_wait_since: float | None = None
        self.create_timer(0.01, self.watchdog)
        self.on_shutdown(lambda: self.finish(control.Verdict("interrupted", f"interrupted after {self.judge.steps} steps")))

    def recorded_label(self) -> str:
        """The model's training label as the summary records it: label:=, else the shipped default
        when no model:= was given ('' with a model file: its header says)."""
        if self.param("label") or self.param("model") or self.param("method") == "none":
            return self.param("label")
        return DEFAULT_LABEL

    def on_rig(self, record, stamp_ns: int, value: float) -> None:
        """A pose or F_N of the rig, on the period clock (held until the first tick, if need be)."""
        self.input_ns = max(self.input_ns, stamp_ns)
        if self.last_command is None:
            self.last_command = time.monotonic()
        if not self.origin.hold((record, stamp_ns, value)):
            stamp = self.origin.relative(stamp_ns)
            if stamp is not None:
                record(stamp, value, time.monotonic())

    def on_tick(self, msg: ActuatorState) -> None:
        self.input_ns = max(self.input_ns, msg.stamp_ns)
        if self.last_command is None:
            self.last_command = time.monotonic()
        if self.origin.origin_ns is None:
            for item in self.origin.tick(msg.period, msg.stamp_ns):
                self.on_rig(*item)
        self.judge.rig_tick(msg.period)

    def on_command(self, msg: GripCommand) -> None:
        self.input_ns = max(self.input_ns, msg.stamp_ns)
        first = self.judge.next_period is None
        dropped = self.judge.command(msg.period, msg.hold, msg.normal_force_kpa, time.monotonic())
        if dropped:
            self.warn(f"{dropped} ({self.judge.dropped} dropped)", throttle_s=1.0)
            return
        if first:
            self.events.publish(RunEvent(stamp_ns=self.input_ns, kind="start", detail=f"method {self.param('method')}"))
        self.last_command = time.monotonic()
        self.watchdog()

    def watchdog(self) -> None:
        j, now = self.judge, time.monotonic()
        verdict = j.close(now)
        if verdict.ended:       # before the last period's step: rig_sim (wait_judge) stops there
            self.publish_verdict()
        for i in range(self.steps_sent, j.steps):           # one RunEvent per judged period
            self.events.publish(RunEvent(stamp_ns=self.input_ns, kind="step", step=i + 1, object_travel_mm=j.traces["travel_mm"][i],
                                         normal_force_kpa=j.traces["force_kpa"][i]))
        self.steps_sent = j.steps
        if j.force_carried > self.force_carried:
            self.force_carried = j.force_carried
            self.warn(f"step {j.steps}: no F_N was stamped in its period (the robot node starved?); judged "
                      f"on the last one ({j.force_carried} such period(s))", throttle_s=1.0, key="carried")
        timeout = self.param("startup_timeout_s" if j.next_period is None else "silence_timeout_s")
        if not verdict.ended and self.last_command is not None and now - self.last_command > timeout:
            verdict = control.Verdict("fault", f"graph silent: no grip command for {timeout} s after step "
                                               f"{j.steps} (rig, estimator or controller stopped)")
        if verdict.ended and not self.awaits_truth(now):
            self.finish(verdict)

    def awaits_truth(self, now: float) -> bool:
        """Lock-step on the simulated rig: the last judged period's /sim/truth (traces only, never a
        verdict) travels on its own connection and may come after the period was judged; wait for
        it, at most TRUTH_WAIT_S (a liveness limit), so that two identical runs write identical
        summaries."""
        j = self.judge
        if not self.param("lockstep") or not j.truth or not j.traces["period"] or j.traces["period"][-1] in j.truth:
            return False
        if self.truth_wait_since is None:
            self.truth_wait_since = now
        if now - self.truth_wait_since < TRUTH_WAIT_S:
            return True
        self.warn(f"no /sim/truth for the last judged period {j.traces['period'][-1]} within {TRUTH_WAIT_S} s "
                  f"(heard {len(j.truth)}, the last for period {max(j.truth)}): the summary has NaN there")
        return False

    def finish(self, verdict: control.Verdict) -> None:
        """Writes the summary (once), prints it and ends the node with the verdict's exit code."""
        if self.summary is not None:
            return
        j = self.judge
        j.end(verdict)
        self.summary = j.summary(pzt_on=self.pzt_on, wall_s=round(time.monotonic() - self.started, 3),
                                 **{**{key: self.param(key) for key in RECORDED}, "label": self.recorded_label()})
        path = self.param("summary_path")
        if path and j.steps == 0 and Path(path).exists():
            path = ""       # a run that judged no period must not replace the last real run's summary
            self.warn(f"no period was judged: {self.param('summary_path')} (an earlier run's) is kept")
        unwritten = ""
        if path:
            try:
                write_summary(path, self.summary)
            except OSError as exc:      # checked at the start; the disk or the folder changed since
                unwritten = (f"the summary could not be written to {path} ({output_error(exc)}); "
                             f"the run's verdict: {j.verdict.kind}")
                path = ""
        if not self.param("quiet"):
            print(control.format_summary(self.summary, path), flush=True)
        self.publish_verdict()
        self.events.publish(RunEvent(stamp_ns=self.input_ns, kind="end", step=j.steps, detail=j.verdict.kind))
        if unwritten:       # the verdict is printed and published; the run still fails, naming why
            if self.stopping:       # on_shutdown (a signal): its exit code stands; say it here
                self.log(f"error: {unwritten}")
            self.shutdown(unwritten, exit_code=EXIT_USAGE)      # logged as "shutting down: ..."
        elif j.verdict.kind in control.EXIT_CODES:   # "interrupted": a signal already ends the node
            self.shutdown(j.verdict.detail, exit_code=control.EXIT_CODES[j.verdict.kind])

    def publish_verdict(self) -> None:
        """The verdict's RunEvent, once: as soon as a judged period ends the run (before that
        period's step event, so that a rig waiting for the judgement stops at it), else at the end."""
        j = self.judge
        if self.verdict_sent or j.verdict.kind not in RUN_EVENT_KINDS:
            return
        self.verdict_sent = True
        self.events.publish(RunEvent(stamp_ns=self.input_ns, kind=j.verdict.kind, step=j.steps, detail=j.verdict.detail,
                                     object_travel_mm=j.travel_mm, normal_force_kpa=j.force_kpa))


def write_summary(path: str, summary: dict) -> None:
    """The summary as JSON at `path`, its folder created; readers never see a half-written one."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with written_atomically(path) as tmp:
        tmp.write_text(json.dumps(summary, indent=1, allow_nan=True))


def main(argv=None):
    return run_node(Supervisor, argv)


if __name__ == "__main__":
    raise SystemExit(main())
