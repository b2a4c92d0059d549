"""The recorder node: writes every message it receives on its topics to an MCAP file.

    python -m incipient_slip.graph.recorder path:=run.mcap topics:='[/biotac/pac, /slip/estimate]'
    slip bag record run.mcap /biotac/pac /slip/estimate        # the same, in the foreground

`topics: []` (the default) records every topic of the graph; `max_messages` > 0 ends the
node (exit 0) once that many are recorded. Bodies are stored exactly as
received (after validation: a malformed message is counted in the heartbeat's
`malformed_dropped` and dropped, never recorded); log time = receive time, publish time =
the message's stamp. On SIGINT/SIGTERM the file is finished (summary, footer, fsync) before
the process exits, so it holds every message the node received, including those already
queued to it when the signal came (drained for up to 1 s).

No message waits in memory longer than `flush_s` (0.5 s): the open chunk is finished,
written and fsync'd when its oldest message is that old, and by a timer when traffic stops.
A recorder killed with SIGKILL (or a power cut) so loses at most the last `flush_s` of
messages; `slip bag recover` turns the unfinished file into a finished one.

Its own heartbeat (the one message it sends, recorded with the rest) is on the clock of the run
it records (docs/graph.md, "One time base"). With `$SLIP_CLOCK=sim` (a launch on the simulated
rig) it carries the latest stamp recorded (1 ns before any), as a node's carries the latest stamp
it sent. Without `$SLIP_CLOCK` (`slip bag record`, started by hand beside any run) it does not
know the run's clock until it has recorded a message: from then on its heartbeat carries the
latest stamp recorded, and the heartbeats it sent before that (on the wall clock) are not
recorded. `$SLIP_CLOCK=wall`: the wall clock.
"""
from __future__ import annotations

import os
import time

from incipient_slip.messages import Heartbeat, Message, MessageError, decode_any
from incipient_slip.graph.bag import FLUSH_S, BagError, BagWriter
from incipient_slip.graph.params import Param, ParamError, checked_output
from incipient_slip.graph.runtime import ANY_TOPIC, CLOCK_ENV, Node, run_node


class Recorder(Node):
    """Records topics (all when `topics` is empty) to the MCAP file `path`."""

    SIGNAL_ENDS_NORMALLY = True      # Ctrl-C is how it ends

    PARAMS = {
        "path": Param("recording.mcap", help="the MCAP file to write (replaced if it exists; its folder created)"),
        "topics": Param([], help="topics to record; [] records every topic of the graph"),
        "compression": Param("zstd", choices=("zstd", "lz4", "none"), help="chunk compression"),
        "max_messages": Param(0, lo=0, help="end the node after this many (0: until stopped)"),
        "metadata": Param({}, help="what the recording is (e.g. the series' rig, material, seed, injection; "
                          "launch/collect.yaml sets it): written as the MCAP metadata record 'recording'"),
        "flush_s": Param(FLUSH_S, lo=0.01, hi=60.0,
                         help="longest a message waits in memory; a SIGKILL loses at most this"),
    }
    INPUTS = {ANY_TOPIC: Message}     # every topic of the graph (see graph/launch/topology.py)
    OUTPUTS: dict = {}

    @classmethod
    def check_inputs(cls, params: dict, name: str = "recorder"):
        """The recording's folder created (as the supervisor's summary's) and writable; ParamError
        naming `path` otherwise (a launch: before any node starts)."""
        checked_output(name, "path", params["path"], "the recording")

    def __init__(self, **kwargs):
        super().__init__("recorder", **kwargs)
        self.check_inputs(self.params, self.name)
        try:
            self.bag = BagWriter(self.param("path"), compression=self.param("compression"),
                                 metadata={**self.param("metadata"), "recorder": self.name}, flush_s=self.param("flush_s"))
        except BagError as exc:   # run_node reports a ParamError in one line, exit code 2
            raise ParamError(f"node {self.name!r}: parameter 'path': {exc}") from None
        self.create_timer(self.param("flush_s"), self.bag.flush)   # when traffic stops
        self.dropped = 0
        # the run's clock is the stamps it records, unless the launch says the wall clock; its
        # heartbeats from this seq on are on the run's clock (None: not known yet)
        clock = os.environ.get(CLOCK_ENV)
        self.follows_stamps = clock != "wall"
        self.clocked_from_seq: int | None = 0 if clock else None
        self.pid = os.getpid()
        self.unclocked_beats = 0                   # its own heartbeats not recorded for that
        self.subs = [self.create_raw_subscription(self.on_message, topic)
                     for topic in self.param("topics") or [None]]
        self.log(f"recording {', '.join(self.param('topics')) or 'all topics'} to {self.bag.path}")

    def on_message(self, topic: str, body: bytes, recv_ns: int) -> None:
        if self.param("max_messages") and self.recorded >= self.param("max_messages"):
            return
        try:
            msg = decode_any(body, topic)
        except MessageError as exc:
            self.dropped += 1
            self.malformed += 1         # reported in this node's heartbeat
            self.warn(throttle_s=1.0, key=("rec-drop", topic), text=f"not recorded, malformed: {exc}")
            return
        if type(msg) is Heartbeat and msg.node == self.name and msg.pid == self.pid:
            if self.clocked_from_seq is None or msg.seq < self.clocked_from_seq:
                self.unclocked_beats += 1     # sent on the wall clock before the run's clock was known
                return
        elif self.follows_stamps and msg.stamp_ns > (self.run_clock_ns or 0):
            self.run_clock_ns = msg.stamp_ns         # its heartbeat's stamp from now on
            if self.clocked_from_seq is None and self._hb_pub is not None:
                self.clocked_from_seq = self._hb_pub.seq     # the next heartbeat's seq
        self.bag.write(topic, msg, log_time_ns=recv_ns, body=body)
        if self.param("max_messages") and self.recorded >= self.param("max_messages"):
            self.shutdown(f"recorded max_messages={self.param('max_messages')}")

    @property
    def recorded(self) -> int:
        return sum(self.bag.counts.values())

    def drain(self, quiet_s: float = 0.05, max_s: float = 1.0) -> None:
        """Records what already reached this process when the stop came (bounded)."""
        deadline = time.monotonic() + max_s
        while time.monotonic() < deadline and not self.bag.closed:
            before = self.recorded + self.dropped
            self.spin_once(quiet_s)          # while stopping, one message per call, no timers
            if self.recorded + self.dropped == before:
                return

    def close(self, run_hooks: bool = True) -> None:
        """Stops receiving, then finishes the MCAP file (valid even after SIGTERM). run_node
        passes run_hooks=False when the constructor failed (Node.close)."""
        bag = getattr(self, "bag", None)
        try:
            if bag is not None and not bag.closed:
                self.drain()
            super().close(run_hooks)
        finally:
            if bag is not None and not bag.closed:
                bag.close()
                received = sum(sub.received for sub in self.subs)
                self.log(f"received {received}, wrote {self.recorded} messages on "
                         f"{len(bag.counts)} topics to {bag.path}"
                         + (f" ({self.dropped} malformed dropped)" if self.dropped else "")
                         + (f" ({self.unclocked_beats} of its own heartbeats, sent before it knew the run's "
                            f"clock, not recorded)" if self.unclocked_beats else ""))


def main(argv=None):
    return run_node(Recorder, argv)


if __name__ == "__main__":
    raise SystemExit(main())
