"""The emulated launch beside CPU hogs: how many of N runs end without a fault.

    python bench/bench_emulated_load.py [--runs 10] [--hogs 2] [--steps 20] [--logs DIR]
    make bench-emulated-load            (the same, defaults)

Starts `--hogs` busy loops (`python -c 'while True: pass'`, stopped at the end whatever happens),
then runs `launch stabilize.yaml rig:=emulated steps:=N` `--runs` times one after another, each in
its own graph directory with its own emulator directory, UR address and NatNet ports. A run
passes when the launch exits 0 (success) or 1 (the paper's failure: a result of the experiment)
and wrote its summary; anything else (a fault, 3, or a node's own exit code, or no exit within
300 s) fails it. Prints one line per run (exit code, outcome, wall time, load average) with the
first warning lines of a failed run, then the pass count. The load average is the machine's
(shared: other people's jobs count too); say it with the numbers.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from incipient_slip.devices.natnet_emulator import free_udp_port_pair  # noqa: E402

HOG = "while True: pass"
# stderr lines that say why a run failed (the first few are printed)
SIGNS = ("warn", "error", "fault", "exit", "timeout", "timed out", "gap", "silent", "no reply", "Traceback")


def start_hogs(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(n)]


def stop_hogs(hogs: list[subprocess.Popen]) -> None:
    for hog in hogs:
        hog.kill()
    for hog in hogs:
        hog.wait()


def one_run(steps: int, seed: int, work: Path, timeout_s: float) -> tuple[int | None, dict | None, str, float]:
    """Runs one emulated launch; returns (exit code or None on timeout, summary, stderr, wall s)."""
    graph = Path(tempfile.mkdtemp(prefix="emu-load-", dir="/tmp"))
    env = dict(os.environ, SLIP_GRAPH_DIR=str(graph), PYTHONUNBUFFERED="1")
    summary = work / "summary.json"
    args = ["stabilize.yaml", "rig:=emulated", f"steps:={steps}", f"seed:={seed}", "quiet:=true",
            f"summary:={summary}", f"emu_dir:={work / 'emu'}", f"emu_natnet_port:={free_udp_port_pair()}",
            f"emu_address:=127.0.{random.randint(1, 254)}.{random.randint(2, 254)}"]
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "incipient_slip.graph.launch", *args], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT / "launch",
                            start_new_session=True)
    try:
        _, err = proc.communicate(timeout=timeout_s)
        code = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 2)          # SIGINT: the launcher stops its nodes
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            _, err = proc.communicate()
        code = None
    finally:
        shutil.rmtree(graph, ignore_errors=True)
    wall = time.monotonic() - t0
    result = json.loads(summary.read_text()) if summary.exists() else None
    return code, result, err, wall


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10, help="launches, one after another (default 10)")
    parser.add_argument("--hogs", type=int, default=2, help="busy-loop CPU hogs beside them (default 2)")
    parser.add_argument("--steps", type=int, default=20, help="periods per run (default 20)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=300.0, help="a run that takes longer fails (s)")
    parser.add_argument("--logs", default="", help="write each run's stderr to DIR/run<i>.log")
    args = parser.parse_args(argv)
    logs = Path(args.logs) if args.logs else None
    if logs:
        logs.mkdir(parents=True, exist_ok=True)
    # SIGTERM/SIGHUP end the runs like Ctrl-C, so the hogs are always stopped
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.default_int_handler)
    hogs = start_hogs(args.hogs)
    passed = 0
    try:
        print(f"{args.runs} runs of launch stabilize.yaml rig:=emulated steps:={args.steps} seed:={args.seed} "
              f"beside {args.hogs} CPU hog(s) (pids {[h.pid for h in hogs]}); load {os.getloadavg()[0]:.1f}",
              flush=True)
        with tempfile.TemporaryDirectory(prefix="emu-load-") as tmp:
            for i in range(args.runs):
                work = Path(tmp) / f"run{i}"
                work.mkdir()
                code, result, err, wall = one_run(args.steps, args.seed, work, args.timeout)
                ok = code in (0, 1) and result is not None
                passed += ok
                if logs:
                    (logs / f"run{i}.log").write_text(err)
                outcome = f"{result['outcome']} after {result['steps']} steps ({result['detail']})" if result else "no summary"
                print(f"run {i + 1:2d}: {'pass' if ok else 'FAIL'}  exit {code}  {outcome}  "
                      f"{wall:5.1f} s  load {os.getloadavg()[0]:.1f}", flush=True)
                if not ok:
                    lines = [ln for ln in err.splitlines() if any(s in ln for s in SIGNS)]
                    for ln in lines[:12]:
                        print(f"      {ln[:220]}")
    finally:
        stop_hogs(hogs)
    print(f"passed {passed} of {args.runs} beside {args.hogs} CPU hog(s); load now {os.getloadavg()[0]:.1f} "
          f"(1-minute average, shared machine)")
    return 0 if passed == args.runs else 1


if __name__ == "__main__":
    raise SystemExit(main())
