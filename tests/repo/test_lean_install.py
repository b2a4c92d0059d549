"""A device-only lab PC installs `.[hardware]`: the hardware launch's nodes and the operator's
commands import nothing of the [sim] extra (numba, llvmlite, dask, matplotlib), the extras hold
what the docs say, and a node or command that needs [sim] without it names the extra."""
from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("numba", "llvmlite", "dask", "distributed", "matplotlib")


def hardware_nodes() -> list[str]:
    """The node modules `launch stabilize.yaml rig:=hardware` and identify.yaml start on the real rig."""
    doc = yaml.safe_load((REPO / "launch" / "rig_hardware.yaml").read_text())
    names = {item["node"]["exec"] for item in doc["launch"] if "node" in item}
    return sorted(names | {"estimator", "grip_controller", "supervisor", "identifier"})


def imported(modules: list[str]) -> set[str]:
    code = ("import importlib, sys\n"
            f"for m in {modules!r}: importlib.import_module(m)\n"
            f"print(' '.join(sorted({{k.split('.')[0] for k in sys.modules}} & set({HEAVY!r}))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


def test_the_hardware_launch_nodes_and_operator_commands_import_nothing_of_sim():
    nodes = hardware_nodes()
    assert {"rig_check", "biotac_reader", "pzt_injector", "mocap_bridge", "linear_actuator", "ur5"} <= set(nodes)
    modules = [f"incipient_slip.nodes.{n}" for n in nodes] + [
        "incipient_slip.nodes.calibrate", "incipient_slip.nodes.device_tools", "incipient_slip.graph.tools",
        "incipient_slip.graph.launch"]
    assert imported(modules) == set()


def test_the_extras_are_what_the_docs_say():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    core = " ".join(project["dependencies"])
    assert not any(name in core for name in ("numba", "matplotlib", "distributed", "dask"))
    extras = project["optional-dependencies"]
    assert {d.split(">")[0].split(";")[0] for d in extras["hardware"]} == {"pyserial", "sounddevice", "ur-rtde"}
    assert {d.split(">")[0] for d in extras["sim"]} == {"numba", "matplotlib", "distributed"}
    assert "robot" not in extras                       # one spelling: [hardware] brings the robot
    assert "'.[sim,test,view]'" in (REPO / "Makefile").read_text()


def test_without_numba_the_simulated_rig_names_the_sim_extra():
    block = "import sys; sys.modules['numba'] = None\n"
    run = subprocess.run([sys.executable, "-c", block + "import incipient_slip.nodes.rig_sim"],
                         capture_output=True, text=True)
    assert run.returncode == 1 and "from the [sim] extra: pip install -e '.[sim]'" in run.stderr.splitlines()[-1]
    run = subprocess.run([sys.executable, "-c", block + "from incipient_slip.graph.launch import main\n"
                          "sys.exit(main(['stabilize.yaml', '--print']))"], capture_output=True, text=True, cwd=REPO)
    assert run.returncode != 0 and "[sim] extra" in run.stdout + run.stderr
