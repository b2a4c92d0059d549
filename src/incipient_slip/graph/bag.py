"""Recordings on disk: MCAP files with one msgpack channel per topic (the one place that knows MCAP).

Layout of a file we write (readable by any MCAP tool, e.g. `mcap info`, Foxglove):

* one **schema** per message type: name = the type's name (``BiotacPac``), encoding
  ``jsonschema``, data = a JSON Schema of the msgpack map on the wire, derived from
  ``Type.schema()`` (which is also embedded verbatim under ``x-incipient-slip``);
* one **channel** per topic: ``message_encoding="msgpack"``, metadata ``{"type", "version"}``;
* one **message** per received message: data = the msgpack body exactly as on the wire,
  ``log_time`` = receive time (ns since the epoch), ``publish_time`` = the message's
  ``stamp_ns``, ``sequence`` = its ``seq`` modulo 2**32 (the full seq is in the body).

Anything wrong with a file on the way in is a :class:`BagError` naming the file.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import IO, Iterable, Iterator

from incipient_slip.messages import MESSAGE_TYPES, Message, decode_any, encode

__all__ = ["BagError", "BagRecord", "BagWriter", "TopicInfo", "BagInfo", "read_bag", "bag_info",
           "json_schema", "MESSAGE_ENCODING", "SCHEMA_ENCODING", "PROFILE"]

MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
PROFILE = "incipient-slip"          # custom MCAP profile: msgpack bodies of incipient_slip.messages
_SEQUENCE_MOD = 1 << 32             # MCAP's sequence field is uint32
_MAGIC = b"\x89MCAP0\r\n"


class BagError(Exception):
    """A recording that cannot be read or written; names the file and what is wrong."""

    def __init__(self, path, reason: str):
        self.path, self.reason = str(path), reason
        super().__init__(f"{self.path}: {reason}")


@dataclass(frozen=True)
class BagRecord:
    """One recorded message: its topic, type name, wire body and the three MCAP times."""

    topic: str
    type_name: str
    body: bytes
    log_time_ns: int        # when the recorder received it
    stamp_ns: int           # the message's own stamp (MCAP publish_time)
    sequence: int           # the message's seq modulo 2**32

    def message(self) -> Message:
        """The decoded, validated message (MessageError if the body breaks the contract)."""
        return decode_any(self.body, self.topic)


# --- schemas -------------------------------------------------------------------------------

_JSON_TYPES = {"int": "integer", "float": "number", "bool": "boolean", "str": "string"}


def json_schema(msg_type: type[Message]) -> dict:
    """A JSON Schema (2020-12) of the msgpack map that carries `msg_type` on the wire."""
    desc = msg_type.schema()
    props = {"type": {"const": desc["type"]}, "v": {"const": desc["version"]}}
    for name, spec in desc["fields"].items():
        if "array" in spec:
            props[name] = {
                "type": "object",
                "description": f"numpy array, dtype {spec['array']}, shape {spec['shape']}; "
                               "data = raw little-endian bytes (msgpack bin)",
                "properties": {"dtype": {"const": spec["array"]},
                               "shape": {"type": "array", "items": {"type": "integer"}},
                               "data": {"description": "msgpack bin"}},
                "required": ["dtype", "shape", "data"],
            }
        else:
            props[name] = {"type": _JSON_TYPES[spec["type"]]}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": desc["type"], "description": desc["description"], "type": "object",
            "properties": props, "required": list(props), "additionalProperties": False,
            "x-incipient-slip": desc}


# --- writing -------------------------------------------------------------------------------

class BagWriter:
    """Writes messages to an MCAP file; `close()` (or leaving the `with`) makes it valid.

    Until `close()` the file has no summary and no footer: a process that may be stopped must
    call `close()` on its way out (the recorder does, on SIGINT and SIGTERM).
    """

    def __init__(self, path: str | os.PathLike, *, compression: str = "zstd",
                 metadata: dict[str, str] | None = None):
        from mcap.writer import CompressionType, Writer

        self.path = os.fspath(path)
        try:
            self._file: IO[bytes] | None = open(self.path, "wb")
        except OSError as exc:
            raise BagError(self.path, f"cannot create the recording ({exc.strerror})") from None
        try:
            kind = CompressionType[compression.upper()]
        except KeyError:
            raise BagError(self.path, f"unknown compression {compression!r} (zstd, lz4 or none)") from None
        self._writer = Writer(self._file, compression=kind)
        self._writer.start(profile=PROFILE, library="incipient_slip.graph.bag")
        self._writer.add_metadata("recording", {
            "created_by": "incipient_slip", "created_unix_ns": str(time.time_ns()),
            **{str(k): str(v) for k, v in (metadata or {}).items()}})
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self.counts: dict[str, int] = {}

    def _channel(self, topic: str, type_name: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != type_name:
                raise BagError(self.path, f"topic {topic} carries {known[1]} in this recording, "
                                          f"refusing a {type_name}")
            return known[0]
        msg_type = MESSAGE_TYPES[type_name]
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            import json
            schema_id = self._schemas[type_name] = self._writer.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING,
                data=json.dumps(json_schema(msg_type), sort_keys=True).encode())
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_id,
            metadata={"type": type_name, "version": str(msg_type.SCHEMA_VERSION)})
        self._channels[topic] = (channel_id, type_name)
        return channel_id

    def write(self, topic: str, msg: Message, *, log_time_ns: int | None = None,
              body: bytes | None = None) -> None:
        """Appends `msg` on `topic`; `body` is its wire encoding if already at hand."""
        if self._file is None:
            raise BagError(self.path, "write after close")
        channel_id = self._channel(topic, type(msg).__name__)
        self._writer.add_message(
            channel_id=channel_id,
            log_time=time.time_ns() if log_time_ns is None else log_time_ns,
            publish_time=msg.stamp_ns, sequence=msg.seq % _SEQUENCE_MOD,
            data=encode(msg) if body is None else body)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    @property
    def closed(self) -> bool:
        """True once the file is finished (or failed to finish) and closed."""
        return self._file is None

    def flush(self) -> None:
        """Writes buffered messages to the OS (the file stays unfinished until close)."""
        if self._file is not None:
            self._writer.flush()

    def close(self) -> None:
        """Writes the summary and footer and closes the file; safe to call twice."""
        if self._file is None:
            return
        try:
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        finally:
            self._file.close()
            self._file = None

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- reading -------------------------------------------------------------------------------

def _open(path) -> IO[bytes]:
    path = os.fspath(path)
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise BagError(path, "no such file") from None
    except IsADirectoryError:
        raise BagError(path, "is a directory, expected an .mcap file") from None
    except OSError as exc:
        raise BagError(path, f"cannot open ({exc.strerror})") from None


def _corrupt(path, exc: BaseException) -> BagError:
    reason = str(exc) or type(exc).__name__
    return BagError(path, f"not a valid MCAP recording or truncated ({type(exc).__name__}: {reason})")


def _reader(path, f):
    from mcap.reader import SeekingReader

    head = f.read(len(_MAGIC))
    if head != _MAGIC:
        raise BagError(path, "not an MCAP file (it does not start with the MCAP magic bytes)")
    size = os.fstat(f.fileno()).st_size
    f.seek(max(size - len(_MAGIC), 0))
    if size < 2 * len(_MAGIC) or f.read(len(_MAGIC)) != _MAGIC:
        raise BagError(path, "truncated MCAP file: no footer (was the recorder killed before it "
                             "could finish the file, or is the copy incomplete?)")
    f.seek(0)
    try:
        reader = SeekingReader(f, validate_crcs=True)
        summary = reader.get_summary()
    except Exception as exc:  # mcap raises McapError, struct.error, EndOfFile, ValueError...
        raise _corrupt(path, exc) from None
    if summary is None:
        raise BagError(path, "has no summary section: the recorder did not finish it "
                             "(killed with SIGKILL?) or the file is truncated")
    for channel in summary.channels.values():
        if channel.message_encoding != MESSAGE_ENCODING:
            raise BagError(path, f"channel {channel.topic} is {channel.message_encoding!r}-encoded; "
                                 f"only {MESSAGE_ENCODING!r} recordings of incipient_slip are readable")
    return reader, summary


def _type_name(path, channel, summary) -> str:
    name = channel.metadata.get("type")
    if name is None and channel.schema_id in summary.schemas:
        name = summary.schemas[channel.schema_id].name
    if name not in MESSAGE_TYPES:
        raise BagError(path, f"channel {channel.topic} has unknown message type {name!r}")
    return name


def read_bag(path: str | os.PathLike, topics: Iterable[str] | None = None) -> Iterator[BagRecord]:
    """The recorded messages of `topics` (all if None) in receive (log time) order."""
    wanted = None if topics is None else list(topics)
    with _open(path) as f:
        reader, summary = _reader(path, f)
        types = {cid: _type_name(path, ch, summary) for cid, ch in summary.channels.items()}
        try:
            for _schema, channel, rec in reader.iter_messages(topics=wanted, log_time_order=True):
                yield BagRecord(channel.topic, types[channel.id], bytes(rec.data), rec.log_time,
                                rec.publish_time, rec.sequence)
        except BagError:
            raise
        except Exception as exc:
            raise _corrupt(path, exc) from None


@dataclass
class TopicInfo:
    """What one topic of a recording holds."""

    topic: str
    type_name: str
    count: int = 0
    first_log_ns: int = 0
    last_log_ns: int = 0
    first_stamp_ns: int = 0
    last_stamp_ns: int = 0
    seq_gaps: int = 0       # messages missing between consecutive seqs (as a subscriber counts)

    @property
    def rate_hz(self) -> float:
        """Mean message rate over the recording's receive times (0 for fewer than 2)."""
        span = self.last_log_ns - self.first_log_ns
        return (self.count - 1) * 1e9 / span if self.count > 1 and span > 0 else 0.0


@dataclass
class BagInfo:
    """A recording's summary: size, span and per-topic counts, types, rates and seq gaps."""

    path: str
    size_bytes: int
    profile: str
    topics: list[TopicInfo] = field(default_factory=list)

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics)

    @property
    def start_ns(self) -> int:
        return min((t.first_log_ns for t in self.topics if t.count), default=0)

    @property
    def end_ns(self) -> int:
        return max((t.last_log_ns for t in self.topics if t.count), default=0)

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def format(self) -> str:
        """A human-readable table, like `ros2 bag info`."""
        lines = [f"file:      {self.path}",
                 f"size:      {self.size_bytes / 1024:.1f} KiB",
                 f"profile:   {self.profile or '-'}",
                 f"messages:  {self.message_count}",
                 f"duration:  {self.duration_s:.3f} s (receive time)"]
        if self.message_count:
            lines.append(f"start:     {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(self.start_ns / 1e9))}"
                         f" ({self.start_ns} ns)")
        width = max([len(t.topic) for t in self.topics] + [5])
        twidth = max([len(t.type_name) for t in self.topics] + [4])
        lines.append(f"topics:    {len(self.topics)}")
        lines.append(f"  {'topic':<{width}}  {'type':<{twidth}}  {'count':>8}  {'rate_hz':>9}  "
                     f"{'stamp_span_s':>12}  {'seq_gaps':>8}")
        for t in self.topics:
            lines.append(f"  {t.topic:<{width}}  {t.type_name:<{twidth}}  {t.count:>8}  "
                         f"{t.rate_hz:>9.2f}  {(t.last_stamp_ns - t.first_stamp_ns) / 1e9:>12.3f}  "
                         f"{t.seq_gaps:>8}")
        return "\n".join(lines)

    def to_plain(self) -> dict:
        """A JSON-able dict of the summary."""
        return {"path": self.path, "size_bytes": self.size_bytes, "profile": self.profile,
                "message_count": self.message_count, "duration_s": self.duration_s,
                "start_ns": self.start_ns, "end_ns": self.end_ns,
                "topics": [{"topic": t.topic, "type": t.type_name, "count": t.count,
                            "rate_hz": t.rate_hz, "first_stamp_ns": t.first_stamp_ns,
                            "last_stamp_ns": t.last_stamp_ns, "seq_gaps": t.seq_gaps}
                           for t in self.topics]}


def bag_info(path: str | os.PathLike) -> BagInfo:
    """The summary of a recording (reads every message record once, decodes none)."""
    path = os.fspath(path)
    with _open(path) as f:
        reader, summary = _reader(path, f)
        try:
            profile = reader.get_header().profile
        except Exception as exc:
            raise _corrupt(path, exc) from None
        topics = {cid: TopicInfo(ch.topic, _type_name(path, ch, summary))
                  for cid, ch in sorted(summary.channels.items())}
        last_seq: dict[int, int] = {}
        try:
            for _schema, channel, rec in reader.iter_messages(log_time_order=True):
                t = topics[channel.id]
                if t.count == 0:
                    t.first_log_ns, t.first_stamp_ns = rec.log_time, rec.publish_time
                else:
                    gap = (rec.sequence - last_seq[channel.id] - 1) % _SEQUENCE_MOD
                    t.seq_gaps += gap if gap < _SEQUENCE_MOD // 2 else 0
                last_seq[channel.id] = rec.sequence
                t.count += 1
                t.last_log_ns = max(t.last_log_ns, rec.log_time)
                t.last_stamp_ns = max(t.last_stamp_ns, rec.publish_time)
        except Exception as exc:
            raise _corrupt(path, exc) from None
    return BagInfo(path, os.path.getsize(path), profile,
                   sorted(topics.values(), key=lambda t: t.topic))

