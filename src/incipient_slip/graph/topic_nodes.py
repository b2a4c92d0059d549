"""The nodes behind `slip topic list|echo|hz` (graph/tools.py registers the commands): each listens
to the running graph and prints what it hears."""
from __future__ import annotations

import json
import math
import os
import sys
import time
from collections import deque

from incipient_slip.graph import discovery
from incipient_slip.graph.runtime import Node
from incipient_slip.messages import MessageError, decode_any, to_plain

__all__ = ["TopicList", "TopicEcho", "TopicHz", "NOTHING_YET_S", "say"]


def say(node: Node, text: str) -> None:
    """Prints `text`; when the reader of stdout went away (`slip topic echo | head`), ends `node`
    cleanly (its announcement withdrawn, exit 0) instead of letting every callback raise."""
    try:
        print(text, flush=True)
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # nothing left to flush
        node.shutdown("the reader of stdout went away")


class TopicList(Node):
    """Listens to every topic for `duration_s` and prints topics, types, publishers and rates."""

    SIGNAL_ENDS_NORMALLY = True      # Ctrl-C is how it ends

    PARAMS = {"duration_s": 1.0, "json": False}

    def __init__(self, **kwargs):
        super().__init__("slip_topic_list", **kwargs)
        self.counts: dict[str, int] = {}
        self.types: dict[str, str] = {}
        self.create_raw_subscription(self.on_message)
        self.create_timer(self.param("duration_s"), self.report)
        self.t0 = time.monotonic()

    def on_message(self, topic: str, body: bytes, recv_ns: int) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if topic not in self.types:
            try:
                self.types[topic] = type(decode_any(body, topic)).__name__
            except MessageError:
                self.types[topic] = "(malformed)"

    def report(self) -> None:
        elapsed = time.monotonic() - self.t0
        rows: dict[str, dict] = {}
        for info in discovery.scan(self._dir, clean=False):
            if info.pid == os.getpid():
                continue
            for topic, type_name in info.publishes.items():
                row = rows.setdefault(topic, {"topic": topic, "type": type_name, "publishers": []})
                row["publishers"].append(info.name)
                if row["type"] == "raw":
                    row["type"] = self.types.get(topic, "raw")
        for topic, n in self.counts.items():   # heard, though its publisher already left
            rows.setdefault(topic, {"topic": topic, "type": self.types[topic], "publishers": []})
        for row in rows.values():
            row["rate_hz"] = self.counts.get(row["topic"], 0) / elapsed
        table = sorted(rows.values(), key=lambda r: r["topic"])
        if self.param("json"):
            say(self, json.dumps(table))
        elif not table:
            say(self, f"no topics in graph {self._dir}")
        else:
            width = max(len(r["topic"]) for r in table)
            say(self, "\n".join([f"{'topic':<{width}}  {'type':<14} {'rate_hz':>9}  publishers"] + [
                f"{r['topic']:<{width}}  {r['type']:<14} {r['rate_hz']:>9.1f}  "
                f"{', '.join(sorted(r['publishers'])) or '-'}" for r in table]))
        self.shutdown()


def _json_safe(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, list):
        return [_json_safe(v) for v in value]
    return value


def _yaml_value(value) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    return json.dumps(value)


NOTHING_YET_S = 3.0       # slip topic echo says it is still waiting after this long without a message


class TopicEcho(Node):
    """Prints each message on `topic` (YAML documents, or JSON lines), `count` times (0: forever)."""

    SIGNAL_ENDS_NORMALLY = True      # Ctrl-C is how it ends

    PARAMS = {"topic": "", "count": 0, "json": False}

    def __init__(self, **kwargs):
        super().__init__("slip_topic_echo", **kwargs)
        self.printed = 0
        self.create_raw_subscription(self.on_message, self.param("topic"))
        self.create_timer(NOTHING_YET_S, self.say_if_silent)

    def say_if_silent(self) -> None:
        """One line on stderr while nothing arrived, so an empty graph is not a silent hang."""
        if not self.printed:
            self.warn(f"no message on {self.param('topic')} yet in graph {self._dir} "
                      f"(is a launch running there?); waiting", throttle_s=30.0)

    def on_message(self, topic: str, body: bytes, recv_ns: int) -> None:
        try:
            msg = decode_any(body, topic)
        except MessageError as exc:
            self.warn(f"malformed message dropped: {exc}")
            return
        plain = to_plain(msg)
        if self.param("json"):
            say(self, json.dumps({"topic": topic, **{k: _json_safe(v) for k, v in plain.items()}}))
        else:   # YAML documents, one field a line, arrays inline (JSON is YAML)
            lines = [f"--- # {topic}"] + [f"{k}: {_yaml_value(v)}" for k, v in plain.items()]
            say(self, "\n".join(lines))
        self.printed += 1
        if self.param("count") and self.printed >= self.param("count"):
            self.shutdown()


class TopicHz(Node):
    """Prints the rate of `topic` every second over the last `window` messages."""

    SIGNAL_ENDS_NORMALLY = True      # Ctrl-C is how it ends

    PARAMS = {"topic": "", "window": 100, "duration_s": 0.0}

    def __init__(self, **kwargs):
        super().__init__("slip_topic_hz", **kwargs)
        self.recv = deque(maxlen=max(2, self.param("window")))
        self.stamps = deque(maxlen=max(2, self.param("window")))
        self.create_raw_subscription(self.on_message, self.param("topic"))
        self.create_timer(1.0, self.report)
        if self.param("duration_s") > 0:
            self.create_timer(self.param("duration_s"), self.shutdown)

    def on_message(self, topic: str, body: bytes, recv_ns: int) -> None:
        try:
            msg = decode_any(body, topic)
        except MessageError:
            return
        self.recv.append(recv_ns)
        self.stamps.append(msg.stamp_ns)

    def report(self) -> None:
        if len(self.recv) < 2:
            say(self, f"{self.param('topic')}: no messages yet")
            return
        import numpy as np
        dt = np.diff(np.array(self.recv, dtype=np.int64)) / 1e9
        dstamp = np.diff(np.array(self.stamps, dtype=np.int64)) / 1e9
        dstamp = dstamp[dstamp > 0]          # a replay that loops restarts its stamps
        rate = 1.0 / dt.mean() if dt.mean() > 0 else float("inf")
        stamp_rate = 1.0 / dstamp.mean() if dstamp.size else float("nan")
        say(self, f"{self.param('topic')}: rate {rate:.2f} Hz (by stamps {stamp_rate:.2f} Hz)  "
                  f"min {dt.min():.4f} s  max {dt.max():.4f} s  std {dt.std():.5f} s  "
                  f"window {len(self.recv)}")
