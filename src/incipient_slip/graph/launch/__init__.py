"""`launch FILE.yaml [name:=value ...]`: start a graph of nodes from a YAML launch file.

The file format follows ROS 2's YAML launch frontend. A top-level `launch:` list of actions:

    launch:
      # which rig feeds the graph
      - arg: {name: rig, default: sim, description: "sim | replay | hardware"}
      - node:
          exec: estimator            # incipient_slip.nodes.estimator (pkg: graph for the tool
                                     # processes recorder, replay, monitor), a dotted module, or a .py path
          name: estimator            # default: the exec's last part
          param: [{name: method, value: "$(var method)"}]
          remap: [{from: /biotac/pac, to: /biotac/pac_raw}]
          required: true             # its exit ends the launch (with its exit code)
          respawn: false             # restart it when it exits (after respawn_delay s)
          if: "$(var rig) == sim"    # or unless:; also on group and include
      - group: {if: "$(var rig) == hardware", actions: [...]}
      - include: {file: other.yaml, arg: [{name: rig, value: "$(var rig)"}]}

Substitutions in strings: `$(var NAME)`, `$(env NAME [default])`, `$(dirname)` (the launch
file's directory) and `$(eval EXPR)` (literals, comparisons, and/or/not, arithmetic only; never
Python's eval). A condition is `true`/`false` (also 1/0, yes/no) or `A == B` / `A != B`.
A param value that came from a substitution is re-typed as YAML (`"$(var rate)"` -> 100).

How a launch ends: Ctrl-C or SIGTERM stops every node (SIGTERM in reverse start order, then
SIGKILL after the grace period) and exits 0 (1 if a node had to be killed). A required node
that exits ends the launch: the others are stopped and the launch exits with that node's code
(0 when it finished cleanly, e.g. a supervisor at the end of a run; 128+N when signal N killed
it). When every node has exited by itself the launch exits 0, or with the first non-zero code.
"""
from __future__ import annotations

import argparse
import ast
import importlib.util
import operator
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from incipient_slip import paths
from incipient_slip.graph import discovery
from incipient_slip.graph.params import format_value

__all__ = ["LaunchError", "NodeSpec", "LaunchDescription", "load", "load_text", "find_launch_file",
           "Launcher", "main"]

GRACE_S = 5.0           # default: SIGTERM ... SIGKILL budget for the whole graph


class LaunchError(Exception):
    """A launch file that cannot be resolved; the message names file, line and key."""


# --- YAML with line numbers -----------------------------------------------------------------

class _MarkedDict(dict):
    """A mapping that remembers the line of itself and of each key (1-based)."""

    line: int = 0
    lines: dict


class _Loader(yaml.SafeLoader):
    pass


def _construct_mapping(loader: _Loader, node: yaml.MappingNode) -> _MarkedDict:
    loader.flatten_mapping(node)
    out = _MarkedDict()
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


# --- the resolved tree ----------------------------------------------------------------------

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
    respawn_delay: float = 1.0
    env: dict[str, str] = field(default_factory=dict)
    source: str = ""

    def argv(self) -> list[str]:
        """The node's command line: params as `name:=<json>`, remaps as `/from:=/to`."""
        return (self.command + [f"__name:={self.name}"]
                + [f"{k}:={format_value(v)}" for k, v in self.params.items()]
                + [f"{k}:={v}" for k, v in self.remaps.items()])


@dataclass
class LaunchDescription:
    """A resolved launch file: argument values and the nodes to start, in order."""

    file: str
    args: dict[str, Any] = field(default_factory=dict)
    arg_descriptions: dict[str, str] = field(default_factory=dict)
    nodes: list[NodeSpec] = field(default_factory=list)

    def to_plain(self) -> dict:
        """A YAML-friendly dict (what `launch FILE --print` shows)."""
        return {"file": self.file, "args": dict(self.args), "nodes": [
            {"name": n.name, "exec": n.exec, "command": " ".join(n.argv()), "params": n.params,
             "remaps": n.remaps, "required": n.required, "respawn": n.respawn,
             **({"respawn_delay": n.respawn_delay} if n.respawn else {}),
             **({"env": n.env} if n.env else {}), "source": n.source} for n in self.nodes]}


# --- substitutions and conditions -----------------------------------------------------------

_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod}
_CMPOPS = {ast.Eq: operator.eq, ast.NotEq: operator.ne, ast.Lt: operator.lt, ast.LtE: operator.le,
           ast.Gt: operator.gt, ast.GtE: operator.ge, ast.In: lambda a, b: a in b,
           ast.NotIn: lambda a, b: a not in b}


def _safe_eval(expr: str) -> Any:
    """The value of a small expression: literals, comparisons, and/or/not, + - * / // %."""
    def ev(n):
        if isinstance(n, ast.Expression):
            return ev(n.body)
        if isinstance(n, ast.Constant):
            return n.value
        if isinstance(n, (ast.Tuple, ast.List)):
            return [ev(e) for e in n.elts]
        if isinstance(n, ast.BoolOp):
            values = [ev(v) for v in n.values]
            return all(values) if isinstance(n.op, ast.And) else any(values)
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, (ast.Not, ast.USub, ast.UAdd)):
            v = ev(n.operand)
            return (not v) if isinstance(n.op, ast.Not) else (-v if isinstance(n.op, ast.USub) else +v)
        if isinstance(n, ast.BinOp) and type(n.op) in _BINOPS:
            left, right = ev(n.left), ev(n.right)
            if isinstance(left, str) and isinstance(n.op, ast.Mult):
                raise ValueError("string repetition is not allowed")
            return _BINOPS[type(n.op)](left, right)
        if isinstance(n, ast.Compare):
            left = ev(n.left)
            for op, comp in zip(n.ops, n.comparators):
                right = ev(comp)
                if type(op) not in _CMPOPS or not _CMPOPS[type(op)](left, right):
                    if type(op) not in _CMPOPS:
                        raise ValueError(f"operator {type(op).__name__} is not allowed")
                    return False
                left = right
            return True
        if isinstance(n, ast.IfExp):
            return ev(n.body) if ev(n.test) else ev(n.orelse)
        raise ValueError(f"{type(n).__name__} is not allowed (literals, comparisons, and/or/not, "
                         f"arithmetic only)")
    if len(expr) > 1000:
        raise ValueError("expression longer than 1000 characters")
    return ev(ast.parse(expr.strip(), mode="eval"))


def _unquote(text: str) -> str:
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"" and text.count(text[0]) == 2:
        return text[1:-1]
    return text


class _Scope:
    """Argument values of one launch file being resolved, and where we are in it."""

    def __init__(self, file: Path, given: dict[str, Any], depth: int = 0):
        self.file, self.given, self.depth = file, dict(given), depth
        self.vars: dict[str, Any] = {}
        self.descriptions: dict[str, str] = {}
        self.used_given: set[str] = set()

    def error(self, line: int | None, key: str | None, reason: str) -> LaunchError:
        where = f"{self.file}:{line}" if line else str(self.file)
        return LaunchError(f"{where}: {'key ' + repr(key) + ': ' if key else ''}{reason}")

    def substitute(self, value: Any, line: int | None, key: str | None) -> Any:
        """`value` with every $(...) replaced; strings that held one are re-typed as YAML."""
        if isinstance(value, str) and "$(" in value:
            text = self._sub_text(value, line, key)
            try:
                typed = yaml.safe_load(text) if text.strip() else text
            except yaml.YAMLError:
                return text
            return typed if isinstance(typed, (int, float, bool)) else text
        if isinstance(value, list):
            return [self.substitute(v, line, key) for v in value]
        if isinstance(value, dict):
            return {k: self.substitute(v, line, key) for k, v in value.items()}
        return value

    def text(self, value: Any, line, key) -> str:
        """`value` substituted, as a string."""
        if not isinstance(value, (str, int, float, bool)):
            raise self.error(line, key, f"expected a string, got {type(value).__name__}")
        return self._sub_text(value, line, key) if isinstance(value, str) else str(value)

    def _sub_text(self, text: str, line, key) -> str:
        out, i = [], 0
        while True:
            j = text.find("$(", i)
            if j < 0:
                out.append(text[i:])
                return "".join(out)
            out.append(text[i:j])
            inner, i = self._scan(text, j + 2, line, key)
            out.append(self._apply(self._sub_text(inner, line, key), line, key))

    def _scan(self, text: str, k: int, line, key) -> tuple[str, int]:
        start, depth, quote = k, 0, None
        while k < len(text):
            c = text[k]
            if quote:
                if c == quote:
                    quote = None
            elif c in "'\"":
                quote = c
            elif c == "(":
                depth += 1
            elif c == ")":
                if depth == 0:
                    return text[start:k], k + 1
                depth -= 1
            k += 1
        raise self.error(line, key, f"unclosed substitution in {text!r}")

    def _apply(self, inner: str, line, key) -> str:
        kind, _, rest = inner.strip().partition(" ")
        rest = rest.strip()
        if kind == "var":
            if rest not in self.vars:
                raise self.error(line, key, f"$(var {rest}): no such arg; declared so far: "
                                 f"{', '.join(self.vars) or '(none)'}")
            return str(self.vars[rest])
        if kind == "env":
            name, _, default = rest.partition(" ")
            if name in os.environ:
                return os.environ[name]
            if default:
                return _unquote(default)
            raise self.error(line, key, f"$(env {name}): environment variable not set and no default")
        if kind == "dirname":
            return str(self.file.parent)
        if kind == "eval":
            try:
                value = _safe_eval(_unquote(rest))
            except (ValueError, SyntaxError, TypeError, ZeroDivisionError) as exc:
                raise self.error(line, key, f"$(eval {rest}): {exc}") from None
            return str(value)
        raise self.error(line, key, f"unknown substitution $({inner}); known: var, env, eval, dirname")

    def condition(self, value: Any, line, key) -> bool:
        """The truth of an if/unless value."""
        if isinstance(value, bool):
            return value
        text = self.text(value, line, key).strip()
        m = re.fullmatch(r"(.*?)\s*(==|!=)\s*(.*)", text)
        if m:
            equal = _unquote(m.group(1)) == _unquote(m.group(3))
            return equal if m.group(2) == "==" else not equal
        low = text.lower()
        if low in ("true", "1", "yes", "on"):
            return True
        if low in ("false", "0", "no", "off", ""):
            return False
        raise self.error(line, key, f"condition {text!r} is neither true/false nor 'A == B' / 'A != B'")

    def flag(self, value: Any, line, key) -> bool:
        return self.condition(value, line, key)


# --- resolution ---------------------------------------------------------------------------

_ACTION_KEYS = {
    "arg": {"name", "default", "description"},
    "node": {"exec", "pkg", "name", "param", "remap", "required", "respawn", "respawn_delay",
             "if", "unless", "env"},
    "group": {"actions", "children", "if", "unless"},
    "include": {"file", "arg", "if", "unless"},
}


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


def _declared_args(actions: Any) -> list[str]:
    names = []
    for action in actions if isinstance(actions, list) else []:
        if isinstance(action, dict) and len(action) == 1:
            (kind, body), = action.items()
            if kind == "arg" and isinstance(body, dict) and "name" in body:
                names.append(str(body["name"]))
            elif kind == "group" and isinstance(body, dict):
                names += _declared_args(body.get("actions", body.get("children")))
    return names


def load(path: str | Path, cli_args: dict[str, str] | None = None) -> LaunchDescription:
    """The resolved launch description of a launch file (path or name in launch/)."""
    file = find_launch_file(str(path))
    return load_text(file.read_text(), cli_args, file)


def load_text(text: str, cli_args: dict[str, str] | None = None,
              file: str | Path = "<string>") -> LaunchDescription:
    """The resolved launch description of a launch document (the parser's test entry point)."""
    file = Path(file)
    desc = LaunchDescription(str(file))
    scope = _Scope(file, cli_args or {})
    actions = _parse_document(text, file)
    known = _declared_args(actions)
    unknown = sorted(set(scope.given) - set(known))
    if unknown:
        listing = "\n".join(f"  {n}" for n in known) or "  (none)"
        raise LaunchError(f"{file}: unknown launch argument{'s' if len(unknown) > 1 else ''} "
                          f"{', '.join(unknown)}; this file declares:\n{listing}")
    _resolve_actions(actions, scope, desc, line=None)
    desc.args = dict(scope.vars)
    desc.arg_descriptions = dict(scope.descriptions)
    seen: dict[str, str] = {}
    for node in desc.nodes:
        if node.name in seen:
            raise LaunchError(f"{node.source}: node name {node.name!r} is already used at "
                              f"{seen[node.name]}; give one of them another `name`")
        seen[node.name] = node.source
    return desc


def _parse_document(text: str, file: Path) -> list:
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
    if not isinstance(doc["launch"], list):
        raise LaunchError(f"{file}:{doc.lines['launch']}: key 'launch': expected a list of actions")
    return doc["launch"]


def _resolve_actions(actions: Any, scope: _Scope, desc: LaunchDescription, line) -> None:
    if not isinstance(actions, list):
        raise scope.error(line, "actions", "expected a list of actions")
    for action in actions:
        if not isinstance(action, _MarkedDict) or len(action) != 1:
            raise scope.error(getattr(action, "line", line), None,
                              f"each action is a one-key mapping ({', '.join(_ACTION_KEYS)}), "
                              f"got {action!r:.80}")
        (kind, body), = action.items()
        aline = action.line
        if kind not in _ACTION_KEYS:
            raise scope.error(aline, kind, f"unknown action; known: {', '.join(_ACTION_KEYS)}")
        if not isinstance(body, _MarkedDict):
            raise scope.error(aline, kind, "expected a mapping of the action's keys")
        unknown = sorted(set(body) - _ACTION_KEYS[kind])
        if unknown:
            raise scope.error(body.lines[unknown[0]], unknown[0],
                              f"unknown key in {kind}; known: {', '.join(sorted(_ACTION_KEYS[kind]))}")
        if "if" in body and not scope.condition(body["if"], body.lines["if"], "if"):
            continue
        if "unless" in body and scope.condition(body["unless"], body.lines["unless"], "unless"):
            continue
        if kind == "arg":
            _resolve_arg(body, scope)
        elif kind == "node":
            desc.nodes.append(_resolve_node(body, scope))
        elif kind == "group":
            children = body.get("actions", body.get("children"))
            key = "actions" if "actions" in body else "children"
            if children is None:
                raise scope.error(body.line, "actions", "a group needs an 'actions' list")
            _resolve_actions(children, scope, desc, body.lines.get(key, body.line))
        else:
            _resolve_include(body, scope, desc)


def _need(body: _MarkedDict, key: str, scope: _Scope, kind: str):
    if key not in body:
        raise scope.error(body.line, key, f"required in {kind}")
    return body[key]


def _resolve_arg(body: _MarkedDict, scope: _Scope) -> None:
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
    scope.vars[name] = value
    scope.descriptions[name] = str(body.get("description", ""))


# `pkg:` of a node action -> the package its `exec:` names a module of
NODE_PACKAGES = {"incipient_slip": "incipient_slip.nodes", "graph": "incipient_slip.graph"}


def _exec_command(exec_: str, pkg: str, scope: _Scope, line) -> list[str]:
    if exec_.endswith(".py") or "/" in exec_:
        path = Path(exec_)
        if not path.is_absolute():
            path = scope.file.parent / path
        if not path.is_file():
            raise scope.error(line, "exec", f"no such node script {path}")
        return [sys.executable, str(path)]
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
    return [sys.executable, "-m", module]


def _resolve_node(body: _MarkedDict, scope: _Scope) -> NodeSpec:
    lines = body.lines
    exec_ = scope.text(_need(body, "exec", scope, "node"), lines["exec"], "exec")
    name = (scope.text(body["name"], lines["name"], "name") if "name" in body
            else Path(exec_).stem.rsplit(".", 1)[-1])
    if not re.fullmatch(r"[A-Za-z_][\w.-]*", name):
        raise scope.error(lines.get("name", body.line), "name",
                          f"node name {name!r}: use letters, digits, '_', '.', '-'")
    pkg = (scope.text(body["pkg"], lines["pkg"], "pkg") if "pkg" in body
           else "incipient_slip")
    if pkg not in NODE_PACKAGES:
        raise scope.error(lines["pkg"], "pkg", f"unknown package {pkg!r} "
                          f"(one of {', '.join(sorted(NODE_PACKAGES))})")
    spec = NodeSpec(name, exec_, _exec_command(exec_, pkg, scope, lines["exec"]),
                    source=f"{scope.file}:{body.line}")
    for item in _list(body, "param", scope):
        if not isinstance(item, _MarkedDict) or set(item) - {"name", "value"} or "name" not in item \
                or "value" not in item:
            raise scope.error(getattr(item, "line", lines["param"]), "param",
                              "each param is {name: NAME, value: VALUE}")
        pname = scope.text(item["name"], item.line, "name")
        if not pname.isidentifier():
            raise scope.error(item.line, "name", f"parameter name {pname!r} is not an identifier")
        spec.params[pname] = scope.substitute(item["value"], item.lines["value"], "value")
    for item in _list(body, "remap", scope):
        if not isinstance(item, _MarkedDict) or set(item) != {"from", "to"}:
            raise scope.error(getattr(item, "line", lines["remap"]), "remap",
                              "each remap is {from: /topic, to: /other}")
        src = scope.text(item["from"], item.line, "from")
        dst = scope.text(item["to"], item.line, "to")
        for key, topic in (("from", src), ("to", dst)):
            if not topic.startswith("/") or " " in topic:
                raise scope.error(item.lines[key], key, f"topic {topic!r} must start with '/'")
        spec.remaps[src] = dst
    for key in ("required", "respawn"):
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


def _list(body: _MarkedDict, key: str, scope: _Scope) -> list:
    value = body.get(key, [])
    if value is None:
        return []
    if not isinstance(value, list):
        raise scope.error(body.lines[key], key, "expected a list")
    return value


def _resolve_include(body: _MarkedDict, scope: _Scope, desc: LaunchDescription) -> None:
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
        if not isinstance(item, _MarkedDict) or set(item) != {"name", "value"}:
            raise scope.error(getattr(item, "line", lines["arg"]), "arg",
                              "each include arg is {name: NAME, value: VALUE}")
        given[scope.text(item["name"], item.line, "name")] = scope.substitute(
            item["value"], item.lines["value"], "value")
    inner = _Scope(path, given, scope.depth + 1)
    actions = _parse_document(path.read_text(), path)
    unknown = sorted(set(given) - set(_declared_args(actions)))
    if unknown:
        raise scope.error(lines["arg"], "arg", f"{path} declares no arg {', '.join(unknown)}; it "
                          f"declares: {', '.join(_declared_args(actions)) or '(none)'}")
    _resolve_actions(actions, inner, desc, None)


# --- running --------------------------------------------------------------------------------

def _describe(rc: int) -> str:
    if rc < 0:
        try:
            return f"signal {signal.Signals(-rc).name}"
        except ValueError:
            return f"signal {-rc}"
    return f"exit code {rc}"


def _exit_code(rc: int) -> int:
    return 128 - rc if rc < 0 else rc


def _child_setup() -> None:
    # Own process group: a terminal's Ctrl-C reaches only the launcher, which then stops the
    # nodes in order. PR_SET_PDEATHSIG: if the launcher is killed, the nodes get SIGTERM.
    os.setpgid(0, 0)
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)
    except Exception:
        pass


class _Proc:
    def __init__(self, spec: NodeSpec):
        self.spec = spec
        self.popen: subprocess.Popen | None = None
        self.threads: list[threading.Thread] = []
        self.respawn_at: float | None = None
        self.rc: int | None = None


class Launcher:
    """Runs a resolved launch description; `run()` returns the launch's exit code."""

    def __init__(self, desc: LaunchDescription, grace_s: float = GRACE_S, graph_dir: Path | None = None):
        self.desc, self.grace_s = desc, grace_s
        self.graph_dir = graph_dir or discovery.graph_dir()
        self.procs = [_Proc(spec) for spec in desc.nodes]
        self._lock = threading.Lock()
        self._signal: int | None = None
        self._signals = 0

    def say(self, text: str) -> None:
        self._write(sys.stderr, f"[launch] {text}\n".encode())

    def _write(self, stream, data: bytes) -> None:
        with self._lock:
            try:
                stream.buffer.write(data)
                stream.flush()
            except (ValueError, OSError):
                pass

    def _pump(self, pipe, stream, prefix: bytes) -> None:
        for line in iter(pipe.readline, b""):
            self._write(stream, prefix + (line if line.endswith(b"\n") else line + b"\n"))
        pipe.close()

    def _start(self, proc: _Proc) -> None:
        env = dict(os.environ, SLIP_LAUNCHED="1", PYTHONUNBUFFERED="1",
                   **{discovery.GRAPH_DIR_ENV: str(self.graph_dir)}, **proc.spec.env)
        proc.popen = subprocess.Popen(proc.spec.argv(), stdin=subprocess.DEVNULL,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                      preexec_fn=_child_setup)
        proc.rc, proc.respawn_at = None, None
        prefix = f"[{proc.spec.name}] ".encode()
        proc.threads = [threading.Thread(target=self._pump, args=(pipe, stream, prefix), daemon=True)
                        for pipe, stream in ((proc.popen.stdout, sys.stdout),
                                             (proc.popen.stderr, sys.stderr))]
        for t in proc.threads:
            t.start()

    def _on_signal(self, signum, frame) -> None:
        self._signals += 1
        self._signal = signum
        if self._signals >= 2:       # a second Ctrl-C: stop waiting, kill everything now
            for proc in self.procs:
                if proc.popen is not None and proc.popen.poll() is None:
                    proc.popen.kill()

    def run(self) -> int:
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            return self._run()
        finally:
            for s, handler in old.items():
                signal.signal(s, handler)

    def _run(self) -> int:
        if not self.procs:
            self.say(f"{self.desc.file}: no nodes to start")
            return 0
        self.say(f"graph {self.graph_dir}: starting {', '.join(p.spec.name for p in self.procs)}")
        for proc in self.procs:
            if self._signal is not None:
                break
            self._start(proc)
        first_failure = 0
        while True:
            if self._signal is not None:
                self.say(f"{signal.Signals(self._signal).name}: shutting down")
                return 0 if self._shutdown() else 1
            now = time.monotonic()
            alive = 0
            for proc in self.procs:
                if proc.popen is None:
                    continue
                if proc.respawn_at is not None:
                    if now >= proc.respawn_at:
                        self.say(f"respawning {proc.spec.name}")
                        self._start(proc)
                    alive += 1
                    continue
                if proc.rc is not None:
                    continue
                rc = proc.popen.poll()
                if rc is None:
                    alive += 1
                    continue
                proc.rc = rc
                for t in proc.threads:
                    t.join(timeout=1.0)
                spec = proc.spec
                if spec.respawn:
                    self.say(f"{spec.name} exited with {_describe(rc)}; respawning in {spec.respawn_delay:g} s")
                    proc.respawn_at = now + spec.respawn_delay
                    alive += 1
                elif spec.required:
                    # "died" only for a signal: a node's own non-zero code is an outcome it chose
                    # (e.g. the supervisor reporting a failed run), not necessarily a crash
                    verb = "finished" if rc == 0 else ("died" if rc < 0 else "exited")
                    self.say(f"required node {spec.name} {verb} with {_describe(rc)}; shutting down the graph")
                    self._shutdown()
                    if rc != 0:
                        self.say(f"launch ends with code {_exit_code(rc)}: required node {spec.name} "
                                 f"{_describe(rc)}")
                    return _exit_code(rc)
                else:
                    self.say(f"{spec.name} exited with {_describe(rc)}")
                    if rc != 0 and not first_failure:
                        first_failure = _exit_code(rc)
            if alive == 0:
                self.say("all nodes have exited")
                return first_failure
            time.sleep(0.05)   # supervision tick; node exits are found by polling

    def _shutdown(self) -> bool:
        """Stops every node: SIGTERM in reverse start order, then SIGKILL at the deadline.
        True when none needed SIGKILL."""
        deadline = time.monotonic() + self.grace_s
        running = [p for p in reversed(self.procs) if p.popen is not None and p.rc is None
                   and p.respawn_at is None]
        for proc in running:
            if proc.popen.poll() is None:
                try:
                    proc.popen.send_signal(signal.SIGTERM)
                except ProcessLookupError:
                    pass
                # wait a little for each so that sinks (started first) stop after sources
                try:
                    proc.popen.wait(timeout=max(0.0, min(1.0, deadline - time.monotonic() - 0.5)))
                except subprocess.TimeoutExpired:
                    pass
        clean = True
        for proc in running:
            try:
                proc.popen.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.say(f"{proc.spec.name} did not stop within {self.grace_s:g} s: SIGKILL")
                proc.popen.kill()
                proc.popen.wait()
                clean = False
            proc.rc = proc.popen.returncode
            for t in proc.threads:
                t.join(timeout=1.0)
            if proc.rc not in (0, -signal.SIGTERM):
                self.say(f"{proc.spec.name} stopped with {_describe(proc.rc)}")
        return clean


def _split_cli_args(tokens: list[str]) -> dict[str, str]:
    out = {}
    for token in tokens:
        if ":=" not in token:
            raise LaunchError(f"argument {token!r} is not name:=value")
        name, value = token.split(":=", 1)
        out[name] = value
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="launch", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Start a graph of nodes from a YAML launch file, each node its own process "
        "with its output prefixed [name].",
        epilog=__doc__.split("\n", 2)[2])
    parser.add_argument("file", help="launch file: a path, or a name in launch/ (e.g. demo.yaml)")
    parser.add_argument("args", nargs="*", metavar="name:=value", help="launch argument values")
    parser.add_argument("--print", action="store_true", dest="print_only",
                        help="print the resolved graph (args, nodes, params, remaps) and exit")
    parser.add_argument("--grace", type=float, default=GRACE_S, metavar="S",
                        help=f"seconds from SIGTERM to SIGKILL at shutdown (default {GRACE_S:g})")
    parser.add_argument("--graph", metavar="NAME", help="graph name (default $SLIP_GRAPH or "
                        "'default'; $SLIP_GRAPH_DIR overrides the directory)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_intermixed_args(argv)
    try:
        desc = load(args.file, _split_cli_args(args.args))
    except LaunchError as exc:
        print(f"launch: error: {exc}", file=sys.stderr)
        return 2
    if args.print_only:
        print(yaml.safe_dump(desc.to_plain(), sort_keys=False, width=120), end="")
        return 0
    return Launcher(desc, args.grace, discovery.graph_dir(args.graph) if args.graph else None).run()


if __name__ == "__main__":
    sys.exit(main())
