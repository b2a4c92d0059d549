"""Six models trained and scored on one shared set of held-out series: the study's core.

Used by the estimation and model-regeneration experiments. It reads data-set directories (the
format of docs/design.md) and never the simulator: the experiments make the data sets.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from . import dataset as ds
from .evaluation import SeriesScores, paired_tests, series_scores
from .features import METHODS, feature_spec
from .modelfile import Model
from .labels import label_rule
from .training import (WindowSet, forked_map, held_out_series, load_window_sets, split_train_test,
                       train_model)

# the data set each method trains on (the key of `data_dirs`); the scene of a closed-loop run
# is another table, control.SCENE_OF_METHOD (electrodes only, no PZT drive)
DATASET_OF_METHOD = {m: ("no_injection" if m == "vibrotactile" else "paper") for m in METHODS}


@dataclass
class MethodResult:
    method: str
    model: Model
    report: dict
    test: WindowSet
    pred: np.ndarray
    scores: SeriesScores


@dataclass
class StudyResult:
    results: dict                       # method -> MethodResult
    tests_rmse: dict
    tests_top10: dict
    test_series: list
    data_dirs: dict
    timings: dict = field(default_factory=dict)

    def table(self) -> list[dict]:
        rows = []
        for m, r in self.results.items():
            s = r.scores.summary()
            s.update(kind=r.report["kind"], params=r.report.get("params"),
                     n_train_windows=r.report["n_windows"], n_support=r.report.get("n_support"),
                     train_s=r.report["train_s"],
                     p_rmse=self.tests_rmse.get(m, {}).get("p_holm"),
                     p_top10=self.tests_top10.get(m, {}).get("p_holm"))
            rows.append(s)
        return rows

    def to_json(self) -> dict:
        return {"table": self.table(), "tests_rmse": self.tests_rmse, "tests_top10": self.tests_top10,
                "test_series": self.test_series, "data_dirs": {k: str(v) for k, v in self.data_dirs.items()},
                "timings": self.timings}


def load_all_windows(data_dirs: dict, methods=METHODS, window_s: float = 1.0, progress: bool = True,
                     workers: int = 1, label="pseudo") -> dict:
    """Return {method: WindowSet} of every window under `label` (default the paper's rule; filter
    post_slip for the incipient range): each data set's series read once for all its methods, by
    `workers` processes."""
    out = {}
    for scene in dict.fromkeys(DATASET_OF_METHOD[m] for m in methods):
        ms = [m for m in methods if DATASET_OF_METHOD[m] == scene]
        sets = load_window_sets(data_dirs[scene], [feature_spec(m, window_s=window_s) for m in ms],
                                progress=progress, workers=workers, label=label)
        out.update(zip(ms, sets))
    return {m: out[m] for m in methods}


def _train_and_predict(train: WindowSet, test: WindowSet, kw: dict):
    tr = train_model(train, **kw)
    return tr, tr.model.predict(test.X)


def _pool_task(shared: tuple, method: str):
    from .estimator_core import limit_blas_threads
    splits, kw = shared
    with limit_blas_threads(1):          # one core per worker
        return method, _train_and_predict(*splits[method], dict(kw, progress=False))


def run_study(data_dirs: dict, methods=METHODS, kind: str = "svr", quick: bool = False,
              max_train: int | None = 6000, grid_max: int = 2000, window_s: float = 1.0,
              after_slip: str = "zero", progress: bool = True, windows: dict | None = None,
              client=None, workers: int = 1, label="pseudo") -> StudyResult:
    """Train and evaluate each method on its data set with one shared held-out series set.

    data_dirs: {"paper": dir with injection, "no_injection": dir without}.
    windows: preloaded `load_all_windows` result (of `label`), reused across after-slip policies.
    label: the training label (`labels.LABELS` name or `labels.LabelRule`; default the paper's).
    client: a dask Client for the grid searches' fits (training.grid_search_svr); workers: train
    that many methods at a time in forked local processes instead, and read the windows with as
    many (the same models: every fit is deterministic).
    """
    t0 = time.perf_counter()
    methods = list(methods)
    if windows is None:
        windows = load_all_windows(data_dirs, methods, window_s, progress, workers, label)
    windows = {m: windows[m] for m in methods}
    if after_slip == "drop":
        windows = {m: w.subset(~w.post_slip) for m, w in windows.items()}
    # one held-out set for all methods: from the series materials of the first data set,
    # checked against the others (same seed -> same material per series index)
    ref = windows[methods[0]].series_materials()
    for m in methods[1:]:
        other = windows[m].series_materials()
        bad = [i for i in set(ref) & set(other) if ref[i] != other[i]]
        if bad:
            raise ds.DatasetError(f"data sets disagree on the material of series {bad[:5]}; "
                                  "generate both scenes with the same seed and series count")
        ref = {**other, **ref}
    test_series = held_out_series(ref)
    timings = {"features_s": time.perf_counter() - t0}
    splits = {m: split_train_test(windows[m], test_series) for m in methods}
    kw = dict(kind=kind, max_train=max_train, grid_max=grid_max, quick=quick)
    if client is None and workers > 1 and len(methods) > 1:
        # the methods on `workers` forked processes (windows inherited), each grid in its process
        trained = dict(tqdm(forked_map(_pool_task, list(splits), workers, (splits, kw)), total=len(splits),
                            desc="train", disable=not progress, leave=False))
    else:
        trained = {m: _train_and_predict(*splits[m], dict(kw, progress=progress, client=client, workers=workers))
                   for m in tqdm(methods, desc="train", disable=not progress, leave=False)}
    results = {}
    for m in methods:
        (tr, pred), test = trained[m], splits[m][1]
        sc = series_scores(m, test.y, pred, test.series, test.material)
        tr.model.header["test_series"] = [int(v) for v in test_series]
        tr.model.header["test_rmse_mean"] = float(sc.rmse.mean())
        rule = label_rule(label)
        tr.model.header.update(label=rule.name, friction_lag_s=rule.friction_lag_s)
        results[m] = MethodResult(m, tr.model, tr.report, test, pred, sc)
    scores = {m: r.scores for m, r in results.items()}
    ref_m = "injection" if "injection" in scores else methods[0]
    timings["total_s"] = time.perf_counter() - t0
    return StudyResult(results, paired_tests(scores, ref_m, "rmse"),
                       paired_tests(scores, ref_m, "top10_rmse"),
                       [int(v) for v in test_series], dict(data_dirs), timings)
