"""The resolver: documents + args in, nodes, checked params and the topic graph out."""
from __future__ import annotations

import json
import re
import textwrap
from pathlib import Path

import pytest
import yaml

from incipient_slip import paths
from incipient_slip.graph.launch import LaunchError, load, load_text, main, parse_document
from incipient_slip.graph.runtime import READERS_ENV

NODES = Path(__file__).parent / "nodes"
EXITER, RELAY, TALKER, LISTENER = (NODES / f"{n}.py" for n in ("exiter", "relay", "talker", "listener"))

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
              exec: {RELAY}
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
    ("launch:\n  - node: {name: y}\n", r"f.yaml:2: key 'exec': required"),
    ("launch:\n  - node: {exec: no_such_node}\n", r"f.yaml:2: key 'exec': no node module incipient_slip.nodes.no_such_node"),
    ("launch:\n  - node: {exec: x, pkg: ros}\n", r"f.yaml:2: key 'pkg': unknown package 'ros'"),
    ("launch:\n  - arg: {name: a}\n", r"f.yaml:2: key 'default': arg 'a' has no default"),
    ("launch:\n  - node: {exec: x, if: \"$(var nope) == 1\"}\n", r"f.yaml:2: key 'if': \$\(var nope\): no such arg"),
    ("launch:\n  - node: {exec: x, if: maybe}\n", r"key 'if': condition 'maybe'"),
    ("launch:\n  - arg: {name: a, default: 1}\n  - arg: {name: a, default: 2}\n", r"f.yaml:3: key 'name': arg 'a' is declared twice"),
    (f"launch:\n  - node: {{exec: {EXITER}}}\n  - node: {{exec: {EXITER}}}\n", r"f.yaml:3: node name 'exiter' is already used"),
])
def test_bad_documents_name_file_line_and_key(doc, match):
    with pytest.raises(LaunchError, match=match):
        load_text(doc, {}, "f.yaml")


def test_unknown_command_line_arg_lists_known_args():
    with pytest.raises(LaunchError) as info:
        load_text(RIGS, {"rgi": "sim"}, "rigs.yaml")
    assert "unknown launch argument rgi" in str(info.value)
    assert "rig" in str(info.value) and "rate" in str(info.value)


# --- params checked against the node's declarations, before anything starts -------------------

ONE = textwrap.dedent(f"""\
    launch:
      - arg: {{name: code, default: "0"}}
      - arg: {{name: after_s, default: "1.0"}}
      - node:
          exec: {EXITER}
          name: supervisor
          param: [{{name: code, value: "$(var code)"}}, {{name: after_s, value: "$(var after_s)"}}]
""")


@pytest.mark.parametrize("arg,value,why", [
    ("code", "300", "code:=300 is above its range [0, 255]"),
    ("code", "-1", "code:=-1 is below its range [0, 255]"),
    ("after_s", ".inf", "after_s:=.inf is not a finite number"),
    ("after_s", ".nan", "after_s:=.nan is not a finite number"),
    ("after_s", "-5", "after_s:=-5.0 must be >= 0.0"),
    ("code", "lots", "parameter 'code' = 'lots' (str) does not fit its default 0 (int)")])
def test_a_launch_arg_outside_the_nodes_declared_range_is_refused_naming_it(arg, value, why):
    with pytest.raises(LaunchError) as info:
        load_text(ONE, {arg: value}, "one.yaml")
    assert str(info.value) == f"one.yaml:7: node 'supervisor': {'parameter ' if ':=' in why else ''}{why}"


def test_an_unknown_param_is_refused_listing_the_known():
    with pytest.raises(LaunchError, match=r"no parameter 'cdoe'; known: after_s, code"):
        load_text(f"launch:\n  - node: {{exec: {EXITER}, param: [{{name: cdoe, value: 1}}]}}\n")


# --- the topic graph -------------------------------------------------------------------------

GRAPH = textwrap.dedent(f"""
    launch:
      - node: {{pkg: graph, exec: recorder, param: [{{name: path, value: /tmp/never.mcap}}]}}
      - node: {{exec: {TALKER}}}
      - node: {{exec: {RELAY}, remap: [{{from: /slip/estimate, to: /slip/estimate_e19}}]}}
      - node: {{exec: {LISTENER}}}
""")


def test_topics_list_writers_and_readers_after_remaps():
    desc = load_text(GRAPH, {}, "g.yaml")
    topics = {row["topic"]: row for row in desc.topology.to_plain()}
    assert set(topics) == {"/biotac/pac", "/slip/estimate_e19"}
    assert topics["/biotac/pac"] == {"topic": "/biotac/pac", "type": "BiotacPac", "writers": ["talker"],
                                     "readers": ["relay", "listener", "recorder"]}
    assert topics["/slip/estimate_e19"]["writers"] == ["relay"]
    assert topics["/slip/estimate_e19"]["readers"] == ["recorder"]
    assert desc.warnings == []


def test_each_node_is_told_the_named_readers_of_its_outputs():
    nodes = {n.name: n for n in load_text(GRAPH, {}, "g.yaml").nodes}
    assert json.loads(nodes["talker"].env[READERS_ENV]) == {"/biotac/pac": ["relay", "listener", "recorder"]}
    assert json.loads(nodes["relay"].env[READERS_ENV]) == {"/slip/estimate_e19": ["recorder"]}
    assert READERS_ENV not in nodes["listener"].env and READERS_ENV not in nodes["recorder"].env


def test_a_reader_without_a_writer_is_a_warning_and_replay_writes_every_topic():
    desc = load_text(f"launch:\n  - node: {{exec: {LISTENER}}}\n", {}, "g.yaml")
    assert desc.warnings == ["topic /biotac/pac is read by listener but no node of this launch writes it"]
    desc = load_text(f"launch:\n  - node: {{exec: {LISTENER}}}\n"
                     f"  - node: {{pkg: graph, exec: replay, param: [{{name: path, value: x.mcap}}]}}\n")
    assert desc.warnings == []
    replay = next(n for n in desc.nodes if n.name == "replay")
    assert json.loads(replay.env[READERS_ENV]) == {"/biotac/pac": ["listener"]}
    # a replay feeding a recorder: both "*", still the recorder is replay's reader
    desc = load_text("launch:\n  - node: {pkg: graph, exec: recorder}\n"
                     "  - node: {pkg: graph, exec: replay, param: [{name: path, value: x.mcap}]}\n")
    replay = next(n for n in desc.nodes if n.name == "replay")
    assert json.loads(replay.env[READERS_ENV]) == {"*": ["recorder"]}


def test_print_shows_nodes_topics_and_handshakes(tmp_path, capsys):
    path = tmp_path / "g.yaml"
    path.write_text(GRAPH)
    assert main([str(path), "--print"]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["topics"]["/biotac/pac"] == {"type": "BiotacPac", "writers": ["talker"],
                                                "readers": ["relay", "listener", "recorder"]}
    talker = next(n for n in printed["nodes"] if n["name"] == "talker")
    assert talker["waits_for"] == ["listener", "recorder", "relay"] and "env" not in talker


def test_print_and_bad_args_exit_2_with_one_line(tmp_path, capsys):
    path = tmp_path / "rigs.yaml"
    path.write_text(RIGS)
    assert main([str(path), "--print", "rig:=replay"]) == 0
    out = capsys.readouterr().out
    assert "name: replay" in out and "/biotac/pac: /replay/pac" in out and "rig: replay" in out
    assert main([str(path), "rig:=nope", "bogus:=1"]) == 2
    assert "unknown launch argument bogus" in capsys.readouterr().err


@pytest.mark.parametrize("how", ["option", "env"])
def test_a_bad_graph_name_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch, how):
    path = tmp_path / "one.yaml"
    path.write_text(ONE)
    monkeypatch.delenv("SLIP_GRAPH_DIR", raising=False)
    if how == "env":
        monkeypatch.setenv("SLIP_GRAPH", "a+b")
    assert main([str(path), *(["--graph", "a+b"] if how == "option" else [])]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "graph name 'a+b'" in err


def test_two_types_on_one_topic_is_a_warning():
    desc = load_text(f"launch:\n  - node: {{exec: {LISTENER}}}\n"
                     f"  - node: {{exec: {RELAY}, remap: [{{from: /slip/estimate, to: /biotac/pac}}]}}\n")
    assert desc.warnings == ["topic /biotac/pac is declared with 2 types: BiotacPac (listener reads, "
                             "relay reads); SlipEstimate (relay writes)"]


# --- hostile substitutions -------------------------------------------------------------------

from hypothesis import given, settings, strategies as st  # noqa: E402


@pytest.mark.parametrize("expr,why", [("-" * 998 + "1", "nested too deeply"),
                                      ("[1] * 999999999", "repeating"),
                                      ("999999999 * 'x'", "repeating"),
                                      ("__import__('os')", "not allowed"),
                                      ("(1).real", "not allowed"),
                                      ("1 / 0", "division by zero")])
def test_a_hostile_eval_is_a_launch_error_naming_it(expr, why):
    with pytest.raises(LaunchError, match=why):
        load_text('launch:\n  - arg: {name: n, default: "$(eval ' + expr + ')"}\n', {}, "f.yaml")


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet="$()'\" +-*/%<>=!,.[]{}:abcdefnotrulsvi019_\\", max_size=60))
def test_any_substitution_text_resolves_or_is_a_launch_error(text):
    doc = "launch:\n  - arg: {name: v, default: x}\n  - arg: {name: n, default: " + \
        '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"}\n'
    try:
        load_text(doc, {}, "f.yaml")
    except LaunchError as exc:
        assert str(exc).startswith("f.yaml")


def test_an_optional_input_without_a_writer_is_no_warning_and_the_stabilize_launch_has_none():
    from incipient_slip.graph.launch.topology import NodeTopics, Topology
    from incipient_slip.nodes.rig_sim import RigSim
    alone = Topology([NodeTopics.of("rig_sim", RigSim, {})])
    assert not any("/pzt/command" in w for w in alone.warnings())
    # the collection protocol reads no grip command: collect.yaml (no controller) warned on every run
    assert not any("/grip/command" in w for w in alone.warnings())
    from incipient_slip.nodes.grip_controller import GripController
    controller = Topology([NodeTopics.of("grip_controller", GripController, {})])
    assert any("/slip/estimate" in w for w in controller.warnings())     # a required input still warns
    remapped = Topology([NodeTopics.of("rig_sim", RigSim, {"/pzt/command": "/pzt/other"})])
    assert not any("/pzt/other" in w for w in remapped.warnings())
    for name in ("stabilize.yaml", "collect.yaml"):
        launch_file = Path(__file__).resolve().parents[2] / "launch" / name
        assert load_text(launch_file.read_text(), {}, str(launch_file)).warnings == [], name


def test_a_node_without_a_name_is_named_after_its_module_or_script():
    # two tools named by their dotted module paths were both "graph" (the package), and collided
    desc = load_text(textwrap.dedent(f"""
        launch:
          - node: {{exec: incipient_slip.graph.recorder}}
          - node: {{exec: incipient_slip.graph.monitor}}
          - node: {{pkg: graph, exec: replay}}
          - node: {{exec: {TALKER}}}
    """), {}, "names.yaml")
    assert [n.name for n in desc.nodes] == ["recorder", "monitor", "replay", "talker"]


def test_two_nodes_with_one_name_are_refused_naming_both_lines():
    text = textwrap.dedent("""
        launch:
          - node: {exec: incipient_slip.graph.recorder}
          - node: {exec: incipient_slip.graph.monitor, name: recorder}
    """)
    with pytest.raises(LaunchError, match=r"names.yaml:4: node name 'recorder' is already used at names.yaml:3"):
        load_text(text, {}, "names.yaml")


def test_a_bad_params_overlay_is_refused_before_any_node_starts_naming_the_file(tmp_path, capsys):
    """rig_sim read the overlay only once started, so a bad one was found after the graph was up."""
    from incipient_slip.graph.launch.resolve import check_node_inputs, load
    bad, missing = tmp_path / "overlay.yaml", tmp_path / "missing.yaml"
    bad.write_text("not: [yaml")
    for path, why in ((bad, "not valid YAML"), (missing, "params overlay not found")):
        with pytest.raises(LaunchError, match=rf"stabilize.yaml:\d+: node 'rig_sim': parameter 'params': .*{why}"):
            check_node_inputs(load("stabilize.yaml", {"params": str(path)}))
        assert main(["stabilize.yaml", f"params:={path}"]) == 2
        err = capsys.readouterr().err
        assert str(path) in err and "starting" not in err


def test_a_bad_transport_is_refused_before_any_node_starts(monkeypatch, capsys):
    monkeypatch.setenv("SLIP_TRANSPORT", "udp")
    assert main(["stabilize.yaml"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("launch: error: $SLIP_TRANSPORT='udp'") and "starting" not in err


def test_a_missing_or_wrong_model_is_refused_before_any_node_starts_naming_the_file(tmp_path, capsys):
    """The estimator loaded its model only once started: the rig and the controller were up first."""
    from incipient_slip.graph.launch.resolve import check_node_inputs, load
    from incipient_slip.paths import model_dir
    missing = tmp_path / "missing.npz"
    with pytest.raises(LaunchError, match=rf"stabilize.yaml:\d+: node 'estimator': .*missing.npz"):
        check_node_inputs(load("stabilize.yaml", {"model": str(missing)}))
    assert main(["stabilize.yaml", f"model:={missing}"]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "starting" not in err
    e19 = model_dir() / "e19.npz"                     # a model of another method
    with pytest.raises(LaunchError, match=r"node 'estimator': .*e19"):
        check_node_inputs(load("stabilize.yaml", {"model": str(e19)}))


# --- args with a fixed set of values (choices:) ----------------------------------------------

@pytest.mark.parametrize("file, arg, value, listing", [
    ("stabilize.yaml", "rig", "simulated", "sim, replay, emulated, hardware"),
    ("stabilize.yaml", "view", "foxgloves", "none, foxglove"),
    ("stabilize.yaml", "method", "e20", "injection, vibrotactile, e19, e10, e4, e1, none"),
    ("stabilize.yaml", "lockstep", "ture", "true, false"),
    ("collect.yaml", "rig", "replay", "sim, emulated, hardware"),
    ("collect.yaml", "injection", "yes", "true, false"),
    ("identify.yaml", "rig", "simulated", "sim, emulated, hardware"),
])
def test_a_value_outside_an_args_choices_is_refused_before_anything_starts(capsys, file, arg, value, listing):
    """rig:=simulated matched no `if:` (six "no node writes" warnings, then a launch that waited
    for ever) and view:=foxgloves ran without a viewer: both were accepted."""
    assert main([file, f"{arg}:={value}", "--print"]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [err.strip()] and "starting" not in err
    assert re.search(rf"launch: error: .*{file}:\d+: launch arg {arg}:=\"{value}\" is not one of "
                     rf"{re.escape(listing)}$", err.strip()), err


def test_an_empty_choice_says_what_it_means():
    """label:=psuedo listed its choices as 'is not one of , pseudo, ...' (an empty first one)."""
    with pytest.raises(LaunchError) as info:
        load("stabilize.yaml", {"label": "psuedo"})
    text = str(info.value)
    assert 'label:="psuedo" is not one of "", measured-ratio, pseudo, true-ratio (label: ' in text
    assert '"" = measured-ratio, or the label model:= was trained on' in text and "of , " not in text


def test_the_launch_files_choices_are_the_nodes_choices():
    """The choices of method:= and label:= are the estimator's and the controller's values."""
    from incipient_slip.messages import METHODS
    from incipient_slip.models.labels import LABELS
    choices = {}
    for action in parse_document(Path(paths.launch_dir() / "stabilize.yaml").read_text()):
        if action.kind == "arg" and "choices" in action.keys:
            choices[action.keys["name"]] = action.keys["choices"]
    assert choices["method"] == list(METHODS)
    assert sorted(choices["label"]) == sorted(("",) + LABELS)


@pytest.mark.parametrize("choices", ["sim", "[]", "[[a], b]"])
def test_choices_that_are_not_a_list_of_values_are_a_file_error(choices):
    with pytest.raises(LaunchError, match=r"f.yaml:2: key 'choices': arg 'rig': expected a list of values"):
        load_text(f"launch:\n  - arg: {{name: rig, default: sim, choices: {choices}}}\n", {}, "f.yaml")


def test_a_default_outside_the_choices_is_refused_too():
    with pytest.raises(LaunchError, match=r'f.yaml:2: launch arg rig:="sim" is not one of replay'):
        load_text("launch:\n  - arg: {name: rig, default: sim, choices: [replay]}\n", {}, "f.yaml")


@pytest.mark.parametrize("file, rig, node", [("stabilize.yaml", "sim", "rig_sim"),
                                             ("stabilize.yaml", "emulated", "emulated_rig"),
                                             ("collect.yaml", "emulated", "emulated_rig"),
                                             ("identify.yaml", "sim", "rig_sim")])
def test_an_unknown_material_is_refused_before_any_node_starts(capsys, file, rig, node):
    """material:=wood was found by rig_sim once the graph was up: the supervisor printed its
    nan-filled summary of an interrupted run before the one line that named the material."""
    from incipient_slip.graph.launch.resolve import check_node_inputs
    with pytest.raises(LaunchError, match=rf"{file if rig == 'sim' else 'rig_emulated.yaml'}:\d+: "
                       rf"node '{node}': parameter material:=\"wood\": material 'wood' is not in scene"):
        check_node_inputs(load(file, {"rig": rig, "material": "wood"}))
    assert main([file, f"rig:={rig}", "material:=wood"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "'wood'" in err and "starting" not in err, err
