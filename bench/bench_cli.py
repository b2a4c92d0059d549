"""`slip` start-up: wall time of `slip topic --help` and `slip topic list` beside `slip --help`
(which loads every command's modules, as every `slip` command did before they loaded lazily).

Each command runs RUNS times in fresh interpreters, the commands in turn (so machine noise hits
all alike); median (min..max) of the wall times. `slip topic list --duration 0.05` listens to an
empty graph for 50 ms, so its start-up is its time less those 50 ms (printed beside it). Then the
`python -X importtime` evidence for `slip topic --help`: modules imported, whether scipy is among
them, and the imports that take longest (cumulative us, self included).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

SLIP = [sys.executable, "-m", "incipient_slip.cli"]
LISTEN_S = 0.05
COMMANDS = {
    "slip topic --help": ["topic", "--help"],
    f"slip topic list --duration {LISTEN_S:g}": ["topic", "list", "--duration", f"{LISTEN_S:g}"],
    "slip --help (every module)": ["--help"],
}


def _wall(argv: list[str], env: dict) -> float:
    t0 = time.perf_counter()
    subprocess.run(SLIP + argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t0


def _importtime(argv: list[str], env: dict) -> list[tuple[int, str]]:
    err = subprocess.run([sys.executable, "-X", "importtime", *SLIP[1:], *argv], env=env,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True).stderr
    rows = []
    for line in err.splitlines():
        if line.startswith("import time:") and "|" in line and "cumulative" not in line:
            _, cumulative, name = line.split("|")
            rows.append((int(cumulative), name.rstrip()))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=9)
    args = ap.parse_args()
    env = dict(os.environ, SLIP_GRAPH_DIR=tempfile.mkdtemp(prefix="sbc", dir="/tmp"))
    print(f"slip start-up, {args.runs} runs per command in turn, {os.cpu_count()} cores, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())} at the start")
    for argv in COMMANDS.values():      # warm the file cache once
        _wall(argv, env)
    times = {name: [] for name in COMMANDS}
    for r in range(args.runs):
        names = list(COMMANDS)
        for name in names[r % len(names):] + names[:r % len(names)]:
            times[name].append(_wall(COMMANDS[name], env))
    for name, t in times.items():
        t = np.array(t)
        extra = f"   (start-up {np.median(t) - LISTEN_S:.3f} s)" if "list" in name else ""
        print(f"  {name:34s} median {np.median(t):.3f} s  ({t.min():.3f}..{t.max():.3f}){extra}")
    lazy, full = np.median(times["slip topic --help"]), np.median(times["slip --help (every module)"])
    print(f"slip topic --help / slip --help = {lazy / full:.2f}")
    rows = _importtime(["topic", "--help"], env)
    names = {n.strip() for _, n in rows}
    print(f"importtime, slip topic --help: {len(names)} modules, scipy "
          f"{'imported' if any(n.split('.')[0] == 'scipy' for n in names) else 'not imported'}; "
          "longest (cumulative us):")
    top = [(c, n) for c, n in rows if n.startswith(" ") and not n.startswith("   ")]   # top two levels
    for cumulative, name in sorted(top, reverse=True)[:10]:
        print(f"  {cumulative:8d}  {name}")
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
