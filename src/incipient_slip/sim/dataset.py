"""In-process data set generation: one npz per series, written by worker processes.

Format: docs/design.md ("Data set on disk"). npz because it needs numpy only, one file per
series streams to disk from each worker (memory bounded to one series per worker) and keys load
lazily. Series i uses material materials[i % n_materials] and seed series_seed(seed, i), so the
arrays do not depend on the number of workers nor on where they run: a local process pool (the
default), or dask tasks when a `client` is given (`incipient_slip.cluster`; `slip dataset --dask`
or `--scheduler tcp://host:port`). With a remote scheduler `out_dir` must be a path every worker
can write (a shared file system).
"""
from __future__ import annotations

import hashlib
import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..cluster import as_done
from ..paths import written_atomically
from . import kernels, mechanics
from .protocols import run_collection
from .rig import Rig, series_seed
from .scene import Scene

TRUTH = ("normal_force_kpa", "tangential_force_n", "actuator_mm", "object_y_mm", "stick_area_ratio",
         "load_ratio_stick", "gross_slip")


PAC_EFFECTS = frozenset({"fingertip_modes", "injection", "vibrotactile", "ambient_noise"})
SLOW = (("electrodes", ("electrode_counts",)), ("pdc", ("pdc_counts",)), ("temperature", ("tac_counts", "tdc_counts")),
        ("mocap", ("mocap_t_s", "mocap_y_mm")))


def view_kind(view: Scene, source: Scene) -> str:
    """Return how `view`'s series follow from a run of `source` with the same seed: "same" P_AC,
    P_AC "without_pzt" (the source's minus the injection) or "no_pac"; raise ValueError when they
    do not (other parameters, other mechanics, or P_AC effects that are neither)."""
    if view.params != source.params or not view.effects <= source.effects:
        raise ValueError(f"scene {view.name!r} does not follow from a run of {source.name!r}")
    if {"contact", "stick_slip"} & source.effects != {"contact", "stick_slip"} & view.effects:
        raise ValueError(f"scene {view.name!r} has other mechanics than {source.name!r}")
    pac_v, pac_s = view.effects & PAC_EFFECTS, source.effects & PAC_EFFECTS
    if pac_v == pac_s and (not view.has("injection") or view.injection_db == source.injection_db):
        return "same"
    if not pac_v:
        return "no_pac"
    if source.has("injection") and pac_v == pac_s - {"injection"}:
        return "without_pzt"
    raise ValueError(f"scene {view.name!r}: its P_AC does not follow from {source.name!r}'s")


def follows(view: Scene, source: Scene) -> bool:
    """Return whether `view`'s data set can be written from `source`'s runs (`view_kind`; same materials)."""
    try:
        view_kind(view, source)
    except ValueError:
        return False
    return tuple(view.materials) == tuple(source.materials)


def _arrays(outs: list, period_s: float, material: str, seed: int, drop=frozenset(), pac: list | None = None,
            pzt_on: bool = True) -> dict:
    """Return a series' arrays from its periods; for a view (`simulate_series`): `drop` the sensor
    fields it does not have, its P_AC per period `pac` instead of the periods' (None entries: none)
    and `pzt_on` False when it has no injection."""
    data: dict = {}

    def cat(name, dtype, empty_shape):
        parts = pac if name == "pac_counts" and pac is not None else [getattr(o, name) for o in outs]
        if name in drop or parts[0] is None:
            return np.zeros(empty_shape, dtype)
        return np.concatenate(parts).astype(dtype, copy=False)

    data["pac_counts"] = cat("pac_counts", np.int16, (0,))
    data["electrode_counts"] = cat("electrode_counts", np.uint16, (0, 19))
    for name in ("pdc_counts", "tac_counts", "tdc_counts"):
        data[name] = cat(name, np.uint16, (0,))
    data["mocap_t_s"] = cat("mocap_t_s", np.float64, (0,))
    data["mocap_y_mm"] = cat("mocap_y_mm", np.float64, (0,))
    data["period_end_s"] = np.array([o.t_start_s + period_s for o in outs])
    for name in TRUTH:
        data[name] = np.array([getattr(o, name) for o in outs], dtype=bool if name == "gross_slip" else np.float64)
    data["material"] = np.array(material)
    data["injection"] = np.array(bool(outs[0].pzt_on and pzt_on))
    data["seed"] = np.int64(seed)
    return data


def simulate_series(scene: Scene, material: str, seed: int, steps: int = 450, views=()) -> dict | list[dict]:
    """Return one data-collection series as the dict of arrays stored in series_NNNNN.npz.

    views: other scenes whose series of the same material and seed follow from this run
    (`view_kind`: the same parameters and mechanics, the P_AC the same, without the PZT or
    none, fewer slow channels): then return [this scene's dict, one per view], each exactly
    what simulating that scene on its own gives, for one run's cost plus a second modal filter."""
    kinds = [view_kind(v, scene) for v in views]
    rig = Rig(scene, material, seed, pac_without_pzt="without_pzt" in kinds)
    outs, off = [], []
    for o in run_collection(rig, steps):
        outs.append(o)
        off.append(rig.last_pac_without_pzt)
    data = _arrays(outs, rig.period_s, material, seed)
    if not views:
        return data
    res = [data]
    for v, kind in zip(views, kinds):
        drop = {f for effect, fields in SLOW if not v.has(effect) for f in fields}
        pac = None if kind == "same" else off if kind == "without_pzt" else [None]
        res.append(_arrays(outs, rig.period_s, material, seed, drop, pac, v.has("injection")))
    return res


def _worker(args) -> str:
    scene, mats, dataset_seed, index, steps, out_dir, views = args
    seed = series_seed(dataset_seed, index)
    data = simulate_series(scene, mats[index % len(mats)], seed, steps, [v for v, _ in views])
    for d, where in zip([data] if not views else data, [out_dir] + [w for _, w in views]):
        with written_atomically(Path(where) / f"series_{index:05d}.npz") as tmp:
            np.savez(tmp, **d)
    return str(Path(out_dir) / f"series_{index:05d}.npz")


def physics_fingerprint(scene: Scene) -> str:
    """A hash of everything that decides the simulated data: the scene, its parameter values and
    the sim code. A cached data set whose fingerprint differs was made by other physics."""
    h = hashlib.sha256()
    h.update(scene.yaml_text.encode())
    h.update(json.dumps(scene.params, sort_keys=True, default=str).encode())
    for source in sorted(Path(__file__).parent.glob("*.py")):
        h.update(source.name.encode())
        h.update(source.read_bytes())
    return h.hexdigest()[:16]


def write_dataset(scene: Scene, n_series: int, seed: int, out_dir: str | Path, *, materials=None,
                  workers: int | None = None, steps: int = 450, progress: bool = True, client=None,
                  views: dict | None = None) -> Path:
    """Write a data set directory (meta.json + series_NNNNN.npz) and return its path.

    meta.json is written last, once every series is on disk: a directory without it is a run that
    did not finish (a crash, Ctrl-C), which readers refuse and `experiments.datasets` redoes.

    client: a dask Client (`cluster.open_client`) to run the series on as tasks; else `workers`
    local processes (default all cores; 1 runs in this process).
    views: {directory: scene} of data sets of the same size and seed that follow from this
    scene's runs (`view_kind`, e.g. no_injection or electrodes_only from paper at the same
    parameters), written in the same pass, each exactly as its own `write_dataset` would."""
    views = [(v, str(Path(d))) for d, v in (views or {}).items()]
    for v, _ in views:
        view_kind(v, scene)
        if not materials and tuple(v.materials) != tuple(scene.materials):
            raise ValueError(f"scene {v.name!r} has other materials than {scene.name!r}; give `materials`")
    mats = tuple(materials) if materials else scene.materials
    for m in mats:
        if m not in scene.params["materials"]:
            raise ValueError(f"unknown material {m!r} (known: {', '.join(scene.params['materials'])})")
    dirs = [(scene, Path(out_dir))] + [(v, Path(where)) for v, where in views]
    for _, where in dirs:
        where.mkdir(parents=True, exist_ok=True)
        (where / "meta.json").unlink(missing_ok=True)     # complete again only when all is written
        for stale in where.glob("series_*.npz"):         # another set's, or an interrupted run's
            stale.unlink()
    out = Path(out_dir)
    jobs = [(scene, mats, seed, i, steps, str(out), views) for i in range(n_series)]
    if client is not None:
        for _ in as_done(client, _worker, [(job,) for job in jobs], desc=f"dataset {scene.name}",
                         progress=progress, key=f"series-{scene.name}"):
            pass
    else:
        _run_local(jobs, n_series, workers, progress, scene.name)
    for sc, where in dirs:
        _write_meta(sc, n_series, seed, where, mats, steps)
    return out


def _run_local(jobs: list, n_series: int, workers: int | None, progress: bool, name: str) -> None:
    """The series jobs in this process (workers 1) or a local process pool."""
    workers = max(1, int(workers or os.cpu_count() or 1))
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_series, unit="series", desc=f"dataset {name}")
    if workers == 1:
        for job in jobs:
            _worker(job)
            if bar:
                bar.update()
    else:
        mechanics.warm_up()          # load the compiled code once here: the forked workers inherit it
        kernels.warm_up()
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for _ in pool.map(_worker, jobs, chunksize=1):
                if bar:
                    bar.update()
    if bar:
        bar.close()


def _write_meta(scene: Scene, n_series: int, seed: int, out: Path, mats: tuple, steps: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    p = scene.params
    meta = {
        "format": "incipient-slip-dataset", "version": 1, "scene": scene.name, "scene_yaml": scene.yaml_text,
        "seed": int(seed), "n_series": int(n_series), "materials": list(mats),
        "injection": scene.has("injection"), "pac_rate_hz": p["timing"]["pac_rate_hz"],
        "slow_rate_hz": p["timing"]["slow_rate_hz"], "mocap_rate_hz": p["timing"]["mocap_rate_hz"],
        "period_s": p["timing"]["period_s"], "steps": int(steps),
        "pac_pa_per_count": p["adc"]["pac_pa_per_count"], "pdc_pa_per_count": p["adc"]["pdc_pa_per_count"],
        "created_by": "incipient_slip.sim.dataset.write_dataset",
        "physics_fingerprint": physics_fingerprint(scene),
        "series_material_rule": "materials[i % len(materials)]",
        "series_seed_rule": "SeedSequence(seed, spawn_key=(i,)) -> int63",
    }
    with written_atomically(out / "meta.json") as tmp:        # whole or absent: its presence says "finished"
        tmp.write_text(json.dumps(meta, indent=1))
