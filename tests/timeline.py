"""The one check of a run's time base (docs/graph.md, "One time base"), for the tests that take it."""
from __future__ import annotations

import signal

from incipient_slip.graph.bag import read_bag
from incipient_slip.messages import Heartbeat


def assert_one_timeline(received: dict, end_ns: int) -> None:
    """Every topic a probe received, per publisher (each node's heartbeats apart), is in stamp order
    and within the run's span (0, end_ns]."""
    for topic, msgs in received.items():
        streams: dict[str, list[int]] = {}
        for m in msgs:
            streams.setdefault(m.node if isinstance(m, Heartbeat) else "", []).append(m.stamp_ns)
        for source, stamps in streams.items():
            assert stamps == sorted(stamps), (topic, source, "stamps go back")
            assert 0 < stamps[0] and stamps[-1] <= end_ns, (topic, source, stamps[0], stamps[-1], end_ns)


def stop_and_read(recorder, out) -> tuple[dict, bytes]:
    """Stops a `slip bag record` process as Ctrl-C does; ({topic: [message, ...]} of its recording
    `out`, its stderr). Fails if it did not end with 0."""
    recorder.send_signal(signal.SIGINT)
    _, err = recorder.communicate(timeout=60)
    assert recorder.returncode == 0, err.decode()[-3000:]
    received: dict[str, list] = {}
    for rec in read_bag(out):
        received.setdefault(rec.topic, []).append(rec.message())
    return received, err
