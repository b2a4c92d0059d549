"""The wire contract: every topic's typed message, its schema version and its msgpack codec.

A message is a frozen dataclass. On the wire a message is two ZeroMQ frames,
``[topic + b"\\0", msgpack body]``; the NUL ends the topic so that ZeroMQ's prefix filter
cannot confuse ``/biotac/pac`` with ``/biotac/pac_raw``. The body is a msgpack map holding
``type``, ``v`` (schema version), ``stamp_ns``, ``seq`` and the fields. numpy arrays travel as
``{"dtype": "<i2", "shape": [22], "data": <raw little-endian bytes>}``, never pickled.

Decoding validates everything and raises :class:`MessageError`, naming topic, field and reason.
Nothing outside this package builds message dicts by hand.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import msgpack
import numpy as np

__all__ = [
    "MessageError", "Message", "encode", "decode", "decode_any", "topic_frame", "split_frames",
    "MESSAGE_TYPES", "DEFAULT_TOPICS",
    "BiotacPac", "BiotacSlow", "PztCommand", "PztState", "ObjectPose", "ActuatorCommand",
    "ActuatorState", "GripCommand", "RobotState", "SlipEstimate", "RunEvent", "Heartbeat",
    "PAC_SAMPLES_PER_FRAME", "ELECTRODE_COUNT", "METHODS", "RUN_EVENT_KINDS",
]

PAC_SAMPLES_PER_FRAME = 22      # 2200 Hz P_AC in 10 ms frames (RIG.md §3)
ELECTRODE_COUNT = 19
METHODS = ("injection", "vibrotactile", "e19", "e10", "e4", "e1", "none")
RUN_EVENT_KINDS = ("start", "step", "success", "failure", "fault", "end")
MAX_BODY_BYTES = 1 << 20        # no topic of ours needs more; larger frames are hostile
MAX_STRING = 4096


class MessageError(ValueError):
    """A frame or message that breaks the wire contract; says which topic, field and why."""

    def __init__(self, topic: str, field_name: str, reason: str):
        self.topic, self.field, self.reason = topic, field_name, reason
        super().__init__(f"{topic}: field '{field_name}': {reason}")


# --- field specifications -----------------------------------------------------------------

@dataclass(frozen=True)
class ArraySpec:
    """An ndarray field: fixed dtype, shape with None for a free axis."""

    dtype: str
    shape: tuple


def array_field(dtype: str, shape: tuple, **kw):
    return field(metadata={"array": ArraySpec(np.dtype(dtype).newbyteorder("<").str, shape)}, **kw)


def scalar_field(kind: type, *, finite: bool = True, low=None, high=None, choices=None, **kw):
    """A scalar field: kind is int, float, bool or str; floats must be finite unless told."""
    return field(metadata={"kind": kind, "finite": finite, "low": low, "high": high,
                           "choices": choices}, **kw)


@dataclass(frozen=True)
class Message:
    """Base of every message: the source clock stamp and the per-publisher sequence number."""

    TOPIC: ClassVar[str] = ""
    SCHEMA_VERSION: ClassVar[int] = 1
    DESCRIPTION: ClassVar[str] = ""

    stamp_ns: int = scalar_field(int, low=0, default=0, kw_only=True)
    seq: int = scalar_field(int, low=0, default=0, kw_only=True)

    def __post_init__(self):
        # Validated and normalised on construction, so an invalid message is never encoded and
        # equality never depends on the caller's dtype or memory layout. Arrays are copied and
        # made read-only, so the caller's buffer may change afterwards. A checker generated per
        # class handles the usual case; anything unusual takes the general path, which names
        # what is wrong.
        cls = type(self)
        try:
            fast = _FAST_INIT[cls]
        except KeyError:
            fast = _FAST_INIT[cls] = _compile_fast(cls, construct=True)
        if fast(self.__dict__):
            return
        for name, spec, meta in _plan(cls):
            value = getattr(self, name)
            if spec is not None:
                arr = np.array(np.asarray(value), dtype=spec.dtype, order="C", copy=True)
                arr = _check_array(self.TOPIC, name, spec, arr)
                arr.setflags(write=False)
                object.__setattr__(self, name, arr)
            else:
                object.__setattr__(self, name, _check_scalar(self.TOPIC, name, meta, value))

    def __eq__(self, other):
        if type(self) is not type(other):
            return NotImplemented
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray):
                if a.shape != b.shape or a.dtype != b.dtype or not np.array_equal(a, b, equal_nan=True):
                    return False
            elif isinstance(a, float) and math.isnan(a):
                if not (isinstance(b, float) and math.isnan(b)):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None

    def replace(self, **changes) -> "Message":
        """A copy with some fields changed (e.g. stamp_ns and seq set by a publisher)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def schema(cls) -> dict:
        """A JSON-able description of the fields (written into MCAP schemas)."""
        fields = {}
        for f in dataclasses.fields(cls):
            if "array" in f.metadata:
                spec = f.metadata["array"]
                fields[f.name] = {"array": spec.dtype, "shape": list(spec.shape)}
            else:
                fields[f.name] = {"type": f.metadata["kind"].__name__}
        return {"type": cls.__name__, "version": cls.SCHEMA_VERSION, "topic": cls.TOPIC,
                "description": cls.DESCRIPTION, "encoding": "msgpack", "fields": fields}


# --- the messages ------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class BiotacPac(Message):
    TOPIC: ClassVar[str] = "/biotac/pac"
    DESCRIPTION: ClassVar[str] = "BioTac P_AC: 22 samples of one 10 ms frame at 2200 Hz, ADC counts"

    pac_counts: np.ndarray = array_field("<i2", (PAC_SAMPLES_PER_FRAME,))
    pa_per_count: float = scalar_field(float, low=0.0, default=0.37)


@dataclass(frozen=True, eq=False)
class BiotacSlow(Message):
    TOPIC: ClassVar[str] = "/biotac/slow"
    DESCRIPTION: ClassVar[str] = "BioTac slow channels at 100 Hz: P_DC, E1..E19, T_AC, T_DC (counts)"

    electrode_counts: np.ndarray = array_field("<u2", (ELECTRODE_COUNT,))
    pdc_counts: int = scalar_field(int, low=0, high=4095, default=0)
    tac_counts: int = scalar_field(int, low=0, high=4095, default=0)
    tdc_counts: int = scalar_field(int, low=0, high=4095, default=0)
    pdc_pa_per_count: float = scalar_field(float, low=0.0, default=36.5)
    pdc_tare_counts: int = scalar_field(int, low=0, high=4095, default=0)

    @property
    def pdc_kpa(self) -> float:
        """P_DC above the out-of-contact tare, in kPa (the paper's F_N)."""
        return (self.pdc_counts - self.pdc_tare_counts) * self.pdc_pa_per_count / 1000.0


@dataclass(frozen=True, eq=False)
class PztCommand(Message):
    TOPIC: ClassVar[str] = "/pzt/command"
    DESCRIPTION: ClassVar[str] = "Start/stop the PZT white-noise injection at intensity I dB"

    enabled: bool = scalar_field(bool, default=True)
    intensity_db: float = scalar_field(float, low=-120.0, high=20.0, default=0.0)


@dataclass(frozen=True, eq=False)
class PztState(Message):
    TOPIC: ClassVar[str] = "/pzt/state"
    DESCRIPTION: ClassVar[str] = "PZT injector state: on/off, intensity, band"

    enabled: bool = scalar_field(bool, default=False)
    intensity_db: float = scalar_field(float, low=-120.0, high=20.0, default=0.0)
    band_low_hz: float = scalar_field(float, low=0.0, default=10.0)
    band_high_hz: float = scalar_field(float, low=0.0, default=1100.0)


@dataclass(frozen=True, eq=False)
class ObjectPose(Message):
    TOPIC: ClassVar[str] = "/object/pose"
    DESCRIPTION: ClassVar[str] = ("Object pose from motion capture; travel along the rail is "
                                  "position_mm[1] (the paper's y)")

    position_mm: np.ndarray = array_field("<f8", (3,))
    orientation_xyzw: np.ndarray = array_field("<f8", (4,))
    tracking_valid: bool = scalar_field(bool, default=True)
    body_id: int = scalar_field(int, low=0, default=1)

    @property
    def travel_mm(self) -> float:
        """Object travel y along the rail, mm."""
        return float(self.position_mm[1])


@dataclass(frozen=True, eq=False)
class ActuatorCommand(Message):
    TOPIC: ClassVar[str] = "/actuator/command"
    DESCRIPTION: ClassVar[str] = "Move the linear actuator relative by move_mm (positive pulls)"

    move_mm: float = scalar_field(float, low=-50.0, high=50.0, default=0.0)


@dataclass(frozen=True, eq=False)
class ActuatorState(Message):
    TOPIC: ClassVar[str] = "/actuator/state"
    DESCRIPTION: ClassVar[str] = "Linear actuator position and step index (one step per period)"

    position_mm: float = scalar_field(float, default=0.0)
    step_index: int = scalar_field(int, low=0, default=0)
    busy: bool = scalar_field(bool, default=False)


@dataclass(frozen=True, eq=False)
class GripCommand(Message):
    TOPIC: ClassVar[str] = "/grip/command"
    DESCRIPTION: ClassVar[str] = ("Normal force target for the robot; hold=True means keep the "
                                  "last safe force (stale/invalid estimate)")

    normal_force_kpa: float = scalar_field(float, low=0.0, default=0.0)
    hold: bool = scalar_field(bool, default=False)
    period: int = scalar_field(int, low=-1, default=-1)
    reason: str = scalar_field(str, default="")


@dataclass(frozen=True, eq=False)
class RobotState(Message):
    TOPIC: ClassVar[str] = "/robot/state"
    DESCRIPTION: ClassVar[str] = "Robot end-effector state and the normal force it applies"

    normal_force_kpa: float = scalar_field(float, default=0.0)
    tcp_z_mm: float = scalar_field(float, default=0.0)
    protective_stop: bool = scalar_field(bool, default=False)


@dataclass(frozen=True, eq=False)
class SlipEstimate(Message):
    TOPIC: ClassVar[str] = "/slip/estimate"
    DESCRIPTION: ClassVar[str] = ("Estimated stick ratio of one window; valid=False after a seq "
                                  "gap or stale stream, with the reason")

    # NaN is allowed on the wire so that an invalid estimate can say "no number"; consumers
    # must check `valid` and range (the grip controller rejects NaN and values outside [0, 1]).
    stick_ratio: float = scalar_field(float, finite=False, default=float("nan"))
    valid: bool = scalar_field(bool, default=False)
    method: str = scalar_field(str, choices=METHODS, default="injection")
    window_end_ns: int = scalar_field(int, low=0, default=0)
    latency_ns: int = scalar_field(int, low=0, default=0)
    period: int = scalar_field(int, low=-1, default=-1)
    reason: str = scalar_field(str, default="")


@dataclass(frozen=True, eq=False)
class RunEvent(Message):
    TOPIC: ClassVar[str] = "/run/event"
    DESCRIPTION: ClassVar[str] = "Run lifecycle: start, step, success, failure, fault, end"

    kind: str = scalar_field(str, choices=RUN_EVENT_KINDS, default="step")
    step: int = scalar_field(int, low=0, default=0)
    detail: str = scalar_field(str, default="")
    object_travel_mm: float = scalar_field(float, finite=False, default=float("nan"))
    normal_force_kpa: float = scalar_field(float, finite=False, default=float("nan"))


@dataclass(frozen=True, eq=False)
class Heartbeat(Message):
    TOPIC: ClassVar[str] = "/heartbeat"
    DESCRIPTION: ClassVar[str] = "Node liveness with its drop and gap counters"

    node: str = scalar_field(str, default="")
    pid: int = scalar_field(int, low=0, default=0)
    uptime_s: float = scalar_field(float, low=0.0, default=0.0)
    malformed_dropped: int = scalar_field(int, low=0, default=0)
    seq_gaps: int = scalar_field(int, low=0, default=0)


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.__name__: cls for cls in (
        BiotacPac, BiotacSlow, PztCommand, PztState, ObjectPose, ActuatorCommand, ActuatorState,
        GripCommand, RobotState, SlipEstimate, RunEvent, Heartbeat)
}
DEFAULT_TOPICS: dict[str, type[Message]] = {cls.TOPIC: cls for cls in MESSAGE_TYPES.values()}


# --- codec ---------------------------------------------------------------------------------

_PLANS: dict[type, tuple] = {}


def _plan(cls) -> tuple:
    """(name, ArraySpec or None, scalar meta) per field, computed once per class (hot path)."""
    plan = _PLANS.get(cls)
    if plan is None:
        plan = _PLANS[cls] = tuple((f.name, f.metadata.get("array"), f.metadata)
                                   for f in dataclasses.fields(cls))
    return plan


def encode(msg: Message, *, stamp_ns: int | None = None, seq: int | None = None) -> bytes:
    """The msgpack body of a message (already validated when it was constructed).

    `stamp_ns` / `seq`, when given, replace the message's own (publishers set them this way
    without building a new, re-validated message on the hot path).
    """
    body = {"type": type(msg).__name__, "v": msg.SCHEMA_VERSION}
    for name, spec, _ in _plan(type(msg)):
        value = getattr(msg, name)
        body[name] = ({"dtype": spec.dtype, "shape": list(value.shape), "data": value.tobytes()}
                      if spec is not None else value)
    if stamp_ns is not None:
        if not (isinstance(stamp_ns, int) and 0 <= stamp_ns < 1 << 64):
            raise MessageError(msg.TOPIC, "stamp_ns", f"{stamp_ns!r} is not a uint64")
        body["stamp_ns"] = stamp_ns
    if seq is not None:
        if not (isinstance(seq, int) and 0 <= seq < 1 << 64):
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


def _unpack(body: bytes, topic: str) -> dict:
    if len(body) > MAX_BODY_BYTES:
        raise MessageError(topic, "<body>", f"{len(body)} bytes exceeds the {MAX_BODY_BYTES} limit")
    try:
        obj = msgpack.unpackb(body, raw=False, strict_map_key=True, max_bin_len=MAX_BODY_BYTES,
                              max_str_len=MAX_STRING, max_array_len=64, max_map_len=64)
    except Exception as exc:  # msgpack raises many types; all mean "not a message"
        raise MessageError(topic, "<body>", f"not valid msgpack ({type(exc).__name__}: {exc})") from None
    if not isinstance(obj, dict):
        raise MessageError(topic, "<body>", f"expected a map, got {type(obj).__name__}")
    return obj


def _check_scalar(topic, name, meta, value):
    kind = meta["kind"]
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, (float, int)) and not isinstance(value, bool)
        value = float(value) if ok else value
    else:
        ok = isinstance(value, str)
    if not ok:
        raise MessageError(topic, name, f"expected {kind.__name__}, got {type(value).__name__}")
    if kind is float and meta["finite"] and not math.isfinite(value):
        raise MessageError(topic, name, f"must be finite, got {value}")
    if kind is int and not (-(1 << 63) <= value < (1 << 64)):
        raise MessageError(topic, name, f"{value} does not fit 64 bits")
    if meta["low"] is not None and value < meta["low"]:
        raise MessageError(topic, name, f"{value} is below the minimum {meta['low']}")
    if meta["high"] is not None and value > meta["high"]:
        raise MessageError(topic, name, f"{value} is above the maximum {meta['high']}")
    if meta["choices"] is not None and value not in meta["choices"]:
        raise MessageError(topic, name, f"{value!r} is not one of {', '.join(meta['choices'])}")
    return value


def _check_array(topic, name, spec: ArraySpec, value):
    if isinstance(value, np.ndarray):  # encode-side validation of our own value
        dtype, shape, data = value.dtype.str, list(value.shape), None
    elif isinstance(value, dict) and set(value) == {"dtype", "shape", "data"}:
        dtype, shape, data = value["dtype"], value["shape"], value["data"]
    else:
        raise MessageError(topic, name, "expected an array map {dtype, shape, data}")
    if dtype != spec.dtype:
        raise MessageError(topic, name, f"dtype {dtype!r}, expected {spec.dtype!r}")
    if (not isinstance(shape, list) or len(shape) != len(spec.shape)
            or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)):
        raise MessageError(topic, name, f"shape {shape!r}, expected {list(spec.shape)}")
    if any(want is not None and n != want for n, want in zip(shape, spec.shape)):
        raise MessageError(topic, name, f"shape {shape}, expected {list(spec.shape)}")
    if data is None:
        arr = value
    else:
        if not isinstance(data, bytes):
            raise MessageError(topic, name, "array data must be bytes")
        expected = math.prod(shape) * np.dtype(dtype).itemsize
        if len(data) != expected:
            raise MessageError(topic, name, f"{len(data)} data bytes for shape {shape}, expected {expected}")
        arr = np.frombuffer(data, dtype=dtype).reshape(shape)
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise MessageError(topic, name, "array holds a non-finite value")
    return arr


def _validate_fields(cls: type[Message], body: dict, topic: str) -> Message:
    """The message built from a decoded body after checking every field."""
    plan = _plan(cls)
    if len(body) != len(plan) + 2:
        known = {name for name, _, _ in plan} | {"type", "v"}
        unknown = sorted(map(str, set(body) - known))
        if unknown:
            raise MessageError(topic, unknown[0], f"unknown field for {cls.__name__}")
    msg = object.__new__(cls)
    for name, spec, meta in plan:
        try:
            value = body[name]
        except KeyError:
            raise MessageError(topic, name, f"missing (required by {cls.__name__} v{cls.SCHEMA_VERSION})") from None
        object.__setattr__(msg, name, _check_array(topic, name, spec, value) if spec is not None
                           else _check_scalar(topic, name, meta, value))
    return msg


def _header(body: dict, topic: str) -> type[Message]:
    type_name = body.get("type")
    cls = MESSAGE_TYPES.get(type_name) if isinstance(type_name, str) else None
    if cls is None:
        raise MessageError(topic, "type", f"unknown message type {type_name!r}")
    version = body.get("v")
    if version != cls.SCHEMA_VERSION:
        raise MessageError(topic, "v", f"schema version {version!r}, this build speaks {cls.SCHEMA_VERSION}")
    return cls


_FAST: dict[type, Any] = {}        # decoders of well-formed bodies
_FAST_INIT: dict[type, Any] = {}   # checkers of well-formed constructor arguments


def _scalar_lines(v: str, meta: dict, i: int, env: dict) -> list[str]:
    """Generated checks of one scalar variable `v`; each line returns None when it fails."""
    kind = meta["kind"]
    if kind is bool:
        lines = [f"    if type({v}) is not bool: return None"]
    elif kind is str:
        lines = [f"    if type({v}) is not str: return None"]
    elif kind is int:
        lines = [f"    if type({v}) is not int or not ({-(1 << 63)} <= {v} < {1 << 64}): return None"]
    else:
        lines = [f"    if type({v}) is not float:",
                 f"        if type({v}) is not int: return None",
                 f"        {v} = float({v})"]
        if meta["finite"]:
            lines.append(f"    if not isfinite({v}): return None")
    if meta["low"] is not None:
        lines.append(f"    if {v} < {meta['low']!r}: return None")
    if meta["high"] is not None:
        lines.append(f"    if {v} > {meta['high']!r}: return None")
    if meta["choices"] is not None:
        env[f"choices{i}"] = frozenset(meta["choices"])
        lines.append(f"    if {v} not in choices{i}: return None")
    return lines


def _compile_fast(cls, construct: bool = False) -> Any:
    """A checker generated once per class from its field specs, because generic per-field
    checks dominated both the receive path and message construction.

    construct=False: decodes a well-formed msgpack body to the message, or returns None.
    construct=True: checks and normalises a new message's __dict__ in place (arrays copied,
    read-only), returning True, or None when anything is unusual.
    Either way None sends the caller to the general validator, which names what is wrong.
    """
    plan = _plan(cls)
    if construct:
        src = ["def fast(body):", "    g = body.get"]
    else:
        src = ["def fast(body):", f"    if len(body) != {len(plan) + 2}: return None", "    g = body.get"]
    env: dict[str, Any] = {"isfinite": math.isfinite, "frombuffer": np.frombuffer,
                           "new": object.__new__, "cls": cls, "MISSING": object(),
                           "ndarray": np.ndarray, "allfinite": lambda a: bool(np.isfinite(a).all())}
    names = []
    for i, (name, spec, meta) in enumerate(plan):
        v = f"v{i}"
        names.append((name, v))
        src.append(f"    {v} = g({name!r}, MISSING)")
        if spec is None:
            src += _scalar_lines(v, meta, i, env)
            continue
        if any(n is None for n in spec.shape):
            return None     # free-length arrays: the general path only
        shape = tuple(spec.shape)
        env[f"dtype{i}"] = np.dtype(spec.dtype)
        if construct:
            src += [f"    if type({v}) is not ndarray or {v}.dtype != dtype{i} or {v}.shape != {shape!r}:"
                    " return None",
                    f"    {v} = {v}.copy()",
                    f"    {v}.flags.writeable = False"]
        else:
            nbytes = math.prod(shape) * np.dtype(spec.dtype).itemsize
            src += [f"    if type({v}) is not dict or len({v}) != 3: return None",
                    f"    d = {v}.get('data')",
                    f"    if type(d) is not bytes or len(d) != {nbytes} or {v}.get('dtype') != {spec.dtype!r}"
                    f" or {v}.get('shape') != {list(shape)!r}: return None",
                    f"    {v} = frombuffer(d, {spec.dtype!r}).reshape({shape!r})"]
        if np.dtype(spec.dtype).kind == "f":
            src.append(f"    if not allfinite({v}): return None")
    values = ", ".join(f"{n}={v}" for n, v in names)
    if construct:
        src += [f"    body.update({values})", "    return True"]
    else:
        src += ["    m = new(cls)", f"    m.__dict__.update({values})", "    return m"]
    exec("\n".join(src), env)  # noqa: S102 - source built above from our own field specs
    return env["fast"]


def decode(body: bytes, expected: type[Message], topic: str | None = None) -> Message:
    """The message of type `expected` in `body`; MessageError if anything is off."""
    topic = topic or expected.TOPIC
    obj = _unpack(body, topic)
    if obj.get("type") == expected.__name__ and obj.get("v") == expected.SCHEMA_VERSION:
        try:
            fast = _FAST[expected]
        except KeyError:
            fast = _FAST[expected] = _compile_fast(expected)
        msg = fast(obj) if fast is not None else None
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
    try:
        fast = _FAST[cls]
    except KeyError:
        fast = _FAST[cls] = _compile_fast(cls)
    msg = fast(obj) if fast is not None else None
    return msg if msg is not None else _validate_fields(cls, obj, topic)


def to_plain(msg: Message) -> dict:
    """A JSON/YAML-friendly dict of a message (arrays as lists), for printing and summaries."""
    out = {"type": type(msg).__name__}
    for f in dataclasses.fields(msg):
        value = getattr(msg, f.name)
        out[f.name] = value.tolist() if isinstance(value, np.ndarray) else value
    return out
