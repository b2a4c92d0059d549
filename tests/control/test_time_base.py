"""One time base per run: every topic of a lock-step `launch stabilize.yaml` run on the simulated
rig, heartbeats, commands and run events included, carries the run's simulated time (from 0),
in order per publisher and within the run's span; before, /grip/command, /run/event and
/heartbeat carried Unix wall time, 56 years from the rest in a viewer's plot."""
from __future__ import annotations

import json
import sys

import pytest

from incipient_slip.messages import MESSAGE_TYPES, PERIOD_NS, Heartbeat
from timeline import assert_one_timeline  # noqa: E402

pytestmark = pytest.mark.timeout(180)


def test_every_topic_of_a_simulated_run_is_on_the_runs_simulated_time(graph, probe, tmp_path):
    for msg_type in MESSAGE_TYPES.values():
        probe.listen(msg_type)
    summary = tmp_path / "summary.json"
    proc = graph.spawn([sys.executable, "-m", "incipient_slip.graph.launch", "stabilize.yaml",
                        "steps:=120", "quiet:=true", f"summary:={summary}"])
    probe.until(lambda: proc.poll() is not None, 150, what="the run's end")
    assert proc.returncode in (0, 1), proc.stderr.read().decode()[-3000:]
    for _ in range(20):
        probe.node.spin_once(0.05)
    steps = json.loads(summary.read_text())["steps"]
    end_ns = (steps + 2) * PERIOD_NS
    heard = {topic for topic, msgs in probe.received.items() if msgs}
    assert {"/heartbeat", "/run/event", "/grip/command", "/slip/estimate", "/robot/state"} <= heard
    assert_one_timeline(probe.received, end_ns)
    nodes = {m.node for m in probe.received[Heartbeat.TOPIC]}
    assert {"rig_sim", "estimator", "grip_controller", "supervisor"} <= nodes, nodes
