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
from dataclasses import dataclass, field
from itertools import product
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..cluster import map_tasks
from . import dataset as ds
from .features import FeatureSpec, series_features, valid_window_mask
from .labels import LABELS, label_series, training_labels
from .modelfile import Model

SPLIT_SEED = 20240917
TEST_FRACTION = 0.10
KINDS = ("svr", "nystroem", "linear")


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

    def subset(self, mask: np.ndarray) -> "WindowSet":
        keep = {k: getattr(self, k)[mask] for k in ("X", "y", "series", "material", "period",
                                                  "stick_area_ratio", "load_ratio_stick",
                                                  "tangential_force_n", "normal_force_kpa",
                                                  "post_slip")}
        return WindowSet(**keep, spec=self.spec, data_hash=self.data_hash,
                         skipped_series=self.skipped_series)

    def series_materials(self) -> dict:
        return {int(s): str(m) for s, m in zip(self.series, self.material)}


AFTER_SLIP = ("zero", "drop")


def load_windows(data_dir: str | Path, spec: FeatureSpec, min_window_s: float | None = None,
                 progress: bool = True, after_slip: str = "zero", label: str = "pseudo") -> WindowSet:
    """Return every labelled window of a data set for `spec` (one series file at a time).

    min_window_s: keep only windows that would also be complete for a window of this length
    (used to compare different T on the same samples).
    after_slip: "zero" keeps the windows after gross slip with label 0 (the paper's rule);
    "drop" keeps windows up to and including the gross-slip onset only (incipient slip range).
    label: "pseudo" (the paper's rule) or "true-ratio" (EXTENSION: the simulator's
    load_ratio_stick, see labels.training_labels); the windows kept are the same for both.
    With a cache on (`incipient_slip.cache`) the windows are stored under a key of the data set's
    content hash, the spec, these options and the code of models/, and read back next time.
    """
    if label not in LABELS:
        raise ValueError(f"label {label!r} unknown; expected one of {', '.join(LABELS)}")
    if after_slip not in AFTER_SLIP:
        raise ValueError(f"after_slip {after_slip!r} unknown; expected one of {AFTER_SLIP}")
    from .. import cache
    if cache.root() is None:
        return _load_windows(data_dir, spec, min_window_s, progress, after_slip, label)
    key = cache.digest("windows-1", ds.dataset_hash(data_dir), repr(spec), min_window_s, after_slip, label,
                       cache.source_version(Path(__file__).parent))
    return cache.cached("windows", key, lambda: _load_windows(data_dir, spec, min_window_s, progress, after_slip,
                                                              label))


def _load_windows(data_dir, spec: FeatureSpec, min_window_s, progress: bool, after_slip: str,
                  label: str) -> WindowSet:
    meta = ds.read_meta(data_dir)
    if spec.stream == "pac" and spec.injection is not None and bool(meta.get("injection", True)) != spec.injection:
        raise ds.DatasetError(
            f"{data_dir}: data set has injection={meta.get('injection')} but method "
            f"{spec.method} needs injection={spec.injection} (scene 'paper' for injection, "
            "'no_injection' for vibrotactile)")
    paths = ds.series_paths(data_dir)
    parts, skipped = [], []
    for path in tqdm(paths, desc=f"phi {spec.method} {Path(data_dir).name}", unit="series",
                     disable=not progress, leave=False):
        s = ds.load_series(path)
        lab = label_series(s)
        if lab.gross_slip_index < 0:
            skipped.append(s.index)
            continue
        n_stream = len(s.pac_counts) if spec.stream == "pac" else len(s.electrode_counts)
        ok = valid_window_mask(s.period_end_s, spec, n_stream)
        if min_window_s is not None:
            ok &= s.period_end_s - min_window_s >= -1e-9
        if after_slip == "drop":
            ok &= np.arange(len(ok)) <= lab.gross_slip_index
        k = np.flatnonzero(ok)
        if len(k) == 0:
            continue
        X = series_features(s, spec, s.period_end_s[k])
        parts.append((X, training_labels(s, lab, label)[k], np.full(len(k), s.index),
                      np.full(len(k), s.material, dtype=object), k, s.stick_area_ratio[k],
                      s.load_ratio_stick[k], s.tangential_force_n[k], s.normal_force_kpa[k],
                      k > lab.gross_slip_index))
    if not parts:
        raise ds.DatasetError(f"{data_dir}: no labelled windows (no series with gross slip?)")
    cols = [np.concatenate(c) for c in zip(*parts)]
    cols[3] = cols[3].astype(str)
    return WindowSet(*cols, spec=spec, data_hash=ds.dataset_hash(data_dir), skipped_series=skipped)


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


def _fit_svr(Z, y, params, cache_mb=500):
    """Return an SVR fitted on (Z, y); from the content-hashed cache when one is on (`cache`)."""
    import sklearn
    from sklearn.svm import SVR

    from .. import cache
    p = dict(params)
    return cache.cached("svr-fit", cache.digest("svr-fit-1", sklearn.__version__, Z, y, p),
                        lambda: SVR(cache_size=cache_mb, **p).fit(Z, y))


def _fold_mse(Z, y, tr, va, params, zy_key: str = "") -> float:
    """Return the validation MSE of one SVR candidate fitted on one grouped fold (a grid task);
    cached by (`zy_key` = the digest of Z and y, the fold, the parameters) when a cache is on."""
    import sklearn
    from sklearn.svm import SVR

    from .. import cache

    def mse():
        m = SVR(cache_size=500, **dict(params)).fit(Z[tr], y[tr])
        return float(np.mean((np.clip(m.predict(Z[va]), 0, 1) - y[va]) ** 2))
    if not zy_key or cache.root() is None:
        return mse()
    return cache.cached("svr-fold", cache.digest("svr-fold-1", sklearn.__version__, zy_key, tr, va, dict(params)), mse)


_SHARED: tuple = ()      # (Z, y, their cache key) of the grid search a forked pool's workers inherit


def _shared_fold_mse(cell) -> float:
    params, tr, va = cell
    Z, y, zy_key = _SHARED
    return _fold_mse(Z, y, tr, va, params, zy_key)


def _pool_mse(Z, y, zy_key, cells, workers: int, bar) -> list[float]:
    """Return the fold MSEs of `cells` from `workers` forked processes (Z and y inherited, not sent)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    global _SHARED
    _SHARED = (Z, y, zy_key)
    try:
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
            out = []
            for v in pool.map(_shared_fold_mse, cells):
                out.append(v)
                bar.update()
            return out
    finally:
        _SHARED = ()


def grid_search_svr(X, y, groups, grid, n_folds=3, progress=True, desc="grid", client=None, workers: int = 1):
    """Return (best params, rows of {params, rmse}) by grouped k-fold RMSE on standardized X.

    client: a dask Client (`cluster.open_client`): the candidate x fold fits run there as tasks.
    workers: without a client, fit the cells in this many forked local processes (1: in process).
    Every fit is deterministic, so the rows and the choice do not depend on where they ran."""
    mean, scale = _standardize(X)
    Z = (X - mean) / scale
    folds = list(grouped_folds(groups, n_folds))
    cells = [(params, tr, va) for params in grid for tr, va in folds]
    from .. import cache
    zy_key = cache.digest(Z, y) if cache.root() is not None else ""
    if client is None and workers > 1:
        with tqdm(total=len(cells), desc=desc, unit="fit", disable=not progress, leave=False) as bar:
            mse = _pool_mse(Z, y, zy_key, cells, workers, bar)
    elif client is None:
        mse = [_fold_mse(Z, y, tr, va, params, zy_key)
               for params, tr, va in tqdm(cells, desc=desc, unit="fit", disable=not progress, leave=False)]
    else:
        Zf, yf = client.scatter([Z, y])
        mse = map_tasks(client, _fold_mse, [(Zf, yf, tr, va, params) for params, tr, va in cells],
                        desc=desc, progress=progress, key="svr-fit", leave=False)
    k = len(folds)
    rows = [{"params": params, "rmse": float(np.sqrt(np.mean(mse[i * k:(i + 1) * k])))}
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
    sq = (Z * Z).sum(1)[:, None] + (centers * centers).sum(1)[None] - 2.0 * Z @ centers.T
    return np.exp(-gamma * np.maximum(sq, 0.0))


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
                         "train_series": [int(v) for v in np.unique(groups)]})
    return TrainResult(model, report)


def _rmse(pred, y):
    return float(np.sqrt(np.mean((np.asarray(pred) - y) ** 2)))


def split_train_test(ws: WindowSet, test_series: np.ndarray) -> tuple[WindowSet, WindowSet]:
    """Return (train, test) WindowSets by series membership."""
    is_test = np.isin(ws.series, test_series)
    return ws.subset(~is_test), ws.subset(is_test)
