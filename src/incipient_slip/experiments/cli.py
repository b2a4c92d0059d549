"""`slip reproduce NAME` runs one experiment; `slip reproduce --list` lists them.

Every experiment gets the same options (budget, seed, work and docs directories, parallel
graphs, --render-only) plus its own from `add_arguments`. Results go to WORK/results.json (and,
for an experiment with a RESULTS file, to docs/figures/ when docs are written, so that
`--render-only` can rewrite the page without running anything); the rendered blocks go between
their markers in the docs page, or into a fresh page in WORK on the quick budget.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from incipient_slip import cache
from incipient_slip.errors import UsageError
from incipient_slip.paths import docs_dir, runs_dir, written_atomically

from . import EXPERIMENTS, load
from .docs import DocsError, write_blocks
from .settings import Settings
from .timing import SIZE_OPTIONS, duration, list_line, load_times, record_time, time_block

COMMON = ("budget", "seed", "out", "docs", "jobs", "quiet", "render_only")


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options every experiment shares (they fill `Settings`)."""
    budget = parser.add_mutually_exclusive_group()
    budget.add_argument("--quick", dest="budget", action="store_const", const="quick",
                        help="a preview: fewer runs and series, each run as long as the full one's "
                        "(`slip reproduce --list` gives each experiment's time); writes WORK only")
    budget.add_argument("--full", dest="budget", action="store_const", const="full",
                        help="the full budget behind the numbers in docs/ (default)")
    parser.set_defaults(budget="full")
    parser.add_argument("--seed", type=int, help="base seed (default 0; models: 7, the shipped one)")
    parser.add_argument("--out", type=Path, metavar="WORK",
                        help="work directory for results, logs and data (default runs/NAME, "
                        "runs/NAME-quick on the quick budget)")
    parser.add_argument("--docs", type=Path, metavar="DIR",
                        help="docs directory to write into (default docs/ on the full budget, "
                        "none on the quick budget)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                        help="processes or graphs in parallel (default min(2, cores))")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    parser.add_argument("--no-cache", dest="no_cache", action="store_true",
                        help="compute every fit and feature again (runs/cache unused): a check that the "
                        "results come from the code, not from an earlier run")
    parser.add_argument("--render-only", action="store_true",
                        help="rewrite the docs blocks from the saved results; run nothing")


def register(subparsers) -> None:
    """Add `slip reproduce` with one sub-command per experiment."""
    p = subparsers.add_parser(
        "reproduce", help="run one of the paper's experiments and write its results into docs/",
        description="Run one of the paper's experiments on the simulated rig. Each writes "
        "WORK/results.json and the generated blocks of its docs page (between "
        "<!-- BEGIN name --> and <!-- END name --> markers; the prose is hand-written).")
    p.add_argument("--list", action="store_true", help="list the experiments and exit")
    p.set_defaults(func=cmd_reproduce, experiment=None)
    sub = p.add_subparsers(dest="experiment", metavar="EXPERIMENT")
    for name in EXPERIMENTS:
        module = load(name)
        # argparse %-formats help texts: a HELP may say "10 %"
        e = sub.add_parser(name, help=module.HELP.replace("%", "%%"), description=module.__doc__.split("\n\n")[0]
                           + f" Writes docs/{module.DOC}.")
        add_common_arguments(e)
        module.add_arguments(e)
    from .reproduce_all import add_all_parser
    add_all_parser(sub, _run_one)


def _run_one(argv: list[str], log: Path) -> int:
    """`slip reproduce ARGV` in a process of its own, its output going to `log` (for reproduce all)."""
    from .reproduce_all import run_logged
    return run_logged(argv, log)


def settings_from_args(args: argparse.Namespace, module) -> Settings:
    """Return the Settings of a parsed `slip reproduce NAME ...` command line."""
    seed = getattr(module, "SEED", 0) if args.seed is None else args.seed
    if seed < 0:
        raise UsageError(f"--seed must be >= 0, got {seed}")
    if args.jobs < 1:
        raise UsageError(f"--jobs must be >= 1, got {args.jobs}")
    quick = args.budget == "quick"
    work = args.out or runs_dir() / (f"{args.experiment}-quick" if quick else args.experiment)
    # an identified rig's prediction (`validation --params`) is that rig's, never the docs' page
    own_rig = getattr(args, "params", None) is not None
    docs = args.docs if args.docs is not None else (None if quick or own_rig else docs_dir())
    options = {k: v for k, v in vars(args).items() if k not in COMMON + ("func", "command", "experiment", "list")}
    return Settings(budget=args.budget, seed=seed, work=work, docs=docs, jobs=args.jobs,
                    progress=not args.quiet, options=options)


def save_results(results: dict, path: Path) -> None:
    """Write `results` as JSON (numpy values as plain numbers, NaN allowed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with written_atomically(path) as tmp:
        tmp.write_text(json.dumps(results, indent=1, default=_plain, allow_nan=True) + "\n")


def _plain(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return float(value) if isinstance(value, (int, float)) else str(value)


def cmd_reproduce(args) -> int:
    """Run (or only render) one experiment; return the exit code."""
    if args.list or args.experiment is None:
        if args.experiment is None and not args.list:
            raise UsageError("name an experiment (slip reproduce --list shows them)")
        width, times = max(map(len, EXPERIMENTS)), load_times()
        for name in EXPERIMENTS:
            module = load(name)
            print(f"{name:<{width}}  {module.HELP} (docs/{module.DOC}; 2 cores: {list_line(name, times)})")
        print("(times: wall time within `slip reproduce all` on a quiet 2-core machine, which shares data "
              "sets and fits between experiments; alone, or on a busy machine, one takes longer)", file=sys.stderr)
        return 0
    module = load(args.experiment)
    settings = settings_from_args(args, module)
    t0, load0 = time.monotonic(), os.getloadavg()[0]
    if hasattr(module, "check") and not args.render_only:     # bad options: one line, before any banner
        module.check(settings)
    if settings.quick and not args.render_only:     # what runs: the plan's own words where there is one
        what = module.plan(settings).describe() if hasattr(module, "plan") else module.QUICK
        print(f"slip reproduce {args.experiment} --quick: a PREVIEW, not the docs' result: {what}", flush=True)
    if getattr(args, "plan", False):           # an experiment that plans before it runs: print, start nothing
        print(module.plan(settings).describe())
        return 0
    source = settings.results_file(getattr(module, "RESULTS", None))
    if args.render_only:
        if not source.is_file():
            raise UsageError(f"--render-only needs {source}; run `slip reproduce {args.experiment}` first")
        results = json.loads(source.read_text())
    else:
        with (cache.off() if getattr(args, "no_cache", False) else
              cache.use(settings.pick(quick=settings.work / "cache", full=runs_dir() / "cache"))):
            results = module.run(settings)
        save_results(results, settings.work / "results.json")
        if source != settings.work / "results.json":
            save_results(results, source)
    blocks = render_blocks(args.experiment, results, settings.docs)
    page = (settings.docs / module.DOC) if settings.docs is not None else settings.work / Path(module.DOC).name
    try:
        write_blocks(page, blocks, title=f"{module.HELP} (simulated rig)")
    except DocsError as exc:
        raise UsageError(str(exc)) from exc
    elapsed = time.monotonic() - t0
    if not args.render_only and not settings.quick and settings.docs is not None and not _resized(args):
        record_time(args.experiment, "full", elapsed, (load0, os.getloadavg()[0]), settings.docs, settings.jobs)
        write_blocks(page, time_block(args.experiment, module, load_times(settings.docs)))
    print(f"wrote {len(blocks)} blocks into {page}" + ("" if args.render_only else
          f" and results to {settings.work / 'results.json'} in {duration(elapsed)} (simulated rig)"))
    return 0


def render_blocks(name: str, results: dict, docs: Path | None = None) -> dict[str, str]:
    """Return the experiment's blocks and its time block (from the times file in `docs`)."""
    module = load(name)
    return {**module.render(results), **time_block(name, module, load_times(docs))}


def _resized(args: argparse.Namespace) -> bool:
    """True when the command line changes the experiment's sizes (its time is not the budget's)."""
    return any(getattr(args, k, None) not in (None, False) for k in SIZE_OPTIONS)
