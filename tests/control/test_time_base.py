"""One time base per run: every topic of a lock-step `launch stabilize.yaml` run on the simulated
rig, heartbeats, commands and run events included, carries the run's simulated time (from 0),
in order per publisher and within the run's span; before, /grip/command, /run/event and
/heartbeat carried Unix wall time, 56 years from the rest in a viewer's plot.

What the run sent is read from `slip bag record`, started before it: the recorder stores frames
undecoded and keeps up at any load. A probe that decoded every topic in the test's process fell
behind under `make test-load`, and the 500 ms a node lingers at its close did not flush a
starved reader's backlog: rig_sim's heartbeats, the last of its messages, were never heard."""
from __future__ import annotations

import json
import sys

import pytest

from incipient_slip.messages import PERIOD_NS, Heartbeat
from timeline import assert_one_timeline, stop_and_read  # noqa: E402

pytestmark = pytest.mark.timeout(240)


def test_every_topic_of_a_simulated_run_is_on_the_runs_simulated_time(graph, probe, tmp_path):
    out, summary = tmp_path / "run.mcap", tmp_path / "summary.json"
    beats = probe.listen(Heartbeat)
    recorder = graph.spawn([sys.executable, "-m", "incipient_slip.graph.tools", "bag", "record", str(out)])
    probe.until(lambda: any(b.node == "recorder" for b in beats), 60, procs=[recorder],
                what="the recorder's first heartbeat")
    proc = graph.spawn([sys.executable, "-m", "incipient_slip.graph.launch", "stabilize.yaml",
                        "steps:=120", "quiet:=true", f"summary:={summary}"])
    probe.until(lambda: proc.poll() is not None, 200, what="the run's end")
    assert proc.returncode in (0, 1), proc.stderr.read().decode()[-3000:]
    received, err = stop_and_read(recorder, out)
    steps = json.loads(summary.read_text())["steps"]
    end_ns = (steps + 2) * PERIOD_NS
    assert {"/heartbeat", "/run/event", "/grip/command", "/slip/estimate", "/robot/state"} <= set(received)
    assert_one_timeline(received, end_ns)
    nodes = {m.node for m in received[Heartbeat.TOPIC]}
    assert {"rig_sim", "estimator", "grip_controller", "supervisor"} <= nodes, nodes
