"""Shared test helpers: the `slow` marker, a private node graph per test, and a probe in it.

`graph` gives a test its own graph directory (SLIP_GRAPH_DIR, short enough for ipc socket
paths) and a `spawn()` that starts processes in it and kills whatever is left at teardown.
A test that uses it gets a hard timeout of GRAPH_TIMEOUT_S unless it sets its own.

`probe` is a node in the test process, in that graph: `probe.listen(Type)` records a topic,
`probe.ready_on(topics)` returns once a message has arrived on each (so the connection to each
writer is up and nothing it publishes later is missed), `probe.until(pred)` spins until a
condition holds, `probe.nodes(names)` until nodes are announced. Each wait has a hard timeout
and fails at once, with its stderr, when a process it watches exits. The only way tests wait.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, Iterable

import pytest

from waiting import spin_until

GRAPH_TIMEOUT_S = 300      # a hang guard that holds on a loaded machine (make test-load)


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes more than a few seconds (deselect with -m 'not slow')")
    if not hasattr(config, "workerinput"):          # once per session, before xdist starts its workers
        _compile_mechanics()


def _compile_mechanics() -> None:
    """Fill numba's on-disk cache of the simulator's compiled mechanics (sim/mechanics.py) once, so
    that no worker or node process compiles it (~4 s on a fresh checkout) inside a test's wait."""
    from incipient_slip.sim import Rig, load_scene
    Rig(load_scene("mechanics"), "pla", 0).run_mechanics([1.0], (0.5, 0.025, 0.05))


def pytest_collection_modifyitems(items):
    for item in items:
        if {"graph", "probe"} & set(getattr(item, "fixturenames", ())) and \
                item.get_closest_marker("timeout") is None:
            item.add_marker(pytest.mark.timeout(GRAPH_TIMEOUT_S))


class Graph:
    """A private graph directory, the environment that selects it, and processes started in it."""

    def __init__(self, directory: Path):
        self.dir = directory
        self.env = dict(os.environ, SLIP_GRAPH_DIR=str(directory), PYTHONUNBUFFERED="1")
        self.procs: list[subprocess.Popen] = []

    def spawn(self, argv: list[str], **kw) -> subprocess.Popen:
        """Starts argv (a list; 'python' means this interpreter) in the graph, own process group."""
        argv = [sys.executable if a == "python" else a for a in argv]
        kw.setdefault("stdout", subprocess.PIPE)
        kw.setdefault("stderr", subprocess.PIPE)
        proc = subprocess.Popen(argv, env=self.env, start_new_session=True, **kw)
        self.procs.append(proc)
        return proc

    def close(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass
                proc.wait()
            for stream in (proc.stdout, proc.stderr):
                if stream:
                    stream.close()


@pytest.fixture
def graph(monkeypatch):
    """A private graph (see Graph); SLIP_GRAPH_DIR is set for in-process nodes too."""
    directory = Path(tempfile.mkdtemp(prefix="sg", dir="/tmp"))
    monkeypatch.setenv("SLIP_GRAPH_DIR", str(directory))
    g = Graph(directory)
    try:
        yield g
    finally:
        g.close()
        shutil.rmtree(directory, ignore_errors=True)


class Probe:
    """A listening node in the test's graph and the waits built on it (see the module doc)."""

    def __init__(self, graph: Graph):
        from incipient_slip.graph.runtime import Node

        self.graph = graph
        self.node = Node("probe", graph_dir=graph.dir, heartbeat_s=0)
        self.received: dict[str, list] = {}

    def listen(self, msg_type, topic: str | None = None) -> list:
        """The list every `msg_type` message on `topic` (default its TOPIC) will be added to."""
        topic = topic or msg_type.TOPIC
        if topic not in self.received:
            self.received[topic] = []
            self.node.create_subscription(msg_type, self.received[topic].append, topic=topic)
        return self.received[topic]

    def ready_on(self, topics: Iterable, timeout_s: float = 20.0, procs=()) -> None:
        """Returns once a message has arrived on each topic (message types are listened to)."""
        names = []
        for t in topics:
            if isinstance(t, str):
                names.append(t)
            else:
                self.listen(t)
                names.append(t.TOPIC)
        self.until(lambda: all(self.received.get(t) for t in names), timeout_s, procs=procs,
                   what=f"a message on each of {', '.join(names)}")

    def nodes(self, names: Iterable[str], timeout_s: float = 20.0, procs=()) -> dict:
        """{name: NodeInfo} once every named node is announced in the graph."""
        from incipient_slip.graph import discovery

        found: dict = {}

        def announced():
            found.update({i.name: i for i in discovery.scan(self.graph.dir)})
            return set(names) <= set(found)
        self.until(announced, timeout_s, procs=procs, what=f"nodes {', '.join(names)} announced")
        return {n: found[n] for n in names}

    def until(self, predicate: Callable[[], bool], timeout_s: float = 30.0, *, procs=(),
              nodes=(), what: str = "") -> None:
        """Spins the probe (and `nodes`) until `predicate()`; fails on timeout or when one of
        `procs` exited and what it sent before does not make `predicate()` true (waiting.py)."""
        def spin():
            self.node.spin_once(0 if nodes else 0.01)   # one message (or timer) per call
            for node in nodes:
                node.spin_once(0.01 / len(nodes))
        spin_until(spin, predicate, timeout_s, procs, what)

    def close(self) -> None:
        self.node.close()


@pytest.fixture
def probe(graph):
    """A Probe in the test's private graph."""
    p = Probe(graph)
    try:
        yield p
    finally:
        p.close()


@pytest.fixture(scope="session")
def dask_client():
    """Return get(n): a dask Client on a LocalCluster of n single-threaded worker processes, started
    once per n for the session (start-up costs about a second) and closed at its end."""
    from contextlib import ExitStack

    from incipient_slip.cluster import open_client

    with ExitStack() as stack:
        clients: dict = {}

        def get(n: int):
            if n not in clients:
                clients[n] = stack.enter_context(open_client(workers=n))
                assert len(clients[n].scheduler_info()["workers"]) == n
            return clients[n]

        yield get
