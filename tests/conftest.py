"""Shared test helpers: the `slow` marker and a private node graph per test.

`graph` gives a test its own graph directory (SLIP_GRAPH_DIR, short enough for ipc socket
paths) and a `spawn()` that starts processes in it and kills whatever is left at teardown.
A test that uses it gets a hard timeout of GRAPH_TIMEOUT_S unless it sets its own.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

GRAPH_TIMEOUT_S = 60


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes more than a few seconds (deselect with -m 'not slow')")


def pytest_collection_modifyitems(items):
    for item in items:
        if "graph" in getattr(item, "fixturenames", ()) and item.get_closest_marker("timeout") is None:
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
