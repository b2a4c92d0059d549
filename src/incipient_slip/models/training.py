"""Training: windows -> (phi, s) -> grid-searched SVR (or a scalable approximation) -> Model.

Splits are grouped by series: windows overlap by 50 %, so a window-level random split would put
half of a test window into training. The held-out test set is the same 10 % of *series indices*
for every method (`held_out_series`), chosen per material so every material is tested.

Regressor kinds (all exported to the array form of `modelfile.Model`):

* `svr`: exact kernel SVR (libsvm via scikit-learn), kernel and C / gamma / epsilon by grouped
  grid search, fitted on at most `max_train` windows (a random subsample when the training set
  is larger; exact SVR time grows ~n^2, see docs/accuracy-vs-time.md).
* `nystroem`: RBF Nystroem features (`n_components` landmarks) + ridge regression on *all*
  training windows; gamma from a small exact-SVR grid on a subsample, ridge alpha by grouped
  validation. Scales linearly in the number of windows.
* `linear`: ridge regression on the standardized features.
"""
from __future__ import annotations

import hashlib
import time
import dataclasses
from dataclasses import dataclass, field
from itertools import product
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..cluster import map_tasks
from . import dataset as ds
from .features import FeatureSpec, series_feature_sets, valid_window_mask
from .labels import label_rule, label_series, training_labels
from .modelfile import Model, rbf_of_dot

SPLIT_SEED = 20240917
TEST_FRACTION = 0.10
KINDS = ("svr", "nystroem", "linear")
SVR_CACHE_MB = 500          # libsvm's kernel cache: the whole kernel of up to ~11 000 windows (float32)


@dataclass
class WindowSet:
    """All labelled windows of a data set for one feature spec, one row per window."""

    X: np.ndarray               # (n, n_features) float32
    y: np.ndarray               # pseudo-stick ratio (or the label option's target)
    series: np.ndarray          # series index (the group)
    material: np.ndarray        # material name per row
    period: np.ndarray          # period index k within its series
    stick_area_ratio: np.ndarray
    load_ratio_stick: np.ndarray
    tangential_force_n: np.ndarray
    normal_force_kpa: np.ndarray
    post_slip: np.ndarray       # window ends after the gross-slip onset period
    spec: FeatureSpec
    data_hash: str = ""
    skipped_series: list = field(default_factory=list)   # no gross slip detected
    series_keys: dict = field(default_factory=dict)      # series index -> dataset.series_key

    def subset(self, mask: np.ndarray) -> "WindowSet":
        keep = {k: getattr(self, k)[mask] for k in ("X", "y", "series", "material", "period",
                                                  "stick_area_ratio", "load_ratio_stick",
                                                  "tangential_force_n", "normal_force_kpa",
                                                  "post_slip")}
        return WindowSet(**keep, spec=self.spec, data_hash=self.data_hash,
                         skipped_series=self.skipped_series, series_keys=self.series_keys)

    def series_materials(self) -> dict:
        return {int(s): str(m) for s, m in zip(self.series, self.material)}


AFTER_SLIP = ("zero", "drop")

_INHERITED: object = None   # what forked_map's workers inherit instead of receiving it pickled


def _inherited_call(task):
    fn, item = task
    return fn(_INHERITED, item)


def forked_map(fn, items, workers: int, inherited=None, chunksize: int = 1):
    """Yield fn(inherited, item) for each item, in order, from `workers` forked processes (in this
    process when workers <= 1). `inherited` (windows, arrays) is copied into the workers by the
    fork, not pickled per task; fn must be a module-level function."""
    global _INHERITED
    if workers <= 1:
        for item in items:
            yield fn(inherited, item)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    _INHERITED = inherited
    try:
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
            yield from pool.map(_inherited_call, [(fn, item) for item in items], chunksize=chunksize)
    finally:
        _INHERITED = None


def load_windows(data_dir: str | Path, spec: FeatureSpec, min_window_s: float | None = None,
                 progress: bool = True, after_slip: str = "zero", label: str = "pseudo",
                 workers: int = 1) -> WindowSet:
    """Return every labelled window of a data set for `spec` (`load_window_sets` of one spec).

    min_window_s: keep only windows that would also be complete for a window of this length
    (used to compare different T on the same samples).
    after_slip: "zero" keeps the windows after gross slip with label 0 (the paper's rule);
    "drop" keeps windows up to and including the gross-slip onset only (incipient slip range).
    label: a name of `labels.LABELS` or a `labels.LabelRule`: "pseudo" (the paper's rule),
    "measured-ratio" (measured quantities under the per-period F_N redraw) or "true-ratio"
    (EXTENSION: the simulator's load_ratio_stick); the windows kept are the same for all.
    With a cache on (`incipient_slip.cache`) the windows are stored under a key of the data set's
    content hash, the spec, these options and the code of models/, and read back next time.
    """
    return load_window_sets(data_dir, [spec], min_window_s, progress, after_slip, label, workers)[0]


def load_window_sets(data_dir: str | Path, specs, min_window_s: float | None = None, progress: bool = True,
                     after_slip: str = "zero", label: str = "pseudo", workers: int = 1) -> list[WindowSet]:
    """Return `load_windows` of each spec, reading each series file once for all of them.

    workers: read the series in this many forked processes (1: in process); the windows are
    the same, in series order, wherever they were computed."""
    label = label_rule(label)                       # a name or a LabelRule; ValueError names a bad one
    if after_slip not in AFTER_SLIP:
        raise ValueError(f"after_slip {after_slip!r} unknown; expected one of {AFTER_SLIP}")
    specs = list(specs)
    meta = ds.read_meta(data_dir)
    for spec in specs:
        if spec.stream == "pac" and spec.injection is not None and bool(meta.get("injection", True)) != spec.injection:
            raise ds.DatasetError(
                f"{data_dir}: data set has injection={meta.get('injection')} but method "
                f"{spec.method} needs injection={spec.injection} (scene 'paper' for injection, "
                "'no_injection' for vibrotactile)")
    computed: list = []

    def compute() -> list[WindowSet]:
        if not computed:
            computed.extend(_load_window_sets(data_dir, specs, min_window_s, progress, after_slip, label, workers))
        return computed
    from .. import cache
    if cache.root() is None:
        return compute()
    data_hash, code = ds.dataset_hash(data_dir), cache.source_version(Path(__file__).parent)
    return [cache.cached("windows", cache.digest("windows-1", data_hash, repr(spec), min_window_s, after_slip,
                                                 repr(label), code), lambda i=i: compute()[i])
            for i, spec in enumerate(specs)]


def series_targets(data_dir: str | Path, labels) -> dict[int, list]:
    """Return {series index: [the per-period target of each label]} of the series with a detected
    gross slip (those that have windows), reading only what labels need, no sensor stream."""
    rules = [label_rule(label) for label in labels]
    out = {}
    for path in ds.series_paths(data_dir):
        s = ds.load_series(path, streams=False)
        lab = label_series(s)
        if lab.gross_slip_index >= 0:
            out[s.index] = [training_labels(s, lab, rule) for rule in rules]
    return out


def relabel(ws: WindowSet, targets: dict) -> WindowSet:
    """Return the same windows (features, series, periods) with the target of another label
    ({series index: per-period target}, `series_targets`): no feature is computed again."""
    y = np.empty(len(ws.y), dtype=np.float64)
    for i in np.unique(ws.series):
        rows = ws.series == i
        y[rows] = targets[int(i)][ws.period[rows]]
    return dataclasses.replace(ws, y=y.astype(ws.y.dtype, copy=False))


def _no_windows(data_dir, spec) -> ds.DatasetError:
    """Why a data set gave `spec` no labelled window: its scene lacks the spec's sensor (e.g.
    'mechanics' for e19), or no series slid. Read only on that error, off the loading path."""
    first = ds.load_series(ds.series_paths(data_dir)[0])
    if (len(first.pac_counts) if spec.stream == "pac" else len(first.electrode_counts)) == 0:
        what = "P_AC samples" if spec.stream == "pac" else "electrode samples"
        return ds.DatasetError(
            f"{data_dir}: its series hold no {what}: scene {ds.read_meta(data_dir).get('scene')!r} "
            f"does not simulate them, and method {spec.method} reads them (slip dataset --scene paper)")
    return ds.DatasetError(f"{data_dir}: no labelled windows (no series with gross slip?)")


def _series_windows(options: tuple, path) -> tuple:
    """Return (series index, its series_key, None) for a series without gross slip, else (series
    index, its key, one tuple of columns per spec, None where the spec keeps no window of it);
    options: (specs, min_window_s, after_slip, label)."""
    specs, min_window_s, after_slip, label = options
    s = ds.load_series(path)
    key = ds.series_key(s)
    lab = label_series(s)
    if lab.gross_slip_index < 0:
        return s.index, key, None
    target = training_labels(s, lab, label)
    parts: list = [None] * len(specs)
    # specs with the same window on the same stream keep the same windows: their features in
    # one call (P_AC specs among them share each window's FFT)
    same_windows: dict = {}
    for j, spec in enumerate(specs):
        same_windows.setdefault((spec.stream, spec.rate_hz, spec.window_samples), []).append(j)
    for js in same_windows.values():
        spec = specs[js[0]]
        n_stream = len(s.pac_counts) if spec.stream == "pac" else len(s.electrode_counts)
        ok = valid_window_mask(s.period_end_s, spec, n_stream)
        if min_window_s is not None:
            ok &= s.period_end_s - min_window_s >= -1e-9
        if after_slip == "drop":
            ok &= np.arange(len(ok)) <= lab.gross_slip_index
        k = np.flatnonzero(ok)
        if len(k) == 0:
            continue
        for j, X in zip(js, series_feature_sets(s, [specs[j] for j in js], s.period_end_s[k])):
            parts[j] = (X, target[k], np.full(len(k), s.index), np.full(len(k), s.material, dtype=object), k,
                        s.stick_area_ratio[k], s.load_ratio_stick[k], s.tangential_force_n[k],
                        s.normal_force_kpa[k], k > lab.gross_slip_index)
    return s.index, key, parts


def _load_window_sets(data_dir, specs, min_window_s, progress: bool, after_slip: str, label: str,
                      workers: int) -> list[WindowSet]:
    paths = ds.series_paths(data_dir)
    desc = f"phi {'+'.join(s.method for s in specs)} {Path(data_dir).name}"
    per_series = []
    with tqdm(total=len(paths), desc=desc, unit="series", disable=not progress, leave=False) as bar:
        for r in forked_map(_series_windows, paths, workers, (specs, min_window_s, after_slip, label), chunksize=8):
            per_series.append(r)
            bar.update()
    skipped = [index for index, _, parts in per_series if parts is None]
    keys = {index: key for index, key, _ in per_series if key}
    data_hash = ds.dataset_hash(data_dir)
    out = []
    for j, spec in enumerate(specs):
        parts = [p[j] for _, _, p in per_series if p is not None and p[j] is not None]
        if not parts:
            raise _no_windows(data_dir, spec)
        cols = [np.concatenate(c) for c in zip(*parts)]
        cols[3] = cols[3].astype(str)
        out.append(WindowSet(*cols, spec=spec, data_hash=data_hash, skipped_series=list(skipped),
                             series_keys=keys))
    return out


def _rank(seed: int, index: int) -> str:
    return hashlib.sha256(f"{seed}:{index}".encode()).hexdigest()


def held_out_series(series_material: dict, fraction: float = TEST_FRACTION,
                    seed: int = SPLIT_SEED) -> np.ndarray:
    """Return the sorted test series indices: per material, the ceil(fraction * n) series with
    the smallest hash(seed, index). Depends only on (index, material), so every method and
    both data sets (with and without injection) share it when their series agree."""
    by_material: dict = {}
    for idx, mat in series_material.items():
        by_material.setdefault(mat, []).append(int(idx))
    test = []
    for mat in sorted(by_material):
        idxs = sorted(by_material[mat], key=lambda i: _rank(seed, i))
        n_test = int(np.ceil(fraction * len(idxs) - 1e-9))
        if len(idxs) > 1:
            n_test = min(max(n_test, 1), len(idxs) - 1)
        else:
            n_test = 0
        test.extend(idxs[:n_test])
    return np.array(sorted(test), dtype=np.int64)


def grouped_folds(groups: np.ndarray, n_folds: int, seed: int = SPLIT_SEED):
    """Yield (train_rows, val_rows) with whole series per fold (no series in both)."""
    uniq = np.unique(groups)
    order = sorted(uniq.tolist(), key=lambda i: _rank(seed + 1, i))
    fold_of = {g: j % n_folds for j, g in enumerate(order)}
    f = np.array([fold_of[g] for g in groups])
    for j in range(n_folds):
        yield np.flatnonzero(f != j), np.flatnonzero(f == j)


def subsample_rows(n: int, max_rows: int | None, seed: int = SPLIT_SEED) -> np.ndarray:
    """Return sorted row indices of a seeded uniform subsample (all rows when n <= max_rows)."""
    if max_rows is None or n <= max_rows:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=max_rows, replace=False))


def _standardize(X):
    mean = X.mean(axis=0, dtype=np.float64)
    scale = X.std(axis=0, dtype=np.float64)
    scale[scale < 1e-12] = 1.0
    return mean, scale


def svr_grid(n_features: int, quick: bool = False) -> list[dict]:
    """Return the SVR hyper-parameter grid (gamma in units of 1 / n_features, 'scale')."""
    eps = (0.02, 0.05)
    if quick:
        return [dict(kernel="rbf", C=C, gamma=g / n_features, epsilon=0.05)
                for C, g in ((1.0, 1.0), (10.0, 0.3), (10.0, 1.0))]
    rbf = [dict(kernel="rbf", C=C, gamma=g / n_features, epsilon=e)
           for C, g, e in product((0.3, 1.0, 3.0, 10.0), (0.3, 1.0, 3.0), eps)]
    lin = [dict(kernel="linear", C=C, epsilon=e) for C, e in product((0.1, 1.0), eps)]
    return rbf + lin


def _fit_svr(Z, y, params, cache_mb=SVR_CACHE_MB):
    """Return an SVR fitted on (Z, y); from the content-hashed cache when one is on (`cache`)."""
    import sklearn
    from sklearn.svm import SVR

    from .. import cache
    p = dict(params)
    return cache.cached("svr-fit", cache.digest("svr-fit-1", sklearn.__version__, Z, y, p),
                        lambda: SVR(cache_size=cache_mb, **p).fit(Z, y))


def _sq_distances(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Return |a|^2 + |b|^2 - 2 a.b for all row pairs: libsvm's RBF distance, term for term."""
    return np.einsum("ij,ij->i", A, A)[:, None] + np.einsum("ij,ij->i", B, B)[None] - 2.0 * (A @ B.T)


def _rbf_kernels(Z_tr, Z_va, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the RBF kernel of a fold's training rows with themselves and of its validation rows
    with them, as libsvm forms it: exp(-gamma (|a|^2 + |b|^2 - 2 a.b)), the diagonal exactly 1."""
    K = np.exp(-gamma * _sq_distances(Z_tr, Z_tr))
    np.fill_diagonal(K, 1.0)
    return K, np.exp(-gamma * _sq_distances(Z_va, Z_tr))


def _group_mse(Z, y, tr, va, cells, zy_key: str = "") -> list[float]:
    """Return the validation MSE of each SVR candidate of one grid task (`grid_tasks`: one fold,
    candidates sharing a kernel), fitted on the fold's training rows.

    RBF candidates of one gamma share one kernel matrix: it is computed once, at the first fit
    that needs it, and each candidate is fitted with `kernel="precomputed"` - the same libsvm
    solver on the same float32 kernel cache as libsvm's own RBF, so the same dual coefficients
    (checked bit for bit in tests/models/test_training.py) in about a third of the time. Other
    kernels are fitted as they are. Each cell is cached by (`zy_key` = the digest of Z and y,
    the fold, its parameters) when a cache is on."""
    import sklearn
    from sklearn.svm import SVR

    from .. import cache
    kernels: list = []

    def fit(p: dict) -> float:
        if p["kernel"] == "rbf":
            if not kernels:
                kernels.extend(_rbf_kernels(Z[tr], Z[va], p["gamma"]))
            rest = {k: v for k, v in p.items() if k not in ("kernel", "gamma")}
            pred = SVR(kernel="precomputed", cache_size=SVR_CACHE_MB, **rest).fit(kernels[0], y[tr]).predict(kernels[1])
        else:
            pred = SVR(cache_size=SVR_CACHE_MB, **p).fit(Z[tr], y[tr]).predict(Z[va])
        return float(np.mean((np.clip(pred, 0, 1) - y[va]) ** 2))
    if len({p.get("gamma") for p in cells if p["kernel"] == "rbf"}) > 1:
        raise ValueError("one grid task shares one RBF gamma")
    if not zy_key or cache.root() is None:
        return [fit(dict(p)) for p in cells]
    return [cache.cached("svr-fold", cache.digest("svr-fold-2", sklearn.__version__, zy_key, tr, va, dict(p)),
                         lambda p=dict(p): fit(p)) for p in cells]


def grid_tasks(grid: list[dict], n_folds: int) -> list[tuple[int, list[int]]]:
    """Return the grid's tasks (fold, [candidate index, ...]): per fold, the RBF candidates of one
    gamma together (they share a kernel matrix), every other candidate alone. The single
    candidates (linear: the slowest fits, seconds each at C = 1) come first, so that a pool ends
    on the short shared-kernel tasks."""
    single, shared = [], []
    for j in range(n_folds):
        by_gamma: dict = {}
        for i, p in enumerate(grid):
            if p.get("kernel") == "rbf":
                by_gamma.setdefault(p["gamma"], []).append(i)
            else:
                single.append((j, [i]))
        shared.extend((j, idx) for idx in by_gamma.values())
    return single + shared


def _task_mse(shared: tuple, task) -> list[float]:
    Z, y, zy_key, grid, folds = shared
    j, idx = task
    return _group_mse(Z, y, *folds[j], [grid[i] for i in idx], zy_key)


def grid_search_svr(X, y, groups, grid, n_folds=3, progress=True, desc="grid", client=None, workers: int = 1):
    """Return (best params, rows of {params, rmse}) by grouped k-fold RMSE on standardized X.

    The candidate x fold fits run as `grid_tasks` (RBF candidates of one gamma share a kernel
    matrix per fold). client: a dask Client (`cluster.open_client`): the tasks run there.
    workers: without a client, run them in this many forked local processes (1: in process).
    Every fit is deterministic, so the rows and the choice do not depend on where they ran."""
    mean, scale = _standardize(X)
    Z = (X - mean) / scale
    folds = list(grouped_folds(groups, n_folds))
    tasks = grid_tasks(grid, len(folds))
    from .. import cache
    zy_key = cache.digest(Z, y) if cache.root() is not None else ""
    with tqdm(total=len(grid) * len(folds), desc=desc, unit="fit", disable=not progress or client is not None,
              leave=False) as bar:
        if client is not None:
            Zf, yf = client.scatter([Z, y])
            mse = map_tasks(client, _group_mse, [(Zf, yf, *folds[j], [grid[i] for i in idx]) for j, idx in tasks],
                            desc=desc, progress=progress, key="svr-fit", leave=False)
        else:
            mse = []
            for v in forked_map(_task_mse, tasks, workers, (Z, y, zy_key, grid, folds)):
                mse.append(v)
                bar.update(len(v))
    per_cell = {(i, j): v for (j, idx), values in zip(tasks, mse) for i, v in zip(idx, values)}
    rows = [{"params": params, "rmse": float(np.sqrt(np.mean([per_cell[i, j] for j in range(len(folds))])))}
            for i, params in enumerate(grid)]
    best = min(rows, key=lambda r: r["rmse"])
    return best["params"], rows


def model_from_svr(svr, mean, scale, spec) -> Model:
    """Return the array form of a fitted sklearn SVR on standardized features."""
    kernel = svr.kernel
    gamma = float(svr._gamma) if kernel in ("rbf", "poly", "sigmoid") else 1.0
    return Model(spec=spec, kind="kernel", mean=mean, scale=scale,
                 weights=svr.dual_coef_[0], intercept=float(svr.intercept_[0]),
                 centers=svr.support_vectors_, kernel=kernel, gamma=gamma,
                 coef0=float(svr.coef0), degree=int(svr.degree))


def rbf_kernel(Z: np.ndarray, centers: np.ndarray, gamma: float) -> np.ndarray:
    """Return exp(-gamma |z - c|^2) for all rows of Z against all centres."""
    return rbf_of_dot((Z * Z).sum(1), (centers * centers).sum(1), Z @ centers.T, gamma)


def nystroem_basis(Z, n_components, gamma, seed=SPLIT_SEED):
    """Return (centers, N) for RBF Nystroem: seeded landmark rows and N = K(C, C)^(-1/2)."""
    n_components = min(n_components, len(Z))
    rng = np.random.default_rng(seed)
    centers = Z[np.sort(rng.choice(len(Z), n_components, replace=False))]
    u, sv, vt = np.linalg.svd(rbf_kernel(centers, centers, gamma))
    return centers, (u / np.sqrt(np.maximum(sv, 1e-12))) @ vt


def nystroem_sums(Z, y, centers, norm, gamma, chunk=20000) -> dict:
    """Return the additive sums (F^T F, F^T y, sum F, sum y, n) of the Nystroem features F."""
    k = len(centers)
    out = {"A": np.zeros((k, k)), "b": np.zeros(k), "f": np.zeros(k), "y": 0.0, "n": 0}
    for a in range(0, len(Z), chunk):
        F = rbf_kernel(Z[a:a + chunk], centers, gamma) @ norm.T
        out["A"] += F.T @ F
        out["b"] += F.T @ y[a:a + chunk]
        out["f"] += F.sum(0)
        out["y"] += float(np.sum(y[a:a + chunk]))
        out["n"] += len(F)
    return out


def nystroem_solve(sums: dict, norm, alpha: float):
    """Return (weights, intercept) of ridge with per-window penalty alpha, folded through N."""
    n = sums["n"]
    fmean, ymean = sums["f"] / n, sums["y"] / n
    A_c = sums["A"] / n - np.outer(fmean, fmean)
    b_c = sums["b"] / n - fmean * ymean
    beta = np.linalg.solve(A_c + alpha * np.eye(len(b_c)), b_c)
    return norm.T @ beta, ymean - float(fmean @ beta)


NYSTROEM_ALPHAS = (1e-5, 1e-4, 1e-3, 1e-2)


@dataclass
class TrainResult:
    model: Model
    report: dict


def train_model(ws: WindowSet, kind: str = "svr", max_train: int | None = 6000,
                grid_max: int = 2000, n_components: int = 1000, quick: bool = False,
                progress: bool = True, params: dict | None = None, client=None, workers: int = 1) -> TrainResult:
    """Return a Model trained on all rows of `ws` (the caller removes the test series first).

    params: skip the grid and use these SVR parameters (kind svr / gamma for nystroem).
    client: a dask Client to run the grid search's fits on (grid_search_svr); workers: local
    processes for them instead (same rows and choice).
    """
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r} unknown; expected one of {', '.join(KINDS)}")
    t0 = time.perf_counter()
    X, y, groups = ws.X.astype(np.float64), ws.y, ws.series
    if len(np.unique(groups)) < 2:        # the searches and the ridge's validation hold whole series out
        raise ValueError(f"training needs windows of at least 2 series, got {len(np.unique(groups))} (after "
                         "the held-out series: a material with n series keeps ceil(n / 10) of them for the test; "
                         "collect at least 3 series per material)")
    report = {"kind": kind, "n_windows": int(len(y)), "n_series": int(len(np.unique(groups)))}
    grid_rows = []
    if kind in ("svr", "nystroem") and params is None:
        g = subsample_rows(len(y), grid_max)
        n_folds = min(3, len(np.unique(groups[g])))
        params, grid_rows = grid_search_svr(X[g], y[g], groups[g], svr_grid(X.shape[1], quick),
                                            n_folds=n_folds, progress=progress,
                                            desc=f"grid {ws.spec.method}", client=client, workers=workers)
    report["grid"] = grid_rows
    if kind == "svr":
        rows = subsample_rows(len(y), max_train)
        mean, scale = _standardize(X[rows])
        t1 = time.perf_counter()
        svr = _fit_svr((X[rows] - mean) / scale, y[rows], params)
        report["fit_s"] = time.perf_counter() - t1
        model = model_from_svr(svr, mean, scale, ws.spec)
        report.update(params=params, n_fit=int(len(rows)), n_support=int(len(svr.support_)))
    elif kind == "nystroem":
        mean, scale = _standardize(X)
        Z = (X - mean) / scale
        gamma = params.get("gamma") if params.get("kernel") == "rbf" else 1.0 / X.shape[1]
        gamma = float(gamma)
        t1 = time.perf_counter()
        centers, norm = nystroem_basis(Z, n_components, gamma)
        tr, va = next(grouped_folds(groups, 5))
        s_tr = nystroem_sums(Z[tr], y[tr], centers, norm, gamma)
        s_va = nystroem_sums(Z[va], y[va], centers, norm, gamma)
        kva = rbf_kernel(Z[va], centers, gamma)
        scores = []
        for a in NYSTROEM_ALPHAS:
            w, b0 = nystroem_solve(s_tr, norm, a)
            scores.append(_rmse(np.clip(kva @ w + b0, 0, 1), y[va]))
        alpha = NYSTROEM_ALPHAS[int(np.argmin(scores))]
        total = {k: s_tr[k] + s_va[k] for k in s_tr}
        weights, b = nystroem_solve(total, norm, alpha)
        alphas = NYSTROEM_ALPHAS
        report["fit_s"] = time.perf_counter() - t1
        model = Model(spec=ws.spec, kind="kernel", mean=mean, scale=scale, weights=weights,
                      intercept=b, centers=centers, kernel="rbf", gamma=gamma)
        report.update(params={"gamma": gamma, "alpha": alpha, "n_components": int(len(centers))},
                      n_fit=int(len(y)), alpha_rmse=dict(zip(map(str, alphas), scores)))
    else:
        from sklearn.linear_model import Ridge
        mean, scale = _standardize(X)
        Z = (X - mean) / scale
        tr, va = next(grouped_folds(groups, 5))
        alphas = (1e-2, 1.0, 100.0)
        scores = [_rmse(np.clip(Ridge(alpha=a).fit(Z[tr], y[tr]).predict(Z[va]), 0, 1), y[va])
                  for a in alphas]
        alpha = alphas[int(np.argmin(scores))]
        t1 = time.perf_counter()
        r = Ridge(alpha=alpha).fit(Z, y)
        report["fit_s"] = time.perf_counter() - t1
        model = Model(spec=ws.spec, kind="linear", mean=mean, scale=scale, weights=r.coef_,
                      intercept=float(r.intercept_))
        report.update(params={"alpha": alpha}, n_fit=int(len(y)))
    report["train_s"] = time.perf_counter() - t0
    model.header.update({"hyper_parameters": report.get("params"), "regressor": kind,
                         "training_data_hash": ws.data_hash, "n_train_windows": int(len(y)),
                         "n_fit_windows": report.get("n_fit"),
                         "train_series": [int(v) for v in np.unique(groups)],
                         "train_series_keys": sorted(ws.series_keys[int(v)] for v in np.unique(groups)
                                                     if int(v) in ws.series_keys)})
    return TrainResult(model, report)


def _rmse(pred, y):
    return float(np.sqrt(np.mean((np.asarray(pred) - y) ** 2)))


def split_train_test(ws: WindowSet, test_series: np.ndarray) -> tuple[WindowSet, WindowSet]:
    """Return (train, test) WindowSets by series membership."""
    is_test = np.isin(ws.series, test_series)
    return ws.subset(~is_test), ws.subset(is_test)
