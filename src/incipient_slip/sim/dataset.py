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
from .protocols import run_collection
from .rig import Rig, series_seed
from .scene import Scene

TRUTH = ("normal_force_kpa", "tangential_force_n", "actuator_mm", "object_y_mm", "stick_area_ratio",
         "load_ratio_stick", "gross_slip")


def simulate_series(scene: Scene, material: str, seed: int, steps: int = 450) -> dict:
    """Return one data-collection series as the dict of arrays stored in series_NNNNN.npz."""
    rig = Rig(scene, material, seed)
    outs = list(run_collection(rig, steps))
    data: dict = {}

    def cat(name, dtype, empty_shape):
        parts = [getattr(o, name) for o in outs]
        if parts[0] is None:
            return np.zeros(empty_shape, dtype)
        return np.concatenate(parts).astype(dtype, copy=False)

    data["pac_counts"] = cat("pac_counts", np.int16, (0,))
    data["electrode_counts"] = cat("electrode_counts", np.uint16, (0, 19))
    for name in ("pdc_counts", "tac_counts", "tdc_counts"):
        data[name] = cat(name, np.uint16, (0,))
    data["mocap_t_s"] = cat("mocap_t_s", np.float64, (0,))
    data["mocap_y_mm"] = cat("mocap_y_mm", np.float64, (0,))
    data["period_end_s"] = np.array([o.t_start_s + rig.period_s for o in outs])
    for name in TRUTH:
        data[name] = np.array([getattr(o, name) for o in outs], dtype=bool if name == "gross_slip" else np.float64)
    data["material"] = np.array(material)
    data["injection"] = np.array(bool(outs[0].pzt_on))
    data["seed"] = np.int64(seed)
    return data


def _worker(args) -> str:
    scene, mats, dataset_seed, index, steps, out_dir = args
    seed = series_seed(dataset_seed, index)
    data = simulate_series(scene, mats[index % len(mats)], seed, steps)
    path = Path(out_dir) / f"series_{index:05d}.npz"
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, **data)
    os.replace(tmp, path)
    return str(path)


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
                  workers: int | None = None, steps: int = 450, progress: bool = True, client=None) -> Path:
    """Write a data set directory (meta.json + series_NNNNN.npz) and return its path.

    client: a dask Client (`cluster.open_client`) to run the series on as tasks; else `workers`
    local processes (default all cores; 1 runs in this process)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mats = tuple(materials) if materials else scene.materials
    for m in mats:
        if m not in scene.params["materials"]:
            raise ValueError(f"unknown material {m!r} (known: {', '.join(scene.params['materials'])})")
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
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    jobs = [(scene, mats, seed, i, steps, str(out)) for i in range(n_series)]
    if client is not None:
        for _ in as_done(client, _worker, [(job,) for job in jobs], desc=f"dataset {scene.name}",
                         progress=progress, key=f"series-{scene.name}"):
            pass
        return out
    workers = max(1, int(workers or os.cpu_count() or 1))
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_series, unit="series", desc=f"dataset {scene.name}")
    if workers == 1:
        for job in jobs:
            _worker(job)
            if bar:
                bar.update()
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for _ in pool.map(_worker, jobs, chunksize=1):
                if bar:
                    bar.update()
    if bar:
        bar.close()
    return out
