"""Liveness that survives PID namespaces: what cannot be proven dead is never removed."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from incipient_slip.graph import discovery

SCAN = ("import sys; from pathlib import Path; from incipient_slip.graph import discovery; "
        "print(sorted(n.name for n in discovery.scan(Path(sys.argv[1]))))")
NODE = "from incipient_slip.graph.runtime import Node; Node('live').spin()"


def _unshare_prefix() -> list[str] | None:
    """A command prefix that runs a process in a new PID namespace (as PID 1), or None."""
    if shutil.which("unshare") is None:
        return None
    for prefix in (["unshare", "--pid", "--fork", "--mount-proc"],
                   ["unshare", "--user", "--map-root-user", "--pid", "--fork", "--mount-proc"]):
        if subprocess.run([*prefix, "true"], capture_output=True).returncode == 0:
            return prefix
    return None


def scan_in_new_pid_namespace(prefix, graph) -> list[str]:
    done = subprocess.run([*prefix, sys.executable, "-c", SCAN, str(graph.dir)], env=graph.env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.replace("'", '"'))


def _settled_files(directory) -> list[str]:
    """The graph directory's files without an announcement being rewritten right now (a node
    rewrites its .node.json through a hidden .tmp; CI once caught one in flight)."""
    return sorted(p.name for p in directory.iterdir() if not p.name.startswith("."))


def test_a_scan_in_another_pid_namespace_keeps_a_live_node_and_removes_a_killed_one(graph, probe):
    prefix = _unshare_prefix()
    if prefix is None:
        pytest.skip("unshare cannot make a PID namespace here")
    node = graph.spawn(["python", "-c", NODE])
    probe.nodes(["live"], procs=[node])
    files = _settled_files(graph.dir)
    assert [n for n in files if n.startswith("live-")] == [f"live-{node.pid}.node.json", f"live-{node.pid}.sock"]
    # the outside check of issue 21: this returned [] and deleted the live node's files
    assert "live" in scan_in_new_pid_namespace(prefix, graph)
    assert _settled_files(graph.dir) == files
    os.killpg(node.pid, signal.SIGKILL)
    node.wait()
    # dead for sure: its ipc socket refuses connections, so even there it is removed
    assert "live" not in scan_in_new_pid_namespace(prefix, graph)
    assert not [n for n in os.listdir(graph.dir) if n.startswith("live-")]


def test_an_announcement_with_a_monotonic_started_ns_is_not_removed_and_a_removal_is_logged(graph):
    me = discovery.NodeInfo("handwritten", os.getpid(), "ipc:///nonexistent.sock",
                            started_ns=time.monotonic_ns(), pidns=discovery.namespace("pid"))
    discovery.announce(graph.dir, me)
    lines: list[str] = []
    assert [n.name for n in discovery.scan(graph.dir, log=lines.append)] == ["handwritten"]
    assert me.path.exists() and lines == []
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    discovery.announce(graph.dir, discovery.NodeInfo("gone", gone.pid, "ipc:///nonexistent.sock",
                                                     started_ns=time.time_ns(), pidns=discovery.namespace("pid")))
    assert [n.name for n in discovery.scan(graph.dir, log=lines.append)] == ["handwritten"]
    assert len(lines) == 1 and f"node gone (pid {gone.pid}" in lines[0] and "process is gone" in lines[0]


def test_a_socket_between_bind_and_listen_is_kept_and_an_old_dead_one_removed(graph):
    """Between bind() and listen() a node's socket refuses connections; a loaded make test-load
    run once caught a node there and its socket was removed under it. Young orphans are kept."""
    import socket as sk
    path = graph.dir / "node-4242.sock"
    with sk.socket(sk.AF_UNIX, sk.SOCK_STREAM) as s:
        s.bind(str(path))                        # bound, not listening: refuses connections
        discovery.scan(graph.dir)
        assert path.exists()
        old = time.time() - 60
        os.utime(path, (old, old))
        discovery.scan(graph.dir)
        assert not path.exists()
