"""The simulated data sets the learning experiments share, made once and reused.

This is where the simulator meets learning: `models/` only reads data-set directories, `sim/`
only writes them, and an experiment asks here for the directory it needs.
"""
from __future__ import annotations

from pathlib import Path

from incipient_slip.models import dataset as ds
from incipient_slip.paths import runs_dir
from incipient_slip.sim.dataset import follows, physics_fingerprint, write_dataset
from incipient_slip.sim.scene import load_scene

from .settings import Settings


def data_root(settings: Settings) -> Path:
    """Return where data sets are cached: --data, else runs/data (full) or WORK/data (quick)."""
    return Path(settings.option("data", settings.pick(quick=settings.work / "data",
                                                      full=runs_dir() / "data")))


def _scene(scene):
    return load_scene(scene) if isinstance(scene, str) else scene


def _reusable(scene, n_series: int, seed: int, steps: int, out_dir: Path) -> bool:
    """Whether out_dir holds this data set, finished (meta.json is written last) and made by the
    same physics: a recalibrated simulator must not be evaluated on the old one's data."""
    try:
        meta = ds.read_meta(out_dir)
        n_files = len(ds.series_paths(out_dir))
    except ds.DatasetError:
        return False
    return (meta.get("scene") == scene.name and meta.get("seed") == seed and meta.get("n_series") == n_series
            and meta.get("steps") == steps and n_files == n_series
            and meta.get("physics_fingerprint") == physics_fingerprint(scene))


def ensure_dataset(scene, n_series: int, seed: int, out_dir: Path, workers: int = 2,
                   steps: int = 450, progress: bool = True, views: dict | None = None) -> Path:
    """Return a data set directory for (scene, n_series, seed, steps), simulating it if needed.

    scene: a scene name or a `Scene` (e.g. with a point's parameters). The directory is reused
    when its meta.json has the same scene, size, seed and physics fingerprint (a hash of the
    scene, its parameter values and the simulator's code), so no data set is simulated twice.
    views: {directory: scene} of data sets of the same size and seed whose series follow from
    `scene`'s runs (`sim.dataset.view_kind`, e.g. no_injection from paper): the missing ones are
    simulated in the same pass, each exactly as on its own."""
    out_dir = Path(out_dir)
    scene_obj = _scene(scene)
    todo = {Path(d): _scene(v) for d, v in (views or {}).items()}
    todo = {d: v for d, v in todo.items() if not _reusable(v, n_series, seed, steps, d)}
    if not todo and _reusable(scene_obj, n_series, seed, steps, out_dir):
        return out_dir
    write_dataset(scene_obj, n_series, seed, out_dir, workers=workers, steps=steps,
                  progress=progress, views=todo)
    return out_dir


def study_datasets(settings: Settings, n_series: int, steps: int, seed: int | None = None,
                   scenes=("paper", "no_injection")) -> dict[str, Path]:
    """Return {scene: directory} of the data sets of one study (same seed and size per scene)."""
    seed = settings.seed if seed is None else seed
    root = data_root(settings)
    dirs = {sc: root / f"{sc}_{n_series}_s{seed}_{steps}" for sc in scenes}
    first, *rest = scenes
    views = {dirs[sc]: load_scene(sc) for sc in rest if follows(load_scene(sc), load_scene(first))}
    for sc in scenes:      # the scenes that follow from the first one's runs are simulated with it
        if dirs[sc] not in views:
            ensure_dataset(sc, n_series, seed, dirs[sc], workers=settings.jobs, steps=steps,
                           progress=settings.progress, views=views if sc == first else None)
    return dirs
