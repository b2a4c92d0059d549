"""`slip bag export --foxglove`: a recording as JSON channels that Foxglove and Lichtblick open.

Those viewers do not read msgpack (PlotJuggler does, from the recording as it is). The
export writes, per recorded topic, a channel with ``message_encoding="json"`` and a
``jsonschema`` schema of the JSON object, and for every BiotacPac topic a second channel
``<topic>/audio`` of Foxglove's well-known ``foxglove.RawAudio`` (pcm-s16, mono, upsampled to
8800 Hz: see AUDIO_RATE_HZ), for the Audio panel. Each message is logged at its stamp (MCAP log
and publish time), the run's one time base, as the live view logs it (docs/graph.md, "One time
base"); the receive times stay in the recording. Seqs are kept.

JSON of one message: the wire fields (``type``, ``v``, ``stamp_ns``, ``seq``, the message's
fields) plus ``stamp`` = ``{"sec", "nsec"}``, the stamp as Foxglove's time type, exact for
every uint64 stamp. Arrays are (nested) lists. JSON has no NaN: a non-finite float is
``null``. JavaScript reads numbers as doubles, exact only up to 2^53: an integer beyond
±(2^53 - 1) (every wall-clock ``stamp_ns`` is, ~1.7e18) is written as a decimal string,
never rounded; the schema says so per field, and the export counts such values.
"""
from __future__ import annotations

import base64
import json
import math
import os
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from incipient_slip.graph.bag import BagError, BagWriter, bag_info, json_schema, read_bag
from incipient_slip.messages import MESSAGE_TYPES, PAC_RATE_HZ, BiotacPac, Message

__all__ = ["export_foxglove", "export_schema", "standard_keywords", "to_export_json", "raw_audio", "raw_audio_block", "RAW_AUDIO_SCHEMA",
           "ExportReport", "JS_SAFE_INT", "AudioUpsampler", "AUDIO_RATE_HZ"]

JS_SAFE_INT = (1 << 53) - 1     # the largest integer a JavaScript number holds exactly
AUDIO_SUFFIX = "/audio"
# RawAudio's rate: P_AC's 2200 Hz x 4. Viewers' Audio panels play through a browser engine's Web
# Audio, whose AudioBuffer must accept 8-96 kHz (Chromium's floor is 3 kHz): 2200 Hz may not play.
AUDIO_RATE_HZ = 4 * PAC_RATE_HZ

_TIME = {"type": "object", "title": "time",
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
         "required": ["sec", "nsec"], "additionalProperties": False}
_BIG_INT = {"type": "string", "pattern": "^-?[0-9]+$",
            "description": "an integer beyond +-(2^53 - 1), as decimal digits (exact)"}
_NON_FINITE = {"type": "null", "description": "NaN or +-inf (JSON has no NaN)"}

# Foxglove's published foxglove.RawAudio (JSON encoding: bytes as base64), written from its
# field list: timestamp, data, format, sample_rate, number_of_channels.
RAW_AUDIO_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "foxglove.RawAudio", "description": "A single block of an audio bitstream",
    "type": "object",
    "properties": {
        "timestamp": {**_TIME, "description": "Timestamp of the start of the audio block"},
        "data": {"type": "string", "contentEncoding": "base64",
                 "description": "Audio data; samples interleaved and little-endian"},
        "format": {"type": "string", "description": "Audio format: 'pcm-s16'"},
        "sample_rate": {"type": "integer", "minimum": 0, "description": "Sample rate in Hz"},
        "number_of_channels": {"type": "integer", "minimum": 0,
                               "description": "Number of channels in the audio block"},
    },
    "required": ["timestamp", "data", "format", "sample_rate", "number_of_channels"],
}


def _time(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _int_schema(base: dict) -> dict:
    """`base` (an integer field's wire schema), or it or a digit string if it may pass 2^53."""
    lo, hi = base.get("minimum"), base.get("maximum")
    if lo is not None and hi is not None and -JS_SAFE_INT <= lo and hi <= JS_SAFE_INT:
        return base
    return {"anyOf": [base, _BIG_INT]}


def _array_schema(dtype: str, shape: list) -> dict:
    kind = np.dtype(dtype)
    if kind.kind in "iu":
        info = np.iinfo(kind)
        item = _int_schema({"type": "integer", "minimum": int(info.min), "maximum": int(info.max)})
    elif kind.kind == "b":
        item = {"type": "boolean"}
    else:
        item = {"anyOf": [{"type": "number"}, _NON_FINITE]}
    for n in reversed(shape):
        item = {"type": "array", "items": item,
                **({"minItems": n, "maxItems": n} if n is not None else {})}
    return {**item, "description": f"numpy array, dtype {dtype}, shape {shape}, as nested lists"}


def export_schema(msg_type: type[Message]) -> dict:
    """The JSON Schema (2020-12) of `msg_type` as exported: the wire schema's fields as JSON."""
    wire = json_schema(msg_type)
    fields = msg_type.schema()["fields"]
    props = {}
    for name, prop in wire["properties"].items():
        spec = fields.get(name, {})
        if "array" in spec:
            props[name] = _array_schema(spec["array"], spec["shape"])
        elif spec.get("type") == "int":
            props[name] = _int_schema(prop)
        elif spec.get("type") == "float":
            props[name] = {"anyOf": [prop, _NON_FINITE]}
        else:                   # bool, str, and the type/v constants
            props[name] = prop
    props["stamp"] = {**_TIME, "description": "stamp_ns as Foxglove's time type (exact)"}
    return standard_keywords({"$schema": "https://json-schema.org/draft/2020-12/schema",
                              "title": wire.get("title", msg_type.__name__),
                              "description": (wire.get("description") or "") + " (JSON export of the msgpack wire form)",
                              "type": "object", "properties": props, "required": list(props),
                              "additionalProperties": False})


def standard_keywords(schema):
    """`schema` with only standard JSON Schema keywords: the wire schema's own `x-` keywords
    (messages/schema.py: the msgpack type, unit, NaN, byte limits) of each subschema go into its
    `$comment`, as a JSON object text. Validators in strict mode (Ajv's default) refuse a
    schema with a keyword they do not know; `$comment` is for exactly this."""
    if isinstance(schema, list):
        return [standard_keywords(s) for s in schema]
    if not isinstance(schema, dict):
        return schema
    ours = {k: v for k, v in schema.items() if k.startswith("x-")}
    out = {k: (v if k in ("const", "enum", "default", "examples") else standard_keywords(v))
           for k, v in schema.items() if not k.startswith("x-")}
    if ours:
        out["$comment"] = json.dumps(ours, separators=(",", ":"), sort_keys=True)
    return out


@dataclass
class _Counter:
    big_ints: int = 0
    non_finite: int = 0


def _json_value(value, seen: _Counter):
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        if -JS_SAFE_INT <= value <= JS_SAFE_INT:
            return value
        seen.big_ints += 1
        return str(value)
    if isinstance(value, float):
        if math.isfinite(value):
            return value
        seen.non_finite += 1
        return None
    if isinstance(value, list):
        return [_json_value(v, seen) for v in value]
    raise TypeError(f"no JSON form for {type(value).__name__}")


_FIELDS: dict[type, tuple[str, ...]] = {}


def _field_names(msg_type: type[Message]) -> tuple[str, ...]:
    names = _FIELDS.get(msg_type)
    if names is None:
        names = _FIELDS[msg_type] = tuple(msg_type.schema()["fields"])
    return names


def _plain_array(value: np.ndarray) -> bool:
    """Whether every element of `value` is its own JSON value (no digit string, no null)."""
    kind = value.dtype.kind
    return (kind == "b" or (kind in "iu" and value.dtype.itemsize <= 4)
            or (kind == "f" and bool(np.isfinite(value).all())))


def to_export_json(msg: Message, seen: _Counter | None = None) -> dict:
    """The exported JSON object of `msg` (see the module doc for the rules)."""
    seen = seen if seen is not None else _Counter()
    out = {"type": type(msg).__name__, "v": type(msg).SCHEMA_VERSION}
    for name in _field_names(type(msg)):
        value = getattr(msg, name)
        if isinstance(value, np.ndarray):
            # lists of ints that fit a JavaScript number, or of finite floats, go as they are
            out[name] = (value.tolist() if _plain_array(value)
                         else _json_value(value.tolist(), seen))
        else:
            out[name] = _json_value(value, seen)
    out["stamp"] = _time(msg.stamp_ns)
    return out


class AudioUpsampler:
    """Streams int16 frames up by an integer `factor`: zero insertion and a windowed-sinc lowpass
    at the input's Nyquist (`scipy.signal.upfirdn` of the whole stream, computed polyphase frame
    by frame: the last input samples carry over, so frames join without a seam)."""

    def __init__(self, factor: int, taps_per_phase: int = 12):
        from scipy import signal     # here: `slip` imports this module and must start quickly

        self.factor = factor
        self.taps = (signal.firwin(taps_per_phase * factor, 1.0 / factor) * factor if factor > 1
                     else np.ones(1))
        self.delay_samples = (len(self.taps) - 1) / 2        # at the output rate
        per_phase = -(-len(self.taps) // factor)
        padded = np.zeros(per_phase * factor)
        padded[:len(self.taps)] = self.taps
        # row k, column p: the tap that weighs input n-k into output factor*n+p
        self._phases = padded.reshape(per_phase, factor)
        self._history = np.zeros(per_phase - 1)

    def __call__(self, counts: np.ndarray) -> np.ndarray:
        """The frame `counts` at `factor` times the rate, as int16 (clipped)."""
        x = np.concatenate((self._history, counts), dtype=float)
        if self._history.size:
            self._history = x[-self._history.size:]
        # windows[n, k] = x[n - k] for the frame's n (newest first): a view of x (as
        # sliding_window_view(x, K)[:, ::-1], built directly: that costs ten times the product)
        k, step = self._phases.shape[0], x.strides[0]
        windows = np.ndarray((x.size - k + 1, k), float, buffer=x, offset=(k - 1) * step,
                             strides=(step, -step))
        out = (windows @ self._phases).ravel()
        return np.clip(np.rint(out, out=out), -32768, 32767, out=out).astype(np.int16)


def raw_audio(msg: BiotacPac, upsample: AudioUpsampler | None = None) -> dict:
    """`msg`'s P_AC frame as a foxglove.RawAudio object (counts as pcm-s16 samples).

    The frame's stamp is at its last sample; RawAudio's timestamp is the first sample's. With
    `upsample` (the topic's stream so far) the block is at its rate and starts earlier by its
    filter's delay.
    """
    return raw_audio_block(msg.pac_counts, msg.stamp_ns, upsample)


def raw_audio_block(counts: np.ndarray, stamp_ns: int, upsample: AudioUpsampler | None = None) -> dict:
    """`raw_audio` of consecutive P_AC samples `counts` whose last sample is at `stamp_ns`
    (one frame, or frames joined into a longer block)."""
    n = counts.size
    factor, delay = (upsample.factor, upsample.delay_samples) if upsample else (1, 0.0)
    pcm = upsample(counts) if upsample else counts
    rate = PAC_RATE_HZ * factor
    start_ns = max(0, stamp_ns - round((n - 1) * 1e9 / PAC_RATE_HZ + delay * 1e9 / rate))
    return {"timestamp": _time(start_ns),
            "data": base64.b64encode(pcm.astype("<i2").tobytes()).decode("ascii"),
            "format": "pcm-s16", "sample_rate": rate, "number_of_channels": 1}


@dataclass
class ExportReport:
    """What an export wrote: messages per output topic and the values it had to re-express."""

    src: str
    dst: str
    counts: dict[str, int] = field(default_factory=dict)
    big_ints: int = 0           # integers written as digit strings (beyond 2^53)
    non_finite: int = 0         # NaN/inf floats written as null

    def format(self) -> str:
        lines = [f"exported {sum(self.counts.values())} messages on {len(self.counts)} JSON "
                 f"channels from {self.src} to {self.dst}",
                 f"  {self.big_ints} integers beyond 2^53 written as decimal strings, "
                 f"{self.non_finite} NaN/inf written as null"]
        lines += [f"  {topic}: {n}" for topic, n in sorted(self.counts.items())]
        return "\n".join(lines)


def export_foxglove(src: str | os.PathLike, dst: str | os.PathLike,
                    progress: Callable[[int], object] | None = None) -> ExportReport:
    """Writes the JSON/jsonschema form of the finished recording `src` to `dst`.

    `progress(n)` is called with the number of source messages done since its last call.
    A source that is unfinished is a BagError: recover it first.
    """
    src, dst = os.fspath(src), os.fspath(dst)
    if os.path.exists(dst) and os.path.samefile(src, dst):
        raise BagError(dst, "is the recording being exported; write the export elsewhere")
    bag_info(src)           # refuses a missing, foreign or unfinished file before dst exists
    report, seen = ExportReport(src, dst), _Counter()
    channels: dict[str, int] = {}
    upsamplers: dict[str, AudioUpsampler] = {}
    try:
        with BagWriter(dst, profile="", flush_s=None,
                       metadata={"exported_from": os.path.basename(src), "encoding": "json"}) as out:
            for rec in read_bag(src):
                msg = rec.message()
                outputs = [(rec.topic, False, to_export_json(msg, seen))]
                if isinstance(msg, BiotacPac):
                    upsample = upsamplers.setdefault(rec.topic, AudioUpsampler(AUDIO_RATE_HZ // PAC_RATE_HZ))
                    outputs.append((rec.topic + AUDIO_SUFFIX, True, raw_audio(msg, upsample)))
                for topic, audio, obj in outputs:
                    cid = channels.get(topic)
                    if cid is None:
                        cid = channels[topic] = _channel(out, topic, rec.type_name, audio)
                    out.write_to(cid, topic, json.dumps(obj, allow_nan=False).encode(),
                                 log_time_ns=rec.stamp_ns, stamp_ns=rec.stamp_ns, seq=rec.sequence)
                if progress is not None:
                    progress(1)
            report.counts = dict(out.counts)
    except BaseException:
        if os.path.exists(dst):
            os.unlink(dst)
        raise
    report.big_ints, report.non_finite = seen.big_ints, seen.non_finite
    return report


def _channel(out: BagWriter, topic: str, type_name: str, audio: bool) -> int:
    if audio:
        return out.add_channel(topic, "foxglove.RawAudio", RAW_AUDIO_SCHEMA, message_encoding="json",
                               metadata={"source_type": type_name})
    msg_type = MESSAGE_TYPES[type_name]
    return out.add_channel(topic, type_name, export_schema(msg_type), message_encoding="json",
                           metadata={"type": type_name, "version": str(msg_type.SCHEMA_VERSION)})
