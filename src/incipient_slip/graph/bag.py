"""Recordings on disk: MCAP files with one msgpack channel per topic (the one place that knows MCAP).

Layout of a file we write (readable by any MCAP tool, e.g. `mcap info`, Foxglove):

* one **schema** per message type: name = the type's name (``BiotacPac``), encoding
  ``jsonschema``, data = a JSON Schema of the msgpack map on the wire, derived from
  ``Type.schema()`` (which is also embedded verbatim under ``x-incipient-slip``);
* one **channel** per topic: ``message_encoding="msgpack"``, metadata ``{"type", "version"}``;
* one **message** per received message: data = the msgpack body exactly as on the wire,
  ``log_time`` = receive time (ns since the epoch), ``publish_time`` = the message's
  ``stamp_ns``, ``sequence`` = its ``seq`` modulo 2**32 (the full seq is in the body).

Files are written in chunks of at most FLUSH_S (0.5 s) of messages, each put on disk with
fsync, so a recorder killed with SIGKILL leaves a file without summary and footer that holds
all but its last half second; :func:`scan_bag` reads such a file record by record and
:func:`recover` writes the readable part to a finished file.

Anything wrong with a file on the way in is a :class:`BagError` naming the file.
"""
from __future__ import annotations

import os
import struct
import time
from dataclasses import dataclass, field
from io import BytesIO
from typing import IO, Callable, Iterable, Iterator

from incipient_slip.messages import MESSAGE_TYPES, Message, MessageError, current_body, decode_recorded, encode
from incipient_slip.messages.schema import json_schema  # derived from the field declarations

__all__ = ["BagError", "BagRecord", "BagWriter", "TopicInfo", "BagInfo", "Damage", "Recovery",
           "read_bag", "scan_bag", "bag_info", "recover", "json_schema", "FLUSH_S",
           "MESSAGE_ENCODING", "SCHEMA_ENCODING", "PROFILE"]

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
        """The decoded, validated message (MessageError if the body breaks the contract); a body
        of an older schema version reads as the current one (messages.history)."""
        return decode_recorded(self.body, self.topic)


# --- writing -------------------------------------------------------------------------------

FLUSH_S = 0.5   # the longest a written message waits in memory before it is on disk (fsync'd)


class BagWriter:
    """Writes messages to an MCAP file; `close()` (or leaving the `with`) makes it valid.

    Until `close()` the file has no summary and no footer, but it is never more than
    `flush_s` behind: `write()` finishes the open chunk, flushes and fsyncs the file once
    its oldest message has waited `flush_s`, and a caller that may fall silent (the
    recorder) also calls `flush()` every `flush_s`. A writer killed with SIGKILL thus loses
    at most the last `flush_s` of messages; `recover()` turns what is on disk into a valid
    file. `flush_s=None` keeps mcap's policy (1 MiB chunks, no fsync): faster, but a kill
    loses everything since the last full chunk.
    """

    def __init__(self, path: str | os.PathLike, *, compression: str = "zstd",
                 metadata: dict[str, str] | None = None, flush_s: float | None = FLUSH_S,
                 profile: str = PROFILE):
        from mcap.writer import CompressionType, Writer

        self.path = os.fspath(path)
        try:
            kind = CompressionType[compression.upper()]
        except KeyError:
            raise BagError(self.path, f"unknown compression {compression!r} (zstd, lz4 or none)") from None
        if flush_s is not None and not flush_s > 0:
            raise BagError(self.path, f"flush_s must be > 0 or None, got {flush_s}")
        try:
            self._file: IO[bytes] | None = open(self.path, "wb")
        except OSError as exc:
            raise BagError(self.path, f"cannot create the recording ({exc.strerror})") from None
        self.flush_s = flush_s
        self._writer = Writer(self._file, compression=kind)
        self._writer.start(profile=profile, library="incipient_slip.graph.bag")
        self._writer.add_metadata("recording", {
            "created_by": "incipient_slip", "created_unix_ns": str(time.time_ns()),
            **{str(k): str(v) for k, v in (metadata or {}).items()}})
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._oldest_unflushed: float | None = None    # monotonic time of the oldest pending message
        self.counts: dict[str, int] = {}
        self.flushes = 0
        if flush_s is not None:     # header on disk at once: a killed recorder leaves an MCAP file
            self._writer.flush()
            self._sync()

    def add_channel(self, topic: str, schema_name: str, schema: dict, *,
                    message_encoding: str = MESSAGE_ENCODING, metadata: dict[str, str] | None = None) -> int:
        """Registers `topic` with a JSON Schema (one record per schema name); returns the channel id.

        Every channel references a schema record: PlotJuggler refuses channels without one.
        """
        import json

        schema_id = self._schemas.get(schema_name)
        if schema_id is None:
            schema_id = self._schemas[schema_name] = self._writer.register_schema(
                name=schema_name, encoding=SCHEMA_ENCODING,
                data=json.dumps(schema, sort_keys=True).encode())
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding=message_encoding, schema_id=schema_id,
            metadata=dict(metadata or {}))
        self._channels[topic] = (channel_id, schema_name)
        return channel_id

    def _channel(self, topic: str, type_name: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != type_name:
                raise BagError(self.path, f"topic {topic} carries {known[1]} in this recording, "
                                          f"refusing a {type_name}")
            return known[0]
        msg_type = MESSAGE_TYPES.get(type_name)
        if msg_type is None:
            raise BagError(self.path, f"topic {topic}: unknown message type {type_name!r}")
        return self.add_channel(topic, type_name, json_schema(msg_type),
                                metadata={"type": type_name, "version": str(msg_type.SCHEMA_VERSION)})

    def write(self, topic: str, msg: Message, *, log_time_ns: int | None = None,
              body: bytes | None = None) -> None:
        """Appends `msg` on `topic`; `body` is its wire encoding if already at hand."""
        self.write_body(topic, type(msg).__name__, encode(msg) if body is None else body,
                        log_time_ns=time.time_ns() if log_time_ns is None else log_time_ns,
                        stamp_ns=msg.stamp_ns, seq=msg.seq)

    def write_body(self, topic: str, type_name: str, body: bytes, *, log_time_ns: int,
                   stamp_ns: int, seq: int) -> None:
        """Appends an already encoded msgpack body of `type_name` (copying a recording)."""
        self.write_to(self._channel(topic, type_name), topic, body, log_time_ns=log_time_ns,
                      stamp_ns=stamp_ns, seq=seq)

    def write_to(self, channel_id: int, topic: str, data: bytes, *, log_time_ns: int,
                 stamp_ns: int, seq: int) -> None:
        """Appends `data` on a channel from `add_channel` (any encoding); flushes when due."""
        if self._file is None:
            raise BagError(self.path, "write after close")
        self._writer.add_message(channel_id=channel_id, log_time=log_time_ns,
                                 publish_time=stamp_ns, sequence=seq % _SEQUENCE_MOD, data=data)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if self.flush_s is not None:
            now = time.monotonic()
            if self._oldest_unflushed is None:
                self._oldest_unflushed = now
            elif now - self._oldest_unflushed >= self.flush_s:
                self.flush()

    @property
    def closed(self) -> bool:
        """True once the file is finished (or failed to finish) and closed."""
        return self._file is None

    def flush(self) -> None:
        """Finishes the open chunk and puts it on disk (fsync); a no-op when nothing is pending.

        The file stays unfinished (no summary) until `close()`, but everything written so
        far can then be read back by `recover()`.
        """
        if self._file is not None and self._oldest_unflushed is not None:
            self._writer.flush()
            self._sync()

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())
        self._oldest_unflushed = None
        self.flushes += 1

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

_RECOVER_HINT = "`slip bag recover IN OUT` saves every complete chunk, `slip bag info` says how much"


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
    return BagError(path, f"not a valid MCAP recording or truncated ({type(exc).__name__}: {reason}); "
                          + _RECOVER_HINT)


def _check_magic(path, f) -> None:
    head = f.read(len(_MAGIC))
    if not head:
        raise BagError(path, "is empty (0 bytes): nothing was ever written to it (a writer "
                             "killed before its first flush leaves this)")
    if head != _MAGIC:
        raise BagError(path, "not an MCAP file (it does not start with the MCAP magic bytes)")


def _reader(path, f):
    from mcap.reader import SeekingReader

    _check_magic(path, f)
    size = os.fstat(f.fileno()).st_size
    f.seek(max(size - len(_MAGIC), 0))
    if size < 2 * len(_MAGIC) or f.read(len(_MAGIC)) != _MAGIC:
        raise BagError(path, "truncated MCAP file: no footer (was the recorder killed before it "
                             "could finish the file, or is the copy incomplete?); " + _RECOVER_HINT)
    f.seek(0)
    try:
        reader = SeekingReader(f, validate_crcs=True)
        summary = reader.get_summary()
    except Exception as exc:  # mcap raises McapError, struct.error, EndOfFile, ValueError...
        raise _corrupt(path, exc) from None
    if summary is None:
        raise BagError(path, "has no summary section: the recorder did not finish it "
                             "(killed with SIGKILL?) or the file is truncated; " + _RECOVER_HINT)
    for channel in summary.channels.values():
        _check_encoding(path, channel)
    return reader, summary


def _check_encoding(path, channel) -> None:
    if channel.message_encoding != MESSAGE_ENCODING:
        raise BagError(path, f"channel {channel.topic} is {channel.message_encoding!r}-encoded; "
                             f"only {MESSAGE_ENCODING!r} recordings of incipient_slip are readable")


def _type_name(path, channel, schemas: dict) -> str:
    name = channel.metadata.get("type")
    if name is None and channel.schema_id in schemas:
        name = schemas[channel.schema_id].name
    if name not in MESSAGE_TYPES:
        raise BagError(path, f"channel {channel.topic} has unknown message type {name!r}")
    return name


def read_bag(path: str | os.PathLike, topics: Iterable[str] | None = None, *,
             file_order: bool = False) -> Iterator[BagRecord]:
    """The recorded messages of `topics` (all if None) in receive (log time) order.

    file_order: in the order they were written instead: each topic's messages still in receive
    order, the topics interleaved by chunk; about twice as fast (no merge across chunks).
    The file must be finished (summary and footer); an unfinished one is a BagError that
    points at `recover()`.
    """
    wanted = None if topics is None else list(topics)
    with _open(path) as f:
        reader, summary = _reader(path, f)
        types = {cid: _type_name(path, ch, summary.schemas) for cid, ch in summary.channels.items()}
        try:
            for _schema, channel, rec in reader.iter_messages(topics=wanted, log_time_order=not file_order):
                yield BagRecord(channel.topic, types[channel.id], bytes(rec.data), rec.log_time,
                                rec.publish_time, rec.sequence)
        except BagError:
            raise
        except Exception as exc:
            raise _corrupt(path, exc) from None


# --- unfinished and damaged files -------------------------------------------------------------

@dataclass
class Damage:
    """What a record-by-record scan of a recording found: how much is readable, what is lost."""

    size_bytes: int
    readable_bytes: int = len(_MAGIC)   # up to the end of the last complete record
    finished: bool = False              # data section, summary and footer all present
    chunks: int = 0                     # complete chunks read
    bad_chunks: int = 0                 # complete chunks with a bad CRC or compression: skipped
    bad_records: int = 0                # other complete records that do not parse: skipped
    orphans: int = 0                    # messages whose channel record was lost with a bad chunk
    stopped: str = ""                   # why the scan ended before the end of the file, if it did
    summary_error: str = ""             # why the summary/index of a finished file is unusable

    @property
    def lost_bytes(self) -> int:
        """Bytes after the last complete record (an unfinished chunk, a cut copy)."""
        return self.size_bytes - self.readable_bytes

    @property
    def intact(self) -> bool:
        """True when the file is finished and nothing in it had to be skipped."""
        return self.finished and not (self.bad_chunks or self.bad_records or self.orphans
                                      or self.summary_error)

    def describe(self) -> str:
        """One line: finished or not, and what could not be read."""
        if self.intact:
            return "finished, nothing lost"
        parts = ["finished" if self.finished else
                 "UNFINISHED (no summary/footer: the recorder was killed, or the copy is cut)"]
        if self.lost_bytes and not self.finished:
            parts.append(f"{self.lost_bytes} bytes at the end unreadable: {self.stopped}")
        if self.bad_chunks:
            parts.append(f"{self.bad_chunks} corrupt chunk(s) skipped")
        if self.bad_records:
            parts.append(f"{self.bad_records} corrupt record(s) skipped")
        if self.orphans:
            parts.append(f"{self.orphans} message(s) without a channel record skipped")
        if self.summary_error and self.finished and len(parts) == 1:
            parts.append(f"its summary/index is unusable ({self.summary_error})")
        return "; ".join(parts)

    def to_plain(self) -> dict:
        return {"finished": self.finished, "intact": self.intact, "size_bytes": self.size_bytes,
                "readable_bytes": self.readable_bytes, "lost_bytes": self.lost_bytes,
                "chunks": self.chunks, "bad_chunks": self.bad_chunks,
                "bad_records": self.bad_records, "orphans": self.orphans, "stopped": self.stopped,
                "summary_error": self.summary_error}


_HEADER_BYTES = 9   # opcode u8 + length u64


def scan_bag(path: str | os.PathLike, damage: Damage | None = None,
             progress: Callable[[int], object] | None = None) -> Iterator[BagRecord]:
    """Every message of every complete record of `path`, in file order, finished or not.

    For files that `read_bag` refuses: records are framed by their own length, so a
    truncated tail (the open chunk of a killed recorder) ends the scan and a complete but
    corrupt chunk is skipped; both are counted in `damage` (filled as the scan goes).
    `progress(n)` is called with the bytes consumed since its last call.
    """
    from mcap.exceptions import McapError
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Chunk, Message as McapMessage, Schema
    from mcap.stream_reader import breakup_chunk

    path = os.fspath(path)
    with _open(path) as f:
        size = os.fstat(f.fileno()).st_size
        damage = damage if damage is not None else Damage(size)
        damage.size_bytes = size
        _check_magic(path, f)
        schemas: dict[int, Schema] = {}
        channels: dict[int, tuple[str, str]] = {}   # id -> (topic, type name)
        pos = len(_MAGIC)

        def parse(records) -> Iterator[BagRecord]:
            for rec in records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    _check_encoding(path, rec)
                    channels[rec.id] = (rec.topic, _type_name(path, rec, schemas))
                elif isinstance(rec, McapMessage):
                    known = channels.get(rec.channel_id)
                    if known is None:
                        damage.orphans += 1
                        continue
                    yield BagRecord(known[0], known[1], bytes(rec.data), rec.log_time,
                                    rec.publish_time, rec.sequence)

        readers = {Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read, Opcode.CHUNK: Chunk.read}
        while True:
            head = f.read(_HEADER_BYTES)
            if len(head) < _HEADER_BYTES:
                damage.stopped = "end of file inside a record header" if head else "end of file"
                break
            opcode, length = head[0], int.from_bytes(head[1:], "little")
            if length > size - pos - _HEADER_BYTES:
                damage.stopped = f"a record of {length} bytes at byte {pos} runs past the end"
                break
            body = f.read(length)
            pos += _HEADER_BYTES + length
            damage.readable_bytes = pos
            if progress is not None:
                progress(_HEADER_BYTES + length)
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                f.seek(max(size - len(_MAGIC), 0))
                damage.finished = f.read(len(_MAGIC)) == _MAGIC and size > pos
                damage.readable_bytes = size if damage.finished else pos
                damage.stopped = "" if damage.finished else "end of data section without a footer"
                if progress is not None:
                    progress(damage.readable_bytes - pos)
                break
            if opcode == Opcode.MESSAGE:
                try:
                    records = [McapMessage.read(ReadDataStream(BytesIO(body)), length)]
                except (McapError, ValueError, struct.error, UnicodeDecodeError):
                    damage.bad_records += 1
                    continue
            elif opcode in readers:
                try:
                    rec = readers[opcode](ReadDataStream(BytesIO(body)))
                    records = breakup_chunk(rec, validate_crc=True) if opcode == Opcode.CHUNK else [rec]
                except Exception:   # zstd/lz4/CRC/struct errors differ by library: one bad record
                    if opcode == Opcode.CHUNK:
                        damage.bad_chunks += 1
                    else:
                        damage.bad_records += 1
                    continue
                damage.chunks += opcode == Opcode.CHUNK
            else:
                continue            # header, indexes, metadata, statistics: nothing to keep
            yield from parse(records)


def recover(src: str | os.PathLike, dst: str | os.PathLike,
            progress: Callable[[int], object] | None = None) -> "Recovery":
    """Writes every readable message of `src` (finished or not) to a finished file `dst`.

    Bodies are copied byte for byte after validation (a body that breaks the wire contract
    is counted in `malformed` and left out; one of an older schema version is written as the
    current version, messages.history); receive times, stamps and seqs are kept.
    """
    src, dst = os.fspath(src), os.fspath(dst)
    if os.path.exists(dst) and os.path.exists(src) and os.path.samefile(src, dst):
        raise BagError(dst, "is the file being recovered; write the recovered copy elsewhere")
    damage = Damage(0)
    result = Recovery(src, dst, damage)
    records = scan_bag(src, damage, progress)
    first = next(records, None)     # a non-MCAP src is refused before dst is created
    try:
        with BagWriter(dst, metadata={"recovered_from": os.path.basename(src)}, flush_s=None) as out:
            for rec in ([] if first is None else [first]):
                result.copy(out, rec)
            for rec in records:
                result.copy(out, rec)
    except BaseException:
        if os.path.exists(dst):     # no half-made copy that looks like a good recording
            os.unlink(dst)
        raise
    return result


@dataclass
class Recovery:
    """What `recover()` did: messages copied per topic, left out as malformed, and the damage."""

    src: str
    dst: str
    damage: Damage
    counts: dict[str, int] = field(default_factory=dict)
    malformed: int = 0
    last_log_ns: int = 0

    def copy(self, out: BagWriter, rec: BagRecord) -> None:
        try:
            # an older schema version is saved as the current one: the channel's schema and
            # version metadata are the current type's (messages.history)
            body = current_body(rec.body, rec.topic)
        except MessageError:
            self.malformed += 1
            return
        out.write_body(rec.topic, rec.type_name, body, log_time_ns=rec.log_time_ns,
                       stamp_ns=rec.stamp_ns, seq=rec.sequence)
        self.counts[rec.topic] = self.counts.get(rec.topic, 0) + 1
        self.last_log_ns = max(self.last_log_ns, rec.log_time_ns)

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def format(self) -> str:
        """A short report: recovered per topic, and what was lost."""
        lines = [f"recovered {self.message_count} messages on {len(self.counts)} topics "
                 f"from {self.src} into {self.dst}",
                 f"source:    {self.damage.describe()}"]
        if self.malformed:
            lines.append(f"left out: {self.malformed} malformed message bodies")
        if self.last_log_ns:
            lines.append(f"last:      the last recovered message was received at "
                         f"{time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(self.last_log_ns / 1e9))}"
                         f".{self.last_log_ns % 10**9:09d}")
        if not self.damage.finished:
            lines.append(f"lost:      what the writer received after that and had not yet put on "
                         f"disk (a recorder killed with SIGKILL: at most its flush_s, {FLUSH_S} s "
                         f"by default)")
        lines.append("recovered per topic:")
        lines += [f"  {topic}: {n}" for topic, n in sorted(self.counts.items())]
        return "\n".join(lines)

    def to_plain(self) -> dict:
        return {"src": self.src, "dst": self.dst, "message_count": self.message_count,
                "counts": dict(sorted(self.counts.items())), "malformed": self.malformed,
                "last_log_ns": self.last_log_ns, "damage": self.damage.to_plain()}


# --- summaries -----------------------------------------------------------------------------

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
    seq_gaps: int = 0       # messages missing between consecutive seqs of one publisher
    _last_seq: dict = field(default_factory=dict, repr=False, compare=False)   # publisher -> seq

    @property
    def rate_hz(self) -> float:
        """Mean message rate over the recording's receive times (0 for fewer than 2)."""
        span = self.last_log_ns - self.first_log_ns
        return (self.count - 1) * 1e9 / span if self.count > 1 and span > 0 else 0.0

    @property
    def stamp_rate_hz(self) -> float:
        """Mean message rate over the messages' own stamps (the source's time: a lock-step or
        sped-up recording is received faster than its sensors sampled); 0 for fewer than 2."""
        span = self.last_stamp_ns - self.first_stamp_ns
        return (self.count - 1) * 1e9 / span if self.count > 1 and span > 0 else 0.0

    def add(self, log_ns: int, stamp_ns: int, sequence: int, publisher=None) -> None:
        """Counts one message (given in receive order). Seqs are each publisher's own, so gaps
        are counted per `publisher` (`publisher_of`; None: the topic's one publisher)."""
        if self.count == 0:
            self.first_log_ns, self.first_stamp_ns = log_ns, stamp_ns
        last = self._last_seq.get(publisher)
        if last is not None:
            gap = (sequence - last - 1) % _SEQUENCE_MOD
            self.seq_gaps += gap if gap < _SEQUENCE_MOD // 2 else 0
        self._last_seq[publisher] = sequence
        self.count += 1
        self.last_log_ns = max(self.last_log_ns, log_ns)
        self.last_stamp_ns = max(self.last_stamp_ns, stamp_ns)


def publisher_of(type_name: str, body) -> tuple[str, int] | None:
    """Who sent a recorded message, where its body says so: a `Heartbeat` names its node and pid
    (every node beats on /heartbeat, each with seqs of its own). Other topics have one publisher
    each (as a subscriber counts them, graph/endpoints.py): None. A body that does not decode
    (never written by the recorder) is None too."""
    if type_name != "Heartbeat":
        return None
    try:
        msg = decode_recorded(bytes(body), "/heartbeat")
    except ValueError:          # MessageError
        return None
    return msg.node, msg.pid


@dataclass
class BagInfo:
    """A recording's summary: size, span and per-topic counts, types, rates and seq gaps.

    `damage` is set when the file was not finished or is corrupt: the counts are then those
    of the messages `recover()` would save.
    """

    path: str
    size_bytes: int
    profile: str
    topics: list[TopicInfo] = field(default_factory=list)
    damage: Damage | None = None

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
                 f"profile:   {self.profile or '-'}"]
        if self.damage is not None:
            lines += [f"status:    {self.damage.describe()}",
                      f"recover:   {self.message_count} messages (below) are recoverable with "
                      f"`slip bag recover {self.path} OUT.mcap`"]
        lines += [f"messages:  {self.message_count}",
                  f"duration:  {self.duration_s:.3f} s (receive time)"]
        if self.message_count:
            lines.append(f"start:     {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(self.start_ns / 1e9))}"
                         f" ({self.start_ns} ns)")
        width = max([len(t.topic) for t in self.topics] + [5])
        twidth = max([len(t.type_name) for t in self.topics] + [4])
        lines.append(f"topics:    {len(self.topics)}")
        lines.append(f"  {'topic':<{width}}  {'type':<{twidth}}  {'count':>8}  {'rate_hz':>9}  "
                     f"{'stamp_hz':>9}  {'stamp_span_s':>12}  {'seq_gaps':>8}")
        for t in self.topics:
            lines.append(f"  {t.topic:<{width}}  {t.type_name:<{twidth}}  {t.count:>8}  "
                         f"{t.rate_hz:>9.2f}  {t.stamp_rate_hz:>9.2f}  "
                         f"{(t.last_stamp_ns - t.first_stamp_ns) / 1e9:>12.3f}  {t.seq_gaps:>8}")
        lines.append("  (rate_hz by receive time, stamp_hz by the messages' stamps)")
        return "\n".join(lines)

    def to_plain(self) -> dict:
        """A JSON-able dict of the summary (`damage` is null for a finished, intact file)."""
        return {"path": self.path, "size_bytes": self.size_bytes, "profile": self.profile,
                "message_count": self.message_count, "duration_s": self.duration_s,
                "start_ns": self.start_ns, "end_ns": self.end_ns,
                "topics": [{"topic": t.topic, "type": t.type_name, "count": t.count,
                            "rate_hz": t.rate_hz, "stamp_rate_hz": t.stamp_rate_hz,
                            "first_stamp_ns": t.first_stamp_ns,
                            "last_stamp_ns": t.last_stamp_ns, "seq_gaps": t.seq_gaps}
                           for t in self.topics],
                "damage": None if self.damage is None else self.damage.to_plain()}


def bag_info(path: str | os.PathLike, *, damaged_ok: bool = False,
             progress: Callable[[int], object] | None = None) -> BagInfo:
    """The summary of a recording (reads every message record once; decodes only the heartbeats,
    whose node and pid tell their publishers apart for the seq gaps).

    A file that is unfinished or corrupt is a BagError, unless `damaged_ok`: then the
    summary counts what `recover()` would save and `damage` says what is lost.
    """
    path = os.fspath(path)
    try:
        return _finished_info(path)
    except BagError as exc:
        if not damaged_ok:
            raise
        refused = exc.reason
    damage = Damage(0, summary_error=refused)
    topics: dict[str, TopicInfo] = {}
    profile = ""
    for rec in scan_bag(path, damage, progress):
        t = topics.get(rec.topic)
        if t is None:
            t = topics[rec.topic] = TopicInfo(rec.topic, rec.type_name)
        t.add(rec.log_time_ns, rec.stamp_ns, rec.sequence, publisher_of(rec.type_name, rec.body))
    with _open(path) as f:          # the header is the first record; it survives any cut
        try:
            from mcap.stream_reader import StreamReader
            profile = next(iter(StreamReader(f).records)).profile
        except Exception:
            profile = ""
    return BagInfo(path, damage.size_bytes, profile, sorted(topics.values(), key=lambda t: t.topic),
                   damage)


def _finished_info(path: str) -> BagInfo:
    with _open(path) as f:
        reader, summary = _reader(path, f)
        try:
            profile = reader.get_header().profile
        except Exception as exc:
            raise _corrupt(path, exc) from None
        topics = {cid: TopicInfo(ch.topic, _type_name(path, ch, summary.schemas))
                  for cid, ch in sorted(summary.channels.items())}
        try:
            for _schema, channel, rec in reader.iter_messages(log_time_order=True):
                t = topics[channel.id]
                t.add(rec.log_time, rec.publish_time, rec.sequence, publisher_of(t.type_name, rec.data))
        except Exception as exc:
            raise _corrupt(path, exc) from None
    return BagInfo(path, os.path.getsize(path), profile,
                   sorted(topics.values(), key=lambda t: t.topic))
