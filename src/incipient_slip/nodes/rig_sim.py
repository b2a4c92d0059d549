"""rig_sim: the simulated rig behind the topics of the four device nodes.

    python -m incipient_slip.nodes.rig_sim scene:=paper material:=pla seed:=7

Each 500 ms period k is one `sim.Rig.step_period` call (the same call the in-process data set
generator makes) and goes out as 50 `BiotacPac`, 50 `BiotacSlow`, 60 `ObjectPose`, one
`RobotState` (the F_N applied), one `SimTruth` (the simulator's true stick ratio and F_T, which no
sensor measures; for the supervisor's run trace) and one `ActuatorState(period=k)` (the stage's
position after the period's step, as the Zaber node reads it back), the last two stamped at the period's end, in stamp order, all with sim stamps (docs/design.md, "Time base"). Only the streams of the
scene's effects are published: no P_AC without a vibration effect, no `BiotacSlow` without
electrodes / P_DC / temperature, no `ObjectPose` without mocap, no `PztState` without injection.

Stamps: P_AC frame j at its last sample, round((22 j + 21) 1e9 / 2200) ns; slow frame j at its
sample, j * 10 ms (as `models.features` cuts windows); mocap at its sample time; `RobotState`
at the period start, `ActuatorState` at its end. The runtime reads stamp 0 as "stamp me now",
so a message due at t = 0 is stamped 1 ns (within every consumer's half-sample tolerance).

Protocols: `closed_loop` applies the F_N of `/grip/command` (`normal_force_kpa` before the first
command, moved at most `max_step_kpa` per period and never past the 6 kPa safety limit, whatever
the command asks; `hold=True` keeps the current force); `commanded` (identification, launch/identify.yaml)
does the same and puts the actuator where `/actuator/command` says instead of stepping it (clamped
to [0, actuator_limit_mm]; in lock-step period k+1 waits for both commands of period k); `collection` redraws F_N each period exactly as
`sim.protocols.collection_forces_kpa(seed, steps)`. `seed` is the rig's own seed (series i of
a data set is `sim.rig.series_seed(dataset_seed, i)`). `/pzt/command` switches the injection
from the next period on; `injection_db` (default: the scene's) sets it at the start.

Before period 0 it waits for the readers of its topics that the launch names
(`Node.wait_for_readers`, from the nodes' declared INPUTS); started by hand (no launch), until
each topic of `wait_topics` (default: all it publishes but `/sim/truth`) has `wait_subscribers`
subscribers. After `wait_timeout_s` it warns and starts.

`lockstep: true`: it starts period k+1 only when `GripCommand(period=k)` has arrived (in
`collection` the command is only the go-ahead, its force is not used). No command within
`lockstep_timeout_s` (wall clock; 0 waits forever) is a fault: the node exits 3 naming the
period. `lockstep: false`: real time x `realtime_factor`, each message released when its stamp
is due; a period is simulated when it starts, with the latest command (so the answer to period
k, which comes after its tick, applies from period k+2, as on a real robot).

After `steps` periods it publishes nothing more and idles until SIGTERM (the supervisor ends a
run), or exits 0 when `exit_when_done`. At the supervisor's verdict (`RunEvent` success, failure,
fault or end) it stops at once: no further command is applied and no period simulated. With
`wait_judge` (lock-step launches with a supervisor) period k+1 also waits for the supervisor's
judgement of period k (its `RunEvent` step; a period that ends the run has its verdict sent
before its step), so a run's recording ends at its last judged period at any load.
"""
from __future__ import annotations

import time
from collections import deque

import numpy as np

from incipient_slip import control
from incipient_slip.errors import EXIT_FAULT
from incipient_slip.messages import (
    PAC_RATE_HZ, PAC_SAMPLES_PER_FRAME, PERIOD_NS, ActuatorCommand, ActuatorState, BiotacPac, BiotacSlow, GripCommand, ObjectPose, PztCommand, PztState,
    RobotState, RunEvent, SimTruth,
)
from incipient_slip.graph.params import Param, ParamError, checked_value
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.extras import needed

try:
    from incipient_slip.sim.protocols import collection_forces_kpa
    from incipient_slip.sim.rig import PeriodOutput, Rig
    from incipient_slip.sim.scene import SceneError, load_scene
except ModuleNotFoundError as exc:      # a lab PC's lean install: name the [sim] extra
    raise needed(exc) from None

PROTOCOLS = ("closed_loop", "collection", "commanded")
PAC_FRAME = PAC_SAMPLES_PER_FRAME
FRAMES_PER_PERIOD = 50
SLOW_FRAME_NS = 10_000_000
_IDENTITY_XYZW = np.array([0.0, 0.0, 0.0, 1.0])


def pac_frame_stamps_ns(k: int) -> np.ndarray:
    """Return the stamps of the 50 P_AC frames of period k: each at its last sample (ns)."""
    last = (np.arange(FRAMES_PER_PERIOD, dtype=np.int64) + FRAMES_PER_PERIOD * k) * PAC_FRAME + PAC_FRAME - 1
    return (last * 2_000_000_000 + PAC_RATE_HZ) // (2 * PAC_RATE_HZ)   # round(i * 1e9 / 2200)


def slow_frame_stamps_ns(k: int) -> np.ndarray:
    """Return the stamps of the 50 slow frames of period k: each at its sample, j * 10 ms."""
    return (np.arange(FRAMES_PER_PERIOD, dtype=np.int64) + FRAMES_PER_PERIOD * k) * SLOW_FRAME_NS


class RigSim(Node):
    """Steps the simulated rig one period at a time and publishes what the devices would."""

    INPUTS = {GripCommand.TOPIC: GripCommand, PztCommand.TOPIC: PztCommand, ActuatorCommand.TOPIC: ActuatorCommand,
              RunEvent.TOPIC: RunEvent}
    # the scene sets the injection, a command may switch it; only `commanded` reads the actuator's;
    # the collection protocol reads no grip command (collect.yaml has no controller); a launch
    # without a supervisor has no verdict
    OPTIONAL_INPUTS = frozenset({PztCommand.TOPIC, ActuatorCommand.TOPIC, GripCommand.TOPIC, RunEvent.TOPIC})
    OUTPUTS = {t.TOPIC: t for t in (BiotacPac, BiotacSlow, ObjectPose, PztState, RobotState, SimTruth, ActuatorState)}
    PARAMS = {
        "scene": Param("", help='scene file or name (scenes/); "": the scene of the method (control.SCENE_OF_METHOD)'),
        "method": Param("injection", help='the closed loop\'s method, whose scene scene:="" runs'),
        "material": Param("", help='object material ("": the scene\'s first)'),
        "params": Param("", help="an identified rig's params overlay on the scene (docs/identification.md)"),
        "seed": Param(0, lo=0, help="the rig's seed"),
        "protocol": Param("closed_loop", choices=PROTOCOLS, help="closed_loop: apply /grip/command; collection: the "
                          "data-set forces; commanded: /grip/command and the actuator at /actuator/command"),
        "actuator_limit_mm": Param(48.0, lo=0.0, hi=50.0, help="commanded: the actuator never goes past this (mm)"),
        "normal_force_kpa": Param(control.DEFAULT_INITIAL_FORCE_KPA, lo=0.0, hi=control.SAFETY_LIMIT_KPA,
                                  help="F_N before the first command (kPa)"),
        "max_step_kpa": Param(control.DEFAULT_MAX_STEP_KPA, lo=1e-6, hi=control.SAFETY_LIMIT_KPA,
                              help="largest change of the applied F_N from one period to the next, whatever "
                                   "a command asks (the grip law's own rate limit, kept here too; kPa)"),
        "injection_db": Param(None, help="PZT intensity (dB); None: the scene's"),
        "steps": Param(450, lo=1, help="periods to simulate"),
        "lockstep": Param(True, help="true: start period k+1 when GripCommand(period=k) arrives"),
        "lockstep_timeout_s": Param(30.0, lo=0.0, help="lock-step: fault when no command this long (s); 0 waits forever"),
        "wait_judge": Param(False, help="lock-step: period k+1 also waits for the supervisor's RunEvent step of "
                                        "period k (a run's recording then ends at its last judged period)"),
        "realtime_factor": Param(1.0, lo=1e-3, help="real time: sim seconds per wall second"),
        "wait_subscribers": Param(1, lo=0, help="started by hand: readers per topic to wait for before period 0"),
        "wait_topics": Param([], help="[] = every topic it publishes"),
        "wait_timeout_s": Param(10.0, lo=0.0, help="longest wait for them (s)"),
        "exit_when_done": Param(False, help="exit 0 after the last period"),
    }

    @classmethod
    def check_inputs(cls, params: dict, name: str = "rig_sim"):
        """The scene with the params overlay applied and the material in it; ParamError naming
        the parameter and the file (run_node reports it in one line, exit 2; a launch before any
        node starts: an unknown material once ended a running graph, after the supervisor's
        empty summary)."""
        try:
            scene = load_scene(control.scene_of(params["scene"], params["method"]), params["params"] or None)
        except (SceneError, ValueError) as exc:
            raise ParamError(f"node {name!r}: parameter {'params' if params['params'] else 'scene'!r}: "
                             f"{exc}") from None
        return scene, checked_value(name, "material", params["material"], scene.material)

    def __init__(self, **kwargs):
        super().__init__("rig_sim", **kwargs)
        scene, material = self.check_inputs(self.params, self.name)
        self.protocol = self.param("protocol")
        self.steps = self.param("steps")
        self.rig = Rig(scene, material, self.param("seed"))
        if self.param("injection_db") is not None:
            if not scene.has("injection"):
                raise ParamError(f"node {self.name!r}: injection_db is set but scene "
                                 f"{scene.name!r} has no 'injection' effect")
            self.rig.set_injection(True, float(self.param("injection_db")))
        self.forces = (collection_forces_kpa(self.rig.seed, self.steps)
                       if self.protocol == "collection" else None)
        self.force_kpa = float(self.param("normal_force_kpa"))
        self.lockstep = self.param("lockstep")
        p = scene.params
        self.pac_pa_per_count = float(p["adc"]["pac_pa_per_count"])
        self.pdc_pa_per_count = float(p["adc"]["pdc_pa_per_count"])
        self.pdc_tare = int(round(p["pdc"]["baseline_counts"])) if scene.has("pdc") else 0

        has = scene.has
        self.pac_pub = self.create_publisher(BiotacPac) if self.rig.has_pac else None
        self.slow_pub = (self.create_publisher(BiotacSlow)
                         if has("electrodes") or has("pdc") or has("temperature") else None)
        self.pose_pub = self.create_publisher(ObjectPose) if has("mocap") else None
        self.pzt_pub = self.create_publisher(PztState) if has("injection") else None
        self.robot_pub = self.create_publisher(RobotState)
        self.truth_pub = self.create_publisher(SimTruth)
        self.tick_pub = self.create_publisher(ActuatorState)
        self.create_subscription(GripCommand, self.on_grip)
        self.commanded = self.protocol == "commanded"
        self.actuator_mm, self.last_actuator = 0.0, -1
        if self.commanded:
            self.create_subscription(ActuatorCommand, self.on_actuator)
        self.create_subscription(PztCommand, self.on_pzt)
        self.create_subscription(RunEvent, self.on_run_event)
        self.judged = 0                   # periods the supervisor judged (its RunEvent steps)
        self.ended = False                # the supervisor's verdict arrived: nothing more is applied

        self.periods_done = 0             # periods simulated: the next one's index
        self.last_command = -1            # period of the last command applied
        self.refused_commands = 0
        self.clamped_commands = 0         # commands whose force was limited here (rate or safety limit)
        self.waiting_since = None         # lock-step: wall time we began waiting for period k-1
        self.queue: deque = deque()       # real time: (stamp_ns, publisher, message) not yet due
        self.t0 = None
        self.cost_s = [0.0, 0.0]          # [CPU, wall] seconds in step_period + publishing
        self.pzt_state = None
        self.done = False

    # --- the run -------------------------------------------------------------------------------

    def spin(self) -> int:
        """Waits for subscribers, runs the first period, then serves commands until shutdown."""
        self.wait_for_subscribers()
        if not self.stopping:
            self.log(f"scene {self.rig.scene.name}, material {self.rig.material}, seed "
                     f"{self.rig.seed}, {self.protocol}, {self._pace()}")
            self.publish_pzt_state()
            if self.lockstep:
                self.create_timer(0.05, self.check_lockstep_timeout)
                self.advance()
            else:
                self.t0 = time.monotonic()
                self.create_timer(min(0.01, 0.01 / self.param("realtime_factor")), self.release_due)
                self.release_due()
        return super().spin()

    def wait_for_subscribers(self) -> None:
        """Before period 0: the launch's readers of its topics (or, started by hand,
        `wait_subscribers` per topic of `wait_topics`) are subscribed, so nothing is lost."""
        n, timeout = self.param("wait_subscribers"), self.param("wait_timeout_s")
        if self.readers:
            self.wait_for_readers(timeout)
            return
        if n <= 0:
            return
        deadline = time.monotonic() + timeout
        pubs = [pub for pub in (self.pac_pub, self.slow_pub, self.pose_pub, self.pzt_pub,
                                self.robot_pub, self.tick_pub) if pub is not None]
        if self.param("wait_topics"):
            wanted = {self.resolve_topic(t) for t in self.param("wait_topics")}
            unknown = wanted - {pub.topic for pub in pubs}
            if unknown:
                self.warn(f"wait_topics {sorted(unknown)} are not published in scene "
                          f"{self.rig.scene.name!r}; not waiting for them")
            pubs = [pub for pub in pubs if pub.topic in wanted]
        lonely = [pub.topic for pub in pubs
                  if not pub.wait_for_subscribers(n, max(0.0, deadline - time.monotonic()))]
        if lonely and not self.stopping:
            self.warn(f"fewer than {n} subscriber(s) after {timeout} s on {', '.join(lonely)}; "
                      "starting anyway")

    def step(self) -> PeriodOutput | None:
        """Simulates period self.periods_done at the current force; None (and a fault exit) on a sim error."""
        force = float(self.forces[self.periods_done]) if self.forces is not None else self.force_kpa
        try:
            if self.commanded:
                self.rig.state.actuator_mm = self.actuator_mm
                return self.rig.step_period(force, actuator_step=False)
            return self.rig.step_period(force)
        except (ValueError, ArithmeticError) as exc:   # SimulationError is a ValueError
            self.warn(f"period {self.periods_done}: the simulator failed at F_N = {force} kPa: {exc}")
            self.shutdown(f"simulator error in period {self.periods_done}", EXIT_FAULT)
            return None

    def advance(self) -> None:
        """Lock-step: simulate and publish period k, then wait for GripCommand(period=k)."""
        t = time.process_time(), time.perf_counter()
        out = self.step()
        if out is None:
            return
        for _, pub, msg in self.period_messages(out):
            pub.publish(msg)
        self.account(t)
        self.periods_done += 1
        self.waiting_since = time.monotonic()
        if self.periods_done >= self.steps:
            self.finish()

    def release_due(self) -> None:
        """Real time: publish every message whose stamp is due; simulate periods as they start."""
        if self.done or self.ended:
            return
        now_ns = int((time.monotonic() - self.t0) * self.param("realtime_factor") * 1e9)
        while True:
            if not self.queue:
                if self.periods_done >= self.steps:
                    self.finish()
                    return
                if now_ns < self.periods_done * PERIOD_NS:
                    return
                t = time.process_time(), time.perf_counter()
                out = self.step()
                if out is None:
                    return
                self.queue.extend(self.period_messages(out))
                self.account(t)
                self.periods_done += 1
            while self.queue and self.queue[0][0] <= now_ns:
                _, pub, msg = self.queue.popleft()
                pub.publish(msg)
            if self.queue:
                return

    def account(self, t) -> None:
        self.cost_s[0] += time.process_time() - t[0]
        self.cost_s[1] += time.perf_counter() - t[1]

    def finish(self) -> None:
        self.done = True
        self.waiting_since = None
        cpu_ms, wall_ms = (1e3 * c / max(self.periods_done, 1) for c in self.cost_s)
        what = "simulate + publish" if self.lockstep else "simulate + build; publishing not counted"
        self.log(f"ran {self.periods_done} periods; {cpu_ms:.2f} ms CPU ({wall_ms:.2f} ms wall) per period ({what})")
        if self.param("exit_when_done"):
            self.shutdown(f"{self.periods_done} periods done")

    # --- commands ------------------------------------------------------------------------------

    def takes(self, what: str, period: int, last: int) -> bool:
        """A command is for the period just simulated (lock-step: the one awaited), never an old or
        future one; anything else is refused and counted. None after the last period."""
        newest = self.periods_done - 1
        ok = period == newest if self.lockstep else last < period <= newest
        if not ok:
            self.refused_commands += 1
            self.warn(f"refused {what}(period={period}): the rig is at period {newest}, last "
                      f"command {last} ({self.refused_commands} refused)", throttle_s=1.0)
        return ok and not self.done and not self.ended

    def on_grip(self, msg: GripCommand) -> None:
        # The node that moves the (simulated) hardware checks on its own: a command is for the
        # period just started (lock-step: the one awaited), never an old or future one, and its
        # force is clamped to the safety limit whatever the controller sent.
        if not self.takes("GripCommand", msg.period, self.last_command):
            return
        self.last_command = msg.period
        if self.protocol in ("closed_loop", "commanded") and not msg.hold:
            self.force_kpa = control.applied_force(msg.normal_force_kpa, self.force_kpa, control.SAFETY_LIMIT_KPA,
                                                   self.param("max_step_kpa"))
            if self.force_kpa != msg.normal_force_kpa:
                self.clamped_commands += 1
                self.warn(f"GripCommand(period={msg.period}) asked {msg.normal_force_kpa} kPa; applying "
                          f"{self.force_kpa} kPa (safety limit {control.SAFETY_LIMIT_KPA} kPa, at most "
                          f"{self.param('max_step_kpa')} kPa per period; {self.clamped_commands} clamped)",
                          throttle_s=1.0)
        self.next_period()

    def on_actuator(self, msg: ActuatorCommand) -> None:
        # checked as a grip command is, and clamped to the actuator's travel
        if not self.takes("ActuatorCommand", msg.period, self.last_actuator):
            return
        self.last_actuator = msg.period
        limit = self.param("actuator_limit_mm")
        self.actuator_mm = min(max(msg.position_mm, 0.0), limit)
        if self.actuator_mm != msg.position_mm:
            self.warn(f"ActuatorCommand(period={msg.period}) asked {msg.position_mm} mm; moving to "
                      f"{self.actuator_mm} mm (limits 0..{limit} mm)", throttle_s=1.0)
        self.next_period()

    def next_period(self) -> None:
        """Lock-step: period k+1 once period k is answered (its grip command, and its actuator
        command when `commanded`) and, with `wait_judge`, judged; never after the verdict."""
        k = self.periods_done - 1
        if (self.lockstep and not self.done and not self.ended and self.last_command == k
                and (not self.commanded or self.last_actuator == k)
                and (not self.param("wait_judge") or self.judged > k)):
            self.advance()

    def on_run_event(self, msg: RunEvent) -> None:
        if msg.kind == "step":
            self.judged = max(self.judged, msg.step)
            self.next_period()
        elif msg.kind in ("success", "failure", "fault", "end") and not self.ended:
            self.ended = True
            self.waiting_since = None
            self.log(f"the supervisor's verdict ({msg.kind}) after period {self.periods_done - 1}: nothing more is applied")

    def on_pzt(self, msg: PztCommand) -> None:
        try:
            self.rig.set_injection(msg.enabled, msg.intensity_db)
        except ValueError as exc:
            self.warn(throttle_s=1.0, key=("pzt", "bad"), text=f"ignored PztCommand: {exc}")
            return
        self.publish_pzt_state()

    def _pace(self) -> str:
        factor = self.param("realtime_factor")
        return "lock-step" if self.lockstep else "real time" if factor == 1.0 else f"{factor:g}x real time"

    def publish_pzt_state(self) -> None:
        if self.pzt_pub is None:
            return
        state = (self.rig.pzt_on, self.rig.pzt_db)
        if state == self.pzt_state:
            return
        self.pzt_state = state
        p = self.rig.p["injection"]
        self.pzt_pub.publish(PztState(enabled=state[0], intensity_db=state[1],
                                      band_low_hz=float(p["band_low_hz"]),
                                      band_high_hz=float(p["band_high_hz"]),
                                      stamp_ns=max(self.periods_done * PERIOD_NS, 1)))

    def check_lockstep_timeout(self) -> None:
        timeout = self.param("lockstep_timeout_s")
        if self.waiting_since is None or timeout <= 0:
            return
        if time.monotonic() - self.waiting_since > timeout:
            self.warn(f"lock-step: no GripCommand(period={self.periods_done - 1}) within {timeout} s "
                      "(is the grip controller running?)")
            self.shutdown(f"lock-step timeout after period {self.periods_done - 1}", EXIT_FAULT)

    # --- one period as messages ----------------------------------------------------------------

    def period_messages(self, out: PeriodOutput) -> list:
        """Return [(stamp_ns, publisher, message)] of one period, in stamp order."""
        k = out.period
        items = []
        if self.pac_pub is not None and out.pac_counts is not None:
            frames = out.pac_counts.reshape(FRAMES_PER_PERIOD, PAC_FRAME)
            pa = self.pac_pa_per_count
            for j, stamp in enumerate(pac_frame_stamps_ns(k).tolist()):
                items.append((stamp, self.pac_pub,
                              BiotacPac(pac_counts=frames[j], pa_per_count=pa, stamp_ns=stamp)))
        if self.slow_pub is not None:
            items += self.slow_messages(out, k)
        if self.pose_pub is not None and out.mocap_y_mm is not None:
            stamps = np.round(out.mocap_t_s * 1e9).astype(np.int64).tolist()
            positions = np.zeros((len(stamps), 3))
            positions[:, 1] = out.mocap_y_mm             # travel along the rail is y
            for stamp, position in zip(stamps, positions):
                stamp = max(stamp, 1)
                items.append((stamp, self.pose_pub,
                              ObjectPose(position_mm=position, orientation_xyzw=_IDENTITY_XYZW,
                                         stamp_ns=stamp)))
        start = max(k * PERIOD_NS, 1)
        items.append((start, self.robot_pub,
                      RobotState(normal_force_kpa=out.normal_force_kpa, stamp_ns=start,
                                 period=self.last_command)))      # the command this F_N came from
        items.sort(key=lambda item: item[0])     # stable: P_AC before slow at equal stamps
        end = (k + 1) * PERIOD_NS
        items.append((end, self.truth_pub,
                      SimTruth(period=k, stick_ratio=float(out.load_ratio_stick),
                               stick_area_ratio=float(out.stick_area_ratio),
                               tangential_force_n=float(out.tangential_force_n),
                               gross_slip=bool(out.gross_slip), stamp_ns=end)))
        items.append((end, self.tick_pub,      # where the stage stands at the tick: after the period's
                      ActuatorState(position_mm=self.rig.state.actuator_mm, period=k, stamp_ns=end)))
        return items

    def slow_messages(self, out: PeriodOutput, k: int) -> list:
        n = FRAMES_PER_PERIOD
        zeros = np.zeros(n, dtype=np.uint16)
        electrodes = (out.electrode_counts if out.electrode_counts is not None
                      else np.zeros((n, 19), dtype=np.uint16))
        pdc = (out.pdc_counts if out.pdc_counts is not None else zeros).tolist()
        tac = (out.tac_counts if out.tac_counts is not None else zeros).tolist()
        tdc = (out.tdc_counts if out.tdc_counts is not None else zeros).tolist()
        items = []
        for j, stamp in enumerate(slow_frame_stamps_ns(k).tolist()):
            stamp = max(stamp, 1)
            items.append((stamp, self.slow_pub, BiotacSlow(
                electrode_counts=electrodes[j], pdc_counts=pdc[j], tac_counts=tac[j],
                tdc_counts=tdc[j], pdc_pa_per_count=self.pdc_pa_per_count,
                pdc_tare_counts=self.pdc_tare, stamp_ns=stamp)))
        return items


def main(argv=None):
    return run_node(RigSim, argv)


if __name__ == "__main__":
    raise SystemExit(main())
