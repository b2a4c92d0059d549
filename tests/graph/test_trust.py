"""Trust: graph directories and announcements of other users are refused, as ssh refuses keys."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from incipient_slip.graph import discovery
from incipient_slip.graph.runtime import Node

OTHER_UID = 65534      # nobody


def _node_exit(env: dict) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "incipient_slip.nodes.supervisor", "summary_path:="],
                          env=env, capture_output=True, text=True, timeout=60)


def test_a_graph_directory_writable_by_others_is_refused_with_one_line(tmp_path):
    shared = tmp_path / "g"
    shared.mkdir()
    shared.chmod(0o777)
    with pytest.raises(discovery.GraphDirError, match=r"writable by group and others .*chmod go-w"):
        Node("a", graph_dir=shared)
    assert not list(shared.iterdir())          # nothing announced, no socket bound
    done = _node_exit(dict(os.environ, SLIP_GRAPH_DIR=str(shared)))
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "refusing to use it" in done.stderr


def test_a_default_base_directory_created_by_someone_else_is_refused(tmp_path, monkeypatch):
    monkeypatch.delenv("SLIP_GRAPH_DIR", raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    base = tmp_path / "incipient-slip"
    base.mkdir(mode=0o777)
    base.chmod(0o777)         # what another user's `mkdir -m 777` leaves
    with pytest.raises(discovery.GraphDirError, match="incipient-slip is writable"):
        discovery.graph_dir("g")
    base.chmod(0o700)
    assert discovery.graph_dir("g") == base / "g"


@pytest.mark.skipif(os.getuid() != 0, reason="needs root to make a directory another user owns")
def test_a_graph_directory_owned_by_another_user_is_refused(tmp_path):
    theirs = tmp_path / "theirs"
    theirs.mkdir(mode=0o700)
    os.chown(theirs, OTHER_UID, OTHER_UID)
    with pytest.raises(discovery.GraphDirError, match=f"owned by uid {OTHER_UID}"):
        discovery.check_graph_dir(theirs)


def test_an_announcement_others_may_write_is_not_trusted(graph):
    with Node("real") as real:
        forged = graph.dir / "forger-1.node.json"
        forged.write_text(json.dumps({"name": "forger", "pid": os.getpid(), "endpoint": "ipc:///tmp/x.sock",
                                      "publishes": {"/grip/command": "GripCommand"},
                                      "pidns": discovery.namespace("pid")}))
        forged.chmod(0o666)
        refused: dict = {}
        names = {n.name for n in discovery.scan(graph.dir, refused=refused)}
        assert names == {"real"} and "writable by group and others" in refused[forged.name]
        forged.chmod(0o600)
        assert {n.name for n in discovery.scan(graph.dir)} == {"real", "forger"}
        if os.getuid() == 0:
            os.chown(forged, OTHER_UID, OTHER_UID)
            assert {n.name for n in discovery.scan(graph.dir)} == {"real"}
