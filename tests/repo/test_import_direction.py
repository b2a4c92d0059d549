"""Every import inside the package points down the layers (docs/design.md), checked by parsing.

experiments -> nodes -> identify -> graph / models / sim / control (a package: law, answerer, judge,
closers, clock) -> messages; `models/` never reads the
simulator and `sim/` never imports learning or control. `cluster` (dask tasks) sits below sim,
models and experiments and imports only the leaves. Imports inside functions count too.
"""
import ast
from pathlib import Path

import pytest

import incipient_slip

PACKAGE = Path(incipient_slip.__file__).parent
LEAVES = {"errors", "paths", "cache", "extras"}   # import nothing of ours; anyone may import them
# layer -> the layers it may import (besides itself and the leaves)
ALLOWED = {
    "messages": set(),
    "cluster": set(),                       # dask client and tasks: the generator, the grid search, the sweep
    "control": {"messages"},
    "sim": {"messages", "cluster"},
    "models": {"messages", "cluster"},
    "graph": {"messages"},
    "devices": {"messages", "sim"},         # emulators take their signal values from the simulated rig
    # rig identification's protocols and fit: the paper's gross-slip rule (models.labels) and the clamps
    "identify": {"control", "models", "messages"},
    "nodes": {"graph", "messages", "models", "sim", "control", "devices", "identify"},
    # a lab's workflow: collection sessions (launches) and recordings -> data sets
    "lab": {"graph", "messages", "models", "sim", "control", "devices"},
    "experiments": {"nodes", "graph", "messages", "models", "sim", "control", "devices", "cluster", "identify"},
    "cli": {"graph", "sim", "models", "experiments", "lab"},
    "__init__": set(),
}
# an upward import with its reason; keep this list short
EXCEPTIONS = {
    ("graph.tools", "cli"): "`python -m incipient_slip.graph.tools` runs its commands through slip's main",
}


def layer(module: str) -> str:
    return module.split(".")[0]


def modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
        if parts[-1] == "__init__" and len(parts) > 1:
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def imports_of(name: str, path: Path) -> set[str]:
    """Return the package-relative modules `name` imports (absolute and relative, at any depth)."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                target = ".".join(["incipient_slip", *base, *(node.module.split(".") if node.module else [])])
            else:
                target = node.module or ""
            found.add(target)
            found |= {f"{target}.{a.name}" for a in node.names}
    return {m[len("incipient_slip."):] for m in found if m.startswith("incipient_slip.")}


def _known(target: str, known: dict) -> str | None:
    while target and target not in known:
        target = target.rpartition(".")[0]
    return target or None


@pytest.mark.parametrize("name", sorted(modules()))
def test_imports_point_down(name):
    known = modules()
    if layer(name) in LEAVES:
        assert not imports_of(name, known[name]), f"{name} is a leaf and must import nothing of ours"
        return
    allowed = ALLOWED[layer(name)] | LEAVES | {layer(name)}
    bad = {t for t in map(lambda m: _known(m, known), imports_of(name, known[name]))
           if t and layer(t) not in allowed and (name, t) not in EXCEPTIONS}
    assert not bad, f"{name} imports {sorted(bad)}: layer {layer(name)!r} may import only {sorted(allowed)}"


def test_the_checker_sees_a_wrong_import(tmp_path):
    bad = tmp_path / "rig.py"
    bad.write_text("def f():\n    from ..models import labels\n")
    assert "models.labels" in imports_of("sim.rig", bad)


# inside the identify package: the protocol is the base; the window bookkeeping and the fit read
# its records; the outputs (overlay, files) read the fit's results and draw the pictures
IDENTIFY_ALLOWED = {
    "identify.protocol": set(),
    "identify.windows": {"identify.protocol"},
    "identify.fit": {"identify.protocol"},
    "identify.figures": {"identify.protocol", "identify.fit"},
    "identify.overlay": {"identify.protocol", "identify.figures"},
}


def test_identify_modules_point_down_inside_the_package():
    known = modules()
    inside = {n for n in known if n.startswith("identify.")}
    assert inside == set(IDENTIFY_ALLOWED), "a new module of identify/ needs its place in IDENTIFY_ALLOWED"
    for name in sorted(inside):
        targets = {_known(m, known) for m in imports_of(name, known[name])}
        bad = {t for t in targets if t and t.startswith("identify") and t != name} - IDENTIFY_ALLOWED[name]
        assert not bad, f"{name} imports {sorted(bad)}; inside identify/ it may import {sorted(IDENTIFY_ALLOWED[name])}"


# inside the control package: the law and the period clock are the base; the answerer returns the
# law's decisions as wire commands; the judge asks the period closers (one per mode) when a period
# is closed
CONTROL_ALLOWED = {
    "control.law": set(),
    "control.clock": set(),
    "control.closers": set(),
    "control.answerer": {"control.law"},
    "control.judge": {"control.law", "control.closers"},
}


def test_control_modules_point_down_inside_the_package():
    known = modules()
    inside = {n for n in known if n.startswith("control.")}
    assert inside == set(CONTROL_ALLOWED), "a new module of control/ needs its place in CONTROL_ALLOWED"
    for name in sorted(inside):
        targets = {_known(m, known) for m in imports_of(name, known[name])}
        bad = {t for t in targets if t and t.startswith("control") and t != name} - CONTROL_ALLOWED[name]
        assert not bad, f"{name} imports {sorted(bad)}; inside control/ it may import {sorted(CONTROL_ALLOWED[name])}"
