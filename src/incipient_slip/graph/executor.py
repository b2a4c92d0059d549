"""Executor of a node (rclpy's spin): the loop that reads what arrived, hands each message to its
subscriptions, runs due timers and ends on `shutdown()`, and `run_node`, which builds a node from
the command line and spins it until SIGINT/SIGTERM.

The loop polls with at most `POLL_S` so that SIGINT/SIGTERM (which only set a flag) end `spin()`
promptly. `Executor` is a base of `runtime.Node` and uses its sockets and tables.
"""
from __future__ import annotations

import atexit
import heapq
import sys
import time
import traceback
import signal
import weakref
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import zmq

from incipient_slip import messages as M
from incipient_slip.errors import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_SIGNAL_BASE, EXIT_USAGE
from incipient_slip.graph import discovery
from incipient_slip.graph.endpoints import LOG_EVERY_S
from incipient_slip.graph.params import ParamError, as_param, declared_params, parse_node_argv

if TYPE_CHECKING:
    from incipient_slip.graph.runtime import Node

__all__ = ["Executor", "Timer", "run_node", "POLL_S"]

POLL_S = 0.1              # longest a loop blocks before it looks at the stop flag
DRAIN_MAX = 256           # queued messages one spin_once handles after the one it waited for
TIMER_DRAIN_MAX = 10_000  # queued messages handled before due timers run (see _read_queued)


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



class Executor:
    """The spin half of `runtime.Node`: timers, shutdown, the read loop and message dispatch."""

    def create_timer(self, period_s: float, callback: Callable[[], Any]) -> Timer:
        """Calls `callback()` every `period_s` seconds (monotonic clock, first call after one period)."""
        if not period_s > 0:
            raise ValueError(f"timer period must be > 0 s, got {period_s}")
        timer = Timer(time.monotonic() + period_s, period_s, callback)
        heapq.heappush(self._timers, timer)
        return timer

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
        if self._per_peer:      # a SUB per publisher (peers.py): poll them
            self._read_peers(self._poll_peers(ms), DRAIN_MAX, due)
        else:
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
        if self._per_peer:
            self._read_peers(list(self._peer_of), TIMER_DRAIN_MAX)
            return
        recv, read = self._sub.recv, self._read
        try:
            for _ in range(TIMER_DRAIN_MAX):
                if self._stop:
                    return
                read(recv(zmq.NOBLOCK, copy=False))
        except zmq.Again:
            pass

    def _poll_peers(self, ms: int) -> list:
        if not self._peer_of:       # zmq_poll of nothing returns at once
            time.sleep(ms / 1000.0)
            return []
        return [sub for sub, _ in self._poller.poll(ms)]

    def _read_peers(self, subs: list, budget: int, due: float | None = None) -> None:
        """Reads up to `budget` queued messages from each of the per-publisher `subs`, each
        checked against its connection (`Peers._takes`)."""
        for sub in subs:
            try:
                for _ in range(budget):
                    peer = self._peer_of.get(sub)    # None: closed by what a message caused
                    if peer is None or self._stop or (due is not None and time.monotonic() >= due):
                        break
                    self._read(sub.recv(zmq.NOBLOCK, copy=False), sub, peer)
            except zmq.Again:
                pass

    def _read(self, first: zmq.Frame, sub: zmq.Socket | None = None, peer=None) -> None:
        """Reads the rest of the message whose first frame is `first` (from `sub`, default the
        node's one SUB) and handles it; a message of other than two frames, or whose topic is not
        NUL-terminated UTF-8, is a counted drop, and one that came on `peer`'s connection is
        handled only if it is `peer`'s to send (`Peers._takes`).
        Frames (copy=False) because Frame.more is a C read, and get(RCVMORE) a Python enum call
        that cost more than the recv itself."""
        recv = (sub or self._sub).recv
        if first.more:
            second = recv(copy=False)
            raw = first.bytes
            if not second.more and raw[-1:] == b"\0":
                try:
                    topic = raw[:-1].decode()
                except UnicodeDecodeError:
                    pass
                else:
                    if peer is None or self._takes(peer, topic):
                        self._handle(topic, second.bytes)
                    return
            frames = [raw, second.bytes]
            while second.more:
                second = recv(copy=False)
                frames.append(second.bytes)
        else:
            frames = [first.bytes]
        self.malformed += 1
        try:
            M.split_frames(frames)
        except M.MessageError as exc:
            self.warn(throttle_s=LOG_EVERY_S, key="frames", text=f"dropped malformed frames: {exc}")

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
                self.warn(throttle_s=LOG_EVERY_S, key=("timer", id(timer)), text=f"timer callback raised:\n{traceback.format_exc()}")


# Nodes whose sockets are open: run_node closes the one whose constructor raised (no caller holds
# it), and at interpreter exit the files of any node never closed are withdrawn, so that an
# announcement and an ipc socket stay behind only after a SIGKILL (the launcher and the next
# scan remove those).
_open_nodes: "weakref.WeakSet[Node]" = weakref.WeakSet()


@atexit.register
def _withdraw_open_nodes() -> None:
    for node in list(_open_nodes):
        discovery.withdraw(node._info)



def run_node(node_class: type[Node], argv: list[str] | None = None, **kwargs) -> int:
    """Builds the node from the command line (`name:=value`, `/from:=/to`, `__name:=x`), spins
    until SIGINT/SIGTERM or `shutdown()`, closes it; returns the exit code. A signal stops the
    node cleanly (its on_shutdown callbacks run) and it exits 128 + the signal (130, 143: an
    interrupted node is not a success), or 0 for a node whose normal end is a signal
    (`Node.SIGNAL_ENDS_NORMALLY`: a recorder, `slip topic echo`)."""
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
    signal_code = 0 if node_class.SIGNAL_ENDS_NORMALLY else None
    early = []      # a signal that came while the node was being built (it may be announced already)

    def on_signal(signum, frame):
        if node is None:
            early.append(signum)
            raise KeyboardInterrupt
        if node.stopping:   # second signal: the user means it
            raise KeyboardInterrupt
        node.shutdown(exit_code=EXIT_SIGNAL_BASE + signum if signal_code is None else signal_code)

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
        if node is not None and node.exit_code:
            return node.exit_code
        if signal_code is not None:
            return signal_code
        return EXIT_SIGNAL_BASE + early[0] if early else EXIT_INTERRUPTED
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

