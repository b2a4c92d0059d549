"""Endpoints of a node (rclpy's publisher/subscription): a `Publisher` per output topic, a
`Subscription` per input callback, and their raw forms for bodies that are not decoded (recorder,
replay). They send through and are fed by their node's sockets (`runtime.Node`).
"""
from __future__ import annotations

import traceback
from typing import TYPE_CHECKING, Any, Callable

import zmq

from incipient_slip import messages as M

if TYPE_CHECKING:
    from incipient_slip.graph.runtime import Node

__all__ = ["Publisher", "RawPublisher", "Subscription", "RawSubscription", "LOG_EVERY_S"]

LOG_EVERY_S = 1.0        # rate limit of repeated warnings (malformed frames, callback errors)


class Publisher:
    """Publishes one message type on one topic; sets `seq` (and `stamp_ns` when it is 0)."""

    def __init__(self, node: "Node", msg_type: type[M.Message], topic: str):
        self.node, self.type, self.topic = node, msg_type, topic
        self.frame = M.topic_frame(topic)
        self.seq = 0
        self._send_part = node._xpub.send      # two sends: send_multipart's checks cost more
        self._encode = M.body_encoder(msg_type) if msg_type is not M.Message else None
        self.latched = msg_type.LATCHED
        self.last: list[bytes] | None = None    # latched: the frames re-sent to a late subscriber

    def publish(self, msg: M.Message, keep_seq: bool = False) -> int:
        """Send `msg`; returns the seq it went out with (original seq when keep_seq)."""
        if type(msg) is not self.type:
            raise TypeError(f"publisher of {self.topic} sends {self.type.__name__}, "
                            f"got {type(msg).__name__}")
        if keep_seq:
            seq = msg.seq
        else:
            seq = self.seq
            self.seq = seq + 1
        stamp = msg.stamp_ns or self.node._stamp_now()
        node = self.node
        if node.run_clock_ns is not None and stamp > node.run_clock_ns:
            node.run_clock_ns = stamp
        body = self._encode(msg, stamp, seq)
        if self.latched:
            self.last = [self.frame, body]
        self._send_part(self.frame, zmq.SNDMORE)
        self._send_part(body)
        return seq

    def _send(self, frames: list[bytes]) -> None:
        self._send_part(frames[0], zmq.SNDMORE)
        self._send_part(frames[1])

    def subscriber_count(self) -> int:
        """How many subscriptions (across nodes) currently match this topic."""
        self.node._drain_xpub()
        return self.node._subscribers_of(self.frame)

    def wait_for_subscribers(self, n: int = 1, timeout_s: float = 5.0) -> bool:
        """True once at least `n` subscriptions match this topic (slow-joiner handshake).

        Uses the XPUB subscription messages, so when it returns True every counted subscriber
        is connected and will receive what is published next. False on timeout or shutdown.
        """
        return self.node._wait_subscribers(self.frame, n, timeout_s)


class RawPublisher(Publisher):
    """Publishes already-encoded bodies on a topic (replay of recorded bytes)."""

    def __init__(self, node: "Node", topic: str):
        super().__init__(node, M.Message, topic)

    def publish(self, msg, keep_seq: bool = True) -> int:  # noqa: D401 - same contract
        raise TypeError("RawPublisher sends bytes: use publish_raw(body)")

    def publish_raw(self, body: bytes) -> None:
        """Send an encoded message body as it is (seq and stamp are whatever it holds)."""
        self._send([self.frame, body])


class Subscription:
    """Delivers one message type on one topic to a callback; counts seq gaps and bad frames.

    `gaps` counts jumps forward in seq, `missed` the messages those jumps skipped, `dropped`
    the malformed frames, `errors` the exceptions raised by the callback. Gap counting assumes
    one publisher per topic; a seq that goes backwards is taken as a restarted publisher.
    For Heartbeat, seqs are tracked per node name.
    """

    def __init__(self, node: "Node", msg_type: type[M.Message], topic: str,
                 callback: Callable[[M.Message], Any], on_gap: Callable[[int, int], Any] | None):
        self.node, self.type, self.topic, self.callback = node, msg_type, topic, callback
        self.on_gap = on_gap
        self.received = self.gaps = self.missed = self.dropped = self.errors = 0
        self.last_seq: int | None = None
        self._by_source = msg_type is M.Heartbeat
        self._last_by_source: dict[str, int] = {}

    def _deliver(self, body: bytes) -> None:
        node = self.node
        try:
            msg = M.decode(body, self.type, self.topic)
        except Exception as exc:  # MessageError; anything else is a decoder bug, still a drop
            self.dropped += 1
            node.malformed += 1
            why = exc if isinstance(exc, M.MessageError) else f"decoder raised {type(exc).__name__}: {exc}"
            node.warn(throttle_s=LOG_EVERY_S, key=("drop", self.topic), text=f"dropped malformed message: {why}")
            return
        self.received += 1
        seq = msg.seq
        if self._by_source:
            last = self._last_by_source.get(msg.node)
            self._last_by_source[msg.node] = seq
        else:
            last = self.last_seq
        self.last_seq = seq
        if last is not None and seq > last + 1:
            self._gap(last, seq)
        try:      # _call inlined: this is the hot path
            self.callback(msg)
        except Exception:  # a bad message must never kill the node: log, count, go on
            self._failed()

    def _gap(self, last: int, seq: int) -> None:
        self.gaps += 1
        self.missed += seq - last - 1
        self.node.seq_gaps += 1
        self.node.warn(throttle_s=LOG_EVERY_S, key=("gap", self.topic),
                       text=f"seq gap on {self.topic}: {last} -> {seq} ({seq - last - 1} lost)")
        if self.on_gap is not None:
            self._call(self.on_gap, last, seq)

    def _call(self, fn, *args) -> None:
        try:
            fn(*args)
        except Exception:  # a bad message must never kill the node: log, count, go on
            self._failed()

    def _failed(self) -> None:
        self.errors += 1
        self.node.warn(throttle_s=LOG_EVERY_S, key=("cb", self.topic),
                       text=f"callback for {self.topic} raised:\n{traceback.format_exc()}")


class RawSubscription(Subscription):
    """Delivers (topic, body, recv_ns) of every message whose topic matches (all if topic None)."""

    def __init__(self, node: "Node", topic: str | None, callback):
        super().__init__(node, M.Message, topic or "", callback, None)

    def _deliver_raw(self, topic: str, body: bytes, recv_ns: int) -> None:
        self.received += 1
        self._call(self.callback, topic, body, recv_ns)

