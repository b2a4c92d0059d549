"""The viewer bridge: every topic of the graph, live, to Foxglove or Lichtblick (read-only).

    launch stabilize.yaml view:=foxglove       # in a launch
    slip view [--port 8765] [--graph NAME]      # attached to a graph already running

Connect the viewer to ws://127.0.0.1:8765 (docs/tools.md, "Live view"), with either name of the
subprotocol (foxglove.sdk.v1, foxglove.websocket.v1). In a launch it advertises the launch's
topics ($SLIP_TOPICS) before any node sends, may hold the start until a viewer subscribes
(`wait_for_client_s`), and at shutdown sends what it still holds before it closes (`finish`). The protocol has no
authentication: the bridge binds the loopback address unless `host` says otherwise, and then
prints a warning. It only reads the graph; the server refuses client publishing, parameters and
services (graph/live_view.py). Needs the `[view]` extra (foxglove-sdk).

It costs the graph little: it receives only the topics some client subscribes to (within
FOLLOW_S of the subscription; a topic's publisher sends it nothing otherwise), thins P_AC for
the viewer (graph/live_view.py) and runs at a lower CPU priority (`priority`; docs/performance.md,
"Live view").
"""
from __future__ import annotations

import errno
import importlib.util
import os
import socket
import sys
import time

from incipient_slip.errors import EXIT_USAGE, UsageError
from incipient_slip.graph import discovery
from incipient_slip.graph.bag_export import AUDIO_RATE_HZ
from incipient_slip.graph.launch.topology import topics_from_env
from incipient_slip.graph.live_view import (
    AUDIO_BLOCK_FRAMES, DRAIN_QUIET_S, DRAIN_TIMEOUT_S, EXTRA_HINT, PAC_VIEW_HZ, LiveView,
    is_loopback,
)
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import ANY_TOPIC, POLL_S, Node, run_node
from incipient_slip.messages import PAC_RATE_HZ, Message, MessageError

__all__ = ["FoxgloveBridge", "register"]

SETTLE_S = 0.25     # a viewer's subscriptions are complete when they have not changed this long
FOLLOW_S = 0.1      # how often the topics received follow what the clients subscribe to


class FoxgloveBridge(Node):
    """Serves every topic of the graph as a Foxglove WebSocket channel (JSON + JSON Schema)."""

    PARAMS = {"host": Param("127.0.0.1", help="address to bind"),
              "port": Param(8765, lo=0, hi=65535, help="TCP port of the viewers (0 = any free, printed)"),
              # a lock-step run sends ~4000 messages a second on the layout's topics: 1024 was a
              # quarter second of lag before a client that keeps up on average lost messages
              "backlog": Param(16384, lo=1, help="messages queued per client; the oldest go first"),
              "audio_rate_hz": Param(AUDIO_RATE_HZ, lo=PAC_RATE_HZ,
                                     help=f"P_AC audio rate: a multiple of {PAC_RATE_HZ} Hz"),
              "audio_block_frames": Param(AUDIO_BLOCK_FRAMES, lo=1, help="P_AC frames per audio "
                                          "message (10 = 100 ms)"),
              "pac_view_hz": Param(PAC_VIEW_HZ, lo=0.0, help="P_AC frames a second (of their "
                                   "stamps) on the BiotacPac channel; 0 = every frame (the audio "
                                   "channel always has every sample)"),
              "wait_for_client_s": Param(0.0, lo=0.0, help="hold this node's start (and a launch's "
                                         "sources) until a viewer subscribes, at most this long"),
              "priority": Param("low", choices=("idle", "low", "normal"),
                                help="CPU priority: idle = only CPU time no node wants (SCHED_IDLE), "
                                     "low = nice +10 (relative to the graph's), normal = as the graph's nodes")}
    INPUTS = {ANY_TOPIC: Message}       # every topic of the graph, like the recorder
    OUTPUTS: dict = {}

    @classmethod
    def check_inputs(cls, params: dict, name: str = "foxglove_bridge"):
        """The viewers' port can be listened on (a launch: before any node starts; a busy port
        was a traceback in the bridge and a launch whose nodes waited for it); ParamError."""
        if params["port"]:
            family = socket.AF_INET6 if ":" in params["host"] else socket.AF_INET
            try:
                with socket.socket(family, socket.SOCK_STREAM) as probe:
                    probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)   # as the front's
                    probe.bind((params["host"], params["port"]))
            except (OSError, OverflowError) as exc:
                raise listen_error(name, params["host"], params["port"], exc) from None

    def __init__(self, **kwargs):
        super().__init__("foxglove_bridge", **kwargs)
        # on a busy machine the loop's nodes get the CPU first; the server's threads, started
        # below, inherit this policy
        lower_priority(self.param("priority"))
        host = self.param("host")
        if not is_loopback(host):
            self.warn(f"serving on {host}, not the loopback address: anyone who reaches it sees "
                      f"the whole graph (the Foxglove WebSocket protocol has no authentication)")
        try:
            self.view = LiveView(host, self.param("port"), backlog=self.param("backlog"),
                                 audio_rate_hz=self.param("audio_rate_hz"),
                                 pac_view_hz=self.param("pac_view_hz"),
                                 audio_block_frames=self.param("audio_block_frames"))
        except OSError as exc:      # taken since the launch's check, or run by hand (slip view)
            raise listen_error(self.name, host, self.param("port"), exc) from None
        self.on_shutdown(self.finish)
        self.untyped: set[str] = set()     # announced topics of no known type (replay's "raw")
        self.heard = 0                     # messages received from the graph
        # a launch's topics, from its topology: advertised before any node has started
        for topic, type_name in topics_from_env(os.environ).items():
            if not self.view.offer(topic, type_name):
                self.untyped.add(topic)
        self.log(f"serving ws://{host}:{self.view.port} (read-only; subprotocol foxglove.websocket.v1 "
                 f"or foxglove.sdk.v1: Foxglove, Lichtblick, the @foxglove/ws-protocol client)")
        self.create_raw_subscription(self.on_message)
        self.create_timer(1.0, self.offer_announced)
        self.create_timer(FOLLOW_S, self.follow_clients)
        self.offer_announced()
        self.follow_clients()
        if self.param("wait_for_client_s") > 0:
            self.wait_for_client(self.param("wait_for_client_s"))

    def on_message(self, topic: str, body: bytes, recv_ns: int) -> None:
        self.heard += 1
        try:
            self.view.forward(topic, body)
        except MessageError as exc:
            self.warn(throttle_s=1.0, key=("bridge-drop", topic), text=f"dropped malformed message: {exc}")

    def finish(self) -> None:
        """At shutdown: what the graph sent before it ended still reaches the clients. Reads
        what is queued from the graph (until nothing new for DRAIN_QUIET_S), waits until the
        server's queues have gone out to the clients (`LiveView.drain`), then stops the server;
        the graph's read at most DRAIN_TIMEOUT_S, the clients' as long as they take what waits for
        them (a client that took nothing for DRAIN_TIMEOUT_S is stalled, and not waited for)."""
        deadline = last = time.monotonic()
        deadline += DRAIN_TIMEOUT_S
        while (now := time.monotonic()) - last < DRAIN_QUIET_S and now < deadline:
            heard = self.heard
            self.spin_once(DRAIN_QUIET_S / 4)
            if self.heard != heard:
                last = time.monotonic()
        if not self.view.drain():
            self.warn(f"a client took none of the messages queued for it for {DRAIN_TIMEOUT_S:g} s; closing")
        self.view.close()

    def offer_announced(self) -> None:
        """Advertises the topics the graph's nodes announce, before their first message."""
        # Node keeps its graph directory private; _dir is where this node announced itself.
        for info in discovery.scan(self._dir, clean=False):
            for topic, type_name in info.publishes.items():
                if not self.view.offer(topic, type_name):
                    self.untyped.add(topic)

    def follow_clients(self) -> None:
        """Receives only the topics some client watches (publishers send the bridge nothing
        else), and those of unknown type until their first message tells the type."""
        self.untyped -= self.view.channels.keys()
        self.receive_only(self.view.watched() | self.untyped)

    def wait_for_client(self, timeout_s: float) -> None:
        """Blocks (before this node says hello, so a launch's sources wait too) until a viewer
        subscribes to a channel, or `timeout_s`: a viewer then sees the run from its start."""
        deadline = time.monotonic() + timeout_s
        while not self.view.subscribed.wait(POLL_S) and not self.stopping:
            self.offer_announced()
            if time.monotonic() > deadline:
                self.warn(f"no viewer subscribed within {timeout_s:g} s; going on")
                return
        # a client subscribes to its topics one op after another (the official client, one per
        # channel): the start waits until its set has not changed for SETTLE_S (at most 2 s)
        watched, since, settle_end = self.view.watched(), time.monotonic(), time.monotonic() + 2.0
        while time.monotonic() - since < SETTLE_S and time.monotonic() < settle_end and not self.stopping:
            time.sleep(SETTLE_S / 5)
            if (now := self.view.watched()) != watched:
                watched, since = now, time.monotonic()
        self.follow_clients()       # before this node's hello: the sources' first messages come


def listen_error(name: str, host: str, port: int, exc: Exception) -> ParamError:
    """The one line for a port the bridge cannot listen on (run_node: exit 2)."""
    reason = getattr(exc, "strerror", None) or str(exc)
    advice = (": another program (a viewer bridge?) has it; pick another port (launch: view_port:=N, "
              "slip view --port N; 0 = any free)" if getattr(exc, "errno", None) == errno.EADDRINUSE else "")
    return ParamError(f"node {name!r}: cannot listen on {host}:{port} ({reason}){advice}")


def lower_priority(priority: str) -> None:
    """Puts this process (every thread it has, ZeroMQ's I/O thread included, and those it
    starts from now on) below the graph's nodes.

    Linux sets nice and the scheduling policy per thread: the node's ZeroMQ context started its
    I/O thread before this runs, so each existing thread (/proc/self/task) is lowered too.
    Linux's scheduler also shares the CPU between session groups ("autogroups", when the kernel
    has them on and the process is in the root CPU cgroup) before it shares a group's time between
    its processes by nice: a bridge alone in its session (a node started with `setsid`, as
    `bench/bench_loop.py` and some supervisors do) would weigh as much as each of the loop's
    nodes whatever its own nice. So when this process leads its session, its group's nice is
    lowered as well; a bridge in a shared session (a launch's, a terminal's) leaves that alone."""
    if priority == "normal":
        return
    idle = priority == "idle" and hasattr(os, "SCHED_IDLE")
    # "low" is 10 below the nice this process started with (the graph's, which may be niced
    # itself), not an absolute nice 10: under `nice -n 10` the graph's nodes are at 10 already
    low = min(19, os.getpriority(os.PRIO_PROCESS, 0) + 10)
    for tid in _thread_ids():
        try:
            if idle:
                os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0))
            else:                           # low, or idle without SCHED_IDLE (not Linux): nice +10
                os.setpriority(os.PRIO_PROCESS, tid, max(os.getpriority(os.PRIO_PROCESS, tid), low))
        except OSError:                     # a thread that ended meanwhile
            pass
    if os.getsid(0) == os.getpid():
        try:
            with open("/proc/self/autogroup", "w") as f:
                f.write("19" if priority == "idle" else "10")
        except OSError:                     # no autogroups here, or not allowed: nothing to do
            pass


def _thread_ids() -> list[int]:
    """This process's thread ids (Linux); elsewhere the process itself (0: the calling thread)."""
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [0]


def main(argv=None):
    if importlib.util.find_spec("foxglove") is None:
        print(f"foxglove_bridge: {EXTRA_HINT}", file=sys.stderr)
        return EXIT_USAGE
    return run_node(FoxgloveBridge, argv)


def cmd_view(args) -> int:
    """`slip view`: the bridge in the foreground on the graph that is running."""
    if args.graph:
        try:
            directory = discovery.graph_dir(args.graph, create=False)
        except discovery.GraphNameError as exc:
            raise UsageError(str(exc)) from None
        kwargs = {"graph_dir": directory}
    else:
        kwargs = {}
    if importlib.util.find_spec("foxglove") is None:
        raise UsageError(EXTRA_HINT)
    from incipient_slip.graph.security import TOOL_IDENTITY    # over tcp: the tools' read-only key
    return run_node(FoxgloveBridge, [f"host:={args.host}", f"port:={args.port}"], identity=TOOL_IDENTITY,
                    **kwargs)


def register(subparsers) -> None:
    """Adds `slip view` to the `slip` command."""
    p = subparsers.add_parser(
        "view", help="serve the running graph to Foxglove/Lichtblick (ws://127.0.0.1:8765)",
        description="Attaches the viewer bridge to a running graph and serves every topic over "
                    "the Foxglove WebSocket protocol, read-only, until Ctrl-C. In Foxglove or "
                    "Lichtblick: Open connection -> Foxglove WebSocket -> ws://127.0.0.1:PORT. "
                    "The default graph is shared by every process of a user: pass --graph when "
                    "more than one graph runs.")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1; any other prints a warning: the "
                        "protocol has no authentication)")
    p.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0 = any free)")
    p.add_argument("--graph", metavar="NAME", help="graph name (default $SLIP_GRAPH or "
                   "'default'; $SLIP_GRAPH_DIR overrides the directory)")
    p.set_defaults(func=cmd_view)


if __name__ == "__main__":
    raise SystemExit(main())
