"""The closed loop as real processes over loopback ipc: launch exit codes, safety and faults.

Each test runs rig_sim / grip_controller / supervisor (and the estimator where it matters) as
separate processes in a private graph (`graph` fixture); a test node in this process stands in
for the estimator where the test must choose what the controller hears. Handshakes, never
sleeps: publishers wait for their subscribers (XPUB) before the first message.
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys

import pytest

from incipient_slip import control
from incipient_slip.messages import PERIOD_NS, GripCommand, Heartbeat, ObjectPose, RobotState, SlipEstimate
from incipient_slip.graph import discovery
from incipient_slip.graph.runtime import Node



def launch_cmd(*args):
    return [sys.executable, "-m", "incipient_slip.graph.launch", "stabilize.yaml", *args]


def finish(proc, timeout=45):
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"launch did not end within {timeout} s:\n{err.decode()[-3000:]}")
    return proc.returncode, out.decode(), err.decode()


class FakeEstimator(Node):
    """Publishes the estimate of period k from `script(k)` when the rig starts period k (its
    RobotState), and records every GripCommand and Heartbeat it hears."""

    def __init__(self, graph_dir, script):
        super().__init__("fake_estimator", graph_dir=graph_dir, heartbeat_s=0)
        self.script = script
        self.estimate_pub = self.create_publisher(SlipEstimate)
        self.raw_pub = self.create_raw_publisher(SlipEstimate.TOPIC)
        self.commands: list[GripCommand] = []
        self.heartbeats: list[Heartbeat] = []
        self.create_subscription(RobotState, self.on_robot)
        self.create_subscription(ObjectPose, lambda msg: None)   # so the rig's handshake completes
        self.create_subscription(GripCommand, self.commands.append)
        self.create_subscription(Heartbeat, self.heartbeats.append)

    def on_robot(self, msg: RobotState):
        k = msg.stamp_ns // PERIOD_NS
        for estimate in self.script(self, k):
            if isinstance(estimate, bytes):
                self.raw_pub.publish_raw(estimate)
            else:
                self.estimate_pub.publish(estimate)



def start_loop(graph, probe, script, steps, controller_params=(), estimate_timeout_s=30.0):
    """rig_sim (mechanics scene, lock-step) + grip_controller as processes; this process plays
    the estimator. Returns (fake estimator node, [processes]); wait with `probe.until(...,
    nodes=[node], procs=procs)`."""
    node = FakeEstimator(graph.dir, script)
    # a deadline no loaded machine reaches, except where the deadline is what a test is about
    ctrl = graph.spawn(["python", "-m", "incipient_slip.nodes.grip_controller", "method:=injection",
                        "wait_subscribers:=2", f"estimate_timeout_s:={estimate_timeout_s}",
                        *controller_params])
    # the controller's hello: it is subscribed to our estimates before the rig starts
    node._readers = {SlipEstimate.TOPIC: ["grip_controller"]}
    assert node.wait_for_readers(timeout_s=20), "the controller never subscribed to the estimates"
    # and we hear it (its heartbeat), so its first command cannot be lost
    probe.until(lambda: any(h.node == "grip_controller" for h in node.heartbeats), 20,
                nodes=[node], procs=[ctrl], what="the controller's heartbeat")
    rig = graph.spawn(["python", "-m", "incipient_slip.nodes.rig_sim", "scene:=mechanics",
                       f"steps:={steps}", "wait_subscribers:=1", "lockstep_timeout_s:=20"])
    return node, [ctrl, rig]


def valid(k, s):
    return SlipEstimate(stick_ratio=s, valid=True, method="injection", period=k,
                        window_end_ns=(k + 1) * PERIOD_NS, stamp_ns=(k + 1) * PERIOD_NS)


@pytest.mark.timeout(60)
def test_launch_without_estimator_runs_to_the_end_and_exits_with_the_supervisor_code(graph, probe, tmp_path):
    """Also the lost-period-0 regression: a recorder of every topic already in the graph (like a
    `slip bag record` started first) must not stand in for the launch's own readers."""
    probe.node.create_raw_subscription(lambda topic, body, recv_ns: None)
    probe.node.spin_once(0)
    summary = tmp_path / "run.json"
    proc = graph.spawn(launch_cmd("method:=none", "steps:=40", f"summary:={summary}"))
    rc, out, err = finish(proc)
    result = json.loads(summary.read_text())
    assert rc == 0, err[-3000:]
    assert result["outcome"] == "success" and result["steps"] == 40
    assert len(result["traces"]["travel_mm"]) == 40
    assert "SUCCESS" in out


@pytest.mark.timeout(60)
def test_nan_and_out_of_range_estimates_are_rejected_and_the_force_held(graph, probe):
    bad = {1: float("nan"), 2: 1.5, 3: -0.2, 4: float("inf")}

    def script(node, k):
        if k in bad:
            return [valid(k, bad[k])]
        if k == 5:
            return [SlipEstimate(stick_ratio=0.2, valid=False, method="injection", period=k,
                                 reason="seq gap", stamp_ns=(k + 1) * PERIOD_NS)]
        return [valid(k, 0.1 if k >= 6 else control.DEFAULT_TARGET_STICK_RATIO)]

    node, procs = start_loop(graph, probe, script, steps=8)
    probe.until(lambda: len(node.commands) >= 8, 30, nodes=[node], procs=procs)
    by_period = {c.period: c for c in node.commands}
    start = by_period[0].normal_force_kpa
    for k in (1, 2, 3, 4, 5):
        assert by_period[k].hold and by_period[k].reason, by_period[k]
        assert by_period[k].normal_force_kpa == start
    assert "outside [0, 1]" in by_period[2].reason and "not finite" in by_period[4].reason
    assert not by_period[6].hold and by_period[6].normal_force_kpa > start   # low s raises F_N
    # the cause on the wire, what a reader switches on (the reason is for people)
    assert [by_period[k].cause for k in range(7)] == [
        "law", "estimate_not_finite", "estimate_out_of_range", "estimate_out_of_range", "estimate_not_finite",
        "estimate_invalid", "law"]


@pytest.mark.timeout(60)
def test_stale_estimates_make_the_controller_hold_within_one_period(graph, probe):
    def script(node, k):
        return [] if k >= 3 else [valid(k, 0.1)]   # the estimator goes silent at period 3

    node, procs = start_loop(graph, probe, script, steps=6, estimate_timeout_s=0.4)
    probe.until(lambda: len(node.commands) >= 6, 30, nodes=[node], procs=procs)
    by_period = {c.period: c for c in node.commands}
    for k in (3, 4, 5):
        assert by_period[k].hold and by_period[k].reason == "stale estimate" and by_period[k].cause == "stale_estimate"
        assert by_period[k].normal_force_kpa == by_period[2].normal_force_kpa   # never ramps


@pytest.mark.timeout(60)
def test_out_of_range_parameter_ends_the_launch_with_one_line_and_exit_2(graph, tmp_path):
    proc = graph.spawn(launch_cmd("steps:=-5", f"summary:={tmp_path / 'run.json'}"))
    rc, out, err = finish(proc, timeout=30)
    assert rc == 2 and "steps:=-5 must be >= 1" in err and "Traceback" not in err
    assert not (tmp_path / "run.json").exists() and "SUCCESS" not in out


@pytest.mark.timeout(90)
def test_estimator_killed_mid_run_ends_the_launch_at_once_naming_it_and_leaves_no_files(graph, probe, tmp_path):
    """The estimator is required (every method but none needs it): its death ends the run.
    (The controller's hold when estimates stop is test_stale_estimates_make_the_controller_hold_...)
    Ordered by messages, not by wall clock: the kill comes after five answered periods, in a run
    that cannot end by itself first (k 0 holds F_N, 20 000 steps: under make test-load a run
    that reached the F_N limit after 115 periods ended before the nodes were looked up)."""
    from incipient_slip.models.estimator_core import default_model_path
    if not default_model_path("injection").exists():
        pytest.skip("shipped model models/injection.npz is missing (slip reproduce models)")
    estimates = probe.listen(SlipEstimate)
    proc = graph.spawn(launch_cmd("k:=0.0", "steps:=20000", f"summary:={tmp_path / 'run.json'}"))
    nodes = probe.nodes(["estimator", "rig_sim", "grip_controller", "supervisor"], procs=[proc])
    probe.until(lambda: len(estimates) >= 5, 60, procs=[proc], what="five estimates")
    os.kill(nodes["estimator"].pid, signal.SIGKILL)
    rc, out, err = finish(proc)
    assert rc == 128 + signal.SIGKILL, err[-2000:]
    assert "required node estimator died with signal SIGKILL" in err
    probe.close()
    assert os.listdir(graph.dir) == []      # every node stopped, the killed one's files removed


@pytest.mark.timeout(60)
def test_a_bad_model_file_ends_the_launch_at_once_with_2_and_the_estimators_line(graph, tmp_path):
    """Used to run on for ~13 s and end as a "fault" with the cause buried in the log; then ended
    with the estimator's line once the graph was up; now refused before any node starts."""
    bad = tmp_path / "model.npz"
    bad.write_bytes(b"not a model")
    proc = graph.spawn(launch_cmd(f"model:={bad}", f"summary:={tmp_path / 'run.json'}"))
    rc, out, err = finish(proc, timeout=40)
    last = err.rstrip().splitlines()[-1]
    assert rc == 2 and last.startswith("launch: error:") and "node 'estimator'" in last \
        and str(bad) in last and "starting" not in err, err[-2000:]


@pytest.mark.timeout(60)
def test_unknown_method_is_refused_at_start(graph, tmp_path):
    proc = graph.spawn(launch_cmd("method:=bogus", f"summary:={tmp_path / 'run.json'}"))
    rc, out, err = finish(proc, timeout=30)
    assert rc == 2 and 'method:="bogus" is not one of injection' in err


def run_lockstep_injection(graph, probe, summary, steps):
    """One lock-step injection run wired as stabilize.yaml wires it, as four processes started
    readers first, with an estimate deadline no loaded machine reaches (the test is about
    ordering, not about deadlines); returns the supervisor's exit code and what it printed on stderr."""
    def started(name, argv):
        proc = graph.spawn(["python", "-m", f"incipient_slip.nodes.{name}", *argv])
        probe.until(lambda: any(n.name == name and n.subscribes for n in discovery.scan(graph.dir)),
                    30, procs=[proc], what=f"{name} announced with its subscriptions")
        return proc

    supervisor = started("supervisor", [f"summary_path:={summary}", f"max_steps:={steps}", "quiet:=true",
                                        "method:=injection", "s_d:=0.3", "k:=2.0"])
    started("estimator", ["method:=injection"])
    started("grip_controller", ["method:=injection", "estimate_timeout_s:=60", "wait_subscribers:=2"])
    started("rig_sim", ["scene:=paper", f"steps:={steps}", "wait_subscribers:=1"])
    code = supervisor.wait(60)
    return code, supervisor.stderr.read().decode(errors="replace")


@pytest.mark.timeout(150)
def test_two_identical_lockstep_runs_write_identical_summaries(graph, probe, tmp_path):
    from incipient_slip.models.estimator_core import default_model_path
    if not default_model_path("injection").exists():
        pytest.skip("shipped model models/injection.npz is missing (slip reproduce models)")
    results, said = [], []
    for run in range(2):
        summary = tmp_path / f"run{run}.json"
        code, stderr = run_lockstep_injection(graph, probe, summary, steps=30)
        assert code == 0, (code, summary.exists() and summary.read_text()[:400], stderr[-2000:])
        said.append(stderr[-2000:])
        result = json.loads(summary.read_text())
        del result["wall_s"]
        results.append(result)
        graph.close()
        graph.procs.clear()
    assert results[0]["steps"] == 30 and results[0]["outcome"] == "success"
    estimates = results[0]["traces"]["stick_ratio_estimate"]
    assert sum(isinstance(e, float) and math.isfinite(e) for e in estimates) >= 25   # by period, not by arrival
    for key, trace in results[0]["traces"].items():
        other = results[1]["traces"][key]
        assert json.dumps(trace) == json.dumps(other), (key, [
            (i, a, b) for i, (a, b) in enumerate(zip(trace, other)) if json.dumps(a) != json.dumps(b)][:5], said)
    assert json.dumps(results[0]) == json.dumps(results[1])
