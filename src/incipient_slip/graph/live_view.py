"""The live view: a graph's topics as Foxglove WebSocket channels, served by `foxglove-sdk`.

`LiveView` owns one foxglove-sdk server (its own `Context`, so nothing else logs to it) and one
channel per topic, made the first time the topic is offered (from the launch's topology or a
node's announcement) or heard. The SDK listens on a loopback port of its own; clients reach it
through `SubprotocolFront` (graph/live_view_front.py) on the public port, which lets in clients
that offer the subprotocol under its older name `foxglove.websocket.v1` (the SDK refuses them)
and tells when the last byte went out to a client (`drain`). A channel carries the same JSON as `slip bag export --foxglove`
(`bag_export.to_export_json`, schema `bag_export.export_schema`: one source, the messages
contract) with the message's `stamp_ns` as its log time; every BiotacPac topic gets a second
channel `<topic>/audio` of `foxglove.RawAudio`.

Audio: P_AC is 2200 Hz, below the 8-96 kHz every browser's Web Audio `AudioBuffer` must support
(Chromium's floor is 3 kHz), so a browser-based Audio panel cannot be relied on to play it.
The live audio is upsampled as in the export (`bag_export.AudioUpsampler`, x4 to 8800 Hz by
default) and carries every sample, in blocks of `audio_block_frames` frames (100 ms by default;
the export writes one block per frame).

P_AC frames (100 a second) on the BiotacPac channel itself are thinned for the viewer: at most
`pac_view_hz` a second of the frames' own time (10 by default: the first frame of each 100 ms of
stamps), which is what a plot of "the latest frame" redraws; 0 passes every frame. The audio
channel carries the whole waveform. Every other topic is passed message for message.

Safety: no capability is advertised, so the server refuses client publishing, parameters and
services (status "does not support ..."); no viewer can command the rig. A slow or stalled
client never blocks anything: `Channel.log` queues per client (`backlog` messages, oldest
dropped first) and returns at once, and a topic no client subscribes to is not even decoded.
(The bridge's CPU use is another matter on a small machine: docs/performance.md, "Live view".)
"""
from __future__ import annotations

import ipaddress
import json
import threading

import msgspec
import numpy as np

from incipient_slip.graph.bag_export import (
    AUDIO_RATE_HZ, AUDIO_SUFFIX, RAW_AUDIO_SCHEMA, AudioUpsampler, export_schema, raw_audio_block,
    to_export_json,
)
from incipient_slip.graph.live_view_front import SubprotocolFront
from incipient_slip.messages import (
    MESSAGE_TYPES, PAC_RATE_HZ, PAC_SAMPLES_PER_FRAME, BiotacPac, decode_any,
)

__all__ = ["LiveView", "is_loopback", "EXTRA_HINT"]

EXTRA_HINT = "the live view needs foxglove-sdk: pip install 'incipient-slip[view]'"
PAC_VIEW_HZ = 10.0          # P_AC frames a second on the BiotacPac channel (see the module doc)
AUDIO_BLOCK_FRAMES = 10     # P_AC frames per RawAudio message: 100 ms
DRAIN_QUIET_S = 0.3         # `drain`: no byte to any client this long means the queues are empty
DRAIN_TIMEOUT_S = 5.0
CLOSE_GRACE_S = 1.0         # `close`: longest wait for the clients to get the server's close frames
_FRAME_NS = PAC_SAMPLES_PER_FRAME * 1_000_000_000 // PAC_RATE_HZ


def is_loopback(host: str) -> bool:
    """True when `host` is reachable only from this machine (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class LiveView:
    """A foxglove-sdk WebSocket server with a JSON channel per graph topic (see module doc)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, *, backlog: int = 1024,
                 audio_rate_hz: int = AUDIO_RATE_HZ, pac_view_hz: float = PAC_VIEW_HZ,
                 audio_block_frames: int = AUDIO_BLOCK_FRAMES, name: str = "incipient-slip"):
        try:
            import foxglove
        except ImportError:
            raise ImportError(EXTRA_HINT) from None
        if audio_rate_hz % PAC_RATE_HZ:
            raise ValueError(f"audio_rate_hz {audio_rate_hz} is not a multiple of {PAC_RATE_HZ} Hz")
        self._fox = foxglove
        self.audio_factor = audio_rate_hz // PAC_RATE_HZ
        self.audio_block_frames = audio_block_frames
        # the BiotacPac channel shows the first frame of each bucket of this many ns of stamps
        self._pac_bucket_ns = int(1e9 / pac_view_hz) if pac_view_hz > 0 else 0
        self._pac_shown: dict[str, int] = {}          # topic -> bucket of the last frame shown
        self.context = foxglove.Context()
        self.subscribed = threading.Event()           # set when a client first subscribes
        self.channels: dict[str, object] = {}         # topic -> foxglove.Channel
        self._audio: dict[str, _AudioBlocks] = {}
        # the SDK on a loopback port of its own, behind the front that every client reaches
        self.server = foxglove.start_server(
            name=name, host="127.0.0.1", port=0, capabilities=[], context=self.context,
            message_backlog_size=backlog, server_listener=_listener(self.subscribed))
        try:
            self.front = SubprotocolFront(host, port, self.server.port)
        except OSError:
            self.server.stop()
            raise
        self.host, self.port = host, self.front.port

    def offer(self, topic: str, type_name: str) -> bool:
        """Advertises `topic` (a message type name of the contract) if it is not yet; False when
        the type is unknown (e.g. replay's "raw": the first message heard tells it)."""
        msg_type = MESSAGE_TYPES.get(type_name)
        if topic not in self.channels and msg_type is not None:
            self._open(topic, msg_type)
        return topic in self.channels

    def watched(self) -> set[str]:
        """The topics some client subscribes to now (to the topic or to its audio channel)."""
        audio = self._audio
        return {topic for topic, channel in self.channels.items()
                if channel.has_sinks() or (topic in audio and audio[topic].channel.has_sinks())}

    def forward(self, topic: str, body: bytes) -> bool:
        """Logs the msgpack `body` heard on `topic` to its channel(s); False when no client
        subscribes (the body is then not decoded). MessageError for a malformed body."""
        channel = self.channels.get(topic)
        if channel is None:                     # first heard: the body tells the type
            msg = decode_any(body, topic)
            channel = self._open(topic, type(msg))
        else:
            msg = None
        audio = self._audio.get(topic)
        to_json = channel.has_sinks()
        to_audio = audio is not None and audio.listened()
        if not (to_json or to_audio):
            return msg is not None
        if msg is None:
            msg = decode_any(body, topic)
        if to_json and (not isinstance(msg, BiotacPac) or self._shows_frame(topic, msg.stamp_ns)):
            channel.log(_json(to_export_json(msg)), log_time=msg.stamp_ns)
        if to_audio:
            audio.add(msg)
        return True

    def _shows_frame(self, topic: str, stamp_ns: int) -> bool:
        """Whether a P_AC frame stamped `stamp_ns` goes to its JSON channel (module doc)."""
        if not self._pac_bucket_ns:
            return True
        bucket = stamp_ns // self._pac_bucket_ns
        if bucket == self._pac_shown.get(topic):
            return False
        self._pac_shown[topic] = bucket
        return True

    def drain(self, quiet_s: float = DRAIN_QUIET_S, timeout_s: float = DRAIN_TIMEOUT_S) -> bool:
        """Waits until every client took what was sent to it and no byte has gone to a client for
        `quiet_s` (what the server queued for the clients has gone out); False once a client took
        nothing for `timeout_s` while bytes wait for it (a stalled client's queue never goes out).
        True if it went quiet."""
        return self.front.drain(quiet_s, timeout_s)

    def close(self) -> None:
        """Stops the server, which sends each client a WebSocket close frame that the front relays
        before the connection ends (closing the front first cut the connections, and the official
        client reported close code 1006, abnormal closure). The server stops in a thread of its
        own: to a client that reads nothing it cannot send its close frame, and the stop waits;
        after CLOSE_GRACE_S the front cuts what is left, and then it returns."""
        stopping = threading.Thread(target=self.server.stop, name="live-view-stop", daemon=True)
        stopping.start()
        self.front.close(grace_s=CLOSE_GRACE_S)
        stopping.join(CLOSE_GRACE_S)

    def _open(self, topic: str, msg_type) -> object:
        fox = self._fox
        schema = fox.Schema(name=msg_type.__name__, encoding="jsonschema",
                            data=json.dumps(export_schema(msg_type)).encode())
        channel = self.channels[topic] = fox.Channel(
            topic, schema=schema, message_encoding="json", context=self.context,
            metadata={"type": msg_type.__name__, "version": str(msg_type.SCHEMA_VERSION)})
        if msg_type is BiotacPac:
            audio_schema = fox.Schema(name="foxglove.RawAudio", encoding="jsonschema",
                                      data=json.dumps(RAW_AUDIO_SCHEMA).encode())
            self._audio[topic] = _AudioBlocks(
                fox.Channel(topic + AUDIO_SUFFIX, schema=audio_schema, message_encoding="json",
                            context=self.context, metadata={"source_type": msg_type.__name__}),
                AudioUpsampler(self.audio_factor), self.audio_block_frames)
        return channel


class _AudioBlocks:
    """One P_AC topic's RawAudio channel: consecutive frames joined into blocks of `frames`
    frames, upsampled and logged at the block's last frame's stamp. A gap in the stamps ends
    a block early (a block holds consecutive samples only); frames no client hears are let go."""

    def __init__(self, channel, upsample: AudioUpsampler, frames: int):
        self.channel, self.upsample, self.frames = channel, upsample, frames
        self.pending: list[np.ndarray] = []
        self.last_ns = 0

    def listened(self) -> bool:
        """Whether a client subscribes to the audio channel now; if not, the frames pending
        are let go (a block holds what a client hears)."""
        if self.channel.has_sinks():
            return True
        self.pending = []
        return False

    def add(self, msg: BiotacPac) -> None:
        """Appends a frame a client hears (`listened()` just said so)."""
        if self.pending and not 0 < msg.stamp_ns - self.last_ns < 1.5 * _FRAME_NS:
            self.flush()
        self.pending.append(msg.pac_counts)
        self.last_ns = msg.stamp_ns
        if len(self.pending) >= self.frames:
            self.flush()

    def flush(self) -> None:
        if self.pending:
            block = raw_audio_block(np.concatenate(self.pending), self.last_ns, self.upsample)
            self.channel.log(_json(block), log_time=self.last_ns)
            self.pending = []


def _json(obj: dict) -> bytes:
    """`obj` (a JSON value already: export JSON, no NaN) as compact JSON bytes; msgspec writes
    what json.dumps would parse back to, at a fifth of its time."""
    return _JSON_ENCODE(obj)


_JSON_ENCODE = msgspec.json.Encoder().encode


def _listener(subscribed: threading.Event):
    """foxglove-sdk server callbacks (the SDK's ServerListener, whose other methods do nothing):
    notes the first subscription (for the bridge's `wait_for_client_s`)."""
    from foxglove.websocket import ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client, channel) -> None:
            subscribed.set()

    return Listener()
