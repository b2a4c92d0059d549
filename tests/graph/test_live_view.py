"""The live view (graph/live_view.py) as a Foxglove WebSocket client sees it: channels, schemas,
messages, audio, refusals and a stalled client. The client is tests/graph/foxglove_client.py,
written from the protocol's specification (no foxglove code)."""
from __future__ import annotations

import base64
import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("foxglove", reason="the [view] extra (foxglove-sdk) is not installed")
from jsonschema import Draft202012Validator  # noqa: E402

from foxglove_client import FoxgloveClient  # noqa: E402
from incipient_slip.graph import discovery  # noqa: E402
from incipient_slip.graph.bag_export import RAW_AUDIO_SCHEMA, raw_audio_block, to_export_json  # noqa: E402
from incipient_slip.graph.live_view import LiveView, _json, is_loopback  # noqa: E402
from incipient_slip.messages import MESSAGE_TYPES, BiotacPac, SlipEstimate, encode  # noqa: E402

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def view():
    v = LiveView("127.0.0.1", 0)
    try:
        yield v
    finally:
        v.close()


def client_of(view, **kw) -> FoxgloveClient:
    client = FoxgloveClient(f"ws://127.0.0.1:{view.port}", **kw)
    client.until(lambda: client.server_info is not None, what="serverInfo")
    return client


def estimate(seq: int, stick_ratio: float = 0.25) -> SlipEstimate:
    return SlipEstimate(stick_ratio=stick_ratio, valid=True, period=seq, method="injection",
                        stamp_ns=1_763_900_000_000_000_000 + seq, seq=seq)


def test_an_offered_topic_is_advertised_as_json_with_a_valid_schema_from_the_contract(view):
    view.offer(SlipEstimate.TOPIC, "SlipEstimate")
    view.offer("/biotac/pac", "BiotacPac")
    view.offer("/unknown", "NoSuchType")              # not in the contract: not advertised
    client = client_of(view)
    client.until(lambda: {"/slip/estimate", "/biotac/pac", "/biotac/pac/audio"} <= set(client.topics()))
    topics = client.topics()
    assert "/unknown" not in topics
    for topic, name in (("/slip/estimate", "SlipEstimate"), ("/biotac/pac", "BiotacPac"),
                        ("/biotac/pac/audio", "foxglove.RawAudio")):
        channel = topics[topic]
        assert (channel["encoding"], channel["schemaEncoding"], channel["schemaName"]) == \
            ("json", "jsonschema", name)
        Draft202012Validator.check_schema(json.loads(channel["schema"]))
    assert json.loads(topics["/biotac/pac/audio"]["schema"]) == RAW_AUDIO_SCHEMA
    client.close()


def test_a_subscribed_client_receives_the_export_json_stamped_with_the_message_time(view):
    view.offer(SlipEstimate.TOPIC, "SlipEstimate")
    client = client_of(view)
    client.until(lambda: SlipEstimate.TOPIC in client.topics())
    client.subscribe([SlipEstimate.TOPIC])
    schema = Draft202012Validator(json.loads(client.topics()[SlipEstimate.TOPIC]["schema"]))
    sent = [estimate(i, 0.1 * i) for i in range(5)]
    # the subscription reaches the server asynchronously: offer until it counts
    client.until(lambda: view.forward(SlipEstimate.TOPIC, encode(sent[0])), what="subscription active")
    for msg in sent[1:]:
        assert view.forward(SlipEstimate.TOPIC, encode(msg))
    client.until(lambda: len(client.messages) >= len(sent))
    for msg, got in zip(sent, client.messages):
        assert got.payload == json.loads(json.dumps(to_export_json(msg)))
        assert got.log_time_ns == msg.stamp_ns
        assert not list(schema.iter_errors(got.payload))
    client.close()


def test_a_topic_no_client_subscribes_to_is_not_decoded(view):
    view.offer(SlipEstimate.TOPIC, "SlipEstimate")
    assert view.forward(SlipEstimate.TOPIC, b"not msgpack") is False   # would raise if decoded


def test_p_ac_audio_is_upsampled_to_a_rate_browsers_play_and_keeps_the_tone(view):
    view.offer("/biotac/pac", "BiotacPac")
    client = client_of(view)
    client.until(lambda: "/biotac/pac/audio" in client.topics())
    client.subscribe(["/biotac/pac/audio"])
    t = np.arange(22 * 40) / 2200.0
    counts = np.rint(1000 * np.sin(2 * np.pi * 200.0 * t)).astype(np.int16).reshape(40, 22)
    frames = [BiotacPac(pac_counts=c, stamp_ns=10**9 + j * 10_000_000, seq=j) for j, c in enumerate(counts)]
    client.until(lambda: view.forward("/biotac/pac", encode(frames[0])), what="subscription active")
    for frame in frames[1:]:
        view.forward("/biotac/pac", encode(frame))
    # every sample, in blocks of 10 frames (100 ms), each logged at its last frame's stamp
    client.until(lambda: len(client.messages) >= len(frames) // 10)
    blocks = [m.payload for m in client.messages]
    assert {(b["format"], b["sample_rate"], b["number_of_channels"]) for b in blocks} == {("pcm-s16", 8800, 1)}
    assert [m.log_time_ns for m in client.messages] == [f.stamp_ns for f in frames[9::10]]
    pcm = np.concatenate([np.frombuffer(base64.b64decode(b["data"]), "<i2") for b in blocks])
    assert pcm.size == 4 * counts.size
    spectrum = np.abs(np.fft.rfft(pcm[400:].astype(float)))
    peak_hz = np.fft.rfftfreq(pcm[400:].size, 1 / 8800)[spectrum.argmax()]
    assert abs(peak_hz - 200.0) < 10.0
    # images of the tone at 2200 -/+ 200 Hz are filtered out (below 5 % of the tone)
    image = spectrum[np.abs(np.fft.rfftfreq(pcm[400:].size, 1 / 8800) - 2000.0) < 20].max()
    assert image < 0.05 * spectrum.max()
    client.close()


def pac_frames(n: int, t0_ns: int = 10**9, seq0: int = 0) -> list[BiotacPac]:
    """n consecutive P_AC frames (10 ms apart), each with different counts."""
    rng = np.random.default_rng(seq0)
    return [BiotacPac(pac_counts=rng.integers(-2000, 2000, 22).astype(np.int16),
                      stamp_ns=t0_ns + j * 10_000_000, seq=seq0 + j) for j in range(n)]


@pytest.mark.parametrize("pac_view_hz,shown", [(10.0, range(0, 40, 10)), (25.0, range(0, 40, 4)),
                                               (0.0, range(40))])
def test_p_ac_frames_are_thinned_to_pac_view_hz_by_their_stamps(pac_view_hz, shown):
    view = LiveView("127.0.0.1", 0, pac_view_hz=pac_view_hz)
    try:
        view.offer("/biotac/pac", "BiotacPac")
        view.offer(SlipEstimate.TOPIC, "SlipEstimate")
        client = client_of(view)
        client.until(lambda: {"/biotac/pac", SlipEstimate.TOPIC} <= set(client.topics()))
        client.subscribe(["/biotac/pac", SlipEstimate.TOPIC])
        client.until(lambda: view.forward(SlipEstimate.TOPIC, encode(estimate(0))), what="subscription active")
        frames = pac_frames(40)
        for frame in frames:
            assert view.forward("/biotac/pac", encode(frame))
        view.forward(SlipEstimate.TOPIC, encode(estimate(1)))     # sent after the frames: arrives after them
        client.until(lambda: any(m.topic == SlipEstimate.TOPIC and m.payload["seq"] == 1
                                 for m in client.messages), what="the estimate after the frames")
        got = [m for m in client.messages if m.topic == "/biotac/pac"]
        assert [m.payload for m in got] == [json.loads(json.dumps(to_export_json(frames[i]))) for i in shown]
        client.close()
    finally:
        view.close()


def test_an_audio_block_holds_consecutive_frames_only():
    view = LiveView("127.0.0.1", 0, audio_rate_hz=2200, audio_block_frames=10)
    try:
        view.offer("/biotac/pac", "BiotacPac")
        client = client_of(view)
        client.until(lambda: "/biotac/pac/audio" in client.topics())
        client.subscribe(["/biotac/pac/audio"])
        # 5 frames, a lost one, 10 more: a block of 5, then one of 10
        frames = pac_frames(16)
        del frames[5]
        client.until(lambda: view.forward("/biotac/pac", encode(frames[0])), what="subscription active")
        for frame in frames[1:]:
            view.forward("/biotac/pac", encode(frame))
        client.until(lambda: len(client.messages) >= 2)
        first, second = (m.payload for m in client.messages[:2])
        for block, part in ((first, frames[:5]), (second, frames[5:])):
            pcm = np.frombuffer(base64.b64decode(block["data"]), "<i2")
            assert np.array_equal(pcm, np.concatenate([f.pac_counts for f in part]))  # x1: as sent
            start_ns = part[-1].stamp_ns - round((pcm.size - 1) * 1e9 / 2200)
            assert block["timestamp"] == {"sec": start_ns // 10**9, "nsec": start_ns % 10**9}
        assert [m.log_time_ns for m in client.messages[:2]] == [frames[4].stamp_ns, frames[-1].stamp_ns]
        client.close()
    finally:
        view.close()


def test_client_publishing_parameters_and_services_are_refused(view):
    client = client_of(view)
    assert client.server_info["capabilities"] == []
    client.send({"op": "advertise", "channels": [{"id": 1, "topic": "/grip/command", "encoding": "json",
                                                  "schemaName": "GripCommand"}]})
    client.send({"op": "getParameters", "parameterNames": []})
    client.send({"op": "setParameters", "parameters": [{"name": "k", "value": 9.0}]})
    client.until(lambda: len(client.statuses) >= 3, what="three refusals")
    text = " ".join(s["message"] for s in client.statuses)
    assert {s["level"] for s in client.statuses} == {2}          # errors
    assert "clientPublish" in text and "parameters" in text
    client.close()


def test_a_stalled_client_neither_blocks_the_bridge_nor_starves_another_client():
    view = LiveView("127.0.0.1", 0, backlog=64)
    try:
        view.offer(SlipEstimate.TOPIC, "SlipEstimate")
        stalled = client_of(view, max_queue=1)
        stalled.until(lambda: SlipEstimate.TOPIC in stalled.topics())
        stalled.subscribe([SlipEstimate.TOPIC])              # and never reads again
        reader = client_of(view)
        reader.until(lambda: SlipEstimate.TOPIC in reader.topics())
        reader.subscribe([SlipEstimate.TOPIC])
        reader.until(lambda: view.forward(SlipEstimate.TOPIC, encode(estimate(0))), what="subscription active")
        # far more than fits the stalled client's backlog and the socket buffers of both hops, the
        # SDK's to the subprotocol front and the front's to the client (~1 KB each; loopback buffers
        # grow to megabytes: 19296 of 20000 fitted on a quiet machine)
        n = 80_000
        for seq in range(1, n):
            view.forward(SlipEstimate.TOPIC, encode(estimate(seq)))
        reader.until(lambda: reader.messages and reader.messages[-1].payload["seq"] == n - 1,
                     what="the reader gets the last message")
        while stalled.pump(0.5):          # what the stalled client had queued: not everything
            pass
        assert len(stalled.messages) < n - 1000
        stalled.close()
        reader.close()
    finally:
        view.close()


@pytest.mark.parametrize("host,loopback", [("127.0.0.1", True), ("127.0.0.5", True), ("::1", True),
                                           ("localhost", True), ("0.0.0.0", False),
                                           ("192.168.1.4", False), ("example.org", False)])
def test_only_loopback_addresses_count_as_local(host, loopback):
    assert is_loopback(host) is loopback


def served_url(proc) -> tuple[str, list[str]]:
    """The URL from the bridge's 'serving ws://...' line, and the stderr lines up to it."""
    lines = []
    for raw in proc.stderr:
        lines.append(raw.decode(errors="replace"))
        if "serving ws://" in lines[-1]:
            return lines[-1].split("serving ", 1)[1].split()[0], lines
    raise AssertionError(f"the bridge ended without serving:\n{''.join(lines)}")


def test_a_non_loopback_address_is_served_with_one_warning_line(graph):
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.foxglove_bridge", "host:=0.0.0.0", "port:=0"])
    url, lines = served_url(proc)
    warnings = [line for line in lines if "WARNING" in line]
    assert len(warnings) == 1 and "no authentication" in warnings[0], lines
    client = FoxgloveClient(url.replace("0.0.0.0", "127.0.0.1"))
    client.until(lambda: client.server_info is not None)
    client.close()


def test_slip_view_attaches_to_the_running_graph_and_advertises_its_topics(graph, probe):
    talker = probe.node.create_publisher(SlipEstimate)          # a node of the running graph
    proc = graph.spawn(["python", "-m", "incipient_slip.cli", "view", "--port", "0"])
    url, lines = served_url(proc)
    assert not [line for line in lines if "WARNING" in line], lines
    # foxglove-sdk 0.30.3 can advertise a channel it adds while a client connects and then refuse
    # that client's subscription to it ("unknown channel", logged by the server only): look
    # first with a client that leaves, then subscribe with one that connects after the channel
    first = FoxgloveClient(url)
    first.until(lambda: SlipEstimate.TOPIC in first.topics(), what="the probe's topic advertised")
    first.close()
    client = FoxgloveClient(url)
    client.until(lambda: SlipEstimate.TOPIC in client.topics(), what="the probe's topic advertised")
    client.subscribe([SlipEstimate.TOPIC])
    # the bridge's hello (its subscription to every topic) reached the probe's publisher
    probe.until(lambda: talker.subscriber_count() >= 1, procs=[proc], what="the bridge subscribed")
    sent = estimate(7)
    probe.until(lambda: (talker.publish(sent), client.pump(0.05))[1] and client.messages, procs=[proc],
                what="a message through slip view")
    assert client.messages[0].payload["stick_ratio"] == sent.stick_ratio
    client.close()


def test_the_bridge_receives_a_topic_only_while_a_client_watches_it(graph, probe):
    from incipient_slip.graph.runtime import ANY_TOPIC, HELLO, ON_DEMAND
    from incipient_slip.messages import GripCommand

    estimates = probe.node.create_publisher(SlipEstimate)
    commands = probe.node.create_publisher(GripCommand)
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.foxglove_bridge", "port:=0"])
    url, lines = served_url(proc)
    # its hello follows every subscription it made before: none reached our publishers
    probe.until(lambda: probe.node._sub_counts.get(HELLO + b"foxglove_bridge"), procs=[proc],
                what="the bridge connected to the probe")
    assert (estimates.subscriber_count(), commands.subscriber_count()) == (0, 0)
    assert probe.nodes(["foxglove_bridge"])["foxglove_bridge"].subscribes == {ANY_TOPIC: ON_DEMAND}
    first = FoxgloveClient(url)       # see the 0.30.3 note in the slip view test below
    first.until(lambda: {SlipEstimate.TOPIC, GripCommand.TOPIC} <= set(first.topics()))
    first.close()
    client = FoxgloveClient(url)
    client.until(lambda: SlipEstimate.TOPIC in client.topics())
    client.subscribe([SlipEstimate.TOPIC])
    probe.until(lambda: estimates.subscriber_count() == 1, procs=[proc], what="the bridge subscribed")
    probe.until(lambda: (estimates.publish(estimate(3)), client.pump(0.05))[1] and client.messages,
                procs=[proc], what="an estimate through the bridge")
    assert commands.subscriber_count() == 0
    client.close()                    # the last client of the topic left: so does the bridge
    probe.until(lambda: estimates.subscriber_count() == 0, procs=[proc], what="the bridge unsubscribed")


def low_nice() -> int:
    """The nice of a bridge at priority "low" started from this process: 10 below ours (relative:
    `make test` may itself run under `nice`)."""
    return min(19, os.getpriority(os.PRIO_PROCESS, 0) + 10)


def own_autogroup() -> str:
    """The kernel prints a task's autogroup only when autogroups are on and the task is in the root
    CPU cgroup (a container's task reads an empty file): '' means the scheduler ignores them here."""
    try:
        with open("/proc/self/autogroup") as f:
            return f.read().strip()
    except OSError:
        return ""


@pytest.mark.skipif(not own_autogroup(), reason="no scheduler autogroups in effect here (a CPU cgroup, or off)")
@pytest.mark.parametrize("own_session,priority,group_nice", [(True, "low", 10), (True, "idle", 19),
                                                             (False, "low", None), (True, "normal", 0)])
def test_the_bridge_lowers_its_session_group_only_when_it_leads_it(own_session, priority, group_nice):
    """Linux weighs session groups before nice within them: a bridge alone in its session
    (setsid, as bench_loop.py starts it) must lower its group, and must leave a shared one."""
    code = ("from incipient_slip.nodes.foxglove_bridge import lower_priority; import os; "
            f"lower_priority({priority!r}); print(open('/proc/self/autogroup').read().split()[-1], "
            "os.getpriority(os.PRIO_PROCESS, 0))")
    before = open("/proc/self/autogroup").read().split()[-1]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         start_new_session=own_session, check=True).stdout.split()
    assert out[0] == str(group_nice if group_nice is not None else before)
    if priority != "idle":                  # idle is SCHED_IDLE, not a nice value
        assert int(out[1]) == (low_nice() if priority == "low" else os.getpriority(os.PRIO_PROCESS, 0))
    assert open("/proc/self/autogroup").read().split()[-1] == before


@pytest.mark.skipif(not os.path.exists("/proc/self/task"), reason="per-thread priorities are Linux's")
@pytest.mark.parametrize("priority", ["low", "idle"])
def test_the_bridge_lowers_threads_started_before_it_zeromqs_io_thread_included(priority):
    """The node's ZeroMQ context starts its I/O thread before the bridge lowers its priority:
    that thread must end below the graph's nodes too (Linux keeps nice and policy per thread)."""
    code = ("import os, zmq\n"
            "from incipient_slip.nodes.foxglove_bridge import lower_priority\n"
            "sock = zmq.Context.instance().socket(zmq.PUB); sock.bind('inproc://x')\n"
            "tids = [int(t) for t in os.listdir('/proc/self/task')]\n"
            "assert len(tids) > 1, tids\n"
            f"lower_priority({priority!r})\n"
            "print(sorted({(os.sched_getscheduler(t), os.getpriority(os.PRIO_PROCESS, t)) for t in tids}))\n"
            "sock.close(0)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    nice = os.getpriority(os.PRIO_PROCESS, 0)       # a test run under `nice` starts above 0
    expected = [(os.SCHED_IDLE, nice)] if priority == "idle" else [(os.SCHED_OTHER, low_nice())]
    assert out.stdout.strip() == str(expected), out.stderr


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_the_live_json_bytes_parse_to_the_export_json_of_every_message_type(name):
    """The channels' bytes (msgspec's encoder) parse to what json.dumps of the export JSON
    parses to: wall-clock stamps as digit strings, NaN as null, non-ASCII text."""
    msg_type = MESSAGE_TYPES[name]
    fields = msg_type.schema()["fields"]
    arrays = {f: np.zeros(spec["shape"], dtype=spec["array"]) for f, spec in fields.items() if "array" in spec}
    msg = msg_type(**arrays, stamp_ns=1_763_900_000_123_456_789, seq=2**64 - 1)
    overrides = {f: "grip ü €" for f, spec in fields.items()
                 if spec.get("type") == "str" and "choices" not in spec and "enum" not in spec}
    overrides.update({f: float("nan") for f, spec in fields.items() if spec.get("type") == "float" and spec.get("nan")})
    if overrides:
        msg = dataclasses.replace(msg, **overrides)
    obj = to_export_json(msg)
    assert json.loads(_json(obj)) == json.loads(json.dumps(obj, allow_nan=False))
    assert json.loads(_json(raw_audio_block(np.arange(44, dtype=np.int16), 10**18))) == \
        json.loads(json.dumps(raw_audio_block(np.arange(44, dtype=np.int16), 10**18)))


@pytest.mark.parametrize("subprotocol", ["foxglove.websocket.v1", "foxglove.sdk.v1"])
def test_a_client_of_either_subprotocol_name_connects_and_is_answered_with_its_own(view, subprotocol):
    """The official @foxglove/ws-protocol client offers only foxglove.websocket.v1, which
    foxglove-sdk alone answers with HTTP 400 (tests/graph/test_official_client.py runs it)."""
    view.offer(SlipEstimate.TOPIC, "SlipEstimate")
    client = client_of(view, subprotocol=subprotocol)
    assert client.ws.subprotocol == subprotocol
    client.until(lambda: SlipEstimate.TOPIC in client.topics())
    client.subscribe([SlipEstimate.TOPIC])
    client.until(lambda: view.forward(SlipEstimate.TOPIC, encode(estimate(0))), what="subscription active")
    client.until(lambda: client.messages, what="a message")
    assert client.messages[0].payload["seq"] == 0
    client.close()


def test_a_client_offering_no_foxglove_subprotocol_is_refused_and_one_sending_garbage_is_closed(view):
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect
    with pytest.raises(InvalidStatus, match="400"):
        connect(f"ws://127.0.0.1:{view.port}", subprotocols=["chat.v2"], proxy=None, open_timeout=10)
    import socket
    with socket.create_connection(("127.0.0.1", view.port), timeout=10) as sock:
        sock.sendall(b"x" * 70_000)            # no HTTP head: the front closes the connection
        try:
            assert sock.recv(100) == b""
        except ConnectionResetError:           # closed with our bytes unread: a reset
            pass
    client_of(view).close()                    # and still serves the next client
    assert view.front.refused == 1


def test_a_launched_bridge_advertises_the_launchs_topics_before_any_node_has_started(graph):
    """The launcher tells the bridge the launch's topics ($SLIP_TOPICS): a viewer sees and can
    subscribe to every one before the rig has started (they were advertised when a node
    announced them or when first heard, seconds into a lock-step run)."""
    topics = {"/slip/estimate": "SlipEstimate", "/robot/state": "RobotState", "/object/pose": "ObjectPose",
              "/replayed": "raw"}
    graph.env["SLIP_TOPICS"] = json.dumps(topics)
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.foxglove_bridge", "port:=0"])
    url, lines = served_url(proc)
    client = FoxgloveClient(url)
    client.until(lambda: {"/slip/estimate", "/robot/state", "/object/pose"} <= set(client.topics()),
                 what="the launch's typed topics advertised")
    assert "/replayed" not in client.topics()          # of no known type: when first heard
    assert {info.name for info in discovery.scan(graph.dir)} == {"foxglove_bridge"}
    client.close()


@pytest.fixture
def busy_port():
    """A port another program listens on."""
    import socket
    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        yield other.getsockname()[1]


def test_a_busy_or_invalid_viewer_port_is_refused_before_the_launch_starts(busy_port, capsys):
    """view_port:= taken: an OSError traceback in the bridge, and a launch whose nodes waited for
    it (Ctrl-C, then SIGKILL); view_port:=99999: an OverflowError traceback, and the same wait."""
    from incipient_slip.graph.launch import main
    for port, says in ((busy_port, f"cannot listen on 127.0.0.1:{busy_port} (Address already in use): "
                                   "another program (a viewer bridge?) has it; pick another port"),
                       (99999, "parameter port:=99999 is above its range [0, 65535]")):
        assert main(["stabilize.yaml", "view:=foxglove", f"view_port:={port}", "view_wait_s:=0", "steps:=5"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("launch: error: ") and "node 'foxglove_bridge'" in err
        assert says in err and "starting" not in err, err


def test_slip_view_on_a_busy_or_invalid_port_is_one_line_and_exit_2(graph, busy_port):
    """slip view --port 99999 was a traceback and exit 1; so was a port in use."""
    for port, says in ((busy_port, f"cannot listen on 127.0.0.1:{busy_port} (Address already in use)"),
                       (99999, "parameter port:=99999 is above its range [0, 65535]")):
        proc = graph.spawn(["python", "-m", "incipient_slip.cli", "view", "--port", str(port)])
        _, err = proc.communicate(timeout=60)
        lines = err.decode().strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and says in lines[0], lines


def test_the_front_drains_only_once_a_slow_client_took_everything_and_gives_up_on_a_stalled_one():
    """`drain` counted "no byte went to a client for 0.3 s" as "the queues went out"; a client
    that paused reading for longer (a loaded make test-load run: the test's own client) held the
    front's copy in a blocked send, which looked quiet, and the bridge closed with the run's last
    estimates still queued. A copy waiting for its client is not quiet; a client that takes
    nothing for the timeout is stalled."""
    import socket
    import threading
    import time

    from incipient_slip.graph.live_view_front import SubprotocolFront

    total = 32 * 1024 * 1024                 # more than every socket buffer on the way holds
    upstream = socket.create_server(("127.0.0.1", 0))
    held = []

    def serve():                             # the SDK's side: a handshake, then a burst
        conn, _ = upstream.accept()
        held.append(conn)
        head = b""
        while b"\r\n\r\n" not in head:
            head += conn.recv(4096)
        try:
            conn.sendall(b"HTTP/1.1 101 Switching Protocols\r\n\r\n" + b"x" * total)
        except OSError:                      # the stalled client's: cut at the end
            pass

    def client():
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 65536)
        sock.connect(("127.0.0.1", front.port))
        sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        reply = b""
        while b"\r\n\r\n" not in reply:
            reply += sock.recv(4096)
        return sock, len(reply) - reply.index(b"\r\n\r\n") - 4

    front = SubprotocolFront("127.0.0.1", 0, upstream.getsockname()[1])
    try:
        threading.Thread(target=serve, daemon=True).start()
        sock, got = client()
        time.sleep(1.0)                      # the client pauses: the front's send blocks
        read = {"n": got}

        def read_all():
            while read["n"] < total:
                chunk = sock.recv(1 << 20)
                if not chunk:
                    break
                read["n"] += len(chunk)
        reader = threading.Thread(target=read_all, daemon=True)
        reader.start()
        assert front.drain(0.3, 30.0)
        assert read["n"] == total            # it went quiet only once the client had it all
        reader.join(10)
        sock.close()
        # a client that never reads: the front gives up after the timeout
        threading.Thread(target=serve, daemon=True).start()
        stalled, _ = client()
        while not front.sending:             # the burst reached the front (a blocked send)
            time.sleep(0.01)
        start = time.monotonic()
        assert not front.drain(0.3, 1.0)
        assert time.monotonic() - start < 10
        stalled.close()
    finally:
        front.close()
        upstream.close()
        for conn in held:
            conn.close()
