"""The shipped default models (models/METHOD.npz), regenerated deterministically.

Simulates the small training data sets (scenes paper and no_injection, 100 series each, seed 7),
grid-searches and fits an exact SVR per method on the incipient-slip range and writes
models/METHOD.npz. Same code + same seed -> same files. The quick budget writes into WORK/models.
"""
from __future__ import annotations

import time
from pathlib import Path

from incipient_slip.models.features import METHODS

from .plots import METHOD_LABELS
from .settings import Settings

NAME = "models"
HELP = "regenerate the shipped default models (all six methods, T = 1.0 s)"
DOC = "estimation.md"
QUICK = ("10 series per scene (full 100), SVR on at most 500 windows (full 3000) with a "
         "3-candidate grid; writes WORK/models, never models/")
SEED = 7
# Shipped models learn the incipient-slip range (windows up to and including the gross-slip
# onset, after_slip="drop"): on the simulated rig ~80 % of the paper-rule windows come after the
# first gross slip, where the contact re-sticks between slides while the label stays 0, and a
# model trained on them answers "about 0" for most stuck contacts - useless for holding s_d = 0.3.
AFTER_SLIP = "drop"
# every label ships (models/<method>.npz: the paper's; models/<label>/<method>.npz: the others), each
# with its windows: the measured-ratio label gives a re-stuck contact its own ratio, so it keeps them
LABEL_VARIANTS = {"pseudo": AFTER_SLIP, "measured-ratio": "zero"}


def add_arguments(parser) -> None:
    """Add the data-set size, the methods and where the model files go."""
    parser.add_argument("--series", type=int, help="series per data set (quick 10, full 100)")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--models-out", type=Path, metavar="DIR",
                        help="where the model files go (default models/; WORK/models on the quick budget)")
    parser.add_argument("--data", type=Path, metavar="DIR", help="data-set cache (default runs/data)")


def budget(settings: Settings) -> dict:
    """Return the sizes of the regeneration on this budget."""
    return {"series": settings.option("series", settings.pick(quick=10, full=100)),
            "steps": 450,
            "max_train": settings.pick(quick=500, full=3000),
            "grid_max": settings.pick(quick=300, full=1500)}


def run(settings: Settings) -> dict:
    """Train each method and write its model file; return what was written."""
    from incipient_slip.models.pipeline import DATASET_OF_METHOD, load_all_windows, run_study
    from incipient_slip.models.training import relabel, series_targets
    from incipient_slip.paths import model_dir

    from .datasets import study_datasets
    t0 = time.perf_counter()
    b = budget(settings)
    out = Path(settings.option("models_out", settings.pick(quick=settings.work / "models", full=model_dir())))
    dirs = study_datasets(settings, b["series"], b["steps"])
    methods = list(settings.option("methods", METHODS))
    # the features once; each label's windows are the same ones with its own target
    windows = load_all_windows(dirs, methods, progress=settings.progress, workers=settings.jobs)
    targets = {scene: series_targets(d, list(LABEL_VARIANTS)) for scene, d in dirs.items()}
    by_label = {}
    for n, (label, after_slip) in enumerate(LABEL_VARIANTS.items()):
        own = windows if label == "pseudo" else {
            m: relabel(w, {i: t[n] for i, t in targets[DATASET_OF_METHOD[m]].items()}) for m, w in windows.items()}
        study = run_study(dirs, methods=methods, quick=settings.quick, max_train=b["max_train"],
                          grid_max=b["grid_max"], progress=settings.progress, after_slip=after_slip,
                          workers=settings.jobs, label=label, windows=own)
        where = out if label == "pseudo" else out / label
        by_label[label] = _write(study, where, b, settings, after_slip)
    written = by_label.pop("pseudo")
    return {**b, "seed": settings.seed, "after_slip": AFTER_SLIP, "models": written,
            "models_by_label": {label: {"after_slip": LABEL_VARIANTS[label], "models": w} for label, w in by_label.items()},
            "elapsed_s": time.perf_counter() - t0}


def _write(study, out: Path, b: dict, settings: Settings, after_slip: str) -> dict:
    """Save each method's model of one label into `out`; return what was written."""
    from incipient_slip.models.modelfile import save_model
    out.mkdir(parents=True, exist_ok=True)
    written = {}
    for m, r in study.results.items():
        r.model.header["after_slip"] = after_slip
        r.model.header["regen"] = {"command": "slip reproduce models", "series": b["series"],
                                   "seed": settings.seed,
                                   "scenes": {"paper": "injection on", "no_injection": "vibrotactile"}}
        r.model.header.pop("versions", None)
        path = save_model(r.model, out / f"{m}.npz")
        hp = r.model.header.get("hyper_parameters") or {}
        written[m] = {"file": _shown(path), "bytes": path.stat().st_size,
                      "support_vectors": int(len(r.model.centers)) if r.model.kind == "kernel" else 0,
                      "hyper_parameters": hp, "rmse": float(r.scores.rmse.mean()),
                      "top10": float(r.scores.top10_rmse.mean())}
        print(f"{m:<13} {path.stat().st_size / 1024:7.0f} KiB  held-out RMSE {written[m]['rmse']:.3f}  "
              f"top-10 % {written[m]['top10']:.3f}  {path}")
    return written


def _shown(path: Path) -> str:
    """Return `path` relative to the repository (models/e1.npz) when it is inside it."""
    from incipient_slip.paths import repo_root
    try:
        return str(path.resolve().relative_to(repo_root()))
    except ValueError:
        return str(path)


def render(results: dict) -> dict[str, str]:
    """Return the shipped-models block of docs/estimation.md: one row per method and label."""
    lines = [f"{results['series']} series per scene (seed {results['seed']}), T = 1.0 s, exact SVR "
             f"by grid search on <= {results['max_train']} windows (simulated rig): the pseudo label's "
             "models on the incipient-slip range (windows up to the first gross-slip onset), the "
             "measured-ratio models on every window. Held-out RMSE is against the model's own label, "
             "on that set's own held-out series.", "",
             "| method | label | file | size | support vectors | hyper-parameters | held-out RMSE |",
             "|---|---|---|---|---|---|---|"]
    variants = {"pseudo": results["models"],
                **{label: v["models"] for label, v in results.get("models_by_label", {}).items()}}
    for m in results["models"]:
        for label, models in variants.items():
            if m not in models:
                continue
            w = models[m]
            hp = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in w["hyper_parameters"].items())
            lines.append(f"| {METHOD_LABELS[m]} | {label} | {w['file']} | {w['bytes'] / 1024:.0f} KiB | "
                         f"{w['support_vectors']} | {hp} | {w['rmse']:.3f} |")
    return {"shipped-models": "\n".join(lines)}
