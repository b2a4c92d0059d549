"""The node runtime: a `Node` base with params, pub/sub by topic, timers and clean shutdown.

A node reads like an rclpy example (see docs/design.md, "Node API"):

    class Talker(Node):
        PARAMS = {"rate_hz": 100.0}
        def __init__(self, **kwargs):
            super().__init__("talker", **kwargs)
            self.pub = self.create_publisher(BiotacPac)
            self.create_timer(1.0 / self.param("rate_hz"), self.tick)
        def tick(self):
            self.pub.publish(BiotacPac(pac_counts=...))

    def main(argv=None):
        return run_node(Talker, argv)

Topics: a node declares `INPUTS`/`OUTPUTS` ({topic: message type}, before remaps); it can then
only subscribe and publish there, and the launcher draws the graph from them. A source calls
`self.wait_for_readers()` before its first message: it returns once every node of the launch
that reads one of its outputs has subscribed (each node names itself with a HELLO subscription).

Transport: each node has one XPUB (all its publishers) and one SUB (all its subscriptions),
found through `discovery` (announcement files in the graph directory, no broker). Frames are
`[topic + b"\\0", msgpack body]`; subscriptions are exact because the topic frame ends in NUL.
The loop polls with at most `POLL_S` so that SIGINT/SIGTERM (which only set a flag) end
`spin()` promptly; sockets close with a bounded linger and the exit code is 0.
"""
from __future__ import annotations

import atexit
import heapq
import json
import os
import signal
import sys
import time
import traceback
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import zmq

from incipient_slip import messages as M
from incipient_slip.graph import discovery, security
from incipient_slip.errors import EXIT_FAILURE, EXIT_USAGE
from incipient_slip.graph.params import ParamError, as_param, declared_params, merge_params, parse_node_argv

__all__ = ["Node", "Publisher", "RawPublisher", "Subscription", "RawSubscription", "Timer",
           "run_node", "POLL_S", "LINGER_MS", "ANY_TOPIC", "ON_DEMAND", "READERS_ENV", "WRITERS_ENV", "HELLO"]

POLL_S = 0.1              # longest a loop blocks before it looks at the stop flag
DRAIN_MAX = 256           # queued messages one spin_once handles after the one it waited for
TIMER_DRAIN_MAX = 10_000  # queued messages handled before due timers run (see _read_queued)
LINGER_MS = 500           # longest close() waits to flush queued messages
HWM = 100_000             # per-peer queue, messages; P_AC at 100 frames/s is tiny beside it
HEARTBEAT_S = 1.0
DISCONNECT_GRACE_S = 2.0  # how long a withdrawn publisher stays connected so its last frames are read
_LOG_EVERY_S = 1.0        # rate limit of repeated warnings (malformed frames, callback errors)
READY_TIMEOUT_S = 10.0    # default wait for the named readers before a source starts anyway

# A node's INPUTS/OUTPUTS key for "every topic" (discovery.ANY_TOPIC, as its announcement says it):
# the recorder reads all, replay writes what its file holds. The launcher counts such a node as a
# reader (writer) of every topic of the launch.
ANY_TOPIC = discovery.ANY_TOPIC
# what an every-topic reader announces when it receives only the topics it asks for (discovery)
ON_DEMAND = discovery.ON_DEMAND
# Set by the launcher for each node: JSON {output topic after remaps: [reader node names]}, the
# readers in this launch that `wait_for_readers` waits for. Unset (a node started by hand): none.
READERS_ENV = "SLIP_READERS"
# Set by the launcher for each node: JSON {input topic after remaps: [writer node names]}. A node
# accepts those topics only from those nodes: it does not connect to a node that announces one of
# them without being its writer (a forged command or state; counted in `refused_writers`, one warning
# each). Unset (a node started by hand, a recorder): every publisher is accepted.
WRITERS_ENV = "SLIP_WRITERS"
# the run's time base: "sim" = its stamps are the simulated time from 0 (rig_sim's), so a message
# stamped "now" (stamp 0) and a heartbeat carry the latest stamp this node sent (1 ns before
# any), never the wall clock; unset = wall clock (docs/graph.md, "One time base")
CLOCK_ENV = "SLIP_CLOCK"
# Each node, once its subscriptions are made, also subscribes HELLO + its name: a subscription no
# one publishes on, whose XPUB message tells a publisher WHICH node is now subscribed (plain XPUB
# subscription messages carry no identity). 0xFF sorts after every "/..." topic, which matters:
# a SUB that connects late sends its subscriptions in ascending byte order (libzmq's trie), and a
# SUB already connected sends each new one in the order it was made, so when a publisher reads a
# node's hello, that node's other subscriptions have reached it before (same pipe, in order).
HELLO = b"\xffhello/"


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
            node.warn(throttle_s=_LOG_EVERY_S, key=("drop", self.topic), text=f"dropped malformed message: {why}")
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
        self.node.warn(throttle_s=_LOG_EVERY_S, key=("gap", self.topic),
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
        self.node.warn(throttle_s=_LOG_EVERY_S, key=("cb", self.topic),
                       text=f"callback for {self.topic} raised:\n{traceback.format_exc()}")


class RawSubscription(Subscription):
    """Delivers (topic, body, recv_ns) of every message whose topic matches (all if topic None)."""

    def __init__(self, node: "Node", topic: str | None, callback):
        super().__init__(node, M.Message, topic or "", callback, None)

    def _deliver_raw(self, topic: str, body: bytes, recv_ns: int) -> None:
        self.received += 1
        self._call(self.callback, topic, body, recv_ns)


@dataclass(order=True)
class Timer:
    """A periodic callback on the monotonic clock; `cancel()` stops it."""

    due: float
    period_s: float
    # ordered by (due, period) only: two timers due together must not compare their callbacks
    callback: Callable[[], Any] = field(compare=False)
    cancelled: bool = field(default=False, compare=False)

    def cancel(self) -> None:
        self.cancelled = True


class Node:
    """Base of every node: params, publishers, subscriptions, timers, heartbeat, clean shutdown.

    Keyword arguments (all optional, normally filled by `run_node` from the command line):
    `params` (overrides of PARAMS), `remaps` ({from topic: to topic}), `node_name` (overrides the
    name given by the subclass), `graph_dir` (default: discovery.graph_dir()), `raw_params` (the text
    each command-line param came from), `heartbeat_s` (0 disables the heartbeat), `readers`
    ({output topic: reader node names} for `wait_for_readers`; default: $SLIP_READERS),
    `writers` ({input topic: the only node names it is accepted from}; default: $SLIP_WRITERS).
    """

    PARAMS: dict[str, Any] = {}
    # The topics this node reads and writes ({topic before remaps: message type}). A node that
    # declares them may only subscribe and publish there, and the launcher draws the graph
    # (`launch FILE --print`) and derives start-up handshakes from them. None: undeclared
    # (tools and tests that pick topics at run time).
    INPUTS: dict[str, type[M.Message]] | None = None
    OUTPUTS: dict[str, type[M.Message]] | None = None
    # Inputs a launch need not write (commands an operator or another launch may send, e.g.
    # rig_sim's /pzt/command): no "read but never written" warning for them.
    OPTIONAL_INPUTS: frozenset[str] = frozenset()

    def __init__(self, name: str, *, params: dict | None = None, remaps: dict | None = None,
                 node_name: str | None = None, graph_dir=None, raw_params: dict | None = None,
                 heartbeat_s: float = HEARTBEAT_S, context: zmq.Context | None = None,
                 readers: dict[str, list[str]] | None = None,
                 writers: dict[str, list[str]] | None = None):
        self.name = node_name or name
        self.params = merge_params(self.name, declared_params(type(self)), params or {}, raw=raw_params)
        self.remaps = dict(remaps or {})
        self.malformed = self.seq_gaps = 0
        self.exit_code = 0
        self.stop_reason = ""
        self._stop = False
        self._closed = False
        self._t0 = time.monotonic()
        # simulated time: the latest stamp sent (see CLOCK_ENV); None: the wall clock
        self.run_clock_ns: int | None = 1 if os.environ.get(CLOCK_ENV) == "sim" else None
        self._timers: list[Timer] = []
        self._subs: dict[str, list[Subscription]] = {}
        self._raw_subs: list[RawSubscription] = []
        self._receive_only: set[bytes] | None = None      # see receive_only
        self._pubs: dict[str, Publisher] = {}
        self._latched: list[Publisher] = []
        self._last_body: dict[str, bytes] = {}   # topic -> last body: a latched re-send is dropped
        # topics whose re-sends are dropped: latched types' own topics (raw readers) and wherever
        # a typed subscription of a latched type reads (remaps)
        self._latched_topics = {t for t, cls in M.DEFAULT_TOPICS.items() if cls.LATCHED}
        self.duplicates = 0
        self._sub_counts: dict[bytes, int] = {}
        self._warned: dict[Any, list] = {}
        self._shutdown_hooks: list[Callable[[], Any]] = []
        self._said_hello = False
        self._readers = _table_from_env(READERS_ENV, self.name) if readers is None else dict(readers)
        self._writers = _table_from_env(WRITERS_ENV, self.name) if writers is None else dict(writers)
        self.refused_writers: dict[tuple[str, int], str] = {}     # (name, pid) of a refused publisher -> why
        self._log_prefix = "" if os.environ.get("SLIP_LAUNCHED") else f"[{self.name}] "

        self._dir = discovery.graph_dir() if graph_dir is None else Path(graph_dir)
        self._dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        discovery.check_graph_dir(self._dir)
        self._ctx = context or zmq.Context.instance()
        self._xpub = self._ctx.socket(zmq.XPUB)
        self._xpub.setsockopt(zmq.XPUB_VERBOSE, 1)
        self._xpub.setsockopt(zmq.XPUB_VERBOSER, 1)
        self._xpub.setsockopt(zmq.SNDHWM, HWM)
        self._xpub.setsockopt(zmq.LINGER, LINGER_MS)
        transport = security.transport()
        # tcp: every socket CURVE-authenticated and encrypted with the graph's keys (security.py)
        self._keys = security.graph_keys(self._dir) if transport == "tcp" else None
        if self._keys:
            security.secure_server(self._xpub, self._keys, str(self._dir))
        elif transport == "tcp-insecure":
            self.warn(security.INSECURE_WARNING)
        if transport != "ipc":
            port = self._xpub.bind_to_random_port("tcp://127.0.0.1")
            endpoint = f"tcp://127.0.0.1:{port}"
        else:
            endpoint = discovery.ipc_endpoint(self._dir, self.name, os.getpid())
            self._xpub.bind(endpoint)
        self._sub = self._ctx.socket(zmq.SUB)
        self._sub.setsockopt(zmq.RCVHWM, HWM)
        self._sub.setsockopt(zmq.LINGER, 0)
        if self._keys:
            security.secure_client(self._sub, self._keys)
        self._rcvtimeo = -1
        self._info = discovery.NodeInfo(self.name, os.getpid(), endpoint, started_ns=time.time_ns(),
                                        pidns=discovery.namespace("pid"), netns=discovery.namespace("net"),
                                        params=dict(self.params))   # for `slip param`
        self._discovery = discovery.Discovery(self._dir, log=lambda text: self.warn(text))
        self._connected: set[str] = set()
        self._retiring: dict[str, float] = {}   # endpoint -> monotonic time to disconnect
        self._refused_endpoints: set[str] = set()
        self._next_scan = 0.0
        _open_nodes.add(self)
        self._announce()
        self._hb_pub = None
        if heartbeat_s > 0:
            # the runtime's own topic: outside any node's declared OUTPUTS
            self._hb_pub = self._publisher(M.Heartbeat, self.resolve_topic(M.Heartbeat.TOPIC))
            self.create_timer(heartbeat_s, self._heartbeat)

    # --- the API nodes use -----------------------------------------------------------------

    def param(self, name: str) -> Any:
        """The value of a parameter (default < launch file < command line)."""
        try:
            return self.params[name]
        except KeyError:
            raise ParamError(f"node {self.name!r} has no parameter {name!r}; known: "
                             f"{', '.join(sorted(self.params)) or '(none)'}") from None

    def resolve_topic(self, topic: str) -> str:
        """The topic after this node's remaps."""
        return self.remaps.get(topic, topic)

    def _check_declared(self, kind: str, declared, msg_type, topic: str) -> None:
        """Refuses a topic or type outside the node's INPUTS/OUTPUTS (when it declares them)."""
        if declared is None or ANY_TOPIC in declared or msg_type is M.Heartbeat:   # its own heartbeat
            return
        if declared.get(topic) is not msg_type:
            have = ", ".join(f"{t} ({c.__name__})" for t, c in declared.items()) or "(none)"
            raise TypeError(f"node {self.name!r}: {msg_type.__name__} on {topic} is not in its "
                            f"{kind} ({have}); declare it in {type(self).__name__}.{kind}")

    def create_publisher(self, msg_type: type[M.Message], topic: str | None = None) -> Publisher:
        """A publisher of `msg_type` on `topic` (default msg_type.TOPIC), after remaps."""
        self._check_declared("OUTPUTS", self.OUTPUTS, msg_type, topic or msg_type.TOPIC)
        return self._publisher(msg_type, self.resolve_topic(topic or msg_type.TOPIC))

    def _publisher(self, msg_type: type[M.Message], topic: str) -> Publisher:
        pub = self._pubs.get(topic)
        if pub is not None:
            if pub.type is not msg_type:
                raise TypeError(f"{topic} is already published as {pub.type.__name__}")
            return pub
        pub = self._pubs[topic] = Publisher(self, msg_type, topic)
        if pub.latched:
            self._latched.append(pub)
        self._info.publishes[topic] = msg_type.__name__
        self._announce()
        return pub

    def create_raw_publisher(self, topic: str) -> RawPublisher:
        """A publisher of encoded bodies on `topic` (after remaps), for replay."""
        topic = self.resolve_topic(topic)
        pub = RawPublisher(self, topic)
        self._info.publishes[topic] = "raw"
        self._announce()
        return pub

    def create_subscription(self, msg_type: type[M.Message], callback: Callable[[M.Message], Any],
                            topic: str | None = None,
                            on_gap: Callable[[int, int], Any] | None = None) -> Subscription:
        """Calls `callback(msg)` for each valid `msg_type` on `topic` (exact match, after remaps).

        `on_gap(last_seq, seq)` (optional) is called before the callback when seqs jump.
        """
        self._check_declared("INPUTS", self.INPUTS, msg_type, topic or msg_type.TOPIC)
        topic = self.resolve_topic(topic or msg_type.TOPIC)
        sub = Subscription(self, msg_type, topic, callback, on_gap)
        self._subs.setdefault(topic, []).append(sub)
        if msg_type.LATCHED:
            self._latched_topics.add(topic)
        self._sub.setsockopt(zmq.SUBSCRIBE, M.topic_frame(topic))
        self._info.subscribes[topic] = msg_type.__name__
        self._after_subscribe()
        return sub

    def create_raw_subscription(self, callback: Callable[[str, bytes, int], Any],
                                topic: str | None = None) -> RawSubscription:
        """Calls `callback(topic, body, recv_ns)` for every message on `topic`, or on all topics
        when topic is None (recorder, `slip topic echo`). Bodies are not decoded."""
        topic = self.resolve_topic(topic) if topic else None
        sub = RawSubscription(self, topic, callback)
        self._raw_subs.append(sub)
        self._sub.setsockopt(zmq.SUBSCRIBE, M.topic_frame(topic) if topic else b"")
        self._info.subscribes[topic or ANY_TOPIC] = "raw"
        self._after_subscribe()
        return sub

    def receive_only(self, topics: set[str]) -> None:
        """Narrows this node's every-topic raw subscription to `topics` (called again with
        another set: the new one): for a reader of every topic that needs few of them at a time
        (the viewer bridge: what its clients watch). Publishers then send it only those; it still
        connects to every publisher, and announces itself as an every-topic reader "on demand"."""
        if not any(raw.topic == "" for raw in self._raw_subs):
            raise ValueError("receive_only narrows an every-topic raw subscription; there is none")
        old = self._receive_only
        new = {M.topic_frame(self.resolve_topic(t)) for t in topics}
        if old is None:
            self._info.subscribes[ANY_TOPIC] = ON_DEMAND
            self._announce()
        for frame in sorted(new - (old or set())):
            self._sub.setsockopt(zmq.SUBSCRIBE, frame)
        if old is None:
            self._sub.setsockopt(zmq.UNSUBSCRIBE, b"")      # after the new ones: no gap
        for frame in sorted((old or set()) - new):
            self._sub.setsockopt(zmq.UNSUBSCRIBE, frame)
        self._receive_only = new

    @property
    def readers(self) -> dict[str, list[str]]:
        """{output topic: names of the nodes of this launch that read it} (the launcher's
        topology; empty for a node started by hand)."""
        return self._readers

    def wait_for_readers(self, timeout_s: float = READY_TIMEOUT_S) -> bool:
        """True once every node of this launch that reads one of this node's outputs has
        subscribed here (its hello arrived, so its subscriptions are in place); at once when there
        is no launch topology. False on timeout (with a warning naming the missing readers) or
        shutdown. Call it after the node's own subscriptions are made, before the first message
        that must not be lost: it says this node's hello too, so two nodes that wait for each
        other both get through."""
        self._say_hello()
        if not self._reader_names():
            return True
        deadline = time.monotonic() + timeout_s
        while True:
            missing = self._missing_readers()
            if not missing:
                return True
            left = deadline - time.monotonic()
            if left <= 0 or self._stop:
                if not self._stop:
                    self.warn(f"readers {', '.join(missing)} not subscribed after {timeout_s:g} s; "
                              f"starting without them")
                return False
            self._xpub.poll(min(left, POLL_S) * 1000.0, zmq.POLLIN)

    def missing_readers(self) -> list[str]:
        """The launch's named readers of this node's outputs that have not subscribed yet, without
        blocking: for nodes that wait inside a timer (`wait_for_readers` is the blocking form).
        Says this node's hello the first time."""
        if not self._said_hello:
            self._say_hello()
        return self._missing_readers()

    def _reader_names(self) -> list[str]:
        return sorted({n for readers in self._readers.values() for n in readers} - {self.name})

    def _missing_readers(self) -> list[str]:
        if time.monotonic() >= self._next_scan:
            self._discover()      # our own subscriptions must connect too, or we deadlock
        self._drain_xpub()
        return [n for n in self._reader_names() if not self._sub_counts.get(HELLO + n.encode())]

    def create_timer(self, period_s: float, callback: Callable[[], Any]) -> Timer:
        """Calls `callback()` every `period_s` seconds (monotonic clock, first call after one period)."""
        if not period_s > 0:
            raise ValueError(f"timer period must be > 0 s, got {period_s}")
        timer = Timer(time.monotonic() + period_s, period_s, callback)
        heapq.heappush(self._timers, timer)
        return timer

    def now_ns(self) -> int:
        """Wall-clock time, ns (sources stamp with it; followers should use message stamps)."""
        return time.time_ns()

    def log(self, text: str) -> None:
        """A line on stderr (the launcher prefixes it with the node name)."""
        print(f"{self._log_prefix}{text}", file=sys.stderr, flush=True)

    def warn(self, text: str, throttle_s: float = 0.0, key: Any = None) -> None:
        """A warning line on stderr; with `throttle_s`, at most one per that many seconds per
        call site (or per `key`), the next one saying how many were suppressed meanwhile."""
        if throttle_s > 0:
            if key is None:
                caller = sys._getframe(1)
                key = (caller.f_code.co_filename, caller.f_lineno)
            now = time.monotonic()
            state = self._warned.get(key)
            if state is not None and now - state[0] < throttle_s:
                state[1] += 1
                return
            if state is not None and state[1]:
                text += f" ({state[1]} similar suppressed)"
            self._warned[key] = [now, 0]
        self.log(f"WARNING: {text}")

    def on_shutdown(self, callback: Callable[[], Any]) -> None:
        """Calls `callback()` once when the node closes (after spin ends, signal or error),
        before its sockets close: flush files, write summaries, ramp outputs to zero."""
        self._shutdown_hooks.append(callback)

    def shutdown(self, reason: str = "", exit_code: int = 0) -> None:
        """Ends `spin()`, which then returns `exit_code`."""
        if not self._stop:
            self.stop_reason, self.exit_code = reason, exit_code
        self._stop = True

    @property
    def stopping(self) -> bool:
        """True once shutdown was requested (by a signal or by `shutdown()`)."""
        return self._stop

    def spin(self) -> int:
        """Runs callbacks and timers until shutdown; returns the exit code."""
        while not self._stop:
            self.spin_once(POLL_S)
        if self.stop_reason:
            self.log(f"shutting down: {self.stop_reason}")
        return self.exit_code

    def spin_once(self, timeout_s: float = POLL_S) -> None:
        """Waits at most `timeout_s` for a message, handles it, then the messages already queued
        (at most DRAIN_MAX, none once a timer or the discovery scan is due), then due timers,
        after every message already queued (`_read_queued`)."""
        # Hot path: one blocking recv with a receive timeout (no poller), as a raw pyzmq loop
        # does, then non-blocking reads while messages are queued (one EAGAIN per burst, not per
        # message); XPUB subscription news is read at discovery ticks.
        if not self._said_hello:
            self._say_hello()
        now = time.monotonic()
        if now >= self._next_scan:
            self._discover()
            self._drain_xpub()
            now = time.monotonic()
        timers = self._timers
        due = min(self._next_scan, timers[0].due) if timers else self._next_scan
        ms = max(0, int(min(timeout_s, due - now) * 1000.0 + 0.999))
        if ms != self._rcvtimeo:
            self._sub.setsockopt(zmq.RCVTIMEO, ms)
            self._rcvtimeo = ms
        recv, read = self._sub.recv, self._read
        try:
            read(recv(copy=False))
            for _ in range(DRAIN_MAX):
                if self._stop or time.monotonic() >= due:
                    break
                read(recv(zmq.NOBLOCK, copy=False))
        except zmq.Again:
            pass
        if timers and timers[0].due <= time.monotonic():
            self._read_queued()
            self._run_timers()

    def _read_queued(self) -> None:
        """Handles the messages already queued (at most TIMER_DRAIN_MAX) before due timers run:
        a timer that judges silence ("no heartbeat for 3 s", "no estimate 0.4 s after the tick")
        must see what arrived while this process was not run, or a loaded host reads as a
        silent graph."""
        recv, read = self._sub.recv, self._read
        try:
            for _ in range(TIMER_DRAIN_MAX):
                if self._stop:
                    return
                read(recv(zmq.NOBLOCK, copy=False))
        except zmq.Again:
            pass

    def close(self, run_hooks: bool = True) -> None:
        """Runs the on_shutdown callbacks (unless `run_hooks` is False: a node whose constructor
        failed), withdraws the announcement and closes the sockets (bounded linger). Idempotent."""
        if self._closed:
            return
        self._closed = True
        for hook in self._shutdown_hooks if run_hooks else ():
            try:
                hook()
            except Exception:
                self.log(f"on_shutdown callback raised:\n{traceback.format_exc()}")
        discovery.withdraw(self._info)
        _open_nodes.discard(self)
        self._sub.close(linger=0)
        self._xpub.close(linger=LINGER_MS)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --- internals ---------------------------------------------------------------------------

    def _announce(self) -> None:
        discovery.announce(self._dir, self._info)

    def _say_hello(self) -> None:
        """Subscribes this node's hello topic, last (see HELLO); again after a later subscription,
        so that a hello always follows every subscription made before it."""
        hello = HELLO + self.name.encode()
        if self._said_hello:
            self._sub.setsockopt(zmq.UNSUBSCRIBE, hello)
        self._sub.setsockopt(zmq.SUBSCRIBE, hello)
        self._said_hello = True

    def _after_subscribe(self) -> None:
        if self._said_hello:
            self._say_hello()
        self._announce()
        self._discover()

    def _discover(self) -> None:
        self._next_scan = time.monotonic() + POLL_S
        added, removed = self._discovery.changes(self._accepts if self._writers else None)
        now = time.monotonic()
        for endpoint in added:
            self._retiring.pop(endpoint, None)
            if endpoint not in self._connected:
                self._sub.connect(endpoint)
                self._connected.add(endpoint)
        # A publisher that withdrew may still have frames in our pipe: ZeroMQ discards them on
        # disconnect, so disconnect only after a grace period in which the loop reads them.
        # A publisher refused as a forger is cut at once (no grace: its frames are not wanted).
        for endpoint in removed:
            if endpoint in self._connected:
                forged = endpoint in self._refused_endpoints
                self._retiring.setdefault(endpoint, now if forged else now + DISCONNECT_GRACE_S)
        for endpoint, due in list(self._retiring.items()):
            if due <= now:
                del self._retiring[endpoint]
                try:
                    self._sub.disconnect(endpoint)
                except zmq.ZMQError:
                    pass
                self._connected.discard(endpoint)

    @property
    def refused_clients(self) -> int:
        """Connections to this node's graph refused by CURVE authentication (a key that is not
        the graph's), counted per process and graph."""
        return security.refused_clients(self._ctx, str(self._dir))

    def _accepts(self, info: discovery.NodeInfo) -> bool:
        """Whether to connect to an announced node, given the launch's writers of our inputs:
        never to one that announces an input of ours without being its declared writer (counted
        and logged once), else to the declared writers and to the publishers of the inputs that
        have none (an operator's command) or of every topic for a node that reads them all."""
        writers = self._writers
        for topic in info.publishes:
            if topic in writers and info.name not in writers[topic]:
                key = (info.name, info.pid)
                if key not in self.refused_writers:
                    self.refused_writers[key] = (f"publisher {info.name} (pid {info.pid}) refused: it "
                                         f"announces {topic}, whose writer in this launch is "
                                         f"{' or '.join(writers[topic])}")
                    self.warn(f"{self.refused_writers[key]} ({len(self.refused_writers)} refused)")
                self._refused_endpoints.add(info.endpoint)
                return False
        if any(info.name in names for names in writers.values()):
            return True
        reads = self._info.subscribes
        return ANY_TOPIC in reads or any(t in reads for t in info.publishes)

    def _read(self, first: zmq.Frame) -> None:
        """Reads the rest of the message whose first frame is `first` and handles it; a message
        of other than two frames, or whose topic is not NUL-terminated UTF-8, is a counted drop.
        Frames (copy=False) because Frame.more is a C read, and get(RCVMORE) a Python enum call
        that cost more than the recv itself."""
        if first.more:
            second = self._sub.recv(copy=False)
            raw = first.bytes
            if not second.more and raw[-1:] == b"\0":
                try:
                    topic = raw[:-1].decode()
                except UnicodeDecodeError:
                    pass
                else:
                    self._handle(topic, second.bytes)
                    return
            frames = [raw, second.bytes]
            while second.more:
                second = self._sub.recv(copy=False)
                frames.append(second.bytes)
        else:
            frames = [first.bytes]
        self.malformed += 1
        try:
            M.split_frames(frames)
        except M.MessageError as exc:
            self.warn(throttle_s=_LOG_EVERY_S, key="frames", text=f"dropped malformed frames: {exc}")

    def _handle(self, topic: str, body: bytes) -> None:
        recv_ns = time.time_ns() if self._raw_subs else 0
        # A body equal to the last one on its topic is a latched state re-sent for a subscriber
        # that joined after us (seq and stamp included, so never a new message of one publisher)
        if topic in self._latched_topics:
            if self._last_body.get(topic) == body:
                self.duplicates += 1
                return
            self._last_body[topic] = body
        for sub in self._subs.get(topic, ()):
            sub._deliver(body)
        for raw in self._raw_subs:
            if raw.topic == "" or raw.topic == topic:
                raw._deliver_raw(topic, body, recv_ns)

    def _drain_xpub(self) -> None:
        counts = self._sub_counts
        while True:
            try:
                msg = self._xpub.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            if not msg:
                continue
            prefix = msg[1:]
            if msg[0] == 1:
                counts[prefix] = counts.get(prefix, 0) + 1
                for pub in self._latched:
                    if pub.last is not None and pub.frame.startswith(prefix):
                        pub._send(pub.last)
            elif msg[0] == 0:
                counts[prefix] = max(0, counts.get(prefix, 0) - 1)

    def _subscribers_of(self, frame: bytes) -> int:
        return sum(n for prefix, n in self._sub_counts.items() if frame.startswith(prefix))

    def _wait_subscribers(self, frame: bytes, n: int, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while True:
            # Keep discovering while we wait: our own subscriptions must connect to the nodes
            # that are joining too, or their first messages to us would be lost.
            if time.monotonic() >= self._next_scan:
                self._discover()
            self._drain_xpub()
            if self._subscribers_of(frame) >= n:
                return True
            left = deadline - time.monotonic()
            if left <= 0 or self._stop:
                return False
            self._xpub.poll(min(left, POLL_S) * 1000.0, zmq.POLLIN)

    def _run_timers(self) -> None:
        timers = self._timers
        now = time.monotonic()
        while timers and timers[0].due <= now and not self._stop:
            timer = heapq.heappop(timers)
            if timer.cancelled:
                continue
            # Next due from the schedule, not from now, so the rate does not drift; skip
            # missed ticks rather than bursting after a stall.
            timer.due += timer.period_s
            if timer.due <= now:
                timer.due = now + timer.period_s
            heapq.heappush(timers, timer)
            try:
                timer.callback()
            except Exception:
                self.warn(throttle_s=_LOG_EVERY_S, key=("timer", id(timer)), text=f"timer callback raised:\n{traceback.format_exc()}")

    def _stamp_now(self) -> int:
        return self.run_clock_ns or time.time_ns()

    def _heartbeat(self) -> None:
        self._hb_pub.publish(M.Heartbeat(node=self.name, pid=os.getpid(), stamp_ns=self._stamp_now(),
                                         uptime_s=time.monotonic() - self._t0,
                                         malformed_dropped=self.malformed, seq_gaps=self.seq_gaps))


# Nodes whose sockets are open: run_node closes the one whose constructor raised (no caller holds
# it), and at interpreter exit the files of any node never closed are withdrawn, so that an
# announcement and an ipc socket stay behind only after a SIGKILL (the launcher and the next
# scan remove those).
_open_nodes: "weakref.WeakSet[Node]" = weakref.WeakSet()


@atexit.register
def _withdraw_open_nodes() -> None:
    for node in list(_open_nodes):
        discovery.withdraw(node._info)


def _table_from_env(env: str, node: str) -> dict[str, list[str]]:
    text = os.environ.get(env)
    if not text:
        return {}
    try:
        table = json.loads(text)
        return {str(t): [str(n) for n in names] for t, names in table.items()}
    except (ValueError, AttributeError, TypeError):
        raise ParamError(f"node {node!r}: ${env} is not JSON {{topic: [node names]}}: "
                         f"{text[:80]!r}") from None


def run_node(node_class: type[Node], argv: list[str] | None = None, **kwargs) -> int:
    """Builds the node from the command line (`name:=value`, `/from:=/to`, `__name:=x`), spins
    until SIGINT/SIGTERM or `shutdown()`, closes it; returns the exit code (0 on a signal)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if any(a in ("-h", "--help") for a in argv):
        print(_usage(node_class))
        return 0
    try:
        args = parse_node_argv(argv)
    except ParamError as exc:
        print(f"{node_class.__name__}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    node = None

    def on_signal(signum, frame):
        if node is None:
            raise KeyboardInterrupt
        if node.stopping:   # second signal: the user means it
            raise KeyboardInterrupt
        node.shutdown()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    before = set(_open_nodes)
    try:
        try:
            node = node_class(params=args.params, raw_params=args.raw, remaps=args.remaps,
                              node_name=args.node_name, **kwargs)
        except BaseException:
            for half_built in set(_open_nodes) - before:
                half_built.close(run_hooks=False)
            raise
        return node.spin()
    except (ParamError, discovery.GraphNameError) as exc:
        print(f"{node_class.__name__}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return 0 if node is None or node.exit_code == 0 else node.exit_code
    except Exception:
        traceback.print_exc()
        return EXIT_FAILURE
    finally:
        if node is not None:
            node.close()
        for s, handler in old.items():
            signal.signal(s, handler)


def _usage(node_class: type[Node]) -> str:
    defaults = declared_params(node_class)
    module = node_class.__module__
    if module == "__main__":     # run as `python -m pkg.node`: name the module, not __main__
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        module = spec.name if spec is not None else module
    lines = [f"usage: python -m {module} [name:=value ...] [/from:=/to ...] "
             f"[__name:=node_name]", "", (node_class.__doc__ or "").strip(), "", "parameters:"]
    for name, declared in defaults.items():
        d = as_param(declared)
        bounds = (f" one of {', '.join(map(str, d.choices))}" if d.choices is not None else
                  f" in [{d.lo}, {d.hi}]" if d.lo is not None and d.hi is not None else
                  f" >= {d.lo}" if d.lo is not None else
                  f" <= {d.hi}" if d.hi is not None else "")
        lines.append(f"  {name} = {d.default!r}{bounds}" + (f"  {d.help}" if d.help else ""))
    if not defaults:
        lines.append("  (none)")
    return "\n".join(lines)
