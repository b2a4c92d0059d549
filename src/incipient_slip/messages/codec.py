"""The msgpack codec: a message to its two ZeroMQ frames and back, refusing anything off-contract.

On the wire a message is two frames, ``[topic + b"\\0", msgpack body]``; the NUL ends the topic
so that ZeroMQ's prefix filter cannot confuse ``/biotac/pac`` with ``/biotac/pac_raw``. The body
is a msgpack map holding ``type``, ``v`` (schema version, an int), ``stamp_ns``, ``seq`` and the
fields. Arrays travel as ``{"dtype": "<i2", "shape": [22], "data": <raw little-endian bytes>}``,
never pickled.

Decoding turns every malformed input into :class:`MessageError` (topic, field, reason) and
nothing else: a subscriber may count and drop it.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import msgpack
import numpy as np

from incipient_slip.messages.fields import (
    MAX_BODY_BYTES, MAX_MAP, MAX_STRING, Message, MessageError, Scalar, check_scalar,
    check_wire_array, compile_checker, field_specs, scalar_check_lines,
)
from incipient_slip.messages.types import MESSAGE_TYPES

__all__ = ["encode", "decode", "decode_any", "topic_frame", "split_frames", "to_plain"]

_UINT64_END = 1 << 64


def encode(msg: Message, *, stamp_ns: int | None = None, seq: int | None = None) -> bytes:
    """The msgpack body of a message (already validated when it was constructed).

    `stamp_ns` / `seq`, when given, replace the message's own (publishers set them this way
    without building a new, re-validated message on the hot path).
    """
    body = {"type": type(msg).__name__, "v": msg.SCHEMA_VERSION}
    for name, spec in field_specs(type(msg)):
        value = getattr(msg, name)
        body[name] = (value if type(spec) is Scalar else
                      {"dtype": spec.dtype, "shape": list(value.shape), "data": value.tobytes()})
    if stamp_ns is not None:
        if not (type(stamp_ns) is int and 0 <= stamp_ns < _UINT64_END):
            raise MessageError(msg.TOPIC, "stamp_ns", f"{stamp_ns!r} is not a uint64")
        body["stamp_ns"] = stamp_ns
    if seq is not None:
        if not (type(seq) is int and 0 <= seq < _UINT64_END):
            raise MessageError(msg.TOPIC, "seq", f"{seq!r} is not a uint64")
        body["seq"] = seq
    return msgpack.packb(body, use_bin_type=True)


def topic_frame(topic: str) -> bytes:
    """The first ZeroMQ frame for a topic; NUL-terminated so prefix matching is exact."""
    return topic.encode() + b"\0"


def split_frames(frames: list[bytes]) -> tuple[str, bytes]:
    """(topic, body) of a received multipart message, or MessageError."""
    if len(frames) != 2:
        raise MessageError("?", "<frames>", f"expected 2 frames [topic, body], got {len(frames)}")
    raw_topic, body = frames
    if not raw_topic.endswith(b"\0"):
        raise MessageError(repr(raw_topic[:64]), "<topic>", "topic frame is not NUL-terminated")
    try:
        return raw_topic[:-1].decode(), body
    except UnicodeDecodeError:
        raise MessageError(repr(raw_topic[:64]), "<topic>", "topic is not UTF-8") from None


def decode(body: bytes, expected: type[Message], topic: str | None = None) -> Message:
    """The message of type `expected` in `body`; MessageError if anything is off."""
    topic = topic or expected.TOPIC
    obj = _unpack(body, topic)
    if obj.get("type") == expected.__name__:
        msg = _fast(expected)(obj)
        if msg is not None:
            return msg
    cls = _header(obj, topic)
    if cls is not expected:
        raise MessageError(topic, "type", f"got {cls.__name__}, expected {expected.__name__}")
    return _validate_fields(cls, obj, topic)


def decode_any(body: bytes, topic: str = "?") -> Message:
    """The message in `body`, of whatever type its header names (for bag and echo tools)."""
    obj = _unpack(body, topic)
    cls = _header(obj, topic)
    msg = _fast(cls)(obj)
    return msg if msg is not None else _validate_fields(cls, obj, topic)


def to_plain(msg: Message) -> dict:
    """A JSON/YAML-friendly dict of a message (arrays as lists), for printing and summaries."""
    out = {"type": type(msg).__name__}
    for f in dataclasses.fields(msg):
        value = getattr(msg, f.name)
        out[f.name] = value.tolist() if isinstance(value, np.ndarray) else value
    return out


# --- the general (naming) path ---------------------------------------------------------------

def _unpack(body: bytes, topic: str) -> dict:
    if not isinstance(body, (bytes, bytearray, memoryview)):
        raise MessageError(topic, "<body>", f"expected bytes, got {type(body).__name__}")
    if len(body) > MAX_BODY_BYTES:
        raise MessageError(topic, "<body>", f"{len(body)} bytes exceeds the {MAX_BODY_BYTES} limit")
    try:
        obj = msgpack.unpackb(body, raw=False, strict_map_key=True, max_bin_len=MAX_BODY_BYTES,
                              max_str_len=MAX_STRING, max_array_len=MAX_MAP, max_map_len=MAX_MAP,
                              max_ext_len=MAX_STRING)
    except Exception as exc:  # msgpack raises many types; all mean "not a message"
        raise MessageError(topic, "<body>", f"not valid msgpack ({type(exc).__name__}: {exc})") from None
    if not isinstance(obj, dict):
        raise MessageError(topic, "<body>", f"expected a map, got {type(obj).__name__}")
    return obj


def _header(body: dict, topic: str) -> type[Message]:
    type_name = body.get("type")
    cls = MESSAGE_TYPES.get(type_name) if isinstance(type_name, str) else None
    if cls is None:
        raise MessageError(topic, "type", f"unknown message type {type_name!r}")
    version = body.get("v")
    if type(version) is not int or version != cls.SCHEMA_VERSION:  # 1.0 and true are not 1
        raise MessageError(topic, "v", f"schema version {version!r}, this build speaks the int "
                                       f"{cls.SCHEMA_VERSION}")
    return cls


def _validate_fields(cls: type[Message], body: dict, topic: str) -> Message:
    """The message built from a decoded body after checking every field (and naming the first
    that is wrong)."""
    specs = field_specs(cls)
    known = {name for name, _ in specs} | {"type", "v"}
    unknown = sorted(k if isinstance(k, str) and k else repr(k) for k in set(body) - known)
    if unknown:
        raise MessageError(topic, unknown[0], f"unknown field for {cls.__name__}")
    msg = object.__new__(cls)
    for name, spec in specs:
        try:
            value = body[name]
        except KeyError:
            raise MessageError(topic, name, f"missing (required by {cls.__name__} v{cls.SCHEMA_VERSION})") from None
        object.__setattr__(msg, name, check_scalar(topic, name, spec, value) if type(spec) is Scalar
                           else check_wire_array(topic, name, spec, value))
    return msg


# --- the fast path: well-formed bodies -------------------------------------------------------

_FAST: dict[type, Any] = {}


def _fast(cls) -> Any:
    """The generated decoder of `cls` (message, or None for anything unusual)."""
    try:
        return _FAST[cls]
    except KeyError:
        fast = _FAST[cls] = _compile_decoder(cls)
        return fast


def _compile_decoder(cls) -> Any:
    """Decodes a well-formed msgpack map (header included) to the message, or returns None;
    generated once per class from its field specs because generic per-field checks dominated
    the receive path. None sends the caller to the general path, which names what is wrong.
    """
    specs = field_specs(cls)
    src = ["def fast(body):",
           f"    if len(body) != {len(specs) + 2}: return None",
           "    g = body.get",
           "    v = g('v')",
           f"    if type(v) is not int or v != {cls.SCHEMA_VERSION}: return None"]
    env: dict[str, Any] = {"frombuffer": np.frombuffer, "new": object.__new__, "cls": cls}
    names = []
    for i, (name, spec) in enumerate(specs):
        v = f"v{i}"
        names.append(f"{name}={v}")
        src.append(f"    {v} = g({name!r})")
        if type(spec) is Scalar:
            src += scalar_check_lines(v, spec, i, env)
            continue
        if any(n is None for n in spec.shape):
            return lambda body: None     # free-length arrays: the general path only
        shape = tuple(spec.shape)
        nbytes = math.prod(shape) * np.dtype(spec.dtype).itemsize
        shape_ok = " and ".join([f"type(s) is list and len(s) == {len(shape)}"]
                                + [f"type(s[{j}]) is int and s[{j}] == {n}" for j, n in enumerate(shape)])
        src += [f"    if type({v}) is not dict or len({v}) != 3: return None",
                f"    d = {v}.get('data')",
                f"    s = {v}.get('shape')",
                f"    if type(d) is not bytes or len(d) != {nbytes} or {v}.get('dtype') != {spec.dtype!r}"
                f" or not ({shape_ok}): return None",
                f"    {v} = frombuffer(d, {spec.dtype!r}).reshape({shape!r})"]
        if np.dtype(spec.dtype).kind == "f":
            src.append(f"    if not allfinite({v}): return None")
    src += ["    m = new(cls)", f"    m.__dict__.update({', '.join(names)})", "    return m"]
    return compile_checker("fast", src, env)
