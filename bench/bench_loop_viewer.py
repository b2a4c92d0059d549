"""What a stalled viewer costs the closed loop: `bench_loop.py` with and without the viewer
bridge, alternated in one sitting, and the ratio of their p99s.

    make bench-loop-viewer        # or: python bench/bench_loop_viewer.py [--rounds 5] [--periods 600]

Each round runs every variant once, in turn (the order rotates each round so that no variant
always follows the same one): `none` (no bridge), `stalled` (the bridge at its default priority
and a Foxglove client that subscribes to every channel and never reads), and any of
`--variants` (e.g. `stalled:idle`, the bridge at SCHED_IDLE; `attached`, the bridge and no
client; `stalled@main`, every process of the run on the package at git revision `main`, to
compare a change in the same sitting). Printed per variant: each run's p99 and median latency and the bridge's CPU per
period, the median of the p99s, and its ratio to `none` (issue goal: <= 1.1 for `stalled`).
The machine's load average is printed beside: other users' jobs set the p99 on a shared
machine, so only a sitting at low load (< 2 on 2 cores) says much about a 10 % goal.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

BENCH_LOOP = Path(__file__).with_name("bench_loop.py")
GOAL_RATIO = 1.1
_NUMBERS = {
    "median": re.compile(r"GripCommand received: median ([0-9.]+) ms"),
    "p99": re.compile(r"loop p99 ms = ([0-9.]+)"),
    "bridge_ms": re.compile(r"foxglove_bridge ([0-9.]+) ms"),
}


def parse_variant(variant: str) -> tuple[str, str, str]:
    """(viewer, priority, rev) of "VIEWER[:PRIORITY][@REV]"; "" for what is not given."""
    variant, _, rev = variant.partition("@")
    viewer, _, priority = variant.partition(":")
    return viewer, priority, rev


def source_tree(rev: str, directory: Path) -> Path:
    """`directory`/REV, holding what a graph's nodes read at git revision `rev`: the package and
    the launch files, scenes and models it finds beside it (paths.repo_root)."""
    root = directory / rev.replace("/", "_")
    if not root.exists():
        root.mkdir(parents=True)
        archive = subprocess.run(["git", "-C", str(BENCH_LOOP.parent.parent), "archive", rev,
                                  "src", "launch", "scenes", "models"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(root)], input=archive, check=True)
        found = subprocess.run([sys.executable, "-c", "import incipient_slip; print(incipient_slip.__file__)"],
                               env=dict(os.environ, PYTHONPATH=str(root / "src")), check=True,
                               capture_output=True, text=True).stdout.strip()
        if not Path(found).is_relative_to(root):
            raise SystemExit(f"bench-loop-viewer: PYTHONPATH={root / 'src'} imports {found}")
    return root


def run_variant(variant: str, periods: int, trees: Path) -> dict:
    """One bench_loop.py run of `variant` ("none", "stalled", "attached", each ":PRIORITY", each
    "@REV": the package at git revision REV for every process of the run, the bench's own too)."""
    viewer, priority, rev = parse_variant(variant)
    cmd = [sys.executable, str(BENCH_LOOP), "--periods", str(periods), "--viewer", viewer]
    if priority:
        cmd += ["--viewer-priority", priority]
    env = dict(os.environ, PYTHONPATH=str(source_tree(rev, trees) / "src")) if rev else None
    load = os.getloadavg()[0]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=900, env=env)
    if out.returncode != 0:
        raise SystemExit(f"bench-loop-viewer: {variant} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    got = {"load": load}
    for key, pattern in _NUMBERS.items():
        m = pattern.search(out.stdout)
        got[key] = float(m.group(1)) if m else float("nan")
    return got


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="runs of each variant (alternated)")
    ap.add_argument("--periods", type=int, default=600, help="lock-step periods per run")
    ap.add_argument("--variants", nargs="*", default=[],
                    help="more variants beside none and stalled: stalled:idle, stalled:normal, attached, ...")
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.periods < 1:
        ap.error("--rounds and --periods must be >= 1")
    variants = ["none", "stalled", *[v for v in args.variants if v not in ("none", "stalled")]]
    for v in variants:
        viewer, priority, _ = parse_variant(v)
        if viewer not in ("none", "stalled", "attached") or priority not in ("", "idle", "low", "normal"):
            ap.error(f"unknown variant {v!r}: VIEWER[:PRIORITY][@REV], VIEWER none|stalled|attached, "
                     "PRIORITY idle|low|normal, REV a git revision")
    runs: dict[str, list[dict]] = {v: [] for v in variants}
    trees = Path(tempfile.mkdtemp(prefix="bench-loop-viewer-"))
    try:
        for r in range(args.rounds):
            order = variants[r % len(variants):] + variants[:r % len(variants)]
            for v in order:
                runs[v].append(run_variant(v, args.periods, trees))
                last = runs[v][-1]
                print(f"  round {r + 1}/{args.rounds} {v:16s} p99 {last['p99']:7.3f} ms  median "
                      f"{last['median']:.3f} ms  load {last['load']:.1f}", flush=True)
    finally:
        shutil.rmtree(trees, ignore_errors=True)
    base = float(np.median([x["p99"] for x in runs["none"]]))
    loads = [x["load"] for rs in runs.values() for x in rs]
    print(f"\n{args.rounds} alternated rounds of {args.periods} lock-step periods, load average "
          f"{min(loads):.1f}-{max(loads):.1f}, {os.cpu_count()} cores")
    print("| variant | p99 ms per run | median of p99 | ratio | median latency | bridge CPU per period |")
    print("|---|---|---|---|---|---|")
    for v, rs in runs.items():
        p99 = [x["p99"] for x in rs]
        bridge = [x["bridge_ms"] for x in rs if np.isfinite(x["bridge_ms"])]
        cpu = f"{np.median(bridge):.2f} ms ({min(bridge):.2f}-{max(bridge):.2f})" if bridge else "-"
        print(f"| {v} | {', '.join(f'{x:.2f}' for x in p99)} | {np.median(p99):.2f} | "
              f"{np.median(p99) / base:.2f}x | {np.median([x['median'] for x in rs]):.3f} ms | {cpu} |")
    ratio = float(np.median([x["p99"] for x in runs["stalled"]])) / base
    print(f"stalled/none p99 ratio = {ratio:.2f} (goal <= {GOAL_RATIO}: {'met' if ratio <= GOAL_RATIO else 'NOT met'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
