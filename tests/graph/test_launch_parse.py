"""The parser in launch_ros's style: one document in, one tree out (nothing substituted yet)."""
from __future__ import annotations

import pytest

from incipient_slip.graph.launch.parse import LaunchError, declared_args, parse_document


def shape(actions):
    """A tree as plain data: (kind, line, {key: raw value}, children)."""
    return [(a.kind, a.line, {k: v for k, v in a.keys.items() if k not in ("actions", "children")},
             shape(a.children)) for a in actions]


def test_a_document_becomes_actions_with_their_lines_and_raw_values():
    doc = """\
launch:
  # which rig
  - arg: {name: rig, default: sim}
  - node:
      exec: rig_sim
      if: "$(var rig) == sim"
      param:
        - {name: seed, value: "$(var seed)"}
  - group:
      unless: "$(var rig) == sim"
      actions:
        - node: {exec: replay, pkg: graph}
        - include: {file: other.yaml}
"""
    assert shape(parse_document(doc, "f.yaml")) == [
        ("arg", 3, {"name": "rig", "default": "sim"}, []),
        ("node", 4, {"exec": "rig_sim", "if": "$(var rig) == sim",
                     "param": [{"name": "seed", "value": "$(var seed)"}]}, []),
        ("group", 9, {"unless": "$(var rig) == sim"}, [
            ("node", 12, {"exec": "replay", "pkg": "graph"}, []),
            ("include", 13, {"file": "other.yaml"}, [])]),
    ]


def test_key_lines_and_nested_item_lines_are_kept():
    (node,) = parse_document("launch:\n  - node:\n      exec: a\n      remap:\n"
                             "        - {from: /x, to: /y}\n", "f.yaml")
    assert node.key_line("exec") == 3 and node.key_line("remap") == 4
    assert node.keys["remap"][0].line == 5 and node.key_line("name") == node.line == 2


def test_declared_args_include_those_inside_groups_whatever_their_condition():
    actions = parse_document("launch:\n  - arg: {name: a, default: 1}\n  - group:\n"
                             "      if: false\n      actions: [{arg: {name: b, default: 2}}]\n")
    assert declared_args(actions) == ["a", "b"]


@pytest.mark.parametrize("doc,match", [
    ("launch:\n  - node: {exec: x, nmae: y}\n", r"f.yaml:2: key 'nmae': unknown key in node"),
    ("launch:\n  - nod: {exec: x}\n", r"f.yaml:2: key 'nod': unknown action"),
    ("launch:\n  - node: {exec: x\n  - arg: {}\n", r"f.yaml:3: not valid YAML"),
    ("nodes: []\n", r"f.yaml:1: expected a top-level mapping with a 'launch:'"),
    ("launch: {}\n", r"f.yaml:1: key 'launch': expected a list of actions"),
    ("launch: []\nextra: 1\n", r"f.yaml:2: key 'extra': unknown top-level key"),
    ("launch:\n  - {arg: {name: a}, node: {exec: x}}\n", r"f.yaml:2: each action is a one-key mapping"),
    ("launch:\n  - node: {exec: x, exec: y}\n", r"f.yaml:2: key 'exec' appears twice"),
    ("launch:\n  - group: {if: true}\n", r"f.yaml:2: key 'actions': a group needs"),
    ("launch:\n  - group:\n      actions:\n        - node: {bad: 1}\n", r"f.yaml:4: key 'bad'"),
    ("launch:\n  - node: [exec, x]\n", r"f.yaml:2: key 'node': expected a mapping"),
])
def test_bad_shapes_name_file_line_and_key(doc, match):
    with pytest.raises(LaunchError, match=match):
        parse_document(doc, "f.yaml")
