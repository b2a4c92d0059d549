"""The generated blocks of docs/stabilization.md, from the results alone (`--render-only`)."""
from __future__ import annotations

import math

import numpy as np

from incipient_slip import control

from ..plots import METHOD_LABELS
from .figures import sweep_lines
from .table import PAPER_TABLE, TABLE_METHODS, fmt, format_table_markdown


def render(results: dict) -> dict[str, str]:
    """Return the generated blocks of docs/stabilization.md (every number: simulated rig)."""
    blocks = {}
    if "table" in results:
        blocks["stabilization-table"] = render_table(results["table"])
        blocks["stabilization-reading"] = render_reading(results["table"]["rows"])
        blocks["stabilization-cost"] = render_cost(results["table"])
    blocks["stabilization-k"] = render_k(results.get("tune_k"))
    blocks["stabilization-sweep"] = render_sweep(results.get("sweep"))
    blocks["stabilization-labels"] = render_labels(results.get("labels"), results.get("table", {}).get("rows", {}))
    blocks["stabilization-extension"] = render_extension(
        results.get("extension"), results.get("table", {}).get("rows", {}))
    return blocks


def render_table(t: dict) -> str:
    """Return the Table block: its set-up in one paragraph, then the Table."""
    return "\n".join([
        f"{t['runs']} runs per method, s_d = {t['s_d']}, k = {t['k']} kPa per unit stick ratio per "
        f"period, at most {t['steps']} steps (simulated rig). y and F_N are the values at each "
        "run's last step (mean ± sd over runs), as in the paper. Score = (0.1 + success)(10 / y + "
        "1 / F_N): the Table's row applies it to the method's success rate and mean y, F_N (as the "
        "paper does); the t-test (Welch, two-sided) compares per-run scores with injection's "
        "(* p < 0.05, ** p < 0.01).", "", format_table_markdown(t["rows"])])


def render_reading(rows: dict) -> str:
    """Return the bullets that read the Table (which method scores highest, how runs end)."""
    if not rows:
        return "(no runs)"
    inj = rows.get("injection", {})
    best = max(rows, key=lambda m: rows[m]["score"] if math.isfinite(rows[m]["score"]) else -1)
    out = [f"* Highest score in simulation: **{METHOD_LABELS[best]}** ({fmt(rows[best]['score'])}); "
           f"injection {fmt(inj.get('score'))}. "
           + ("In the paper injection scores highest too." if best == "injection"
              else "In the paper injection scores highest; on the simulated rig it does not.")]
    controlled = {m: r for m, r in rows.items() if m != "none"}
    if controlled and not any(r["success_rate"] > 0 for r in controlled.values()):
        out.append("* **No controlled run succeeds in simulation**, where the paper has injection and "
                   "E10 at 1.0.")
    for m, r in controlled.items():
        n = r["outcomes"]
        out.append(f"* {METHOD_LABELS[m]}: {n['success']} held, {n['failure']} failed, {n['fault']} "
                   f"faults; final y {fmt(r['y_mean'])} mm, F_N {fmt(r['fn_mean'])} kPa.")
    if "none" in rows:
        out.append(f"* No action ends at y {fmt(rows['none'].get('y_mean'))} mm (paper 2.48 mm).")
    return "\n".join(out)


def render_cost(t: dict) -> str:
    """Return the cost sentence: wall time of the Table and how it was run."""
    n = sum(r["n"] for r in t["rows"].values()) + t.get("other_label_runs", 0)
    what = f"{n} runs" + (", both labels" if t.get("other_label_runs") else "")
    return (f"The Table ({what}) took **{t['wall_s']} s** wall on {t.get('cpus')} cores with "
            f"{t['jobs']} graphs in parallel (start = {t['start']}; the machine was shared with "
            "other jobs).")


def render_k(tune: dict | None) -> str:
    """Return the gain study's table, or how to run it."""
    if not tune:
        return "(not run yet: `slip reproduce stabilization --tune-k 0.5,1,2,4,8`)"
    out = ["| k | success | steps | y [mm] | F_N [kPa] | score | mean abs(ŝ − s_d) |",
           "|---|---|---|---|---|---|---|"]
    for k, r in tune["rows"].items():
        out.append(f"| {float(k):g} | {fmt(r['success_rate'])} | {fmt(r['steps_mean'], '.0f')} | "
                   f"{fmt(r['y_mean'])} | {fmt(r['fn_mean'])} | {fmt(r['score'])} | "
                   f"{fmt(r.get('tracking_error'), '.3f')} |")
    out += ["", f"({tune['runs']} injection runs per k at s_d = {tune['s_d']}, simulated rig, "
            f"`--tune-k`, {tune['wall_s']} s.)"]
    return "\n".join(out)


def render_sweep(sweep: dict | None) -> str:
    """Return the s_d sweep's tables and reading, or how to run it."""
    if not sweep:
        return "(not run yet: `slip reproduce stabilization --sweep`)"
    rows_s = sweep["rows"]
    lines = sweep_lines(sweep)
    sds = sorted({float(x) for _, _, by_sd in lines for x in by_sd})
    out = []
    for metric, label, spec in (("success_rate", "success rate", ".2f"),
                                ("steps_mean", "steps (mean)", ".0f"),
                                ("fn_mean", "final F_N [kPa] (mean)", ".2f"),
                                ("tracking_error", "mean abs(ŝ − s_d)", ".3f")):
        out += [f"**{label}** ({sweep['runs']} runs per point, k = {sweep['k']}, simulated rig)", "",
                "| method | " + " | ".join(f"s_d {x:g}" for x in sds) + " |",
                "|---|" + "---|" * len(sds)]
        for name, _, by_sd in lines:
            cells = [fmt(by_sd.get(repr(x), {}).get(metric), spec) for x in sds]
            out.append(f"| {name} | " + " | ".join(cells) + " |")
        out.append("")
    inj_err = [rows_s.get("injection", {}).get(repr(x), {}).get("tracking_error", math.nan) for x in sds]
    n_success = sum(r.get("success_rate", 0) > 0 for m in rows_s for r in rows_s[m].values())
    out += ["Reading it (simulated rig):", ""]
    if n_success == 0:
        out.append("* With the paper's label no method succeeds at any s_d, so the paper's prediction "
                   "(electrodes failing above 0.7) cannot be tested with it on this simulated rig.")
    n_paper = len([m for m in TABLE_METHODS if m in rows_s])
    for i, (name, _, by_sd) in enumerate(lines):
        held = [x for x in sds if by_sd.get(repr(x), {}).get("success_rate", 0) >= 0.5]
        if i < n_paper and not held:       # the paper's label: only the rows that hold somewhere
            continue
        out.append(f"* {name}{' (the paper’s label)' if i < n_paper else ''}: holds in at least half the runs "
                   f"at s_d " + (", ".join(f"{x:g}" for x in held) or "none")
                   + " of " + ", ".join(f"{x:g}" for x in sds) + ".")
    if np.isfinite(inj_err).any():
        out.append(f"* Tracking error |ŝ − s_d| of injection over s_d: {fmt(np.nanmin(inj_err), '.3f')}"
                   f"–{fmt(np.nanmax(inj_err), '.3f')}.")
    return "\n".join(out)


def render_labels(labels: dict | None, main_rows: dict) -> str:
    """Return the Table per training label through the graph: the paper's pseudo label (the Table
    above) beside the others, method by method."""
    if not labels:
        return "(not run yet: `slip reproduce stabilization`)"
    out = ["| method | label | success rate | y (mm) | F_N (kPa) | steps | paper's success, y, F_N |",
           "|---|---|---|---|---|---|---|"]
    for m in TABLE_METHODS:
        p = PAPER_TABLE[m]
        if not any(m in v["rows"] for v in labels.values()):
            continue
        for label, rows in (("pseudo", main_rows), *((k, v["rows"]) for k, v in labels.items())):
            d = rows.get(m)
            if not d or m == "none":
                continue
            out.append(f"| {METHOD_LABELS[m]} | {label} | {fmt(d.get('success_rate'))} | {fmt(d.get('y_mean'))} ± "
                       f"{fmt(d.get('y_std'))} | {fmt(d.get('fn_mean'))} ± {fmt(d.get('fn_std'))} | "
                       f"{fmt(d.get('steps_mean'), '.0f')} | {fmt(p['success'])}, {fmt(p['y'])}, {fmt(p['fn'])} |")
    some = next(iter(labels.values()))
    return "\n".join([f"{some['runs']} runs per method and label through `launch stabilize.yaml label:=LABEL` "
                      f"(the shipped models of that label; the Table's seeds and materials, s_d = {some['s_d']}, "
                      f"k = {some['k']}); simulated rig, not measurements.", "", *out])


def render_extension(r: dict | None, main_rows: dict) -> str:
    """Return the extension's table (beside the Table's row of the same method) and reading."""
    if not r:
        return ("(not run yet: `slip reproduce stabilization --methods injection "
                "--model runs/extension/injection_true_ratio.npz`)")
    row, main = r["row"], main_rows.get(r["method"], {})

    def line(name, d):
        return (f"| {name} | {fmt(d.get('success_rate'))} | {fmt(d.get('y_mean'))} ± "
                f"{fmt(d.get('y_std'))} | {fmt(d.get('fn_mean'))} ± {fmt(d.get('fn_std'))} | "
                f"{fmt(d.get('steps_mean'), '.0f')} | {fmt(d.get('tracking_error'), '.3f')} |")
    table = ["| injection model (simulated rig) | success rate | y (mm) | F_N (kPa) | steps | "
             "mean abs(ŝ − s_d) |", "|---|---|---|---|---|---|"]
    if main:
        table.append(line("pseudo label (shipped, the Table above)", main))
    table.append(line(f"true ratio (extension, `{r['model']}`)", row))
    det = r.get("runs_detail", [])
    lim = [d for d in det if not d.get("success")
           and d.get("final_force_kpa", 0) >= control.SAFETY_LIMIT_KPA - 1e-6]
    low = [d for d in det if not d.get("success") and d not in lim]
    low_txt = ", ".join(f"{d['material']} at F_N {d['final_force_kpa']:.2f} kPa" for d in low)
    lim_txt = (f"{len(lim)} failed by reaching the F_N limit (after {', '.join(str(d['steps']) for d in lim)} steps)"
               if lim else "none reached the F_N limit")
    reading = (f"Reading it (simulated rig, extension): {sum(bool(d.get('success')) for d in det)} of "
               f"{len(det)} runs held all {r['steps']} steps (pseudo-label model: success rate "
               f"{fmt(main.get('success_rate'))}); {lim_txt} and {len(low)} failed on y > 1.5 mm"
               + (f" ({low_txt}). " if low else ". ")
               + ("So changing only the training target moves the loop towards holding, consistent "
                  "with the diagnosis that the pseudo label is a main cause here; "
                  if row.get("success_rate", 0) > main.get("success_rate", 0) else
                  "So changing only the training target does not make the loop hold; ")
               + "the true-ratio model's held-out RMSE to the true ratio is "
               f"{fmt(r.get('model_test_rmse'), '.3f')}.")
    return "\n".join([
        f"{r['runs']} runs through `launch stabilize.yaml method:={r['method']} model:=...` "
        f"(same seeds and materials as the Table, s_d = {r['s_d']}, k = {r['k']}, at most "
        f"{r['steps']} steps; model sha256 {r['model_sha256'][:8]}…, header label "
        f"`{r['label']}`). Regenerate: `slip reproduce stabilization --methods {r['method']} "
        f"--model {r['model']}`.", "", *table, "", reading])
