"""`launch FILE --show-args` and `launch FILE --print --dot`: one launch file in, the text out."""
from __future__ import annotations

from incipient_slip.graph.launch import main

DOC = """\
launch:
  - arg: {name: rate, default: "100", description: "frames per second"}
  - arg: {name: quiet, default: "false"}
  - node: {exec: rig_sim, name: rig}
  - node: {exec: estimator, param: [{name: method, value: injection}]}
"""


def write(tmp_path):
    path = tmp_path / "two.yaml"
    path.write_text(DOC)
    return str(path)


def test_show_args_prints_each_arg_with_its_default_and_description(tmp_path, capsys):
    assert main([write(tmp_path), "--show-args"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split() for line in lines] == [["rate", ":=", "100", "#", "frames", "per", "second"],
                                                ["quiet", ":=", "false"]]


def test_show_args_shows_a_given_value_in_place_of_the_default(tmp_path, capsys):
    assert main([write(tmp_path), "rate:=250", "--show-args"]) == 0
    assert capsys.readouterr().out.splitlines()[0].split()[:3] == ["rate", ":=", "250"]


def test_print_dot_draws_writer_topic_reader_edges(tmp_path, capsys):
    assert main([write(tmp_path), "--print", "--dot"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("digraph launch {") and out.rstrip().endswith("}")
    assert '"rig" [shape=box];' in out and '"estimator" [shape=box];' in out
    assert '"rig" -> "/biotac/pac";' in out and '"/biotac/pac" -> "estimator";' in out
    assert '"estimator" -> "/slip/estimate";' in out
    assert '"/biotac/pac" [shape=ellipse, label="/biotac/pac\\nBiotacPac"];' in out


def test_dot_without_print_is_a_usage_error(tmp_path, capsys):
    assert main([write(tmp_path), "--dot"]) == 2
    assert "--dot goes with --print" in capsys.readouterr().err
