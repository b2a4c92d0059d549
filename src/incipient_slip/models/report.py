"""Figures and the markdown page of the estimation study (docs/estimation.md).

Every figure says "simulated rig" in its title: these are statements about the simulator.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .evaluation import TOP_FRACTION  # noqa: E402
from .features import feature_spec  # noqa: E402

LABEL = "simulated rig"
NAMES = {"injection": "injection (ours)", "vibrotactile": "vibrotactile", "e19": "E19",
         "e10": "E10", "e4": "E4", "e1": "E1"}

# The paper gives the estimation results as figures only; its findings, in words.
PAPER_FINDINGS = {
    "injection": "low RMSE, no significant difference to E19/E10/E4; lowest top-10 % RMSE (**)",
    "vibrotactile": "large variance: fails to estimate",
    "e19": "low RMSE; large errors above s ~ 0.7; top-10 % significantly above injection",
    "e10": "low RMSE; large errors above s ~ 0.7; top-10 % significantly above injection",
    "e4": "low RMSE; large errors above s ~ 0.7; top-10 % significantly above injection",
    "e1": "large variance: fails to estimate",
}


def fig_sorted(study, path: Path) -> Path:
    methods = list(study.results)
    fig, axes = plt.subplots(2, 3, figsize=(12, 6), sharey=True)
    for ax, m in zip(axes.ravel(), methods):
        r = study.results[m]
        order = np.argsort(r.test.y, kind="stable")
        ax.plot(r.pred[order], ".", ms=2, alpha=0.4, label="estimate")
        ax.plot(r.test.y[order], "k-", lw=1.5, label="pseudo-stick ratio")
        ax.set_title(f"{NAMES[m]}  RMSE {r.scores.rmse.mean():.3f}")
        ax.set_xlabel("test window (sorted by s)")
    axes[0, 0].set_ylabel("s")
    axes[0, 0].legend(loc="upper left", fontsize=8)
    fig.suptitle(f"Stick-ratio estimate vs label on held-out series ({LABEL})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def fig_bars(study, path: Path) -> Path:
    methods = list(study.results)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, metric, tests, title in ((axes[0], "rmse", study.tests_rmse, "RMSE per series"),
                                     (axes[1], "top10_rmse", study.tests_top10,
                                      f"top-{int(TOP_FRACTION * 100)} % RMSE per series")):
        vals = [getattr(study.results[m].scores, metric) for m in methods]
        means = [v.mean() for v in vals]
        sds = [v.std(ddof=1) if len(v) > 1 else 0 for v in vals]
        x = np.arange(len(methods))
        ax.bar(x, means, yerr=sds, capsize=3, color=["C3" if m == "injection" else "C0" for m in methods])
        for i, m in enumerate(methods):
            mark = tests.get(m, {}).get("stars", "")
            if mark:
                ax.text(i, means[i] + sds[i] + 0.01, mark, ha="center")
        ax.set_xticks(x, [NAMES[m] for m in methods], rotation=30)
        ax.set_title(f"{title} ({LABEL})")
        ax.set_ylabel("RMSE of s")
    fig.text(0.01, 0.01, "** p<0.01, * p<0.05: paired t-test vs injection, Holm-corrected", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def fig_material(study, path: Path) -> Path:
    methods = list(study.results)
    mats = sorted(set(np.concatenate([r.scores.material for r in study.results.values()])))
    fig, ax = plt.subplots(figsize=(10, 4))
    w = 0.8 / len(mats)
    for j, mat in enumerate(mats):
        vals = [study.results[m].scores.rmse[study.results[m].scores.material == mat].mean() for m in methods]
        ax.bar(np.arange(len(methods)) + j * w, vals, w, label=mat)
    ax.set_xticks(np.arange(len(methods)) + 0.4 - w / 2, [NAMES[m] for m in methods])
    ax.set_ylabel("mean RMSE of s")
    ax.set_title(f"RMSE per material ({LABEL})")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def spectrum_by_s(ws, edges=(0.0, 0.01, 0.25, 0.5, 0.75, 1.01)):
    """Return (bin centres Hz, {label: mean log10 amplitude}) of windows grouped by s."""
    spec = ws.spec
    centres = spec.band_hz[0] + spec.bin_hz * (np.arange(ws.X.shape[1]) + 0.5)
    out = {}
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (ws.y >= lo) & (ws.y < hi)
        if m.any():
            out["s = 0 (gross slip)" if hi <= 0.01 else f"{lo:.2f} <= s < {min(hi, 1):.2f}"] = ws.X[m].mean(0)
    return centres, out


def fig_spectrum(ws, path: Path) -> Path:
    centres, groups = spectrum_by_s(ws)
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, mean in groups.items():
        ax.plot(centres, mean, label=label)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("mean log10 amplitude [counts]")
    ax.set_title(f"Injected vibration at P_AC, mean spectrum by s ({LABEL})")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def band_vs_force(ws, band_hz: float = 200.0):
    """Return (band feature, F_T, mask of pre-slip windows, pooled R, mean R within F_N levels)."""
    j = int((band_hz - ws.spec.band_hz[0]) // ws.spec.bin_hz)
    band = ws.X[:, j].astype(np.float64)
    pre = ws.y > 0
    pooled = float(np.corrcoef(band[pre], ws.tangential_force_n[pre])[0, 1]) if pre.sum() > 2 else float("nan")
    rs = []
    for fn in np.unique(ws.normal_force_kpa[pre]):
        m = pre & (ws.normal_force_kpa == fn)
        if m.sum() > 5:
            rs.append(np.corrcoef(band[m], ws.tangential_force_n[m])[0, 1])
    return band, pre, pooled, float(np.mean(rs)) if rs else float("nan")


def fig_band(ws, path: Path) -> tuple[Path, float, float]:
    band, pre, pooled, within = band_vs_force(ws)
    fig, ax = plt.subplots(figsize=(6, 4))
    sc = ax.scatter(ws.tangential_force_n[pre], band[pre], c=ws.normal_force_kpa[pre], s=3, cmap="viridis")
    fig.colorbar(sc, label="F_N [kPa]")
    ax.set_xlabel("F_T [N]")
    ax.set_ylabel("log10 amplitude, 200-210 Hz bin")
    ax.set_title(f"200 Hz band vs F_T before gross slip ({LABEL})\n"
                 f"R pooled {pooled:.2f}, mean R at fixed F_N {within:.2f} (paper R = 0.97)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path, pooled, within


def write_figures(study, fig_dir: Path, prefix: str = "est_") -> dict:
    fig_dir.mkdir(parents=True, exist_ok=True)
    figs = {"sorted": fig_sorted(study, fig_dir / f"{prefix}sorted.png"),
            "bars": fig_bars(study, fig_dir / f"{prefix}rmse_bars.png"),
            "material": fig_material(study, fig_dir / f"{prefix}rmse_material.png")}
    if "injection" in study.results:
        from .training import load_windows
        ws = load_windows(study.data_dirs["paper"], feature_spec("injection"), progress=False)
        figs["spectrum"] = fig_spectrum(ws, fig_dir / f"{prefix}spectrum.png")
        figs["band"], figs["band_r_pooled"], figs["band_r_within"] = fig_band(ws, fig_dir / f"{prefix}band200_vs_ft.png")
    return figs


def label_quality(data_dir) -> dict:
    """Return how far the pseudo label is from the simulator's true ratios (before / after slip)."""
    from . import dataset as ds
    from .labels import label_series
    pre = {"sar": [], "lrs": [], "y": []}
    post = {"sar": [], "y": []}
    onset = []
    for p in ds.series_paths(data_dir):
        s = ds.load_series(p)
        lab = label_series(s)
        if lab.gross_slip_index < 0:
            continue
        k = lab.gross_slip_index
        true_k = np.flatnonzero(s.gross_slip)
        onset.append(k - true_k[0] if len(true_k) else np.nan)
        pre["sar"].append(s.stick_area_ratio[:k]); pre["lrs"].append(s.load_ratio_stick[:k])
        pre["y"].append(lab.pseudo_stick_ratio[:k])
        post["sar"].append(s.stick_area_ratio[k:]); post["y"].append(lab.pseudo_stick_ratio[k:])
    cat = {k: np.concatenate(v) for k, v in pre.items()}
    catp = {k: np.concatenate(v) for k, v in post.items()}
    rm = lambda a, b: float(np.sqrt(np.mean((a - b) ** 2)))  # noqa: E731
    onset = np.array(onset, dtype=float)
    return {"pre_rmse_vs_stick_area": rm(cat["y"], cat["sar"]), "pre_rmse_vs_load_ratio": rm(cat["y"], cat["lrs"]),
            "post_rmse_vs_stick_area": rm(catp["y"], catp["sar"]),
            "post_fraction": float(len(catp["y"]) / (len(catp["y"]) + len(cat["y"]))),
            "onset_exact_fraction": float(np.mean(onset == 0)), "onset_offset_max": float(np.nanmax(np.abs(onset)))}


def _result_rows(study) -> list[str]:
    out = []
    for r in study.table():
        m = r["method"]
        pr = "-" if r["p_rmse"] is None else _p_cell(study.tests_rmse[m])
        pt = "-" if r["p_top10"] is None else _p_cell(study.tests_top10[m])
        params = r["params"] or {}
        ptxt = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items())
        out.append(f"| {NAMES[m]} | {r['rmse_mean']:.3f} ± {r['rmse_std']:.3f} | {pr} | "
                   f"{r['top10_mean']:.3f} ± {r['top10_std']:.3f} | {pt} | {ptxt} | {PAPER_FINDINGS[m]} |")
    return out


def verdict(tests: dict, what: str) -> str:
    """Return one sentence: where injection is significantly better / worse / not different."""
    better = [NAMES[m] for m, t in tests.items() if t["p_holm"] < 0.05 and t["mean_diff"] < 0]
    worse = [NAMES[m] for m, t in tests.items() if t["p_holm"] < 0.05 and t["mean_diff"] > 0]
    same = [NAMES[m] for m, t in tests.items() if t["p_holm"] >= 0.05]
    parts = []
    if better:
        parts.append(f"lower than {', '.join(better)}")
    if worse:
        parts.append(f"higher than {', '.join(worse)}")
    if same:
        parts.append(f"not significantly different from {', '.join(same)}")
    return f"Injection's {what} is " + "; ".join(parts) + " (Holm-corrected p < 0.05)."


def _p_cell(test: dict) -> str:
    """Return 'p stars (lower|higher)': the method's error relative to injection."""
    side = "lower" if test["mean_diff"] > 0 else "higher"
    return f"{test['p_holm']:.2g} {test['stars']} ({side})".replace("  ", " ")


TABLE_HEAD = ["| method | RMSE (mean ± std) | p vs injection | top-10 % RMSE | p vs injection | kernel, params | paper's finding |",
              "|---|---|---|---|---|---|---|"]


def write_markdown(study, figs: dict, path: Path, fig_rel: str, labelq: dict, command: str,
                   elapsed_s: float, incipient=None) -> Path:
    rows = study.table()
    lines = [
        "# Stick-ratio estimation: the paper's study on the simulated rig",
        "",
        f"Generated by `{command}` in {elapsed_s / 60:.1f} min on 2 cores. **Every number and figure",
        "on this page is from the simulated rig** (`scenes/paper.yaml`, `scenes/no_injection.yaml`),",
        "not from the paper's hardware; the paper's own findings are quoted beside them.",
        "",
        "## Set-up",
        "",
        f"* Data: {len(study.test_series)} held-out test series (the same series indices for all six",
        "  methods and both data sets; 10 % of each material's series, chosen by a seeded hash of the",
        "  series index), the other series for training. Windows T = 1.0 s every 500 ms, labels by the",
        "  paper's rule (`models/labels.py`); windows after gross slip are labelled 0.",
        "* phi: P_AC spectrum 10-1100 Hz, Hann, 10 Hz bins of the magnitude, log10 (injection,",
        "  vibrotactile); time average of the raw counts of E19 (all), E10 (E1, E3, ..., E19),",
        "  E4 (E1, E7, E13, E19), E1 (the centre electrode E17). Details: `models/features.py`.",
        "* f: SVR (libsvm), kernel (rbf / linear) and C, gamma, epsilon by 3-fold grid search grouped",
        "  by series on a subsample, then fitted on at most the stated number of training windows.",
        "* RMSE is per test series; **top-10 % RMSE** of a series is the RMSE over its ceil(10 %)",
        "  windows with the largest absolute error. Both are averaged over test series (± std).",
        "  Paired two-sided t-tests (per series) of injection vs each method, Holm-corrected over the",
        "  five comparisons: ** p < 0.01, * p < 0.05; (lower) / (higher) = that method's error",
        "  relative to injection.",
        "",
        "## Results (simulated rig) and the paper side by side",
        "",
        "Paper's rule (all windows; after gross slip s = 0):",
        "",
        *TABLE_HEAD, *_result_rows(study),
    ]
    lines += ["", verdict(study.tests_rmse, "RMSE") + " " + verdict(study.tests_top10, "top-10 % RMSE")]
    if incipient is not None:
        lines += ["", "Incipient-slip range only (windows up to and including the gross-slip onset; the",
                  "shipped default models are trained this way, see below):", "",
                  *TABLE_HEAD, *_result_rows(incipient), "",
                  verdict(incipient.tests_rmse, "RMSE") + " " + verdict(incipient.tests_top10, "top-10 % RMSE")]
    mats = sorted(rows[0]["by_material"])
    lines += ["", "Mean RMSE per material (simulated rig):", "",
              "| method | " + " | ".join(mats) + " |", "|---|" + "---|" * len(mats)]
    for r in rows:
        lines.append(f"| {NAMES[r['method']]} | " + " | ".join(f"{r['by_material'][m]['rmse']:.3f}" for m in mats) + " |")
    lines += ["", f"![estimate vs truth]({fig_rel}/{Path(figs['sorted']).name})", "",
              "*Simulated rig.* Estimate (dots) and pseudo-stick ratio (line) on the held-out windows,",
              "sorted by s (the paper's Fig. 'Results for stick-ratio estimation').", ""]
    if "sorted_incipient" in figs:
        lines += [f"![estimate vs truth, incipient range]({fig_rel}/{Path(figs['sorted_incipient']).name})", "",
                  "*Simulated rig.* The same for models trained and tested on the incipient-slip range.", ""]
    lines += [
              f"![RMSE bars]({fig_rel}/{Path(figs['bars']).name})", "",
              "*Simulated rig.* Mean per-series RMSE and top-10 % RMSE with std; stars: Holm-corrected",
              "paired t-test against injection.", "",
              f"![RMSE per material]({fig_rel}/{Path(figs['material']).name})", "",
              "*Simulated rig.* Mean RMSE per material (paper: no material trend).", ""]
    if "spectrum" in figs:
        lines += [f"![spectrum by s]({fig_rel}/{Path(figs['spectrum']).name})", "",
                  "*Simulated rig.* Mean injected-vibration spectrum at P_AC for groups of s (paper's",
                  "Fig. 'injected vibration feature in frequency domain').", "",
                  f"![200 Hz band vs F_T]({fig_rel}/{Path(figs['band']).name})", "",
                  f"*Simulated rig.* 200 Hz band amplitude vs F_T before gross slip: R pooled over all F_N = "
                  f"{figs['band_r_pooled']:.2f}, mean R within one F_N level = {figs['band_r_within']:.2f}; the paper",
                  "reports |R| = 0.97 with the spectrum falling as F_T rises (optical F_T, sawtooth injection).", ""]
    lines += ["## The pseudo label against the simulator's truth", "",
              "The simulator knows the true stick-area ratio (c/a)^2 and its own load ratio",
              "1 - Q/(mu_s F_N); the paper cannot measure either. On the injection data set:", "",
              f"* before gross slip: RMSE(pseudo label, (c/a)^2) = {labelq['pre_rmse_vs_stick_area']:.3f}, "
              f"RMSE(pseudo label, 1 - Q/(mu_s F_N)) = {labelq['pre_rmse_vs_load_ratio']:.3f};",
              f"* after gross slip ({labelq['post_fraction'] * 100:.0f} % of all windows) the label is 0 but the",
              f"  contact re-sticks between slides: RMSE(label, (c/a)^2) = {labelq['post_rmse_vs_stick_area']:.3f};",
              f"* the detected slip onset equals the simulator's first sliding period in "
              f"{labelq['onset_exact_fraction'] * 100:.0f} % of the series (max offset {labelq['onset_offset_max']:.0f} periods).",
              "", "So a large part of every method's error under the paper's rule is the label rule itself:",
              "after the first gross slip the rig sticks and slips again while the label stays 0. This is",
              "why the shipped default models (`slip model regen`) learn the incipient-slip range only.", ""]
    lines += shipped_models_section() + STATIC_SECTIONS
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def shipped_models_section() -> list[str]:
    """Return markdown lines describing models/*.npz (from their headers)."""
    from .estimator_core import default_model_path
    from .features import METHODS
    from .modelfile import read_model_file
    lines = ["## Shipped default models (`models/*.npz`, simulated rig)", "",
             "Written by `slip model regen`: 100 series per scene (seed 7), T = 1.0 s, exact SVR by grid",
             "search on <= 3000 windows of the incipient-slip range (windows after the gross-slip onset left",
             "out; see the label section). Held-out RMSE is on that small set's own held-out series.", "",
             "| method | file | size | support vectors | hyper-parameters | held-out RMSE |", "|---|---|---|---|---|---|"]
    for m in METHODS:
        path = default_model_path(m)
        if not path.is_file():
            lines.append(f"| {NAMES[m]} | missing | | | | |")
            continue
        mdl = read_model_file(path)
        hp = mdl.header.get("hyper_parameters") or {}
        hp_txt = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in hp.items())
        nsv = len(mdl.centers) if mdl.kind == "kernel" else 0
        lines.append(f"| {NAMES[m]} | models/{path.name} | {path.stat().st_size / 1024:.0f} KiB | {nsv} | {hp_txt} | "
                     f"{mdl.header.get('test_rmse_mean', float('nan')):.3f} |")
    return lines + [""]


STATIC_SECTIONS = """
## Commands

* `slip reproduce estimation [--quick]` - this page: simulates both data sets (500 series each,
  or reuses `runs/data/`), trains the six methods under both label policies, evaluates, writes
  `docs/estimation.md` and `docs/figures/est_*.png`. `--quick` (10 short series) writes to
  `runs/estimation-quick/` only.
* `slip train --method M --data DIR [--kind svr|nystroem|linear] [--after-slip zero|drop]` -
  one model on a data set written by `slip dataset`, scored on the held-out series.
* `slip evaluate --data DIR [--data-no-injection DIR] --model A.npz --model B.npz ...` -
  per-series RMSE, top-10 % RMSE, per material, Holm-corrected paired t-tests vs the first model.
* `slip model regen` - regenerates the shipped `models/METHOD.npz` (all six, T = 1.0 s) from a
  simulated data set (100 series per scene, seed 7), deterministically.
* `slip reproduce accuracy-vs-time [--quick]` - docs/accuracy-vs-time.md.

## Definitions

* **Label**: pseudo-stick ratio s = 1 - F_T / F_T^slip per 500 ms sample, F_T^slip = the
  largest F_T up to the gross-slip onset; onset = first period in which the object (mocap)
  travels >= 0.02 mm between the mean of the period's first 25 ms and of its last 50 ms (the
  second half of the paper's 1 s window, after the step's deformation jump). Paper's rule:
  s = 0 for every later window. Incipient-range policy: windows after the onset are left out.
* **Held-out series**: per material, the ceil(10 %) series indices with the smallest
  sha256(seed, index); the same for every method and for both data sets.
* **RMSE** per held-out series; **top-10 % RMSE** per series = RMSE over that series' ceil(10 %)
  windows with the largest |estimate - label|; reported as mean ± std over the series.
* **Significance**: paired two-sided t-test on the per-series values, injection vs each other
  method, Holm correction over the five comparisons, ** p < 0.01, * p < 0.05.

## Model files and the estimator core

A model file is a compressed `.npz` of float64 arrays (`mean`, `scale`, `centers`, `weights`,
`intercept`) plus `header`, a UTF-8 JSON (method, feature spec and its hash, regressor,
kernel and hyper-parameters, training data hash, held-out series, library versions); it is read
with `allow_pickle=False`. Exact SVR and Nystroem + ridge are both stored as one kernel
expansion f(z) = sum_j w_j k(z, c_j) + b on standardized features, clipped to [0, 1].
`incipient_slip.models.estimator_core` loads it (`load_model(path, stream=..., rate_hz=...)`
refuses a spec that does not fit the stream) and `StreamingEstimator` turns P_AC or electrode
frames into `estimate(window_end_ns) -> (stick_ratio, valid, reason)`.
""".strip("\n").split("\n")
