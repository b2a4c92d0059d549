"""stabilize.yaml and collect.yaml as the launcher resolves them (one document in, one tree out)."""
from __future__ import annotations

import json

import pytest

from incipient_slip.graph.launch import find_launch_file, load
from incipient_slip.graph.launch import main as launch_main
from incipient_slip.graph.runtime import READERS_ENV


def nodes(desc):
    return {n.name: n for n in desc.nodes}


def test_stabilize_defaults_are_one_simulated_lockstep_injection_run():
    desc = load(find_launch_file("stabilize.yaml"))
    got = nodes(desc)
    assert set(got) == {"rig_sim", "estimator", "grip_controller", "supervisor"}
    assert (got["rig_sim"].params["scene"], got["rig_sim"].params["method"]) == ("", "injection")   # scene paper
    assert got["rig_sim"].params["lockstep"] is True
    assert got["grip_controller"].params == {"method": "injection", "s_d": 0.3, "k": 2.0, "lockstep": True,
                                             "estimate_timeout_s": 0.4, "wait_timeout_s": 300.0}
    # no subscriber counts: each publisher waits for the readers the topology names
    readers = json.loads(got["rig_sim"].env[READERS_ENV])
    assert readers["/biotac/pac"] == ["estimator"]
    # the estimator and the supervisor declare the tick: on device clocks they read it (period_origin)
    assert sorted(readers["/actuator/state"]) == ["estimator", "grip_controller", "supervisor"]
    assert sorted(json.loads(got["grip_controller"].env[READERS_ENV])["/grip/command"]) == ["rig_sim", "supervisor"]
    # every node the method needs ends the launch if it dies or refuses its input
    assert all(node.required for node in got.values())
    assert got["supervisor"].params["end_on_failure"] is True


@pytest.mark.parametrize("method,scene", [("vibrotactile", "no_injection"), ("e19", "electrodes_only"),
                                          ("e1", "electrodes_only"), ("none", "mechanics")])
def test_scene_follows_the_method(method, scene):
    """The simulated rigs get the method and choose its scene from the one table (scene:="")."""
    from incipient_slip.control import scene_of
    got = nodes(load(find_launch_file("stabilize.yaml"), {"method": method}))
    params = got["rig_sim"].params
    assert (params["scene"], params["method"]) == ("", method) and scene_of("", method) == scene
    emulated = nodes(load(find_launch_file("stabilize.yaml"), {"method": method, "rig": "emulated"}))
    assert (emulated["emulated_rig"].params["scene"], emulated["emulated_rig"].params["method"]) == ("", method)
    assert ("estimator" in got) == (method != "none")
    named = nodes(load(find_launch_file("stabilize.yaml"), {"method": method, "scene": "paper"}))
    assert named["rig_sim"].params["scene"] == "paper"


def test_no_action_runs_all_steps():
    got = nodes(load(find_launch_file("stabilize.yaml"), {"method": "none"}))
    assert got["supervisor"].params["end_on_failure"] is False


def test_replay_rig_swaps_the_simulator_for_replay():
    got = nodes(load(find_launch_file("stabilize.yaml"), {"rig": "replay", "recording": "x.mcap"}))
    assert "rig_sim" not in got and got["replay"].params["path"] == "x.mcap"
    # a recording's stamps may be a device rig's wall clock: its own ticks place the periods
    # (tests/bags/test_replay_wall_clock.py replays one)
    assert got["estimator"].params["period_origin"] == got["supervisor"].params["period_origin"] == "tick"


@pytest.mark.parametrize("method", ["injection", "e19", "none"])
def test_replay_skips_every_topic_the_launch_writes_itself(method):
    """A recording of a whole run also holds the old run's estimates, grip commands and events;
    replayed, they reached the live controller and supervisor (seq gaps, dropped commands)."""
    desc = load(find_launch_file("stabilize.yaml"), {"rig": "replay", "recording": "x.mcap", "method": method})
    own = {t for n in desc.topology.nodes if n.name != "replay" for t in (n.outputs or {}) if t != "*"}
    assert {"/slip/estimate", "/grip/command", "/run/event", "/heartbeat"} & own
    assert own <= set(nodes(desc)["replay"].params["skip_topics"])


def test_hardware_rig_checks_the_devices_then_runs_every_device_node():
    """(The launch itself, with no device attached: tests/devices/test_rig_hardware.py.)"""
    got = nodes(load(find_launch_file("stabilize.yaml"), {"rig": "hardware", "rig_config": "lab.yaml",
                                                          "biotac_port": "/dev/ttyX"}))
    motion = ["mocap_bridge", "linear_actuator", "ur5"]
    assert set(motion) | {"rig_check", "biotac_reader", "pzt_injector"} <= set(got) and "rig_sim" not in got
    for name in motion:
        assert got[name].required and got[name].params["rig_config"] == "lab.yaml"
    # the check is a gate: the device nodes start once it exited 0 (docs/graph.md)
    assert got["rig_check"].gate and got["rig_check"].params["rig_config"] == "lab.yaml"
    assert list(got).index("rig_check") < min(list(got).index(name) for name in motion)
    assert got["rig_check"].params["biotac_port"] == got["biotac_reader"].params["port"] == "/dev/ttyX"


def test_collect_records_the_collection_protocol():
    got = nodes(load(find_launch_file("collect.yaml"), {"injection": "false", "seed": "3"}))
    assert got["rig_sim"].params["protocol"] == "collection" and got["rig_sim"].required
    assert got["rig_sim"].params["method"] == "vibrotactile" and got["rig_sim"].params["seed"] == 3   # scene no_injection
    # the recording is the launch's output: a recorder that dies ends it (exit 128+N), never a
    # collection that reports success without its data (a new user SIGKILLed it: exit 0 before)
    assert got["recorder"].required


@pytest.mark.parametrize("arg,node,name", [("s_d:=2", "grip_controller", "s_d"),
                                           ("k:=-1", "grip_controller", "k"),
                                           ("k:=.inf", "grip_controller", "k"),
                                           ("steps:=-5", "rig_sim", "steps")])
def test_an_out_of_range_launch_arg_is_one_line_and_exit_2_before_anything_starts(arg, node, name, capsys):
    """Used to be a traceback and exit 1 (s_d, k) or a "SUCCESS" (steps:=-5). The check runs
    when the file is resolved, the same for `--print` as for a launch."""
    assert launch_main(["stabilize.yaml", arg, "--print"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"node '{node}': parameter {name}:=" in err


@pytest.mark.timeout(300)          # 28 resolutions; each imports node modules (slow on a loaded host)
def test_the_shipped_launch_files_resolve_to_the_recorded_graphs():
    """Every rig and method of stabilize.yaml and collect.yaml gives the graph recorded in
    tests/data/launch_graphs.json (nodes in start order, params, commands, topics, handshakes;
    not where in which file a node is written): a refactoring of the files keeps the graphs."""
    import importlib.util
    from pathlib import Path
    data = Path(__file__).resolve().parents[1] / "data"
    spec = importlib.util.spec_from_file_location("make_launch_graphs", data / "make_launch_graphs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    recorded = json.loads((data / "launch_graphs.json").read_text())
    got = json.loads(json.dumps(module.graphs()))          # the JSON types, as recorded
    assert sorted(got) == sorted(recorded)
    for case in recorded:
        assert got[case] == recorded[case], f"{case}: the graph changed (see make_launch_graphs.py)"


def test_the_summary_records_which_model_overlay_and_recording_a_run_used():
    got = nodes(load(find_launch_file("stabilize.yaml"), {"model": "runs/models/e19.npz", "method": "e19",
                                                          "params": "runs/identify/identify_overlay.yaml"}))
    sup = got["supervisor"].params
    assert (sup["model"], sup["rig_params"], sup["recording"]) == ("runs/models/e19.npz",
                                                                   "runs/identify/identify_overlay.yaml", "")
    from incipient_slip.nodes.supervisor import RECORDED
    assert {"model", "rig_params", "recording"} <= set(RECORDED)
