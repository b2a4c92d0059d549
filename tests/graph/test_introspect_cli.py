"""`slip node list|info`, `slip topic info|pub` against a live graph: a probe node in this test
process, the command as a separate process (as a user runs it)."""
from __future__ import annotations

import json

import pytest

from incipient_slip.messages import GripCommand, SimTruth, SlipEstimate


def slip(graph, probe, *argv, spin: bool = False):
    """Runs `slip ARGV` in the graph; spins the probe meanwhile (so it can receive); returns
    (exit code, stdout, stderr)."""
    proc = graph.spawn(["python", "-m", "incipient_slip.cli", *argv])
    if spin:
        probe.until(lambda: proc.poll() is not None, 60, what=f"slip {' '.join(argv)} to end")
    out, err = proc.communicate(timeout=60)
    return proc.returncode, out.decode(), err.decode()


def test_node_list_and_info_show_the_running_nodes_and_their_topics(graph, probe):
    probe.node.create_publisher(GripCommand)
    probe.listen(SlipEstimate)
    code, out, err = slip(graph, probe, "node", "list", "--json")
    assert code == 0, err
    (node,) = [n for n in json.loads(out) if n["name"] == "probe"]
    assert node["publishes"] == {"/grip/command": "GripCommand"}
    assert node["subscribes"] == {"/slip/estimate": "SlipEstimate"}
    code, out, err = slip(graph, probe, "node", "info", "probe")
    assert code == 0, err
    assert "/grip/command: GripCommand" in out and "/slip/estimate: SlipEstimate" in out
    code, out, err = slip(graph, probe, "node", "info", "nobody")
    assert code == 2 and "no node 'nobody'" in err


def test_topic_info_names_the_writers_and_live_readers(graph, probe):
    probe.listen(SlipEstimate)
    code, out, err = slip(graph, probe, "topic", "info", "/slip/estimate", "--json")
    assert code == 0, err
    assert json.loads(out) == {"topic": "/slip/estimate", "type": "SlipEstimate", "writers": [],
                               "readers": ["probe"]}


def test_topic_pub_delivers_the_yaml_message_to_a_live_reader(graph, probe):
    got = probe.listen(SimTruth)
    code, out, err = slip(graph, probe, "topic", "pub", "/sim/truth",
                          "{period: 4, stick_ratio: 0.25, gross_slip: true}", spin=True)
    assert code == 0, err
    probe.until(lambda: got, what="the published SimTruth")
    assert (got[0].period, got[0].stick_ratio, got[0].gross_slip) == (4, 0.25, True)


def test_topic_pub_says_when_no_reader_takes_its_message_and_sends_nothing(graph, probe):
    """A launch's supervisor takes /sim/truth only from rig_sim: the README's example once
    printed 'publishing anyway' and exited 0 while nobody received the message."""
    from incipient_slip.graph.runtime import Node
    with Node("supervisor", graph_dir=graph.dir, heartbeat_s=0, writers={"/sim/truth": ["rig_sim"]}) as reader:
        got = []
        reader.create_subscription(SimTruth, got.append)
        proc = graph.spawn(["python", "-m", "incipient_slip.cli", "topic", "pub", "/sim/truth", "{period: 3}",
                            "--wait", "1"])
        probe.until(lambda: proc.poll() is not None, 60, nodes=[reader], what="slip topic pub to end")
        out, err = (b.decode() for b in proc.communicate(timeout=10))
        assert proc.returncode == 1, (out, err)
        assert "none of the readers of /sim/truth (supervisor) subscribed" in err and "writer" in err
        assert "published" not in out and not got
        assert [why for why in reader.refused_writers.values() if "/sim/truth" in why], reader.refused_writers


@pytest.mark.parametrize("message,words", [("{stick_ratio: 0.3, bogus: 1}", "no field bogus"),
                                           ("{period: -5}", "period"),
                                           ("[1, 2]", "YAML mapping")])
def test_topic_pub_refuses_what_the_contract_refuses_in_one_line(graph, probe, message, words):
    code, out, err = slip(graph, probe, "topic", "pub", "/sim/truth", message)
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err


def test_topic_pub_refuses_a_command_topic_without_force(graph, probe):
    got = probe.listen(GripCommand)
    code, out, err = slip(graph, probe, "topic", "pub", "/grip/command", "{normal_force_kpa: 3.0}")
    assert code == 2 and "command topic" in err and "--force" in err
    code, out, err = slip(graph, probe, "topic", "pub", "/grip/command", "{normal_force_kpa: 3.0}",
                          "--force", spin=True)
    assert code == 0, err
    probe.until(lambda: got, what="the forced GripCommand")
    assert got[0].normal_force_kpa == 3.0


def test_topic_pub_refuses_any_topic_on_a_graph_with_real_device_nodes(graph, probe):
    from incipient_slip.graph.runtime import Node
    with Node("ur5", graph_dir=graph.dir, heartbeat_s=0):          # a device node is running
        code, out, err = slip(graph, probe, "topic", "pub", "/sim/truth", "{period: 1}")
    assert code == 2 and "real device nodes (ur5)" in err, err


def test_topic_pub_prints_the_stamp_it_sends(graph, probe):
    got = probe.listen(SimTruth)
    code, out, err = slip(graph, probe, "topic", "pub", "/sim/truth", "{period: 4}", spin=True)
    assert code == 0, err
    probe.until(lambda: got, what="the published SimTruth")
    printed = json.loads(out.split(": ", 1)[1])
    assert printed["stamp_ns"] == got[0].stamp_ns > 0 and printed["seq"] == got[0].seq


def test_topic_pub_refuses_a_graph_with_a_recorder_without_force(graph, probe, tmp_path):
    """A message from the side would go into the run's recording as if the run had sent it."""
    got = probe.listen(SimTruth)
    proc = graph.spawn(["python", "-m", "incipient_slip.graph.recorder", f"path:={tmp_path / 'run.mcap'}"])
    probe.nodes(["recorder"], procs=[proc])
    code, out, err = slip(graph, probe, "topic", "pub", "/sim/truth", "{period: 1}")
    assert code == 2 and "recorder records every message" in err and "--force" in err, err
    code, out, err = slip(graph, probe, "topic", "pub", "/sim/truth", "{period: 1}", "--force", spin=True)
    assert code == 0, err
    probe.until(lambda: got, what="the forced SimTruth")


@pytest.fixture
def controller(graph, probe):
    """A grip_controller process with two parameters given on its command line, announced."""
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.grip_controller", "s_d:=0.45",
                        "method:=e19", "wait_subscribers:=0"])
    probe.nodes(["grip_controller"], procs=[proc])
    return proc


def test_param_dump_gives_every_parameter_of_a_running_node_as_resolved(graph, probe, controller):
    import yaml

    from incipient_slip.graph.params import declared_params
    from incipient_slip.nodes.grip_controller import GripController

    code, out, err = slip(graph, probe, "param", "dump", "grip_controller")
    assert code == 0, err
    assert out.startswith(f"# grip_controller (pid {controller.pid})")
    expected = {name: p.default for name, p in declared_params(GripController).items()}
    expected.update(s_d=0.45, method="e19", wait_subscribers=0)
    assert yaml.safe_load(out) == expected
    code, out, err = slip(graph, probe, "param", "dump", "grip_controller", "--json")
    assert code == 0, err
    assert json.loads(out) == {"name": "grip_controller", "pid": controller.pid, "params": expected}
    code, out, err = slip(graph, probe, "param", "list", "grip_controller")
    assert code == 0, err
    assert out.split() == sorted(expected)


def test_param_get_prints_one_value_as_a_command_line_would_give_it(graph, probe, controller):
    from incipient_slip.graph.params import parse_value

    for name, value in (("s_d", 0.45), ("method", "e19"), ("lockstep", False)):
        code, out, err = slip(graph, probe, "param", "get", "grip_controller", name)
        assert code == 0, err
        assert parse_value(out.strip()) == value, (name, out)
    code, out, err = slip(graph, probe, "param", "get", "grip_controller", "gain")
    assert code == 2 and "no parameter 'gain'" in err and "s_d" in err, err
    assert len(err.strip().splitlines()) == 1
    code, out, err = slip(graph, probe, "param", "get", "nobody", "s_d")
    assert code == 2 and "no node 'nobody'" in err


def test_params_are_read_only_from_the_tool(graph, probe, controller):
    code, out, err = slip(graph, probe, "param", "set", "grip_controller", "s_d", "0.9")
    assert code == 2 and "invalid choice: 'set'" in err, err


def test_topic_pub_does_not_wait_for_a_reader_on_demand_and_info_marks_it(graph, probe):
    from incipient_slip.graph.runtime import Node
    with Node("foxglove_bridge", graph_dir=graph.dir, heartbeat_s=0) as bridge:   # as the bridge reads
        bridge.create_raw_subscription(lambda topic, body, ns: None)
        bridge.receive_only(set())
        code, out, err = slip(graph, probe, "topic", "info", "/sim/truth", "--json")
        assert code == 0, err
        assert json.loads(out)["readers"] == ["foxglove_bridge (on demand)"]
        code, out, err = slip(graph, probe, "topic", "pub", "/sim/truth", "{period: 1}", "--wait", "20")
    assert code == 0, err
    assert "readers" not in out and out.startswith("published SimTruth"), out


def test_topic_pub_with_no_reader_in_the_graph_says_nothing_was_sent(graph, probe):
    """Before, with no graph running it printed 'published ...' and exited 0."""
    code, out, err = slip(graph, probe, "topic", "pub", "/slip/estimate", "{stick_ratio: 0.5}")
    assert code == 1 and "no node of the graph" in err and "nothing was sent" in err, (out, err)
    assert "published" not in out
