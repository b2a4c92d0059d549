"""`slip bag record` beside a simulated run records one time base: its own heartbeat follows the
run's clock (docs/graph.md, "One time base"); before, it was the one topic on Unix wall time, so
`slip bag info` showed a /heartbeat stamp span of 1795861320 s and the Foxglove export a 57-year
timeline."""
from __future__ import annotations

import json
import sys
import time

import numpy as np
import pytest

from incipient_slip.graph.recorder import Recorder
from incipient_slip.graph.runtime import CLOCK_ENV, Node
from incipient_slip.messages import PERIOD_NS, BiotacPac, Heartbeat
from timeline import assert_one_timeline, stop_and_read  # noqa: E402

STEPS = 20


@pytest.mark.timeout(240)
def test_slip_bag_record_beside_a_simulated_run_records_its_heartbeat_on_the_runs_clock(graph, probe, tmp_path):
    graph.env.pop(CLOCK_ENV, None)               # the tool's own environment: no clock given
    out, summary = tmp_path / "rec.mcap", tmp_path / "summary.json"
    beats = probe.listen(Heartbeat)
    recorder = graph.spawn([sys.executable, "-m", "incipient_slip.graph.tools", "bag", "record", str(out)])
    mine = lambda: [b for b in beats if b.node == "recorder"]   # noqa: E731
    # started first, as a user does: it beats (on its own clock) before the run exists
    probe.until(lambda: mine(), 60, procs=[recorder], what="the recorder's first heartbeat")
    run = graph.spawn([sys.executable, "-m", "incipient_slip.graph.launch", "stabilize.yaml",
                       f"steps:={STEPS}", "quiet:=true", f"summary:={summary}"])
    probe.until(lambda: run.poll() is not None, 180, what="the run's end")
    assert run.returncode in (0, 1), run.stderr.read().decode()[-3000:]
    after = len(mine())
    probe.until(lambda: len(mine()) >= after + 2, 30, procs=[recorder], what="two more recorder heartbeats")
    received, err = stop_and_read(recorder, out)
    steps = json.loads(summary.read_text())["steps"]
    end_ns = (steps + 2) * PERIOD_NS
    recorded_beats = [m for m in received["/heartbeat"] if m.node == "recorder"]
    # its own heartbeats are in the recording, on the run's simulated time (after the run: at
    # the last stamp it recorded), not on the wall clock
    assert recorded_beats and recorded_beats[-1].stamp_ns > PERIOD_NS, recorded_beats
    assert_one_timeline(received, end_ns)
    # the heartbeats it sent before the run (wall clock) were left out, and it says so
    assert b"of its own heartbeats, sent before it knew the run's clock, not recorded" in err, err.decode()


@pytest.mark.timeout(60)
@pytest.mark.parametrize("clock", ["sim", "wall"])
def test_a_launched_recorder_beats_on_the_clock_the_launch_gives_it(graph, probe, tmp_path, monkeypatch, clock):
    """`SLIP_CLOCK=sim` (collect.yaml on the simulated rig): its heartbeat carries the latest
    stamp it recorded (it stayed at 1 ns, the run's start, for the whole run); `wall`: the wall clock."""
    monkeypatch.setenv(CLOCK_ENV, clock)
    beats = probe.listen(Heartbeat)
    stamp = 7 * PERIOD_NS
    with Recorder(params={"path": str(tmp_path / "r.mcap")}, graph_dir=graph.dir, heartbeat_s=0.1) as rec, \
            Node("source", graph_dir=graph.dir, heartbeat_s=0) as source:
        pub = source.create_publisher(BiotacPac)
        probe.until(lambda: pub.subscriber_count() >= 1, 20, nodes=[rec, source], what="the recorder subscribed")
        pub.publish(BiotacPac(pac_counts=np.zeros(22, dtype=np.int16), stamp_ns=stamp))
        probe.until(lambda: rec.recorded >= 1, 20, nodes=[rec, source], what="the frame recorded")
        n = len(beats)
        probe.until(lambda: len(beats) > n + 1, 20, nodes=[rec, source], what="a heartbeat after it")
    last = [b for b in beats if b.node == "recorder"][-1]
    if clock == "sim":
        assert last.stamp_ns == stamp
    else:
        assert abs(last.stamp_ns - time.time_ns()) < 60 * 10**9
