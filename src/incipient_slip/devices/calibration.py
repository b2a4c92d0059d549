"""The rig's calibration file: what `slip calibrate` measured, read by the nodes that need it.

`config/rig.yaml` names the file (`calibration: calibration.yaml`, a path relative to rig.yaml);
`slip calibrate pdc | spring | press-gain` each write one section of it, keeping the others, and
`slip calibrate show` prints it. One section per calibration:

| section | value | who reads it |
|---|---|---|
| `pdc` | `newton_per_kpa` (N of normal force per kPa of tared P_DC), `rel_sd` | the rig identification (`launch identify.yaml rig:=hardware`, its `newton_per_kpa`, `gain_rel_sd`) |
| `spring` | `spring_n_per_mm`, `rel_sd`, `slack_mm` (stage position at zero spring force, from `start_mm`) | the rig identification (`spring_n_per_mm`, `spring_rel_sd`) and a data set's F_T from recordings |
| `press_gain` | `gain_mm_per_kpa` | the `ur5` node (its section's parameter of that name, through `rig_config`) |

Each section also keeps its measured points, the fit's residual, the date and the instrument the
operator named, so that a number in the file can be traced to the session that made it.
`node_values(rig_config, section)` is how a node takes them (`devices.rig_config.apply_rig_config`):
precedence node default < rig.yaml section < calibration < launch file / command line; a key set
both in rig.yaml's section and by the calibration is a named error (two places for one number).
"""
from __future__ import annotations

import datetime
import math
from pathlib import Path

import numpy as np
import yaml

from incipient_slip.devices.rig_config import load_document
from incipient_slip.errors import UsageError

__all__ = ["SECTIONS", "NODE_PARAMS", "path_of", "load", "save_section", "node_values", "fit_line",
           "press_gain"]

SECTIONS = ("pdc", "spring", "press_gain")
# node section of rig.yaml -> {parameter: (calibration section, key)}
NODE_PARAMS = {"ur5": {"gain_mm_per_kpa": ("press_gain", "gain_mm_per_kpa")}}


def path_of(rig_config: str | Path) -> Path | None:
    """The calibration file rig.yaml names (`calibration:`, relative to rig.yaml), or None."""
    rig_config = Path(rig_config)
    doc = load_document(rig_config)
    name = doc.get("calibration") if isinstance(doc, dict) else None
    if name is None:
        return None
    if not isinstance(name, str) or not name:
        raise UsageError(f"rig_config {rig_config}: calibration must be a file name, got {name!r}")
    return rig_config.parent / name


def load(rig_config: str | Path) -> dict:
    """The calibration sections of the file rig.yaml names ({} when it names none or the file
    does not exist yet: nothing calibrated); UsageError for a file that is not a calibration."""
    path = path_of(rig_config)
    if path is None or not path.exists():
        return {}
    try:
        doc = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise UsageError(f"calibration {path}: not valid YAML ({exc})") from None
    if not isinstance(doc, dict) or set(doc) - set(SECTIONS):
        raise UsageError(f"calibration {path}: expected sections of {', '.join(SECTIONS)}, got "
                         f"{', '.join(map(str, doc)) if isinstance(doc, dict) else type(doc).__name__}")
    for name, section in doc.items():
        if not isinstance(section, dict):
            raise UsageError(f"calibration {path}: section {name} is not a mapping")
    return doc


def save_section(rig_config: str | Path, section: str, values: dict) -> Path:
    """Writes `section` of the calibration file (the others kept); returns the file's path."""
    if section not in SECTIONS:
        raise ValueError(f"unknown calibration section {section!r}")
    path = path_of(rig_config)
    if path is None:
        raise UsageError(f"rig_config {rig_config} names no calibration file: add the line "
                         f"`calibration: calibration.yaml` (a path relative to it)")
    doc = load(rig_config)
    doc[section] = {**values, "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    tmp = path.with_name(path.name + ".new")
    tmp.write_text("# written by `slip calibrate` (docs/hardware/setup.md, \"Calibration\"); "
                   "one section per calibration\n" + yaml.safe_dump(doc, sort_keys=False))
    tmp.replace(path)
    return path


def node_values(rig_config: str | Path, node_section: str, rig_values: dict) -> dict:
    """The parameters of `node_section` that the calibration sets; UsageError when rig.yaml's
    section sets one of them too."""
    wanted = NODE_PARAMS.get(node_section, {})
    if not wanted:
        return {}
    doc = load(rig_config)
    out = {}
    for param, (section, key) in wanted.items():
        if key in doc.get(section, {}):
            if param in rig_values:
                raise UsageError(f"rig_config {rig_config} [{node_section}] sets {param}, which the "
                                 f"calibration file {path_of(rig_config)} [{section}] sets too: "
                                 f"remove it from rig.yaml (one place for one number)")
            out[param] = doc[section][key]
    return out


def fit_line(x, y) -> tuple[float, float, float, float]:
    """Least squares y = slope x + intercept: (slope, intercept, slope's standard error, RMS
    residual). ValueError with fewer than 3 points or x without spread."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size < 3:
        raise ValueError(f"a line needs at least 3 points, got {x.size}")
    sxx = float(np.sum((x - x.mean()) ** 2))
    if not sxx > 0:
        raise ValueError("all points at the same x")
    slope = float(np.sum((x - x.mean()) * (y - y.mean())) / sxx)
    intercept = float(y.mean() - slope * x.mean())
    resid = y - (slope * x + intercept)
    se = math.sqrt(float(np.sum(resid ** 2)) / (x.size - 2) / sxx)
    return slope, intercept, se, float(np.sqrt(np.mean(resid ** 2)))


def press_gain(depth_mm, kpa, lo_kpa: float, hi_kpa: float, fraction: float) -> tuple[float, float]:
    """(gain_mm_per_kpa, stiffness kPa/mm) for the ur5 node's press loop from a depth sweep.

    The loop moves gain x (target - measured) each period; on a contact of stiffness s (kPa/mm)
    the error shrinks by (1 - gain s) a period: no overshoot while gain s <= 1. A finger stiffens
    as it is pressed, so the gain is `fraction` / the steepest stiffness met in [lo_kpa, hi_kpa]
    (the secant between neighbouring points whose mean P_DC lies in it): gain s <= fraction
    everywhere in the working range. ValueError when no secant lies in the range.
    """
    d, p = np.asarray(depth_mm, float), np.asarray(kpa, float)
    slopes = [(p[i + 1] - p[i]) / (d[i + 1] - d[i]) for i in range(d.size - 1)
              if lo_kpa <= (p[i] + p[i + 1]) / 2 <= hi_kpa and d[i + 1] > d[i]]
    if not slopes:
        raise ValueError(f"no two neighbouring points with P_DC between {lo_kpa:g} and {hi_kpa:g} kPa")
    stiffness = float(max(slopes))
    if not stiffness > 0:
        raise ValueError(f"P_DC does not rise with the press depth (steepest {stiffness:.3g} kPa/mm)")
    return fraction / stiffness, stiffness
