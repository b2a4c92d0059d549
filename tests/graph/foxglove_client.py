"""A Foxglove WebSocket protocol client written only from the protocol's published specification
(foxglove/ws-protocol, docs/spec.md), over the `websockets` library: no foxglove code.

Text frames are JSON with an `op`: the server sends `serverInfo`, `advertise` (channels: id,
topic, encoding, schemaName, schema, schemaEncoding), `unadvertise`, `status`; the client sends
`subscribe` ({subscriptions: [{id, channelId}]}), `unsubscribe`, `advertise` (client publishing).
Binary frames from the server: opcode 0x01 "message data" = u32 LE subscription id, u64 LE log
time (ns), payload; 0x02 "time" = u64 LE timestamp.
"""
from __future__ import annotations

import json
import struct
import time
from dataclasses import dataclass, field

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"


@dataclass
class Received:
    """One message-data frame: the channel's topic, its log time, the decoded JSON payload."""

    topic: str
    log_time_ns: int
    payload: dict


@dataclass
class FoxgloveClient:
    """Connects to ws://host:port; `pump()` reads frames into the fields below."""

    url: str
    max_queue: int = 16
    subprotocol: str = SUBPROTOCOL
    server_info: dict | None = None
    channels: dict[int, dict] = field(default_factory=dict)        # channel id -> advertisement
    statuses: list[dict] = field(default_factory=list)
    messages: list[Received] = field(default_factory=list)
    closed: bool = False
    _subs: dict[int, int] = field(default_factory=dict)             # subscription id -> channel id

    def __post_init__(self):
        self._connection = connect(self.url, subprotocols=[self.subprotocol], proxy=None, compression=None,
                                   max_size=None, max_queue=self.max_queue, open_timeout=10)
        self.ws = self._connection.__enter__()

    def close(self) -> None:
        self._connection.__exit__(None, None, None)

    def topics(self) -> dict[str, dict]:
        """{topic: advertisement} of every advertised channel."""
        return {c["topic"]: c for c in self.channels.values()}

    def pump(self, timeout_s: float = 0.0) -> bool:
        """Handles one frame if one comes within `timeout_s`; False if none did (or the server
        closed the connection: `closed`)."""
        try:
            frame = self.ws.recv(timeout=timeout_s)
        except TimeoutError:
            return False
        except ConnectionClosed:
            self.closed = True
            return False
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg["op"] == "serverInfo":
                self.server_info = msg
            elif msg["op"] == "advertise":
                self.channels.update({c["id"]: c for c in msg["channels"]})
            elif msg["op"] == "unadvertise":
                for cid in msg["channelIds"]:
                    self.channels.pop(cid, None)
            elif msg["op"] == "status":
                self.statuses.append(msg)
            return True
        if frame[0] == 0x01:
            sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
            channel = self.channels[self._subs[sub_id]]
            assert channel["encoding"] == "json"
            self.messages.append(Received(channel["topic"], log_time, json.loads(frame[13:])))
        return True

    def until(self, predicate, timeout_s: float = 20.0, what: str = "") -> None:
        """Pumps frames until `predicate()`; AssertionError after `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise AssertionError(f"foxglove client: not within {timeout_s} s: {what or predicate}")
            self.pump(0.05)

    def subscribe(self, topics) -> None:
        """Subscribes to the advertised channels of `topics` (one subscription id each)."""
        by_topic = self.topics()
        subs = []
        for topic in topics:
            sub_id = len(self._subs) + 1
            self._subs[sub_id] = by_topic[topic]["id"]
            subs.append({"id": sub_id, "channelId": by_topic[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def send(self, op: dict) -> None:
        self.ws.send(json.dumps(op))
