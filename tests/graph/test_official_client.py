"""The live view with the official Foxglove WebSocket client, `@foxglove/ws-protocol` (0.8.0,
from npm) on Node, and its channels' schemas under Ajv (draft 2020-12, strict mode): the
client and validator a Foxglove user's own tools are built on (tests/graph/official_client.cjs).

The packages are installed once into a cache directory ($SLIP_NPM_CACHE, default
~/.cache/incipient-slip/npm); where Node or npm is absent or the registry cannot be reached the
tests are skipped with one line saying so.
"""
from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

pytest.importorskip("foxglove", reason="the [view] extra (foxglove-sdk) is not installed")

from incipient_slip.graph.bag_export import to_export_json  # noqa: E402
from incipient_slip.graph.live_view import LiveView  # noqa: E402
from incipient_slip.messages import MESSAGE_TYPES, SlipEstimate, encode  # noqa: E402
from waiting import spin_until  # noqa: E402
from timeline import assert_one_timeline  # noqa: E402

PACKAGES = ["@foxglove/ws-protocol@0.8.0", "ws@8.18.3", "ajv@8.17.1"]
SCRIPT = Path(__file__).with_name("official_client.cjs")

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="session")
def npm_dir() -> Path:
    """The directory whose node_modules holds PACKAGES (installed here the first time)."""
    if not (shutil.which("node") and shutil.which("npm")):
        pytest.skip("Node.js or npm is not installed: the official Foxglove client test is skipped")
    root = Path(os.environ.get("SLIP_NPM_CACHE", Path.home() / ".cache" / "incipient-slip" / "npm"))
    root.mkdir(parents=True, exist_ok=True)
    stamp = root / ("installed-" + "-".join(p.replace("/", "_") for p in PACKAGES))
    with open(root / ".lock", "w") as lock:        # two test workers: one installs
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not stamp.exists():
            done = subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--no-save",
                                   "--prefix", str(root), *PACKAGES],
                                  capture_output=True, text=True, timeout=300)
            if done.returncode != 0:
                pytest.skip(f"npm install {' '.join(PACKAGES)} failed (offline?): "
                            f"{done.stderr.strip().splitlines()[-1:]}")
            stamp.touch()
    return root


class OfficialClient:
    """official_client.cjs on Node, connected to `url`, subscribing to `topics`; its events
    are read from the JSON-lines file it writes."""

    def __init__(self, npm_dir: Path, url: str, topics: list[str], out: Path):
        self.out = out
        self.proc = subprocess.Popen(["node", str(SCRIPT), url, json.dumps(topics), str(out)],
                                     env=dict(os.environ, NODE_PATH=str(npm_dir / "node_modules")),
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    def events(self, kind: str | None = None) -> list[dict]:
        if not self.out.exists():
            return []
        lines = self.out.read_text().splitlines()
        if lines and not lines[-1].endswith("}"):      # a line being written
            lines = lines[:-1]
        found = [json.loads(line) for line in lines if line]
        return [e for e in found if kind is None or e["event"] == kind]

    def messages(self, topic: str) -> list[dict]:
        return [e for e in self.events("message") if e["topic"] == topic]

    def wait_exit(self, timeout_s: float = 60) -> str:
        """Waits for Node to end (it does when the server closes); its stderr."""
        _, err = self.proc.communicate(timeout=timeout_s)
        return err.decode(errors="replace")


def test_the_official_client_connects_and_every_schema_is_valid_under_ajv_strict(npm_dir, tmp_path):
    view = LiveView("127.0.0.1", 0)
    try:
        for name, msg_type in MESSAGE_TYPES.items():
            view.offer(msg_type.TOPIC, name)
        client = OfficialClient(npm_dir, f"ws://127.0.0.1:{view.port}", [SlipEstimate.TOPIC],
                                tmp_path / "events.jsonl")
        spin_until(lambda: client.proc.poll(), lambda: client.events("subscribed"), 60, [client.proc],
                   what="the official client subscribed")
        schemas = {e["topic"]: e for e in client.events("schema")}
        assert set(schemas) == {t.TOPIC for t in MESSAGE_TYPES.values()} | {"/biotac/pac/audio"}
        assert {t: e["error"] for t, e in schemas.items() if e["error"]} == {}
        sent = [SlipEstimate(stick_ratio=0.1 * i, valid=True, period=i, method="injection",
                             stamp_ns=500_000_000 * (i + 1), seq=i) for i in range(5)]
        spin_until(lambda: None, lambda: view.forward(SlipEstimate.TOPIC, encode(sent[0])), 30,
                   what="the subscription active")
        for msg in sent[1:]:
            view.forward(SlipEstimate.TOPIC, encode(msg))
        spin_until(lambda: client.proc.poll(), lambda: len(client.messages(SlipEstimate.TOPIC)) >= 5, 30,
                   [client.proc], what="five estimates")
    finally:
        view.drain()
        view.close()
    stderr = client.wait_exit()
    got = client.messages(SlipEstimate.TOPIC)
    assert [m["payload"] for m in got] == [json.loads(json.dumps(to_export_json(m))) for m in sent], stderr
    assert [int(m["logTime"]) for m in got] == [m.stamp_ns for m in sent]
    assert not [m["errors"] for m in got if m["errors"]]
    assert client.events("error") == [] and [e["code"] for e in client.events("close")] == [1005]   # a close frame (no status), never 1006


WATCHED = ("/slip/estimate", "/grip/command", "/robot/state", "/object/pose")


@pytest.mark.timeout(300)
def test_the_official_client_receives_every_message_of_a_lock_step_run_on_one_timeline(
        npm_dir, graph, probe, tmp_path):
    """`launch stabilize.yaml view:=foxglove` as a user types it (lock-step: the run waits for
    the viewer): every /slip/estimate, /grip/command, /robot/state and /object/pose message
    reaches the official client, equal to what the graph carried and logged at its stamp; and
    every topic of the run, heartbeats and events included, is on the run's simulated time."""
    from test_foxglove_bridge_launch import Launch
    from incipient_slip.messages import Heartbeat
    from incipient_slip.nodes.rig_sim import PERIOD_NS

    for msg_type in MESSAGE_TYPES.values():
        probe.listen(msg_type)
    launch = Launch(graph, tmp_path / "summary.json", "view:=foxglove", "view_port:=0")
    probe.until(lambda: launch.url() is not None, 60, procs=[launch.proc], what="the bridge's URL")
    # the probe hears the run from its first message: it connects to every node before the
    # bridge lets the run start (no node sends before the viewer subscribed)
    nodes = probe.nodes(["rig_sim", "estimator", "grip_controller", "supervisor"], procs=[launch.proc])
    probe.until(lambda: {n.endpoint for n in nodes.values()} <= probe.node._connected, 30,
                procs=[launch.proc], what="probe connected to every node")
    client = OfficialClient(npm_dir, launch.url(), list(WATCHED), tmp_path / "events.jsonl")
    probe.until(lambda: launch.proc.poll() is not None, 240, what="the run's end")
    assert launch.wait() in (0, 1), launch.log()
    stderr = client.wait_exit(60)             # the bridge closes the connection once drained
    while True:                               # what the probe has still to read
        before = sum(map(len, probe.received.values()))
        probe.node.spin_once(1.0)
        if sum(map(len, probe.received.values())) == before:
            break

    assert client.events("error") == [], stderr
    assert [e["code"] for e in client.events("close")] == [1005], stderr     # the server's close frame, not 1006
    assert {e["topic"]: e["error"] for e in client.events("schema") if e["error"]} == {}
    summary = json.loads((tmp_path / "summary.json").read_text())
    end_ns = (summary["steps"] + 2) * PERIOD_NS
    ratios = {}
    for topic in WATCHED:
        carried = {m.seq: m for m in probe.received[topic]}
        got = {}
        for e in client.messages(topic):
            assert e["errors"] is None, (topic, e["errors"])
            got.setdefault(e["payload"]["seq"], e)
        published = max([*carried, *got]) + 1
        ratios[topic] = f"{len(got)}/{published}"
        assert sorted(carried) == list(range(len(carried))), (topic, "the probe missed messages")
        assert sorted(got) == list(range(published)), (topic, ratios[topic], launch.log())
        for seq, msg in carried.items():
            assert got[seq]["payload"] == json.loads(json.dumps(to_export_json(msg))), (topic, seq)
            assert int(got[seq]["logTime"]) == msg.stamp_ns, (topic, seq)
        times = [int(e["logTime"]) for e in client.messages(topic)]
        assert times == sorted(times) and 0 < times[0] and times[-1] <= end_ns, (topic, times[:3], times[-3:])
    print(f"delivered/published to the official client: {ratios}")
    # one timeline: every topic the graph carried, per publisher, in order and within the run
    assert_one_timeline(probe.received, end_ns)
    assert {Heartbeat.TOPIC, "/run/event", "/grip/command", "/sim/truth"} <= {t for t, m in probe.received.items() if m}
