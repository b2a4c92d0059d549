"""Many closed-loop runs through the real node graph, `jobs` graphs at a time.

Every run is `launch/stabilize.yaml` resolved by the launcher (same file, same args as a user's
`launch stabilize.yaml method:=e19 seed:=3`): rig_sim, estimator, grip_controller and
supervisor as separate processes talking ZeroMQ in lock-step, each graph in its own graph
directory so that graphs run side by side. The supervisor's JSON summary of each run is what
a run returns.

Process start: by default (`start="fork"`) a pre-imported parent forks each node process and
calls the node module's `main(argv)` with the launcher's argv, instead of exec'ing a fresh
interpreter (importing scipy for rig_sim alone costs ~1.5 s of CPU, about as much as a whole
run). The nodes, sockets and messages are the same; `start="exec"` runs the `launch` command
itself for every run (slower; a cross-check).
"""
from __future__ import annotations

import importlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from incipient_slip import control
from incipient_slip.graph.launch.supervise import child_setup

NODE_MODULES = ("rig_sim", "estimator", "grip_controller", "supervisor")
RUN_TIMEOUT_S = 180.0
STOP_GRACE_S = 5.0

# --- one run ---------------------------------------------------------------------------------

@dataclass
class RunSpec:
    """One closed-loop run: the launch args of stabilize.yaml and where its summary goes."""

    method: str
    seed: int
    material: str
    s_d: float = control.DEFAULT_TARGET_STICK_RATIO
    k: float = control.DEFAULT_GAIN_KPA
    steps: int = control.MAX_STEPS
    tag: str = "table"
    summary_path: Path = Path()
    log_path: Path = Path()
    model: str = ""          # estimator model file ("" = the shipped model of `label`)
    label: str = "pseudo"    # the training label of the shipped model (launch label:=)

    def launch_args(self) -> dict[str, str]:
        args = {"method": self.method, "seed": str(self.seed), "material": self.material,
                "s_d": repr(float(self.s_d)), "k": repr(float(self.k)), "steps": str(self.steps),
                "summary": str(self.summary_path), "quiet": "true"}
        if self.model:                       # the file's own label
            args["model"] = self.model
        else:
            args["label"] = self.label
        return args

    @property
    def name(self) -> str:
        label = "" if self.label == "pseudo" else f"-{self.label}"
        return f"{self.tag}-{self.method}{label}-sd{self.s_d:g}-k{self.k:g}-{self.material}-s{self.seed}"


@dataclass
class _Graph:
    spec: RunSpec
    directory: Path
    pids: dict[int, str] = field(default_factory=dict)     # fork mode: pid -> node name
    popen: subprocess.Popen | None = None                   # exec mode: the launch command
    required_pid: int | None = None
    started: float = 0.0
    rc: int | None = None
    log: object = None


class GraphRunner:
    """Runs RunSpecs as node graphs, `jobs` at a time, from one single-threaded loop.

    start="fork": resolve stabilize.yaml with the launcher, fork one process per node from this
    pre-imported parent, end the graph when its required node (the supervisor) exits.
    start="exec": run the `launch` command (the user's entry point) per run.
    """

    def __init__(self, jobs: int = 2, start: str = "fork", timeout_s: float = RUN_TIMEOUT_S):
        if start not in ("fork", "exec"):
            raise ValueError(f"start must be 'fork' or 'exec', got {start!r}")
        self.jobs, self.start, self.timeout_s = max(1, jobs), start, timeout_s
        from incipient_slip.graph import launch as launcher
        self.launcher = launcher
        self.launch_file = launcher.find_launch_file("stabilize.yaml")
        if start == "fork":
            for name in NODE_MODULES:      # imported once here; every forked node shares them
                importlib.import_module(f"incipient_slip.nodes.{name}")

    def run(self, specs: list[RunSpec], progress=None) -> list[dict]:
        """The summaries of all runs, in the order of `specs` (a failed launch gets a fault)."""
        pending = list(enumerate(specs))[::-1]
        active: list[tuple[int, _Graph]] = []
        results: list[dict | None] = [None] * len(specs)
        while pending or active:
            while pending and len(active) < self.jobs:
                i, spec = pending.pop()
                active.append((i, self._begin(spec)))
            time.sleep(0.005)
            still = []
            for i, g in active:
                if self._poll(g):
                    results[i] = self._collect(g)
                    if progress:
                        progress(i, results[i])
                else:
                    still.append((i, g))
            active = still
        return results

    # --- starting and ending one graph -------------------------------------------------------

    def _begin(self, spec: RunSpec) -> _Graph:
        directory = Path(tempfile.mkdtemp(prefix="stab", dir="/tmp"))
        spec.summary_path.parent.mkdir(parents=True, exist_ok=True)
        if spec.summary_path.exists():
            spec.summary_path.unlink()
        g = _Graph(spec, directory, started=time.monotonic())
        g.log = open(spec.log_path, "wb")
        if self.start == "exec":
            cmd = [sys.executable, "-m", "incipient_slip.graph.launch", str(self.launch_file)]
            cmd += [f"{k}:={v}" for k, v in spec.launch_args().items()]
            env = dict(os.environ, SLIP_GRAPH_DIR=str(directory), PYTHONUNBUFFERED="1")
            g.popen = subprocess.Popen(cmd, stdout=g.log, stderr=subprocess.STDOUT, env=env,
                                       stdin=subprocess.DEVNULL, start_new_session=True)
            return g
        desc = self.launcher.load(self.launch_file, spec.launch_args())
        sys.stdout.flush()
        sys.stderr.flush()
        for node in desc.nodes:
            pid = self._fork_node(node, directory, g.log.fileno())
            g.pids[pid] = node.name
            if node.required:
                g.required_pid = pid
        return g

    @staticmethod
    def _fork_node(node, directory: Path, log_fd: int) -> int:
        module = node.command[-1]              # [python, -m, module]
        argv = node.argv()[len(node.command):]
        pid = os.fork()
        if pid:
            return pid
        rc = 1
        try:                                   # the child: become the node, never return
            child_setup()
            for s in (signal.SIGINT, signal.SIGTERM, signal.SIGCHLD):
                signal.signal(s, signal.SIG_DFL)
            os.dup2(log_fd, 1)
            os.dup2(log_fd, 2)
            os.environ.update(SLIP_GRAPH_DIR=str(directory), SLIP_LAUNCHED="1", **node.env)
            print(f"--- {node.name}: {module} {' '.join(argv)}", file=sys.stderr, flush=True)
            rc = int(importlib.import_module(module).main(argv) or 0)
        except BaseException:
            traceback.print_exc()
        finally:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
            finally:
                os._exit(rc)

    def _poll(self, g: _Graph) -> bool:
        """True once the graph has ended (required node exited, or timed out) and is cleaned up."""
        timed_out = time.monotonic() - g.started > self.timeout_s
        if g.popen is not None:
            rc = g.popen.poll()
            if rc is None and not timed_out:
                return False
            if rc is None:
                os.killpg(g.popen.pid, signal.SIGTERM)
                try:
                    g.popen.wait(STOP_GRACE_S)
                except subprocess.TimeoutExpired:
                    os.killpg(g.popen.pid, signal.SIGKILL)
                    g.popen.wait()
                g.rc = -1
            else:
                g.rc = rc
            return True
        done = {}
        for pid in list(g.pids):
            r, status = os.waitpid(pid, os.WNOHANG)
            if r:
                done[pid] = os.waitstatus_to_exitcode(status)
        for pid, rc in done.items():
            name = g.pids.pop(pid)
            if pid == g.required_pid:
                g.rc = rc
            elif rc not in (0,):
                os.write(g.log.fileno(), f"--- {name} exited with {rc}\n".encode())
        if g.rc is None and g.required_pid not in g.pids and g.required_pid is not None:
            g.rc = 1
        if g.rc is None and not timed_out:
            return False
        if g.rc is None:
            g.rc = -1
        self._stop(g)
        return True

    def _stop(self, g: _Graph) -> None:
        """SIGTERM every node still running, SIGKILL at the grace deadline, reap all."""
        for pid in g.pids:
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + STOP_GRACE_S
        while g.pids and time.monotonic() < deadline:
            for pid in list(g.pids):
                if os.waitpid(pid, os.WNOHANG)[0]:
                    g.pids.pop(pid)
            time.sleep(0.005)
        for pid in list(g.pids):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)
            g.pids.pop(pid)

    def _collect(self, g: _Graph) -> dict:
        wall = time.monotonic() - g.started
        g.log.close()
        shutil.rmtree(g.directory, ignore_errors=True)
        spec = g.spec
        try:
            summary = json.loads(spec.summary_path.read_text())
        except (OSError, ValueError):
            summary = {"outcome": "fault", "success": False, "steps": 0,
                       "final_travel_mm": float("nan"), "final_force_kpa": float("nan"),
                       "detail": f"no summary (launch exit {g.rc}); log {spec.log_path}",
                       "traces": {}}
        summary.update(launch_rc=g.rc, launch_wall_s=round(wall, 3), method=spec.method,
                       seed=spec.seed, material=spec.material, s_d=spec.s_d, k=spec.k, tag=spec.tag)
        return summary


