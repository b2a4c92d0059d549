"""docker-compose.yml cannot run here (no docker engine); check what can be checked without it."""
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]


def compose():
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def test_every_service_builds_from_the_dockerfile_and_shares_the_graph_volume():
    doc = compose()
    assert doc["services"], "no services"
    for name, service in doc["services"].items():
        assert service["build"] == ".", name
        assert "graph:/graph" in service["volumes"], name
        assert service["environment"]["SLIP_GRAPH_DIR"] == "/graph", name
    assert "graph" in doc["volumes"]


def test_dockerfile_copies_only_paths_that_exist():
    for line in (ROOT / "Dockerfile").read_text().splitlines():
        if line.startswith("COPY "):
            for source in line.split()[1:-1]:
                assert (ROOT / source).exists(), f"Dockerfile copies missing {source}"


@pytest.mark.timeout(600)
def test_every_service_command_runs_outside_docker(tmp_path):
    """Each command's module exists and accepts its params (checked with --help, which parses them)."""
    for name, service in compose()["services"].items():
        command = service["command"]
        assert command[:2] == ["python", "-m"], name
        module = command[2]
        result = subprocess.run([sys.executable, "-m", module, "--help"], cwd=ROOT,
                                capture_output=True, text=True, timeout=120,   # imports, under load
                                env={**os.environ, "SLIP_GRAPH_DIR": str(tmp_path)})
        assert result.returncode == 0, f"{name}: {result.stderr}"
        for arg in command[3:]:
            param = re.match(r"(\w+):=", arg).group(1)
            assert param in result.stdout + result.stderr, f"{name}: unknown param {param}"


def test_the_default_demo_is_the_closed_loop_one_container_per_node():
    """Without a profile, compose starts the rig, the estimator, the grip controller and the
    supervisor (whose exit ends the demo), each its own service with one node module."""
    default = {name: s for name, s in compose()["services"].items() if not s.get("profiles")}
    modules = {s["command"][2].rsplit(".", 1)[1] for s in default.values()}
    assert modules == {"rig_sim", "estimator", "grip_controller", "supervisor"}
    assert len(modules) == len(default)


def test_the_image_makes_the_graph_directory_for_the_node_user_and_pins_versions():
    """A named volume starts as a copy of the image's directory: made 0700 and owned by `slip`
    there, it is not the root-owned /graph that nodes refuse; two builds install the same
    versions (every package in constraints.txt pinned with ==)."""
    docker = (ROOT / "Dockerfile").read_text()
    assert "mkdir -m 0700 /graph" in docker and re.search(r"chown slip:slip /graph", docker)
    assert docker.index("chown slip:slip /graph") < docker.index("USER slip")
    assert "-c constraints.txt" in docker
    pins = [l for l in (ROOT / "constraints.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert pins and all(re.fullmatch(r"[A-Za-z0-9_.\-\[\]]+==[^=\s]+", l) for l in pins), pins
    names = {l.split("==")[0].lower().replace("_", "-") for l in pins}
    assert {"pyzmq", "msgpack", "numpy", "scipy", "scikit-learn", "pyyaml", "mcap"} <= names
    ignored = (ROOT / ".dockerignore").read_text().split()
    assert {".git", ".venv", "runs"} <= set(ignored)


def test_the_image_compiles_the_simulator_s_kernels_into_the_node_user_s_cache(tmp_path):
    """The image's warm-up command (run as the node user, after USER slip) compiles and caches
    the rig's numba kernels: run here with numba's cache pointed at an empty directory, it fills
    it, and a second process loads them from there without compiling again."""
    docker = (ROOT / "Dockerfile").read_text()
    line = next(l for l in docker.splitlines() if l.startswith("RUN python -c") and "Rig(" in l)
    assert docker.index("USER slip") < docker.index(line)
    code = shlex.split(line)[3]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), NUMBA_DEBUG_CACHE="1")
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600,
                           check=True)
    assert list((tmp_path / "numba").rglob("*.nbi")), first.stdout[-2000:]
    again = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600,
                           check=True)
    assert "[cache] data loaded" in again.stdout and "[cache] data saved" not in again.stdout, again.stdout[-2000:]


def test_the_summary_reaches_the_host_and_compose_returns_the_verdict():
    doc = compose()
    supervisor = doc["services"]["supervisor"]
    path = next(a.split(":=", 1)[1] for a in supervisor["command"] if a.startswith("summary_path:="))
    mounts = [v.split(":") for v in supervisor["volumes"]]
    assert any(host.startswith("./") and path.startswith(inside + "/") for host, inside in mounts)
    header = (ROOT / "docker-compose.yml").read_text()
    assert "--exit-code-from supervisor" in header
