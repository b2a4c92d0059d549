"""The recorder node: writes every message it receives on its topics to an MCAP file.

    python -m incipient_slip.nodes.recorder path:=run.mcap topics:='[/biotac/pac, /slip/estimate]'
    slip bag record run.mcap /biotac/pac /slip/estimate        # the same, in the foreground

`topics: []` (the default) records every topic of the graph. Bodies are stored exactly as
received (after validation: a malformed message is counted and dropped, never recorded);
log time = receive time, publish time = the message's stamp. On SIGINT/SIGTERM the file is
finished (summary, footer, fsync) before the process exits, so it holds every message the
node received.
"""
from __future__ import annotations

from incipient_slip.messages import MessageError, decode_any
from incipient_slip.nodes.bag import BagError, BagWriter
from incipient_slip.nodes.params import ParamError
from incipient_slip.nodes.runtime import Node, run_node


class Recorder(Node):
    """Records topics (all when `topics` is empty) to the MCAP file `path`."""

    PARAMS = {"path": "recording.mcap", "topics": [], "compression": "zstd"}

    def __init__(self, **kwargs):
        super().__init__("recorder", **kwargs)
        try:
            self.bag = BagWriter(self.param("path"), compression=self.param("compression"),
                                 metadata={"recorder": self.name})
        except BagError as exc:   # run_node reports a ParamError in one line, exit code 2
            raise ParamError(f"node {self.name!r}: parameter 'path': {exc}") from None
        self.dropped = 0
        for topic in self.param("topics") or [None]:
            self.create_raw_subscription(self.on_message, topic)
        self.log(f"recording {', '.join(self.param('topics')) or 'all topics'} to {self.bag.path}")

    def on_message(self, topic: str, body: bytes, recv_ns: int) -> None:
        try:
            msg = decode_any(body, topic)
        except MessageError as exc:
            self.dropped += 1
            self._warn_limited(("rec-drop", topic), f"not recorded, malformed: {exc}")
            return
        self.bag.write(topic, msg, log_time_ns=recv_ns, body=body)

    def close(self) -> None:
        """Stops receiving, then finishes the MCAP file (valid even after SIGTERM)."""
        try:
            super().close()
        finally:
            if getattr(self, "bag", None) is not None and not self.bag.closed:
                self.bag.close()
                total = sum(self.bag.counts.values())
                self.log(f"wrote {total} messages on {len(self.bag.counts)} topics to "
                         f"{self.bag.path}" + (f" ({self.dropped} malformed dropped)" if self.dropped else ""))


def main(argv=None):
    return run_node(Recorder, argv)


if __name__ == "__main__":
    raise SystemExit(main())
