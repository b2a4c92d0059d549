"""`slip train`, `slip evaluate`, `slip model regen`, `slip reproduce estimation` and
`slip reproduce accuracy-vs-time`.

Handlers return an exit code; bad input (missing data set, unknown method, unreadable model)
prints one line naming the thing and exits 2, without a traceback.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from incipient_slip.cli import fail

from .features import METHODS

# Shipped models learn the incipient-slip range (windows up to and including the gross-slip
# onset, after_slip="drop"): on the simulated rig ~80 % of the paper-rule windows come after the
# first gross slip, where the contact re-sticks between slides while the label stays 0, and a
# model trained on them answers "about 0" for most stuck contacts - useless for holding s_d = 0.3.
DEFAULT_REGEN = {"series": 100, "seed": 7, "max_train": 3000, "grid_max": 1500, "after_slip": "drop"}


def _user_errors():
    from .dataset import DatasetError
    from .modelfile import ModelFileError
    return (DatasetError, ModelFileError, ValueError, FileNotFoundError)


def register(subparsers, reproduce) -> None:
    """Add this area's commands to the `slip` parser."""
    p = subparsers.add_parser(
        "train", help="train a slip model (SVR by grid search) on a data set",
        description="Train the slip model f of one method on DIR (written by `slip dataset`). "
        "The held-out 10 % of series (the same for every method) is left out and scored.")
    p.add_argument("--method", required=True, choices=METHODS, help="feature method")
    p.add_argument("--data", required=True, type=Path, metavar="DIR", help="data set directory")
    p.add_argument("--kind", default="svr", choices=("svr", "nystroem", "linear"),
                   help="svr: exact kernel SVR on <= --max-train windows; nystroem: RBF Nystroem "
                   "+ ridge on all windows (paper scale); linear: ridge (default svr)")
    p.add_argument("--max-train", type=int, default=6000, help="windows for the exact SVR fit (default 6000)")
    p.add_argument("--grid-max", type=int, default=2000, help="windows for the grid search (default 2000)")
    p.add_argument("--components", type=int, default=1000, help="Nystroem landmarks (default 1000)")
    p.add_argument("--window-s", type=float, default=1.0, help="window T in seconds (default 1.0)")
    p.add_argument("--after-slip", default="zero", choices=("zero", "drop"),
                   help="windows after gross slip: label 0 (paper) or leave out")
    p.add_argument("--label", default="pseudo", choices=("pseudo", "true-ratio"),
                   help="training target: the paper's pseudo-stick ratio (default) or, as an "
                   "EXTENSION (not the paper's method), the simulator's true load_ratio_stick")
    p.add_argument("--quick", action="store_true", help="small grid")
    p.add_argument("--out", type=Path, help="model file (default runs/models/METHOD.npz)")
    p.set_defaults(func=cmd_train)

    p = subparsers.add_parser(
        "evaluate", help="score model files on the held-out series of a data set",
        description="Per-series RMSE and top-10 % RMSE (RMSE over each series' 10 % largest "
        "absolute errors) on the held-out series, per material, paired t-tests vs the first "
        "model with Holm correction.")
    p.add_argument("--data", required=True, type=Path, metavar="DIR",
                   help="data set with injection (for P_AC injection and electrode models)")
    p.add_argument("--data-no-injection", type=Path, metavar="DIR",
                   help="data set without injection (needed by a vibrotactile model)")
    p.add_argument("--model", type=Path, action="append", required=True,
                   help="model file; repeat for several (the first is the t-test reference)")
    p.add_argument("--json", type=Path, help="also write the scores as JSON here")
    p.set_defaults(func=cmd_evaluate)

    p = subparsers.add_parser("model", help="manage the shipped default models")
    sub = p.add_subparsers(dest="model_command", metavar="ACTION", required=True)
    r = sub.add_parser(
        "regen", help="regenerate models/*.npz (all six methods, T = 1.0 s) deterministically",
        description="Simulate the small training data sets (scene paper and no_injection, "
        f"{DEFAULT_REGEN['series']} series each, seed {DEFAULT_REGEN['seed']}), grid-search and fit "
        "an exact SVR per method and write models/METHOD.npz. Same code + same seed -> same files.")
    r.add_argument("--series", type=int, default=DEFAULT_REGEN["series"],
                   help=f"series per data set (default {DEFAULT_REGEN['series']})")
    r.add_argument("--seed", type=int, default=DEFAULT_REGEN["seed"],
                   help=f"data set seed (default {DEFAULT_REGEN['seed']})")
    r.add_argument("--work", type=Path, default=None, help="data directory (default runs/regen)")
    r.add_argument("--out", type=Path, default=None, help="model directory (default models/)")
    r.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    r.set_defaults(func=cmd_regen)

    e = reproduce.add_parser(
        "estimation", help="the paper's estimation study: data -> six models -> evaluation -> docs",
        description="Simulate both data sets, train the six methods (grid-searched SVR), evaluate on "
        "the shared held-out series, write figures and docs/estimation.md. --quick runs a small "
        "version into --out only (used by the tests).")
    e.add_argument("--quick", action="store_true", help="small data set and grid; docs untouched")
    e.add_argument("--series", type=int, help="series per data set (default 500, quick 10)")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--max-train", type=int, help="windows per exact SVR fit (default 8000, quick 1500)")
    e.add_argument("--out", type=Path, help="work directory (default runs/estimation[-quick])")
    e.add_argument("--docs", type=Path, help="docs directory to write (default docs/ unless --quick)")
    e.set_defaults(func=cmd_reproduce)

    a = reproduce.add_parser(
        "accuracy-vs-time", help="what accuracy costs in time: sweeps of T, bins, band, model, data size",
        description="Sweeps window length, spectral binning, band limits, regressor kind and training "
        "size for the injection method; writes docs/accuracy-vs-time.md and its Pareto figure.")
    a.add_argument("--quick", action="store_true", help="few points, small data; docs untouched")
    a.add_argument("--series", type=int, help="series in the injection data set (default 500)")
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--out", type=Path)
    a.add_argument("--docs", type=Path)
    a.set_defaults(func=cmd_tradeoff)


def _run(fn, args) -> int:
    try:
        return fn(args)
    except _user_errors() as exc:
        return fail(str(exc))


def cmd_train(args) -> int:
    return _run(_train, args)


def _train(args) -> int:
    from .evaluation import series_scores
    from .features import feature_spec
    from .modelfile import save_model
    from ..paths import runs_dir
    from .training import held_out_series, load_windows, split_train_test, train_model
    spec = feature_spec(args.method, window_s=args.window_s)
    ws = load_windows(args.data, spec, after_slip=args.after_slip, label=args.label)
    test_series = held_out_series(ws.series_materials())
    train, test = split_train_test(ws, test_series)
    res = train_model(train, args.kind, max_train=args.max_train, grid_max=args.grid_max,
                      n_components=args.components, quick=args.quick)
    sc = series_scores(args.method, test.y, res.model.predict(test.X), test.series, test.material)
    res.model.header.update(test_series=[int(v) for v in test_series], after_slip=args.after_slip,
                            label=args.label, test_rmse_mean=float(sc.rmse.mean()))
    out = args.out or runs_dir() / "models" / f"{args.method}.npz"
    save_model(res.model, out)
    s = sc.summary()
    print(f"{args.method}: {args.kind} {res.report.get('params')} on {res.report.get('n_fit')} of "
          f"{res.report['n_windows']} windows in {res.report['train_s']:.1f} s; held-out "
          f"{s['n_series']} series: RMSE {s['rmse_mean']:.3f} ± {s['rmse_std']:.3f}, "
          f"top-10 % RMSE {s['top10_mean']:.3f}; wrote {out}")
    return 0


def cmd_evaluate(args) -> int:
    return _run(_evaluate, args)


def _evaluate(args) -> int:
    import numpy as np
    from .estimator_core import load_model
    from .evaluation import paired_tests, series_scores
    from .training import held_out_series, load_windows
    scores, names = {}, []
    test_series = None
    for path in args.model:
        model = load_model(path)
        data = args.data
        if model.spec.stream == "pac" and model.spec.injection is False:
            if args.data_no_injection is None:
                raise ValueError(f"{path}: a vibrotactile model needs --data-no-injection")
            data = args.data_no_injection
        ws = load_windows(data, model.spec, after_slip=model.header.get("after_slip", "zero"),
                          label=model.header.get("label", "pseudo"))
        if test_series is None:
            test_series = held_out_series(ws.series_materials())
        te = ws.subset(np.isin(ws.series, test_series))
        name = model.method if model.method not in scores else f"{model.method}:{path.name}"
        scores[name] = series_scores(name, te.y, model.predict(te.X), te.series, te.material)
        names.append(name)
    print(f"held-out series: {len(test_series)}  (RMSE per series; top-10 % = RMSE over each "
          "series' 10 % largest |error|)")
    print(f"{'model':<22}{'RMSE':>16}{'top-10 % RMSE':>18}{'p(RMSE)':>10}{'p(top10)':>10}")
    t1 = paired_tests(scores, names[0], "rmse") if len(names) > 1 else {}
    t2 = paired_tests(scores, names[0], "top10_rmse") if len(names) > 1 else {}
    out = {}
    for n in names:
        s = scores[n].summary()
        out[n] = {**s, "p_rmse_holm": t1.get(n, {}).get("p_holm"), "p_top10_holm": t2.get(n, {}).get("p_holm")}
        p1 = f"{t1[n]['p_holm']:.2g}{t1[n]['stars']}" if n in t1 else "-"
        p2 = f"{t2[n]['p_holm']:.2g}{t2[n]['stars']}" if n in t2 else "-"
        print(f"{n:<22}{s['rmse_mean']:>8.3f} ± {s['rmse_std']:.3f}{s['top10_mean']:>10.3f} ± "
              f"{s['top10_std']:.3f}{p1:>10}{p2:>10}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


def cmd_regen(args) -> int:
    return _run(_regen, args)


def regen_models(series: int, seed: int, work: Path, out: Path, methods=METHODS, progress=True) -> dict:
    """Simulate the regen data sets, train each method, write out/METHOD.npz; return reports."""
    from .modelfile import save_model
    from .pipeline import ensure_dataset, run_study
    dirs = {sc: ensure_dataset(sc, series, seed, work / f"{sc}_{series}_s{seed}", progress=progress)
            for sc in ("paper", "no_injection")}
    study = run_study(dirs, methods=list(methods), max_train=DEFAULT_REGEN["max_train"],
                      grid_max=DEFAULT_REGEN["grid_max"], progress=progress,
                      after_slip=DEFAULT_REGEN["after_slip"])
    written = {}
    for m, r in study.results.items():
        r.model.header["after_slip"] = DEFAULT_REGEN["after_slip"]
        r.model.header["regen"] = {"command": "slip model regen", "series": series, "seed": seed,
                                   "scenes": {"paper": "injection on", "no_injection": "vibrotactile"}}
        r.model.header.pop("versions", None)
        path = save_model(r.model, out / f"{m}.npz")
        written[m] = {"path": str(path), "bytes": path.stat().st_size,
                      "rmse": float(r.scores.rmse.mean()), "top10": float(r.scores.top10_rmse.mean())}
    return written


def _regen(args) -> int:
    from ..paths import model_dir, runs_dir
    t0 = time.perf_counter()
    written = regen_models(args.series, args.seed, args.work or runs_dir() / "regen",
                           args.out or model_dir(), args.methods)
    for m, w in written.items():
        print(f"{m:<13} {w['bytes'] / 1024:7.0f} KiB  held-out RMSE {w['rmse']:.3f}  "
              f"top-10 % {w['top10']:.3f}  {w['path']}")
    print(f"regenerated {len(written)} models in {time.perf_counter() - t0:.0f} s")
    return 0


def cmd_reproduce(args) -> int:
    return _run(_reproduce, args)


def _reproduce(args) -> int:
    from ..paths import repo_root, runs_dir
    from .pipeline import ensure_dataset, load_all_windows, run_study, save_results
    from .report import fig_sorted, label_quality, write_figures, write_markdown
    t0 = time.perf_counter()
    quick = args.quick
    n = args.series or (10 if quick else 500)
    out = args.out or runs_dir() / ("estimation-quick" if quick else "estimation")
    docs = args.docs or (None if quick else repo_root() / "docs")
    steps = 200 if quick else 450    # quick: shorter series (gross slip still happens by ~120)
    data_root = (args.out / "data") if args.out else runs_dir() / "data"   # shared with accuracy-vs-time
    dirs = {sc: ensure_dataset(sc, n, args.seed, data_root / f"{sc}_{n}_s{args.seed}_{steps}", steps=steps)
            for sc in ("paper", "no_injection")}
    max_train = args.max_train or (1000 if quick else 8000)
    grid_max = 600 if quick else 2000
    windows = load_all_windows(dirs)
    study = run_study(dirs, quick=quick, max_train=max_train, grid_max=grid_max, windows=windows)
    incipient = run_study(dirs, quick=quick, max_train=max_train, grid_max=grid_max, after_slip="drop",
                          windows=windows)
    save_results(study, out / "results.json")
    save_results(incipient, out / "results_incipient.json")
    fig_dir = (docs / "figures") if docs else out / "figures"
    figs = write_figures(study, fig_dir)
    figs["sorted_incipient"] = fig_sorted(incipient, fig_dir / "est_sorted_incipient.png")
    md = (docs / "estimation.md") if docs else out / "estimation.md"
    cmd = "slip reproduce estimation" + (" --quick" if quick else "") + (f" --series {n}" if args.series else "")
    write_markdown(study, figs, md, "figures", label_quality(dirs["paper"]), cmd, time.perf_counter() - t0,
                   incipient=incipient)
    for r in study.table():
        p_rmse, p_top10 = (f"{p:.2g}" if p is not None else "ref" for p in (r["p_rmse"], r["p_top10"]))
        print(f"{r['method']:<13} RMSE {r['rmse_mean']:.3f} ± {r['rmse_std']:.3f}  top-10 % "
              f"{r['top10_mean']:.3f}  Holm p vs injection: RMSE {p_rmse}, top-10 % {p_top10}")
    print(f"wrote {md} in {time.perf_counter() - t0:.0f} s (simulated rig)")
    return 0


def cmd_tradeoff(args) -> int:
    return _run(_tradeoff, args)


def _tradeoff(args) -> int:
    from .tradeoff import run_tradeoff_cli
    return run_tradeoff_cli(args)
