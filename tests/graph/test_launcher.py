"""The launcher: the parser fed documents (resolved tree checked), and real launches."""
from __future__ import annotations

import os
import signal
import sys
import textwrap
import time
from pathlib import Path

import pytest

from incipient_slip.graph import discovery
from incipient_slip.graph.launch import LaunchError, load_text, main

NODES = Path(__file__).parent / "nodes"
EXITER = NODES / "exiter.py"

RIGS = textwrap.dedent(f"""
    launch:
      # which rig feeds the graph
      - arg: {{name: rig, default: sim, description: "sim | replay | hardware"}}
      - arg: {{name: rate, default: "100"}}
      - group:
          if: "$(var rig) == sim"
          actions:
            - node: {{exec: {EXITER}, name: rig_sim, param: [{{name: after_s, value: "$(var rate)"}}]}}
      - node:
          exec: {EXITER}
          name: replay
          if: "$(eval '$(var rig)' == 'replay')"
          remap: [{{from: /biotac/pac, to: /replay/pac}}]
      - group:
          unless: "$(var rig) != hardware"
          actions:
            - node: {{exec: {EXITER}, name: biotac_reader, required: true}}
      - node:
          exec: {EXITER}
          name: estimator
          param: [{{name: code, value: 2}}, {{name: after_s, value: 0.5}}]
          respawn: "$(var rig) == hardware"
          respawn_delay: 2
""")


@pytest.mark.parametrize("rig,expected", [("sim", ["rig_sim", "estimator"]),
                                          ("replay", ["replay", "estimator"]),
                                          ("hardware", ["biotac_reader", "estimator"])])
def test_one_file_serves_every_rig(rig, expected):
    desc = load_text(RIGS, {"rig": rig}, "rigs.yaml")
    assert [n.name for n in desc.nodes] == expected
    assert desc.args == {"rig": rig, "rate": "100"}


def test_resolved_tree_has_typed_params_remaps_and_flags():
    desc = load_text(RIGS, {"rig": "replay"}, "rigs.yaml")
    replay, estimator = desc.nodes
    assert replay.remaps == {"/biotac/pac": "/replay/pac"}
    assert estimator.params == {"code": 2, "after_s": 0.5}
    assert (estimator.required, estimator.respawn) == (False, False)
    sim = load_text(RIGS, {"rate": "7.5"}, "rigs.yaml").nodes[0]
    assert sim.params == {"after_s": 7.5}
    hw = load_text(RIGS, {"rig": "hardware"}, "rigs.yaml").nodes
    assert (hw[0].required, hw[1].respawn, hw[1].respawn_delay) == (True, True, 2.0)
    assert hw[1].argv()[-3:] == ["__name:=estimator", "code:=2", "after_s:=0.5"]


def test_env_and_eval_substitutions(monkeypatch):
    monkeypatch.setenv("SLIP_TEST_X", "abc")
    desc = load_text(textwrap.dedent(f"""
        launch:
          - arg: {{name: n, default: "$(eval 2 * 3 + 1)"}}
          - node:
              exec: {EXITER}
              param:
                - {{name: a, value: "$(env SLIP_TEST_X)"}}
                - {{name: b, value: "$(env SLIP_TEST_UNSET 'fallback')"}}
                - {{name: c, value: "$(var n)"}}
                - {{name: d, value: "pre-$(var n)"}}
    """))
    assert desc.nodes[0].params == {"a": "abc", "b": "fallback", "c": 7, "d": "pre-7"}
    with pytest.raises(LaunchError, match="not allowed"):
        load_text('launch:\n  - arg: {name: n, default: "$(eval __import__(\'os\'))"}\n')


def test_include_passes_args(tmp_path):
    (tmp_path / "inner.yaml").write_text(textwrap.dedent(f"""
        launch:
          - arg: {{name: who}}
          - node: {{exec: {EXITER}, name: "inner_$(var who)"}}
    """))
    outer = tmp_path / "outer.yaml"
    outer.write_text('launch:\n  - include: {file: inner.yaml, arg: [{name: who, value: x}]}\n')
    assert [n.name for n in load_text(outer.read_text(), {}, outer).nodes] == ["inner_x"]


@pytest.mark.parametrize("doc,match", [
    ("launch:\n  - node: {exec: x, nmae: y}\n", r"f.yaml:2: key 'nmae': unknown key in node"),
    ("launch:\n  - node: {name: y}\n", r"f.yaml:2: key 'exec': required"),
    ("launch:\n  - nod: {exec: x}\n", r"f.yaml:2: key 'nod': unknown action"),
    ("launch:\n  - node: {exec: no_such_node}\n", r"f.yaml:2: key 'exec': no node module incipient_slip.nodes.no_such_node"),
    ("launch:\n  - arg: {name: a}\n", r"f.yaml:2: key 'default': arg 'a' has no default"),
    ("launch:\n  - node: {exec: x, if: \"$(var nope) == 1\"}\n", r"f.yaml:2: key 'if': \$\(var nope\): no such arg"),
    ("launch:\n  - node: {exec: x, if: maybe}\n", r"key 'if': condition 'maybe'"),
    ("launch:\n  - node: {exec: x\n  - arg: {}\n", r"f.yaml:3: not valid YAML"),
    ("nodes: []\n", r"f.yaml:1: expected a top-level mapping with a 'launch:'"),
    ("launch:\n  - arg: {name: a, default: 1}\n  - arg: {name: a, default: 2}\n", r"f.yaml:3: key 'name': arg 'a' is declared twice"),
])
def test_bad_documents_name_file_line_and_key(doc, match):
    with pytest.raises(LaunchError, match=match):
        load_text(doc, {}, "f.yaml")


def test_unknown_command_line_arg_lists_known_args():
    with pytest.raises(LaunchError) as info:
        load_text(RIGS, {"rgi": "sim"}, "rigs.yaml")
    assert "unknown launch argument rgi" in str(info.value)
    assert "rig" in str(info.value) and "rate" in str(info.value)


def test_print_shows_resolved_graph(tmp_path, capsys):
    path = tmp_path / "rigs.yaml"
    path.write_text(RIGS)
    assert main([str(path), "--print", "rig:=replay"]) == 0
    out = capsys.readouterr().out
    assert "name: replay" in out and "/biotac/pac: /replay/pac" in out and "rig: replay" in out
    assert main([str(path), "rig:=nope", "bogus:=1"]) == 2
    assert "unknown launch argument bogus" in capsys.readouterr().err


# --- real launches ----------------------------------------------------------------------------

def _launch(graph, doc: str, *args):
    path = graph.dir / "test.yaml"
    path.write_text(textwrap.dedent(doc))
    return graph.spawn(["python", "-m", "incipient_slip.graph.launch", str(path), *args])


def _wait_nodes(graph, names, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = {i.name: i for i in discovery.scan(graph.dir)}
        if set(names) <= set(found):
            return found
        time.sleep(0.02)
    raise AssertionError(f"nodes {names} did not all start")


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.parametrize("code", [0, 3])
def test_required_node_exit_ends_launch_with_its_code(graph, code):
    proc = _launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: bystander}}
          - node: {{exec: {EXITER}, name: supervisor, required: true,
                    param: [{{name: after_s, value: 0.3}}, {{name: code, value: {code}}}]}}
    """)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == code
    assert f"required node supervisor".encode() in err and f"exit code {code}".encode() in err
    assert discovery.scan(graph.dir) == []


def test_killing_required_node_fails_launch_naming_node_and_signal(graph):
    proc = _launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: estimator, required: true}}
          - node: {{exec: {EXITER}, name: other}}
    """)
    nodes = _wait_nodes(graph, ["estimator", "other"])
    os.kill(nodes["estimator"].pid, signal.SIGKILL)
    _, err = proc.communicate(timeout=15)
    assert proc.returncode == 128 + signal.SIGKILL
    assert b"required node estimator died with signal SIGKILL" in err
    assert not _alive(nodes["other"].pid)


def test_sigint_stops_every_node_within_seconds(graph):
    proc = _launch(graph, f"""
        launch:
          - node: {{exec: {NODES / 'listener.py'}}}
          - node: {{exec: {NODES / 'talker.py'}, param: [{{name: rate_hz, value: 200.0}}]}}
          - node: {{exec: {EXITER}}}
    """)
    nodes = _wait_nodes(graph, ["listener", "talker", "exiter"])
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=10)
    assert time.monotonic() - t0 < 4.0
    assert proc.returncode == 0, err
    assert not any(_alive(i.pid) for i in nodes.values())
    assert b"[listener]" in err or b"SIGINT" in err


def test_non_required_node_is_respawned(graph):
    proc = _launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: flaky, respawn: true, respawn_delay: 0.1,
                    param: [{{name: after_s, value: 0.2}}, {{name: code, value: 1}}]}}
          - node: {{exec: {EXITER}, name: end, required: true, param: [{{name: after_s, value: 1.5}}]}}
    """)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0
    assert err.count(b"respawning flaky") >= 2
