"""The UR5 path: the press loop (pure), ur-rtde's own interfaces against the fake controller,
and the ur5 node end to end: period checks, holds, stops that wait for an explicit recovery.
The fake controller runs as its own process (ur-rtde's constructors hold the GIL)."""
from __future__ import annotations

import json
import os
from pathlib import Path
import random
import signal
import subprocess
import contextlib
import sys
import time

import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.devices.ur5 import PressLoop, explain
from waiting import spin_until

pytestmark = pytest.mark.timeout(90)
LOOP = PressLoop(gain_mm_per_kpa=0.1, max_step_mm=0.5, safety_limit_kpa=6.0, max_press_mm=10.0, max_lift_mm=20.0)


def test_press_loop_moves_towards_the_target_force():
    assert LOOP.next_depth_mm(1.0, 4.0, 2.0) == (pytest.approx(1.2), "")
    assert LOOP.next_depth_mm(1.0, 2.0, 4.0) == (pytest.approx(0.8), "")


def test_press_loop_clamps_the_target_to_the_safety_limit_and_retracts_above_it():
    assert LOOP.next_depth_mm(1.0, 50.0, 5.9)[0] == pytest.approx(1.01)     # target clamped at 6.0
    depth, why = LOOP.next_depth_mm(1.0, 3.0, 6.5)
    assert depth == pytest.approx(0.5) and "safety limit" in why


@settings(max_examples=300, deadline=None)
@given(st.floats(-30, 30), st.floats(0, 100), st.floats(-5, 100))
def test_press_loop_never_leaves_its_workspace_or_exceeds_one_step(depth, target, measured):
    new, _ = LOOP.next_depth_mm(depth, target, measured)
    assert -20.0 <= new <= 10.0
    if -20.0 <= depth <= 10.0:
        assert abs(new - depth) <= 0.5 + 1e-9


def test_connect_errors_name_the_fix():
    assert "Fieldbus" in explain(RuntimeError("One of the RTDE input registers are already in use!"), "h")
    assert "Remote Control" in explain(RuntimeError("ur_rtde: Please enable remote control on the robot!"), "h")


def test_a_receive_interface_that_lags_the_control_interface_is_not_taken_for_a_stop(monkeypatch):
    """The control interface returns once the script runs; the receive interface's data may
    still say "not running" for a while on a loaded host (make test-load: the robot fixture's
    node latched "stopped" at connect). The link waits for the receive side to see it run."""

    from incipient_slip.devices import ur5

    class Receive:
        def __init__(self, *args):
            self.stale = 5                  # five reads of the state before the script started

        def getRuntimeState(self):
            self.stale -= 1
            return ur5.RUNTIME_PLAYING if self.stale < 0 else 1

        def getActualTCPPose(self):
            return [0.4, 0.0, 0.3, 0.0, 0.0, 0.0]

        def isConnected(self):
            return True

        def isProtectiveStopped(self):
            return False

        def isEmergencyStopped(self):
            return False

    class Control:
        def __init__(self, *args):
            pass

        def setWatchdog(self, hz):
            return True

        def kickWatchdog(self):
            return True

        def isConnected(self):
            return True

    with _link_on_fakes(monkeypatch, Receive, Control) as link:
        link._connect_once()
        assert link._refresh() and link.snapshot["state"] == "ready"


def test_the_watchdog_is_kicked_while_the_link_waits_for_the_receive_side_to_see_the_script(monkeypatch):
    """The watchdog is armed before the wait for the receive interface's "running": a wait longer
    than 1/watchdog_hz without a kick stopped the script it waited for (make test-load: the
    robot fixture's node connected, then found "control script not running" and refused every
    command). So every step of the wait kicks it: no two reads of the state without a kick."""

    from incipient_slip.devices import ur5

    log = []

    class Receive:
        def __init__(self, *args):
            self.stale = 20                 # twenty reads (10 ms apart) before the script runs

        def getRuntimeState(self):
            log.append("read")
            self.stale -= 1
            return ur5.RUNTIME_PLAYING if self.stale < 0 else 1

        def getActualTCPPose(self):
            return [0.4, 0.0, 0.3, 0.0, 0.0, 0.0]

    class Control:
        def __init__(self, *args):
            pass

        def setWatchdog(self, hz):
            log.append("armed")
            return True

        def kickWatchdog(self):
            log.append("kick")
            return True

    with _link_on_fakes(monkeypatch, Receive, Control) as link:
        link._connect_once()
    assert log[0] == "armed" and log.count("read") == 21
    assert "read read" not in " ".join(log), log


@contextlib.contextmanager
def _link_on_fakes(monkeypatch, receive, control):
    """A RobotLink whose ur-rtde interfaces are `receive` and `control`, its RTDE port a local
    listening socket (the reachability check passes), closed at the end."""
    import socket
    import types

    from incipient_slip.devices import ur5
    monkeypatch.setitem(sys.modules, "rtde_receive", types.SimpleNamespace(RTDEReceiveInterface=receive))
    monkeypatch.setitem(sys.modules, "rtde_control", types.SimpleNamespace(RTDEControlInterface=control))
    server = socket.create_server(("127.0.0.1", 0))
    monkeypatch.setattr(ur5, "RTDE_PORT", server.getsockname()[1])
    cfg = ur5.LinkConfig("127.0.0.1", 125.0, 0.01, 0.1, LOOP, 2, 1.0, 2.0)
    try:
        yield ur5.RobotLink(cfg, None, __import__("queue").Queue(), None)
    finally:
        server.close()


# --- against the fake controller -------------------------------------------------------------

rtde_control = pytest.importorskip("rtde_control", reason="ur-rtde has no wheel for this Python (CPython 3.10-3.12, x86-64 Linux)")
rtde_receive = pytest.importorskip("rtde_receive", reason="ur-rtde has no wheel for this Python")


class Fake:
    """The fake controller process on its own loopback address, driven through stdin."""

    def __init__(self, *extra):
        for _ in range(20):
            self.address = f"127.0.{random.randint(1, 254)}.{random.randint(2, 254)}"
            self.proc = subprocess.Popen([sys.executable, "-m", "incipient_slip.devices.fake_ur",
                                          "--address", self.address, *extra],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            line = self.proc.stdout.readline()
            if line.startswith("{"):
                return
            self.proc.wait()
        raise RuntimeError("no free loopback address for the fake controller")

    def __call__(self, control: str) -> dict:
        self.proc.stdin.write(control + "\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def close(self):
        if self.proc.poll() is None:
            self.proc.stdin.close()
            self.proc.wait(timeout=10)


@pytest.fixture
def fake():
    made = []

    def start(*extra):
        made.append(Fake(*extra))
        return made[-1]

    yield start
    for f in made:
        f.close()


def test_ur_rtde_moves_the_fake_tcp_and_sees_a_protective_stop(fake):
    ur = fake()
    receive = rtde_receive.RTDEReceiveInterface(ur.address, 125.0, ["timestamp", "actual_TCP_pose",
                                                                     "safety_status_bits", "runtime_state"])
    control = rtde_control.RTDEControlInterface(ur.address, 125.0)
    try:
        assert control.isProgramRunning()
        pose = receive.getActualTCPPose()
        pose[2] -= 0.002
        assert control.moveL(pose, 0.05, 0.5) is True
        assert ur("state")["tcp_pose"][2] == pytest.approx(pose[2], abs=1e-6)
        ur("protective_stop")
        while not receive.isProtectiveStopped():
            time.sleep(0.005)
        assert control.moveL(pose, 0.05, 0.5) is False
        assert not control.isProgramRunning()
    finally:
        control.disconnect()
        receive.disconnect()


def test_in_use_registers_raise_at_connect(fake):
    ur = fake()
    ur("in_use 1")
    with pytest.raises(RuntimeError, match="in use"):
        rtde_control.RTDEControlInterface(ur.address, 125.0)


def test_remote_control_off_raises_at_connect(fake):
    ur = fake("--no-remote-control")
    with pytest.raises(RuntimeError, match="remote control"):
        rtde_control.RTDEControlInterface(ur.address, 125.0)


# --- the ur5 node ------------------------------------------------------------------------------

from incipient_slip.graph.runtime import Node                          # noqa: E402
from incipient_slip.messages import BiotacSlow, GripCommand, RobotRecover, RobotState  # noqa: E402
from incipient_slip.nodes.ur5 import UR5                               # noqa: E402
import numpy as np                                                     # noqa: E402


class Probe(Node):
    def __init__(self, graph_dir):
        super().__init__("probe", graph_dir=graph_dir, heartbeat_s=0)
        self.states: list[RobotState] = []
        self.create_subscription(RobotState, self.states.append)
        self.grip = self.create_publisher(GripCommand)
        self.pdc = self.create_publisher(BiotacSlow)
        self.recover = self.create_publisher(RobotRecover)

    def force(self, kpa: float):
        self.pdc.publish(BiotacSlow(electrode_counts=np.zeros(19, np.uint16), pdc_counts=2000 + round(kpa * 1000 / 36.5),
                                    pdc_tare_counts=2000))


def run(nodes, predicate, timeout_s=60.0):        # a hang guard (inside the test's timeout)
    spin_until(lambda: [node.spin_once(0.002) for node in nodes], predicate, timeout_s)


@pytest.fixture
def robot(fake, graph):
    made = []

    def start(**params):
        ur = fake()
        node = UR5(params={"robot_address": ur.address, "gain_mm_per_kpa": 0.1, **params},
                   graph_dir=graph.dir, heartbeat_s=0)
        probe = Probe(graph.dir)
        made.append((node, probe))
        nodes = (node, probe)
        run(nodes, lambda: probe.grip.subscriber_count() >= 1 and probe.pdc.subscriber_count() >= 1
            and probe.recover.subscriber_count() >= 1 and any(s.state == "ready" for s in probe.states))
        return ur, node, probe, nodes

    yield start
    for node, probe in made:
        node.close()
        probe.close()


def test_each_period_presses_towards_the_target_and_reports_it(robot):
    ur, node, probe, nodes = robot(max_step_kpa=6.0)        # the press loop alone, not the rate limit
    z0 = ur("state")["tcp_pose"][2]
    probe.force(2.0)
    run(nodes, lambda: math_isfinite(node.measured_kpa))
    probe.grip.publish(GripCommand(normal_force_kpa=4.0, period=0))
    run(nodes, lambda: any(s.period == 0 for s in probe.states))
    assert ur("state")["tcp_pose"][2] == pytest.approx(z0 - 0.0002, abs=1e-6)   # 0.1 mm/kPa x 2 kPa
    state = next(s for s in probe.states if s.period == 0)
    # the measured TCP, read a few RTDE packages (8 ms each) after the move ended
    assert state.state == "ready" and state.tcp_z_mm == pytest.approx((z0 - 0.0002) * 1000, abs=0.05)


def test_a_forged_99_kpa_command_moves_the_target_by_the_rate_limit_only(robot):
    """The node that moves the finger limits the force on its own: 0.5 kPa per period from the
    measured F_N, then from its last target, never past the safety limit, whatever is asked."""
    ur, node, probe, nodes = robot()
    z0 = ur("state")["tcp_pose"][2]
    probe.force(2.0)
    run(nodes, lambda: math_isfinite(node.measured_kpa))
    probe.grip.publish(GripCommand(normal_force_kpa=99.0, period=0))
    run(nodes, lambda: any(s.period == 0 for s in probe.states))
    assert node.target_kpa == pytest.approx(node.measured_kpa + 0.5) and node.clamped == 1   # P_DC: 2.0075
    assert ur("state")["tcp_pose"][2] == pytest.approx(z0 - 0.00005, abs=1e-6)   # 0.1 mm/kPa x 0.5 kPa
    for k in range(1, 12):
        probe.force(2.0)
        probe.grip.publish(GripCommand(normal_force_kpa=99.0, period=k))
        run(nodes, lambda: any(s.period == k for s in probe.states))
    assert node.target_kpa == 6.0 and node.clamped == 12                       # capped at the safety limit


def test_protective_stop_holds_until_an_explicit_recovery(robot):
    ur, node, probe, nodes = robot()
    probe.force(3.0)
    run(nodes, lambda: math_isfinite(node.measured_kpa))
    ur("protective_stop")
    run(nodes, lambda: any(s.state == "stopped" and s.protective_stop for s in probe.states))
    probe.grip.publish(GripCommand(normal_force_kpa=4.0, period=0))
    probe.force(3.0)
    run(nodes, lambda: node.refused == 1)        # the link refuses it: stopped
    assert 3 not in ur("state")["commands"] and ur("state")["protective_stop"]
    probe.recover.publish(RobotRecover(note="test"))
    run(nodes, lambda: node.recoveries == [True])
    run(nodes, lambda: probe.states[-1].state == "ready")     # the probe reads it a spin later
    assert not ur("state")["protective_stop"] and ur("state")["scripts"] == 2
    probe.force(3.0)
    probe.grip.publish(GripCommand(normal_force_kpa=4.0, period=1))
    run(nodes, lambda: any(s.period == 1 for s in probe.states))


def test_no_controller_is_exit_2_naming_the_address(graph):
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.ur5", "robot_address:=127.0.0.1",
                        "connect_timeout_s:=0.5"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and "no UR controller at 127.0.0.1:30004" in err.decode()


def test_in_use_registers_are_exit_2_naming_the_fieldbus_fix(fake, graph):
    ur = fake()
    ur("in_use 1")
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.ur5", f"robot_address:={ur.address}"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and "Fieldbus" in err.decode()


def math_isfinite(x):
    return x == x and abs(x) != float("inf")


def test_emergency_stop_refuses_recovery_until_released(robot):
    ur, node, probe, nodes = robot()
    ur("emergency_stop")
    run(nodes, lambda: any(s.state == "stopped" and s.emergency_stop for s in probe.states))
    probe.recover.publish(RobotRecover())
    run(nodes, lambda: node.recoveries == [False])
    assert probe.states[-1].state == "stopped" and ur("state")["scripts"] == 1
    ur("release_emergency_stop")
    run(nodes, lambda: not probe.states[-1].emergency_stop)
    probe.recover.publish(RobotRecover())
    run(nodes, lambda: node.recoveries == [False, True])
    run(nodes, lambda: probe.states[-1].state == "ready")
    assert ur("state")["powered"] and ur("state")["scripts"] == 2


def test_stopped_program_is_a_stop(robot):
    ur, node, probe, nodes = robot()
    ur("stop_program")
    run(nodes, lambda: any(s.state == "stopped" and not s.program_running for s in probe.states))


def test_dropped_connection_is_recovered_and_the_next_period_applies(robot):
    ur, node, probe, nodes = robot()
    ur("drop_connections")
    run(nodes, lambda: any(s.state == "reconnecting" for s in probe.states))
    run(nodes, lambda: probe.states[-1].state == "ready")
    # a fresh F_N measurement arrived (an event, not a 0.1 s window a loaded machine can miss)
    t0 = time.monotonic()
    probe.force(3.0)
    run(nodes, lambda: node.measured_at >= t0)
    probe.grip.publish(GripCommand(normal_force_kpa=4.0, period=0))
    run(nodes, lambda: any(s.period == 0 for s in probe.states))
    assert ur("state")["commands"][-1] == 3


def test_a_hung_link_is_killed_and_replaced(robot):
    """ur-rtde's control interface, kicked just as the connection drops, reconnects in a loop of
    its own and never returns (make test-load: "reconnecting" never came in 60 s). A link that
    sends nothing for link_silence_s is hung: the node kills it and starts a fresh one. SIGSTOP
    is the hang here; before, the node waited on it for ever."""
    ur, node, probe, nodes = robot(link_silence_s=1.0)
    link = node.link
    os.kill(link.pid, signal.SIGSTOP)
    try:
        run(nodes, lambda: any(s.state == "reconnecting" for s in probe.states))
        assert not link.is_alive() and link.exitcode == -signal.SIGKILL
        run(nodes, lambda: node.link is not link and probe.states[-1].state == "ready")
    finally:
        if link.is_alive():
            os.kill(link.pid, signal.SIGKILL)
    probe.force(3.0)
    t0 = time.monotonic()
    run(nodes, lambda: node.measured_at >= t0)
    probe.grip.publish(GripCommand(normal_force_kpa=3.5, period=0))
    run(nodes, lambda: any(s.period == 0 for s in probe.states))


def test_slip_robot_recover_brings_a_protective_stop_back_to_ready(robot, graph):
    ur, node, probe, nodes = robot()
    ur("protective_stop")
    run(nodes, lambda: probe.states[-1].state == "stopped")
    cli = graph.spawn([str(Path(sys.executable).parent / "slip"), "robot", "recover", "--note", "cleared"])
    run(nodes, lambda: cli.poll() is not None, timeout_s=30)
    out, err = cli.communicate()
    assert cli.returncode == 0, err.decode()
    assert "robot ready" in out.decode() and node.recoveries == [True]


def test_commands_that_queue_behind_a_move_are_superseded_by_the_newest(robot):
    ur, node, probe, nodes = robot()
    probe.force(3.0)
    run(nodes, lambda: math_isfinite(node.measured_kpa))
    for k in range(3):
        probe.grip.publish(GripCommand(normal_force_kpa=4.0, period=k))
    run(nodes, lambda: any(s.period == 2 for s in probe.states))
    moves = ur("state")["commands"].count(3)
    assert moves + node.refused == 3 and node.refused >= 1      # no command applied late


# --- restarts, periods, the state's period, the watchdog (issue 20) ----------------------------

def press(nodes, probe, node, period, target_kpa, measured_kpa):
    """One period: a fresh F_N, the command, and the wait for the state that reports it."""
    probe.force(measured_kpa)
    run(nodes, lambda: node.measured_kpa == pytest.approx(measured_kpa, abs=0.05)
        and time.monotonic() - node.measured_at < 0.2)
    probe.grip.publish(GripCommand(normal_force_kpa=target_kpa, period=period))
    run(nodes, lambda: any(s.period == period for s in probe.states))


def test_a_restarted_link_takes_the_depth_from_the_robot_and_keeps_the_step_limit(robot):
    ur, node, probe, nodes = robot(max_step_mm=0.5, max_step_kpa=6.0)    # the mm step limit alone
    z0 = ur("state")["tcp_pose"][2]
    for k in range(4):                                    # 4 clamped steps: 2 mm deep
        press(nodes, probe, node, k, 5.0, 0.0)
    z_pressed = ur("state")["tcp_pose"][2]
    assert z0 - z_pressed == pytest.approx(0.002, abs=2e-6)
    link = node.link
    os.kill(link.pid, signal.SIGKILL)                    # the link crashes without a word
    run(nodes, lambda: not link.is_alive() and node.link is not link
        and probe.states[-1].state == "ready" and node.respawn_at is None)
    press(nodes, probe, node, 4, 0.0, 3.0)                # lift: 0.1 mm/kPa x 3 kPa = 0.3 mm
    step_mm = (ur("state")["tcp_pose"][2] - z_pressed) * 1000.0
    assert step_mm == pytest.approx(0.3, abs=0.01)        # was 2.3 mm with a remembered depth of 0


def test_a_later_period_supersedes_missing_ones_an_older_or_repeated_one_is_refused(robot):
    ur, node, probe, nodes = robot()
    press(nodes, probe, node, 0, 3.5, 3.0)
    press(nodes, probe, node, 3, 3.5, 3.0)               # periods 1 and 2 never came
    assert node.missed_periods == 2 and node.refused == 0
    for old in (3, 2, 0):                                 # repeated, reordered, older
        probe.grip.publish(GripCommand(normal_force_kpa=3.5, period=old))
    run(nodes, lambda: node.refused == 3)
    press(nodes, probe, node, 4, 3.5, 3.0)
    press(nodes, probe, node, 10, 3.5, 3.0)
    assert node.refused == 3 and node.missed_periods == 2 + 5
    assert ur("state")["commands"].count(3) == 4          # moves of periods 0, 3, 4 and 10


def test_regular_states_carry_the_last_applied_period(robot):
    ur, node, probe, nodes = robot()
    assert {s.period for s in probe.states} == {-1}       # no command applied yet
    press(nodes, probe, node, 0, 3.5, 3.0)
    seen = len(probe.states)
    run(nodes, lambda: len(probe.states) >= seen + 3)     # timer states after the move
    assert [s.period for s in probe.states[seen:]] == [0] * (len(probe.states) - seen)


def test_the_fake_controllers_watchdog_stops_the_program_unless_kicked(fake):
    ur = fake()
    control = rtde_control.RTDEControlInterface(ur.address, 125.0)
    try:
        assert control.setWatchdog(1.0)                  # 1 s, as the node's default
        deadline = time.monotonic() + 2.5
        while time.monotonic() < deadline:               # kicked: keeps running
            assert control.kickWatchdog()
            time.sleep(0.02)
        assert ur("state")["program_running"]
        run_until(lambda: not ur("state")["program_running"], 10.0)   # not kicked: stops
        assert ur("state")["stats"]["watchdog_stops"] == 1
    finally:
        control.disconnect()


def run_until(predicate, timeout_s):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def ur5_process(graph, ur, *params):
    """A ur5 node process, returned once it says it is connected (its link armed the watchdog)."""
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.ur5", f"robot_address:={ur.address}", *params])
    for line in iter(proc.stderr.readline, b""):
        if b"] connected to" in line:
            break
    assert proc.poll() is None, proc.communicate()[1].decode()
    assert 35 in ur("state")["commands"]
    return proc


def test_a_killed_node_and_link_leave_the_robot_program_stopped_by_its_watchdog(fake, graph):
    ur = fake()
    proc = ur5_process(graph, ur, "watchdog_hz:=2")
    assert ur("state")["program_running"]
    os.killpg(proc.pid, signal.SIGKILL)                  # as a host that loses power: no goodbye
    proc.wait()
    killed = time.monotonic()
    run_until(lambda: not ur("state")["program_running"], 10.0)
    stopped_after_s = time.monotonic() - killed
    state = ur("state")
    assert state["stats"]["watchdog_stops"] == 1 and 255 not in state["commands"]
    assert stopped_after_s < 0.5 + 2.0                    # 1/watchdog_hz, and slack for a loaded host


def test_a_stopped_node_stops_the_robot_program(fake, graph):
    ur = fake()
    proc = ur5_process(graph, ur)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=30)
    state = ur("state")
    assert not state["program_running"] and state["commands"][-1] == 255
    assert state["stats"].get("watchdog_stops", 0) == 0


def test_a_watchdog_shorter_than_one_move_is_refused(graph):
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.ur5", "robot_address:=127.0.0.1",
                        "speed_m_s:=0.001", "watchdog_hz:=1"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and "watchdog_hz:=1 needs a kick every 1 s" in err.decode()
