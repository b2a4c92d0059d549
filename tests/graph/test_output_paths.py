"""A run's output files (the recorder's MCAP, the supervisor's summary): their folder is created,
and a path that cannot be written is one line and exit 2 before any node starts; a summary that
cannot be written at the end still ends the run, its verdict printed, with a non-zero code."""
from __future__ import annotations

import shutil

import pytest

from incipient_slip import control
from incipient_slip.graph.launch import main
from incipient_slip.graph.recorder import Recorder
from incipient_slip.graph.runtime import run_node


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    return lines[0]


def test_a_recording_in_a_new_folder_gets_the_folder(graph, tmp_path):
    """out:=runs/newdir/x.mcap ended collect.yaml with exit 1 and a TypeError traceback; the
    summary:= of stabilize.yaml always created its folder, and so does the recorder now."""
    path = tmp_path / "new" / "dir" / "x.mcap"
    node = Recorder(params={"path": str(path)}, graph_dir=graph.dir, heartbeat_s=0)
    node.close()
    assert path.is_file() and path.stat().st_size > 0


def test_a_recorder_that_cannot_start_is_one_line_and_exit_2(graph, tmp_path, capsys):
    """Its constructor's error went through Node.close(run_hooks=False), which Recorder.close did
    not take: `TypeError: Recorder.close() got an unexpected keyword argument 'run_hooks'`, exit 1."""
    assert run_node(Recorder, [f"path:={tmp_path}"]) == 2
    line = one_line(capsys.readouterr().err)
    assert f'path:="{tmp_path}": cannot write the recording there (is a directory: {tmp_path})' in line
    assert "Traceback" not in line


@pytest.mark.timeout(120)     # before the fix the stabilize launch started and never ended
@pytest.mark.parametrize("file, arg, what", [("collect.yaml", "out", "recording"),
                                             ("stabilize.yaml", "summary", "summary")])
def test_an_output_path_that_cannot_be_written_is_refused_before_any_node_starts(capsys, tmp_path, file, arg, what):
    """summary:=/proc/nope/s.json: the supervisor's timer raised FileNotFoundError at the run's
    end, no verdict was printed and the launch never ended."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for path, why in (("/proc/nope/x", "No such file or directory: /proc/nope"),
                      (blocker / "x", f"a file, not a folder: {blocker}"),
                      (tmp_path, f"is a directory: {tmp_path}")):
        assert main([file, f"{arg}:={path}"]) == 2
        line = one_line(capsys.readouterr().err)
        assert line.startswith(f"launch: error: ") and f'{arg if arg == "summary" else "path"}' in line
        assert f"cannot write the {what} there ({why})" in line, line


def test_a_summary_that_cannot_be_written_at_the_end_is_named_and_exit_2(graph, tmp_path, capsys):
    """Checked at the start, the folder may go away by the end: the verdict is still printed and
    published, the node ends with exit 2 and a line that names the path (before: an exception in
    the timer, no verdict, a node that never ended)."""
    from incipient_slip.nodes.supervisor import Supervisor
    folder = tmp_path / "out"
    node = Supervisor(params={"summary_path": str(folder / "s.json"), "max_steps": 3},
                      graph_dir=graph.dir, heartbeat_s=0)
    try:
        shutil.rmtree(folder)
        folder.write_text("now a file")
        node.finish(control.Verdict("success", "held for 3 steps"))
        assert node.stopping and node.exit_code == 2
        assert node.stop_reason.startswith(f"the summary could not be written to {folder / 's.json'} (")
        assert node.stop_reason.endswith("the run's verdict: success")
        assert "stabilization run" in capsys.readouterr().out      # the verdict's screen
        assert node.verdict_sent
    finally:
        node.close()
