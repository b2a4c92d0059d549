"""The msgpack codec: a message to its two ZeroMQ frames and back, refusing anything off-contract.

On the wire a message is two frames, ``[topic + b"\\0", msgpack body]``; the NUL ends the topic
so that ZeroMQ's prefix filter cannot confuse ``/biotac/pac`` with ``/biotac/pac_raw``. The body
is a msgpack map holding ``type``, ``v`` (schema version, an int), ``stamp_ns``, ``seq`` and the
fields. Arrays travel as ``{"dtype": "<i2", "shape": [22], "data": <raw little-endian bytes>}``,
never pickled.

Decoding turns every malformed input into :class:`MessageError` (topic, field, reason) and
nothing else: a subscriber may count and drop it. Two paths, both derived from the field specs:
the wire path (msgspec Structs decode and validate in one pass) takes every well-formed body;
whatever it refuses goes to the naming path (msgpack, then each field checked), which decides
and names the first wrong field. The wire path never accepts what the naming path refuses.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Annotated, Any, Literal, Union

import msgpack
import msgspec
import numpy as np

from incipient_slip.messages.fields import (
    MAX_BODY_BYTES, MAX_MAP, MAX_STRING, Array, Message, MessageError, Scalar, check_scalar,
    check_wire_array, compile_checker, field_specs,
)
from incipient_slip.messages.types import MESSAGE_TYPES

__all__ = ["encode", "body_encoder", "decode", "decode_any", "decode_named", "topic_frame", "split_frames", "to_plain"]

_UINT64_END = 1 << 64


def encode(msg: Message, *, stamp_ns: int | None = None, seq: int | None = None) -> bytes:
    """The msgpack body of a message (already validated when it was constructed).

    `stamp_ns` / `seq`, when given, replace the message's own (publishers set them this way
    without building a new, re-validated message on the hot path).
    """
    if stamp_ns is not None and not (type(stamp_ns) is int and 0 <= stamp_ns < _UINT64_END):
        raise MessageError(msg.TOPIC, "stamp_ns", f"{stamp_ns!r} is not a uint64")
    if seq is not None and not (type(seq) is int and 0 <= seq < _UINT64_END):
        raise MessageError(msg.TOPIC, "seq", f"{seq!r} is not a uint64")
    return body_encoder(type(msg))(msg, msg.stamp_ns if stamp_ns is None else stamp_ns,
                                   msg.seq if seq is None else seq)


def body_encoder(cls: type[Message]) -> Any:
    """The body encoder of `cls`, (msg, stamp_ns, seq) -> bytes, for callers whose stamp_ns and
    seq are uint64 already (a publisher's); generated once per class from its field specs."""
    try:
        return _ENCODERS[cls]
    except KeyError:
        enc = _ENCODERS[cls] = _compile_encoder(cls)
        return enc


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
    try:
        msg = _wire(body)
        if type(msg) is expected:
            return msg
    except Exception:  # refused or unusual: the naming path decides, and says what is wrong
        pass
    return decode_named(body, expected, topic)


def decode_any(body: bytes, topic: str = "?") -> Message:
    """The message in `body`, of whatever type its header names (for bag and echo tools)."""
    try:
        return _wire(body)
    except Exception:  # refused or unusual: the naming path decides, and says what is wrong
        obj = _unpack(body, topic)
        return _validate_fields(_header(obj, topic), obj, topic)


def to_plain(msg: Message) -> dict:
    """A JSON/YAML-friendly dict of a message (arrays as lists), for printing and summaries."""
    out = {"type": type(msg).__name__}
    for f in dataclasses.fields(msg):
        value = getattr(msg, f.name)
        out[f.name] = value.tolist() if isinstance(value, np.ndarray) else value
    return out


# --- the general (naming) path ---------------------------------------------------------------

def decode_named(body: bytes, expected: type[Message], topic: str | None = None) -> Message:
    """`decode` by the naming path only (msgpack, then every field checked and the first wrong one
    named): what the wire path falls back to, and is tested and measured against."""
    topic = topic or expected.TOPIC
    obj = _unpack(body, topic)
    cls = _header(obj, topic)
    if cls is not expected:
        raise MessageError(topic, "type", f"got {cls.__name__}, expected {expected.__name__}")
    return _validate_fields(cls, obj, topic)


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


# --- the wire path: msgspec decodes and validates well-formed bodies --------------------------
#
# A msgspec Struct per message type, generated from the same field specs (tagged by "type",
# unknown fields forbidden; ints with their width's bounds, enums as Literals, array maps as
# nested Structs with the exact dtype, shape and byte length), plus the checks msgspec has no
# constraint for (finite floats and arrays, the UTF-8 byte limit of non-ASCII strings). It only
# accepts what the naming path accepts, and builds the same message; anything it refuses goes
# to the naming path, which refuses it with the field and the reason (or, for what msgspec is
# stricter about, accepts it).

_INT64 = (-(1 << 63), (1 << 63) - 1)      # msgspec's integer bounds must fit an int64
_ENCODERS: dict[type, Any] = {}           # message type -> (msg, stamp_ns, seq) -> body
def _scalar_type(spec: Scalar) -> Any:
    if spec.choices is not None:
        return Literal[spec.choices]
    if spec.kind is bool:
        return bool
    if spec.kind is str:
        return Annotated[str, msgspec.Meta(max_length=spec.max_bytes)]
    bounds = {}
    if spec.low is not None and (spec.kind is float or _INT64[0] <= spec.low <= _INT64[1]):
        bounds["ge"] = spec.low
    if spec.high is not None and (spec.kind is float or _INT64[0] <= spec.high <= _INT64[1]):
        bounds["le"] = spec.high
    return Annotated[spec.kind, msgspec.Meta(**bounds)] if bounds else spec.kind


def _array_type(cls, name: str, spec: Array) -> Any:
    nbytes = math.prod(spec.shape) * np.dtype(spec.dtype).itemsize
    return msgspec.defstruct(
        f"{cls.__name__}_{name}",
        [("dtype", Literal[spec.dtype]),
         ("shape", tuple[tuple(Literal[n] for n in spec.shape)]),
         ("data", Annotated[bytes, msgspec.Meta(min_length=nbytes, max_length=nbytes)])],
        forbid_unknown_fields=True, array_like=False)


def _wire_struct(cls) -> Any:
    """The msgspec Struct of `cls`'s body, or None if a field has no exact wire type."""
    fields = [("v", Literal[cls.SCHEMA_VERSION])]
    for name, spec in field_specs(cls):
        if type(spec) is Array and any(n is None for n in spec.shape):
            return None     # free-length arrays: the naming path only
        fields.append((name, _scalar_type(spec) if type(spec) is Scalar else _array_type(cls, name, spec)))
    return msgspec.defstruct(f"{cls.__name__}Wire", fields, tag_field="type", tag=cls.__name__,
                             forbid_unknown_fields=True)


def _wire(body) -> Message:
    """The wire decoder, built on first use (not at import: `slip --help` need not pay for it)."""
    global _wire
    _wire = _compile_wire_decoder()
    return _wire(body)


def _compile_wire_decoder() -> Any:
    """body -> message of the type its header names, raising on anything the wire types or
    the extra checks refuse (the caller then asks the naming path). One tagged union of every
    type: msgspec requires the tag of a union member, not of a lone tagged Struct."""
    structs = {c: _wire_struct(c) for c in MESSAGE_TYPES.values()}
    structs = {c: w for c, w in structs.items() if w is not None}
    assert len(structs) > 1, "a union of one type would not require its tag"
    env: dict[str, Any] = {"frombuffer": np.frombuffer, "new": object.__new__, "max_body": MAX_BODY_BYTES}
    src = []
    for k, (c, wire) in enumerate(structs.items()):
        env[f"cls{k}"] = c
        src += [f"def build{k}(w):", f"    m = new(cls{k})"]
        names = []
        for i, (name, spec) in enumerate(field_specs(c)):
            names.append(f"{name}=v{i}")
            src.append(f"    v{i} = w.{name}")
            if type(spec) is Array:
                reshape = "" if len(spec.shape) == 1 else f".reshape({tuple(spec.shape)!r})"
                src.append(f"    v{i} = frombuffer(v{i}.data, {spec.dtype!r}){reshape}")
                if np.dtype(spec.dtype).kind == "f":
                    src.append(f"    if not allfinite(v{i}): raise ValueError")
            elif spec.kind is float and spec.finite:
                src.append(f"    if not isfinite(v{i}): raise ValueError")
            elif spec.kind is str and spec.choices is None:
                src.append(f"    if not v{i}.isascii() and len(v{i}.encode()) > {spec.max_bytes}: raise ValueError")
        src += [f"    m.__dict__.update({', '.join(names)})", "    return m"]
    union = list(structs.values())
    env["decode_wire"] = msgspec.msgpack.Decoder(Union[tuple(union)]).decode
    src += ["def wire(body):",
            "    if len(body) > max_body: raise ValueError",
            "    w = decode_wire(body)",
            "    return builders[type(w)](w)"]
    fn = compile_checker("wire", src, env)
    env["builders"] = {w: env[f"build{k}"] for k, w in enumerate(union)}
    return fn


def _compile_encoder(cls) -> Any:
    """(msg, stamp_ns, seq) -> the msgpack body of `cls` (header first, fields in declaration
    order); generated from the field specs, as a generic loop over them dominated encoding."""
    items = [f"'type': {cls.__name__!r}", f"'v': {cls.SCHEMA_VERSION}"]
    for name, spec in field_specs(cls):
        value = {"stamp_ns": "stamp_ns", "seq": "seq"}.get(name, f"m.{name}")
        if type(spec) is Array:
            # construction made a fixed shape exactly the declared one
            shape = f"list(m.{name}.shape)" if None in spec.shape else repr(list(spec.shape))
            value = f"{{'dtype': {spec.dtype!r}, 'shape': {shape}, 'data': m.{name}.tobytes()}}"
        items.append(f"{name!r}: {value}")
    src = ["def encode(m, stamp_ns, seq):", f"    return pack({{{', '.join(items)}}})"]
    return compile_checker("encode", src, {"pack": msgspec.msgpack.Encoder().encode})
