"""Rig identification, the outputs: the params overlay (only the identified parameters, each with
its value, 95 % interval and provenance) and the files a run writes (results with every period,
the overlay, the pictures of `identify.figures`)."""
from __future__ import annotations

import datetime as _dt
import math
from dataclasses import asdict
from pathlib import Path

from .protocol import Record

# what an overlay entry without an interval says: the plan left nothing to bound it with
UNBOUNDED = "too few levels or trials to bound it: identify with 3 or more F_N levels"


def overlay(results: dict, protocol: str = "launch identify.yaml", date: str | None = None) -> dict:
    """Return the params overlay: only the identified parameters, each {value, unit, source,
    interval}, plus the inputs used and the provenance (sim.scene.load_params(..., overlay=)
    applies it)."""
    inp, stiff, lag = results["inputs"], results["stiffness"], results["lag"]
    date = date or _dt.date.today().isoformat()
    src = f"identified ({protocol}, rig {inp['rig']}, material {inp['material']}, {date})"
    doc: dict = {"provenance": {"date": date, "rig": inp["rig"], "material": inp["material"], "protocol": protocol,
                                "inputs": {k: inp[k] for k in ("spring_n_per_mm", "spring_rel_sd", "newton_per_kpa",
                                                               "gain_rel_sd")}}}

    def entry(value, unit, interval, what, positive=False):
        out = {"value": float(value), "unit": unit, "source": f"{src}: {what}"}
        if not all(math.isfinite(v) for v in interval):    # e.g. two levels fit k_b exactly
            out["source"] += f"; no interval ({UNBOUNDED})"
        elif positive and interval[0] <= 0:                # a noisy pair of levels: t95(1) = 12.7
            out["source"] += f"; no interval (it reaches {interval[0]:.3g}: {UNBOUNDED})"
        else:
            out["interval"] = [float(interval[0]), float(interval[1])]
        return out

    pre, ss = {}, {}
    if "k_ref" in stiff:
        pre["bulk_shear_n_per_mm"] = entry(stiff["k_ref"], "N/mm", stiff["k_ref_interval"],
                                           f"k_b at {stiff['ref_force_n']:g} N from {stiff['levels']} ramps",
                                           positive=True)
        pre["bulk_ref_force_n"] = {"value": float(stiff["ref_force_n"]), "unit": "N", "source": f"{src}: reference force"}
        pre["bulk_stiffening_exponent"] = entry(stiff["beta"], "-", stiff["beta_interval"], "log-log slope of k_b(F_N)")
    if lag:
        ss["friction_limit_lag_s"] = entry(lag["tau_s"], "s", lag["tau_interval"],
                                           f"slide onsets after F_N steps ({lag['trials']} trials)")
    rel = inp["spring_rel_sd"]
    ss["spring_n_per_mm"] = entry(inp["spring_n_per_mm"], "N/mm",
                                  [inp["spring_n_per_mm"] * (1 - 1.96 * rel), inp["spring_n_per_mm"] * (1 + 1.96 * rel)],
                                  "input (measured by hand)")
    g, grel = inp["newton_per_kpa"], inp["gain_rel_sd"]
    doc["contact"] = {"newton_per_kpa": entry(g, "N/kPa", [g * (1 - 1.96 * grel), g * (1 + 1.96 * grel)],
                                              "input (measured by hand)")}
    if pre:
        doc["pre_slip"] = pre
    doc["stick_slip"] = ss
    if "mu" in stiff:
        doc["materials"] = {inp["material"]: {"mu_identified": entry(stiff["mu"], "-", stiff["mu_interval"],
                                                                      f"Q/F_N at onset, {stiff['mu_levels']} levels",
                                                                      positive=True)}}
    return doc


def write_outputs(results: dict, records: list[Record], out_dir, protocol: str = "launch identify.yaml") -> dict:
    """Write results JSON (with every period), the params overlay YAML and the pictures into
    out_dir; return {what: path}. A picture that cannot be drawn is reported, never loses data."""
    import json

    import yaml

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"results": out_dir / "identify_results.json", "overlay": out_dir / "identify_overlay.yaml"}
    doc = {**results, "records": [asdict(r) for r in records]}
    paths["results"].write_text(json.dumps(doc, indent=1, default=float))
    ov = overlay(results, protocol)
    header = ("# Params overlay of an identified rig (docs/identification.md): only the identified parameters,\n"
              "# each with its 95 % interval; use it with --params (slip reproduce validation --params FILE).\n")
    paths["overlay"].write_text(header + yaml.safe_dump(ov, sort_keys=False))
    try:
        from .figures import figures

        paths.update(figures(results, records, out_dir))
    except Exception as exc:     # a figure never costs the measurements
        paths["figure_error"] = f"pictures not drawn: {exc}"
    return {k: str(v) for k, v in paths.items()}
