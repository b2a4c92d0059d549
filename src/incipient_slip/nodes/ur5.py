"""ur5: the robot node. Sets the normal force F_N through the end-effector position, as the
paper does: each 500 ms period one moveL along the pressing axis, from a slow position loop
on the measured F_N (P_DC of /biotac/slow) towards the target of /grip/command.

    python -m incipient_slip.nodes.ur5 robot_address:=192.168.1.5

One process of its own (`RobotLink`) owns ur-rtde's `RTDEControlInterface` and
`RTDEReceiveInterface` (the `[hardware]` extra); the node's thread only talks ZeroMQ. Safety of its own, whatever the
controller sent: the target moves at most `max_step_kpa` per period (from the last target; the
first from the measured F_N: the grip law's own rate limit, kept here too; the collection and
identification launches, whose protocols redraw F_N, open it) and is clamped to
`safety_limit_kpa`; a measured F_N above it
retracts; one period's move is at most `max_step_mm`; the TCP never goes more than
`max_press_mm` below (or `max_lift_mm` above) where it started; a command for a period older
than or equal to the last one is refused and counted (a later period supersedes missing ones,
which are counted); without a fresh F_N it holds still. Before every move it
checks protective stop, emergency stop and that the control script runs; on a stop it holds,
publishes state `stopped` and waits for an explicit recovery (`slip robot recover`, which
publishes /robot/recover): it never retries motion by itself. A lost connection recreates both
interfaces in a fresh link process (state `reconnecting`, back-off from 0.5 s to 8 s); the
command of that period is not replayed, and the new link takes the press depth from the
robot's actual pose (never a remembered one), so the step limit holds across the restart.
`RobotState.period` is the newest period whose move was made (-1 before the first).

When the node is gone the robot's control script stops by itself: the link arms ur-rtde's
watchdog (`watchdog_hz`) and kicks it; killed (SIGKILL, host power loss) nobody kicks it and the
controller stops the program within 1/watchdog_hz s; a clean exit stops it at once. The finger
stays where the last move left it (at most `safety_limit_kpa` when it was made); no motion
happens until a node connects again.

At start it names the fix when it can: no controller at the address, remote control off, RTDE
registers IN_USE (a fieldbus holds them). Any of these is exit 2 with one line.
"""
from __future__ import annotations

import math
import multiprocessing
import os
import queue
import socket
import time
from dataclasses import dataclass

from incipient_slip import control
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.devices import calibration
from incipient_slip.nodes.rig_check import apply_rig_config
from incipient_slip.messages import BiotacSlow, GripCommand, RobotRecover, RobotState

EXIT_NO_DEVICE = 2
RTDE_PORT = 30004
RUNTIME_PLAYING = 2         # RTDE runtime_state: the control script runs
SCRIPT_START_S = 10.0       # longest wait for the receive interface to see the script run (liveness)
RECEIVE_VARIABLES = ["timestamp", "actual_TCP_pose", "safety_status_bits", "runtime_state",
                     "robot_mode", "robot_status_bits"]


@dataclass(frozen=True)
class PressLoop:
    """The slow position loop on F_N: where the TCP goes next along the pressing axis."""

    gain_mm_per_kpa: float
    max_step_mm: float
    safety_limit_kpa: float
    max_press_mm: float
    max_lift_mm: float

    def next_depth_mm(self, depth_mm: float, target_kpa: float, measured_kpa: float) -> tuple[float, str]:
        """(next press depth in mm, below the start pose; what limited it, or "") for one period."""
        target = min(max(target_kpa, 0.0), self.safety_limit_kpa)
        if measured_kpa > self.safety_limit_kpa:
            step, why = -self.max_step_mm, f"F_N {measured_kpa:.2f} kPa above the safety limit: retract"
        else:
            step = self.gain_mm_per_kpa * (target - measured_kpa)
            why = "step clamped" if abs(step) > self.max_step_mm else ""
            step = max(-self.max_step_mm, min(self.max_step_mm, step))
        depth = depth_mm + step
        if depth > self.max_press_mm or depth < -self.max_lift_mm:
            depth = max(-self.max_lift_mm, min(self.max_press_mm, depth))
            why = why or "workspace limit"
        return depth, why


class RobotError(RuntimeError):
    """A robot that cannot be used; the text says what to fix."""


def explain(exc: Exception, host: str) -> str:
    """One line naming the fix for what ur-rtde raised while connecting."""
    text = str(exc)
    if "IN_USE" in text or "already in use" in text:
        return (f"RTDE input registers on {host} are IN_USE: disable EtherNet/IP, PROFINET and "
                f"Modbus units on the robot (Installation > Fieldbus), then restart this node")
    if "remote control" in text.lower():
        return (f"robot {host} is not in remote control: enable it on the pendant (Settings > "
                f"System > Remote Control) and switch the pendant to Remote mode")
    return f"robot {host}: {text}"


@dataclass(frozen=True)
class LinkConfig:
    """What the link process needs to reach and move the robot."""

    host: str
    frequency_hz: float
    speed_m_s: float
    accel_m_s2: float
    loop: PressLoop
    press_axis: int
    press_sign: float
    connect_timeout_s: float
    startup_timeout_s: float = 0.0
    watchdog_hz: float = 1.0

    def depth_of(self, start_pose, pose) -> float:
        """The press depth in mm (below `start_pose` along the pressing axis) of a TCP pose."""
        return self.press_sign * (start_pose[self.press_axis] - pose[self.press_axis]) * 1000.0

    def move_s(self) -> float:
        """The longest one period's moveL takes: max_step_mm with a trapezoidal speed profile
        (a triangular one when the move is too short to reach speed_m_s)."""
        d, v, a = self.loop.max_step_mm / 1000.0, self.speed_m_s, self.accel_m_s2
        return d / v + v / a if d >= v * v / a else 2.0 * math.sqrt(d / a)


def link_main(cfg: LinkConfig, jobs, events, start_pose) -> None:
    """The link process: owns both ur-rtde interfaces until told to quit or the connection drops."""
    RobotLink(cfg, jobs, events, start_pose).run()


class RobotLink:
    """Both ur-rtde interfaces, in a process of their own (see UR5): jobs in, events out.

    A process, not a thread, because ur-rtde 1.6.5 cannot be trusted after a dropped
    connection: its control interface then reconnects by itself in an endless loop (its
    reconnect flag is never reset), and disconnecting it, or reading its state, during that loop
    crashed the whole process (segfault). On a drop this process reports and exits; the node
    starts a fresh one. Its constructors also hold Python's GIL while they connect.

    The press depth is never carried over from an earlier link: each link derives it from the
    robot's actual TCP pose when it connects, so the step limit holds across a restart. Once
    connected it arms ur-rtde's watchdog (`setWatchdog`) and kicks it every loop: when neither
    this process nor the node is left to kick it (killed, host down), the robot's control script
    stops by itself within 1/watchdog_hz s. A clean exit stops the script too.
    """

    def __init__(self, cfg: LinkConfig, jobs, events, start_pose):
        self.cfg, self.jobs, self.events = cfg, jobs, events
        self.host = cfg.host
        self.start_pose, self.depth_mm = start_pose, 0.0
        self.snapshot = {"state": "ready", "tcp_pose": None, "protective_stop": False,
                         "emergency_stop": False, "program_running": False}
        self.control = self.receive = None
        self.parent = os.getppid()      # the node; this process ends when it is gone

    def _connect(self) -> None:
        """Both interfaces, retried until `startup_timeout_s` has passed; RobotError after."""
        deadline = time.monotonic() + self.cfg.startup_timeout_s
        while True:
            try:
                return self._connect_once()
            except RobotError:
                if time.monotonic() >= deadline or os.getppid() != self.parent:
                    raise
                time.sleep(0.5)

    def _connect_once(self) -> None:
        try:      # a fast check first: ur-rtde's connect holds the GIL and may wait long
            socket.create_connection((self.host, RTDE_PORT), timeout=self.cfg.connect_timeout_s).close()
        except OSError as exc:
            raise RobotError(f"no UR controller at {self.host}:{RTDE_PORT} ({exc}): is the robot "
                             f"on, and robot_address its IP (Settings > System > Network)?") from None
        try:
            import rtde_control
            import rtde_receive
        except ImportError:
            raise RobotError("ur-rtde is not installed: pip install -e '.[hardware]' "
                             "(wheels for CPython 3.10-3.12 on x86-64 Linux)") from None
        try:
            self.receive = rtde_receive.RTDEReceiveInterface(self.host, self.cfg.frequency_hz, RECEIVE_VARIABLES)
            self.control = rtde_control.RTDEControlInterface(self.host, self.cfg.frequency_hz)
            watchdog = self.control.setWatchdog(self.cfg.watchdog_hz)
        except Exception as exc:         # ur-rtde raises RuntimeError / logic_error texts
            raise RobotError(explain(exc, self.host)) from None
        if not watchdog:
            raise RobotError(f"robot {self.host}: the control script did not arm its watchdog")
        # the control interface returns once the script runs; the receive interface's data can
        # lag it on a loaded host, and a stale "not running" would be taken for a stop
        self._wait_playing(SCRIPT_START_S)
        pose = list(self.receive.getActualTCPPose())
        if self.start_pose is None:
            self.start_pose = pose
        self.depth_mm = self.cfg.depth_of(self.start_pose, pose)

    def run(self) -> None:
        try:
            self._connect()
        except RobotError as exc:
            self.events.put(("fatal", str(exc)))
            return
        self.events.put(("connected", f"connected to {self.host}; TCP at "
                                      f"{[round(v, 4) for v in self.start_pose[:3]]} m, press depth "
                                      f"{self.depth_mm:.3f} mm (from the actual pose)", self.start_pose))
        while True:
            try:
                job = self.jobs.get(timeout=0.05)
            except queue.Empty:
                job = None
            if (job is not None and job[0] == "quit") or os.getppid() != self.parent:
                break
            if not self._refresh():
                self.events.put(("dropped", f"robot {self.host}: RTDE connection lost; starting "
                                            f"fresh interfaces"))
                events_flush(self.events)
                os._exit(0)          # no ur-rtde disconnect: see the class docstring
            self.control.kickWatchdog()
            if job is None:
                continue
            if job[0] == "press":
                job = self._latest_press(job)
                if job is None:
                    break
                self._press(*job[1:])
            elif job[0] == "recover":
                self._recover()
        try:
            self.control.stopScript()        # no node, no program: as the watchdog would
        except Exception:
            pass
        for iface in (self.control, self.receive):
            try:
                iface.disconnect()
            except Exception:
                pass

    def _latest_press(self, job):
        """The newest press job waiting (older ones are refused: a late move is a wrong move);
        None when a quit was waiting too. A waiting recovery goes back on the queue."""
        others = []
        while True:
            try:
                newer = self.jobs.get_nowait()
            except queue.Empty:
                break
            if newer[0] == "press":
                self.events.put(("refused", f"period {job[1]}: superseded by period {newer[1]} "
                                            f"before the robot could apply it"))
                job = newer
            elif newer[0] == "quit":
                return None
            else:
                others.append(newer)
        for other in others:
            self.jobs.put(other)
        return job

    def _wait_playing(self, timeout_s: float) -> bool:
        """Waits until the receive interface reports the control script running; False after
        `timeout_s` (then the next refresh reports the stop)."""
        deadline = time.monotonic() + timeout_s
        while self.receive.getRuntimeState() != RUNTIME_PLAYING:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    def _refresh(self) -> bool:
        """Reads the robot's state (all of it from the receive interface); False on a drop."""
        try:
            if not self.receive.isConnected():
                return False
            pose = list(self.receive.getActualTCPPose())
            protective = self.receive.isProtectiveStopped()
            emergency = self.receive.isEmergencyStopped()
            running = self.receive.getRuntimeState() == RUNTIME_PLAYING
        except Exception:
            return False
        state = self.snapshot["state"]
        if protective or emergency or not running:
            if state != "stopped":
                why = ("EMERGENCY STOP" if emergency else "PROTECTIVE STOP" if protective
                       else "control script not running")
                self.events.put(("stopped", f"robot {self.host}: {why}: holding; inspect the "
                                            f"cause, then run `slip robot recover`"))
            state = "stopped"
        self.snapshot.update(state=state, tcp_pose=pose, protective_stop=protective,
                             emergency_stop=emergency, program_running=running)
        self.events.put(("snapshot", dict(self.snapshot)))
        return True

    def _press(self, period: int, target_kpa: float, measured_kpa: float) -> None:
        if self.snapshot["state"] != "ready":
            self.events.put(("refused", f"period {period}: robot {self.snapshot['state']}, "
                                        f"command not applied"))
            return
        depth, why = self.cfg.loop.next_depth_mm(self.depth_mm, target_kpa, measured_kpa)
        pose = list(self.start_pose)
        pose[self.cfg.press_axis] -= self.cfg.press_sign * depth / 1000.0
        if self.control.moveL(pose, self.cfg.speed_m_s, self.cfg.accel_m_s2):
            self.depth_mm = depth
            self._refresh()                      # the state published for this period is after the move
            self.events.put(("pressed", period, why))
        else:
            self._refresh()
            self.events.put(("refused", f"period {period}: moveL refused by the controller "
                                        f"(stop or script not running)"))

    def _recover(self) -> None:
        """The explicit recovery: unlock a protective stop, power on, re-upload the script."""
        if self.snapshot["emergency_stop"]:
            self.events.put(("recovery", False, "recovery refused: the emergency stop is engaged; "
                                                "release it on the pendant first"))
            return
        try:
            import dashboard_client
            dash = dashboard_client.DashboardClient(self.host)
            dash.connect()
            dash.closeSafetyPopup()
            if self.snapshot["protective_stop"]:
                dash.unlockProtectiveStop()
            dash.powerOn()
            dash.brakeRelease()
            dash.disconnect()
            self.control.reuploadScript()
            self._wait_playing(SCRIPT_START_S)
            self.control.setWatchdog(self.cfg.watchdog_hz)     # a stopped program lost it
        except Exception as exc:
            self.events.put(("recovery", False, f"recovery failed: {exc}"))
            return
        self.snapshot["state"] = "ready"         # the refresh says stopped again if it is not
        self._refresh()
        state = self.snapshot["state"]
        self.events.put(("recovery", state == "ready", f"recovery done; robot {state}"))


def events_flush(events) -> None:
    """Waits until what was put on a multiprocessing queue has reached the pipe."""
    events.close()
    events.join_thread()


class UR5(Node):
    """Applies the grip controller's F_N through the UR5's end-effector position."""

    INPUTS = {GripCommand.TOPIC: GripCommand, BiotacSlow.TOPIC: BiotacSlow,
              RobotRecover.TOPIC: RobotRecover}
    OPTIONAL_INPUTS = frozenset({RobotRecover.TOPIC})   # sent by `slip robot recover`, not by the launch
    OUTPUTS = {RobotState.TOPIC: RobotState}
    PARAMS = {
        "rig_config": Param("", help="config/rig.yaml: unset parameters from its ur5 section"),
        "robot_address": Param("192.168.1.5", help="the controller's IP address"),
        "rtde_hz": Param(125.0, lo=1.0, hi=500.0, help="RTDE rate (CB3 125, e-Series up to 500)"),
        "safety_limit_kpa": Param(control.SAFETY_LIMIT_KPA, lo=0.0, hi=100.0, help="never above this F_N"),
        "max_step_kpa": Param(control.DEFAULT_MAX_STEP_KPA, lo=1e-6, hi=100.0,
                              help="largest change of the target F_N from one period to the next, whatever a "
                                   "command asks (the grip law's own rate limit, kept here too; kPa)"),
        "gain_mm_per_kpa": Param(0.05, lo=0.0, hi=5.0, help="press depth per kPa of F_N error per period"),
        "max_step_mm": Param(0.5, lo=0.0, hi=5.0, help="largest move in one period"),
        "max_press_mm": Param(10.0, lo=0.0, hi=100.0, help="deepest below the start pose"),
        "max_lift_mm": Param(20.0, lo=0.0, hi=200.0, help="highest above the start pose"),
        "press_axis": Param("z", choices=("x", "y", "z"), help="base-frame axis the finger presses along"),
        "press_sign": Param(1.0, choices=(1.0, -1.0), help="1: pressing lowers the axis coordinate"),
        "speed_m_s": Param(0.01, lo=0.001, hi=0.25, help="moveL speed"),
        "accel_m_s2": Param(0.1, lo=0.01, hi=1.2, help="moveL acceleration"),
        "force_stale_s": Param(0.5, lo=0.01, hi=10.0, help="older P_DC than this: hold still"),
        "connect_timeout_s": Param(2.0, lo=0.1, hi=30.0, help="one connection attempt's timeout"),
        "startup_timeout_s": Param(0.0, lo=0.0, hi=600.0, help="keep trying to reach the robot this long at start"),
        "state_hz": Param(10.0, lo=0.1, hi=125.0, help="/robot/state rate besides each period"),
        "watchdog_hz": Param(1.0, lo=0.1, hi=50.0,
                             help="the control script stops when not kicked this often (node gone)"),
    }

    def __init__(self, **kwargs):
        super().__init__("ur5", **kwargs)
        apply_rig_config(self, "ur5", kwargs.get("params"))
        p = self.param
        if p("rig_config") and "gain_mm_per_kpa" not in (kwargs.get("params") or {}) and \
                "press_gain" not in calibration.load(p("rig_config")):
            self.warn(f"gain_mm_per_kpa is not calibrated: the default {p('gain_mm_per_kpa'):g} mm/kPa "
                      f"(slow); slip calibrate press-gain --config {p('rig_config')} measures it")
        loop = PressLoop(p("gain_mm_per_kpa"), p("max_step_mm"), p("safety_limit_kpa"),
                         p("max_press_mm"), p("max_lift_mm"))
        self.cfg = LinkConfig(p("robot_address"), p("rtde_hz"), p("speed_m_s"), p("accel_m_s2"),
                              loop, "xyz".index(p("press_axis")), p("press_sign"),
                              p("connect_timeout_s"), p("startup_timeout_s"), p("watchdog_hz"))
        if self.cfg.move_s() > 0.5 / self.cfg.watchdog_hz:       # a blocking moveL does not kick
            raise ParamError(f"node 'ur5': watchdog_hz:={p('watchdog_hz'):g} needs a kick every "
                             f"{1 / p('watchdog_hz'):g} s, but one move of max_step_mm at speed_m_s "
                             f"takes up to {self.cfg.move_s():.2f} s (more than half of it): lower "
                             f"watchdog_hz or max_step_mm, or raise speed_m_s")
        self.mp = multiprocessing.get_context("spawn")
        self.snapshot = {"state": "reconnecting", "tcp_pose": None, "protective_stop": False,
                         "emergency_stop": False, "program_running": False}
        self.start_pose, self.connected_once = None, False
        self.respawn_at, self.backoff_s = None, 0.5
        self.link = self.jobs = self.events = None
        self.measured_kpa = math.nan
        self.measured_at = -math.inf
        self.last_period = None     # the newest period a command arrived for
        self.applied_period = -1    # the newest period whose move the robot made
        self.missed_periods = 0     # periods with no command (superseded by a later one)
        self.target_kpa = None      # hold=True keeps it
        self.clamped = 0            # commands whose target was limited here (rate or safety limit)
        self.recoveries: list[bool] = []   # outcome of each explicit recovery
        self.refused = 0
        self.state_pub = self.create_publisher(RobotState)
        self.create_subscription(GripCommand, self.on_command)
        self.create_subscription(BiotacSlow, self.on_pdc)
        self.create_subscription(RobotRecover, self.on_recover)
        self.on_shutdown(self._close)
        self._spawn()
        self.create_timer(0.01, self.drain)
        self.create_timer(1.0 / p("state_hz"), self.publish_state)

    def on_pdc(self, msg: BiotacSlow):
        self.measured_kpa, self.measured_at = msg.pdc_kpa, time.monotonic()

    def on_command(self, msg: GripCommand):
        k, last = msg.period, self.last_period
        if k < 0 or (last is not None and k <= last):      # older or repeated: refused
            expected = "a period >= 0" if last is None else f"a period after {last}"
            return self.refuse(f"command for period {k}, expected {expected}")
        if last is not None and k > last + 1:               # a later period supersedes missing ones
            self.missed_periods += k - last - 1
            self.warn(f"no command for period(s) {last + 1}..{k - 1}; period {k} supersedes them "
                      f"({self.missed_periods} missed)", throttle_s=1.0, key="missed")
        self.last_period = k
        if self.respawn_at is not None:
            return self.refuse(f"period {k}: reconnecting to the robot; command not applied")
        if time.monotonic() - self.measured_at > self.param("force_stale_s"):
            return self.refuse(f"period {k}: no fresh F_N from {BiotacSlow.TOPIC}; holding still")
        if not msg.hold or self.target_kpa is None:
            base = self.measured_kpa if self.target_kpa is None else self.target_kpa
            self.target_kpa = control.applied_force(msg.normal_force_kpa, base, self.param("safety_limit_kpa"),
                                                    self.param("max_step_kpa"))
            if self.target_kpa != msg.normal_force_kpa:
                self.clamped += 1
                self.warn(f"GripCommand(period={k}) asked {msg.normal_force_kpa} kPa; target {self.target_kpa:.3f} "
                          f"kPa (safety limit {self.param('safety_limit_kpa')} kPa, at most "
                          f"{self.param('max_step_kpa')} kPa per period; {self.clamped} clamped)",
                          throttle_s=1.0, key="clamped")
        self.jobs.put(("press", k, self.target_kpa, self.measured_kpa))

    def on_recover(self, msg: RobotRecover):
        self.log(f"recovery requested{': ' + msg.note if msg.note else ''}")
        self.jobs.put(("recover",))

    def refuse(self, why: str):
        self.refused += 1
        self.warn(f"refused #{self.refused}: {why}", throttle_s=1.0, key="refused")

    def _spawn(self):
        """Starts a link process (again after a drop, with the start pose and depth kept)."""
        self.jobs, self.events = self.mp.Queue(), self.mp.Queue()
        self.link = self.mp.Process(target=link_main, name="ur5-link", daemon=True,
                                    args=(self.cfg, self.jobs, self.events, self.start_pose))
        self.link.start()
        self.respawn_at = None

    def drain(self):
        if self.respawn_at is not None:
            if time.monotonic() >= self.respawn_at:
                self._spawn()
            return
        while True:
            try:
                event = self.events.get_nowait()
            except queue.Empty:
                break
            self.on_event(event)
            if self.respawn_at is not None or self.stopping:
                return
        if not self.link.is_alive() and self.respawn_at is None:   # died without a word (a crash)
            self.on_event(("dropped", f"robot link process ended (exit {self.link.exitcode})"))

    def on_event(self, event):
        kind = event[0]
        if kind == "snapshot":
            self.snapshot = event[1]
        elif kind == "connected":
            self.connected_once, self.start_pose, self.backoff_s = True, event[2], 0.5
            self.log(event[1])
        elif kind == "fatal":
            self.log(f"ur5: {event[1]}")
            if not self.connected_once:
                self.shutdown("no usable robot", EXIT_NO_DEVICE)
            else:
                self._respawn_later()
        elif kind == "dropped":
            self.warn(event[1])
            self._respawn_later()
        elif kind == "pressed":
            if event[2]:
                self.warn(f"period {event[1]}: {event[2]}", throttle_s=5.0, key="limited")
            self.applied_period = max(self.applied_period, event[1])
            self.publish_state()
        elif kind == "recovery":
            self.recoveries.append(event[1])
            (self.log if event[1] else self.warn)(event[2])
            self.publish_state()
        elif kind == "refused":
            self.refuse(event[1])
        elif kind == "stopped":
            self.warn(event[1])
            self.publish_state()

    def _respawn_later(self):
        self.snapshot = dict(self.snapshot, state="reconnecting")
        self.publish_state()
        self.respawn_at = time.monotonic() + self.backoff_s
        self.backoff_s = min(self.backoff_s * 2, 8.0)

    def publish_state(self):
        snap = self.snapshot
        pose = snap["tcp_pose"]
        if pose is None:
            return
        force = self.measured_kpa if math.isfinite(self.measured_kpa) else 0.0
        self.state_pub.publish(RobotState(
            normal_force_kpa=force, tcp_z_mm=pose[2] * 1000.0,
            protective_stop=snap["protective_stop"], emergency_stop=snap["emergency_stop"],
            program_running=snap["program_running"], state=snap["state"],
            period=self.applied_period))

    def _close(self):
        if self.link is not None and self.link.is_alive():
            # the link stops the robot's script and disconnects ur-rtde cleanly; one still
            # connecting is terminated (its watchdog, once armed, stops the script then)
            self.jobs.put(("quit",))
            self.link.join(timeout=5.0)
            if self.link.is_alive():
                self.link.terminate()
                self.link.join(timeout=2.0)
        self.log(f"refused {self.refused} command(s); {self.missed_periods} period(s) had none")


def main(argv=None):
    return run_node(UR5, argv)


if __name__ == "__main__":
    raise SystemExit(main())
