"""Supervise: start the resolved nodes as processes, watch them, stop them, choose the exit code.

Each node runs in its own process group (a terminal's Ctrl-C reaches only the launcher, which
then stops the nodes in order) with PR_SET_PDEATHSIG (if the launcher is killed, its nodes get
SIGTERM). Output lines are prefixed `[name]`. When a node process ends, the launcher removes
the discovery file and ipc socket it may have left (a SIGKILLed node cannot).

Exit codes of a launch (docs/graph.md):
  * a required node exits: the others are stopped; the launch exits with its code (128+N for
    signal N, also when the node stopped cleanly on SIGTERM/SIGINT sent from outside the launch:
    143, 130 — an interrupted run is not a success; 2 for bad input: a parameter, a model file),
    its last line repeated last;
  * a node that exits 2 is not respawned (restarting cannot fix its input); if other nodes wait
    for it as a reader (a viewer bridge whose port was taken), it ends the launch with 2;
  * Ctrl-C / SIGTERM: the nodes are stopped; 128 + the signal (130 for Ctrl-C, 143 for
    SIGTERM, as a shell reports it);
  * a stop that needed SIGKILL (at the grace deadline, or at once by a second Ctrl-C): 3, a
    fault (a node did not stop), unless a required node had already exited non-zero (its code:
    the cause first);
  * every node exited by itself: 0, or the first non-zero code.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from incipient_slip.errors import EXIT_FAULT, EXIT_SIGNAL_BASE, EXIT_USAGE
from incipient_slip.graph import discovery
from incipient_slip.graph.launch.resolve import LaunchDescription, NodeSpec
from incipient_slip.graph.runtime import READERS_ENV

__all__ = ["Launcher", "GRACE_S", "EXIT_KILLED"]

GRACE_S = 30.0          # default: SIGTERM ... SIGKILL budget for the whole graph: a loaded
                        # machine can take seconds to flush and tear down a node (issue 21)
EXIT_KILLED = EXIT_FAULT     # a stop that needed SIGKILL: a node did not stop
TICK_S = 0.05           # supervision tick: node exits are found by polling


def describe(rc: int) -> str:
    """'exit code N' or 'signal NAME' for a Popen return code."""
    if rc < 0:
        try:
            return f"signal {signal.Signals(-rc).name}"
        except ValueError:
            return f"signal {-rc}"
    if EXIT_SIGNAL_BASE < rc < EXIT_SIGNAL_BASE + 32:   # a node that stopped cleanly on a signal
        try:
            return f"exit code {rc} (stopped by {signal.Signals(rc - EXIT_SIGNAL_BASE).name})"
        except ValueError:
            pass
    return f"exit code {rc}"


def exit_code(rc: int) -> int:
    """A Popen return code as a shell exit code (128+N for signal N)."""
    return 128 - rc if rc < 0 else rc


def child_setup() -> None:
    """In a node's child process: its own process group, and SIGTERM when its parent dies."""
    os.setpgid(0, 0)
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
    except Exception:
        pass


class _Proc:
    def __init__(self, spec: NodeSpec):
        self.spec = spec
        self.popen: subprocess.Popen | None = None
        self.threads: list[threading.Thread] = []
        self.respawn_at: float | None = None
        self.rc: int | None = None
        self.last_err = b""       # its last stderr line, repeated when it ends the launch


class Launcher:
    """Runs a resolved launch description; `run()` returns the launch's exit code."""

    def __init__(self, desc: LaunchDescription, grace_s: float = GRACE_S, graph_dir: Path | None = None):
        self.desc, self.grace_s = desc, grace_s
        self.graph_dir = graph_dir or discovery.graph_dir()
        self.procs = [_Proc(spec) for spec in desc.nodes]
        self._lock = threading.Lock()
        self._signal: int | None = None
        self._signals = 0
        self._killed: set[str] = set()

    def say(self, text: str) -> None:
        self._write(sys.stderr, f"[launch] {text}\n".encode())

    def _write(self, stream, data: bytes) -> None:
        with self._lock:
            try:
                stream.buffer.write(data)
                stream.flush()
            except (ValueError, OSError):
                pass

    def _pump(self, proc: _Proc, pipe, stream, prefix: bytes) -> None:
        for line in iter(pipe.readline, b""):
            line = line if line.endswith(b"\n") else line + b"\n"
            if stream is sys.stderr and line.strip():
                proc.last_err = line
            self._write(stream, prefix + line)
        pipe.close()

    def _start(self, proc: _Proc) -> None:
        env = dict(os.environ, SLIP_LAUNCHED="1", PYTHONUNBUFFERED="1",
                   **{discovery.GRAPH_DIR_ENV: str(self.graph_dir)}, **proc.spec.env)
        proc.popen = subprocess.Popen(proc.spec.argv(), stdin=subprocess.DEVNULL,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                      preexec_fn=child_setup)
        proc.rc, proc.respawn_at, proc.last_err = None, None, b""
        prefix = f"[{proc.spec.name}] ".encode()
        proc.threads = [threading.Thread(target=self._pump, args=(proc, pipe, stream, prefix), daemon=True)
                        for pipe, stream in ((proc.popen.stdout, sys.stdout),
                                             (proc.popen.stderr, sys.stderr))]
        for t in proc.threads:
            t.start()

    def _ended(self, proc: _Proc, rc: int) -> None:
        """Books a node's end: its output read to the end, its discovery files removed."""
        proc.rc = rc
        for t in proc.threads:
            t.join(timeout=1.0)
        discovery.remove_pid(self.graph_dir, proc.popen.pid)

    def _on_signal(self, signum, frame) -> None:
        self._signals += 1
        if self._signal is None:
            self._signal = signum
        if self._signals >= 2:       # a second Ctrl-C: stop waiting, kill everything now
            for proc in self.procs:
                if proc.popen is not None and proc.popen.poll() is None:
                    proc.popen.kill()
                    self._killed.add(proc.spec.name)

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
        for warning in self.desc.warnings:
            self.say(f"warning: {warning}")
        self.say(f"graph {self.graph_dir}: starting "
                 f"{', '.join(p.spec.name + (' (gate)' if p.spec.gate else '') for p in self.procs)}")
        for proc in self.procs:
            if self._signal is not None:
                break
            self._start(proc)
            if proc.spec.gate:
                rc = self._pass_gate(proc)
                if rc is not None and rc != 0:
                    return rc
        first_failure = 0
        while True:
            if self._signal is not None:
                self.say(f"{signal.Signals(self._signal).name}: shutting down")
                self._shutdown()
                if self._killed:
                    return self._killed_code()
                return 128 + self._signal     # as a shell reports it: 130 for Ctrl-C
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
                self._ended(proc, rc)
                spec = proc.spec
                if spec.respawn and rc != EXIT_USAGE:
                    self.say(f"{spec.name} exited with {describe(rc)}; respawning in {spec.respawn_delay:g} s")
                    proc.respawn_at = now + spec.respawn_delay
                    alive += 1
                elif spec.required:
                    # "died" only for a signal: a node's own non-zero code is an outcome it chose
                    # (e.g. the supervisor reporting a failed run), not necessarily a crash
                    verb = "finished" if rc == 0 else ("died" if rc < 0 else "exited")
                    self.say(f"required node {spec.name} {verb} with {describe(rc)}; shutting down the graph")
                    self._shutdown()
                    if rc == 0 and self._killed:
                        return self._killed_code()
                    if rc != 0:     # the cause last, where it is seen: the node's own last line
                        last = proc.last_err.decode(errors="replace").strip()
                        self.say(f"launch ends with code {exit_code(rc)}: required node {spec.name} "
                                 f"{describe(rc)}" + (f": {last}" if last else ""))
                    return exit_code(rc)
                elif rc == EXIT_USAGE and (waiting := self._waiting_for(spec.name)):
                    # its input was bad (the viewer's port taken since the launch's check): the
                    # nodes that wait for it as a reader would wait until their wait_timeout_s
                    self.say(f"{spec.name} exited with {describe(rc)} (bad input) and "
                             f"{', '.join(waiting)} wait{'s' if len(waiting) == 1 else ''} for it; shutting down the graph")
                    self._shutdown()
                    last = proc.last_err.decode(errors="replace").strip()
                    self.say(f"launch ends with code {rc}: node {spec.name} {describe(rc)}"
                             + (f": {last}" if last else ""))
                    return rc
                else:
                    self.say(f"{spec.name} exited with {describe(rc)}")
                    if rc != 0 and not first_failure:
                        first_failure = exit_code(rc)
            if alive == 0:
                self.say("all nodes have exited")
                return first_failure
            time.sleep(TICK_S)

    def _waiting_for(self, name: str) -> list[str]:
        """The running nodes told to wait for node `name` as a reader of their outputs."""
        return [p.spec.name for p in self.procs
                if p.popen is not None and p.rc is None and p.spec.name != name
                and any(name in readers for readers in json.loads(p.spec.env.get(READERS_ENV, "{}")).values())]

    def _killed_code(self) -> int:
        self.say(f"launch ends with code {EXIT_KILLED}: SIGKILL was needed for "
                 f"{', '.join(sorted(self._killed))}")
        return EXIT_KILLED

    def _pass_gate(self, proc: _Proc) -> int | None:
        """Waits for a gate node to exit. Exit 0: None (start the rest); a signal: None (the
        main loop shuts down); any other exit: the graph is shut down, the launch's exit code."""
        while proc.popen.poll() is None and self._signal is None:
            time.sleep(TICK_S)
        if self._signal is not None:
            return None
        rc = proc.popen.returncode
        self._ended(proc, rc)
        later = [p.spec.name for p in self.procs if p.popen is None]
        if rc == 0:
            self.say(f"gate {proc.spec.name} passed; starting {', '.join(later) or 'nothing more'}")
            return None
        self.say(f"gate {proc.spec.name} exited with {describe(rc)}; not started: {', '.join(later)}")
        self._shutdown()
        last = proc.last_err.decode(errors="replace").strip()
        self.say(f"launch ends with code {exit_code(rc)}: gate {proc.spec.name} {describe(rc)}"
                 + (f": {last}" if last else ""))
        return exit_code(rc)

    def _shutdown(self) -> None:
        """Stops every node: SIGTERM in reverse start order, then SIGKILL at the deadline
        (the names of the nodes that needed it go to self._killed)."""
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
        for proc in running:
            try:
                proc.popen.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.say(f"{proc.spec.name} did not stop within {self.grace_s:g} s: SIGKILL")
                proc.popen.kill()
                proc.popen.wait()
                self._killed.add(proc.spec.name)
            self._ended(proc, proc.popen.returncode)
            if proc.rc not in (0, -signal.SIGTERM, EXIT_SIGNAL_BASE + signal.SIGTERM):
                self.say(f"{proc.spec.name} stopped with {describe(proc.rc)}")
