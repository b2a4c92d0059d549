"""The validation's plan: every option checked and every usage error raised before a cluster
starts; `--plan` prints it."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from incipient_slip import control
from incipient_slip.cluster import check_scheduler
from incipient_slip.errors import UsageError

from .overlays import merge_overlays, overlay_points
from .spec import LABEL_METHODS, POINTS, QUICK_POINTS, QUICK_REFITS, RESULTS, joint_points


def budget(settings) -> dict:
    """Return the points, runs, series, steps and refits of the budget (the options override them)."""
    opt = settings.option
    return {"points": opt("points", [] if (opt("joint", False) or opt("sweep_at"))
                          else list(settings.pick(QUICK_POINTS, POINTS))),
            "runs": opt("runs", settings.pick(2, 10)), "series": opt("series", settings.pick(30, 100)),
            "steps": opt("steps", control.MAX_STEPS),      # quick too: shorter runs would all "succeed"
            "refits": opt("refits", settings.pick(QUICK_REFITS, None))}


@dataclasses.dataclass
class Plan:
    """What a validation run will do, checked before any cluster starts (`plan`; `--plan` prints it)."""

    names: list                     # the one-at-a-time (or identified rig's) points whose Table runs
    runs: int
    n_series: int
    steps: int
    refits: tuple | None
    joint: bool                     # refit every joint point, the Table where consistent
    grid: dict                      # the joint set {name: overrides}
    sweep_at: list                  # joint points run again with the s_d sweep
    sweep_runs: int | None
    scheduler: str | None
    workers: int
    work: Path
    old: dict = dataclasses.field(default_factory=dict)   # kept results (--keep, or the committed page's)
    kept_from: Path | None = None
    rig_points: dict = dataclasses.field(default_factory=dict)   # an identified rig's points (--params)
    provenance: dict | None = None
    rig_materials: tuple | None = None

    def sweep_of(self, name: str) -> int:
        """Runs per s_d of a point's sweep (0: none; a joint point only when --sweep-at)."""
        if name in self.sweep_at:
            return self.sweep_runs or 3
        return 0 if name in self.grid else (self.sweep_runs or 0)

    def describe(self) -> str:
        """Return the plan as lines a user can read before anything runs."""
        lines = [f"validation plan: {self.runs} runs per method, {self.n_series} training series per data set, "
                 f"{self.steps} steps per run; {'a running scheduler ' + self.scheduler if self.scheduler else f'a LocalCluster of {self.workers} workers'}"]
        if self.rig_points:
            lines.append(f"identified rig ({(self.provenance or {}).get('material')}): {len(self.rig_points)} points, "
                         f"no refit: {', '.join(self.rig_points)}")
        elif self.names:
            lines.append(f"one-at-a-time points ({len(self.names)}), each refitted to T1-T4' and T7, then the Table "
                         f"per label: {', '.join(self.names)}")
        elif not self.old.get("points"):
            lines.append("one-at-a-time points: none run and none kept (--keep RESULTS_JSON keeps a run's)")
        if self.joint:
            lines.append(f"joint set: {len(self.grid)} refits, the Table at each consistent one")
        if self.names or self.joint:
            lines.append(f"labels: pseudo (every method and the oracle); measured-ratio ({', '.join(LABEL_METHODS)}) at "
                         "the fitted point and where the refit meets the targets, and with the point's friction lag "
                         "as if identified where it has one (docs/estimation.md)")
        if self.sweep_at:
            lines.append(f"s_d sweep ({self.sweep_runs or 3} runs per cell) at: {', '.join(self.sweep_at)}")
        elif self.sweep_runs:
            lines.append(f"s_d sweep ({self.sweep_runs} runs per cell) at every one-at-a-time point")
        if self.kept_from:
            kept = [n for n in self.old.get("points", {}) if n not in self.names]
            lines.append(f"kept from {self.kept_from}: " + ", ".join(
                (["the joint set"] if "joint" in self.old and not self.joint else []) + kept or ["nothing"]))
        return "\n".join(lines)


def plan(settings) -> Plan:
    """Return the run's plan from the options; every usage error is raised here, before a cluster starts."""
    opt = settings.option
    joint = bool(opt("joint", False))
    b = budget(settings)
    names, runs, n_series, steps, refits = (b[k] for k in ("points", "runs", "series", "steps", "refits"))
    for label, v in (("--runs", runs), ("--series", n_series), ("--steps", steps)):
        if v < 1:
            raise UsageError(f"{label} must be >= 1, got {v}")
    scheduler = check_scheduler(opt("scheduler"))
    keep = _keep_file(settings, joint)
    old = _read_kept(keep)
    rig_points, provenance, rig_materials = {}, None, None
    if opt("params"):
        rig_points, provenance, rig_materials = _identified_rig(settings, joint)
        names = list(rig_points)
    grid = joint_points()
    sweep_at = opt("sweep_at") or []
    for n in sweep_at:
        if n not in grid:
            raise UsageError(f"--sweep-at {n!r}: not a point of the joint set (e.g. {next(iter(grid))!r})")
    if sweep_at and not joint and "joint" not in old:
        raise UsageError("--sweep-at needs the joint results: add --joint, or --keep a results file that has them")
    return Plan(list(names), runs, n_series, steps, refits, joint, grid, list(sweep_at), opt("sweep_runs"),
                scheduler, opt("workers", settings.jobs), Path(settings.work) / "data", old,
                Path(keep) if keep else None, rig_points, provenance, rig_materials)


def _keep_file(settings, joint: bool):
    """The results file whose points not run this time are kept: --keep, or into the docs without
    --joint the committed page's."""
    opt = settings.option
    keep = opt("keep")
    if keep is None and not joint and settings.docs is not None and not opt("params"):
        # the page's joint set (hours of refits before issue 22) is not rerun without --joint:
        # keep it as committed instead of dropping it from the page
        committed = settings.results_file(RESULTS)
        if committed.is_file():
            keep = committed
    return keep


def _read_kept(keep) -> dict:
    if not keep:
        return {}
    import json
    try:
        return json.loads(Path(keep).read_text())
    except (OSError, ValueError) as e:
        raise UsageError(f"--keep {keep}: {e}") from None


def _identified_rig(settings, joint: bool) -> tuple[dict, dict, tuple | None]:
    """Return an identified rig's points, provenance and materials from its overlays (--params)."""
    from incipient_slip.sim.scene import SceneError, load_overlay

    opt = settings.option
    if settings.docs is not None:
        raise UsageError("--params predicts the Table of one identified rig: its page goes to --out, not into --docs")
    if joint or opt("points") or opt("sweep_at"):
        raise UsageError("--params runs the identified rig's own points; leave out --joint, --points and --sweep-at")
    try:
        doc = merge_overlays([load_overlay(path) for path in opt("params")])
        rig_points = overlay_points(doc)
    except SceneError as exc:
        raise UsageError(str(exc)) from None
    rig_materials = tuple(doc.get("materials", {})) or None   # the Table on the identified object(s)
    return rig_points, doc["provenance"], rig_materials
