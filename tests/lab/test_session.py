"""Collection sessions: what happens to the series' launch when Ctrl-C comes at the worst moment."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from incipient_slip.lab import session as session_mod
from incipient_slip.lab.session import load_manifest, plan_session, run_session


def test_a_ctrl_c_inside_popen_stops_the_launch_it_started(tmp_path, monkeypatch):
    """Popen forks before it returns: a SIGINT then used to raise inside it, leaving the series'
    launch running with no handle (a rerun then shared its graph: 240 of 120 ticks recorded)."""
    started: list[subprocess.Popen] = []
    real_popen = subprocess.Popen

    def popen_then_ctrl_c(argv, **kwargs):
        proc = real_popen([sys.executable, "-c", "import time; time.sleep(60)"], **kwargs)
        started.append(proc)
        os.kill(os.getpid(), signal.SIGINT)          # arrives before Popen has returned
        for _ in range(1000):                        # let the handler run inside this frame
            pass
        return proc

    monkeypatch.setattr(session_mod.subprocess, "Popen", popen_then_ctrl_c)
    session = plan_session("sim", ["pla"], 1, seed=0, injection="on", steps=10)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)   # as in `slip collect` (a test
    try:                                                                  # worker may ignore SIGINT)
        with pytest.raises(KeyboardInterrupt):
            run_session(session, tmp_path, log=lambda *_: None)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert len(started) == 1
    try:
        assert started[0].wait(timeout=20) is not None       # stopped, not orphaned
    finally:
        if started[0].poll() is None:
            started[0].kill()
    assert [(e.index, e.status) for e in load_manifest(tmp_path).series] == [(0, "pending")]
