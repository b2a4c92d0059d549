"""Recording and replay with real processes: through the launcher, and a recorder stopped by a signal."""
from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from incipient_slip.messages import BiotacPac
from incipient_slip.graph.bag import bag_info, read_bag
from incipient_slip.graph.runtime import Node

HERE = Path(__file__).resolve().parent
DEMO = HERE.parent / "data" / "demo.mcap"
LAUNCH = [sys.executable, "-m", "incipient_slip.graph.launch"]


def launch(graph, file: str, timeout: float = 40.0, **args) -> subprocess.CompletedProcess:
    argv = LAUNCH + [str(HERE / file)] + [f"{k}:={v}" for k, v in args.items()]
    proc = graph.spawn(argv)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)          # the launcher stops its nodes; show what they said
        out, err = proc.communicate(timeout=15)
        pytest.fail(f"launch {file} still running after {timeout} s:\n{out.decode()}{err.decode()}")
    return subprocess.CompletedProcess(argv, proc.returncode, out.decode(), err.decode())


def assert_every_channel_has_a_schema(path: Path) -> None:
    """PlotJuggler refuses a channel without a schema record."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.channels and all(c.schema_id != 0 and c.schema_id in summary.schemas
                                    for c in summary.channels.values())


def content(path: Path) -> list[tuple]:
    """What a recording says, minus receive times: (topic, type, body, stamp, seq) in order."""
    return [(r.topic, r.type_name, r.body, r.stamp_ns, r.sequence) for r in read_bag(path)]


@pytest.mark.timeout(60)
@pytest.mark.parametrize("speed", [{"rate": 4.0}, {"max_speed": "true"}], ids=["rate4", "max_speed"])
def test_replay_delivers_every_message_in_order_without_seq_gap(graph, tmp_path, speed):
    expected = {t.topic: t.count for t in bag_info(DEMO).topics}
    summary = tmp_path / "summary.json"
    run = launch(graph, "replay_monitor.yaml", bag=DEMO, expect=sum(expected.values()),
                 summary=summary, **speed)
    assert run.returncode == 0, run.stdout + run.stderr
    got = json.loads(summary.read_text())
    assert got["pass"], got["problems"]
    assert {t: s["count"] for t, s in got["topics"].items()} == expected
    assert all(s["seq_gaps"] == 0 and s["out_of_order"] == 0 for s in got["topics"].values())
    assert "PASS" in run.stdout


@pytest.mark.timeout(60)
def test_record_play_record_gives_identical_content(graph, tmp_path):
    count = bag_info(DEMO).message_count
    first, second = tmp_path / "first.mcap", tmp_path / "second.mcap"
    for source, out in ((DEMO, first), (first, second)):
        run = launch(graph, "replay_record.yaml", bag=source, out=out, count=count)
        assert run.returncode == 0, run.stdout + run.stderr
    assert len(content(first)) == count
    assert content(second) == content(first) == content(DEMO)
    for path in (first, second):
        assert_every_channel_has_a_schema(path)


def publish_until(proc: subprocess.Popen, pub, node: Node, first: int, then: int) -> int:
    """Publishes `first` frames, signals nothing, keeps publishing up to `then` more while
    `proc` lives; returns how many were published."""
    sent = 0
    while sent < first + then and (sent < first or proc.poll() is None):
        pub.publish(BiotacPac(pac_counts=np.full(22, sent % 2000, dtype=np.int16)))
        sent += 1
        if sent % 20 == 0:
            node.spin_once(0.002)
    return sent


@pytest.mark.timeout(60)
@pytest.mark.parametrize("how", ["node_sigterm", "slip_bag_record_sigint"])
def test_recorder_stopped_by_signal_leaves_a_valid_file_with_every_message_received(graph, tmp_path, how):
    out = tmp_path / "stopped.mcap"
    if how == "node_sigterm":
        argv = ["python", "-m", "incipient_slip.graph.recorder", f"path:={out}", 'topics:=["/biotac/pac"]']
        sig = signal.SIGTERM
    else:
        argv = ["python", "-m", "incipient_slip.graph.tools", "bag", "record", str(out), "/biotac/pac"]
        sig = signal.SIGINT
    recorder = graph.spawn(argv)
    with Node("test_publisher", heartbeat_s=0) as node:
        pub = node.create_publisher(BiotacPac)
        assert pub.wait_for_subscribers(1, timeout_s=30), "recorder never subscribed"
        sent = publish_until(recorder, pub, node, first=300, then=0)
        recorder.send_signal(sig)
        sent += publish_until(recorder, pub, node, first=0, then=2000)   # mid-stream stop
        _, err = recorder.communicate(timeout=20)
    err = err.decode()
    assert recorder.returncode == 0, err
    said = re.search(r"received (\d+), wrote (\d+) messages", err)
    assert said, err
    received, wrote = map(int, said.groups())
    seqs = [r.message().seq for r in read_bag(out)]
    assert received == wrote == len(seqs) > 0
    assert seqs == list(range(len(seqs)))           # in order, no gap, nothing after a hole
    assert len(seqs) <= sent
    assert_every_channel_has_a_schema(out)


@pytest.mark.timeout(60)
def test_recorder_killed_with_sigkill_loses_at_most_its_last_flush_interval(graph, tmp_path):
    """A real recorder process, SIGKILLed mid-stream, and `slip bag recover` on what it left.

    Handshakes, no sleeps: after N frames the publisher sends one malformed frame on the same
    topic; frames from one publisher arrive in order, so the recorder has received all N once
    its heartbeat counts that drop (heartbeat H1). Streaming goes on; the recorder is killed
    on its first heartbeat at least 1 s of its own uptime after H1. Its flush timer (every
    0.5 s, due before that heartbeat) has by then put all N frames on disk: they must all be
    recovered, as an unbroken prefix of what was sent.
    """
    from incipient_slip.messages import Heartbeat

    out, recovered = tmp_path / "killed.mcap", tmp_path / "recovered.mcap"
    recorder = graph.spawn(["python", "-m", "incipient_slip.graph.recorder", f"path:={out}",
                            'topics:=["/biotac/pac"]', "flush_s:=0.5"])
    beats: list[Heartbeat] = []
    n = 400
    with Node("test_publisher", heartbeat_s=0) as node:
        pub = node.create_publisher(BiotacPac)
        bad = node.create_raw_publisher("/biotac/pac")      # same socket: same order as pub
        node.create_subscription(Heartbeat, lambda hb: beats.append(hb) if hb.node == "recorder" else None)
        assert pub.wait_for_subscribers(1, timeout_s=30), "recorder never subscribed"
        sent = 0

        def stream(frames: int) -> None:
            nonlocal sent
            for _ in range(frames):
                pub.publish(BiotacPac(pac_counts=np.full(22, sent % 2000, dtype=np.int16)))
                sent += 1
            node.spin_once(0.005)

        while sent < n:
            stream(10)
        bad.publish_raw(b"\xc1")                             # malformed: the marker
        while not any(hb.malformed_dropped for hb in beats):
            assert recorder.poll() is None, recorder.stderr.read().decode()
            stream(2)
        marker = next(hb for hb in beats if hb.malformed_dropped)
        while not any(hb.uptime_s >= marker.uptime_s + 1.0 for hb in beats):
            assert recorder.poll() is None, recorder.stderr.read().decode()
            stream(2)
        recorder.kill()                                          # SIGKILL, mid-stream
        recorder.wait(timeout=10)
    assert recorder.returncode == -signal.SIGKILL
    run = subprocess.run([sys.executable, "-m", "incipient_slip.graph.tools", "bag", "recover",
                          str(out), str(recovered)], capture_output=True, text=True, timeout=30)
    assert run.returncode == 0, run.stderr
    seqs = [r.message().seq for r in read_bag(recovered)]
    assert seqs == list(range(len(seqs)))        # an unbroken prefix of what was sent
    assert n <= len(seqs) <= sent
    assert f"recovered {len(seqs)} messages" in run.stdout and "UNFINISHED" in run.stdout
    assert_every_channel_has_a_schema(recovered)


@pytest.mark.timeout(60)
def test_an_old_recording_replays_as_the_current_schema(graph, tmp_path):
    """tests/data/demo_v1.mcap is demo.mcap as make_demo_mcap.py wrote it before ActuatorState v2
    (`step_index`, now `period`): replayed, the graph gets the current version (its nodes speak
    only that), so recording the replay gives today's demo.mcap, body for body."""
    old = HERE.parent / "data" / "demo_v1.mcap"
    assert any(b'step_index' in r.body for r in read_bag(old))
    out = tmp_path / "again.mcap"
    run = launch(graph, "replay_record.yaml", bag=old, out=out, count=bag_info(old).message_count)
    assert run.returncode == 0, run.stdout + run.stderr
    assert content(out) == content(DEMO)
