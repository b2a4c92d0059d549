"""Start-up handshakes by name: a publisher waits for the readers the launch gives it (hello).

XPUB subscription messages carry no identity, so each node also subscribes HELLO + its name
once its own subscriptions are made; a publisher's `wait_for_readers` returns when the hello of
every named reader of its outputs has arrived, and then those readers' subscriptions are in
place (same pipe, in order). A stranger that subscribes to everything (a `slip bag record`
started earlier) satisfies no one.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

from incipient_slip import messages as M
from incipient_slip.graph.runtime import HELLO, Node
from waiting import spin_until


def pac(i=0):
    return M.BiotacPac(pac_counts=np.full(22, i, dtype=np.int16))


class Spinner:
    """Spins nodes in a thread (each node is used by this thread only) until stopped."""

    def __init__(self, *nodes):
        self.nodes, self.stop = nodes, threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self):
        while not self.stop.is_set():
            for node in self.nodes:
                node.spin_once(0.005)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(5)


def test_wait_for_readers_returns_at_once_without_a_launch_topology(graph):
    with Node("alone", heartbeat_s=0, readers={}) as node:
        node.create_publisher(M.BiotacPac)
        assert node.wait_for_readers(timeout_s=0.0)


def test_wait_for_readers_times_out_naming_the_missing_reader(graph, capsys):
    with Node("src", heartbeat_s=0, readers={"/biotac/pac": ["estimator"]}) as node:
        node.create_publisher(M.BiotacPac)
        assert not node.wait_for_readers(timeout_s=0.2)
    assert "readers estimator not subscribed" in capsys.readouterr().err


# Topics on both sides of HELLO's first byte in a plain sort; raw "" subscribes to everything.
TOPIC_SETS = [["/biotac/pac"], ["/a", "/z", "/~tilde", "/slip/estimate", "/grip/command"],
              [""] + [f"/t{i:03d}" for i in range(60)]]


@pytest.mark.parametrize("late_publisher", [False, True], ids=["reader-first", "publisher-first"])
@pytest.mark.parametrize("topics", TOPIC_SETS, ids=["one", "mixed", "many+all"])
def test_hello_arrives_after_every_other_subscription_of_the_reader(graph, topics, late_publisher):
    """Both ways a SUB sends its subscriptions: all at once when it connects (reader-first: they
    were made before the publisher existed; libzmq sends them in byte order, so HELLO's 0xFF
    puts the hello last) or one by one as they are made (publisher-first)."""
    def make_reader():
        reader = Node("reader", heartbeat_s=0)
        for topic in topics:
            if topic:
                reader.create_subscription(M.BiotacPac, lambda m: None, topic=topic)
            else:
                reader.create_raw_subscription(lambda *a: None)
        return reader

    reader = None if late_publisher else make_reader()
    if reader is not None:
        reader.spin_once(0)                     # subscriptions and hello made before the XPUB exists
    with Node("writer", heartbeat_s=0, readers={"/x": ["reader"]}) as writer:
        writer._xpub = LoggedSocket(writer._xpub)
        reader = reader or make_reader()
        with Spinner(reader):
            assert writer.wait_for_readers(timeout_s=20)
        frames = [M.topic_frame(t) if t else b"" for t in topics]
        assert all(writer._sub_counts.get(f) for f in frames), "hello overtook a subscription"
        # and in order, so that a batch split between two reads cannot reorder them either
        log = writer._xpub.log
        hello = log.index(b"\x01" + HELLO + b"reader")
        assert all(log.index(b"\x01" + f) < hello for f in frames), log
    reader.close()


class LoggedSocket:
    """A socket that logs what recv() returned (the XPUB's subscription messages, in order)."""

    def __init__(self, socket):
        self.socket, self.log = socket, []

    def recv(self, *args, **kwargs):
        msg = self.socket.recv(*args, **kwargs)
        self.log.append(msg)
        return msg

    def __getattr__(self, name):
        return getattr(self.socket, name)


def test_a_stranger_subscribed_to_everything_does_not_satisfy_a_named_reader(graph, probe):
    """The lost-period-0 bug: a recorder started before the launch met "one subscriber per
    topic", so the source started before the estimator listened."""
    with Node("recorder", heartbeat_s=0) as stranger, \
            Node("rig", heartbeat_s=0, readers={"/biotac/pac": ["estimator"]}) as rig:
        stranger.create_raw_subscription(lambda *a: None)
        pub = rig.create_publisher(M.BiotacPac)
        with Spinner(stranger):
            assert pub.wait_for_subscribers(1, 20)          # a count is satisfied by the stranger
            assert not rig.wait_for_readers(timeout_s=0.3)  # the named reader is not there
        got = []
        with Node("estimator", heartbeat_s=0) as estimator:
            estimator.create_subscription(M.BiotacPac, got.append)
            with Spinner(estimator, stranger):
                assert rig.wait_for_readers(timeout_s=20)
            pub.publish(pac(0))
            probe.until(lambda: got, 10, nodes=[estimator], what="message 0 at the estimator")
        assert [m.seq for m in got] == [0]


def test_two_nodes_that_read_each_other_both_get_through(graph):
    a = Node("a", heartbeat_s=0, readers={"/grip/command": ["b"]})
    b = Node("b", heartbeat_s=0, readers={"/slip/estimate": ["a"]})
    try:
        a.create_subscription(M.SlipEstimate, lambda m: None)
        b.create_subscription(M.GripCommand, lambda m: None)
        results = {}
        t = threading.Thread(target=lambda: results.setdefault("b", b.wait_for_readers(20)))
        t.start()
        results["a"] = a.wait_for_readers(20)
        t.join(25)
        assert results == {"a": True, "b": True}
    finally:
        a.close()
        b.close()


def test_missing_readers_names_them_without_blocking_until_their_hello_arrives(graph):
    """The timer-driven form (linear_actuator): a list of names, empty once each reader's hello
    is in; a stranger subscribing to everything does not count."""
    import time
    with Node("src", heartbeat_s=0, readers={"/biotac/pac": ["estimator", "recorder"]}) as src:
        src.create_publisher(M.BiotacPac)
        assert src.missing_readers() == ["estimator", "recorder"]
        stranger = Node("stranger", heartbeat_s=0)
        stranger.create_raw_subscription(lambda *a: None)
        readers = [Node(n, heartbeat_s=0) for n in ("estimator", "recorder")]
        for r in readers:
            r.create_subscription(M.BiotacPac, lambda m: None)
        with Spinner(stranger, *readers):
            spin_until(lambda: time.sleep(0.01), lambda: src.missing_readers() == [], 20, (), "the readers' hellos")
        for n in (stranger, *readers):
            n.close()
