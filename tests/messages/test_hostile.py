"""Hostile input: every malformed body decodes to MessageError (never another exception, never a
wrong message), and a node that receives one counts it and keeps running."""
from __future__ import annotations

import dataclasses

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from incipient_slip import messages as M
from incipient_slip.graph.runtime import Node
from incipient_slip.messages.codec import _validate_fields, decode_named
from incipient_slip.messages.fields import INT_RANGES, Array, field_specs

from test_messages import any_message
from waiting import spin_until

TYPES = list(M.MESSAGE_TYPES.values())
ARRAY_TYPES = [cls for cls in TYPES if any(isinstance(s, Array) for _, s in field_specs(cls))]
U64_MAX = (1 << 64) - 1


def body_of(msg: M.Message) -> dict:
    return msgpack.unpackb(M.encode(msg), raw=False)


def pack(obj) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def outcome(body: bytes, cls):
    """The decoded message, or the MessageError; any other exception fails the test."""
    try:
        return M.decode(body, cls)
    except M.MessageError as exc:
        assert exc.topic and exc.field and exc.reason
        return exc


def assert_valid(msg: M.Message) -> None:
    """A decoded message must be one that construction accepts and that round-trips."""
    fields = {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)}
    assert type(msg)(**fields) == msg
    assert M.decode(M.encode(msg), type(msg)) == msg


def sample(cls):
    arrays = {name: np.ones(spec.shape, dtype=spec.dtype) for name, spec in field_specs(cls)
              if isinstance(spec, Array)}
    return cls(**arrays)


# --- the cases found by the outside test ----------------------------------------------------

@pytest.mark.parametrize("data", [None, "x" * 44, [0] * 22, 0, {"a": b""}, True])
@pytest.mark.parametrize("cls", ARRAY_TYPES, ids=lambda c: c.__name__)
def test_array_data_that_is_not_bytes_is_a_message_error(cls, data):
    # The outside test's 90-byte frame: {"dtype": "<i2", "shape": [22], "data": nil} raised
    # AttributeError, which the subscription did not catch, and killed the node.
    body = body_of(sample(cls))
    name = next(n for n, s in field_specs(cls) if isinstance(s, Array))
    body[name]["data"] = data
    for decode in (lambda b: M.decode(b, cls), M.decode_any):
        with pytest.raises(M.MessageError) as info:
            decode(pack(body))
        assert info.value.field == name and "bytes" in info.value.reason


@pytest.mark.parametrize("version", [1.0, True, "1", 2, 0, -1, None, [1], U64_MAX])
def test_schema_version_must_be_the_exact_int(version):
    body = body_of(sample(M.BiotacPac))
    body["v"] = version
    for decode in (lambda b: M.decode(b, M.BiotacPac), M.decode_any):
        with pytest.raises(M.MessageError) as info:
            decode(pack(body))
        assert info.value.field == "v"
    del body["v"]
    with pytest.raises(M.MessageError, match="'v'"):
        M.decode(pack(body), M.BiotacPac)


def test_largest_uint64_stamp_and_seq_round_trip():
    msg = M.SlipEstimate(stamp_ns=U64_MAX, seq=U64_MAX, window_end_ns=U64_MAX, latency_ns=U64_MAX)
    out = M.decode(M.encode(msg), M.SlipEstimate)
    assert (out.stamp_ns, out.seq, out.window_end_ns, out.latency_ns) == (U64_MAX,) * 4
    assert M.decode(M.encode(sample(M.BiotacPac), stamp_ns=U64_MAX), M.BiotacPac).stamp_ns == U64_MAX
    with pytest.raises(M.MessageError, match="stamp_ns"):
        M.SlipEstimate(stamp_ns=U64_MAX + 1)
    with pytest.raises(M.MessageError, match="stamp_ns"):
        M.encode(msg, stamp_ns=-1)


@pytest.mark.parametrize("cls, name, value", [
    (M.ActuatorState, "period", 1 << 63),          # the supervisor's "9223372036854775809 steps"
    (M.ActuatorState, "period", 1 << 32),
    (M.ActuatorState, "period", -1),
    (M.GripCommand, "period", 1 << 63),
    (M.GripCommand, "period", -2),
    (M.RunEvent, "step", 1 << 32),
    (M.BiotacSlow, "pdc_counts", 4096),
    (M.Heartbeat, "pid", 1 << 32),
    (M.BiotacPac, "stamp_ns", -1),
    (M.BiotacPac, "seq", True),                         # a bool is not an int
    (M.ActuatorState, "busy", 1),                       # nor an int a bool
    (M.ActuatorState, "period", 3.0),
    (M.BiotacPac, "pa_per_count", float("nan")),
    (M.BiotacPac, "pa_per_count", float("inf")),
    (M.GripCommand, "normal_force_kpa", 100.5),
    (M.SlipEstimate, "method", "magic"),
    (M.GripCommand, "reason", b"bytes"),
    (M.Heartbeat, "node", "n" * 256),
])
def test_out_of_contract_scalar_is_refused_on_decode_and_construction(cls, name, value):
    body = body_of(sample(cls))
    body[name] = value
    with pytest.raises(M.MessageError) as info:
        M.decode(pack(body), cls)
    assert info.value.field == name
    with pytest.raises(M.MessageError, match=name):
        cls(**{**{n: getattr(sample(cls), n) for n, s in field_specs(cls) if isinstance(s, Array)},
               name: value})


def test_widths_hold_at_their_edges():
    edge = M.ActuatorState(period=INT_RANGES["uint32"][1])
    assert M.decode(M.encode(edge), M.ActuatorState) == edge
    assert M.decode(M.encode(M.GripCommand(period=-1)), M.GripCommand).period == -1
    assert M.decode(M.encode(M.SlipEstimate()), M.SlipEstimate).stick_ratio != 0.0  # NaN travels


@pytest.mark.parametrize("mutate", [
    lambda a: a.update(dtype=">i2"), lambda a: a.update(dtype="<i4"), lambda a: a.update(dtype="int16"),
    lambda a: a.update(dtype=""), lambda a: a.update(dtype=5), lambda a: a.update(dtype=None),
    lambda a: a.update(shape=[21]), lambda a: a.update(shape=[22, 1]), lambda a: a.update(shape=[]),
    lambda a: a.update(shape=[22.0]), lambda a: a.update(shape=["22"]), lambda a: a.update(shape=22),
    lambda a: a.update(shape=[1 << 62]), lambda a: a.update(data=a["data"][:-1]),
    lambda a: a.update(data=a["data"] + b"\0\0"), lambda a: a.pop("data"), lambda a: a.update(extra=1),
])
def test_broken_array_maps_are_refused(mutate):
    body = body_of(sample(M.BiotacPac))
    mutate(body["pac_counts"])
    with pytest.raises(M.MessageError) as info:
        M.decode(pack(body), M.BiotacPac)
    assert info.value.field == "pac_counts"


def test_non_finite_array_values_are_refused():
    body = body_of(sample(M.ObjectPose))
    body["position_mm"]["data"] = np.array([0.0, np.nan, 0.0]).tobytes()
    with pytest.raises(M.MessageError, match="non-finite"):
        M.decode(pack(body), M.ObjectPose)


@pytest.mark.parametrize("change", ["extra", "missing", "bytes_key", "list_body", "nested"])
def test_wrong_containers_and_keys_are_refused(change):
    body = body_of(sample(M.RunEvent))
    if change == "extra":
        body["colour"] = "red"
    elif change == "missing":
        del body["detail"]
    elif change == "bytes_key":
        body[b"detail"] = body.pop("detail")
    elif change == "list_body":
        body = list(body.items())
    else:
        body["detail"] = {"a": [{"b": [None]}]}
    with pytest.raises(M.MessageError):
        M.decode(pack(body), M.RunEvent)


@pytest.mark.parametrize("body", [
    b"\x91" * 100_000 + b"\xc0",                      # 100 000 nested arrays
    b"\x81\xa1a" * 50_000 + b"\xc0",                  # 50 000 nested maps
    b"\xdd\xff\xff\xff\xff",                           # an array claiming 2**32-1 items
    b"\xd6\xff\x00\x00\x00\x01",                       # a msgpack timestamp instead of a map
    b"\xc7\x05\xff" + b"\x00" * 5,                      # a malformed timestamp ext
    pack({"type": "BiotacPac"}) + b"\xc0",             # trailing bytes after the map
])
def test_msgpack_oddities_are_message_errors(body):
    with pytest.raises(M.MessageError) as info:
        M.decode(body, M.BiotacPac)
    assert info.value.field == "<body>"


def test_an_ext_value_in_a_field_is_refused():
    body = body_of(sample(M.BiotacPac))
    body["stamp_ns"] = msgpack.Timestamp(1, 0)
    with pytest.raises(M.MessageError, match="stamp_ns"):
        M.decode(msgpack.packb(body, use_bin_type=True, datetime=False), M.BiotacPac)


def test_size_limits_of_bodies_and_strings():
    with pytest.raises(M.MessageError, match="exceeds"):
        M.decode(b"\x00" * (M.MAX_BODY_BYTES + 1), M.BiotacPac)
    body = body_of(M.RunEvent())
    body["detail"] = "x" * (M.MAX_STRING + 1)
    with pytest.raises(M.MessageError, match="msgpack"):
        M.decode(pack(body), M.RunEvent)
    with pytest.raises(M.MessageError, match="detail"):
        M.RunEvent(detail="é" * (M.MAX_STRING // 2 + 1))      # limit is in UTF-8 bytes
    assert M.decode(M.encode(M.RunEvent(detail="é" * 100)), M.RunEvent).detail == "é" * 100
    with pytest.raises(M.MessageError, match="UTF-8"):
        M.RunEvent(detail="\udc80")


def test_construction_refuses_lossy_conversions_and_overflow():
    with pytest.raises(M.MessageError, match="pac_counts"):
        M.BiotacPac(pac_counts=[1.5] * 22)
    with pytest.raises(M.MessageError, match="pac_counts"):
        M.BiotacPac(pac_counts=[40000] * 22)
    with pytest.raises(M.MessageError, match="pac_counts"):
        M.BiotacPac(pac_counts=["1"] * 22)
    with pytest.raises(M.MessageError, match="position_mm"):
        M.ActuatorCommand(position_mm=10 ** 400)
    assert M.BiotacPac(pac_counts=[2.0] * 22).pac_counts.tolist() == [2] * 22


# --- properties ----------------------------------------------------------------------------

_ints = st.integers(-(1 << 63), U64_MAX)
_edges = st.sampled_from([-1, 0, 1, True, False, 1.0, 1 << 32, (1 << 32) - 1, 1 << 53, (1 << 53) + 1,
                          1 << 63, U64_MAX, -(1 << 63), 4096, float("nan"), float("inf"), -0.0,
                          "", "<i2", "<u2", "<f8", b"", [22], [19], [3], [4], None])
_leaves = st.none() | st.booleans() | _ints | st.floats() | st.text(max_size=12) | st.binary(max_size=48) | _edges
msgpack_values = st.recursive(
    _leaves, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=10)


def _mutate(obj: dict, data) -> dict:
    """`obj` with one to three fields (or array-map entries) replaced, removed or added."""
    for _ in range(data.draw(st.integers(1, 3))):
        target = obj
        arrays = [k for k, v in obj.items() if isinstance(v, dict)]
        if arrays and data.draw(st.booleans()):
            target = obj[data.draw(st.sampled_from(arrays))]
        if not isinstance(target, dict):
            break
        action = data.draw(st.sampled_from(["set", "set", "set", "delete", "add"]))
        keys = sorted(target, key=str)
        if action == "add" or not keys:
            target[data.draw(st.text(max_size=8))] = data.draw(msgpack_values)
        elif action == "delete":
            del target[data.draw(st.sampled_from(keys))]
        else:
            target[data.draw(st.sampled_from(keys))] = data.draw(msgpack_values)
    return obj


@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(any_message, st.data())
def test_mutated_fields_of_every_type_decode_to_a_valid_message_or_message_error(msg, data):
    cls = type(msg)
    body = pack(_mutate(body_of(msg), data))
    result = outcome(body, cls)
    any_result = M.decode_any(body) if isinstance(result, M.Message) else None
    if isinstance(result, M.Message):
        assert_valid(result)
        assert any_result == result
        # the wire (msgspec) path never accepts what the naming path refuses, nor builds another message
        assert decode_named(body, cls) == result


@settings(max_examples=300, deadline=None)
@given(msgpack_values, st.sampled_from(TYPES))
def test_random_msgpack_structures_decode_to_a_valid_message_or_message_error(obj, cls):
    try:
        body = pack(obj)
    except (OverflowError, ValueError):
        return
    result = outcome(body, cls)
    if isinstance(result, M.Message):
        assert_valid(result)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400), st.sampled_from(TYPES))
def test_random_bytes_decode_only_to_message_error(body, cls):
    result = outcome(body, cls)
    if isinstance(result, M.Message):
        assert_valid(result)
    try:
        M.decode_any(body)
    except M.MessageError:
        pass


# --- the runtime ---------------------------------------------------------------------------

def _spin_until(node, cond, timeout_s=20.0):
    spin_until(lambda: node.spin_once(0.01), cond, timeout_s)


def test_node_counts_the_hostile_array_frame_and_keeps_delivering(graph):
    hostile = body_of(sample(M.BiotacPac))
    hostile["pac_counts"]["data"] = None
    good = M.BiotacPac(pac_counts=np.arange(22, dtype=np.int16))
    with Node("sender", heartbeat_s=0) as sender, Node("reader", heartbeat_s=0) as reader:
        got = []
        sub = reader.create_subscription(M.BiotacPac, got.append)
        raw = sender.create_raw_publisher("/biotac/pac")
        pub = sender.create_publisher(M.BiotacPac)
        assert raw.wait_for_subscribers(1, 20) and pub.wait_for_subscribers(1, 20)
        raw.publish_raw(pack(hostile))
        pub.publish(good)      # one socket, so it arrives after the hostile frame
        _spin_until(reader, lambda: got)
        assert got == [good.replace(stamp_ns=got[0].stamp_ns, seq=got[0].seq)]
        assert (sub.dropped, reader.malformed, sub.errors) == (1, 1, 0)


def test_any_exception_from_the_decoder_is_a_counted_drop(graph, monkeypatch):
    # Should the codec ever raise something other than MessageError, the node still survives.
    real_decode = M.decode
    calls = []

    def flaky_decode(body, cls, topic=None):
        calls.append(body)
        if len(calls) == 1:
            raise AttributeError("'NoneType' object has no attribute 'dtype'")
        return real_decode(body, cls, topic)

    monkeypatch.setattr(M, "decode", flaky_decode)
    with Node("sender", heartbeat_s=0) as sender, Node("reader", heartbeat_s=0) as reader:
        got = []
        sub = reader.create_subscription(M.BiotacPac, got.append)
        pub = sender.create_publisher(M.BiotacPac)
        assert pub.wait_for_subscribers(1, 20)
        pub.publish(sample(M.BiotacPac))
        pub.publish(sample(M.BiotacPac))
        _spin_until(reader, lambda: got)
        assert (len(got), sub.dropped, reader.malformed) == (1, 1, 1)


@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
def test_a_body_without_its_type_is_refused_by_decode_and_decode_any(cls):
    # msgspec does not require the tag of a lone tagged Struct: the wire path must still
    # refuse a body that names no type (found by the mutation test above)
    body = body_of(sample(cls))
    assert M.decode(pack(body), cls) == sample(cls)      # the wire path is built and in use
    del body["type"]
    for fn in (lambda b: M.decode(b, cls), M.decode_any):
        with pytest.raises(M.MessageError, match="type"):
            fn(pack(body))
