"""Recordings of the collection protocol -> the data set `slip train` reads (docs/design.md).

One recording (MCAP, `launch collect.yaml`) is one series. What a lab's rig measures becomes the
series' arrays; nothing the simulator alone knows is needed:

* the streams as recorded: P_AC frames, the slow channels (electrodes, P_DC, temperatures), the
  object's mocap travel; cut to start at period 0's start, the time origin (t = 0 s);
* the periods from the actuator's ticks: `ActuatorState(period=k)` is stamped at the end of
  period k and says where the stage stands after the period's step, so the stage during period k is
  tick k-1 (period 0: one step before tick 0; the paper's steps are equal);
* F_N per period: the robot's applied force (`RobotState`, the mean of those stamped in the
  period), or where no robot reports one (a press held by hand) P_DC above its tare, the mean
  over the period (`normal_force="pdc"` forces the latter);
* F_T = k_s * (u - y): the spring's extension, the stage during the period less the object's
  travel at the period's end, both from their positions at period 0 (the spring slack there);
  k_s from `spring_n_per_mm`, else the simulated rig's scene (rig sim or emulated);
* `/sim/truth` (simulated rig only) gives the truth columns; elsewhere they are NaN / False.

A defect is a `RecordingError` naming the file and what is wrong (missing topic, seq gap, a
stamp that goes back or jumps, an unfinished file, too few periods); a session import reports it
per file and goes on with the others.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from incipient_slip.graph.bag import BagError, read_bag
from incipient_slip.paths import written_atomically
from incipient_slip.messages import (
    PAC_RATE_HZ, PAC_SAMPLES_PER_FRAME, PERIOD_NS, SLOW_RATE_HZ, ActuatorState, BiotacPac, BiotacSlow,
    ObjectPose, PztState, RobotState, SimTruth,
)

TOPICS = (BiotacPac.TOPIC, BiotacSlow.TOPIC, ObjectPose.TOPIC, ActuatorState.TOPIC, RobotState.TOPIC,
          SimTruth.TOPIC, PztState.TOPIC)
REQUIRED = (BiotacSlow.TOPIC, ObjectPose.TOPIC, ActuatorState.TOPIC)   # P_AC: only with a vibration scene
NORMAL_FORCE_SOURCES = ("auto", "robot", "pdc")
CLOCK_JUMP_S = 0.25       # a stream whose stamps step further than this without a seq gap: a clock jump
MIN_PERIODS = 3


class RecordingError(ValueError):
    """A recording that cannot become a series; names the file and what is wrong."""

    def __init__(self, path, reason: str):
        self.path, self.reason = str(path), reason
        super().__init__(f"{self.path}: {reason}")


@dataclass
class SeriesNotes:
    """What importing one recording found that the data set does not show."""

    normal_force_from: str = ""       # "robot" or "pdc"
    spring_n_per_mm: float = math.nan
    mocap_invalid: int = 0            # pose samples marked not tracked, left out
    periods: int = 0
    gross_slip: bool = True           # the paper's rule flags a period: pseudo labels exist


def read_metadata(path: str | Path) -> dict:
    """The recording's 'recording' metadata (what collect.yaml's recorder wrote); {} if none."""
    from mcap.reader import make_reader
    try:
        with open(path, "rb") as f:
            for record in make_reader(f).iter_metadata():
                if record.name == "recording":
                    return dict(record.metadata)
    except Exception:           # an unfinished file has no index: read_bag names it below
        return {}
    return {}


def _by_topic(path) -> dict[str, list]:
    """The decoded messages of TOPICS with their seqs, checked for seq gaps and malformed bodies."""
    out: dict[str, list] = {t: [] for t in TOPICS}
    last_seq: dict[str, int] = {}
    try:
        for rec in read_bag(path, TOPICS, file_order=True):      # per topic in receive order
            try:
                msg = rec.message()
            except ValueError as exc:          # MessageError: the recorder never writes one, a tool might
                raise RecordingError(path, f"malformed {rec.topic} message: {exc}") from None
            prev = last_seq.get(rec.topic)
            if prev is not None and rec.sequence != (prev + 1) % (1 << 32):
                missing = (rec.sequence - prev - 1) % (1 << 32)
                raise RecordingError(path, f"seq gap on {rec.topic}: {missing} message(s) missing after "
                                           f"seq {prev} (lost on the way to the recorder)")
            last_seq[rec.topic] = rec.sequence
            out[rec.topic].append(msg)
    except BagError as exc:
        hint = (f"; `slip bag recover {path} FIXED.mcap` saves what it holds" if "unfinished" in exc.reason
                or "recover" in exc.reason else "")
        raise RecordingError(path, f"{exc.reason}{hint}") from None
    return out


def _check_clock(path, topic: str, stamps: np.ndarray, nominal_s: float) -> None:
    """Stamps of one stream go forward, never further than CLOCK_JUMP_S past their rate."""
    if len(stamps) < 2:
        return
    step = np.diff(stamps)
    back = np.flatnonzero(step < 0)
    if len(back):
        i = int(back[0])
        raise RecordingError(path, f"clock went back on {topic}: message {i + 1} is stamped "
                                   f"{-step[i] / 1e6:.3f} ms before the one before it")
    jump = np.flatnonzero(step > (nominal_s + CLOCK_JUMP_S) * 1e9) if math.isfinite(nominal_s) else []
    if len(jump):
        i = int(jump[0])
        raise RecordingError(path, f"clock jump on {topic}: {step[i] / 1e9:.3f} s between messages {i} and "
                                   f"{i + 1} with no message lost (expected {nominal_s * 1e3:.0f} ms)")


def _cut(samples: np.ndarray, first_sample_ns: int, rate_hz: float, t0_ns: int, path, topic: str) -> np.ndarray:
    """The samples from the time origin on (a stream starting after period 0 is an error)."""
    n = int(round((t0_ns - first_sample_ns) * rate_hz / 1e9))
    if n < 0:
        raise RecordingError(path, f"{topic} starts {-n / rate_hz:.3f} s after period 0 started")
    return samples[n:]


def spring_of_scene(meta: dict) -> float:
    """k_s (N/mm) of the simulated rig a recording's metadata names (its method's scene + overlay)."""
    from incipient_slip import control
    from incipient_slip.sim.scene import load_scene
    scene = load_scene(control.scene_of("", meta.get("method") or "injection"), meta.get("params") or None)
    return float(scene.params["stick_slip"]["spring_n_per_mm"])


def read_series(path: str | Path, *, spring_n_per_mm: float | None = None,
                normal_force: str = "auto") -> tuple[dict, SeriesNotes]:
    """Return (the arrays of series_NNNNN.npz, notes) of one recording; RecordingError if it cannot."""
    if normal_force not in NORMAL_FORCE_SOURCES:
        raise ValueError(f"normal_force must be one of {', '.join(NORMAL_FORCE_SOURCES)}, got {normal_force!r}")
    path = Path(path)
    meta = read_metadata(path)
    got = _by_topic(path)
    notes = SeriesNotes()
    missing = [t for t in REQUIRED if not got[t]]
    if missing:
        raise RecordingError(path, f"no messages on {', '.join(missing)} (a collection recording holds the "
                                   "BioTac slow channels, the object's pose and the actuator's ticks)")
    ticks = got[ActuatorState.TOPIC]
    tick_ns, t0 = _periods(path, ticks)
    period_end_s = (tick_ns - t0) / 1e9
    notes.periods = len(ticks)
    data = _biotac_streams(path, got, t0)
    data["mocap_t_s"], data["mocap_y_mm"], notes.mocap_invalid = _mocap(path, got, t0, period_end_s,
                                                                       meta.get("rig", "sim"))
    data["period_end_s"] = period_end_s
    data["normal_force_kpa"], notes.normal_force_from = _normal_force(path, got, tick_ns, t0, normal_force)
    if spring_n_per_mm is None:
        if meta.get("rig", "sim") == "hardware" or not meta:
            raise RecordingError(path, "the spring constant is unknown: give --rig-config FILE (its "
                                       "calibration: slip calibrate spring) or --spring-n-per-mm")
        spring_n_per_mm = spring_of_scene(meta)
    if not (math.isfinite(spring_n_per_mm) and spring_n_per_mm > 0):
        raise RecordingError(path, f"spring constant {spring_n_per_mm} N/mm is not a positive number")
    notes.spring_n_per_mm = float(spring_n_per_mm)
    data.update(_shear(path, ticks, data["mocap_t_s"], data["mocap_y_mm"], period_end_s, spring_n_per_mm))
    data.update(_truth(got[SimTruth.TOPIC], len(ticks)))
    data["material"] = np.array(str(meta.get("material", "")))
    data["injection"] = np.array(_injection(meta, got))
    data["seed"] = np.int64(int(meta["seed"]) if str(meta.get("seed", "")).lstrip("-").isdigit() else -1)
    _check_streams(path, data, period_end_s[-1])
    return data, notes


def _periods(path, ticks: list) -> tuple[np.ndarray, int]:
    """(the ticks' stamps, the time origin: period 0's start) of the actuator's period ticks."""
    if [m.period for m in ticks] != list(range(len(ticks))):
        raise RecordingError(path, "the actuator's ticks are not periods 0, 1, 2, ... in order")
    if len(ticks) < MIN_PERIODS:
        raise RecordingError(path, f"only {len(ticks)} period(s) recorded (at least {MIN_PERIODS})")
    tick_ns = np.array([m.stamp_ns for m in ticks], dtype=np.int64)
    # ticks are events, not samples: a real stage's late move makes a period longer (the streams
    # stay whole), so only a tick stamped before the one before it is a clock fault
    _check_clock(path, ActuatorState.TOPIC, tick_ns, math.inf)
    return tick_ns, int(tick_ns[0]) - PERIOD_NS            # period 0 starts one period before its tick


def _biotac_streams(path, got: dict, t0: int) -> dict:
    """The BioTac's sample streams (P_AC, electrodes, P_DC, temperatures) from the time origin on."""
    data: dict = {}
    pac = got[BiotacPac.TOPIC]
    if pac:
        stamps = np.array([m.stamp_ns for m in pac], dtype=np.int64)
        _check_clock(path, BiotacPac.TOPIC, stamps, PAC_SAMPLES_PER_FRAME / PAC_RATE_HZ)
        first = int(stamps[0]) - round((PAC_SAMPLES_PER_FRAME - 1) * 1e9 / PAC_RATE_HZ)
        data["pac_counts"] = _cut(np.concatenate([m.pac_counts for m in pac]).astype(np.int16), first,
                                  PAC_RATE_HZ, t0, path, BiotacPac.TOPIC)
    else:
        data["pac_counts"] = np.zeros(0, np.int16)
    slow = got[BiotacSlow.TOPIC]
    stamps = np.array([m.stamp_ns for m in slow], dtype=np.int64)
    _check_clock(path, BiotacSlow.TOPIC, stamps, 1.0 / SLOW_RATE_HZ)
    for key in ("electrode_counts", "pdc_counts", "tac_counts", "tdc_counts"):
        data[key] = _cut(np.asarray([getattr(m, key) for m in slow], dtype=np.uint16), int(stamps[0]),
                         SLOW_RATE_HZ, t0, path, BiotacSlow.TOPIC)
    return data


def _mocap(path, got: dict, t0: int, period_end_s: np.ndarray, rig: str) -> tuple[np.ndarray, np.ndarray, int]:
    """(sample times from the origin, the object's travel, how many samples were untracked)."""
    poses = got[ObjectPose.TOPIC]
    tracked = [m for m in poses if m.tracking_valid]
    if len(tracked) < 2:
        raise RecordingError(path, f"{ObjectPose.TOPIC}: {len(tracked)} tracked sample(s)")
    pose_ns = np.array([m.stamp_ns for m in tracked], dtype=np.int64)
    _check_clock(path, ObjectPose.TOPIC, pose_ns, PERIOD_NS / 1e9)
    keep = pose_ns >= t0 - 1           # rig_sim stamps t = 0 as 1 ns
    mocap_t_s = np.maximum(pose_ns[keep] - t0, 0) / 1e9
    y_abs = np.array([m.travel_mm for m in tracked])[keep]
    first_period = mocap_t_s < period_end_s[0]
    if not first_period.any():
        raise RecordingError(path, f"{ObjectPose.TOPIC}: no tracked sample in period 0 (the object's origin)")
    # rig_sim's travel is already from 0 (the simulator's own origin): kept as recorded, so a simulated
    # recording's mocap stream is the in-process one; a real rig's is moved to its period-0 rest
    # (at rest in period 0: the spring is slack, the stage at its origin)
    y_mm = y_abs if rig == "sim" else y_abs - float(np.mean(y_abs[first_period]))
    return mocap_t_s, y_mm, len(poses) - len(tracked)


def _shear(path, ticks: list, mocap_t_s: np.ndarray, mocap_y_mm: np.ndarray, period_end_s: np.ndarray,
           spring_n_per_mm: float) -> dict:
    """The stage during each period (from the origin), the object at its end, and F_T = k_s (u - y)."""
    positions = np.array([m.position_mm for m in ticks])
    step = positions[1] - positions[0]
    during = np.concatenate([[positions[0] - step], positions[:-1]])      # the stage in period k
    u = during - during[0]
    # the object at the period's end: its last sample before the end (the one stamped at the end
    # belongs to the next period, whose F_N already moved the contact)
    last = np.searchsorted(mocap_t_s, period_end_s - 0.5e-9, side="left") - 1
    if (last < 0).any():
        raise RecordingError(path, f"{ObjectPose.TOPIC}: no tracked sample in period {int(np.argmax(last < 0))}")
    y_end = mocap_y_mm[last]
    return {"tangential_force_n": spring_n_per_mm * (u - y_end), "actuator_mm": u, "object_y_mm": y_end}


def _truth(truths: list, n_periods: int) -> dict:
    """The simulator's truth per period (NaN / False where a period has none: real rigs)."""
    by_period = {m.period: m for m in truths}
    rows = [by_period.get(k) for k in range(n_periods)]
    return {"stick_area_ratio": np.array([r.stick_area_ratio if r else np.nan for r in rows]),
            "load_ratio_stick": np.array([r.stick_ratio if r else np.nan for r in rows]),
            "gross_slip": np.array([bool(r.gross_slip) if r else False for r in rows])}


def _normal_force(path, got: dict, tick_ns: np.ndarray, t0: int, source: str) -> tuple[np.ndarray, str]:
    """F_N per period (kPa) and where it came from."""
    starts = np.concatenate([[t0], tick_ns[:-1]])
    robot = got[RobotState.TOPIC]
    if source in ("auto", "robot") and robot:
        stamps = np.array([m.stamp_ns for m in robot], dtype=np.int64)
        force = np.array([m.normal_force_kpa for m in robot])
        out = _period_means(stamps, force, starts, tick_ns)
        if np.isnan(out).any():
            k = int(np.flatnonzero(np.isnan(out))[0])
            raise RecordingError(path, f"{RobotState.TOPIC}: no applied F_N in period {k}")
        return out, "robot"
    if source == "robot":
        raise RecordingError(path, f"no {RobotState.TOPIC} messages (normal_force robot); use pdc")
    slow = got[BiotacSlow.TOPIC]
    stamps = np.array([m.stamp_ns for m in slow], dtype=np.int64)
    out = _period_means(stamps, np.array([m.pdc_kpa for m in slow]), starts, tick_ns)
    if np.isnan(out).any():
        k = int(np.flatnonzero(np.isnan(out))[0])
        raise RecordingError(path, f"{BiotacSlow.TOPIC}: no P_DC sample in period {k}")
    return out, "pdc"


def _period_means(stamps: np.ndarray, values: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """The mean of the values stamped in [start, end) of each period; NaN where there is none
    (a value stamped 1 ns stands for t = 0: rig_sim's)."""
    lo = np.searchsorted(stamps, starts - 1, side="left")
    hi = np.searchsorted(stamps, ends - 1, side="left")
    return np.array([values[a:b].mean() if b > a else np.nan for a, b in zip(lo, hi)])


def _injection(meta: dict, got: dict) -> bool:
    states = got[PztState.TOPIC]
    if states:
        return bool(states[0].enabled)
    return str(meta.get("injection", "true")).lower() in ("true", "1", "yes")


def _check_streams(path, data: dict, last_end_s: float) -> None:
    """The streams cover every period (a short stream: samples lost or the recording cut)."""
    for key, rate in (("pac_counts", PAC_RATE_HZ), ("electrode_counts", SLOW_RATE_HZ)):
        n = len(data[key])
        if key == "pac_counts" and n == 0:
            continue
        short = last_end_s - n / rate
        if short > 1.5 / SLOW_RATE_HZ:
            raise RecordingError(path, f"{key}: the stream ends {short:.3f} s before the last period does")


# --- a directory of recordings -> a data set --------------------------------------------------

@dataclass
class ImportReport:
    """What `import_recordings` wrote and what it left out, per file, with the reason."""

    out_dirs: dict = field(default_factory=dict)         # "injection" / "no_injection" -> directory
    imported: list = field(default_factory=list)        # (file, series index, SeriesNotes)
    dropped: list = field(default_factory=list)         # (file, reason)
    not_collected: list = field(default_factory=list)   # manifest entries never finished

    def format(self) -> str:
        lines = [f"imported {len(self.imported)} series into " + ", ".join(
            f"{d} ({kind})" for kind, d in self.out_dirs.items()) if self.out_dirs else "imported no series"]
        no_slip = [f for f, _, n in self.imported if not n.gross_slip]
        if no_slip:
            lines.append(f"  {len(no_slip)} series without gross slip (kept: the paper's pseudo label has no "
                         f"F_T^slip there, so `slip train --label pseudo` leaves their periods out): "
                         + ", ".join(Path(f).name for f in no_slip[:5]) + (" ..." if len(no_slip) > 5 else ""))
        sources = sorted({n.normal_force_from for _, _, n in self.imported})
        if sources:
            lines.append(f"  F_N from: {', '.join(sources)}")
        invalid = sum(n.mocap_invalid for _, _, n in self.imported)
        if invalid:
            lines.append(f"  {invalid} mocap samples not tracked, left out")
        if self.dropped:
            lines.append(f"dropped {len(self.dropped)} recording(s):")
            lines += [f"  {f}: {reason}" for f, reason in self.dropped]
        if self.not_collected:
            lines.append(f"{len(self.not_collected)} series of the session not collected (status not done): "
                         + ", ".join(self.not_collected[:8]) + (" ..." if len(self.not_collected) > 8 else ""))
        return "\n".join(lines)

    def to_plain(self) -> dict:
        return {"out_dirs": self.out_dirs,
                "imported": [{"file": f, "index": i, "periods": n.periods, "normal_force_from": n.normal_force_from,
                              "spring_n_per_mm": n.spring_n_per_mm, "mocap_invalid": n.mocap_invalid,
                              "gross_slip": n.gross_slip} for f, i, n in self.imported],
                "dropped": [{"file": f, "reason": r} for f, r in self.dropped],
                "not_collected": self.not_collected}


def recordings_of(src: str | Path) -> tuple[list[tuple[Path, int]], list[str]]:
    """[(recording, series index)] of a session directory (its manifest's finished series) or of a
    directory of recordings (every *.mcap, indexed in name order), and the manifest's unfinished ones."""
    from incipient_slip.lab.session import MANIFEST, load_manifest
    src = Path(src)
    if not src.is_dir():
        raise RecordingError(src, "is not a directory of recordings")
    if (src / MANIFEST).is_file():
        session = load_manifest(src)
        done = [(src / s.file, s.index) for s in session.series if s.status == "done"]
        return done, [s.file for s in session.series if s.status != "done"]
    files = sorted(src.rglob("*.mcap"))
    if not files:
        raise RecordingError(src, "holds no *.mcap recordings and no session manifest")
    return [(f, i) for i, f in enumerate(files)], []


def _read_one(options: tuple, path: Path):
    """(arrays, notes) of one recording, or the reason it cannot be a series (a worker's task)."""
    from incipient_slip.models.labels import GROSS_SLIP_MM, gross_slip_travel_mm
    spring_n_per_mm, normal_force = options
    try:
        data, notes = read_series(path, spring_n_per_mm=spring_n_per_mm, normal_force=normal_force)
    except RecordingError as exc:
        return exc.reason
    travel = gross_slip_travel_mm(data["mocap_t_s"], data["mocap_y_mm"], data["period_end_s"])
    notes.gross_slip = bool((travel >= GROSS_SLIP_MM).any())
    return data, notes


def import_recordings(src: str | Path, out: str | Path, *, spring_n_per_mm: float | None = None,
                      normal_force: str = "auto", progress=None, workers: int | None = None) -> ImportReport:
    """Write the data set(s) of a directory of collection recordings: out/injection and/or
    out/no_injection, one per injection setting present (always that layout, so the training
    command does not depend on which settings a session held). Recordings
    are read by `workers` forked processes (default: all cores), in index order."""
    import json

    from incipient_slip.models.dataset import DATASET_FORMAT, DATASET_VERSION
    from incipient_slip.models.training import forked_map
    report = ImportReport()
    todo, report.not_collected = recordings_of(src)
    read: list = []
    workers = min(len(todo), workers or os.cpu_count() or 1)
    for (path, index), result in zip(todo, forked_map(_read_one, [p for p, _ in todo], workers,
                                                       (spring_n_per_mm, normal_force))):
        if isinstance(result, str):
            report.dropped.append((str(path), result))
        else:
            read.append((path, index, *result))
        if progress:
            progress(1)
    kinds = sorted({bool(d["injection"]) for _, _, d, _ in read}, reverse=True)
    out = Path(out)
    for inj in kinds:
        where = out / ("injection" if inj else "no_injection")
        where.mkdir(parents=True, exist_ok=True)
        (where / "meta.json").unlink(missing_ok=True)
        for stale in where.glob("series_*.npz"):
            stale.unlink()
        mine = [r for r in read if bool(r[2]["injection"]) == inj]
        for path, index, data, notes in mine:
            with written_atomically(where / f"series_{index:05d}.npz") as tmp:
                np.savez(tmp, **data)
            report.imported.append((str(path), index, notes))
        materials = list(dict.fromkeys(str(d["material"]) for _, _, d, _ in mine))
        meta = {"format": DATASET_FORMAT, "version": DATASET_VERSION, "scene": "recordings",
                "source": str(Path(src).resolve()), "n_series": len(mine), "materials": materials,
                "injection": inj, "pac_rate_hz": PAC_RATE_HZ, "slow_rate_hz": SLOW_RATE_HZ, "period_s": PERIOD_NS / 1e9,
                "steps": max(n.periods for *_, n in mine), "created_by": "incipient_slip.lab.recordings.import_recordings",
                "spring_n_per_mm": sorted({n.spring_n_per_mm for *_, n in mine}),
                "normal_force_from": sorted({n.normal_force_from for *_, n in mine}),
                "recordings": {f"series_{i:05d}": str(p) for p, i, _, _ in mine}}
        with written_atomically(where / "meta.json") as tmp:
            tmp.write_text(json.dumps(meta, indent=1))
        report.out_dirs["injection" if inj else "no_injection"] = str(where)
    return report
