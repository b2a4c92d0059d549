"""The MCAP bag module: what it writes, what it reads back, and how it refuses bad files."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from incipient_slip.messages import BiotacPac, BiotacSlow, Heartbeat, SlipEstimate, encode
from incipient_slip.graph.bag import BagError, BagWriter, bag_info, json_schema, read_bag

DATA = Path(__file__).resolve().parents[1] / "data"


def pac(seq: int) -> BiotacPac:
    return BiotacPac(pac_counts=np.arange(22, dtype=np.int16) * seq, stamp_ns=10_000_000 * (seq + 1), seq=seq)


def write_small(path: Path, n: int = 50) -> list:
    sent = []
    with BagWriter(path) as bag:
        for i in range(n):
            msg = pac(i)
            bag.write("/biotac/pac", msg, log_time_ns=1_000 + i)
            sent.append(("/biotac/pac", msg))
            if i % 10 == 0:
                est = SlipEstimate(stick_ratio=float("nan"), stamp_ns=i + 1, seq=i // 10)
                bag.write("/slip/estimate", est, log_time_ns=1_000 + i)
                sent.append(("/slip/estimate", est))
    return sent


@pytest.mark.timeout(10)
def test_messages_read_back_equal_and_in_receive_order(tmp_path):
    sent = write_small(tmp_path / "a.mcap")
    got = [(r.topic, r.message()) for r in read_bag(tmp_path / "a.mcap")]
    assert got == sent


@pytest.mark.timeout(10)
def test_bodies_are_stored_byte_for_byte_with_stamp_and_seq(tmp_path):
    msg = pac(7)
    body = encode(msg)
    with BagWriter(tmp_path / "a.mcap") as bag:
        bag.write("/biotac/pac_raw", msg, log_time_ns=5, body=body)
    (rec,) = read_bag(tmp_path / "a.mcap")
    assert (rec.topic, rec.type_name, rec.body) == ("/biotac/pac_raw", "BiotacPac", body)
    assert (rec.log_time_ns, rec.stamp_ns, rec.sequence) == (5, msg.stamp_ns, 7)


@pytest.mark.timeout(10)
def test_topic_filter_reads_only_those_topics(tmp_path):
    write_small(tmp_path / "a.mcap")
    assert {r.topic for r in read_bag(tmp_path / "a.mcap", ["/slip/estimate"])} == {"/slip/estimate"}


@pytest.mark.timeout(10)
def test_channels_are_msgpack_with_a_json_schema_per_type(tmp_path):
    write_small(tmp_path / "a.mcap")
    with open(tmp_path / "a.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    by_topic = {c.topic: c for c in summary.channels.values()}
    assert {c.message_encoding for c in by_topic.values()} == {"msgpack"}
    schema = summary.schemas[by_topic["/biotac/pac"].schema_id]
    assert (schema.name, schema.encoding) == ("BiotacPac", "jsonschema")
    doc = json.loads(schema.data)
    assert doc == json.loads(json.dumps(json_schema(BiotacPac)))
    assert doc["properties"]["pac_counts"]["properties"]["dtype"] == {"const": "<i2"}
    assert doc["x-incipient-slip"] == BiotacPac.schema()
    assert by_topic["/slip/estimate"].metadata == {"type": "SlipEstimate", "version": "2"}


@pytest.mark.timeout(10)
def test_info_gives_topics_types_counts_rates_and_seq_gaps(tmp_path):
    with BagWriter(tmp_path / "a.mcap") as bag:
        for i in (0, 1, 2, 5, 6):           # seq 3 and 4 lost: 2 missing messages
            bag.write("/biotac/pac", pac(i), log_time_ns=i * 10_000_000)
        bag.write("/heartbeat", Heartbeat(node="x", stamp_ns=1), log_time_ns=0)
    info = bag_info(tmp_path / "a.mcap")
    topics = {t.topic: t for t in info.topics}
    assert info.message_count == 6
    assert (topics["/biotac/pac"].type_name, topics["/biotac/pac"].count) == ("BiotacPac", 5)
    assert topics["/biotac/pac"].seq_gaps == 2
    assert topics["/biotac/pac"].rate_hz == pytest.approx(4 / 0.06)
    assert info.duration_s == pytest.approx(0.06)
    assert "/biotac/pac" in info.format() and "BiotacPac" in info.format()


def beats(path: Path, lost: dict[str, set[int]], finished: bool = True, n: int = 40) -> Path:
    """Heartbeats of three nodes interleaved on /heartbeat, each with its own seqs from 0 (as every
    node beats), the estimator restarted halfway (a new pid, seqs from 0 again), less the `lost`
    seqs of each node (the estimator's: of its first run); `finished=False`: the bytes a killed
    recorder leaves (everything flushed, no summary)."""
    written = path.with_suffix(".writing")
    with BagWriter(written, flush_s=60.0) as bag:
        t = 0
        for i in range(n):
            for node, pid in (("rig_sim", 11), ("estimator", 12), ("recorder", 13)):
                seq = i
                if node == "estimator" and i >= n // 2:
                    pid, seq = 99, i - n // 2           # respawned: seqs restart, not a gap
                elif i in lost.get(node, ()):
                    continue
                t += 1
                bag.write("/heartbeat", Heartbeat(node=node, pid=pid, stamp_ns=i * 10**9 + 1, seq=seq),
                          log_time_ns=t)
        bag.flush()
        if not finished:
            shutil.copyfile(written, path)
    if finished:
        written.replace(path)
    return path


@pytest.mark.timeout(10)
@pytest.mark.parametrize("finished", [True, False], ids=["finished", "unfinished"])
def test_info_counts_seq_gaps_per_publisher_of_a_shared_topic(tmp_path, finished):
    """Every node beats on /heartbeat with seqs of its own; counted as one sequence, a clean
    recording showed hundreds of gaps (324 and 43 in two runs). Counted per node and pid: 0."""
    clean = bag_info(beats(tmp_path / "clean.mcap", {}, finished), damaged_ok=not finished)
    assert (clean.damage is None) == finished
    (topic,) = clean.topics
    assert (topic.topic, topic.count, topic.seq_gaps) == ("/heartbeat", 3 * 40, 0)
    # real losses are still counted, each against its own publisher: 2 + 1 + 3 missing
    lossy = bag_info(beats(tmp_path / "lossy.mcap", {"rig_sim": {5, 6}, "recorder": {30}, "estimator": {3, 4, 5}},
                           finished), damaged_ok=not finished)
    assert lossy.topics[0].seq_gaps == 6


@pytest.mark.timeout(10)
def test_truncated_file_is_an_error_naming_it(tmp_path):
    write_small(tmp_path / "a.mcap")
    data = (tmp_path / "a.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=r"cut\.mcap: truncated"):
        bag_info(cut)
    with pytest.raises(BagError, match=r"cut\.mcap: truncated"):
        list(read_bag(cut))


@pytest.mark.timeout(10)
def test_corrupt_chunk_is_an_error_naming_the_file(tmp_path):
    write_small(tmp_path / "a.mcap")
    data = bytearray((tmp_path / "a.mcap").read_bytes())
    data[len(data) // 4: len(data) // 4 + 64] = b"\xff" * 64      # inside the chunk; magics intact
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"bad\.mcap: not a valid MCAP recording"):
        bag_info(bad)
    with pytest.raises(BagError, match=r"bad\.mcap: not a valid MCAP recording"):
        list(read_bag(bad))


@pytest.mark.timeout(10)
@pytest.mark.parametrize("content, reason", [(b"not an mcap at all", "not an MCAP file"),
                                              (b"", r"is empty \(0 bytes\)")])
def test_non_mcap_file_is_an_error_naming_it(tmp_path, content, reason):
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    with pytest.raises(BagError, match=rf"x\.mcap: {reason}"):
        bag_info(path)


@pytest.mark.timeout(10)
def test_missing_file_is_an_error_naming_it(tmp_path):
    with pytest.raises(BagError, match=r"nope\.mcap: no such file"):
        list(read_bag(tmp_path / "nope.mcap"))


@pytest.mark.timeout(10)
def test_foreign_message_encoding_is_refused(tmp_path):
    from mcap.writer import Writer
    path = tmp_path / "ros.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel("/chatter", "json", sid)
        w.add_message(cid, 1, b"{}", 1)
        w.finish()
    with pytest.raises(BagError, match=r"ros\.mcap: channel /chatter is 'json'-encoded"):
        bag_info(path)


@pytest.mark.timeout(10)
def test_one_topic_keeps_one_type(tmp_path):
    with BagWriter(tmp_path / "a.mcap") as bag:
        bag.write("/biotac/pac", pac(0))
        with pytest.raises(BagError, match="/biotac/pac carries BiotacPac"):
            bag.write("/biotac/pac", Heartbeat())


@pytest.mark.timeout(30)
def test_shipped_demo_recording_is_what_its_script_generates(tmp_path):
    out = tmp_path / "demo.mcap"
    subprocess.run([sys.executable, str(DATA / "make_demo_mcap.py"), str(out)], check=True,
                   capture_output=True, timeout=25)
    assert out.read_bytes() == (DATA / "demo.mcap").read_bytes()
    assert (DATA / "demo.mcap").stat().st_size < 1_000_000


@pytest.mark.timeout(10)
def test_info_gives_the_rate_by_stamps_beside_the_rate_by_receive_time(tmp_path):
    """A recording received 10x faster than its sensor sampled (lock-step, sped-up rig)."""
    with BagWriter(tmp_path / "fast.mcap") as bag:
        for i in range(11):                 # stamped 10 ms apart (100 Hz), received 1 ms apart
            bag.write("/biotac/slow", BiotacSlow(electrode_counts=np.zeros(19, np.uint16),
                                                  stamp_ns=10**9 + i * 10_000_000, seq=i),
                      log_time_ns=i * 1_000_000)
    (t,) = bag_info(tmp_path / "fast.mcap").topics
    assert t.rate_hz == pytest.approx(1000.0) and t.stamp_rate_hz == pytest.approx(100.0)
    plain = bag_info(tmp_path / "fast.mcap").to_plain()["topics"][0]
    assert plain["stamp_rate_hz"] == pytest.approx(100.0)
