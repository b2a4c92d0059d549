"""Substitute: `$(var NAME)`, `$(env NAME [default])`, `$(dirname)`, `$(eval EXPR)` and conditions.

`$(eval ...)` evaluates literals, comparisons, and/or/not, if-else and + - * / // % only (an
AST walk, never Python's eval). A condition (`if:`/`unless:`) is true/false (also 1/0, yes/no,
on/off) or `A == B` / `A != B`. A value that held a substitution is re-typed as YAML, so
`"$(var rate)"` gives 100, not "100".
"""
from __future__ import annotations

import ast
import operator
import os
import re
from pathlib import Path
from typing import Any

import yaml

from incipient_slip.graph.launch.parse import LaunchError

__all__ = ["Scope", "safe_eval"]

_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod}
_CMPOPS = {ast.Eq: operator.eq, ast.NotEq: operator.ne, ast.Lt: operator.lt, ast.LtE: operator.le,
           ast.Gt: operator.gt, ast.GtE: operator.ge, ast.In: lambda a, b: a in b,
           ast.NotIn: lambda a, b: a not in b}


def safe_eval(expr: str) -> Any:
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
            if isinstance(n.op, ast.Mult) and (isinstance(left, (str, list)) or isinstance(right, (str, list))):
                raise ValueError("repeating a string or list is not allowed")
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


class Scope:
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
                value = safe_eval(_unquote(rest))
            except (ValueError, SyntaxError, TypeError, ZeroDivisionError, OverflowError) as exc:
                raise self.error(line, key, f"$(eval {rest}): {exc}") from None
            except (RecursionError, MemoryError):
                raise self.error(line, key, f"$(eval {rest[:40]}...): nested too deeply") from None
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
        """The truth of a yes/no key (`required`, `respawn`): same rules as a condition."""
        return self.condition(value, line, key)
