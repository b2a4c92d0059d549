"""Unfinished and damaged recordings: the flush policy, `scan_bag`, `recover`, `bag_info(damaged_ok)`.

A recorder killed with SIGKILL leaves what it flushed: a file with no summary and no footer,
cut anywhere in its open chunk. Here such files are made by copying the bytes of a writer
that was never closed (exactly what the kernel holds after a kill) and by cutting finished
files at arbitrary bytes.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from incipient_slip.graph.bag import (BagError, BagWriter, Damage, bag_info, read_bag, recover,
                                      scan_bag)
from incipient_slip.messages import BiotacPac, SlipEstimate

CHUNK = 10          # messages per chunk in the files made here


def pac(seq: int) -> BiotacPac:
    return BiotacPac(pac_counts=np.arange(22, dtype=np.int16) * (seq % 50), stamp_ns=10_000_000 * seq,
                     seq=seq)


def fill(bag: BagWriter, first: int, n: int) -> None:
    for seq in range(first, first + n):
        bag.write("/biotac/pac", pac(seq), log_time_ns=1_000 + seq)
        if seq % 7 == 0:
            bag.write("/slip/estimate", SlipEstimate(stick_ratio=0.5, stamp_ns=seq, seq=seq // 7),
                      log_time_ns=1_000 + seq)


def killed_copy(bag: BagWriter, to: Path) -> Path:
    """The bytes a killed writer leaves on disk (the writer goes on unharmed)."""
    shutil.copyfile(bag.path, to)
    return to


def pac_seqs(path: Path) -> list[int]:
    return [r.message().seq for r in read_bag(path) if r.topic == "/biotac/pac"]


def chunk_ends(data: bytes) -> list[int]:
    """Where each chunk record of an MCAP file ends (records are opcode u8, length u64, body)."""
    ends, pos = [], 8
    while pos + 9 <= len(data):
        opcode, length = data[pos], int.from_bytes(data[pos + 1:pos + 9], "little")
        pos += 9 + length
        if opcode == 0x06:
            ends.append(pos)
    return ends


@pytest.fixture
def chunked(tmp_path) -> tuple[Path, list[int]]:
    """A finished file of 6 flushed chunks of CHUNK pac frames, and where its chunks end."""
    path = tmp_path / "chunked.mcap"
    with BagWriter(path, flush_s=60.0) as bag:
        for k in range(6):
            fill(bag, k * CHUNK, CHUNK)
            bag.flush()
    ends = chunk_ends(path.read_bytes())
    assert len(ends) == 6
    return path, ends


@pytest.mark.timeout(20)
def test_flushed_messages_are_on_disk_and_the_open_chunk_is_not(tmp_path):
    path = tmp_path / "live.mcap"
    with BagWriter(path, flush_s=60.0) as bag:
        assert bag_info(killed_copy(bag, tmp_path / "empty.mcap"), damaged_ok=True).message_count == 0
        fill(bag, 0, 25)
        bag.flush()
        fill(bag, 25, 5)            # still in memory when the "kill" comes
        cut = killed_copy(bag, tmp_path / "killed.mcap")
    out = tmp_path / "recovered.mcap"
    result = recover(cut, out)
    assert pac_seqs(out) == list(range(25))
    assert result.counts == {"/biotac/pac": 25, "/slip/estimate": 4}
    assert not result.damage.finished and result.damage.chunks == 1
    assert pac_seqs(path) == list(range(30))        # the writer itself lost nothing


@pytest.mark.timeout(20)
def test_write_flushes_once_the_oldest_pending_message_is_flush_s_old(tmp_path, monkeypatch):
    import incipient_slip.graph.bag as bagmod
    clock = [100.0]
    monkeypatch.setattr(bagmod.time, "monotonic", lambda: clock[0])
    with BagWriter(tmp_path / "a.mcap", flush_s=0.5) as bag:
        flushes = bag.flushes
        fill(bag, 0, 3)
        clock[0] += 0.49
        fill(bag, 3, 1)
        assert bag.flushes == flushes               # oldest pending is 0.49 s old
        clock[0] += 0.01
        fill(bag, 4, 1)
        assert bag.flushes == flushes + 1           # 0.5 s: chunk finished and fsync'd
        cut = killed_copy(bag, tmp_path / "cut.mcap")
    assert [r.message().seq for r in scan_bag(cut) if r.topic == "/biotac/pac"] == list(range(5))


@pytest.mark.timeout(60)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(0.0, 1.0))
def test_a_cut_anywhere_recovers_exactly_the_chunks_before_it(chunked, tmp_path, fraction):
    path, ends = chunked
    data = path.read_bytes()
    cut_at = int(fraction * len(data))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:cut_at])
    out = tmp_path / "out.mcap"
    out.unlink(missing_ok=True)     # tmp_path is shared by the examples
    if cut_at < 8:
        with pytest.raises(BagError, match="not an MCAP file|is empty"):
            recover(cut, out)
        assert not out.exists()
        return
    result = recover(cut, out)
    whole_chunks = sum(end <= cut_at for end in ends)
    assert pac_seqs(out) == list(range(whole_chunks * CHUNK))   # a prefix, in order, no hole
    assert result.damage.finished == (cut_at == len(data))
    assert result.damage.readable_bytes <= cut_at
    info = bag_info(cut, damaged_ok=True)
    assert info.message_count == result.message_count
    assert (info.damage is None) == (cut_at == len(data))


@pytest.mark.timeout(20)
def test_a_corrupt_chunk_is_skipped_and_counted_and_later_chunks_are_kept(chunked, tmp_path):
    path, ends = chunked
    data = bytearray(path.read_bytes())
    data[ends[2] - 40:ends[2] - 24] = bytes(16)     # inside chunk 2's compressed data
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(BagError, match="not a valid MCAP recording"):
        bag_info(bad)
    result = recover(bad, tmp_path / "out.mcap")
    assert result.damage.bad_chunks == 1 and result.damage.finished
    assert pac_seqs(tmp_path / "out.mcap") == list(range(2 * CHUNK)) + list(range(3 * CHUNK, 6 * CHUNK))
    info = bag_info(bad, damaged_ok=True)
    assert "1 corrupt chunk(s) skipped" in info.format()


@pytest.mark.timeout(20)
def test_a_finished_file_with_a_broken_summary_is_read_by_its_chunks(chunked, tmp_path):
    path, ends = chunked
    data = bytearray(path.read_bytes())
    data[-40:-8] = b"\xff" * 32            # the footer's summary offsets; chunks intact
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(BagError):
        bag_info(bad)
    info = bag_info(bad, damaged_ok=True)
    assert info.message_count == bag_info(path).message_count
    assert not info.damage.intact and "summary/index is unusable" in info.damage.describe()
    recover(bad, tmp_path / "out.mcap")
    assert pac_seqs(tmp_path / "out.mcap") == list(range(6 * CHUNK))


@pytest.mark.timeout(20)
def test_a_finished_file_recovers_whole_and_info_reports_no_damage(chunked, tmp_path):
    path, _ = chunked
    result = recover(path, tmp_path / "copy.mcap")
    assert result.damage.intact and result.damage.describe() == "finished, nothing lost"
    assert [(r.topic, r.body, r.stamp_ns, r.sequence) for r in read_bag(tmp_path / "copy.mcap")] == \
           [(r.topic, r.body, r.stamp_ns, r.sequence) for r in read_bag(path)]
    assert bag_info(path, damaged_ok=True).damage is None


@pytest.mark.timeout(20)
def test_info_of_an_unfinished_file_says_so_and_counts_what_is_recoverable(chunked, tmp_path):
    path, ends = chunked
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:ends[3] + 100])
    info = bag_info(cut, damaged_ok=True)
    topics = {t.topic: t for t in info.topics}
    assert topics["/biotac/pac"].count == 4 * CHUNK and topics["/biotac/pac"].seq_gaps == 0
    assert info.damage.lost_bytes == 100 and not info.damage.finished
    text = info.format()
    assert "UNFINISHED" in text and "100 bytes at the end unreadable" in text
    assert f"{info.message_count} messages (below) are recoverable" in text
    with pytest.raises(BagError, match=r"cut\.mcap: truncated MCAP file: no footer.*slip bag recover"):
        bag_info(cut)


@pytest.mark.timeout(20)
def test_recover_refuses_to_overwrite_its_source(chunked):
    path, _ = chunked
    with pytest.raises(BagError, match="is the file being recovered"):
        recover(path, path)
    assert bag_info(path).message_count > 0


def test_damage_of_a_finished_file_is_intact():
    assert Damage(100, readable_bytes=100, finished=True).intact
    assert not Damage(100, readable_bytes=100, finished=True, orphans=1).intact


@pytest.mark.timeout(120)
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_corruption_is_recovered_around_or_named_never_a_crash(chunked, tmp_path, data):
    path, _ = chunked
    raw = bytearray(path.read_bytes())
    for _ in range(data.draw(st.integers(1, 8))):
        at = data.draw(st.integers(0, len(raw) - 1))
        raw[at] = data.draw(st.integers(0, 255))
    bad = tmp_path / "fuzz.mcap"
    bad.write_bytes(bytes(raw[:data.draw(st.integers(0, len(raw)))]))
    out = tmp_path / "out.mcap"
    out.unlink(missing_ok=True)
    try:
        result = recover(bad, out)
    except BagError:
        assert not out.exists()
        return
    seqs = pac_seqs(out)                                  # the output is a finished, valid file
    assert len(seqs) == result.counts.get("/biotac/pac", 0)
    assert seqs == sorted(set(seqs)) and set(seqs) <= set(range(6 * CHUNK))   # nothing invented
    assert bag_info(bad, damaged_ok=True).message_count >= result.message_count
