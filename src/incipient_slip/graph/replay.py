"""The replay node: republishes a recording with its original seq, stamps and bytes.

    python -m incipient_slip.graph.replay path:=run.mcap rate:=2.0
    slip bag play run.mcap --rate 2                 # the same, in the foreground

Before the first message it waits (XPUB handshake, no sleep) until the readers the launch names
have subscribed (started by hand, `slip bag play`: until every played topic has
`wait_subscribers` subscribers), or `wait_timeout_s` passed (then it warns and plays anyway).
Pacing follows the messages' stamps, each topic anchored where it starts in receive time,
so a recording made faster than real time (lock-step sim) plays back at sim time x `rate`;
`max_speed` drops pacing. Messages go out in the recording's receive order. `/heartbeat` is
not replayed unless named in `topics` (the replay node beats for itself). When the recording
ends the node exits 0 (unless `loop`), after its subscribers left or `end_hold_s` passed.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

from incipient_slip.messages import Message, MessageError, current_body
from incipient_slip.graph.bag import BagError, bag_info, read_bag
from incipient_slip.graph.params import ParamError
from incipient_slip.graph.runtime import ANY_TOPIC, POLL_S, Node, run_node
from incipient_slip.paths import repo_root

_YIELD_EVERY = 256       # at max speed, messages sent between two looks at signals and timers


def resolve_bag_path(path: str) -> Path:
    """`path` as given if it exists, else relative to the repository root (launch files)."""
    given = Path(path).expanduser()
    if given.exists() or given.is_absolute():
        return given
    in_repo = repo_root() / given
    return in_repo if in_repo.exists() else given


class Replay(Node):
    """Plays the MCAP file `path` at `rate` x (or `max_speed`), once or in a `loop`."""

    PARAMS = {"path": "", "rate": 1.0, "max_speed": False, "loop": False, "topics": [],
              "skip_topics": ["/heartbeat"], "wait_subscribers": 1, "wait_timeout_s": 10.0,
              "end_hold_s": 1.0, "progress": False}
    INPUTS: dict = {}
    OUTPUTS = {ANY_TOPIC: Message}    # whatever its file holds (see graph/launch/topology.py)

    def __init__(self, **kwargs):
        super().__init__("replay", **kwargs)
        if not str(self.param("path")).strip():
            raise ParamError(f"node {self.name!r}: parameter 'path' is empty: name the MCAP "
                             "recording to play (in a launch file, e.g. recording:=run.mcap)")
        self.path = resolve_bag_path(self.param("path"))
        if not self.param("rate") > 0:
            raise ParamError(f"node {self.name!r}: rate must be > 0, got {self.param('rate')}")
        try:
            self.info = bag_info(self.path)
        except BagError as exc:   # run_node reports a ParamError in one line, exit code 2
            raise ParamError(f"node {self.name!r}: parameter 'path': {exc}") from None
        recorded = {t.topic: t for t in self.info.topics}
        wanted = self.param("topics")
        missing = sorted(set(wanted) - set(recorded))
        if missing:
            raise ParamError(f"node {self.name!r}: parameter 'topics': {self.path} has no topic "
                             f"{', '.join(missing)}; it has {', '.join(recorded) or 'none'}")
        self.topics = [t for t in (wanted or recorded)
                       if wanted or t not in self.param("skip_topics")]
        # Where each topic starts in the recording's receive time, and its first stamp.
        self.anchor = {t: (recorded[t].first_log_ns - self.info.start_ns, recorded[t].first_stamp_ns)
                       for t in self.topics}
        self.pubs = {t: self.create_raw_publisher(t) for t in self.topics}
        self.published = self.skipped = 0

    def offset_ns(self, rec) -> int:
        """When `rec` is due, ns after the start of playback at 1x."""
        log_offset, first_stamp = self.anchor[rec.topic]
        if rec.stamp_ns < first_stamp:  # the source's clock restarted: fall back to receive time
            return rec.log_time_ns - self.info.start_ns
        return log_offset + rec.stamp_ns - first_stamp

    def wait_for_subscribers(self) -> None:
        n, deadline = self.param("wait_subscribers"), time.monotonic() + self.param("wait_timeout_s")
        if self.readers:      # in a launch: the nodes it names as readers, by their hello
            self.wait_for_readers(self.param("wait_timeout_s"))
            return
        if n <= 0:
            return
        lonely = [t for t, pub in self.pubs.items()
                  if not pub.wait_for_subscribers(n, max(0.0, deadline - time.monotonic()))]
        if lonely and not self.stopping:
            self.warn(f"no {n} subscriber(s) after {self.param('wait_timeout_s')} s on "
                      f"{', '.join(lonely)}; playing anyway")

    def play_once(self) -> None:
        from tqdm import tqdm

        rate, max_speed = self.param("rate"), self.param("max_speed")
        total = sum(t.count for t in self.info.topics if t.topic in self.pubs)
        bar = tqdm(total=total, unit="msg", desc=self.path.name, file=sys.stderr,
                   disable=not self.param("progress"), leave=False)
        start = time.monotonic()
        try:
            for i, rec in enumerate(read_bag(self.path, self.topics)):
                if max_speed:
                    if i % _YIELD_EVERY == 0:
                        self.spin_once(0)
                else:
                    due = start + self.offset_ns(rec) / 1e9 / rate
                    while not self.stopping and (left := due - time.monotonic()) > 0:
                        self.spin_once(min(left, POLL_S))
                if self.stopping:
                    return
                try:
                    # never put a malformed body on the wire; an older schema version goes out
                    # as the current one (the graph's nodes speak only that)
                    body = current_body(rec.body, rec.topic)
                except MessageError as exc:
                    self.skipped += 1
                    self.warn(throttle_s=1.0, key=("replay-bad", rec.topic), text=f"{self.path}: skipped {exc}")
                    continue
                self.pubs[rec.topic].publish_raw(body)
                self.published += 1
                bar.update()
        finally:
            bar.close()

    def hold(self) -> None:
        """Stays in the graph until every subscriber left, or for `end_hold_s` at most.

        Leaving the graph makes subscribers disconnect from this node, and ZeroMQ discards
        what they had received but not yet read: leaving at once would cut off the tail of
        the recording at a slow subscriber. A subscriber that ends by itself (a recorder
        with max_messages, a monitor with expect_count) releases the replay at once.
        """
        deadline = time.monotonic() + self.param("end_hold_s")
        while not self.stopping and time.monotonic() < deadline:
            if not any(pub.subscriber_count() for pub in self.pubs.values()):
                return
            self.spin_once(POLL_S)

    def spin(self) -> int:
        """Waits for subscribers, plays (again and again if `loop`), then ends the node."""
        self.wait_for_subscribers()
        while not self.stopping:
            self.play_once()
            if not self.param("loop"):
                break
        self.hold()
        self.shutdown(f"played {self.published} messages from {self.path}"
                      + (f", skipped {self.skipped} malformed" if self.skipped else ""))
        return super().spin()


def main(argv=None):
    return run_node(Replay, argv)


if __name__ == "__main__":
    raise SystemExit(main())
