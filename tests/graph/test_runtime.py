"""The node runtime over real ipc sockets: exact topics, gaps, params, remaps, fuzz, shutdown."""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from incipient_slip import messages as M
from incipient_slip.graph import discovery
from incipient_slip.graph.params import ParamError, parse_node_argv
from incipient_slip.graph.runtime import Node, run_node

NODES = Path(__file__).parent / "nodes"


def pac(i=0, **kw):
    return M.BiotacPac(pac_counts=np.full(22, i, dtype=np.int16), **kw)


def test_subscription_gets_messages_in_order_with_no_gap(graph, probe):
    with Node("a") as a, Node("b") as b:
        got = []
        pub = a.create_publisher(M.BiotacPac)
        sub = b.create_subscription(M.BiotacPac, got.append)
        assert pub.wait_for_subscribers(1, 5)
        for i in range(50):
            pub.publish(pac(i))
        probe.until(lambda: len(got) == 50, 5, nodes=[b])
        assert [m.seq for m in got] == list(range(50))
        assert all(m.stamp_ns > 0 for m in got) and sub.gaps == 0


def test_topic_match_is_exact_not_prefix(graph, probe):
    with Node("a") as a, Node("b") as b:
        got = []
        raw_pub = a.create_publisher(M.BiotacPac, "/biotac/pac_raw")
        pub = a.create_publisher(M.BiotacPac)
        b.create_subscription(M.BiotacPac, got.append)
        assert pub.wait_for_subscribers(1, 5)
        assert raw_pub.subscriber_count() == 0
        raw_pub.publish(pac(1))
        pub.publish(pac(2))
        probe.until(lambda: len(got) == 1, 5, nodes=[b])
        b.spin_once(0.05)
        assert [int(m.pac_counts[0]) for m in got] == [2]


def test_seq_gap_is_counted_and_reported(graph, probe):
    with Node("a") as a, Node("b") as b:
        gaps = []
        pub = a.create_publisher(M.BiotacPac)
        sub = b.create_subscription(M.BiotacPac, lambda m: None, on_gap=lambda *g: gaps.append(g))
        assert pub.wait_for_subscribers(1, 5)
        for seq in (0, 1, 5, 6):
            pub.publish(pac(seq=seq), keep_seq=True)
        probe.until(lambda: sub.received == 4, 5, nodes=[b])
        assert (sub.gaps, sub.missed, gaps) == (1, 3, [(1, 5)])


def test_stamp_is_kept_when_set_and_remaps_change_topic(graph, probe):
    with Node("a", remaps={"/biotac/pac": "/sim/pac"}) as a, Node("b") as b:
        got = []
        pub = a.create_publisher(M.BiotacPac)
        assert pub.topic == "/sim/pac"
        b.create_subscription(M.BiotacPac, got.append, topic="/sim/pac")
        assert pub.wait_for_subscribers(1, 5)
        pub.publish(pac(stamp_ns=123))
        probe.until(lambda: got, 5, nodes=[b])
        assert got[0].stamp_ns == 123


def test_params_defaults_then_launch_then_command_line(graph):
    class P(Node):
        PARAMS = {"rate_hz": 100.0, "method": "injection", "n": 3}

    args = parse_node_argv(["rate_hz:=50", "method:=e19", "/a:=/b", "__name:=x"])
    assert (args.params, args.remaps, args.node_name) == ({"rate_hz": 50, "method": "e19"}, {"/a": "/b"}, "x")
    node = P("p", params=args.params, raw_params=args.raw, heartbeat_s=0)
    try:
        assert node.params == {"rate_hz": 50.0, "method": "e19", "n": 3}
        assert isinstance(node.param("rate_hz"), float)
    finally:
        node.close()
    with pytest.raises(ParamError, match="known: method, n, rate_hz"):
        P("p", params={"rate": 1})
    with pytest.raises(ParamError, match="does not fit"):
        P("p", params={"n": "three"})


def test_timer_fires_and_shutdown_returns_exit_code(graph):
    class T(Node):
        def __init__(self, **kw):
            super().__init__("t", **kw)
            self.ticks = 0
            self.create_timer(0.01, self.tick)

        def tick(self):
            self.ticks += 1
            if self.ticks == 5:
                self.shutdown("done", exit_code=3)

    assert run_node(T, []) == 3


def test_node_announces_itself_and_withdraws_on_close(graph):
    node = Node("lonely")
    node.create_subscription(M.SlipEstimate, lambda m: None)
    (info,) = discovery.scan(graph.dir)
    assert (info.name, info.subscribes["/slip/estimate"]) == ("lonely", "SlipEstimate")
    assert info.publishes == {"/heartbeat": "Heartbeat"}
    node.close()
    assert discovery.scan(graph.dir) == []


def test_running_node_survives_fuzzed_frames_and_counts_them(graph, probe):
    listener = graph.spawn(["python", str(NODES / "listener.py"), "report_every:=1"], stdout=None)
    probe.nodes(["listener"])
    rng = np.random.default_rng(0)
    good = M.encode(pac(7, stamp_ns=1, seq=0))
    bad = [good[:n] for n in (0, 1, 5, len(good) // 2, len(good) - 1)]
    bad += [bytes(rng.integers(0, 256, size=n, dtype=np.uint8)) for n in (1, 10, 100, 1000)]
    for _ in range(20):
        b = bytearray(good)
        b[int(rng.integers(len(b)))] ^= 0xFF
        bad.append(bytes(b))
    bad.append(b"\x00" * (M.MAX_BODY_BYTES + 10))
    bad.append(M.encode(M.SlipEstimate()))       # right topic, wrong type
    with Node("fuzzer") as fuzzer:
        hb = []
        fuzzer.create_subscription(M.Heartbeat, lambda m: m.node == "listener" and hb.append(m))
        raw = fuzzer.create_raw_publisher("/biotac/pac")
        assert raw.wait_for_subscribers(1, 10)
        for body in bad:
            raw.publish_raw(body)
        for frames in ([b"/biotac/pac\0"], [b"/biotac/pac\0", good, b"extra"], [b"/biotac/pac\0\xff\xfe", good]):
            fuzzer._xpub.send_multipart(frames)
        fuzzer.create_publisher(M.BiotacPac).publish(pac(1))
        probe.until(lambda: hb and hb[-1].malformed_dropped > 0 and hb[-1].uptime_s > 0, 10, nodes=[fuzzer])
        # counts arrive with the next heartbeat after the frames were handled
        t_first = hb[-1].uptime_s
        probe.until(lambda: hb[-1].uptime_s > t_first, 5, nodes=[fuzzer])
        assert listener.poll() is None, "fuzzed frames killed the node"
        n_bad = sum(1 for b in bad if _is_bad(b))
        assert hb[-1].malformed_dropped == n_bad + 3    # + the three bad multipart messages
    listener.send_signal(signal.SIGTERM)
    out_err = listener.communicate(timeout=5)
    assert listener.returncode == 128 + signal.SIGTERM      # stopped cleanly, by a signal
    assert b"dropped malformed" in out_err[1]


def _is_bad(body):
    try:
        M.decode(body, M.BiotacPac)
    except M.MessageError:
        return True
    return False


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_node_process_stops_cleanly_and_promptly_on_signal_and_exits_128_plus_it(graph, sig, probe):
    proc = graph.spawn(["python", str(NODES / "listener.py")])
    probe.nodes(["listener"])
    t0 = time.monotonic()
    proc.send_signal(sig)
    assert proc.wait(timeout=5) == 128 + sig      # 130, 143: an interrupted node is no success
    assert time.monotonic() - t0 < 5.0     # not the 5 s grace of a launcher: the node itself stopped
    assert [i.name for i in discovery.scan(graph.dir)] == ["probe"]


def test_frames_of_a_publisher_that_just_exited_are_still_delivered(graph, probe):
    """ZeroMQ drops unread frames on disconnect: the runtime must read them before it lets go."""
    with Node("listener") as listener:
        got = []
        listener.create_subscription(M.BiotacPac, got.append)
        own = len(listener._connected)  # a node also connects to its own endpoint
        talker = graph.spawn(["python", str(NODES / "talker.py"), "rate_hz:=100000",
                              "count:=2000", "wait_for:=1"])
        # Connect to the talker, then read nothing until it is gone: all 2000 frames are queued
        # in our pipe when its announcement disappears.
        probe.until(lambda: len(listener._connected) > own, 20, nodes=[listener])
        assert talker.wait(timeout=30) == 0
        probe.until(lambda: len(got) == 2000, 10, nodes=[listener])
        assert [m.seq for m in got] == list(range(2000))


def test_a_node_whose_constructor_fails_leaves_no_files(graph):
    class Broken(Node):
        PARAMS = {"model": ""}

        def __init__(self, **kw):
            super().__init__("broken", **kw)
            self.on_shutdown(lambda: self.never_set)      # would raise: not run for a half-built node
            raise ParamError(f"node {self.name!r}: parameter 'model': no such file")

    assert run_node(Broken, []) == 2
    assert sorted(os.listdir(graph.dir)) == []


def test_files_of_a_sigkilled_node_are_removed_at_the_next_scan(graph, probe):
    proc = graph.spawn(["python", str(NODES / "listener.py")])
    probe.nodes(["listener"], procs=[proc])
    assert any(name.startswith("listener-") and name.endswith(".sock") for name in os.listdir(graph.dir))
    proc.kill()
    proc.wait()
    assert [i.name for i in discovery.scan(graph.dir)] == ["probe"]
    assert not [n for n in os.listdir(graph.dir) if n.startswith("listener-")]


def test_an_announcement_whose_pid_now_belongs_to_a_younger_process_is_stale(graph):
    """pid reuse: the file of a node killed long ago names a pid that a newer process holds."""
    info = discovery.NodeInfo("ghost", os.getpid(), "ipc:///nonexistent", started_ns=1)
    discovery.announce(graph.dir, info)
    assert discovery.scan(graph.dir) == []
    assert os.listdir(graph.dir) == []


def test_a_node_that_declares_no_outputs_still_beats(graph, probe):
    beats = probe.listen(M.Heartbeat)

    class Quiet(Node):
        INPUTS: dict = {}
        OUTPUTS: dict = {}

    with Quiet("quiet", heartbeat_s=0.05) as quiet:
        probe.until(lambda: any(b.node == "quiet" for b in beats), 10, nodes=[quiet])


def test_a_node_closing_before_its_first_heartbeat_still_sends_one_with_its_counts(graph, probe):
    """A node's last heartbeat is sent as it closes: rig_sim's lock-step run is shorter than a
    heartbeat period once it starts, and a loaded test run heard none from it at all."""
    beats = probe.listen(M.Heartbeat)
    talker = Node("brief", heartbeat_s=3600.0)
    pub = talker.create_publisher(M.PztCommand)
    probe.listen(M.PztCommand)
    probe.until(lambda: pub.subscriber_count() >= 1, 10, nodes=[talker])
    talker.malformed = 2
    talker.close()
    probe.until(lambda: any(b.node == "brief" for b in beats), 10)
    assert [b.malformed_dropped for b in beats if b.node == "brief"] == [2]


def test_a_script_that_never_closes_its_node_leaves_no_files(graph):
    script = ("from incipient_slip.graph.runtime import Node\n"
              "node = Node('careless')\n"
              "raise SystemExit(5)\n")
    proc = graph.spawn(["python", "-c", script])
    assert proc.wait(timeout=30) == 5
    assert os.listdir(graph.dir) == []


def test_a_latched_state_reaches_a_late_subscriber_and_no_one_gets_it_twice(graph, probe):
    """/pzt/state goes out at start and on change: a recorder or echo that joins mid-run gets the
    last one (transient-local, depth 1); the subscribers it reached already drop the re-send."""
    with Node("rig") as rig, Node("early") as early, Node("late") as late:
        first, later, raw = [], [], []
        pub = rig.create_publisher(M.PztState)
        early.create_subscription(M.PztState, first.append)
        assert pub.wait_for_subscribers(1, 20)
        pub.publish(M.PztState(enabled=True, intensity_db=-6.0))
        probe.until(lambda: first, 20, nodes=[rig, early])
        late.create_subscription(M.PztState, later.append)        # joins after the only message
        late.create_raw_subscription(lambda topic, body, ns: raw.append(topic))    # a recorder
        probe.until(lambda: later and raw, 20, nodes=[rig, early, late], what="the latched state")
        pub.publish(M.PztState(enabled=False))
        probe.until(lambda: len(first) == 2 and len(later) == 2, 20, nodes=[rig, early, late])
        assert [m.enabled for m in first] == [True, False] and [m.enabled for m in later] == [True, False]
        assert later[0].intensity_db == -6.0 and raw.count("/pzt/state") == 2
        assert early.duplicates >= 1


def test_a_callback_that_shuts_down_gets_no_further_message_from_the_queue(graph):
    # spin_once drains queued messages after the one it waited for; shutdown() in a callback
    # must end that drain (no callback after shutdown). inproc puts every sent message in the
    # reader's queue before send returns, so all of them are queued when the node spins.
    import zmq

    with Node("reader", heartbeat_s=0) as node:
        got = []

        def on_pac(msg):
            got.append(msg.seq)
            node.shutdown()

        node.create_subscription(M.BiotacPac, on_pac)
        xpub = zmq.Context.instance().socket(zmq.XPUB)
        try:
            xpub.bind("inproc://drain-test")
            node._sub.connect("inproc://drain-test")
            while xpub.recv() != b"\x01" + M.topic_frame(M.BiotacPac.TOPIC):
                pass
            for seq in range(20):
                xpub.send_multipart([M.topic_frame(M.BiotacPac.TOPIC), M.encode(pac(seq), seq=seq)])
            assert node.spin() == 0
            assert got == [0]
            node._stop = False          # the rest is still queued: the next spin reads it
            node.spin_once(0.5)
            assert got == [0, 1]
        finally:
            xpub.close(0)
