"""linear_actuator on the emulated Zaber stage: the paper's stepping protocol published as
period ticks, lock-step on grip commands, faults end the run with exit 3, a missing device is
exit 2 with one line."""
from __future__ import annotations

import os

import pytest
import serial

from incipient_slip.devices.zaber_emulator import ZaberEmulator
from incipient_slip.graph.runtime import Node
from incipient_slip.messages import ActuatorCommand, ActuatorState, BiotacStatus, GripCommand
from incipient_slip.nodes.linear_actuator import LinearActuator, step_target_mm
from waiting import spin_until

pytestmark = pytest.mark.timeout(60)


def test_paper_steps_are_23_mm_in_450_absolute_targets():
    assert step_target_mm(0, 0.0, 23.0, 450) == pytest.approx(23.0 / 450)
    assert step_target_mm(449, 2.0, 23.0, 450) == pytest.approx(25.0)


class Probe(Node):
    def __init__(self, graph_dir):
        super().__init__("probe", graph_dir=graph_dir, heartbeat_s=0)
        self.states: list[ActuatorState] = []
        self.create_subscription(ActuatorState, self.states.append)
        self.grip = self.create_publisher(GripCommand)
        self.actuator = self.create_publisher(ActuatorCommand)
        self.biotac = self.create_publisher(BiotacStatus)


def run(nodes, predicate, timeout_s=20.0):
    spin_until(lambda: [node.spin_once(0.002) for node in nodes], predicate, timeout_s)


@pytest.fixture
def rig(graph):
    made = []

    def start(emulator_kw=None, **params):
        emulator = ZaberEmulator(speed_mm_s=100.0, **(emulator_kw or {})).start()
        port = serial.Serial(emulator.port, 115200, timeout=0.02)
        probe = Probe(graph.dir)
        params = {"port": emulator.port, "microsteps_per_mm": emulator.microsteps_per_mm,
                  "travel_mm": 1.0, "steps": 5, "period_s": 0.05, "start_mm": 2.0, **params}
        node = LinearActuator(port=port, params=params, graph_dir=graph.dir, heartbeat_s=0)
        made.append((emulator, node, probe))
        run((node, probe), lambda: node.state_pub.subscriber_count() >= 1 or node.stopping)
        return emulator, node, probe

    yield start
    for emulator, node, probe in made:
        node.close()
        probe.close()
        emulator.stop()


def test_homes_then_steps_to_each_target_and_publishes_the_tick(rig):
    emulator, node, probe = rig()
    assert "home" in emulator.commands
    run((node, probe), lambda: len(probe.states) == 5)
    assert [s.period for s in probe.states] == [0, 1, 2, 3, 4]
    for k, state in enumerate(probe.states):
        assert state.position_mm == pytest.approx(2.0 + (k + 1) * 0.2, abs=1e-4)
    assert node.done and emulator.position_mm == pytest.approx(3.0, abs=1e-4)


def test_lockstep_waits_for_the_grip_command_of_the_last_period(rig):
    emulator, node, probe = rig(lockstep=True)
    run((node, probe), lambda: len(probe.states) == 1)
    deadline = node.steps_done                          # stays at 1 while period 0 is unanswered
    for _ in range(50):
        node.spin_once(0.005)
    assert node.steps_done == deadline == 1
    probe.grip.publish(GripCommand(normal_force_kpa=3.0, period=0))
    run((node, probe), lambda: len(probe.states) == 2)


def test_stall_mid_run_stops_the_stage_and_exits_3(rig):
    emulator, node, probe = rig()
    emulator.stall_at(2.5)
    run((node, probe), lambda: node.stopping)
    assert node.exit_code == 3 and node.failed
    assert [s.period for s in probe.states] == [0, 1]
    assert emulator.commands[-1] == "stop"


def test_reset_mid_run_is_a_fault(rig):
    emulator, node, probe = rig()
    run((node, probe), lambda: len(probe.states) >= 2)
    emulator.reset()
    run((node, probe), lambda: node.stopping)
    assert node.exit_code == 3


def test_target_outside_the_configured_travel_is_refused(rig):
    emulator, node, probe = rig(limit_max_mm=2.5)
    run((node, probe), lambda: node.stopping)
    assert node.exit_code == 3 and emulator.position_mm <= 2.5 + 1e-6


def test_a_configured_travel_beyond_the_device_s_limits_is_exit_2_before_any_move(rig):
    emulator, node, probe = rig(emulator_kw={"limit_max_mm": 2.5})      # node: limit_max_mm 50
    run((node, probe), lambda: node.stopping)
    assert node.exit_code == 2 and emulator.commands.count("home") == 0
    assert not any(c.startswith("move") for c in emulator.commands)


def test_a_resolution_other_than_the_configured_one_is_exit_2(rig):
    emulator, node, probe = rig(emulator_kw={"resolution": 128})
    run((node, probe), lambda: node.stopping)
    assert node.exit_code == 2 and not any(c.startswith("move") for c in emulator.commands)


def test_missing_port_is_exit_2_with_one_line(graph):
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.linear_actuator", "port:=/dev/ttyNOPE9"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert err.decode().strip().count("\n") == 0 and "/dev/ttyNOPE9" in err.decode()


def test_silent_device_is_exit_2_naming_the_port(graph):
    master, slave = os.openpty()             # a port where nothing answers
    try:
        path = os.ttyname(slave)
        proc = graph.spawn(["python", "-m", "incipient_slip.nodes.linear_actuator", f"port:={path}",
                            "reply_timeout_s:=0.1"])
        _, err = proc.communicate(timeout=30)
    finally:
        os.close(master)
        os.close(slave)
    assert proc.returncode == 2
    assert "no reply" in err.decode() and path in err.decode()


def test_without_readers_it_starts_after_the_wait_timeout(rig):
    emulator, node, probe = rig(wait_subscribers=5, wait_timeout_s=0.2)
    run((node, probe), lambda: node.done)
    assert node.steps_done == 5


def test_wait_tare_holds_step_0_until_the_biotac_reader_is_tared(rig):
    """No period on an untared P_DC: a status still collecting does not start it, 'done' does."""
    emulator, node, probe = rig(wait_tare=True, wait_timeout_s=60.0)
    run((node, probe), lambda: probe.biotac.subscriber_count() >= 1)
    probe.biotac.publish(BiotacStatus(tare_state="collecting"))
    for _ in range(100):                              # 0.2 s: four periods of 50 ms
        node.spin_once(0.002)
        probe.spin_once(0.0)
    assert node.steps_done == 0 and probe.states == []
    probe.biotac.publish(BiotacStatus(tare_state="done"))
    run((node, probe), lambda: len(probe.states) == 5)
    assert [s.period for s in probe.states] == [0, 1, 2, 3, 4]


def test_commanded_mode_goes_where_each_command_says_and_ticks_with_its_period(rig):
    emulator, node, probe = rig(mode="commanded", limit_max_mm=10.0)
    run((node, probe), lambda: node._started)
    for k, position in enumerate((1.5, 0.25, 3.0)):
        probe.actuator.publish(ActuatorCommand(position_mm=position, period=k))
        run((node, probe), lambda: len(probe.states) == k + 1)
        assert probe.states[-1].period == k
        assert probe.states[-1].position_mm == pytest.approx(2.0 + position, abs=1e-4)   # from start_mm
    # an older or repeated period is refused and counted; a target past the limit is clamped
    probe.actuator.publish(ActuatorCommand(position_mm=4.0, period=1))
    probe.actuator.publish(ActuatorCommand(position_mm=40.0, period=3))
    run((node, probe), lambda: len(probe.states) == 4)
    assert node.refused == 1 and probe.states[-1].position_mm == pytest.approx(10.0, abs=1e-4)
    assert emulator.position_mm == pytest.approx(10.0, abs=1e-4)


def test_commanded_mode_leaves_the_spring_slack_when_the_node_stops(rig):
    emulator, node, probe = rig(mode="commanded")
    run((node, probe), lambda: node._started)
    probe.actuator.publish(ActuatorCommand(position_mm=6.0, period=0))
    run((node, probe), lambda: len(probe.states) == 1)
    assert emulator.position_mm == pytest.approx(8.0, abs=1e-4)
    node.close()                                    # the shutdown hooks run: back to start_mm
    assert emulator.position_mm == pytest.approx(2.0, abs=1e-4)
