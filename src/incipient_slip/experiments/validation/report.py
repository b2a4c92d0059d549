"""The docs blocks of docs/validation.md from the results alone (`render`; `--render-only`)."""
from __future__ import annotations

from ..timing import duration
from .spec import CONTROLLED, LABELS, PAPER, SWEEP_SD, TABLE_METHODS


def _outcome(t: dict) -> str:
    """A method's cell: success rate (mean final y, mean final F_N); no action has no rate."""
    rate = "-" if t["success"] is None else f"{t['success']:.1f}"
    return f"{rate} ({t['y']:.2f} mm, {t['fn']:.1f} kPa)"


def _cell(v, fmt="{:.2f}") -> str:
    return "–" if v is None else fmt.format(v)


def render(results: dict) -> dict:
    """Return the Table at the fitted point beside the paper's, and success over the uncertainty set."""
    if results.get("rig"):
        return {"validation-rig": render_rig(results)}
    pts = results["points"]
    head = (f"Simulated rig, not measurements: {results['runs']} runs per method, {results['steps']} steps, models "
            f"trained on {results['series']} simulated series per data set (quick SVR), budget `{results['budget']}`.")
    blocks = {}
    if "fitted" in pts:
        blocks["validation-fitted"] = _render_fitted(results, head)
    blocks["validation-answer"] = render_answer(results)
    methods = list(CONTROLLED)
    if results.get("joint"):
        blocks["validation-joint"] = _render_joint(results, head, methods)
    if not pts:
        return blocks
    blocks["validation-set"] = _render_set(results, head, methods)
    sweep = _render_sweep(results)
    if sweep:
        blocks["validation-sweep"] = sweep
    return blocks


def _render_fitted(results: dict, head: str) -> str:
    """The Table at the fitted point beside the paper's, the oracle and the trajectory figure."""
    t = results["points"]["fitted"]["table"]
    lines = [head, "", "| | " + " | ".join(LABELS[m] for m in TABLE_METHODS) + " |",
             "|---|" + "---|" * len(TABLE_METHODS)]
    for key, label, fmt, idx in (("success", "success rate", "{:.1f}", 0), ("y", "y [mm]", "{:.2f}", 1),
                                 ("fn", "F_N [kPa]", "{:.2f}", 2), ("steps", "steps", "{:.0f}", 3)):
        lines.append(f"| {label}, simulated | " + " | ".join(_cell(t[m][key], fmt) for m in TABLE_METHODS) + " |")
        lines.append(f"| {label}, paper | " + " | ".join(_cell(PAPER[m][idx], fmt) for m in TABLE_METHODS) + " |")
    lines.append("| score, simulated | " + " | ".join(f"{t[m]['score']:.2f}" for m in TABLE_METHODS) + " |")
    o = t["oracle"]
    lines += ["", f"Oracle (diagnostic, the law on the simulator's true load ratio): success {o['success']:.1f}, "
              f"y {o['y']:.2f} mm, F_N {o['fn']:.2f} kPa."]
    if results.get("trajectory"):
        f = results["trajectory"]
        lines += ["", f"![simulated rig: one controlled run per method](figures/{f})",
                  f"*Simulated rig, not a measurement: `{f}` (the Table's first run at the fitted point, "
                  f"with the models trained at that point; the paper's trajectory shape is held out).*"]
    return "\n".join(lines)


def _render_set(results: dict, head: str, methods: list) -> str:
    """Each one-at-a-time point: its refit, its consistency and every controlled method's outcome."""
    lines = [head, "", "| point | consistent with T1-T4', T7 | k_b [N/mm] | k_s [N/mm] | "
             + " | ".join(LABELS[m] for m in methods) + " |", "|---|---|---|---|" + "---|" * len(methods)]
    for name, p in results["points"].items():
        v = p["fit"]["values"]
        lines.append(f"| {name} | {'yes' if p['consistent'] else 'no'} | {v['pre_slip.bulk_shear_n_per_mm']:.3f} | "
                     f"{v['stick_slip.spring_n_per_mm']:.4f} | " + " | ".join(
                         _outcome(p['table'][m])
                         for m in methods) + " |")
    lines += ["", "Cells: success rate (mean final y, mean final F_N).", "",
              f"![simulated rig: success over the uncertainty set](figures/{results['figure']})",
              f"*Simulated rig, not a measurement: `{results['figure']}`.*"]
    return "\n".join(lines)


def _render_sweep(results: dict) -> str | None:
    """The s_d sweep at every point that has one (one-at-a-time and joint), or None."""
    swept = {**results["points"], **(results.get("joint") or {}).get("points", {})}
    sw = {n: p["sweep_table"] for n, p in swept.items() if p.get("sweep_table")}
    if not sw:
        return None
    n_sweep = max(len(r) for p in swept.values() for by_sd in p.get("sweep", {}).values() for r in by_sd.values())
    lines = [f"Simulated rig, not measurements: {n_sweep} runs per cell (seeds other than the Table's), "
             f"{results['steps']} steps, the point's own models.", "", "| point | method | " + " | ".join(f"s_d {sd}" for sd in SWEEP_SD) + " |",
             "|---|---|" + "---|" * len(SWEEP_SD)]
    for name, t in sw.items():
        for m, by_sd in t.items():
            lines.append(f"| {name} | {LABELS[m]} | " + " | ".join(
                _outcome(by_sd[str(sd)])
                for sd in SWEEP_SD) + " |")
    lines += ["", "Cells: success rate (mean final y, mean final F_N)."]
    return "\n".join(lines)


def render_rig(results: dict) -> str:
    """Return the Table predicted for an identified rig (`--params`), at its values and interval ends."""
    rig, methods = results["rig"], list(TABLE_METHODS) + ["oracle"]
    lines = [f"Prediction on the simulated rig fitted to an identified rig, not a measurement: rig "
             f"{rig.get('rig')}, material {rig.get('material')}, identified {rig.get('date')} "
             f"({rig.get('protocol')}); {results['runs']} runs per method, {results['steps']} steps, models trained "
             f"on {results['series']} simulated series per data set (quick SVR), budget `{results['budget']}`.", "",
             "| point | " + " | ".join(LABELS[m] for m in methods) + " |", "|---|" + "---|" * len(methods)]
    for name, p in results["points"].items():
        lines.append(f"| {name} | " + " | ".join(_outcome(p["table"][m]) for m in methods) + " |")
    lines += ["", "Cells: success rate (mean final y, mean final F_N). Rows: the overlay's values, then each "
              "identified parameter at one end of its interval with the others at their values."]
    return "\n".join(lines)


ANSWER_METHODS = ("oracle", "injection", "e10", "e19")


def _label_bias(fit: dict) -> str:
    return _bias((fit.get("summary") or {}).get("label_error_by_fn"))


def render_answer(results: dict) -> str:
    """Return the one answer at the top of docs/validation.md: can the paper's method hold the object
    at the fitted point, where in the uncertainty set the oracle, injection, E10 and E19 hold, and
    the pseudo label's bias by F_N there."""
    pts = dict(results.get("points", {}))
    pts.update({n: p for n, p in (results.get("joint") or {}).get("points", {}).items() if p.get("table")})
    joint_runs = (results.get("joint") or {}).get("runs")
    lines = ["Simulated rig (v3), not measurements; the paper's protocol (a run stops at the 6 kPa limit or after "
             f"{results['steps']} steps and is judged on its end state); {results['runs']} runs per method at the "
             "one-at-a-time points" + (f", {joint_runs} at the joint points (named with all three parameters)"
                                       if joint_runs else "") + "."]
    fitted = pts.get("fitted")
    if fitted and fitted.get("table"):
        lines += _answer_fitted(fitted)
    ok = {n: p for n, p in pts.items() if p.get("table") and p.get("consistent")}
    if ok:
        lines += _answer_set(ok) + _answer_held(ok) + _answer_own_lag(ok)
    return "\n".join(lines)


def _answer_fitted(fitted: dict) -> list[str]:
    """The fitted point's line (a sentence per other label) and its estimation per label."""
    t = fitted["table"]
    lines = ["", f"**At the fitted point:** injection {t['injection']['success']:.1f} "
             f"(y {t['injection']['y']:.2f} mm, F_N {t['injection']['fn']:.2f} kPa), oracle {t['oracle']['success']:.1f} "
             f"(y {t['oracle']['y']:.2f} mm, F_N {t['oracle']['fn']:.2f} kPa), E10 {t['e10']['success']:.1f}, "
             f"E19 {t['e19']['success']:.1f}; paper: injection 1.0, E10 1.0, E19 0.8."]
    for key, table, _ in label_tables(fitted)[1:]:
        i = table["injection"]
        lines[-1] += (f" With the {key} label: injection {i['success']:.1f} (y {i['y']:.2f} mm, F_N {i['fn']:.2f} kPa), "
                      f"E10 {_success(table.get('e10'))}, E19 {_success(table.get('e19'))}.")
    for key, row in (fitted.get("labels") or {}).items():
        lines += ["", f"*Estimation at the fitted point, {key} label* (held-out series of the point's data set; "
                  "RMSE against the model's own label / against the true load ratio): " + ", ".join(
                      f"{LABELS[m]} {row['rmse'][m]:.3f} / {row['rmse_truth'][m]:.3f}" for m in row["rmse"]) + "."]
    return lines


def _answer_set(ok: dict) -> list[str]:
    """The success table over the consistent points, a row per label the point was run with."""
    lines = ["", f"Success rate at every point consistent with the open-loop targets ({len(ok)} points), a "
             "row per training label where the point was run with it (docs/estimation.md: pseudo = the "
             "paper's; measured-ratio = nothing identified; lag identified = the point's lag as if "
             "`launch identify.yaml` measured it exactly), and the label minus the true load ratio by F_N "
             "over the point's collection series (every period; the pseudo label before its onset where "
             "the point predates the label rows). The oracle does not depend on the label:", "",
             "| point | label | " + " | ".join(LABELS[m].split(" (")[0] for m in ANSWER_METHODS)
             + " | label - truth by F_N |", "|---|---|" + "---|" * len(ANSWER_METHODS) + "---|"]
    for n, p in ok.items():
        for key, table, bias in label_tables(p):
            lines.append(f"| {n} | {key} | " + " | ".join(
                _success((p['table'] if m == 'oracle' else table).get(m)) for m in ANSWER_METHODS)
                + f" | {bias} |")
    return lines


def _answer_held(ok: dict) -> list[str]:
    """Per method and label: at how many of the consistent points it holds (success >= 0.8)."""
    lines = []
    keys = list(dict.fromkeys(key for p in ok.values() for key, _, _ in label_tables(p)))
    for m in ANSWER_METHODS:
        for key in (keys if m != "oracle" else ["pseudo"]):
            with_key = {n: t for n, p in ok.items() for k, t, _ in label_tables(p) if k == key and m in t}
            if not with_key:
                continue
            held = [n for n, t in with_key.items() if t[m]["success"] >= 0.8]
            who = LABELS[m].split(" (")[0] + ("" if m == "oracle" else f" ({key})")
            lines += ["", f"* {who} holds (success >= 0.8) at {len(held)} of {len(with_key)} points"
                      + (": " + "; ".join(held) if held and len(held) < len(with_key) else "")]
    return lines


def _answer_own_lag(ok: dict) -> list[str]:
    """Injection on the measured ratio with each point's own friction lag: where it holds."""
    own = {n: dict((k, t) for k, t, _ in label_tables(p)) for n, p in ok.items()}
    own = {n: t.get("measured-ratio, lag identified") or t.get("measured-ratio") for n, t in own.items()}
    own = {n: t for n, t in own.items() if t and "injection" in t}
    if not own:
        return []
    held = [n for n, t in own.items() if t["injection"]["success"] >= 0.8]
    missed = {n: t["injection"]["success"] for n, t in own.items() if n not in held}
    return ["", f"* injection (measured-ratio with the point's own friction lag: 0 where it has none, "
            f"identified where it has one) holds at {len(held)} of {len(own)} points"
            + ("; the others: " + "; ".join(f"{n} {v:.1f}" for n, v in missed.items()) if missed else "")]


def label_tables(p: dict) -> list:
    """Return [(label row, its Table, its label - truth by F_N)] of a point (pseudo only before the label rows)."""
    rows = p.get("labels") or {}
    out = [("pseudo", p["table"], _bias(rows.get("pseudo", {}).get("label_error_by_fn")) if rows
            else _label_bias(p.get("fit", {})))]
    return out + [(key, row["table"], _bias(row["label_error_by_fn"])) for key, row in rows.items()
                  if key != "pseudo" and row.get("table")]


def _success(row: dict | None) -> str:
    return f"{row['success']:.1f}" if row else "–"


def _bias(rows) -> str:
    # a mean that rounds to zero reads +0.00, never -0.00
    return ", ".join(f"{r['bin']} {r['mean'] if abs(r['mean']) >= 0.005 else 0.0:+.2f}" for r in rows or ()) or "–"


def task_times(pts: dict, cores: int = 16) -> str:
    """Return the joint set's per-task times (one single-threaded dask worker each) and what they
    add up to on 2 workers and on a `cores`-core cluster (where the longest task sets the time)."""
    refits = [p["fit"]["seconds"] for p in pts.values() if (p.get("fit") or {}).get("seconds")]
    tables = [p["seconds"] for p in pts.values() if p.get("table") and p.get("seconds")]
    if not refits and not tables:
        return "(no per-task times recorded)"
    span = lambda v: f"{min(v):.0f}–{max(v):.0f} s (sum {duration(sum(v))})" if v else "–"  # noqa: E731
    longest = max(refits or [0.0]) + max(tables or [0.0])
    return (f"Per-task times (simulated rig; one single-threaded dask worker per task, on the shared 2-core "
            f"machine): refits {span(refits)} for {len(refits)} of {len(pts)} points"
            + ("" if len(refits) == len(pts) else " (the others' refit time was not recorded by that run)")
            + f"; Tables {span(tables)} for {len(tables)} points. On 2 workers the recorded tasks take at least "
            f"{duration((sum(refits) + sum(tables)) / 2)}; on a {cores}-core cluster every point runs at once "
            f"and the longest refit plus the longest Table, {duration(longest)}, bounds the set "
            "(a refit is one Nelder-Mead fit, sequential; `--scheduler tcp://HOST:PORT` uses such a cluster).")


def _render_joint(results: dict, head: str, methods: list) -> str:
    """Return the joint set's block: which points the open-loop data allow, and the Table there."""
    joint = results["joint"]
    pts = joint["points"]
    ok = {n: p for n, p in pts.items() if p.get("table")}
    if "runs" in joint:
        fewer = " (fewer than the paper's 10, for time)" if joint["runs"] < 10 else ""
        head = (f"Simulated rig, not measurements: {joint['runs']} runs per method{fewer}, "
                f"{results['steps']} steps, models trained on {joint['series']} simulated series per data set (quick SVR).")
    lines = [head, "", f"{len(pts)} points, {len(ok)} consistent with T1-T4', T7 after their own refit.", "",
             "| point | T1 onset [mm] | T2 spread [mm] | T3 slips | T4' no-action y [mm] (slid) | T7 range [mm] | consistent |",
             "|---|---|---|---|---|---|---|"]
    for n, p in pts.items():
        f = p["fit"]["summary"]
        lines.append(f"| {n} | {f['T1']:.2f} | {f['T2']:.2f} | {f['T3']:.2f} | {f['T4']:.2f} ({f['T4_slid']:.2f}) | "
                     + "/".join(f"{v:.2f}" for v in f["T7"].values()) + f" | {'yes' if p['consistent'] else 'no'} |")
    lines += ["", "Closed loop at the consistent points (success rate, mean final y, mean final F_N):", "",
              "| point | k_b [N/mm] | k_s [N/mm] | " + " | ".join(LABELS[m] for m in methods) + " |",
              "|---|---|---|" + "---|" * len(methods)]
    for n, p in ok.items():
        v = p["fit"]["values"]
        lines.append(f"| {n} | {v['pre_slip.bulk_shear_n_per_mm']:.3f} | {v['stick_slip.spring_n_per_mm']:.4f} | "
                     + " | ".join(_outcome(p['table'][m]) for m in methods) + " |")
    lines += ["", task_times(pts)]
    if results.get("joint_figure"):
        f = results["joint_figure"]
        lines += ["", f"![simulated rig: success over the joint uncertainty set](figures/{f})",
                  f"*Simulated rig, not a measurement: `{f}`.*"]
    return "\n".join(lines)
