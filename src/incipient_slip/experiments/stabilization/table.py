"""The stabilization Table: the methods and the paper's row, the statistics of the runs (score,
Welch t-test against injection) and the Table as text and markdown."""
from __future__ import annotations

import math

import numpy as np

from incipient_slip import control

from ..plots import METHOD_LABELS

# the paper's column order
TABLE_METHODS = ("none", "vibrotactile", "e1", "e4", "e10", "e19", "injection")
# the paper's Table (y and F_N at the last step; None where the paper gives none)
PAPER_TABLE = {
    "none": {"success": None, "y": 2.48, "fn": 2.94, "steps": 450},
    "vibrotactile": {"success": 0.3, "y": 1.32, "fn": 5.96, "steps": 397},
    "e1": {"success": 0.0, "y": 0.89, "fn": 6.47, "steps": 139},
    "e4": {"success": 0.1, "y": 2.52, "fn": 3.59, "steps": 450},
    "e10": {"success": 1.0, "y": 1.55, "fn": 5.23, "steps": 450},
    "e19": {"success": 0.8, "y": 1.40, "fn": 6.24, "steps": 435},
    "injection": {"success": 1.0, "y": 1.38, "fn": 4.50, "steps": 450},
}


def materials() -> tuple[str, ...]:
    """Return the materials runs cycle through: the paper scene's (one source: the sim params)."""
    from incipient_slip.sim.scene import load_scene
    return load_scene("paper").materials


def run_score(summary: dict) -> float:
    """The paper's score of one run (success 0 or 1); nan when y or F_N is not positive."""
    y, fn = summary.get("final_travel_mm", math.nan), summary.get("final_force_kpa", math.nan)
    if not (isinstance(y, (int, float)) and isinstance(fn, (int, float)) and y > 0 and fn > 0):
        return math.nan
    return control.score(1.0 if summary.get("success") else 0.0, y, fn)


def aggregate(summaries: list[dict]) -> dict:
    """Success rate, mean/std of final y, F_N and steps, the Table score and per-run scores."""
    y = np.array([s["final_travel_mm"] for s in summaries], dtype=float)
    fn = np.array([s["final_force_kpa"] for s in summaries], dtype=float)
    steps = np.array([s["steps"] for s in summaries], dtype=float)
    success = np.array([bool(s.get("success")) for s in summaries])
    scores = np.array([run_score(s) for s in summaries])
    rate = float(success.mean()) if len(success) else math.nan
    y_mean, fn_mean = float(np.nanmean(y)), float(np.nanmean(fn))
    table_score = (control.score(rate, y_mean, fn_mean)
                   if y_mean > 0 and fn_mean > 0 else math.nan)
    errors = []
    for s in summaries:       # tracking: |estimate - s_d| after the first 10 steps
        est = np.array((s.get("traces") or {}).get("stick_ratio_estimate", [])[10:], dtype=float)
        if np.isfinite(est).any():
            errors.append(float(np.nanmean(np.abs(est - s.get("s_d", math.nan)))))
    return {"n": len(summaries), "success_rate": rate,
            "tracking_error": float(np.mean(errors)) if errors else math.nan,
            "y_mean": y_mean, "y_std": float(np.nanstd(y)), "fn_mean": fn_mean,
            "fn_std": float(np.nanstd(fn)), "steps_mean": float(np.mean(steps)),
            "score": table_score, "run_scores": scores.tolist(),
            "faults": int(sum(s.get("outcome") == "fault" for s in summaries)),
            "outcomes": {k: int(sum(s.get("outcome") == k for s in summaries))
                         for k in ("success", "failure", "fault")}}


def t_test_p(a, b) -> float:
    """Two-sided Welch t-test p-value of two samples of run scores (nan if undefined)."""
    from scipy import stats
    a, b = np.asarray(a, float), np.asarray(b, float)
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if len(a) < 2 or len(b) < 2:
        return math.nan
    if np.std(a) == 0 and np.std(b) == 0:
        return 1.0 if np.mean(a) == np.mean(b) else 0.0
    return float(stats.ttest_ind(a, b, equal_var=False).pvalue)


def stars(p: float) -> str:
    return "**" if p < 0.01 else ("*" if p < 0.05 else "")


def table_rows(results: dict[str, list[dict]]) -> dict[str, dict]:
    """Aggregate per method plus the p-value of its run scores against injection."""
    rows = {m: aggregate(results[m]) for m in TABLE_METHODS if results.get(m)}
    ref = rows.get("injection", {}).get("run_scores", [])
    for m, row in rows.items():
        row["p_vs_injection"] = math.nan if m == "injection" else t_test_p(row["run_scores"], ref)
    return rows


def fmt(v, spec=".2f", none="–") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return none
    return format(v, spec)


def format_table_markdown(rows: dict[str, dict]) -> str:
    """The Table, simulation beside the paper, as markdown."""
    methods = [m for m in TABLE_METHODS if m in rows]
    head = "| | " + " | ".join(METHOD_LABELS[m] for m in methods) + " |"
    sep = "|---|" + "---|" * len(methods)
    paper_score = {m: (control.score(PAPER_TABLE[m]["success"] or 0.0, PAPER_TABLE[m]["y"],
                                     PAPER_TABLE[m]["fn"])) for m in methods}

    def line(label, fn):
        return f"| {label} | " + " | ".join(fn(m) for m in methods) + " |"
    lines = [head, sep,
             line("success rate ↑ (sim)", lambda m: fmt(rows[m]["success_rate"])),
             line("success rate (paper)", lambda m: fmt(PAPER_TABLE[m]["success"])),
             line("y [mm] ↓ (sim)", lambda m: f"{fmt(rows[m]['y_mean'])} ± {fmt(rows[m]['y_std'])}"),
             line("y [mm] (paper)", lambda m: fmt(PAPER_TABLE[m]["y"])),
             line("F_N [kPa] ↓ (sim)", lambda m: f"{fmt(rows[m]['fn_mean'])} ± {fmt(rows[m]['fn_std'])}"),
             line("F_N [kPa] (paper)", lambda m: fmt(PAPER_TABLE[m]["fn"])),
             line("steps ↑ (sim)", lambda m: fmt(rows[m]["steps_mean"], ".0f")),
             line("steps (paper)", lambda m: fmt(PAPER_TABLE[m]["steps"], "d")),
             line("score ↑ (sim)", lambda m: fmt(rows[m]["score"]) + stars(rows[m]["p_vs_injection"])),
             line("score (paper's numbers)", lambda m: fmt(paper_score[m])),
             line("p vs injection (Welch, run scores)",
                  lambda m: "ref" if m == "injection" else fmt(rows[m]["p_vs_injection"], ".3g")),
             line("runs (success/failure/fault)",
                  lambda m: "/".join(str(rows[m]["outcomes"][k]) for k in ("success", "failure", "fault")))]
    return "\n".join(lines)


def format_table_text(rows: dict[str, dict]) -> str:
    """The Table for a terminal: one line per method."""
    out = [f"{'method':<17}{'succ':>6}{'(paper)':>8}{'y mm':>7}{'(paper)':>8}{'F_N kPa':>9}"
           f"{'(paper)':>8}{'steps':>7}{'(paper)':>8}{'score':>7}{'p':>9}"]
    for m in TABLE_METHODS:
        if m not in rows:
            continue
        r, p = rows[m], PAPER_TABLE[m]
        out.append(f"{METHOD_LABELS[m]:<17}{fmt(r['success_rate']):>6}{fmt(p['success']):>8}"
                   f"{fmt(r['y_mean']):>7}{fmt(p['y']):>8}{fmt(r['fn_mean']):>9}{fmt(p['fn']):>8}"
                   f"{fmt(r['steps_mean'], '.0f'):>7}{fmt(p['steps'], 'd'):>8}{fmt(r['score']):>7}"
                   f"{'ref' if m == 'injection' else fmt(r['p_vs_injection'], '.2g'):>9}")
    return "\n".join(out)
