"""`slip train` and `slip evaluate`: one model on a data set, and model files scored.

Handlers return an exit code; bad input (missing data set, unknown method, unreadable model)
raises UsageError, which `slip` prints as one line naming the thing (exit 2, no traceback).
The paper's studies built on these are experiments (`slip reproduce estimation`, `models`).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from incipient_slip.errors import UsageError

from .features import METHODS
from .labels import LABELS, LabelRule, rule_of_header

def _user_errors():
    from .dataset import DatasetError
    from .modelfile import ModelFileError
    return (DatasetError, ModelFileError, ValueError, FileNotFoundError)


def register(subparsers) -> None:
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
                   help="windows after the first gross slip: zero (default) keeps them (the pseudo label "
                   "gives them 0, the paper's rule; measured-ratio their own ratio), drop leaves them out")
    p.add_argument("--label", default="pseudo", choices=LABELS,
                   help="training target: pseudo, the paper's pseudo-stick ratio (default; F_T^slip "
                   "of the first onset); measured-ratio, 1 - F_T / (mu F_N) with mu the largest "
                   "load ratio the series held, consistent with F_N redrawn every period "
                   "(docs/estimation.md); true-ratio, an EXTENSION (not the paper's method): the "
                   "simulator's true load_ratio_stick")
    lag = p.add_mutually_exclusive_group()
    lag.add_argument("--friction-lag-s", type=float, metavar="S",
                     help="measured-ratio: the friction limit's lag behind F_N in s (default 0: it "
                     "follows F_N at once)")
    lag.add_argument("--params", type=Path, metavar="OVERLAY",
                     help="measured-ratio: take the friction lag an identified rig measured "
                     "(stick_slip.friction_limit_lag_s of launch identify.yaml's overlay)")
    p.add_argument("--quick", action="store_true", help="small grid")
    p.add_argument("--workers", type=int, help="run the grid search's candidate fits as dask tasks on a "
                   "LocalCluster of this many processes (default: in this process)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the grid search's candidate fits "
                   "as dask tasks on this running scheduler")
    p.add_argument("--out", type=Path, help="model file (default runs/models/METHOD.npz)")
    p.add_argument("--force", action="store_true", help="replace an existing model file")
    p.set_defaults(func=cmd_train)

    p = subparsers.add_parser(
        "evaluate", help="score model files on the held-out series of a data set",
        description="Per-series RMSE and top-10 % RMSE (RMSE over each series' 10 % largest "
        "absolute errors) on the held-out series (per material in --json), paired t-tests vs the "
        "first model with Holm correction. Held-out series the model was trained on are refused "
        "(data sets of one seed share their series).")
    p.add_argument("--data", required=True, type=Path, metavar="DIR",
                   help="data set with injection (for P_AC injection and electrode models)")
    p.add_argument("--data-no-injection", type=Path, metavar="DIR",
                   help="data set without injection (needed by a vibrotactile model)")
    p.add_argument("--model", type=Path, action="append", required=True,
                   help="model file; repeat for several (the first is the t-test reference)")
    p.add_argument("--json", type=Path, help="also write the scores as JSON here")
    p.add_argument("--allow-train-overlap", action="store_true",
                   help="score a model even on held-out series it was trained on (refused by default: "
                   "data sets of one seed share their series; a warning says the scores flatter it)")
    p.set_defaults(func=cmd_evaluate)


def _run(fn, args) -> int:
    try:
        return fn(args)
    except _user_errors() as exc:
        raise UsageError(str(exc)) from exc


def cmd_train(args) -> int:
    return _run(_train, args)


def _train(args) -> int:
    from .evaluation import series_scores
    from .features import feature_spec
    from .modelfile import save_model
    from ..paths import runs_dir
    from .training import held_out_series, load_windows, split_train_test, train_model
    from ..cluster import check_scheduler, check_workers, open_client
    check_scheduler(args.scheduler)
    if args.workers is not None:
        check_workers(args.workers)
    from .dataset import read_meta
    read_meta(args.data)                      # a wrong --data is named first
    out = args.out or runs_dir() / "models" / f"{args.method}.npz"
    if out.is_dir():
        raise ValueError(f"--out {out} is a directory; name the model file, e.g. {out / (args.method + '.npz')}")
    if out.exists() and not args.force:       # before the work, not after: no model is lost
        raise ValueError(f"{out} exists (a model trained before); --out elsewhere, or --force to replace it")
    rule = _label_rule(args)
    spec = feature_spec(args.method, window_s=args.window_s)
    progress = sys.stderr.isatty()            # bars on a terminal, not in a log or a pipe
    ws = load_windows(args.data, spec, after_slip=args.after_slip, label=rule, progress=progress)
    test_series = held_out_series(ws.series_materials())
    train, test = split_train_test(ws, test_series)
    kw = dict(max_train=args.max_train, grid_max=args.grid_max, n_components=args.components, quick=args.quick,
              progress=progress)
    if args.workers or args.scheduler:
        with open_client(args.scheduler, args.workers) as client:
            res = train_model(train, args.kind, client=client, **kw)
    else:
        res = train_model(train, args.kind, **kw)
    sc = series_scores(args.method, test.y, res.model.predict(test.X), test.series, test.material)
    res.model.header.update(test_series=[int(v) for v in test_series], after_slip=args.after_slip,
                            label=rule.name, friction_lag_s=rule.friction_lag_s, test_rmse_mean=float(sc.rmse.mean()))
    save_model(res.model, out)
    s = sc.summary()
    print(f"{args.method}: {args.kind} {res.report.get('params')} on {res.report.get('n_fit')} of "
          f"{res.report['n_windows']} windows in {res.report['train_s']:.1f} s; held-out "
          f"{s['n_series']} series: RMSE {s['rmse_mean']:.3f} ± {s['rmse_std']:.3f}, "
          f"top-10 % RMSE {s['top10_mean']:.3f} (label {rule}); wrote {out}")
    return 0


def _label_rule(args) -> LabelRule:
    """The label of `slip train`: --label, with the friction lag of --friction-lag-s or --params."""
    lag = args.friction_lag_s
    if args.params is not None:
        lag = friction_lag_of_overlay(args.params)
    if lag is not None and args.label != "measured-ratio":
        raise ValueError(f"--friction-lag-s and --params are inputs of --label measured-ratio, not {args.label}")
    return LabelRule(args.label, float(lag or 0.0))


def friction_lag_of_overlay(path: Path) -> float:
    """Return stick_slip.friction_limit_lag_s of an identified rig's params overlay (seconds)."""
    import math
    import yaml
    try:
        doc = yaml.safe_load(Path(path).read_text())
    except OSError as exc:
        raise ValueError(f"--params {path}: cannot read the overlay ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        raise ValueError(f"--params {path}: not YAML" + (f" (line {where.line + 1})" if where else "")) from None
    section = doc.get("stick_slip") if isinstance(doc, dict) else None
    entry = section.get("friction_limit_lag_s") if isinstance(section, dict) else None
    if entry is None:
        raise ValueError(f"--params {path}: no stick_slip.friction_limit_lag_s (the lag protocol of "
                         "launch identify.yaml measures it); give --friction-lag-s instead")
    value, unit = (entry.get("value"), entry.get("unit", "s")) if isinstance(entry, dict) else (entry, "s")
    if unit != "s":
        raise ValueError(f"--params {path}: stick_slip.friction_limit_lag_s is in {unit!r}; the overlay's unit is s")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"--params {path}: stick_slip.friction_limit_lag_s = {value!r} is not a finite number of seconds")
    return float(value)


def cmd_evaluate(args) -> int:
    return _run(_evaluate, args)


def _check_not_trained_on(path, model, ws, test_series, data, allow: bool) -> None:
    """A held-out series the model was trained on scores it on what it has seen: data sets of one
    seed share their series (dataset.series_key), so the split alone cannot tell."""
    trained = set(model.header.get("train_series_keys") or ())
    if not trained:
        print(f"note: {path} does not list its training series (made before they were recorded): "
              f"whether {data} holds them is not checked", file=sys.stderr)
        return
    seen = sorted(int(i) for i in test_series if ws.series_keys.get(int(i)) in trained)
    if not seen:
        return
    what = (f"{path}: {len(seen)} of the {len(test_series)} held-out series of {data} (e.g. "
            f"series {seen[0]}) are series this model was trained on (the same physics, material "
            f"and seed: data sets of one seed share their series)")
    if not allow:
        raise ValueError(f"{what}; evaluate on a data set of another seed (slip dataset --seed N), "
                         "or pass --allow-train-overlap to score it anyway")
    print(f"WARNING: {what}; scored anyway (--allow-train-overlap): these scores flatter it",
          file=sys.stderr)


def _evaluate(args) -> int:
    import numpy as np
    from .estimator_core import load_model
    from .evaluation import paired_tests, series_scores
    from .training import held_out_series, load_windows
    scores, names, labels = {}, [], {}
    test_series = None
    for path in args.model:
        model = load_model(path)
        data = args.data
        if model.spec.stream == "pac" and model.spec.injection is False:
            if args.data_no_injection is None:
                raise ValueError(f"{path}: a vibrotactile model needs --data-no-injection")
            data = args.data_no_injection
        ws = load_windows(data, model.spec, after_slip=model.header.get("after_slip", "zero"),
                          label=rule_of_header(model.header), progress=sys.stderr.isatty())
        if test_series is None:
            test_series = held_out_series(ws.series_materials())
        _check_not_trained_on(path, model, ws, test_series, data, args.allow_train_overlap)
        te = ws.subset(np.isin(ws.series, test_series))
        name = model.method if model.method not in scores else f"{model.method}:{path.name}"
        scores[name] = series_scores(name, te.y, model.predict(te.X), te.series, te.material)
        names.append(name)
        labels[name] = str(rule_of_header(model.header))
    print(f"held-out series: {len(test_series)}  (RMSE per series against each model's own label; "
          "top-10 % = RMSE over each series' 10 % largest |error|)")
    if len(set(labels.values())) > 1:
        print("WARNING: the models were trained on different labels (" + "; ".join(f"{n}: {v}" for n, v in labels.items())
              + "): each is scored against its own, so the RMSEs and p-values compare different targets",
              file=sys.stderr)
    width = max(22, *(len(n) + 2 for n in names))
    print(f"{'model':<{width}}{'RMSE':>16}{'top-10 % RMSE':>18}{'p(RMSE)':>10}{'p(top10)':>10}  label")
    t1 = paired_tests(scores, names[0], "rmse") if len(names) > 1 else {}
    t2 = paired_tests(scores, names[0], "top10_rmse") if len(names) > 1 else {}
    out = {}
    for n in names:
        s = scores[n].summary()
        out[n] = {**s, "p_rmse_holm": t1.get(n, {}).get("p_holm"), "p_top10_holm": t2.get(n, {}).get("p_holm")}
        p1 = f"{t1[n]['p_holm']:.2g}{t1[n]['stars']}" if n in t1 else "-"
        p2 = f"{t2[n]['p_holm']:.2g}{t2[n]['stars']}" if n in t2 else "-"
        out[n]["label"] = labels[n]
        print(f"{n:<{width}}{s['rmse_mean']:>8.3f} ± {s['rmse_std']:.3f}{s['top10_mean']:>10.3f} ± "
              f"{s['top10_std']:.3f}{p1:>10}{p2:>10}  {labels[n]}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0
