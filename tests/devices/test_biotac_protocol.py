"""The BioTac word layer and the bridge frame parser (devices/biotac.py) as specifications."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.devices import biotac as bt


def test_command_bytes_are_the_published_ones():
    assert [bt.command_byte(c) for c in ("PAC", "PDC", "TAC", "TDC", "HAL")] == [0x80, 0x83, 0x85, 0x86, 0x9E]
    electrodes = [bt.command_byte(f"E{i:02d}") for i in range(1, 20)]
    assert bytes(electrodes).hex() == "a2a4a7a8abadaeb0b3b5b6b9babcbfc1c2c4c7"
    assert bt.FRAME_SCHEDULE[:4] == bytes([0xA2, 0x80, 0xA4, 0x80])
    assert bt.FRAME_SCHEDULE[-6:] == bytes([0x83, 0x80, 0x85, 0x80, 0x86, 0x80])
    assert list(bt.FRAME_SCHEDULE[1::2]) == [0x80] * bt.PAC_SAMPLES_PER_FRAME


@settings(deadline=None)
@given(st.integers(0, 4095))
def test_word_round_trips_with_odd_parity_in_both_bytes(value):
    b0, b1 = bt.encode_word(value)
    assert bt.decode_word(b0, b1) == value
    assert bt.word_status(b0, b1) == "ok"


@settings(deadline=None)
@given(st.integers(0, 4095), st.integers(0, 1), st.integers(0, 7))
def test_any_single_bit_flip_fails_parity(value, which, bit):
    word = bytearray(bt.encode_word(value))
    word[which] ^= 1 << bit
    assert bt.word_status(*word) != "ok"


def test_every_error_word_fails_parity_and_is_named():
    for word, name in bt.ERROR_WORDS.items():
        assert bt.word_status(word >> 8, word & 0xFF) == name


def test_encode_word_refuses_more_than_12_bits():
    with pytest.raises(ValueError, match="12 bits"):
        bt.encode_word(4096)


def _frame(counter, time_us, value=100, n=1, status=0):
    return bt.pack_data_frame(counter, time_us, bt.encode_word(value) * (44 * n), n, status=status)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(1, 40), min_size=1, max_size=30), st.binary(max_size=20))
def test_parser_finds_every_frame_however_the_stream_is_cut(cuts, garbage):
    frames = [_frame(i, i * 10_000, value=i) for i in range(5)]
    stream = garbage.replace(b"\xB1", b"") + b"".join(frames)
    parser, events, pos = bt.FrameParser(), [], 0
    for cut in cuts * 20:
        events += parser.feed(stream[pos:pos + cut])
        pos += cut
    events += parser.feed(stream[pos:])
    got = [e for e in events if isinstance(e, bt.DataFrame)]
    assert [f.counter for f in got] == list(range(5))
    assert sum(e.nbytes for e in events if isinstance(e, bt.FrameError)) == len(garbage.replace(b"\xB1", b""))


@settings(deadline=None)
@given(st.integers(2, 105), st.integers(0, 7))
def test_a_corrupted_frame_is_a_crc_error_and_the_next_frame_survives(index, bit):
    bad = bytearray(_frame(0, 0))
    bad[index] ^= 1 << bit
    # a corrupted length (n_biotacs) may hold the parser back by up to one longest frame
    following = b"".join(_frame(i, i * 10_000) for i in range(1, 5))
    events = bt.FrameParser().feed(bytes(bad) + following)
    assert [e.counter for e in events if isinstance(e, bt.DataFrame)] == [1, 2, 3, 4]
    assert any(isinstance(e, bt.FrameError) and e.kind in ("crc", "header") for e in events)


def test_stream_counts_drops_repeats_and_counter_jumps():
    stream = bt.BridgeStream()
    readings = stream.feed(_frame(0, 0) + _frame(1, 10_000) + _frame(1, 10_000)   # repeat
                           + _frame(4, 40_000)                                     # 2 dropped
                           + _frame(1000, 50_000))                                 # counter jump
    c = stream.counters
    assert [r.frame_index for r in readings] == [0, 1, 4, 5]
    assert (c.frames_repeated, c.frames_dropped, c.counter_jumps) == (1, 2, 1)
    assert [r.device_time_ns for r in readings] == [0, 10_000_000, 40_000_000, 50_000_000]


def test_stream_unwraps_the_32_bit_device_clock():
    start = 2**32 - 10_000
    readings = bt.BridgeStream().feed(_frame(7, start) + _frame(8, 0) + _frame(9, 10_000))
    assert [r.device_time_ns for r in readings] == [0, 10_000_000, 20_000_000]


def test_bad_words_refuse_only_their_stream_and_are_counted_per_channel():
    replies = bytearray(bt.encode_word(2000) * 44)
    replies[2 * 1] ^= 0x01                                   # slot 1 is P_AC: parity
    replies[2 * 4:2 * 4 + 2] = (0xA52D).to_bytes(2, "big")   # slot 4 is E03: "E-"
    stream = bt.BridgeStream()
    [reading] = stream.feed(bt.pack_data_frame(0, 0, bytes(replies), 1))
    assert reading.pac is None and reading.electrodes is None
    c = stream.counters
    assert c.parity_errors[bt.REPORTED_CHANNELS.index("PAC")] == 1
    assert c.error_words[bt.REPORTED_CHANNELS.index("E03")] == 1
    assert c.error_word_kinds[bt.ERROR_NAMES.index("insufficient_sampling_delay")] == 1
    assert (c.pac_frames_refused, c.slow_frames_refused) == (1, 1)


def test_a_frame_of_another_schedule_is_refused():
    stream = bt.BridgeStream()
    assert stream.feed(bt.pack_data_frame(0, 0, bt.encode_word(1) * 44, 1, pattern=0x1234)) == []
    assert stream.counters.pattern_mismatches == 1


def test_units_file_overrides_and_refuses_unknown_keys(tmp_path):
    good = tmp_path / "u.yaml"
    good.write_text("pdc_pa_per_count: 30.0\npac_zero_counts: 2000\n")
    units = bt.load_units(good)
    assert (units.pdc_pa_per_count, units.pac_zero_counts, units.pac_pa_per_count) == (30.0, 2000, 0.37)
    assert set(bt.UNIT_SOURCES) == {f for f in units.__dataclass_fields__}
    bad = tmp_path / "b.yaml"
    bad.write_text("pdc_pa_per_bit: 30\n")
    with pytest.raises(ValueError, match="unknown unit 'pdc_pa_per_bit'"):
        bt.load_units(bad)
    np.testing.assert_allclose(units.electrode_impedance_kohm([4095 / 2]), [10.0])


def test_tare_then_touch_after_five_frames_above_fifty_sigma():
    tare = bt.Tare(frames=100)
    tare.start()
    rng = np.random.default_rng(0)
    for _ in range(100):
        tare.add(int(2000 + rng.integers(-2, 3)), np.full(19, 3000))
    assert tare.state == "done" and abs(tare.pdc_tare_counts - 2000) <= 1
    for i in range(5):
        assert not tare.touching
        tare.add(2000 + 500, np.full(19, 3000))
    assert tare.touching
    tare.add(2000, np.full(19, 3000))
    assert not tare.touching


def test_tare_is_refused_when_touched_while_taring_and_the_last_baseline_stays():
    tare = bt.Tare(frames=10)
    tare.start()
    for i in range(10):
        tare.add(2000 + 100 * i, np.zeros(19))
    assert tare.state == "refused" and tare.pdc_tare_counts == 0
    tare.start()
    for _ in range(10):
        tare.add(1900, np.zeros(19))
    assert tare.state == "done" and tare.pdc_tare_counts == 1900
    tare.start()
    tare.add(1800, np.zeros(19))
    assert tare.state == "collecting" and tare.pdc_tare_counts == 1900


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=200), st.lists(st.integers(1, 64), min_size=1, max_size=10))
def test_parser_recovers_every_frame_after_any_garbage(garbage, cuts):
    """Garbage may hold sync bytes and fake headers: none of the real frames after it is lost."""
    frames = b"".join(_frame(i, i * 10_000, value=i) for i in range(10))
    stream = garbage + b"\xB1\x0C" + garbage[:30] + frames
    parser, events, pos = bt.FrameParser(), [], 0
    for cut in cuts * 50:
        events += parser.feed(stream[pos:pos + cut])
        pos += cut
    events += parser.feed(stream[pos:])
    assert [e.counter for e in events if isinstance(e, bt.DataFrame)] == list(range(10))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.sampled_from(["ok", "drop", "repeat"]), min_size=1, max_size=60))
def test_stream_counts_exactly_the_drops_and_repeats_it_was_given(plan):
    data, sent = b"", []
    for i, what in enumerate(["ok"] + plan + ["ok"]):
        if what != "drop":
            data += _frame(i, i * 10_000)
            sent.append(i)
        if what == "repeat":
            data += _frame(i, i * 10_000)
    stream = bt.BridgeStream()
    readings = stream.feed(data)
    assert [r.frame_index for r in readings] == sent
    assert stream.counters.frames_dropped == plan.count("drop")
    assert stream.counters.frames_repeated == plan.count("repeat")
    assert stream.counters.counter_jumps == 0


# --- what the counters count, as docs/hardware/biotac-bridge.md and docs/messages.md say -------

def test_bytes_skipped_holds_the_rest_of_a_frame_refused_for_its_crc_but_not_its_sync():
    bad = bytearray(_frame(1, 10_000))
    bad[-1] ^= 0xFF                                            # the CRC
    stream = bt.BridgeStream()
    readings = stream.feed(_frame(0, 0) + bytes(bad) + _frame(2, 20_000))
    c = stream.counters
    assert [r.frame_index for r in readings] == [0, 2]
    assert (c.crc_errors, c.bytes_skipped) == (1, len(bad) - 2)
    assert c.frames_dropped == 1                               # the refused frame is missing too


def test_frames_dropped_counts_refused_frames_but_not_those_missed_while_disconnected():
    stream = bt.BridgeStream()
    stream.feed(_frame(0, 0) + bt.pack_data_frame(1, 10_000, bt.encode_word(1) * 44, 1, pattern=0x1234)
                + _frame(2, 20_000))
    assert (stream.counters.pattern_mismatches, stream.counters.frames_dropped) == (1, 1)
    stream.restart()                                           # a reconnection (unplug, stall)
    [reading] = stream.feed(_frame(500, 5_000_000))
    assert reading.frame_index == 0 and stream.counters.frames_dropped == 1


def test_an_error_word_is_counted_as_an_error_word_only_not_as_a_parity_error():
    replies = bytearray(bt.encode_word(2000) * 44)
    replies[2 * 4:2 * 4 + 2] = (0xA52D).to_bytes(2, "big")    # slot 4 is E03: "E-"
    stream = bt.BridgeStream()
    stream.feed(bt.pack_data_frame(0, 0, bytes(replies), 1))
    e03 = bt.REPORTED_CHANNELS.index("E03")
    assert (stream.counters.error_words[e03], stream.counters.parity_errors[e03]) == (1, 0)


@given(st.integers(0, 0xFFF), st.integers(0, 3))
def test_bits_2_and_1_of_the_second_byte_are_not_part_of_the_value(value, unused):
    b0, b1 = bt.encode_word(value)
    assert b1 & 0b110 == 0                                     # sent as 0
    b1 = bt.with_odd_parity((b1 >> 1) | unused)                # set them, parity made right again
    assert bt.decode_word(b0, b1) == value and bt.word_status(b0, b1) == "ok"
