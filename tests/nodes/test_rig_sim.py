"""The rig_sim node as a real process: the same seed and F_N sequence give byte-identical data
through the node and through the in-process `Rig.step_period` loop; lock-step, real time,
scenes and faults."""
from __future__ import annotations

import signal
import time

import numpy as np
import pytest

from incipient_slip import control
from incipient_slip.messages import (
    ActuatorState, BiotacPac, BiotacSlow, GripCommand, ObjectPose, PztCommand, PztState, RobotState, SimTruth,
)
from incipient_slip.nodes.rig_sim import RigSim, pac_frame_stamps_ns, slow_frame_stamps_ns
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.sim.dataset import simulate_series
from incipient_slip.sim.rig import Rig, load_scene
from waiting import handshake, spin_until

RECORDED = (BiotacPac, BiotacSlow, ObjectPose, RobotState, ActuatorState, PztState, SimTruth)


class Controller(Node):
    """Records every rig topic and answers each tick k with GripCommand(period=k)."""

    def __init__(self, graph_dir, answer=None):
        super().__init__("test_controller", graph_dir=graph_dir, heartbeat_s=0)
        self.answer = answer                  # k -> GripCommand or None (no answer)
        self.got = {t: [] for t in RECORDED}
        self.subs = {t: self.create_subscription(t, self.got[t].append) for t in RECORDED
                     if t is not ActuatorState}
        self.subs[ActuatorState] = self.create_subscription(ActuatorState, self.on_tick)
        self.grip = self.create_publisher(GripCommand)
        self.pzt = self.create_publisher(PztCommand)

    def on_tick(self, msg):
        self.got[ActuatorState].append(msg)
        if self.answer is not None:
            self.answer(self, msg.period)

    def ticks(self):
        return len(self.got[ActuatorState])

    def spin_until(self, predicate, timeout_s=20.0, proc=None):
        spin_until(lambda: self.spin_once(0.02), predicate, timeout_s, [proc] if proc else (), "rig_sim")


def start_rig(graph, **params):
    argv = ["python", "-m", "incipient_slip.nodes.rig_sim"] + [f"{k}:={v}" for k, v in params.items()]
    return graph.spawn(argv)


def connect(ctl, proc, pub):
    """Waits until rig_sim subscribed to `pub` (it waits for us on its own topics)."""
    handshake(pub, 20, [proc], "rig_sim subscribed")


def stop(proc):
    proc.terminate()
    assert proc.wait(10) == 128 + signal.SIGTERM      # stopped cleanly, by a signal
    return proc.stderr.read().decode()


def streams_of(got):
    """The node's messages as arrays, in the layout of the in-process outputs."""
    pac, slow, pose = got[BiotacPac], got[BiotacSlow], got[ObjectPose]
    for msgs in (pac, slow, pose):
        assert [m.seq for m in msgs] == list(range(len(msgs))), "lost or reordered messages"
    return {
        "pac_counts": np.concatenate([m.pac_counts for m in pac]),
        "pac_stamps": np.array([m.stamp_ns for m in pac]),
        "electrode_counts": np.stack([m.electrode_counts for m in slow]),
        "pdc_counts": np.array([m.pdc_counts for m in slow], dtype=np.uint16),
        "tac_counts": np.array([m.tac_counts for m in slow], dtype=np.uint16),
        "tdc_counts": np.array([m.tdc_counts for m in slow], dtype=np.uint16),
        "slow_stamps": np.array([m.stamp_ns for m in slow]),
        "mocap_y_mm": np.array([m.position_mm[1] for m in pose]),
        "mocap_stamps": np.array([m.stamp_ns for m in pose]),
    }


def assert_same_sensor_data(node: dict, ref: dict, steps: int):
    for key in ("pac_counts", "electrode_counts", "pdc_counts", "tac_counts", "tdc_counts", "mocap_y_mm"):
        assert node[key].dtype == ref[key].dtype, key
        assert node[key].tobytes() == ref[key].tobytes(), f"{key} differs"
    assert np.array_equal(node["pac_stamps"], np.concatenate([pac_frame_stamps_ns(k) for k in range(steps)]))
    assert np.array_equal(node["slow_stamps"],
                          np.maximum(np.concatenate([slow_frame_stamps_ns(k) for k in range(steps)]), 1))
    assert np.array_equal(node["mocap_stamps"], np.maximum(np.round(ref["mocap_t_s"] * 1e9).astype(np.int64), 1))


def concat_outputs(outs):
    return {key: np.concatenate([getattr(o, key) for o in outs])
            for key in ("pac_counts", "electrode_counts", "pdc_counts", "tac_counts", "tdc_counts",
                        "mocap_t_s", "mocap_y_mm")}


@pytest.mark.timeout(60)
def test_node_and_in_process_loop_give_identical_data_for_the_same_seed(graph):
    steps, seed, material = 30, 11, "abs"
    commands = {k: GripCommand(normal_force_kpa=round(2.0 + 0.13 * k, 2), period=k) for k in range(steps)}
    commands[7] = GripCommand(normal_force_kpa=9.9, hold=True, period=7)    # hold keeps the force
    pzt_off_after = 12                                                     # PZT off from period 13

    def answer(ctl, k):
        if k == pzt_off_after:
            ctl.pzt.publish(PztCommand(enabled=False))    # same socket: arrives before the command
        ctl.grip.publish(commands[k])

    proc = start_rig(graph, scene="paper", material=material, seed=seed, steps=steps,
                     normal_force_kpa=3.5, max_step_kpa=6.0)   # the schedule jumps: the rig is the plant
    ctl = Controller(graph.dir, answer)
    connect(ctl, proc, ctl.grip)
    connect(ctl, proc, ctl.pzt)
    ctl.spin_until(lambda: ctl.ticks() == steps, proc=proc)
    ctl.spin_until(lambda: len(ctl.got[PztState]) == 2, proc=proc)
    log = stop(proc)                      # idles after the last period until SIGTERM, exits 0

    # the in-process driver: the same Rig and the same F_N / PZT sequence
    rig = Rig(load_scene("paper"), material, seed)
    force, outs = 3.5, []
    for k in range(steps):
        outs.append(rig.step_period(force))
        if k == pzt_off_after:
            rig.set_injection(False, 0.0)
        force = force if commands[k].hold else commands[k].normal_force_kpa
    ref = concat_outputs(outs)

    assert_same_sensor_data(streams_of(ctl.got), ref, steps)
    assert [m.normal_force_kpa for m in ctl.got[RobotState]] == [o.normal_force_kpa for o in outs]
    # the period of the last command applied: none before period 0, then the one before each
    assert [m.period for m in ctl.got[RobotState]] == [-1] + list(range(steps - 1))
    assert outs[8].normal_force_kpa == outs[7].normal_force_kpa          # the hold
    ticks = ctl.got[ActuatorState]
    assert [m.period for m in ticks] == list(range(steps))
    # the stage after the period's step (as the Zaber node reads it back): where the next period runs
    assert [m.position_mm for m in ticks][:-1] == [o.actuator_mm for o in outs[1:]]
    assert ticks[-1].position_mm > outs[-1].actuator_mm
    assert [m.stamp_ns for m in ticks] == [(k + 1) * 500_000_000 for k in range(steps)]
    truth = ctl.got[SimTruth]            # the simulator's truth of each period, before its tick
    assert [(m.period, m.stamp_ns) for m in truth] == [(k, (k + 1) * 500_000_000) for k in range(steps)]
    assert [(m.stick_ratio, m.stick_area_ratio, m.tangential_force_n, m.gross_slip) for m in truth] == [
        (o.load_ratio_stick, o.stick_area_ratio, o.tangential_force_n, o.gross_slip) for o in outs]
    assert [m.enabled for m in ctl.got[PztState]] == [True, False]
    assert not outs[pzt_off_after + 1].pzt_on and outs[pzt_off_after].pzt_on
    assert all(sub.gaps == 0 and sub.dropped == 0 for sub in ctl.subs.values())
    assert "ms CPU" in log and "per period" in log
    ctl.close()


@pytest.mark.timeout(60)
def test_collection_protocol_reproduces_the_data_set_series(graph):
    steps, seed = 20, 5

    def go_ahead(ctl, k):                 # in collection the command is only the go-ahead
        ctl.grip.publish(GripCommand(normal_force_kpa=0.5, period=k))

    proc = start_rig(graph, scene="paper", material="pla", seed=seed, steps=steps,
                     protocol="collection", exit_when_done="true")
    ctl = Controller(graph.dir, go_ahead)
    connect(ctl, proc, ctl.grip)
    ctl.spin_until(lambda: ctl.ticks() == steps, proc=proc)
    assert proc.wait(10) == 0             # exit_when_done
    ref = simulate_series(load_scene("paper"), "pla", seed, steps)
    assert_same_sensor_data(streams_of(ctl.got), ref, steps)
    assert np.array_equal([m.normal_force_kpa for m in ctl.got[RobotState]], ref["normal_force_kpa"])
    ctl.close()


def test_lockstep_applies_only_the_awaited_period_and_clamps_to_the_safety_limit(graph):
    proc = start_rig(graph, scene="mechanics", steps=5, normal_force_kpa=2.5, max_step_kpa=6.0)
    ctl = Controller(graph.dir)
    connect(ctl, proc, ctl.grip)
    ctl.spin_until(lambda: ctl.ticks() == 1, proc=proc)
    t = time.monotonic()
    while time.monotonic() - t < 0.3:     # nothing of period 1 before the answer to period 0
        ctl.spin_once(0.02)
    assert ctl.ticks() == 1 and len(ctl.got[RobotState]) == 1
    ctl.grip.publish(GripCommand(normal_force_kpa=4.2, period=3))     # a future period: refused
    ctl.grip.publish(GripCommand(normal_force_kpa=4.4, period=0))
    ctl.spin_until(lambda: ctl.ticks() == 2, proc=proc)
    ctl.grip.publish(GripCommand(normal_force_kpa=1.5, period=0))     # answered already: refused
    ctl.grip.publish(GripCommand(normal_force_kpa=99.0, period=1))    # valid on the wire, unsafe
    ctl.spin_until(lambda: ctl.ticks() == 3, proc=proc)
    assert [m.normal_force_kpa for m in ctl.got[RobotState]] == [2.5, 4.4, control.SAFETY_LIMIT_KPA]
    assert [m.stamp_ns for m in ctl.got[RobotState]] == [1, 500_000_000, 1_000_000_000]
    err = stop(proc)
    assert "refused GripCommand(period=3)" in err         # the repeat of period 0 is throttled
    assert "asked 99.0 kPa; applying 6.0 kPa" in err
    ctl.close()


def test_a_forged_command_moves_the_applied_force_at_most_one_rate_step_per_period(graph):
    # the grip law's rate limit (0.5 kPa per period) is kept where the force is applied: a command
    # of 99 kPa, valid on the wire, moves F_N by one step, then the next by one more
    proc = start_rig(graph, scene="mechanics", steps=5, normal_force_kpa=2.5)
    ctl = Controller(graph.dir)
    connect(ctl, proc, ctl.grip)
    ctl.spin_until(lambda: ctl.ticks() == 1, proc=proc)
    ctl.grip.publish(GripCommand(normal_force_kpa=99.0, period=0))
    ctl.spin_until(lambda: ctl.ticks() == 2, proc=proc)
    ctl.grip.publish(GripCommand(normal_force_kpa=0.0, period=1))
    ctl.spin_until(lambda: ctl.ticks() == 3, proc=proc)
    ctl.grip.publish(GripCommand(normal_force_kpa=2.7, period=2))        # within one step: as asked
    ctl.spin_until(lambda: ctl.ticks() == 4, proc=proc)
    assert [m.normal_force_kpa for m in ctl.got[RobotState]] == pytest.approx([2.5, 3.0, 2.5, 2.7])
    err = stop(proc)
    assert "asked 99.0 kPa; applying 3.0 kPa" in err and "at most 0.5 kPa per period" in err
    ctl.close()


@pytest.mark.parametrize("scene, topics", [
    ("mechanics", ["/actuator/state", "/heartbeat", "/object/pose", "/robot/state", "/sim/truth"]),
    ("electrodes_only", ["/actuator/state", "/biotac/slow", "/heartbeat", "/object/pose", "/robot/state",
                         "/sim/truth"]),
    ("paper", ["/actuator/state", "/biotac/pac", "/biotac/slow", "/heartbeat", "/object/pose",
               "/pzt/state", "/robot/state", "/sim/truth"]),
])
def test_a_scene_publishes_only_the_topics_of_its_effects(graph, scene, topics):
    with RigSim(params={"scene": scene}) as node:           # announced, not started
        assert sorted(node._info.publishes) == topics
        assert sorted(node._info.subscribes) == ["/grip/command", "/pzt/command", "/run/event"]


def test_lockstep_without_a_controller_is_a_fault_naming_the_period(graph, capsys):
    argv = ["scene:=mechanics", "steps:=5", "wait_subscribers:=0", "lockstep_timeout_s:=0.3"]
    assert run_node(RigSim, argv) == 3
    assert "no GripCommand(period=0)" in capsys.readouterr().err


def test_realtime_mode_releases_messages_when_their_stamps_are_due(graph):
    steps, factor = 4, 10.0              # 2 s of sim time in 0.2 s
    proc = start_rig(graph, scene="mechanics", steps=steps, lockstep="false",
                     realtime_factor=factor, exit_when_done="true")
    ctl = Controller(graph.dir)
    arrivals = []
    ctl.create_subscription(ObjectPose, lambda m: arrivals.append((time.monotonic(), m.stamp_ns)),
                            topic=ObjectPose.TOPIC)
    ctl.spin_until(lambda: ctl.ticks() == steps, proc=proc)
    assert proc.wait(10) == 0
    wall = np.array([a[0] for a in arrivals])
    sim = np.array([a[1] for a in arrivals]) / 1e9
    assert len(arrivals) == 60 * steps
    assert wall[-1] - wall[0] >= 0.8 * (sim[-1] - sim[0]) / factor       # paced, not a burst
    # no upper bound: how late a loaded machine delivers them is a speed, measured by the
    # benchmarks (bench/bench_emulated.py), not asserted here (it failed under make test-load)
    ctl.close()


def test_unknown_scene_or_material_is_a_one_line_error(graph, capsys):
    assert run_node(RigSim, ["scene:=no_such_scene"]) == 2
    assert "scene not found" in capsys.readouterr().err
    assert run_node(RigSim, ["scene:=mechanics", "material:=granite"]) == 2
    assert "'granite' is not in scene 'mechanics'" in capsys.readouterr().err
