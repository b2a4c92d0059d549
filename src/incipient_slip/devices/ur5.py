"""The UR5's ur-rtde side: the slow press loop on F_N, and the link process that owns ur-rtde's
`RTDEControlInterface` and `RTDEReceiveInterface` (the `[hardware]` extra), jobs in and events
out. The node (`nodes.ur5`) starts a link, sends it press and recovery jobs and reads its events;
`nodes.calibrate` reuses `explain` for its own connection errors.
"""
from __future__ import annotations

import math
import os
import queue
import socket
import time
from dataclasses import dataclass

from incipient_slip.devices.queues import waiting

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
        # lag it on a loaded host, and a stale "not running" would be taken for a stop. The
        # watchdog is armed now: the wait kicks it, or a lag longer than 1/watchdog_hz stops the
        # script it waits for
        self._wait_playing(SCRIPT_START_S, kick=True)
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
        for newer in waiting(self.jobs):
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

    def _wait_playing(self, timeout_s: float, kick: bool = False) -> bool:
        """Waits until the receive interface reports the control script running; False after
        `timeout_s` (then the next refresh reports the stop). `kick`: the script's watchdog is
        armed, kick it while waiting."""
        deadline = time.monotonic() + timeout_s
        while self.receive.getRuntimeState() != RUNTIME_PLAYING:
            if time.monotonic() >= deadline:
                return False
            if kick:
                self.control.kickWatchdog()
            time.sleep(0.01)
        return True

    def _refresh(self) -> bool:
        """Reads the robot's state (all of it from the receive interface); False on a drop."""
        try:
            # both: a kick on a control interface that lost its connection enters ur-rtde's
            # endless reconnect loop and never returns (the node then kills this process)
            if not (self.receive.isConnected() and self.control.isConnected()):
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
