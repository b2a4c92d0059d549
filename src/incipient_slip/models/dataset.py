"""Reading a data set written by `slip dataset` (format in docs/design.md).

A data set is a directory with `meta.json` and one `series_NNNNN.npz` per series. Nothing here
writes data sets; the simulator (or a recorder conversion) does.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DATASET_FORMAT = "incipient-slip-dataset"
DATASET_VERSION = 1


class DatasetError(ValueError):
    """A data set directory or series file is missing or malformed; the message names it."""


@dataclass(frozen=True)
class Series:
    """One series (one pass of the actuator over 23 mm) loaded from `series_NNNNN.npz`."""

    index: int                    # NNNNN from the file name: the identity used for splits
    material: str
    injection: bool
    pac_counts: np.ndarray        # int16 (n_pac,)
    electrode_counts: np.ndarray  # uint16 (n_slow, 19)
    mocap_t_s: np.ndarray
    mocap_y_mm: np.ndarray
    period_end_s: np.ndarray
    normal_force_kpa: np.ndarray
    tangential_force_n: np.ndarray
    stick_area_ratio: np.ndarray
    load_ratio_stick: np.ndarray
    gross_slip: np.ndarray
    seed: int = -1                # the series' own seed (meta.json's series_seed_rule); -1: not stored


_REQUIRED_KEYS = ("pac_counts", "electrode_counts", "mocap_t_s", "mocap_y_mm", "period_end_s",
                  "normal_force_kpa", "tangential_force_n", "material")


def read_meta(data_dir: str | Path) -> dict:
    """Return the parsed `meta.json` of a data set, checked for format and version."""
    path = Path(data_dir) / "meta.json"
    if not Path(data_dir).is_dir():
        raise DatasetError(f"data set directory {data_dir} does not exist")
    if not path.is_file():
        raise DatasetError(f"{path}: missing; a data set directory holds meta.json and "
                           "series_NNNNN.npz files (written by `slip dataset`)")
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from None
    if meta.get("format") != DATASET_FORMAT:
        raise DatasetError(f"{path}: format is {meta.get('format')!r}, expected {DATASET_FORMAT!r}")
    if meta.get("version") != DATASET_VERSION:
        raise DatasetError(f"{path}: version {meta.get('version')!r} is not supported "
                           f"(expected {DATASET_VERSION})")
    return meta


def series_paths(data_dir: str | Path) -> list[Path]:
    """Return the series files of a data set, sorted by series index."""
    paths = sorted(Path(data_dir).glob("series_*.npz"))
    if not paths:
        raise DatasetError(f"{data_dir}: no series_NNNNN.npz files")
    return paths


def series_index(path: Path) -> int:
    """Return NNNNN of `series_NNNNN.npz`."""
    try:
        return int(path.stem.split("_", 1)[1])
    except (IndexError, ValueError):
        raise DatasetError(f"{path}: file name is not series_NNNNN.npz") from None


def load_series(path: str | Path, streams: bool = True) -> Series:
    """Return one series; a missing key is an error naming the file and key. `streams` False leaves
    the sensor streams (P_AC, electrodes) unread and empty: what labels need is read alone."""
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from None
    with data:
        missing = [k for k in _REQUIRED_KEYS if k not in data.files]
        if missing:
            raise DatasetError(f"{path}: missing keys {missing}")
        n_periods = len(data["period_end_s"])

        def opt(key, fill):
            return np.asarray(data[key]) if key in data.files else np.full(n_periods, fill)

        return Series(
            index=series_index(path),
            material=str(data["material"]),
            injection=bool(data["injection"]) if "injection" in data.files else True,
            pac_counts=np.asarray(data["pac_counts"]) if streams else np.zeros(0, np.int16),
            electrode_counts=np.asarray(data["electrode_counts"]) if streams else np.zeros((0, 19), np.uint16),
            mocap_t_s=np.asarray(data["mocap_t_s"], dtype=np.float64),
            mocap_y_mm=np.asarray(data["mocap_y_mm"], dtype=np.float64),
            period_end_s=np.asarray(data["period_end_s"], dtype=np.float64),
            normal_force_kpa=np.asarray(data["normal_force_kpa"], dtype=np.float64),
            tangential_force_n=np.asarray(data["tangential_force_n"], dtype=np.float64),
            stick_area_ratio=opt("stick_area_ratio", np.nan).astype(np.float64),
            load_ratio_stick=opt("load_ratio_stick", np.nan).astype(np.float64),
            gross_slip=opt("gross_slip", False).astype(bool),
            seed=int(data["seed"]) if "seed" in data.files else -1,
        )


def series_key(s: Series) -> str:
    """Who a series is across data sets, from what it holds: its material, seed and the object's
    measured path and the normal force, so two data sets of one seed share series (a 20- and a
    500-series set of seed 0 share their first 20) and a series of other physics is another one.
    Not from the simulator's code version, which a change of a comment moves. A model's header
    lists its training series' keys; `slip evaluate` refuses held-out series among them."""
    h = hashlib.sha256(f"{s.material}|{s.seed}|".encode())
    h.update(np.ascontiguousarray(s.mocap_y_mm).tobytes())
    h.update(np.ascontiguousarray(s.normal_force_kpa).tobytes())
    return h.hexdigest()[:16]


def dataset_hash(data_dir: str | Path) -> str:
    """Return a short content hash of a data set (meta.json + file names and sizes + heads).

    Cheap on purpose (a paper-scale set is gigabytes): it hashes meta.json, each series file's
    name and size and its first 64 KiB, enough to tell two generated sets apart. The meta's
    `physics_fingerprint` is left out: it hashes the simulator's source, so a refactor that keeps
    every array bit for bit (tests/data/sim_series.json) changed it, and with it every shipped
    model's `training_data_hash`, although the models were the same to the byte.
    """
    h = hashlib.sha256()
    data_dir = Path(data_dir)
    meta = json.loads((data_dir / "meta.json").read_text())
    meta.pop("physics_fingerprint", None)
    h.update(json.dumps(meta, sort_keys=True).encode())
    for p in series_paths(data_dir):
        h.update(p.name.encode())
        h.update(str(p.stat().st_size).encode())
        with open(p, "rb") as f:
            h.update(f.read(65536))
    return h.hexdigest()[:16]
