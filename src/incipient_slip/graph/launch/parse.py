"""Parse: a launch document (YAML) -> a tree of actions, each with its line numbers.

Nothing is substituted or decided here: `$(var x)` is still text and `if:` is not evaluated
(that is `resolve`). What this step refuses is the shape: not YAML, a key twice in one
mapping, no top-level `launch:` list, an action that is not a one-key mapping of a known kind,
a key the action does not know, a group without `actions`. Every error names file and line.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

__all__ = ["LaunchError", "Action", "Marked", "ACTION_KEYS", "parse_document", "declared_args"]


class LaunchError(Exception):
    """A launch file that cannot be resolved; the message names file, line and key."""


# the keys each action accepts
ACTION_KEYS = {
    "arg": {"name", "default", "description", "choices"},
    "node": {"exec", "pkg", "name", "param", "remap", "required", "respawn", "respawn_delay",
             "gate", "if", "unless", "env"},
    "group": {"actions", "children", "if", "unless"},
    "include": {"file", "arg", "if", "unless"},
}


class Marked(dict):
    """A mapping that remembers its own line and the line of each key (1-based)."""

    line: int = 0
    lines: dict


@dataclass
class Action:
    """One action of a launch document: its kind, raw keys (unsubstituted) and lines; a group
    holds its children."""

    kind: str
    line: int
    keys: Marked
    children: list["Action"] = field(default_factory=list)

    def key_line(self, key: str) -> int:
        """The line of `key`, or of the action when it is absent."""
        return self.keys.lines.get(key, self.line)


class _Loader(yaml.SafeLoader):
    pass


def _construct_mapping(loader: _Loader, node: yaml.MappingNode) -> Marked:
    loader.flatten_mapping(node)
    out = Marked()
    out.line, out.lines = node.start_mark.line + 1, {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in out:
            raise LaunchError(f"{loader.name}:{key_node.start_mark.line + 1}: key {key!r} "
                              f"appears twice in one mapping")
        out[key] = loader.construct_object(value_node, deep=True)
        out.lines[key] = key_node.start_mark.line + 1
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def parse_document(text: str, file: str | Path = "<string>") -> list[Action]:
    """The actions of a launch document, in order; LaunchError naming file:line otherwise."""
    loader = _Loader(text)
    loader.name = str(file)
    try:
        doc = loader.get_single_data()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f":{mark.line + 1}" if mark else ""
        raise LaunchError(f"{file}{line}: not valid YAML: {exc.problem or exc}") from None
    except yaml.YAMLError as exc:
        raise LaunchError(f"{file}: not valid YAML: {exc}") from None
    finally:
        loader.dispose()
    if not isinstance(doc, dict) or "launch" not in doc:
        raise LaunchError(f"{file}:1: expected a top-level mapping with a 'launch:' list of actions")
    extra = sorted(set(doc) - {"launch"})
    if extra:
        raise LaunchError(f"{file}:{doc.lines[extra[0]]}: key {extra[0]!r}: unknown top-level key "
                          f"(only 'launch' is allowed)")
    return _actions(doc["launch"], file, doc.lines["launch"], "launch")


def _actions(items: Any, file, line: int, key: str) -> list[Action]:
    if not isinstance(items, list):
        raise LaunchError(f"{file}:{line}: key {key!r}: expected a list of actions")
    return [_action(item, file, line) for item in items]


def _action(item: Any, file, line: int) -> Action:
    if not isinstance(item, Marked) or len(item) != 1:
        raise LaunchError(f"{file}:{getattr(item, 'line', line)}: each action is a one-key mapping "
                          f"({', '.join(ACTION_KEYS)}), got {item!r:.80}")
    (kind, body), = item.items()
    if kind not in ACTION_KEYS:
        raise LaunchError(f"{file}:{item.line}: key {kind!r}: unknown action; known: "
                          f"{', '.join(ACTION_KEYS)}")
    if not isinstance(body, Marked):
        raise LaunchError(f"{file}:{item.line}: key {kind!r}: expected a mapping of the action's keys")
    unknown = sorted(set(body) - ACTION_KEYS[kind])
    if unknown:
        raise LaunchError(f"{file}:{body.lines[unknown[0]]}: key {unknown[0]!r}: unknown key in "
                          f"{kind}; known: {', '.join(sorted(ACTION_KEYS[kind]))}")
    action = Action(kind, item.line, body)
    if kind == "group":
        key = "actions" if "actions" in body else "children"
        if key not in body:
            raise LaunchError(f"{file}:{body.line}: key 'actions': a group needs an 'actions' list")
        action.children = _actions(body[key], file, body.lines[key], key)
    return action


def declared_args(actions: list[Action]) -> list[str]:
    """The names of the args an action list declares (groups included, conditions ignored)."""
    names = []
    for action in actions:
        if action.kind == "arg" and "name" in action.keys:
            names.append(str(action.keys["name"]))
        names += declared_args(action.children)
    return names
