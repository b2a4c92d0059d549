"""How long each experiment takes: measured wall times, kept in docs/figures/reproduce_times.json.

`slip reproduce all` (and `slip reproduce NAME` on the full budget with docs) records each
experiment's wall time, the load average beside it and the date; `slip reproduce --list` shows
them and every docs page an experiment writes gets a `NAME-time` block rendered from this file,
so the page says what reproducing it costs and what its quick preview leaves out.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import os
from pathlib import Path

from incipient_slip.paths import docs_dir

TIMES_FILE = "reproduce_times.json"
# options that change an experiment's size: a run with any of them is not the budget's time
SIZE_OPTIONS = ("series", "runs", "steps", "max_train", "maxfev", "estimation_series", "points", "seeds",
                "sweep_runs", "tune_k", "sweep", "joint", "model", "sweep_at", "labels", "label_methods",
                "sets")


def times_path(docs: Path | None = None) -> Path:
    """Return the times file in `docs`/figures (default the repository's docs/)."""
    return Path(docs if docs is not None else docs_dir()) / "figures" / TIMES_FILE


def load_times(docs: Path | None = None) -> dict:
    """Return {experiment: {budget: entry}} (empty when there is no file yet)."""
    path = times_path(docs)
    try:
        return json.loads(path.read_text()).get("experiments", {})
    except (OSError, ValueError):
        return {}


def record_time(name: str, budget: str, seconds: float, load: tuple[float, float], docs: Path | None = None,
                jobs: int = 2) -> dict:
    """Store one measured wall time of experiment `name` on `budget`; return the entry."""
    path = times_path(docs)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        data = {}
    entry = {"seconds": round(float(seconds), 1), "load_average": [round(float(v), 2) for v in load],
             "cores": os.cpu_count(), "jobs": int(jobs),
             "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d")}
    data.setdefault("experiments", {}).setdefault(name, {})[budget] = entry
    data["experiments"] = {k: data["experiments"][k] for k in sorted(data["experiments"])}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    return entry


def duration(seconds: float | None) -> str:
    """Return '42 s' or '3.4 min' ('–' when unknown)."""
    if seconds is None or not math.isfinite(seconds):
        return "–"
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def entry_text(entry: dict | None) -> str:
    """Return '3.4 min (load 2.1, 2026-11-26)' or 'not measured yet'."""
    if not entry:
        return "not measured yet"
    load = entry.get("load_average") or []
    where = f"load {max(load):.1f}, " if load else ""
    note = f"; {entry['note']}" if entry.get("note") else ""
    return f"{duration(entry.get('seconds'))} ({where}{entry.get('date', '?')}{note})"


def list_line(name: str, times: dict) -> str:
    """Return the 'full ..., quick ...' part of `slip reproduce --list` for one experiment."""
    t = times.get(name, {})
    full, quick = ((t.get(b) or {}).get("seconds") for b in ("full", "quick"))
    return f"full {duration(full)}, quick {duration(quick)}"


def time_block(name: str, module, times: dict) -> dict[str, str]:
    """Return {f'{name}-time': markdown}: the full and quick wall times and what --quick leaves out."""
    t = times.get(name, {})
    return {f"{name}-time": (
        f"*Time to reproduce on a 2-core machine:* `slip reproduce {name}` (the full budget behind these "
        f"numbers) {entry_text(t.get('full'))}; `slip reproduce {name} --quick` {entry_text(t.get('quick'))}. "
        f"The quick budget is a preview (runs/{name}-quick/, never docs/): {module.QUICK}. Wall times "
        "are measured by `slip reproduce all` (`make reproduce`), which rewrites this line, on a machine "
        "shared with other jobs (load average beside each).")}
