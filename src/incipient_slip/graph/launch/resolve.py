"""Resolve: a parsed launch document + argument values -> the nodes to start.

Args take the command line's value, else their default; `if:`/`unless:` drop actions; groups
are flattened; includes are resolved with the args they pass; each node becomes a `NodeSpec`
(command line, typed params, remaps, flags). Then, before anything starts, each node's params
are checked against its class's `PARAMS` declarations (an out-of-range value is a LaunchError
naming the parameter) and the topology is drawn from the nodes' `INPUTS`/`OUTPUTS`, which tells
each node the readers it waits for (`$SLIP_READERS`).
"""
from __future__ import annotations

import importlib.util
import json
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from incipient_slip import paths
from incipient_slip.graph.launch.parse import Action, LaunchError, Marked, declared_args, parse_document
from incipient_slip.graph.launch.substitute import Scope
from incipient_slip.graph.launch.topology import TOPICS_ENV, NodeTopics, Topology, node_class
from incipient_slip.graph.params import ParamError, check_params, declared_params, format_value, merge_params, one_of
from incipient_slip.graph.runtime import ANY_TOPIC, READERS_ENV, WRITERS_ENV

__all__ = ["NodeSpec", "LaunchDescription", "find_launch_file", "load", "load_text", "NODE_PACKAGES"]

# `pkg:` of a node action -> the package its `exec:` names a module of
NODE_PACKAGES = {"incipient_slip": "incipient_slip.nodes", "graph": "incipient_slip.graph"}


@dataclass
class NodeSpec:
    """One node to start, after substitution."""

    name: str
    exec: str
    command: list[str]
    params: dict[str, Any] = field(default_factory=dict)
    remaps: dict[str, str] = field(default_factory=dict)
    required: bool = False
    respawn: bool = False
    gate: bool = False        # the nodes after it start only once it exited 0
    respawn_delay: float = 1.0
    env: dict[str, str] = field(default_factory=dict)
    source: str = ""
    target: str = ""          # the module name or .py path its class is imported from
    param_sources: dict[str, str] = field(default_factory=dict)   # name -> file:line

    def argv(self) -> list[str]:
        """The node's command line: params as `name:=<json>`, remaps as `/from:=/to`."""
        return (self.command + [f"__name:={self.name}"]
                + [f"{k}:={format_value(v)}" for k, v in self.params.items()]
                + [f"{k}:={v}" for k, v in self.remaps.items()])


@dataclass
class LaunchDescription:
    """A resolved launch file: argument values, the nodes to start in order, and the topics."""

    file: str
    args: dict[str, Any] = field(default_factory=dict)
    arg_descriptions: dict[str, str] = field(default_factory=dict)
    nodes: list[NodeSpec] = field(default_factory=list)
    topology: Topology | None = None
    warnings: list[str] = field(default_factory=list)

    def to_plain(self) -> dict:
        """A YAML-friendly dict (what `launch FILE --print` shows)."""
        nodes = []
        for n in self.nodes:
            env = {k: v for k, v in n.env.items() if k not in (READERS_ENV, WRITERS_ENV, TOPICS_ENV)}
            readers = json.loads(n.env.get(READERS_ENV, "{}"))
            nodes.append({
                "name": n.name, "exec": n.exec, "command": " ".join(n.argv()), "params": n.params,
                "remaps": n.remaps, "required": n.required, "respawn": n.respawn,
                **({"respawn_delay": n.respawn_delay} if n.respawn else {}),
                **({"gate": True} if n.gate else {}),
                **({"env": env} if env else {}),
                "waits_for": sorted({r for names in readers.values() for r in names}),
                "source": n.source})
        topics = {row.pop("topic"): row for row in (self.topology.to_plain() if self.topology else [])}
        return {"file": self.file, "args": dict(self.args), "topics": topics, "nodes": nodes,
                **({"warnings": self.warnings} if self.warnings else {})}


def find_launch_file(name: str) -> Path:
    """The launch file `name`: a path, or a file in launch/ (".yaml" may be left out)."""
    path = Path(name)
    candidates = [path, paths.launch_dir() / name, paths.launch_dir() / f"{name}.yaml"]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    known = sorted(p.name for p in paths.launch_dir().glob("*.yaml")) if paths.launch_dir().is_dir() else []
    raise LaunchError(f"{name}: no such launch file (looked at {path} and in {paths.launch_dir()}; "
                      f"known: {', '.join(known) or '(none)'})")


def load(path: str | Path, cli_args: dict[str, str] | None = None) -> LaunchDescription:
    """The resolved launch description of a launch file (path or name in launch/)."""
    file = find_launch_file(str(path))
    return load_text(file.read_text(), cli_args, file)


def load_text(text: str, cli_args: dict[str, str] | None = None,
              file: str | Path = "<string>") -> LaunchDescription:
    """The resolved launch description of a launch document (the resolver's test entry point)."""
    file = Path(file)
    desc = LaunchDescription(str(file))
    scope = Scope(file, cli_args or {})
    actions = parse_document(text, file)
    known = declared_args(actions)
    unknown = sorted(set(scope.given) - set(known))
    if unknown:
        listing = "\n".join(f"  {n}" for n in known) or "  (none)"
        raise LaunchError(f"{file}: unknown launch argument{'s' if len(unknown) > 1 else ''} "
                          f"{', '.join(unknown)}; this file declares:\n{listing}")
    _resolve_actions(actions, scope, desc)
    desc.args = dict(scope.vars)
    desc.arg_descriptions = dict(scope.descriptions)
    seen: dict[str, str] = {}
    for node in desc.nodes:
        if node.name in seen:
            raise LaunchError(f"{node.source}: node name {node.name!r} is already used at "
                              f"{seen[node.name]}; give one of them another `name`")
        seen[node.name] = node.source
    _check_and_connect(desc)
    return desc


def _check_and_connect(desc: LaunchDescription) -> None:
    """Checks each node's params against its declarations and draws the topology."""
    topics = []
    for spec in desc.nodes:
        klass = node_class(spec.target)
        if klass is not None:
            declared = declared_params(klass)
            for name, value in spec.params.items():   # one at a time, to point at its line
                try:
                    check_params(spec.name, declared, {name: value})
                except ParamError as exc:
                    raise LaunchError(f"{spec.param_sources.get(name, spec.source)}: {exc}") from None
        topics.append(NodeTopics.of(spec.name, klass, spec.remaps))
    desc.topology = Topology(topics)
    desc.warnings = desc.topology.warnings()
    for spec in desc.nodes:
        readers = desc.topology.readers_of_node(spec.name)
        if readers:
            spec.env[READERS_ENV] = json.dumps(readers, separators=(",", ":"))
        writers = desc.topology.writers_of_node_inputs(spec.name)
        if writers:
            spec.env[WRITERS_ENV] = json.dumps(writers, separators=(",", ":"))
        if ANY_TOPIC in (desc.topology.node(spec.name).inputs or {}):
            spec.env[TOPICS_ENV] = json.dumps(desc.topology.typed_topics(), separators=(",", ":"))


def check_node_inputs(desc: LaunchDescription) -> None:
    """Checks what each node's params name outside the launch file (`Node.check_inputs`: a params
    overlay...), as the launcher does before it starts any node; LaunchError naming the node's
    line, the parameter and the file. Not part of `load`: `--print` and tests resolve launches
    whose files exist only where they run."""
    for spec in desc.nodes:
        klass = node_class(spec.target)
        if klass is None:
            continue
        try:
            klass.check_inputs(merge_params(spec.name, declared_params(klass), spec.params), spec.name)
        except ParamError as exc:
            raise LaunchError(f"{spec.source}: {exc}") from None


def _resolve_actions(actions: list[Action], scope: Scope, desc: LaunchDescription) -> None:
    for action in actions:
        body = action.keys
        if "if" in body and not scope.condition(body["if"], body.lines["if"], "if"):
            continue
        if "unless" in body and scope.condition(body["unless"], body.lines["unless"], "unless"):
            continue
        if action.kind == "arg":
            _resolve_arg(body, scope)
        elif action.kind == "node":
            desc.nodes.append(_resolve_node(body, scope))
        elif action.kind == "group":
            _resolve_actions(action.children, scope, desc)
        else:
            _resolve_include(body, scope, desc)


def _need(body: Marked, key: str, scope: Scope, kind: str):
    if key not in body:
        raise scope.error(body.line, key, f"required in {kind}")
    return body[key]


def _resolve_arg(body: Marked, scope: Scope) -> None:
    name = scope.text(_need(body, "name", scope, "arg"), body.lines["name"], "name")
    if name in scope.vars:
        raise scope.error(body.lines["name"], "name", f"arg {name!r} is declared twice")
    if name in scope.given:
        value = scope.given[name]
    elif "default" in body:
        value = scope.substitute(body["default"], body.lines["default"], "default")
    else:
        raise scope.error(body.line, "default",
                          f"arg {name!r} has no default; give it on the command line: {name}:=VALUE")
    description = str(body.get("description", ""))
    if "choices" in body:
        _check_choice(name, value, body, scope, description)
    scope.vars[name] = value
    scope.descriptions[name] = description


def _check_choice(name: str, value: Any, body: Marked, scope: Scope, description: str) -> None:
    """An arg with `choices:` (a list of texts) takes one of them, given or by default: a value
    outside them is a LaunchError naming the arg, the value and the choices (a misspelt
    `rig:=` or `view:=` would otherwise drop every node its `if:` names, or the viewer, silently).
    An empty choice means what the arg's description says; the message repeats it."""
    line = body.lines["choices"]
    choices = body["choices"]
    if not isinstance(choices, list) or not choices or \
            not all(isinstance(c, (str, int, float, bool)) for c in choices):
        raise scope.error(line, "choices", f"arg {name!r}: expected a list of values")
    texts = [_arg_text(c) for c in choices]
    if _arg_text(value) not in texts:
        raise LaunchError(f"{scope.file}:{body.line}: launch arg {name}:={format_value(value)} is not "
                          f"{one_of(name, texts, description)}")


def _arg_text(value: Any) -> str:
    """An arg value as the text a choice is compared with (true/false for booleans)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _exec_target(exec_: str, pkg: str, scope: Scope, line) -> str:
    """The module name or .py path an `exec:` names."""
    if exec_.endswith(".py") or "/" in exec_:
        path = Path(exec_)
        if not path.is_absolute():
            path = scope.file.parent / path
        if not path.is_file():
            raise scope.error(line, "exec", f"no such node script {path}")
        return str(path)
    module = exec_ if "." in exec_ else f"{NODE_PACKAGES[pkg]}.{exec_}"
    if not re.fullmatch(r"[A-Za-z_][\w.]*", module):
        raise scope.error(line, "exec", f"{exec_!r} is not a module name or a .py path")
    try:
        found = importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise scope.error(line, "exec", f"no node module {module} (exec is a module under "
                          f"{NODE_PACKAGES[pkg]} (pkg: {pkg}), a dotted module path, "
                          f"or a .py file)")
    return module


def _default_name(exec_: str) -> str:
    """A node's name when it has no `name:`: a .py path's file stem, a module's last part
    (`incipient_slip.graph.recorder` is `recorder`, not its package's `graph`)."""
    if exec_.endswith(".py") or "/" in exec_:
        return Path(exec_).stem
    return exec_.rsplit(".", 1)[-1]


def _resolve_node(body: Marked, scope: Scope) -> NodeSpec:
    lines = body.lines
    exec_ = scope.text(_need(body, "exec", scope, "node"), lines["exec"], "exec")
    name = scope.text(body["name"], lines["name"], "name") if "name" in body else _default_name(exec_)
    if not re.fullmatch(r"[A-Za-z_][\w.-]*", name):
        raise scope.error(lines.get("name", body.line), "name",
                          f"node name {name!r}: use letters, digits, '_', '.', '-'")
    pkg = (scope.text(body["pkg"], lines["pkg"], "pkg") if "pkg" in body
           else "incipient_slip")
    if pkg not in NODE_PACKAGES:
        raise scope.error(lines["pkg"], "pkg", f"unknown package {pkg!r} "
                          f"(one of {', '.join(sorted(NODE_PACKAGES))})")
    target = _exec_target(exec_, pkg, scope, lines["exec"])
    command = [sys.executable, target] if target.endswith(".py") else [sys.executable, "-m", target]
    spec = NodeSpec(name, exec_, command, source=f"{scope.file}:{body.line}", target=target)
    for item in _list(body, "param", scope):
        if not isinstance(item, Marked) or set(item) - {"name", "value"} or "name" not in item \
                or "value" not in item:
            raise scope.error(getattr(item, "line", lines["param"]), "param",
                              "each param is {name: NAME, value: VALUE}")
        pname = scope.text(item["name"], item.line, "name")
        if not pname.isidentifier():
            raise scope.error(item.line, "name", f"parameter name {pname!r} is not an identifier")
        spec.params[pname] = scope.substitute(item["value"], item.lines["value"], "value")
        spec.param_sources[pname] = f"{scope.file}:{item.lines['value']}"
    for item in _list(body, "remap", scope):
        if not isinstance(item, Marked) or set(item) != {"from", "to"}:
            raise scope.error(getattr(item, "line", lines["remap"]), "remap",
                              "each remap is {from: /topic, to: /other}")
        src = scope.text(item["from"], item.line, "from")
        dst = scope.text(item["to"], item.line, "to")
        for key, topic in (("from", src), ("to", dst)):
            if not topic.startswith("/") or " " in topic:
                raise scope.error(item.lines[key], key, f"topic {topic!r} must start with '/'")
        spec.remaps[src] = dst
    for key in ("required", "respawn", "gate"):
        if key in body:
            setattr(spec, key, scope.flag(body[key], lines[key], key))
    if "respawn_delay" in body:
        delay = scope.substitute(body["respawn_delay"], lines["respawn_delay"], "respawn_delay")
        if not isinstance(delay, (int, float)) or isinstance(delay, bool) or delay < 0:
            raise scope.error(lines["respawn_delay"], "respawn_delay", f"expected seconds >= 0, got {delay!r}")
        spec.respawn_delay = float(delay)
    if "env" in body:
        if not isinstance(body["env"], dict):
            raise scope.error(lines["env"], "env", "expected a mapping NAME: value")
        spec.env = {str(k): scope.text(v, lines["env"], str(k)) for k, v in body["env"].items()}
    return spec


def _list(body: Marked, key: str, scope: Scope) -> list:
    value = body.get(key, [])
    if value is None:
        return []
    if not isinstance(value, list):
        raise scope.error(body.lines[key], key, "expected a list")
    return value


def _resolve_include(body: Marked, scope: Scope, desc: LaunchDescription) -> None:
    lines = body.lines
    target = scope.text(_need(body, "file", scope, "include"), lines["file"], "file")
    if scope.depth > 20:
        raise scope.error(lines["file"], "file", "includes nest deeper than 20 (a cycle?)")
    path = Path(target)
    if not path.is_absolute():
        local = scope.file.parent / path
        path = local if local.is_file() else paths.launch_dir() / path
    if not path.is_file():
        raise scope.error(lines["file"], "file", f"no such launch file {target}")
    given = {}
    for item in _list(body, "arg", scope):
        if not isinstance(item, Marked) or set(item) != {"name", "value"}:
            raise scope.error(getattr(item, "line", lines["arg"]), "arg",
                              "each include arg is {name: NAME, value: VALUE}")
        given[scope.text(item["name"], item.line, "name")] = scope.substitute(
            item["value"], item.lines["value"], "value")
    actions = parse_document(path.read_text(), path)
    declared = declared_args(actions)
    unknown = sorted(set(given) - set(declared))
    if unknown:
        raise scope.error(lines["arg"], "arg", f"{path} declares no arg {', '.join(unknown)}; it "
                          f"declares: {', '.join(declared) or '(none)'}")
    _resolve_actions(actions, Scope(path, given, scope.depth + 1), desc)
