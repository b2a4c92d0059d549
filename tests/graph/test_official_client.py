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
    assert client.events("error") == [] and client.events("close")
