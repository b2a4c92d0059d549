"""`slip bag export --foxglove`: read back with the mcap reader, every message valid against its schema."""
from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from incipient_slip.graph.bag import BagWriter, read_bag
from scipy.signal import upfirdn

from incipient_slip.graph.bag_export import (JS_SAFE_INT, PAC_RATE_HZ, RAW_AUDIO_SCHEMA, AudioUpsampler,
                                             _Counter, _json_value, _plain_array, export_foxglove,
                                             export_schema, to_export_json)
from incipient_slip.messages import MESSAGE_TYPES, BiotacPac, Heartbeat, SlipEstimate

DEMO = Path(__file__).resolve().parents[1] / "data" / "demo.mcap"
EPOCH_NS = 1_763_900_000_123_456_789        # a wall-clock stamp: beyond 2^53


def exported(path: Path) -> list[tuple]:
    """(channel, schema, message, decoded JSON) of every message of an export, validated."""
    out, validators = [], {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        for channel in summary.channels.values():       # every channel references a schema
            assert channel.schema_id in summary.schemas, channel.topic
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert (channel.message_encoding, schema.encoding) == ("json", "jsonschema")
            if schema.id not in validators:
                doc = json.loads(schema.data)
                Draft202012Validator.check_schema(doc)
                validators[schema.id] = Draft202012Validator(doc)
            obj = json.loads(message.data)
            errors = [e.message for e in validators[schema.id].iter_errors(obj)]
            assert not errors, (channel.topic, errors)
            out.append((channel, schema, message, obj))
    return out


@pytest.mark.timeout(60)
def test_demo_export_reads_back_valid_with_every_message_and_p_ac_as_raw_audio(tmp_path):
    out = tmp_path / "foxglove.mcap"
    report = export_foxglove(DEMO, out)
    got = exported(out)
    source = list(read_bag(DEMO))
    by_topic: dict[str, list] = {}
    for channel, schema, message, obj in got:
        by_topic.setdefault(channel.topic, []).append((schema.name, message, obj))
    assert {t: len(v) for t, v in by_topic.items()} == {**{t: sum(r.topic == t for r in source)
                                                         for t in {r.topic for r in source}},
                                                      "/biotac/pac/audio": 200}
    assert report.counts == {t: len(v) for t, v in by_topic.items()}
    pac = [r for r in source if r.topic == "/biotac/pac"]
    blocks = []
    for rec, (name, message, obj), (aname, _, audio) in zip(pac, by_topic["/biotac/pac"],
                                                           by_topic["/biotac/pac/audio"]):
        msg = rec.message()
        assert (name, aname) == ("BiotacPac", "foxglove.RawAudio")
        assert obj["pac_counts"] == msg.pac_counts.tolist() and obj["seq"] == msg.seq
        # logged at the stamp, the run's time base, as the live view logs it (not the receive time)
        assert (message.log_time, message.publish_time) == (rec.stamp_ns, rec.stamp_ns)
        blocks.append(np.frombuffer(base64.b64decode(audio["data"]), dtype="<i2"))
        assert (audio["format"], audio["sample_rate"], audio["number_of_channels"]) == ("pcm-s16", 8800, 1)
        start = audio["timestamp"]["sec"] * 10**9 + audio["timestamp"]["nsec"]
        # first sample's time, less the upsampling filter's delay (47 / 2 samples at 8800 Hz)
        assert start == max(0, msg.stamp_ns - round(21e9 / PAC_RATE_HZ + 23.5e9 / 8800))
    # the audio is the P_AC stream upsampled x4, frames joined without a seam
    stream = np.concatenate([r.message().pac_counts for r in pac]).astype(float)
    expected = upfirdn(AudioUpsampler(4).taps, stream, up=4)[:4 * stream.size]
    assert np.array_equal(np.concatenate(blocks), np.clip(np.rint(expected), -32768, 32767).astype(np.int16))


@pytest.mark.timeout(30)
def test_wall_clock_stamps_nan_and_big_seqs_survive_exactly(tmp_path):
    src, out = tmp_path / "src.mcap", tmp_path / "out.mcap"
    msgs = [SlipEstimate(stick_ratio=float("nan"), stamp_ns=EPOCH_NS, seq=0),
            SlipEstimate(stick_ratio=0.25, stamp_ns=EPOCH_NS + 1, seq=2**64 - 1),
            Heartbeat(node="x", stamp_ns=2**64 - 1, seq=JS_SAFE_INT)]
    with BagWriter(src) as bag:
        for i, m in enumerate(msgs):
            bag.write(m.TOPIC, m, log_time_ns=EPOCH_NS + i)
    report = export_foxglove(src, out)
    objs = [obj for *_, obj in exported(out)]
    assert objs[0]["stamp_ns"] == str(EPOCH_NS) and objs[0]["stick_ratio"] is None
    assert objs[0]["stamp"] == {"sec": EPOCH_NS // 10**9, "nsec": EPOCH_NS % 10**9}
    assert objs[1]["seq"] == str(2**64 - 1) and objs[1]["stick_ratio"] == 0.25
    assert objs[2]["stamp_ns"] == str(2**64 - 1) and objs[2]["seq"] == JS_SAFE_INT
    assert (report.big_ints, report.non_finite) == (4, 1)


@settings(max_examples=40, deadline=None)
@given(stamp=st.integers(0, 2**64 - 1), seq=st.integers(0, 2**64 - 1),
       ratio=st.one_of(st.floats(0.0, 1.0), st.just(float("nan"))))
def test_export_json_is_valid_and_exact_for_any_stamp_and_seq(stamp, seq, ratio):
    msg = SlipEstimate(stick_ratio=ratio, stamp_ns=stamp, seq=seq)
    obj = json.loads(json.dumps(to_export_json(msg), allow_nan=False))
    Draft202012Validator(export_schema(SlipEstimate)).validate(obj)
    assert int(obj["stamp_ns"]) == stamp and int(obj["seq"]) == seq
    assert obj["stamp"]["sec"] * 10**9 + obj["stamp"]["nsec"] == stamp


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_every_export_schema_is_a_valid_json_schema_that_accepts_the_default_message(name):
    msg_type = MESSAGE_TYPES[name]
    arrays = {f: np.zeros([n or 3 for n in spec["shape"]], dtype=spec["array"])
              for f, spec in msg_type.schema()["fields"].items() if "array" in spec}
    msg = msg_type(**arrays, stamp_ns=EPOCH_NS, seq=1)
    Draft202012Validator.check_schema(export_schema(msg_type))
    Draft202012Validator(export_schema(msg_type)).validate(json.loads(json.dumps(to_export_json(msg))))


def test_raw_audio_schema_has_foxgloves_fields():
    assert set(RAW_AUDIO_SCHEMA["required"]) == {"timestamp", "data", "format", "sample_rate",
                                                 "number_of_channels"}
    assert RAW_AUDIO_SCHEMA["properties"]["data"]["contentEncoding"] == "base64"
    assert BiotacPac.schema()["fields"]["pac_counts"]["array"] == "<i2"    # pcm-s16 as it is


def test_upsampler_frame_by_frame_equals_upfirdn_of_the_whole_stream():
    """No seam at frame edges: the frames together are scipy's upfirdn of the stream."""
    stream = np.random.default_rng(0).integers(-2000, 2000, 22 * 30).astype(np.int16)
    framed = AudioUpsampler(4)
    by_frame = np.concatenate([framed(f) for f in stream.reshape(30, 22)])
    whole = upfirdn(framed.taps, stream.astype(float), up=4)[:by_frame.size]
    assert np.array_equal(by_frame, np.clip(np.rint(whole), -32768, 32767).astype(np.int16))


@pytest.mark.parametrize("name", sorted(n for n, t in MESSAGE_TYPES.items()
                                        if any("array" in s for s in t.schema()["fields"].values())))
def test_export_json_of_arrays_equals_the_element_by_element_rule(name):
    """Arrays whose every element is its own JSON value go as one list (the live view's hot
    path): the same JSON as checking each element, at the dtype's extremes too."""
    msg_type = MESSAGE_TYPES[name]
    rng = np.random.default_rng(0)
    arrays = {}
    for f, spec in msg_type.schema()["fields"].items():
        if "array" in spec:
            dtype = np.dtype(spec["array"])
            info = np.iinfo(dtype) if dtype.kind in "iu" else np.finfo(dtype)
            values = rng.uniform(-1e6, 1e6, spec["shape"]).astype(dtype)
            values.flat[0], values.flat[-1] = info.min, info.max
            arrays[f] = values
    msg = msg_type(**arrays, stamp_ns=EPOCH_NS, seq=1)
    seen = _Counter()
    expected = {**to_export_json(msg), **{f: _json_value(a.tolist(), seen) for f, a in arrays.items()}}
    assert json.dumps(to_export_json(msg)) == json.dumps(expected)
    assert not _plain_array(np.array([JS_SAFE_INT + 1], dtype="<i8"))       # would need a digit string
