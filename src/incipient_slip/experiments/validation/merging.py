"""This run's points over the kept ones: the summaries of their runs (the Tables) and the figures."""
from __future__ import annotations

import numpy as np

from incipient_slip import control

from . import spec
from .figures import joint_figure, success_figure
from .planning import Plan
from .spec import POINTS


def merge(p: Plan, done: dict, joint_done: dict, refit_only: dict, settings) -> dict:
    """Return the results: this run's points over the kept ones, with their Tables and figures."""
    old = p.old
    points = {n: q for n, q in old.get("points", {}).items() if n not in p.names}
    points.update(done)
    points = {n: points[n] for n in (p.rig_points or POINTS) if n in points}
    for q in points.values():
        _summarize_point(q)
    kept_only = not done and old.get("points")      # the one-at-a-time points all come from --keep
    out = {"rig": p.provenance, "budget": settings.budget, "runs": old.get("runs", p.runs) if kept_only else p.runs,
           "series": old.get("series", p.n_series) if kept_only else p.n_series, "steps": p.steps, "points": points,
           "figure": success_figure(points, settings.figures) if points else None}
    for q in joint_done.values():
        _summarize_point(q)
    if p.joint:
        out["joint"] = {"axes": {k: list(v) for k, v in spec.JOINT.items()}, "runs": p.runs, "series": p.n_series,
                        "points": {n: joint_done.get(n) or {"point": n, "overrides": p.grid[n],
                                                            "consistent": False, "fit": refit_only[n]}
                                   for n in p.grid}}
    elif "joint" in old:
        out["joint"] = old["joint"]
        out["joint"]["points"].update(joint_done)
    if joint_done or p.joint:
        out["joint_figure"] = joint_figure(out["joint"], settings.figures)
    elif "joint" in old:
        out["joint_figure"] = old.get("joint_figure")
    if done.get("fitted", {}).get("trajectory"):
        out["trajectory"] = done["fitted"]["trajectory"]
    elif old.get("trajectory"):
        out["trajectory"] = old["trajectory"]
    return out


def summarize(runs: list) -> dict:
    """Return success rate, mean final y, F_N and steps, and the paper's score of a method's runs."""
    succ = [r["success"] for r in runs if r["success"] is not None]
    rate = float(np.mean(succ)) if succ else None
    y = float(np.mean([r["y"] for r in runs]))
    fn = float(np.mean([r["fn"] for r in runs]))
    return {"success": rate, "y": y, "fn": fn, "steps": float(np.mean([r["steps"] for r in runs])),
            "score": control.score(rate or 0.0, max(y, 1e-6), max(fn, 1e-6))}


def _summarize_point(p: dict) -> None:
    p["table"] = {m: summarize(r) for m, r in p["runs"].items()}
    for row in p.get("labels", {}).values():        # the pseudo row's runs are the point's own
        if "runs" in row:
            row["table"] = {m: summarize(r) for m, r in row["runs"].items()}
    p["sweep_table"] = {m: {sd: summarize(r) for sd, r in by_sd.items()} for m, by_sd in p.get("sweep", {}).items()}
