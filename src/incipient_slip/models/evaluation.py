"""Evaluation: per-series RMSE, the worst case ("top 10 %"), per material, paired t-tests.

Definitions used everywhere (docs/estimation.md repeats them):

* **RMSE of a series**: sqrt(mean((s_hat - s)^2)) over all labelled windows of one test series.
* **Top-10 % RMSE of a series**: the RMSE over that series' ceil(10 %) windows with the largest
  absolute error |s_hat - s| (at least one window). It is the worst-case error the paper
  compares; computed per series so it can be paired across methods like the RMSE.
* A method's score is the mean (and std) of these per-series values over the held-out series.
* **Tests**: paired two-sided t-tests (`scipy.stats.ttest_rel`) of the per-series values of
  the injection method against each other method on the same held-out series; the five
  p-values of one metric are Holm-corrected; ** marks p_Holm < 0.01, * p_Holm < 0.05.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

TOP_FRACTION = 0.10


def top_fraction_rmse(abs_err: np.ndarray, fraction: float = TOP_FRACTION) -> float:
    """Return the RMSE over the ceil(fraction * n) largest absolute errors (at least one)."""
    abs_err = np.abs(np.asarray(abs_err, dtype=np.float64))
    k = max(1, int(np.ceil(fraction * len(abs_err) - 1e-9)))
    top = np.partition(abs_err, len(abs_err) - k)[-k:]
    return float(np.sqrt(np.mean(top ** 2)))


@dataclass
class SeriesScores:
    """Per-series scores of one method on the held-out series (aligned arrays, sorted by series)."""

    method: str
    series: np.ndarray
    material: np.ndarray
    rmse: np.ndarray
    top10_rmse: np.ndarray
    n_windows: np.ndarray

    def summary(self) -> dict:
        out = {"method": self.method, "n_series": int(len(self.series)),
               "rmse_mean": float(self.rmse.mean()), "rmse_std": float(self.rmse.std(ddof=1)) if len(self.rmse) > 1 else 0.0,
               "top10_mean": float(self.top10_rmse.mean()),
               "top10_std": float(self.top10_rmse.std(ddof=1)) if len(self.rmse) > 1 else 0.0}
        out["by_material"] = {str(m): {"rmse": float(self.rmse[self.material == m].mean()),
                                       "top10": float(self.top10_rmse[self.material == m].mean()),
                                       "n_series": int((self.material == m).sum())}
                              for m in np.unique(self.material)}
        return out


def series_scores(method: str, y: np.ndarray, pred: np.ndarray, series: np.ndarray,
                  material: np.ndarray) -> SeriesScores:
    """Return the per-series RMSE and top-10 % RMSE of predictions against labels."""
    ids = np.unique(series)
    rmse, top, n, mats = [], [], [], []
    for sid in ids:
        m = series == sid
        err = pred[m] - y[m]
        rmse.append(np.sqrt(np.mean(err ** 2)))
        top.append(top_fraction_rmse(err))
        n.append(m.sum())
        mats.append(material[m][0])
    return SeriesScores(method, ids, np.array(mats), np.array(rmse), np.array(top), np.array(n))


def holm(pvalues) -> np.ndarray:
    """Return Holm-Bonferroni adjusted p-values (same order as given)."""
    p = np.asarray(pvalues, dtype=np.float64)
    order = np.argsort(p)
    m = len(p)
    adj = np.empty(m)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        adj[i] = running
    return adj


def stars(p: float) -> str:
    """Return the paper's significance mark: ** p < 0.01, * p < 0.05, '' otherwise."""
    return "**" if p < 0.01 else "*" if p < 0.05 else ""


def paired_tests(scores: dict, reference: str = "injection", metric: str = "rmse") -> dict:
    """Return {method: {t, p, p_holm, stars, n}} of reference vs each other method.

    Pairs are the held-out series both methods scored (the same 10 % for every method).
    """
    ref = scores[reference]
    rows = {}
    for name, sc in scores.items():
        if name == reference:
            continue
        common, ia, ib = np.intersect1d(ref.series, sc.series, return_indices=True)
        a, b = getattr(ref, metric)[ia], getattr(sc, metric)[ib]
        if len(common) < 2 or np.allclose(a - b, 0):
            t, p = float("nan"), 1.0
        else:
            t, p = stats.ttest_rel(a, b)
        rows[name] = {"t": float(t), "p": float(p), "n": int(len(common)),
                      "mean_diff": float(np.mean(a - b)) if len(common) else float("nan")}
    if rows:
        adj = holm([r["p"] for r in rows.values()])
        for r, pa in zip(rows.values(), adj):
            r["p_holm"] = float(pa)
            r["stars"] = stars(pa)
    return rows
