"""SLIP_TRANSPORT=tcp: CURVE authentication and encryption with each node's key pair (the
permissions file and identity by key: tests/graph/test_node_keys.py)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import zmq

from incipient_slip import messages as M
from incipient_slip.graph import security
from incipient_slip.graph.runtime import Node


@pytest.fixture
def tcp(graph, monkeypatch):
    monkeypatch.setenv("SLIP_TRANSPORT", "tcp")
    monkeypatch.delenv("SLIP_KEYSTORE", raising=False)
    return graph


def test_a_process_without_the_graph_key_can_neither_read_nor_publish(tcp, probe):
    ctx = zmq.Context()
    with Node("w", heartbeat_s=0) as w, Node("r", heartbeat_s=0) as r:
        pub = w.create_publisher(M.RunEvent)
        got = []
        r.create_subscription(M.RunEvent, got.append)
        # two readers without a key of the graph: plain TCP, and CURVE with a key of their own
        # (knowing the writer's public key, as anyone who saw it could)
        plain = ctx.socket(zmq.SUB)
        stranger = ctx.socket(zmq.SUB)
        stranger.curve_publickey, stranger.curve_secretkey = zmq.curve_keypair()
        store = security.keystore(tcp.dir)
        stranger.curve_serverkey = security.node_keys(store, "w")[0]
        for sock in (plain, stranger):
            sock.setsockopt(zmq.SUBSCRIBE, b"")
            sock.connect(w._info.endpoint)
        # and a publisher without it, announced in the graph: plain TCP
        rogue = ctx.socket(zmq.XPUB)
        port = rogue.bind_to_random_port("tcp://127.0.0.1")
        (tcp.dir / f"rogue-{os.getpid()}.node.json").write_text(json.dumps(
            {"name": "rogue", "pid": os.getpid(), "endpoint": f"tcp://127.0.0.1:{port}",
             "publishes": {M.RunEvent.TOPIC: "RunEvent"}, "subscribes": {}}))
        # plain TCP lets the plain stranger subscribe (2 subscriptions); CURVE refuses the wrong key
        probe.until(lambda: pub.subscriber_count() >= 2 or getattr(w, "refused_clients", 0) >= 1, 30, nodes=[w, r],
                    what="the strangers subscribed or refused")
        assert pub.wait_for_subscribers(1, 30)
        # the rogue has no key in the keystore: no node connects to it
        probe.until(lambda: ("rogue", os.getpid()) in r.refused_writers, 30, nodes=[w, r])
        for i in range(5):
            pub.publish(M.RunEvent(kind="step", step=i))
            rogue.send_multipart([M.topic_frame(M.RunEvent.TOPIC), M.encode(M.RunEvent(kind="fault", detail="forged"))])
        probe.until(lambda: len(got) >= 5, 30, nodes=[w, r], what="the graph's own messages")
        assert [m.kind for m in got] == ["step"] * 5 and pub.subscriber_count() == 1
        assert w.refused_clients >= 1
        assert (store / "w.key_secret").stat().st_mode & 0o777 == 0o600
        assert store.stat().st_mode & 0o777 == 0o700
        # a bound, not a wait for an event: nothing may arrive (with plain TCP it would be there)
        for sock in (plain, stranger):
            assert not sock.poll(500), "a reader without the key received a message"
    for sock in (plain, stranger, rogue):
        sock.close(linger=0)
    ctx.term()


def test_a_key_file_others_can_read_is_refused(tcp):
    security.node_keys(security.keystore(tcp.dir), "a")
    key = tcp.dir / "keys" / "a.key_secret"
    key.chmod(0o644)
    with pytest.raises(security.TransportError, match="chmod 600"):
        Node("a")


@pytest.mark.parametrize("value,expect", [("tcp-insecure", "WARNING: SLIP_TRANSPORT=tcp-insecure: plain TCP"),
                                          ("udp", "SLIP_TRANSPORT='udp': use one of ipc, tcp, tcp-insecure")])
def test_insecure_tcp_warns_and_an_unknown_transport_is_one_line(graph, value, expect):
    code = ("from incipient_slip.graph.runtime import Node, run_node\n"
            "class X(Node):\n"
            "    def __init__(self, **kw):\n"
            "        super().__init__('x', **kw)\n"
            "        self.shutdown()\n"
            "raise SystemExit(run_node(X, []))\n")
    done = subprocess.run([sys.executable, "-c", code], env=dict(graph.env, SLIP_TRANSPORT=value),
                          capture_output=True, text=True, timeout=60)
    assert expect in done.stderr
    assert done.returncode == (0 if value == "tcp-insecure" else 2)
