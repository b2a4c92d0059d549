"""Liveness that survives PID namespaces: what cannot be proven dead is never removed."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from incipient_slip import messages as M
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
    instance = probe.nodes(["live"])["live"].instance
    assert [n for n in files if n.startswith("live-")] == [f"live-{node.pid}.{instance}.node.json",
                                                            f"live-{node.pid}.{instance}.sock"]
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


TWIN = ("import sys; from incipient_slip import messages as M; from incipient_slip.graph.runtime import Node; "
        "n = Node('twin'); p = n.create_publisher(M.PztCommand); "
        "n.create_timer(0.05, lambda: p.publish(M.PztCommand(intensity_db=float(sys.argv[1])))); n.spin()")


def test_two_nodes_of_one_name_each_pid_1_of_its_own_pid_namespace_are_both_in_the_graph(graph, probe):
    """Same name, same pid number (1) in two PID namespaces: before instance ids in the file and
    socket names both wrote twin-1.node.json and bound twin-1.sock, so the graph saw one, and
    when that one exited the other vanished with it."""
    prefix = _unshare_prefix()
    if prefix is None:
        pytest.skip("unshare cannot make a PID namespace here")
    heard: set[float] = set()
    probe.node.create_subscription(M.PztCommand, lambda m: heard.add(m.intensity_db))
    twins = [graph.spawn([*prefix, "python", "-c", TWIN, str(db)]) for db in (-1.0, -2.0)]
    probe.until(lambda: heard >= {-1.0, -2.0}, 60, procs=twins, what="both twins heard")
    twin_files = lambda: [i for i in discovery.scan(graph.dir) if i.name == "twin"]   # noqa: E731
    assert sorted(i.pid for i in twin_files()) == [1, 1]
    endpoints = {i.endpoint for i in twin_files()}
    os.killpg(twins[0].pid, signal.SIGKILL)
    twins[0].wait()
    probe.until(lambda: len(twin_files()) == 1, 30, procs=twins[1:], what="the killed twin's files removed")
    # the probe reads what the killed twin sent before it died for a grace period after its
    # files went (DISCONNECT_GRACE_S); a loaded run read a -1.0 sent before the kill after the
    # clear below, and never saw {-2.0} alone. So: clear once that connection is cut
    killed = endpoints - {i.endpoint for i in twin_files()}
    probe.until(lambda: not killed & probe.node._connected, 30, procs=twins[1:],
                what="the probe's connection to the killed twin cut")
    heard.clear()
    probe.until(lambda: heard == {-2.0}, 30, procs=twins[1:], what="the other twin still heard")
    assert [i.pid for i in twin_files()] == [1] and os.path.exists(twin_files()[0].endpoint[6:])


def test_remove_pid_removes_a_killed_node_s_files_whatever_its_instance_id(graph):
    info = discovery.NodeInfo("n", 4242, discovery.ipc_endpoint(graph.dir, "n", 4242, "0a1b2c3d"),
                              pidns=discovery.namespace("pid"), instance="0a1b2c3d")
    discovery.announce(graph.dir, info)
    Path(info.endpoint[6:]).touch()
    (graph.dir / "n-4243.0a1b2c3d.sock").touch()
    (graph.dir / ".n-4242.99aa.node.json.tmp").touch()      # killed while announcing
    assert discovery.remove_pid(graph.dir, 4242) == 3
    assert sorted(os.listdir(graph.dir)) == ["n-4243.0a1b2c3d.sock"]


def test_remove_pid_keeps_a_live_node_of_the_same_pid_number_in_another_pid_namespace(graph):
    """A launch books its child's end by pid; a node in a container (another PID namespace) may
    have the same number. Before, remove_pid deleted that live node's announcement and socket."""
    import socket as sk
    foreign = discovery.NodeInfo("twin", 4242, discovery.ipc_endpoint(graph.dir, "twin", 4242, "0a1b2c3d"),
                                 pidns="pid:[1]", instance="0a1b2c3d")
    gone = discovery.NodeInfo("twin", 4242, discovery.ipc_endpoint(graph.dir, "twin", 4242, "0e0e0e0e"),
                              pidns="pid:[2]", instance="0e0e0e0e")
    for info in (foreign, gone):
        discovery.announce(graph.dir, info)
    with sk.socket(sk.AF_UNIX, sk.SOCK_STREAM) as listening:
        listening.bind(foreign.endpoint[6:])
        listening.listen()
        Path(gone.endpoint[6:]).touch()               # nothing listens there: proven gone
        assert discovery.remove_pid(graph.dir, 4242) == 2
        assert sorted(os.listdir(graph.dir)) == ["twin-4242.0a1b2c3d.node.json", "twin-4242.0a1b2c3d.sock"]
        assert discovery.remove_pid(graph.dir, 4242, pidns="pid:[1]") == 2     # named: it goes
    assert os.listdir(graph.dir) == []


def test_a_launch_booking_its_pid_1_child_spares_the_pid_1_node_of_another_namespace(graph, probe):
    """Under unshare a node is PID 1 of its namespace; our side's remove_pid(dir, 1) (what a
    launch calls when a child of that number ends) must leave it in the graph."""
    prefix = _unshare_prefix()
    if prefix is None:
        pytest.skip("unshare cannot make a PID namespace here")
    heard: set[float] = set()
    probe.node.create_subscription(M.PztCommand, lambda m: heard.add(m.intensity_db))
    twin = graph.spawn([*prefix, "python", "-c", TWIN, "-3.0"])
    probe.until(lambda: heard >= {-3.0}, 60, procs=[twin], what="the twin heard")
    assert discovery.remove_pid(graph.dir, 1) == 0
    assert [i.pid for i in discovery.scan(graph.dir) if i.name == "twin"] == [1]
    heard.clear()
    probe.until(lambda: heard == {-3.0}, 30, procs=[twin], what="the twin still heard")