"""The shipped Foxglove layout (docs/viewers/stabilize.foxglove-layout.json): what the generator
writes today, and every topic path it plots names a topic and field of the messages contract."""
from __future__ import annotations

import json
import re

import pytest

from incipient_slip.messages import DEFAULT_TOPICS
from incipient_slip.nodes.viewer_layout import LAYOUT_PATH, LIMITS_TOPIC


def paths(node) -> list[str]:
    """Every string under a key that holds a message path ("value", "path", "topic", "topicPath")."""
    if isinstance(node, dict):
        found = [v for k, v in node.items() if k in ("value", "path", "topic", "topicPath") and isinstance(v, str)]
        return found + [p for v in node.values() for p in paths(v)]
    if isinstance(node, list):
        return [p for v in node for p in paths(v)]
    return []


def test_the_shipped_layout_is_what_the_generator_writes():
    pytest.importorskip("foxglove", reason="the [view] extra (foxglove-sdk) is not installed")
    from incipient_slip.nodes.viewer_layout import layout_json
    assert LAYOUT_PATH.read_text() == layout_json(), \
        "regenerate: python -m incipient_slip.nodes.viewer_layout"


def test_every_plotted_path_is_a_topic_and_field_of_the_contract():
    layout = json.loads(LAYOUT_PATH.read_text())
    script = layout["userScripts"]["limits"]["sourceCode"]
    script_fields = set(re.search(r"type Limits = \{([^}]*)\}", script).group(1).replace(";", " ").split()) 
    script_fields = {f.rstrip(":") for f in script_fields if f.endswith(":")}
    found = paths(layout["content"])
    assert len(found) >= 9
    for path in found:
        topic, _, field = path.partition(".")
        name = re.match(r"[A-Za-z_]\w*", field).group(0) if field else None
        if topic == LIMITS_TOPIC:
            assert name in script_fields, path
        elif topic == "/biotac/pac/audio":
            assert name is None, path                # the bridge's foxglove.RawAudio channel
        else:
            assert topic in DEFAULT_TOPICS, path
            assert name is None or name in DEFAULT_TOPICS[topic].schema()["fields"], path
