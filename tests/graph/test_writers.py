"""Commands and states are accepted only from the writer the launch declared (no spoofing)."""
from __future__ import annotations

import pytest

from incipient_slip import messages as M
import json

from incipient_slip.graph.launch.resolve import find_launch_file, load
from incipient_slip.graph.launch.topology import NodeTopics, Topology
from incipient_slip.graph.endpoints import Publisher
from incipient_slip.graph.runtime import WRITERS_ENV, Node

FORGED = {M.GripCommand: dict(normal_force_kpa=99.0, period=1, reason="forged"),
          M.PztState: dict(enabled=False)}
REAL = {M.GripCommand: lambda i: M.GripCommand(normal_force_kpa=3.0, period=i),
        M.PztState: lambda i: M.PztState(enabled=True)}


@pytest.mark.parametrize("msg_type", [M.GripCommand, M.PztState])
def test_a_forged_command_or_state_is_refused_and_counted(graph, probe, msg_type):
    writer_name = "grip_controller" if msg_type is M.GripCommand else "rig_sim"
    with Node("reader", writers={msg_type.TOPIC: [writer_name]}) as reader, \
            Node(writer_name) as writer, Node("forger") as forger:
        got = []
        reader.create_subscription(msg_type, got.append)
        real_pub, forged_pub = writer.create_publisher(msg_type), forger.create_publisher(msg_type)
        assert real_pub.wait_for_subscribers(1, 20)
        # the forger sends as soon as the reader subscribes to it, or once it was refused
        probe.until(lambda: forged_pub.subscriber_count() or reader.refused_writers, 20,
                    nodes=[reader, writer, forger], what="the reader connected to or refused the forger")
        forged_pub.publish(msg_type(**FORGED[msg_type]))
        for i in range(3):
            real_pub.publish(REAL[msg_type](i))
        forged_pub.publish(msg_type(**FORGED[msg_type]))
        # before this fix the forged messages arrive (in any order with the real ones)
        probe.until(lambda: len(got) >= 3 and (len(got) > 3 or reader.refused_writers), 20,
                    nodes=[reader, writer, forger], what="the real messages and the forger's fate")
        assert [m for m in got if m.normal_force_kpa == 99.0] == [] if msg_type is M.GripCommand else \
            [m for m in got if not m.enabled] == []
        assert len(got) == 3 and list(reader.refused_writers) == [("forger", forger._info.pid)]
        assert "whose writer in this launch is " + writer_name in reader.refused_writers[("forger", forger._info.pid)]
        assert forged_pub.subscriber_count() == 0


def test_a_topic_is_taken_only_from_its_writer_even_on_a_connection_accepted_for_another(graph, probe):
    """The omission case: rig_sim reads /pzt/command, which nothing in the launch writes, so it
    connects to a process that announces only that; before each message was checked against its
    connection, that process could then send /grip/command (99 kPa) and rig_sim applied it."""
    with Node("reader", writers={M.GripCommand.TOPIC: ["grip_controller"]}) as reader, \
            Node("grip_controller") as writer, Node("operator") as forger:
        grips, pzts = [], []
        reader.create_subscription(M.GripCommand, grips.append)
        reader.create_subscription(M.PztCommand, pzts.append)
        real = writer.create_publisher(M.GripCommand)
        announced = forger.create_publisher(M.PztCommand)
        unannounced = Publisher(forger, M.GripCommand, M.GripCommand.TOPIC)   # sends, never announces
        probe.until(lambda: real.subscriber_count() and announced.subscriber_count()
                    and unannounced.subscriber_count(), 20, nodes=[reader, writer, forger],
                    what="the reader connected to the writer and to the operator")
        unannounced.publish(M.GripCommand(**FORGED[M.GripCommand]))
        announced.publish(M.PztCommand(enabled=True))       # after the forged one, on the same pipe
        real.publish(REAL[M.GripCommand](0))
        probe.until(lambda: grips and pzts, 20, nodes=[reader, writer, forger],
                    what="the writer's command and the operator's pzt command")
        assert [m.normal_force_kpa for m in grips] == [3.0] and len(pzts) == 1
        assert reader.refused_messages == 1 and list(reader.refused_writers) == [("operator", forger._info.pid)]
        assert "/grip/command" in reader.refused_writers[("operator", forger._info.pid)]
        unannounced.publish(M.GripCommand(**FORGED[M.GripCommand]))    # counted again, logged once
        announced.publish(M.PztCommand(enabled=True))
        probe.until(lambda: len(pzts) == 2, 20, nodes=[reader, writer, forger], what="the second pzt command")
        assert reader.refused_messages == 2 and len(grips) == 1


def test_a_node_with_a_refused_counter_of_its_own_survives_a_refused_writer(graph, probe):
    """Device nodes count refused commands in `self.refused`; the runtime's own record of refused
    writers once had that name, so the first stray writer crashed ur5 and linear_actuator with a
    TypeError (seen when another launch shared the default graph)."""
    class Counting(Node):
        def __init__(self, **kw):
            super().__init__("reader", writers={M.GripCommand.TOPIC: ["grip_controller"]}, **kw)
            self.refused = 0

    with Counting() as reader, Node("forger") as forger:
        reader.create_subscription(M.GripCommand, lambda m: None)
        forger.create_publisher(M.GripCommand)
        probe.until(lambda: reader.refused_writers, 20, nodes=[reader, forger], what="the forger refused")
        reader.spin_once(0.01)
        assert reader.refused == 0 and list(reader.refused_writers) == [("forger", forger._info.pid)]


def test_the_launch_tells_each_node_the_writers_of_its_inputs():
    desc = load(find_launch_file("stabilize.yaml"))
    env = {n.name: n.env.get(WRITERS_ENV) for n in desc.nodes}
    rig, sup = json.loads(env["rig_sim"]), json.loads(env["supervisor"])
    assert rig == {"/grip/command": ["grip_controller"], "/run/event": ["supervisor"]}  # /pzt/command: no writer
    assert sup["/grip/command"] == ["grip_controller"] and sup["/pzt/state"] == ["rig_sim"]
    assert "/heartbeat" not in sup


def test_a_node_reading_every_topic_accepts_every_publisher():
    desc = load(find_launch_file("stabilize.yaml"))
    topo = Topology(desc.topology.nodes + [NodeTopics("recorder", {"*": "any"}, {})])
    assert topo.writers_of_node_inputs("recorder") == {}
