"""The wire contract as properties: every type round-trips; bad bytes only raise MessageError."""
from __future__ import annotations

import ast
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from incipient_slip import messages as M
from incipient_slip.messages.codec import _validate_fields, decode_named
from incipient_slip.messages.fields import Array, Scalar, field_specs

TYPES = list(M.MESSAGE_TYPES.values())


def _scalar(spec: Scalar):
    if spec.choices is not None:
        return st.sampled_from(spec.choices)
    if spec.kind is bool:
        return st.booleans()
    if spec.kind is str:
        return st.text(max_size=40)
    if spec.kind is int:
        return st.integers(spec.low, spec.high)
    return st.floats(spec.low, spec.high, allow_nan=not spec.finite,
                     allow_infinity=not spec.finite and spec.low is None and spec.high is None)


def _array(spec: Array):
    shape = tuple(3 if n is None else n for n in spec.shape)
    dtype = np.dtype(spec.dtype)
    if dtype.kind == "f":
        elements = st.floats(-1e12, 1e12, width=dtype.itemsize * 8)
    else:
        info = np.iinfo(dtype)
        elements = st.integers(int(info.min), int(info.max))
    return st.lists(elements, min_size=int(np.prod(shape)), max_size=int(np.prod(shape))).map(
        lambda xs: np.array(xs, dtype=dtype).reshape(shape))


def messages_of(cls):
    """Strategy: valid messages of `cls`, every field drawn from its declared spec."""
    return st.builds(cls, **{name: _array(spec) if isinstance(spec, Array) else _scalar(spec)
                             for name, spec in field_specs(cls)})


any_message = st.sampled_from(TYPES).flatmap(messages_of)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
@pytest.mark.parametrize("cls", TYPES, ids=lambda c: c.__name__)
def test_every_type_round_trips_through_encode_and_decode(cls, data):
    msg = data.draw(messages_of(cls))
    body = M.encode(msg)
    assert M.decode(body, cls) == msg
    assert M.decode_any(body, cls.TOPIC) == msg


@settings(max_examples=100, deadline=None)
@given(any_message)
def test_wire_decoder_agrees_with_the_naming_path(msg):
    body = M.encode(msg)
    obj = msgpack.unpackb(body, raw=False)
    assert _validate_fields(type(msg), obj, "/t") == M.decode(body, type(msg), "/t")
    assert decode_named(body, type(msg), "/t") == M.decode(body, type(msg), "/t")
    # the body is what msgpack itself packs from the same map: the bytes on the wire did not change
    assert msgpack.packb(obj, use_bin_type=True) == body


@settings(max_examples=60, deadline=None)
@given(any_message, st.integers(0, (1 << 64) - 1), st.integers(0, (1 << 64) - 1))
def test_encode_overrides_stamp_and_seq(msg, stamp, seq):
    out = M.decode(M.encode(msg, stamp_ns=stamp, seq=seq), type(msg))
    assert (out.stamp_ns, out.seq) == (stamp, seq)
    assert out == msg.replace(stamp_ns=stamp, seq=seq)


def test_topic_frames_are_exact():
    assert M.split_frames([M.topic_frame("/biotac/pac"), b"x"]) == ("/biotac/pac", b"x")
    assert not M.topic_frame("/biotac/pac_raw").startswith(M.topic_frame("/biotac/pac"))


def _decode_only_message_error(body: bytes, cls=M.BiotacPac):
    for fn in (lambda: M.decode(body, cls), lambda: M.decode_any(body)):
        try:
            fn()
        except M.MessageError as exc:
            assert exc.topic and exc.field and exc.reason
        # a mutation may leave a valid message: that is fine too


@settings(max_examples=300, deadline=None)
@given(any_message, st.data())
def test_truncated_bodies_raise_only_message_error(msg, data):
    body = M.encode(msg)
    cut = data.draw(st.integers(0, len(body) - 1))
    with pytest.raises(M.MessageError):
        M.decode_any(body[:cut])


@settings(max_examples=500, deadline=None)
@given(any_message, st.data())
def test_mutated_bodies_raise_only_message_error(msg, data):
    body = bytearray(M.encode(msg))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(body) - 1))
        body[i] = data.draw(st.integers(0, 255))
    _decode_only_message_error(bytes(body), type(msg))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_raise_only_message_error(body):
    _decode_only_message_error(body)


@settings(max_examples=200, deadline=None)
@given(any_message, st.sampled_from([None, True, -1, 1.5, "x", b"\x00", [1], {"a": 1}, (1 << 64) - 1, -(1 << 63),
                                     float("nan"), float("inf")]), st.data())
def test_wrong_field_values_raise_only_message_error(msg, bad, data):
    obj = msgpack.unpackb(M.encode(msg), raw=False)
    key = data.draw(st.sampled_from(sorted(obj)))
    obj[key] = bad
    _decode_only_message_error(msgpack.packb(obj, use_bin_type=True), type(msg))


def test_oversized_body_is_rejected_by_size_before_parsing():
    with pytest.raises(M.MessageError, match="exceeds"):
        M.decode(b"\x00" * (M.MAX_BODY_BYTES + 1), M.BiotacPac)


def test_wrong_dtype_names_topic_and_field():
    obj = msgpack.unpackb(M.encode(M.BiotacPac(pac_counts=np.zeros(22))), raw=False)
    obj["pac_counts"]["dtype"] = "<f8"
    with pytest.raises(M.MessageError) as info:
        M.decode(msgpack.packb(obj), M.BiotacPac, "/biotac/pac")
    assert (info.value.topic, info.value.field) == ("/biotac/pac", "pac_counts")


def test_constructing_a_message_copies_arrays_so_the_callers_buffer_may_change():
    buffer = np.arange(22, dtype=np.int16)
    msg = M.BiotacPac(pac_counts=buffer)
    buffer[:] = -1
    assert msg.pac_counts.tolist() == list(range(22))
    assert buffer.flags.writeable and not msg.pac_counts.flags.writeable


def test_constructor_fast_path_and_general_path_agree_on_what_is_invalid():
    with pytest.raises(M.MessageError, match="pac_counts"):
        M.BiotacPac(pac_counts=np.zeros(21, dtype=np.int16))
    with pytest.raises(M.MessageError, match="position_mm"):
        M.ObjectPose(position_mm=np.array([0.0, np.inf, 0.0]), orientation_xyzw=np.zeros(4))
    with pytest.raises(M.MessageError, match="seq"):
        M.BiotacPac(pac_counts=np.zeros(22, dtype=np.int16), seq=-1)
    # a list or another dtype is converted by the general path, not refused
    assert M.BiotacPac(pac_counts=[1] * 22).pac_counts.dtype == np.dtype("<i2")


def test_messages_import_nothing_above_them():
    # The wire contract is the bottom layer: the graph, nodes and models build on it.
    for path in Path(M.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                assert not name.startswith("incipient_slip.") or name.startswith("incipient_slip.messages"), (
                    f"{path.name} imports {name}")
