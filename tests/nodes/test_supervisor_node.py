"""The supervisor as a real process: it counts periods itself (a forged period is dropped,
never progress) and writes its summary, with the per-period traces, also when it is interrupted
(and that summary plots)."""
from __future__ import annotations

import json
import signal

from incipient_slip.messages import PERIOD_NS
from incipient_slip.graph.runtime import Node
from incipient_slip.experiments.run_plot import load_summary, plot_run
from incipient_slip.messages import GripCommand, Heartbeat, ObjectPose, RobotState, RunEvent, SimTruth, SlipEstimate
from waiting import spin_until


class FakeLoop(Node):
    """Publishes what the rig, estimator and controller would for chosen periods."""

    def __init__(self, graph_dir):
        super().__init__("fake_loop", graph_dir=graph_dir, heartbeat_s=0)
        self.pubs = {t: self.create_publisher(t) for t in (RobotState, ObjectPose, SlipEstimate, SimTruth, GripCommand)}
        self.events: list[RunEvent] = []
        self.heard: set[str] = set()
        self.create_subscription(RunEvent, self.events.append)
        self.create_subscription(Heartbeat, lambda m: self.heard.add(m.node))

    def spin_until(self, predicate, proc, timeout_s=20.0):
        spin_until(lambda: self.spin_once(0.02), predicate, timeout_s, [proc], "the supervisor")

    def period(self, k, force_kpa=3.0, y_mm=0.2):
        start = k * PERIOD_NS
        self.pubs[RobotState].publish(RobotState(normal_force_kpa=force_kpa, stamp_ns=max(start, 1)))
        self.pubs[ObjectPose].publish(ObjectPose(position_mm=[0.0, y_mm, 0.0], orientation_xyzw=[0, 0, 0, 1.0],
                                                 stamp_ns=start + PERIOD_NS - 8_333_333))
        self.pubs[SlipEstimate].publish(SlipEstimate(stick_ratio=0.3, valid=True, method="injection", period=k,
                                                     stamp_ns=start + PERIOD_NS))
        self.pubs[SimTruth].publish(SimTruth(period=k, stick_ratio=0.9 - 0.1 * k, tangential_force_n=0.2 * k,
                                             stamp_ns=start + PERIOD_NS))
        self.pubs[GripCommand].publish(GripCommand(normal_force_kpa=force_kpa, period=k))


def test_forged_period_is_dropped_and_an_interrupted_run_still_writes_its_summary(graph, tmp_path):
    summary = tmp_path / "run.json"
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.supervisor", "max_steps:=3", "method:=injection",
                        f"summary_path:={summary}", "quiet:=true"])
    node = FakeLoop(graph.dir)
    for pub in node.pubs.values():
        while not pub.wait_for_subscribers(1, 0.1):
            assert proc.poll() is None, proc.stderr.read().decode()
    node.spin_until(lambda: "supervisor" in node.heard, proc)         # its RunEvents reach us
    node.period(0)
    node.pubs[GripCommand].publish(GripCommand(normal_force_kpa=3.0, period=2 ** 32 - 1))   # valid, forged
    node.period(1)
    node.spin_until(lambda: [e.step for e in node.events if e.kind == "step"] == [1, 2], proc)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(10) == 128 + signal.SIGTERM     # an interrupted run is no success
    result = json.loads(summary.read_text())
    assert result["outcome"] == "interrupted" and not result["success"]
    assert result["steps"] == 2 and result["dropped_commands"] == 1
    assert result["traces"]["step"] == [1, 2] and result["traces"]["stick_ratio_estimate"] == [0.3, 0.3]
    assert result["traces"]["period"] == [0, 1] and result["traces"]["stick_ratio_true"] == [0.9, 0.8]
    assert result["traces"]["tangential_force_n"] == [0.0, 0.2]
    assert {len(trace) for trace in result["traces"].values()} == {2}
    figure = plot_run(load_summary(summary), tmp_path / "run.png")
    assert figure.read_bytes().startswith(b"\x89PNG")
    assert "dropped GripCommand(period=4294967295)" in proc.stderr.read().decode()
    node.close()


def test_a_run_that_judged_no_period_keeps_the_earlier_summary(graph, tmp_path):
    """A launch that dies before period 0 (an unknown material, no devices) must not replace the
    last real run's summary with an empty one."""
    summary = tmp_path / "run.json"
    summary.write_text('{"outcome": "success", "steps": 450}')
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.supervisor", "max_steps:=3", "method:=injection",
                        f"summary_path:={summary}", "quiet:=true"])
    node = FakeLoop(graph.dir)
    node.spin_until(lambda: "supervisor" in node.heard, proc)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(10) == 128 + signal.SIGTERM     # an interrupted run is no success
    assert json.loads(summary.read_text()) == {"outcome": "success", "steps": 450}
    assert "no period was judged" in proc.stderr.read().decode()


def test_start_up_waits_for_the_rig_and_then_a_silent_graph_is_a_fault(graph, tmp_path):
    """A rig that takes longer to start than startup_timeout_s is not "graph silent": the clock
    starts at the rig's first message (before: at the supervisor's start, so a loaded machine
    that took 60 s to start rig_sim ended the run before step 0)."""
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.supervisor", "startup_timeout_s:=1.0",
                        "summary_path:=", "quiet:=true"])
    node = FakeLoop(graph.dir)
    beats: list[Heartbeat] = []
    node.create_subscription(Heartbeat, beats.append)
    # three of its heartbeats (1 s apart) are more than its 1 s start-up timeout: still running
    node.spin_until(lambda: sum(b.node == "supervisor" for b in beats) >= 3 and
                    max(b.uptime_s for b in beats if b.node == "supervisor") > 2.0, proc, timeout_s=60)
    assert proc.poll() is None
    while not node.pubs[RobotState].wait_for_subscribers(1, 0.1):
        assert proc.poll() is None
    node.pubs[RobotState].publish(RobotState(normal_force_kpa=2.9, stamp_ns=1))   # the rig is up
    assert proc.wait(60) == 3          # then no command within 1 s: a fault
    assert "graph silent" in proc.stderr.read().decode()


def test_lockstep_summary_waits_for_the_last_periods_truth_within_a_liveness_limit(graph, tmp_path, capfd):
    """/sim/truth travels on its own connection: the last judged period's may come after the
    verdict (two identical lock-step runs once differed in the last truth, NaN in one)."""
    from incipient_slip.nodes import supervisor as sv
    node = sv.Supervisor(params={"lockstep": True, "summary_path": str(tmp_path / "s.json"), "quiet": True},
                         graph_dir=graph.dir, heartbeat_s=0)
    try:
        j = node.judge
        j.traces["period"][:] = [0, 1]
        j.truth[0] = (0.9, 0.1)
        assert node.awaits_truth(100.0)                            # period 1's truth not in yet
        assert node.awaits_truth(100.0 + sv.TRUTH_WAIT_S - 0.1)
        assert not node.awaits_truth(100.0 + sv.TRUTH_WAIT_S)      # a liveness limit, not forever
        said = capfd.readouterr().err                              # and a NaN there is never silent
        assert "no /sim/truth for the last judged period 1" in said and "the last for period 0" in said
        node.truth_wait_since = None
        j.truth[1] = (0.8, 0.2)
        assert not node.awaits_truth(200.0)                       # in: the summary goes out
        j.truth.clear()
        assert not node.awaits_truth(300.0)                       # a rig without truth: never waits
    finally:
        node.close()

def test_lockstep_reaches_the_judge(graph):
    """`lockstep:=true` (stabilize.yaml passes it on the simulated rig) makes the judge wait for
    the rig's tick, never for data_wait_s; the parameter was declared but not handed on."""
    from incipient_slip.nodes.supervisor import Supervisor
    for lockstep in (True, False):
        node = Supervisor(params={"lockstep": lockstep, "summary_path": "", "quiet": True},
                          graph_dir=graph.dir, heartbeat_s=0)
        try:
            assert node.judge.lockstep is lockstep
        finally:
            node.close()
