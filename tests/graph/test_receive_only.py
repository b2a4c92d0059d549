"""Node.receive_only: an every-topic reader narrowed to some topics is sent only those (the
publisher counts it as a subscriber of those only), and can change the set while connected."""
from __future__ import annotations

import pytest

from incipient_slip.graph import discovery
from incipient_slip.graph.runtime import ANY_TOPIC, ON_DEMAND, Node
from incipient_slip.messages import GripCommand, SlipEstimate


def test_a_narrowed_every_topic_reader_is_sent_only_the_topics_it_names(graph, probe):
    estimates = probe.node.create_publisher(SlipEstimate)
    commands = probe.node.create_publisher(GripCommand)
    heard = []
    with Node("reader", graph_dir=graph.dir, heartbeat_s=0) as reader:
        reader.create_raw_subscription(lambda topic, body, ns: heard.append(topic))
        reader.receive_only({SlipEstimate.TOPIC})
        infos = probe.nodes(["reader"])
        assert infos["reader"].subscribes == {ANY_TOPIC: ON_DEMAND}
        # (it subscribed every topic for a moment, on connecting, before receive_only took over)
        probe.until(lambda: estimates.subscriber_count() == 1 and commands.subscriber_count() == 0,
                    nodes=[reader], what="the reader subscribed to the estimates only")
        probe.until(lambda: (estimates.publish(SlipEstimate()), commands.publish(GripCommand()))
                    and heard.count(SlipEstimate.TOPIC) >= 3, nodes=[reader], what="estimates heard")
        assert GripCommand.TOPIC not in heard
        reader.receive_only({GripCommand.TOPIC})            # another set, while connected
        probe.until(lambda: commands.subscriber_count() == 1 and estimates.subscriber_count() == 0,
                    nodes=[reader], what="the subscriptions swapped")
        heard.clear()
        probe.until(lambda: (estimates.publish(SlipEstimate()), commands.publish(GripCommand()))
                    and heard.count(GripCommand.TOPIC) >= 3, nodes=[reader], what="commands heard")
        assert SlipEstimate.TOPIC not in heard      # the SUB socket filters what was in flight too


def test_receive_only_needs_an_every_topic_subscription(graph):
    with Node("typed", graph_dir=graph.dir, heartbeat_s=0) as node:
        node.create_subscription(SlipEstimate, lambda msg: None)
        with pytest.raises(ValueError, match="every-topic raw subscription"):
            node.receive_only({SlipEstimate.TOPIC})
    assert not discovery.scan(graph.dir)
