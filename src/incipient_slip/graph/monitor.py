"""The monitor node: counts what flows on the graph and prints a summary with PASS/FAIL.

    python -m incipient_slip.graph.monitor expect_count:=648

It listens to `topics` (all but `skip_topics` when empty), decodes every message, and per
topic counts messages, seq gaps and messages out of order. It ends, printing the summary on
stdout, when `expect_count` messages arrived, or when every node that published to it has
left the graph and `idle_s` passed without a message (end of a replay), or after `timeout_s`
with nothing at all. Exit code 0 (PASS) when messages arrived in order with no seq gap and,
if given, exactly `expect_count` of them; 1 (FAIL) otherwise. `summary_json` names a file
to write the summary to, for scripts and tests.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass

from incipient_slip.messages import Message, MessageError, decode_any
from incipient_slip.graph import discovery
from incipient_slip.graph.runtime import ANY_TOPIC, Node, run_node


@dataclass
class TopicStats:
    """What one topic delivered: count, seq gaps and disorder, first and last stamp."""

    type_name: str
    count: int = 0
    seq_gaps: int = 0           # forward jumps in seq
    out_of_order: int = 0       # seq not above the previous one
    first_seq: int = -1
    last_seq: int = -1
    first_stamp_ns: int = 0
    last_stamp_ns: int = 0

    def add(self, seq: int, stamp_ns: int) -> None:
        if self.count == 0:
            self.first_seq, self.first_stamp_ns = seq, stamp_ns
        elif seq > self.last_seq + 1:
            self.seq_gaps += 1
        elif seq <= self.last_seq:
            self.out_of_order += 1
        self.last_seq, self.last_stamp_ns = seq, stamp_ns
        self.count += 1

    @property
    def rate_hz(self) -> float:
        """Mean rate by the messages' stamps (source time, not arrival)."""
        span = self.last_stamp_ns - self.first_stamp_ns
        return (self.count - 1) * 1e9 / span if self.count > 1 and span > 0 else 0.0


class Monitor(Node):
    """Counts messages per topic and prints what flowed, with PASS/FAIL."""

    SIGNAL_ENDS_NORMALLY = True      # Ctrl-C is how it ends

    PARAMS = {"topics": [], "skip_topics": ["/heartbeat"], "expect_count": 0, "idle_s": 0.5,
              "timeout_s": 30.0, "summary_json": ""}
    INPUTS = {ANY_TOPIC: Message}     # every topic of the graph (see graph/launch/topology.py)
    OUTPUTS: dict = {}

    def __init__(self, **kwargs):
        super().__init__("monitor", **kwargs)
        self.stats: dict[str, TopicStats] = {}
        self.malformed_dropped = 0
        self.started = time.monotonic()
        self.last_rx = self.first_rx = None
        for topic in self.param("topics") or [None]:
            self.create_raw_subscription(self.on_message, topic)
        self.create_timer(0.1, self.check_end)

    def on_message(self, topic: str, body: bytes, recv_ns: int) -> None:
        if not self.param("topics") and topic in self.param("skip_topics"):
            return
        try:
            msg = decode_any(body, topic)
        except MessageError as exc:
            self.malformed_dropped += 1
            self.warn(throttle_s=1.0, key=("mon-drop", topic), text=f"dropped malformed message: {exc}")
            return
        stats = self.stats.get(topic)
        if stats is None:
            stats = self.stats[topic] = TopicStats(type(msg).__name__)
        stats.add(msg.seq, msg.stamp_ns)
        self.last_rx = time.monotonic()
        self.first_rx = self.first_rx or self.last_rx
        expect = self.param("expect_count")
        if expect and self.total >= expect:
            self.finish("expected count reached")

    @property
    def total(self) -> int:
        return sum(s.count for s in self.stats.values())

    def publishers_alive(self) -> bool:
        """True while some other node of the graph announces one of the topics seen."""
        # Node has no public graph directory; _dir is where this node announced itself.
        return any(set(info.publishes) & set(self.stats)
                   for info in discovery.scan(self._dir, clean=False) if info.pid != os.getpid())

    def check_end(self) -> None:
        now = time.monotonic()
        if self.last_rx is None:
            if now - self.started > self.param("timeout_s"):
                self.finish(f"nothing received in {self.param('timeout_s'):g} s")
        elif now - self.last_rx >= self.param("idle_s") and not self.publishers_alive():
            self.finish("publishers left the graph")

    def summary(self, why: str) -> dict:
        """The summary as a JSON-able dict, with the verdict and its reasons."""
        problems = []
        if not self.total:
            problems.append("no message received")
        expect = self.param("expect_count")
        if expect and self.total != expect:
            problems.append(f"{self.total} messages, expected {expect}")
        for topic, s in sorted(self.stats.items()):
            if s.seq_gaps:
                problems.append(f"{topic}: {s.seq_gaps} seq gaps")
            if s.out_of_order:
                problems.append(f"{topic}: {s.out_of_order} messages out of order")
        if self.malformed_dropped:
            problems.append(f"{self.malformed_dropped} malformed messages dropped")
        span = (self.last_rx - self.first_rx) if self.first_rx is not None else 0.0
        return {"ended": why, "messages": self.total, "receive_span_s": span,
                "malformed_dropped": self.malformed_dropped, "pass": not problems,
                "problems": problems,
                "topics": {t: {"type": s.type_name, "count": s.count, "seq_gaps": s.seq_gaps,
                               "out_of_order": s.out_of_order, "first_seq": s.first_seq,
                               "last_seq": s.last_seq, "rate_hz": s.rate_hz,
                               "stamp_span_s": (s.last_stamp_ns - s.first_stamp_ns) / 1e9}
                           for t, s in sorted(self.stats.items())}}

    def finish(self, why: str) -> None:
        summary = self.summary(why)
        width = max([len(t) for t in summary["topics"]] + [5])
        lines = [f"{summary['messages']} messages on {len(summary['topics'])} topics "
                 f"in {summary['receive_span_s']:.2f} s ({why})",
                 f"  {'topic':<{width}}  {'type':<14} {'count':>7} {'rate_hz':>8} "
                 f"{'seq_gaps':>8} {'disorder':>8}"]
        for topic, s in summary["topics"].items():
            lines.append(f"  {topic:<{width}}  {s['type']:<14} {s['count']:>7} {s['rate_hz']:>8.1f} "
                         f"{s['seq_gaps']:>8} {s['out_of_order']:>8}")
        lines.append("PASS: every message arrived in order, no seq gap" if summary["pass"]
                     else "FAIL: " + "; ".join(summary["problems"]))
        print("\n".join(lines), flush=True)
        if self.param("summary_json"):
            with open(self.param("summary_json"), "w") as f:
                json.dump(summary, f, indent=1)
        self.shutdown(why, exit_code=0 if summary["pass"] else 1)


def main(argv=None):
    return run_node(Monitor, argv)


if __name__ == "__main__":
    raise SystemExit(main())
