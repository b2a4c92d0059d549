"""`slip reproduce all`: every experiment, in dependency order, with one progress display.

Order: calibration (reports the fit; it never rewrites the params file here), models (the shipped
models/*.npz, which the Table and the diagnosis load), estimation, accuracy-vs-time, stabilization,
diagnosis, validation. The experiments share what they can: data sets are reused by
`experiments.datasets` (meta.json's scene, size, seed and physics fingerprint: a hash of the
scene, its params and the simulator's code), so estimation and accuracy vs time read one
500-series set and models and diagnosis one 100-series set; SVR fits, feature windows and
validation refits go through the content-hashed cache (`incipient_slip.cache`, runs/cache), so a
rerun of an unchanged experiment fits and refits nothing it has done before.

Each experiment's own output goes to WORK/NAME.log; the terminal shows one line per experiment
and, at the end, the table of what ran, how long it took (with the load average) and where it
wrote. Wall times go to docs/figures/reproduce_times.json (`experiments.timing`), from which
`slip reproduce --list` and every page's time block are rendered.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from incipient_slip.errors import UsageError
from incipient_slip.paths import docs_dir, runs_dir

from . import EXPERIMENTS, load
from .docs import write_blocks
from .timing import duration, load_times, record_time, time_block

# the order in which they run: models before stabilization and diagnosis, which load the shipped models
ORDER = ("calibration", "models", "estimation", "accuracy-vs-time", "stabilization", "diagnosis", "validation",
         "identification")


def add_all_parser(sub, run_one) -> None:
    """Add `slip reproduce all`; `run_one(argv, log)` runs one `slip reproduce NAME ...` in this
    process with its output to `log` and returns its exit code (experiments.cli's)."""
    p = sub.add_parser("all", help="every experiment in dependency order, one progress display, a final table",
                       description=__doc__.split("\n\n")[0])
    budget = p.add_mutually_exclusive_group()
    budget.add_argument("--quick", dest="budget", action="store_const", const="quick",
                        help="every experiment's quick preview (WORK only: no tracked file changes unless --record-quick-times)")
    budget.add_argument("--full", dest="budget", action="store_const", const="full",
                        help="the full budget behind docs/ (default)")
    p.set_defaults(budget="full", func=cmd_all, run_one=run_one)
    p.add_argument("--only", nargs="+", choices=ORDER, metavar="NAME",
                   help=f"run only these (in the order {', '.join(ORDER)})")
    p.add_argument("--joint", action="store_true", help="validation also runs the joint uncertainty set")
    p.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                   help="processes, graphs or dask workers in parallel (default min(2, cores))")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="where the logs and each experiment's WORK go (default runs/all, runs/all-quick)")
    p.add_argument("--docs", type=Path, metavar="DIR", help="docs directory (default docs/)")
    p.add_argument("--render-times", action="store_true",
                   help="only rewrite every page's time block from docs/figures/reproduce_times.json; run nothing")
    p.add_argument("--record-quick-times", dest="times", action="store_true",
                   help="with --quick: record the quick wall times in docs/figures/reproduce_times.json and the "
                   "pages' time lines (the times `slip reproduce --list` shows); without it --quick changes no "
                   "tracked file. A full run always records its own, as `slip reproduce NAME` does")


def _say(text: str) -> None:
    """Print one progress line."""
    print(text, flush=True)


def plan(only=None) -> list[str]:
    """Return the experiments to run, in ORDER (every experiment of EXPERIMENTS exactly once)."""
    assert sorted(ORDER) == sorted(EXPERIMENTS), "ORDER must list every experiment"
    return [n for n in ORDER if not only or n in only]


def cmd_all(args) -> int:
    """Run the plan; print one line per experiment and the final table; return 0 if all succeeded."""
    if args.jobs < 1:
        raise UsageError(f"--jobs must be >= 1, got {args.jobs}")
    docs = args.docs or docs_dir()
    if args.render_times:
        for name in EXPERIMENTS:
            module = load(name)
            write_blocks(docs / module.DOC, time_block(name, module, load_times(docs)))
        print(f"rewrote the time blocks of {len(EXPERIMENTS)} experiments in {docs}")
        return 0
    quick = args.budget == "quick"
    out = args.out or runs_dir() / ("all-quick" if quick else "all")
    out.mkdir(parents=True, exist_ok=True)
    names = plan(args.only)
    preview = ((" --quick (PREVIEWS: of docs/ only the time lines change)" if args.times else
                " --quick (PREVIEWS into runs/; docs/ unchanged)") if quick else "")
    _say(f"slip reproduce all{preview}: {len(names)} "
        f"experiments, {args.jobs} jobs, logs in {out}/ (simulated rig)")
    rows, t_all = [], time.monotonic()
    for i, name in enumerate(names, 1):
        argv = ["reproduce", name, "--quiet", "--jobs", str(args.jobs), "--out", str(out / name)]
        argv += ["--quick"] if quick else ["--docs", str(docs)]
        if name == "validation" and args.joint:     # the joint set and the one-at-a-time points
            argv += ["--joint", "--points", *load(name).POINTS]
        log = out / f"{name}.log"
        _say(f"[{i}/{len(names)}] {name:<16} running (log {log}) ...")
        load0, t0 = os.getloadavg()[0], time.monotonic()
        rc = args.run_one(argv, log)
        seconds, loads = time.monotonic() - t0, (load0, os.getloadavg()[0])
        module = load(name)
        results = f", {docs / 'figures' / module.RESULTS}" if getattr(module, "RESULTS", None) else ""
        rows.append((name, rc, seconds, loads, str(out / name) if quick else f"{docs / module.DOC}{results}"))
        if rc == 0 and quick and args.times:      # (a full run records its own time: experiments.cli)
            record_time(name, "quick", seconds, loads, docs, args.jobs)
            if (docs / module.DOC).is_file():
                write_blocks(docs / module.DOC, time_block(name, module, load_times(docs)))
        _say(f"[{i}/{len(names)}] {name:<16} {'done' if rc == 0 else f'FAILED (exit {rc})'} in "
            f"{duration(seconds)} (load {max(loads):.1f})")
    _say(table(rows, time.monotonic() - t_all))
    return 0 if all(r[1] == 0 for r in rows) else 1


def run_logged(argv: list[str], log: Path) -> int:
    """Run one `slip reproduce ...` in a fresh process with its output (and its children's) going
    to `log`; return its exit code.

    A fresh process each: run in this one, after calibration, models, estimation and accuracy vs
    time (a 4 GB process with their thread pools), the stabilization's node processes forked from
    it lost the first grip command of 5-8 of the Table's 80 lock-step runs (a silent graph for 30 s,
    a "fault") in two fresh-clone runs, while the same Table run alone faulted in none of 400 runs."""
    sys.stdout.flush()
    sys.stderr.flush()
    with open(log, "w", buffering=1) as f:
        return subprocess.run([sys.executable, "-m", "incipient_slip.cli", *argv], stdin=subprocess.DEVNULL,
                              stdout=f, stderr=subprocess.STDOUT).returncode


def table(rows, total_s: float) -> str:
    """Return the final table: experiment, result, wall time, load average, where it wrote."""
    lines = ["", "| experiment | result | wall time | load average | wrote |", "|---|---|---|---|---|"]
    for name, rc, seconds, load, wrote in rows:
        lines.append(f"| {name} | {'ok' if rc == 0 else f'exit {rc}'} | {duration(seconds)} | "
                     f"{load[0]:.1f}..{load[1]:.1f} | {wrote} |")
    lines.append(f"\ntotal {duration(total_s)} on {os.cpu_count()} cores (simulated rig)")
    return "\n".join(lines)
