"""Field kinds of the wire contract: what a field may hold, its msgpack type, unit and bounds.

Every message field is declared with one of `integer`, `real`, `flag`, `text` or `array`; the
declaration is the one source for validation (construction and decoding), for the JSON schema
written into recordings and for docs/messages.md. Integers carry an explicit width and
signedness (a stamp is a uint64 and may exceed 2**53, so it is not a JSON/JavaScript number);
floats are float64 and finite unless a field allows NaN; strings are UTF-8 with a byte limit;
arrays are little-endian numpy dtypes with a fixed shape.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

__all__ = ["MessageError", "Message", "Scalar", "Array", "integer", "real", "flag", "text",
           "array", "field_specs", "INT_RANGES", "MAX_BODY_BYTES", "MAX_STRING"]

MAX_BODY_BYTES = 1 << 20        # no topic of ours needs more; larger frames are hostile
MAX_STRING = 4096               # UTF-8 bytes of any string in a body (keys included)
MAX_MAP = 64                    # entries of any msgpack map or array in a body

# Integer widths on the wire: (smallest, largest) value, both inclusive.
INT_RANGES = {
    "uint16": (0, (1 << 16) - 1),
    "uint32": (0, (1 << 32) - 1),
    "int64": (-(1 << 63), (1 << 63) - 1),
    "uint64": (0, (1 << 64) - 1),
}


class MessageError(ValueError):
    """A frame or message that breaks the wire contract; says which topic, field and why."""

    def __init__(self, topic: str, field_name: str, reason: str):
        self.topic, self.field, self.reason = topic, field_name, reason
        super().__init__(f"{topic}: field '{field_name}': {reason}")


@dataclass(frozen=True)
class Scalar:
    """A scalar field: its Python kind, wire type, unit and inclusive bounds."""

    kind: type                      # bool, int, float or str after decoding
    wire: str                       # "bool", "str", "float64" or a key of INT_RANGES
    unit: str = ""
    low: Any = None                 # ints: always set (the width's range at least)
    high: Any = None
    finite: bool = True             # floats: NaN and +-inf refused unless False
    choices: tuple | None = None    # str: the only values allowed
    max_bytes: int = MAX_STRING     # str: UTF-8 length limit
    note: str = ""


@dataclass(frozen=True)
class Array:
    """An ndarray field: little-endian dtype string, fixed shape, unit; floats always finite."""

    dtype: str
    shape: tuple
    unit: str = ""
    note: str = ""


def _declare(spec, default, kw) -> Any:
    if default is not dataclasses.MISSING:
        kw["default"] = default
    return dataclasses.field(metadata={"spec": spec}, **kw)


def integer(wire: str, default: int = 0, *, unit: str = "", low: int | None = None,
            high: int | None = None, note: str = "", **kw) -> Any:
    """A field holding an integer of width `wire` (e.g. "uint32"), optionally narrower."""
    wire_low, wire_high = INT_RANGES[wire]
    low = wire_low if low is None else low
    high = wire_high if high is None else high
    assert wire_low <= low <= high <= wire_high, (wire, low, high)
    return _declare(Scalar(int, wire, unit, low, high, note=note), default, kw)


def real(default: float = 0.0, *, unit: str = "", low: float | None = None,
         high: float | None = None, nan: bool = False, note: str = "", **kw) -> Any:
    """A float64 field; finite unless `nan` (then NaN and +-inf travel too)."""
    return _declare(Scalar(float, "float64", unit, low, high, finite=not nan, note=note), default, kw)


def flag(default: bool = False, *, note: str = "", **kw) -> Any:
    """A bool field (msgpack true/false; 0 and 1 are not bools)."""
    return _declare(Scalar(bool, "bool", note=note), default, kw)


def text(default: str = "", *, choices: tuple | None = None, max_bytes: int = MAX_STRING,
         note: str = "", **kw) -> Any:
    """A UTF-8 string field of at most `max_bytes` bytes, or one of `choices`."""
    assert max_bytes <= MAX_STRING
    return _declare(Scalar(str, "str", choices=choices, max_bytes=max_bytes, note=note), default, kw)


def array(dtype: str, shape: tuple, *, unit: str = "", note: str = "", **kw) -> Any:
    """A fixed-shape numpy array field; `dtype` is normalised to its little-endian string."""
    spec = Array(np.dtype(dtype).newbyteorder("<").str, tuple(shape), unit, note)
    return _declare(spec, kw.pop("default", dataclasses.MISSING), kw)


_SPECS: dict[type, tuple] = {}


def field_specs(cls) -> tuple:
    """((name, Scalar or Array), ...) of a message class in declaration order (cached: hot path)."""
    specs = _SPECS.get(cls)
    if specs is None:
        specs = _SPECS[cls] = tuple((f.name, f.metadata["spec"]) for f in dataclasses.fields(cls))
    return specs


# --- validation ----------------------------------------------------------------------------

def check_scalar(topic: str, name: str, spec: Scalar, value):
    """`value` normalised to the field's kind, or MessageError naming what is wrong."""
    kind = spec.kind
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        value = int(value) if ok else value
    elif kind is float:
        ok = isinstance(value, (float, int)) and not isinstance(value, bool)
        if ok:
            try:
                value = float(value)
            except OverflowError:
                raise MessageError(topic, name, f"{value} does not fit a float64") from None
    else:
        ok = isinstance(value, str)
    if not ok:
        raise MessageError(topic, name, f"expected {spec.wire}, got {type(value).__name__}")
    if kind is float and spec.finite and not math.isfinite(value):
        raise MessageError(topic, name, f"must be finite, got {value}")
    if kind is str:
        try:
            size = len(value.encode("utf-8"))
        except UnicodeEncodeError:
            raise MessageError(topic, name, "not encodable as UTF-8 (lone surrogate)") from None
        if size > spec.max_bytes:
            raise MessageError(topic, name, f"{size} UTF-8 bytes exceeds the {spec.max_bytes} limit")
    if spec.low is not None and value < spec.low:
        what = f"a {spec.wire}" if kind is int and spec.low == INT_RANGES[spec.wire][0] else "allowed"
        raise MessageError(topic, name, f"{value} is below the minimum {spec.low} ({what})")
    if spec.high is not None and value > spec.high:
        what = f"a {spec.wire}" if kind is int and spec.high == INT_RANGES[spec.wire][1] else "allowed"
        raise MessageError(topic, name, f"{value} is above the maximum {spec.high} ({what})")
    if spec.choices is not None and value not in spec.choices:
        raise MessageError(topic, name, f"{value!r} is not one of {', '.join(spec.choices)}")
    return value


def check_wire_array(topic: str, name: str, spec: Array, value) -> np.ndarray:
    """The read-only array a decoded `{dtype, shape, data}` map holds, or MessageError."""
    if not isinstance(value, dict) or set(value) != {"dtype", "shape", "data"}:
        raise MessageError(topic, name, "expected an array map {dtype, shape, data}")
    dtype, shape, data = value["dtype"], value["shape"], value["data"]
    if not isinstance(dtype, str) or dtype != spec.dtype:
        raise MessageError(topic, name, f"dtype {dtype!r}, expected {spec.dtype!r}")
    _check_shape(topic, name, spec, shape)
    if not isinstance(data, bytes):
        raise MessageError(topic, name, f"array data must be bytes (msgpack bin), got {type(data).__name__}")
    expected = math.prod(shape) * np.dtype(dtype).itemsize
    if len(data) != expected:
        raise MessageError(topic, name, f"{len(data)} data bytes for shape {shape}, expected {expected}")
    return _check_finite(topic, name, np.frombuffer(data, dtype=dtype).reshape(shape))


def check_new_array(topic: str, name: str, spec: Array, value) -> np.ndarray:
    """A read-only C-ordered copy of `value` in the field's dtype, or MessageError.

    Lists and other dtypes are converted, but only when no value changes (an int16 field does
    not silently wrap 40000 or truncate 1.5).
    """
    try:
        given = np.asarray(value)
        with np.errstate(invalid="ignore", over="ignore"):     # a lossy cast is refused below
            arr = np.array(given, dtype=spec.dtype, order="C", copy=True)
    except (TypeError, ValueError, OverflowError) as exc:
        raise MessageError(topic, name, f"not an array of {spec.dtype} ({exc})") from None
    _check_shape(topic, name, spec, list(arr.shape))
    if given.dtype != arr.dtype and arr.dtype.kind in "iu":
        if given.dtype.kind not in "biuf" or not np.array_equal(arr, given):
            raise MessageError(topic, name, f"values of dtype {given.dtype} do not fit {spec.dtype}")
    arr = _check_finite(topic, name, arr)
    arr.setflags(write=False)
    return arr


def _check_shape(topic, name, spec: Array, shape) -> None:
    if (not isinstance(shape, list) or len(shape) != len(spec.shape)
            or not all(type(n) is int and (n == want or want is None and 0 <= n <= MAX_BODY_BYTES)
                       for n, want in zip(shape, spec.shape))):
        raise MessageError(topic, name, f"shape {shape!r}, expected {list(spec.shape)}")


def _check_finite(topic, name, arr: np.ndarray) -> np.ndarray:
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise MessageError(topic, name, "array holds a non-finite value")
    return arr


# --- generated checkers (the hot path) -----------------------------------------------------

def scalar_check_lines(v: str, spec: Scalar, i: int, env: dict) -> list[str]:
    """Generated checks of one scalar variable `v`; each line returns None when it fails.

    Anything unusual fails here and goes to the general path (check_scalar), which names it.
    """
    kind = spec.kind
    if kind is bool:
        lines = [f"    if type({v}) is not bool: return None"]
    elif kind is str:
        lines = [f"    if type({v}) is not str or not {v}.isascii() or len({v}) > {spec.max_bytes}:"
                 " return None"]
    elif kind is int:
        lines = [f"    if type({v}) is not int or not ({spec.low} <= {v} <= {spec.high}): return None"]
    else:
        lines = [f"    if type({v}) is not float:",
                 f"        if type({v}) is not int or not (-{1 << 53} <= {v} <= {1 << 53}): return None",
                 f"        {v} = float({v})"]
        if spec.finite:
            lines.append(f"    if not isfinite({v}): return None")
    if kind is not int:
        if spec.low is not None:
            lines.append(f"    if {v} < {spec.low!r}: return None")
        if spec.high is not None:
            lines.append(f"    if {v} > {spec.high!r}: return None")
    if spec.choices is not None:
        env[f"choices{i}"] = frozenset(spec.choices)
        lines.append(f"    if {v} not in choices{i}: return None")
    return lines


def compile_checker(name: str, lines: list[str], env: dict) -> Any:
    """The function `name` defined by `lines`, executed in `env` (source built from our specs)."""
    env.setdefault("isfinite", math.isfinite)
    env.setdefault("allfinite", lambda a: bool(np.isfinite(a).all()))
    exec("\n".join(lines), env)  # noqa: S102 - generated from our own field specs, never input
    return env[name]


def _compile_init(cls) -> Any:
    """Checks and normalises a new message's __dict__ in place, returning True, or None when
    anything is unusual (then the general path in Message.__post_init__ names it).

    Generated once per class because generic per-field checks dominated construction time.
    """
    src = ["def fast(d):", "    g = d.get"]
    env: dict[str, Any] = {"ndarray": np.ndarray}
    names = []
    for i, (name, spec) in enumerate(field_specs(cls)):
        v = f"v{i}"
        names.append(f"{name}={v}")
        src.append(f"    {v} = g({name!r})")
        if isinstance(spec, Scalar):
            src += scalar_check_lines(v, spec, i, env)
            continue
        if any(n is None for n in spec.shape):
            return lambda d: None
        env[f"dtype{i}"] = np.dtype(spec.dtype)
        src += [f"    if type({v}) is not ndarray or {v}.dtype != dtype{i} or {v}.shape != {spec.shape!r}:"
                " return None",
                f"    {v} = {v}.copy()",
                f"    {v}.flags.writeable = False"]
        if np.dtype(spec.dtype).kind == "f":
            src.append(f"    if not allfinite({v}): return None")
    src += [f"    d.update({', '.join(names)})", "    return True"]
    return compile_checker("fast", src, env)


_FAST_INIT: dict[type, Any] = {}


@dataclass(frozen=True)
class Message:
    """Base of every message: the source clock stamp and the per-publisher sequence number."""

    TOPIC: ClassVar[str] = ""
    SCHEMA_VERSION: ClassVar[int] = 1
    DESCRIPTION: ClassVar[str] = ""
    # A state sent once and then only on change: a publisher re-sends its last one to each
    # subscriber that joins later (ROS 2's transient-local durability, depth 1; graph/runtime.py)
    LATCHED: ClassVar[bool] = False

    stamp_ns: int = integer("uint64", unit="ns", kw_only=True,
                            note="source clock, ns since the Unix epoch (exceeds 2**53)")
    seq: int = integer("uint64", kw_only=True, note="per publisher and topic, +1 per message")

    def __post_init__(self):
        # Validated and normalised on construction, so an invalid message is never encoded and
        # equality never depends on the caller's dtype or memory layout. Arrays are copied and
        # made read-only, so the caller's buffer may change afterwards.
        cls = type(self)
        try:
            fast = _FAST_INIT[cls]
        except KeyError:
            fast = _FAST_INIT[cls] = _compile_init(cls)
        if fast(self.__dict__):
            return
        for name, spec in field_specs(cls):
            value = getattr(self, name)
            checked = (check_scalar(self.TOPIC, name, spec, value) if isinstance(spec, Scalar)
                       else check_new_array(self.TOPIC, name, spec, value))
            object.__setattr__(self, name, checked)

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
        """A JSON-able description of the type and every field's wire contract (the one source
        of the JSON schema in recordings and of docs/messages.md)."""
        return {"type": cls.__name__, "version": cls.SCHEMA_VERSION, "topic": cls.TOPIC,
                "description": cls.DESCRIPTION, "encoding": "msgpack",
                "fields": {name: describe(spec) for name, spec in field_specs(cls)}}


def describe(spec: Scalar | Array) -> dict:
    """A JSON-able description of one field: wire type, bounds, unit, NaN rule, limits."""
    if isinstance(spec, Array):
        desc = {"array": spec.dtype, "shape": list(spec.shape)}
    else:
        desc = {"type": spec.kind.__name__, "wire": spec.wire}
        if spec.low is not None:
            desc["min"] = spec.low
        if spec.high is not None:
            desc["max"] = spec.high
        if spec.kind is float:
            desc["nan"] = not spec.finite
        if spec.kind is str:
            desc["max_bytes"] = spec.max_bytes
        if spec.choices is not None:
            desc["enum"] = list(spec.choices)
    if spec.unit:
        desc["unit"] = spec.unit
    if spec.note:
        desc["note"] = spec.note
    return desc
