"""The live view: a graph's topics as Foxglove WebSocket channels, served by `foxglove-sdk`.

`LiveView` owns one foxglove-sdk server (its own `Context`, so nothing else logs to it) and one
channel per topic, made the first time the topic is offered (from a node's announcement) or
heard. A channel carries the same JSON as `slip bag export --foxglove`
(`bag_export.to_export_json`, schema `bag_export.export_schema`: one source, the messages
contract) with the message's `stamp_ns` as its log time; every BiotacPac topic gets a second
channel `<topic>/audio` of `foxglove.RawAudio`.

Audio: P_AC is 2200 Hz, below the 8-96 kHz every browser's Web Audio `AudioBuffer` must support
(Chromium's floor is 3 kHz), so a browser-based Audio panel cannot be relied on to play it.
The live audio is upsampled as in the export (`bag_export.AudioUpsampler`, x4 to 8800 Hz by
default); the raw counts stay on `/biotac/pac`.

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

from incipient_slip.graph.bag_export import (
    AUDIO_RATE_HZ, AUDIO_SUFFIX, RAW_AUDIO_SCHEMA, AudioUpsampler, export_schema, raw_audio,
    to_export_json,
)
from incipient_slip.messages import MESSAGE_TYPES, PAC_RATE_HZ, BiotacPac, decode_any

__all__ = ["LiveView", "is_loopback", "EXTRA_HINT"]

EXTRA_HINT = "the live view needs foxglove-sdk: pip install 'incipient-slip[view]'"


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
                 audio_rate_hz: int = AUDIO_RATE_HZ, name: str = "incipient-slip"):
        try:
            import foxglove
        except ImportError:
            raise ImportError(EXTRA_HINT) from None
        if audio_rate_hz % PAC_RATE_HZ:
            raise ValueError(f"audio_rate_hz {audio_rate_hz} is not a multiple of {PAC_RATE_HZ} Hz")
        self._fox = foxglove
        self.audio_factor = audio_rate_hz // PAC_RATE_HZ
        self.context = foxglove.Context()
        self.subscribed = threading.Event()           # set when a client first subscribes
        self.channels: dict[str, object] = {}         # topic -> foxglove.Channel
        self._audio: dict[str, tuple[object, AudioUpsampler]] = {}
        self.server = foxglove.start_server(
            name=name, host=host, port=port, capabilities=[], context=self.context,
            message_backlog_size=backlog, server_listener=_listener(self.subscribed))
        self.host, self.port = host, self.server.port

    def offer(self, topic: str, type_name: str) -> None:
        """Advertises `topic` (a message type name of the contract) if it is not yet."""
        msg_type = MESSAGE_TYPES.get(type_name)
        if topic not in self.channels and msg_type is not None:
            self._open(topic, msg_type)

    def forward(self, topic: str, body: bytes) -> bool:
        """Logs the msgpack `body` heard on `topic` to its channel(s); False when no client
        subscribes (the body is then not decoded). MessageError for a malformed body."""
        channel = self.channels.get(topic)
        audio = self._audio.get(topic)
        if channel is not None and not channel.has_sinks() and not (audio and audio[0].has_sinks()):
            return False
        msg = decode_any(body, topic)
        if channel is None:
            channel = self._open(topic, type(msg))
            audio = self._audio.get(topic)
        if channel.has_sinks():
            channel.log(json.dumps(to_export_json(msg), allow_nan=False).encode(), log_time=msg.stamp_ns)
        if audio is not None and audio[0].has_sinks():
            self._log_audio(msg, *audio)
        return True

    def close(self) -> None:
        self.server.stop()

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
            self._audio[topic] = (fox.Channel(topic + AUDIO_SUFFIX, schema=audio_schema,
                                              message_encoding="json", context=self.context,
                                              metadata={"source_type": msg_type.__name__}),
                                  AudioUpsampler(self.audio_factor))
        return channel

    def _log_audio(self, msg: BiotacPac, channel, upsample: AudioUpsampler) -> None:
        obj = raw_audio(msg, upsample)
        channel.log(json.dumps(obj).encode(), log_time=msg.stamp_ns)


def _listener(subscribed: threading.Event):
    """foxglove-sdk server callbacks (the SDK's ServerListener, whose other methods do nothing):
    notes the first subscription (for the bridge's `wait_for_client_s`)."""
    from foxglove.websocket import ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client, channel) -> None:
            subscribed.set()

    return Listener()
