"""`slip topic`: bad graph names are one line and exit 2, before any socket exists."""
from __future__ import annotations

import pytest

from incipient_slip.graph import tools


@pytest.mark.parametrize("tool", [["list"], ["echo", "/slip/estimate"], ["hz", "/biotac/pac"]])
@pytest.mark.parametrize("how", ["option", "env"])
def test_a_bad_graph_name_is_one_line_and_exit_2(monkeypatch, capsys, tool, how):
    monkeypatch.delenv("SLIP_GRAPH_DIR", raising=False)
    argv = ["topic", *tool]
    if how == "env":
        monkeypatch.setenv("SLIP_GRAPH", "a+b")
    else:
        argv += ["--graph", "a+b"]
    assert tools.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"slip topic {tool[0]}: error: graph name 'a+b'" in err


@pytest.mark.timeout(120)
def test_echo_with_nothing_running_says_it_is_waiting_instead_of_hanging_silently(tmp_path):
    import os
    import subprocess
    import sys
    env = dict(os.environ, SLIP_GRAPH_DIR=str(tmp_path / "empty-graph"))
    proc = subprocess.Popen([sys.executable, "-m", "incipient_slip.cli", "topic", "echo", "/slip/estimate"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    # wait for the line itself (the test's timeout bounds it), not a fixed time: on a loaded
    # machine importing `slip` alone can take longer than NOTHING_YET_S
    seen = []
    try:
        for line in proc.stderr:
            seen.append(line)
            if "no message on" in line:
                break
    finally:
        proc.terminate()
        out, rest = proc.communicate(timeout=10)
    err = "".join(seen) + rest
    assert out == ""
    assert "no message on /slip/estimate yet in graph" in err and "empty-graph" in err
