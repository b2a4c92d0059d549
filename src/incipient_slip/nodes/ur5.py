"""ur5: the robot node. Sets the normal force F_N through the end-effector position, as the
paper does: each 500 ms period one moveL along the pressing axis, from a slow position loop
on the measured F_N (P_DC of /biotac/slow) towards the target of /grip/command.

    python -m incipient_slip.nodes.ur5 robot_address:=192.168.1.5

One process of its own (`devices.ur5.RobotLink`) owns ur-rtde's `RTDEControlInterface` and
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
interfaces in a fresh link process (state `reconnecting`, back-off from 0.5 s to 8 s), and so
does a connected link that has sent nothing for `link_silence_s` (ur-rtde's control interface,
kicked just as the connection drops, enters its own reconnect loop and never returns: the link is
killed; its watchdog kicks stopped with it, so the robot's script stops by itself); the
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
import time

from incipient_slip import control
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.devices import calibration
from incipient_slip.devices.queues import waiting
from incipient_slip.devices.rig_config import apply_rig_config
from incipient_slip.devices.ur5 import SCRIPT_START_S, LinkConfig, PressLoop, link_main
from incipient_slip.messages import BiotacSlow, GripCommand, RobotRecover, RobotState

EXIT_NO_DEVICE = 2


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
        "link_silence_s": Param(5.0, lo=0.5, hi=60.0,
                                help="a connected robot link that sends nothing this long, plus one move's "
                                     "time, is hung (in ur-rtde's reconnect loop): it is killed and a fresh "
                                     f"one started; a recovery is given {SCRIPT_START_S:g} s more"),
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
        self.link_connected, self.link_heard_at = False, -math.inf   # this link's "connected"; its last event
        self.recovering = False     # a recovery job sent, its outcome not yet heard
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
        self.recovering = True
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
        self.link_connected, self.recovering = False, False

    def drain(self):
        if self.respawn_at is not None:
            if time.monotonic() >= self.respawn_at:
                self._spawn()
            return
        for event in waiting(self.events):
            self.link_heard_at = time.monotonic()
            self.on_event(event)
            if self.respawn_at is not None or self.stopping:
                return
        if not self.link.is_alive() and self.respawn_at is None:   # died without a word (a crash)
            self.on_event(("dropped", f"robot link process ended (exit {self.link.exitcode})"))
        elif self.link_connected and (silent := time.monotonic() - self.link_heard_at) > self.silence_limit_s():
            self.link.kill()                     # hung in ur-rtde: no clean disconnect is possible
            self.link.join(timeout=2.0)
            self.on_event(("dropped", f"robot link silent for {silent:.1f} s (hung in ur-rtde's reconnect "
                                      f"loop); killed, starting a fresh one"))

    def silence_limit_s(self) -> float:
        """How long a connected link may send nothing: every loop of it sends the robot's state,
        one move blocks it up to `move_s`, a recovery waits up to SCRIPT_START_S for the script."""
        return self.param("link_silence_s") + self.cfg.move_s() + (SCRIPT_START_S if self.recovering else 0.0)

    def on_event(self, event):
        kind = event[0]
        if kind == "snapshot":
            self.snapshot = event[1]
        elif kind == "connected":
            self.connected_once, self.start_pose, self.backoff_s = True, event[2], 0.5
            self.link_connected = True
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
            self.recovering = False
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
