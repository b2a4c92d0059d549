"""Every import inside the package points down the layers (docs/design.md), checked by parsing.

experiments -> nodes -> identify -> graph / models / sim / control (a package: law, answerer, judge,
closers, clock) -> messages; `models/` never reads the
simulator and `sim/` never imports learning or control. `cluster` (dask tasks) sits below sim,
models and experiments and imports only the leaves. Imports inside functions count too.

Inside two layers the modules are siblings, not layers: a node never imports another node (what two
nodes share lives in devices/, control, models/ or graph/), and an experiment never imports another
experiment (what two share is a module of experiments/ that is not one: settings, plots, runner,
datasets, closed_loop, mechanics_fit, ...). An experiment is a module `experiments.EXPERIMENTS`
registers, with its package's modules when it is a package.
"""
import ast
from pathlib import Path

import pytest

import incipient_slip

PACKAGE = Path(incipient_slip.__file__).parent
BASE = {"errors", "paths"}                        # import nothing of ours
LEAVES = BASE | {"cache", "extras"}              # import at most the base; anyone may import them
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
    ("devices.rig_config", "graph.params"): "a device node's rig file section fills the node's declared params "
                                            "(apply_rig_config: merge_params, ParamError)",
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
    if layer(name) in BASE:
        assert not imports_of(name, known[name]), f"{name} is the base and must import nothing of ours"
        return
    if layer(name) in LEAVES:
        above = {t for t in map(lambda m: _known(m, known), imports_of(name, known[name])) if layer(t) not in BASE}
        assert not above, f"{name} is a leaf and may import only {sorted(BASE)}, not {sorted(above)}"
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


# a package whose modules are layers too -> its table (IDENTIFY_ALLOWED, CONTROL_ALLOWED)
INNER_ORDERS = {"identify": IDENTIFY_ALLOWED, "control": CONTROL_ALLOWED}


@pytest.mark.parametrize("package", sorted(INNER_ORDERS))
def test_modules_point_down_inside_their_package(package):
    order, table = INNER_ORDERS[package], f"{package.upper()}_ALLOWED"
    known = modules()
    inside = {n for n in known if n.startswith(f"{package}.")}
    assert inside == set(order), f"a new module of {package}/ needs its place in {table}"
    for name in sorted(inside):
        targets = {_known(m, known) for m in imports_of(name, known[name])}
        bad = {t for t in targets if t and t.startswith(package) and t != name} - order[name]
        assert not bad, f"{name} imports {sorted(bad)}; inside {package}/ it may import {sorted(order[name])}"


# --- siblings: node -> node and experiment -> experiment -----------------------------------------

# a sibling import with its reason; keep this list shorter still
SIBLING_EXCEPTIONS = {
    ("nodes.device_tools", "nodes.rig_check"): "`slip rig check` (not a node: the operator's commands for the "
                                               "device nodes) runs the rig_check node once, in its own process",
}

def experiment_of(name: str) -> str | None:
    """The registered experiment module `name` belongs to (itself, or a module of its package), else None."""
    from incipient_slip.experiments import EXPERIMENTS

    for module in EXPERIMENTS.values():
        own = module[len("incipient_slip."):]
        if name == own or name.startswith(own + "."):
            return own
    return None


def sibling_imports(name: str, path: Path, known: dict) -> set[str]:
    """Return the modules `name` imports that it must not: another node when it is in nodes/,
    another experiment when it is in experiments/ (a shared module of experiments/, one that is
    no experiment, imports no experiment at all: it loads them by name, `experiments.load`)."""
    targets = {t for t in (_known(m, known) for m in imports_of(name, path)) if t}
    if layer(name) == "nodes":
        return {t for t in targets if layer(t) == "nodes" and t not in ("nodes", name)
                and (name, t) not in SIBLING_EXCEPTIONS}
    if layer(name) == "experiments":
        own = experiment_of(name)
        return {t for t in targets if experiment_of(t) not in (None, own)}
    return set()


@pytest.mark.parametrize("name", sorted(n for n in modules() if layer(n) in ("nodes", "experiments")))
def test_no_node_imports_another_node_and_no_experiment_another_experiment(name):
    known = modules()
    bad = sibling_imports(name, known[name], known)
    what = "a node may not import another node" if layer(name) == "nodes" else \
        "an experiment (or a shared module of experiments/) may not import an experiment"
    assert not bad, f"{name} imports {sorted(bad)}: {what}; move what they share below them"


def test_the_sibling_rule_sees_a_node_or_an_experiment_importing_its_sibling(tmp_path):
    known = modules()
    node = tmp_path / "ur5.py"
    node.write_text("from incipient_slip.nodes.rig_check import EXIT_MISSING\n")
    assert sibling_imports("nodes.ur5", node, known) == {"nodes.rig_check"}
    node.write_text("from incipient_slip.devices.rig_config import apply_rig_config\n")
    assert sibling_imports("nodes.ur5", node, known) == set()
    experiment = tmp_path / "identification.py"
    experiment.write_text("def scene_with():\n    from .calibration import VIBRATION\n")
    assert sibling_imports("experiments.identification", experiment, known) == {"experiments.calibration"}
    experiment.write_text("from .validation.spec import POINTS\nfrom .settings import Settings\n")
    assert sibling_imports("experiments.identification", experiment, known) == {"experiments.validation.spec"}
    inside = tmp_path / "report.py"
    inside.write_text("from .spec import LABELS\nfrom ..plots import pyplot\n")
    assert sibling_imports("experiments.validation.report", inside, known) == set()
    shared = tmp_path / "plots.py"
    shared.write_text("from . import stabilization\n")
    assert sibling_imports("experiments.plots", shared, known) == {"experiments.stabilization"}


def test_every_registered_experiment_is_a_module_here():
    from incipient_slip.experiments import EXPERIMENTS

    known = modules()
    assert all(m[len("incipient_slip."):] in known for m in EXPERIMENTS.values())
