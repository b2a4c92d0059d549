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

The runtime is split along rclpy's seams: this module is the node API (`Node`: params, remaps,
endpoints by topic, logging, shutdown hooks, heartbeat); `endpoints` holds the publishers and
subscriptions, `executor` the spin loop, timers and `run_node`, `peers` discovery, connections and
the reader handshake. Everything a node or test imported from here still is.
"""
from __future__ import annotations

import os
import sys
import time
import traceback
from typing import Any, Callable

import zmq

from incipient_slip import messages as M
from incipient_slip.graph import discovery
from incipient_slip.graph.endpoints import Publisher, RawPublisher, RawSubscription, Subscription
from incipient_slip.graph.executor import POLL_S, Executor, Timer, _open_nodes, run_node
from incipient_slip.graph.params import ParamError, declared_params, merge_params
from incipient_slip.graph.peers import HELLO, LINGER_MS, READERS_ENV, WRITERS_ENV, Peers, _table_from_env

# the run's time base: "sim" = its stamps are the simulated time from 0 (rig_sim's), so a message
# stamped "now" (stamp 0) and a heartbeat carry the latest stamp this node sent (1 ns before
# any), never the wall clock; unset = wall clock (docs/graph.md, "One time base")
CLOCK_ENV = "SLIP_CLOCK"

__all__ = ["Node", "Publisher", "RawPublisher", "Subscription", "RawSubscription", "Timer",
           "run_node", "POLL_S", "LINGER_MS", "ANY_TOPIC", "ON_DEMAND", "READERS_ENV", "WRITERS_ENV", "CLOCK_ENV", "HELLO"]

HEARTBEAT_S = 1.0

# A node's INPUTS/OUTPUTS key for "every topic" (discovery.ANY_TOPIC, as its announcement says it):
# the recorder reads all, replay writes what its file holds. The launcher counts such a node as a
# reader (writer) of every topic of the launch.
ANY_TOPIC = discovery.ANY_TOPIC
# what an every-topic reader announces when it receives only the topics it asks for (discovery)
ON_DEMAND = discovery.ON_DEMAND


class Node(Peers, Executor):
    """Base of every node: params, publishers, subscriptions, timers, heartbeat, clean shutdown.

    Keyword arguments (all optional, normally filled by `run_node` from the command line):
    `params` (overrides of PARAMS), `remaps` ({from topic: to topic}), `node_name` (overrides the
    name given by the subclass), `graph_dir` (default: discovery.graph_dir()), `raw_params` (the text
    each command-line param came from), `heartbeat_s` (0 disables the heartbeat), `readers`
    ({output topic: reader node names} for `wait_for_readers`; default: $SLIP_READERS),
    `writers` ({input topic: the only node names it is accepted from}; default: $SLIP_WRITERS),
    `identity` (over tcp, the keystore identity whose key it holds; default: its name; the
    `slip` tools use security.TOOL_IDENTITY or FORCE_IDENTITY).
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
    # True for a tool whose normal end is Ctrl-C (a recorder, `slip topic echo`): a signal then
    # ends it with 0; any other node stopped by a signal exits 128 + the signal (run_node).
    SIGNAL_ENDS_NORMALLY: bool = False

    def __init__(self, name: str, *, params: dict | None = None, remaps: dict | None = None,
                 node_name: str | None = None, graph_dir=None, raw_params: dict | None = None,
                 heartbeat_s: float = HEARTBEAT_S, context: zmq.Context | None = None,
                 readers: dict[str, list[str]] | None = None,
                 writers: dict[str, list[str]] | None = None, identity: str | None = None):
        self.name = node_name or name
        # whose key it holds over tcp (security.py): its name, or a tool's shared identity
        self._identity = identity or self.name
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

        self._join_graph(graph_dir, context)
        self._announce()
        self._hb_pub = None
        if heartbeat_s > 0:
            # the runtime's own topic: outside any node's declared OUTPUTS
            self._hb_pub = self._publisher(M.Heartbeat, self.resolve_topic(M.Heartbeat.TOPIC))
            self.create_timer(heartbeat_s, self._heartbeat)

    @classmethod
    def check_inputs(cls, params: dict, name: str = ""):
        """Checks what this node's params name outside the command line (a params overlay, a
        model file) from `params` (declared defaults merged with the given ones), raising
        ParamError that names the parameter and the file. The launcher calls it for every node
        before it starts any. Default: nothing to check."""

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
        self._subscribe(M.topic_frame(topic))
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
        self._subscribe(M.topic_frame(topic) if topic else b"")
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
            self._subscribe(frame)
        if old is None:
            self._subscribe(b"", False)      # after the new ones: no gap
        for frame in sorted((old or set()) - new):
            self._subscribe(frame, False)
        self._receive_only = new

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

    def close(self, run_hooks: bool = True) -> None:
        """Runs the on_shutdown callbacks (unless `run_hooks` is False: a node whose constructor
        failed), sends a last heartbeat (its final counts; a node that lived less than a heartbeat
        period sent none before), withdraws the announcement and closes the sockets (bounded
        linger). Idempotent."""
        if self._closed:
            return
        self._closed = True
        for hook in self._shutdown_hooks if run_hooks else ():
            try:
                hook()
            except Exception:
                self.log(f"on_shutdown callback raised:\n{traceback.format_exc()}")
        if run_hooks and getattr(self, "_hb_pub", None) is not None:
            try:
                self._heartbeat()
            except Exception:       # a socket already gone: nothing to tell
                pass
        discovery.withdraw(self._info)
        _open_nodes.discard(self)
        self._close_subs()
        self._xpub.close(linger=LINGER_MS)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _stamp_now(self) -> int:
        return self.run_clock_ns or time.time_ns()

    def _heartbeat(self) -> None:
        self._hb_pub.publish(M.Heartbeat(node=self.name, pid=os.getpid(), stamp_ns=self._stamp_now(),
                                         uptime_s=time.monotonic() - self._t0,
                                         malformed_dropped=self.malformed, seq_gaps=self.seq_gaps))

