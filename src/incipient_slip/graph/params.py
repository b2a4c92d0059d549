"""Node command lines: `name:=value` parameters, `/from:=/to` remaps, `__name:=node_name`.

The same syntax serves a node run by hand (`python -m incipient_slip.nodes.estimator
window_s:=0.5`) and the launcher, which passes each launch-file parameter as `name:=<json>`
(JSON is YAML, so the node gets the exact type back). Precedence: node defaults (`PARAMS`)
< launch file < command line, because the launcher puts command-line overrides last.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from incipient_slip.paths import output_error, prepare_output

__all__ = ["ParamError", "Param", "NodeArgs", "parse_node_argv", "parse_value", "format_value", "coerce_param",
           "merge_params", "check_params", "declared_params", "one_of", "checked_value", "checked_output"]


class ParamError(ValueError):
    """A bad parameter or remap on a node's command line; names it and says what would be right."""


@dataclass(frozen=True)
class Param:
    """A parameter's declaration in a node's PARAMS: its default and the values it accepts.

    `PARAMS = {"s_d": Param(0.3, lo=0.0, hi=1.0, help="target stick ratio")}`; a bare value
    (`"rate_hz": 100.0`) is a Param with no bounds. Numbers must be finite unless
    `finite=False`; `choices` lists the accepted values of a text or number.
    """

    default: Any
    lo: float | None = None
    hi: float | None = None
    choices: tuple | None = None
    finite: bool = True
    help: str = ""

    def check(self, node: str, name: str, value: Any) -> Any:
        """`value` if it is inside the declaration; ParamError naming the parameter otherwise."""
        where = f"node {node!r}: parameter {name}:={format_value(value)}"
        if self.choices is not None and value not in self.choices:
            raise ParamError(f"{where} is not {one_of(name, self.choices, self.help)}")
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if self.finite and not math.isfinite(value):
                raise ParamError(f"{where} is not a finite number")
            if self.lo is not None and not value >= self.lo:
                raise ParamError(f"{where} is below its range [{self.lo}, {self.hi}]"
                                 if self.hi is not None else f"{where} must be >= {self.lo}")
            if self.hi is not None and not value <= self.hi:
                raise ParamError(f"{where} is above its range [{self.lo}, {self.hi}]"
                                 if self.lo is not None else f"{where} must be <= {self.hi}")
        return value


def as_param(declared: Any) -> Param:
    """A PARAMS entry as a Param (a bare default becomes an unbounded one)."""
    return declared if isinstance(declared, Param) else Param(declared)


@dataclass
class NodeArgs:
    """What a node's command line says: parameters, remaps and an optional node name."""

    params: dict[str, Any] = field(default_factory=dict)
    raw: dict[str, str] = field(default_factory=dict)      # the text each param came from
    remaps: dict[str, str] = field(default_factory=dict)
    node_name: str | None = None


def parse_value(text: str) -> Any:
    """The YAML value of a command-line text (`1.5` -> float, `true` -> bool, `sim` -> str)."""
    try:
        return yaml.safe_load(text) if text.strip() else ""
    except yaml.YAMLError:
        return text


def format_value(value: Any) -> str:
    """A command-line text that parse_value turns back into exactly `value`."""
    if isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    return json.dumps(value, separators=(",", ":"))


def one_of(name: str, choices, meaning: str = "") -> str:
    """'one of a, b, ""' for a value outside `choices` (a param's or a launch arg's); an empty
    choice shows as "" and means what `meaning` (the help, the description) says, so it follows."""
    texts = [str(c) for c in choices]
    listing = ", ".join(t if t else '""' for t in texts)
    return f"one of {listing}" + (f" ({name}: {meaning})" if "" in texts and meaning else "")


def checked_output(node: str, param: str, path: str, what: str) -> Path:
    """`prepare_output(path)` (its folder created, writable); an OSError becomes the ParamError
    naming the node, the parameter and the path, the one line a launch refuses it with."""
    try:
        return prepare_output(path)
    except OSError as exc:
        raise ParamError(f"node {node!r}: parameter {param}:={format_value(path)}: "
                         f"cannot write {what} there ({output_error(exc)})") from None


def checked_value(node: str, param: str, value: Any, pick):
    """`pick(value)`; a ValueError it raises (an unknown material, ...) becomes the ParamError
    naming the node, the parameter and the value, the one line a launch refuses it with."""
    try:
        return pick(value)
    except ValueError as exc:
        raise ParamError(f"node {node!r}: parameter {param}:={format_value(value)}: {exc}") from None


def parse_node_argv(argv: list[str]) -> NodeArgs:
    """The parameters, remaps and node name in `argv`; ParamError on anything else."""
    out = NodeArgs()
    for token in argv:
        if ":=" not in token:
            raise ParamError(f"argument {token!r} is not 'name:=value' (parameter), "
                             f"'/from:=/to' (remap) or '__name:=node_name'")
        key, text = token.split(":=", 1)
        if key == "__name":
            out.node_name = text
        elif key.startswith("/"):
            if not text.startswith("/"):
                raise ParamError(f"remap {token!r}: the target topic must start with '/'")
            out.remaps[key] = text
        elif key.isidentifier():
            out.params[key] = parse_value(text)
            out.raw[key] = text
        else:
            raise ParamError(f"argument {token!r}: {key!r} is not a parameter name "
                             f"(letters, digits, '_') nor a topic ('/...')")
    return out


def coerce_param(node: str, name: str, default: Any, value: Any, raw: str | None = None) -> Any:
    """`value` converted to the type of the parameter's default, or ParamError."""
    if default is None or value is None:
        return value
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
    elif isinstance(default, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
    elif isinstance(default, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif isinstance(default, str):
        if isinstance(value, str):
            return value
        if raw is not None:         # `name:=123` for a string parameter means the text "123"
            return raw
        if isinstance(value, (int, float, bool)):
            return str(value)
    elif isinstance(default, (list, tuple)):
        if isinstance(value, (list, tuple)):
            return list(value)
    elif isinstance(default, dict):
        if isinstance(value, dict):
            return value
    else:
        return value
    raise ParamError(f"node {node!r}: parameter {name!r} = {value!r} ({type(value).__name__}) "
                     f"does not fit its default {default!r} ({type(default).__name__})")


def merge_params(node: str, declared: dict[str, Any], *layers: dict[str, Any],
                 raw: dict[str, str] | None = None) -> dict[str, Any]:
    """The defaults overridden by each layer in turn, each value checked against its
    declaration (`Param`); ParamError names any unknown or out-of-range parameter."""
    decls = {name: as_param(d) for name, d in declared.items()}
    out = {name: d.default for name, d in decls.items()}
    raw = raw or {}
    for layer in layers:
        for name, value in layer.items():
            if name not in decls:
                known = ", ".join(sorted(decls)) or "(none)"
                raise ParamError(f"node {node!r} has no parameter {name!r}; known: {known}")
            out[name] = coerce_param(node, name, decls[name].default, value, raw.get(name))
    for name, value in out.items():
        decls[name].check(node, name, value)
    return out


def check_params(node: str, declared: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """The `given` values coerced and checked against their declarations (defaults are not
    checked: they are the node's); ParamError naming the first unknown or out-of-range one.
    The launcher calls this before it starts anything."""
    decls = {name: as_param(d) for name, d in declared.items()}
    out = {}
    for name, value in given.items():
        if name not in decls:
            known = ", ".join(sorted(decls)) or "(none)"
            raise ParamError(f"node {node!r} has no parameter {name!r}; known: {known}")
        out[name] = decls[name].check(node, name, coerce_param(node, name, decls[name].default, value))
    return out


def declared_params(node_class: type) -> dict[str, Any]:
    """The PARAMS of a node class and its bases (a subclass's entry wins)."""
    declared: dict[str, Any] = {}
    for klass in reversed(node_class.__mro__):
        declared.update(getattr(klass, "PARAMS", {}) or {})
    return declared
