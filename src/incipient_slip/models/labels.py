"""Labels: the paper's pseudo-stick ratio s = 1 - F_T / F_T^slip, one per 500 ms sample.

The rule (paper, "Labeling pseudo-stick ratio"):

* Sample k is the window ending at the end of period k (`period_end_s[k]`).
* Gross slip starts at the first sample k_slip whose object travel over the *second half of the
  paper's 1.0 s window* - the 500 ms ending at `period_end_s[k]` - is >= 0.02 mm, read from the
  mocap stream. The rule is fixed to the paper's window (0.5 s half) even when a feature
  window of another length is studied, so labels never depend on the feature choice.
* Mocap is noisy, so the position at a time t is the mean of the mocap samples within
  +-`MOCAP_AVERAGE_S` of t (about 7 samples at 120 Hz). Documented choice; the paper reads raw
  mocap and tuned the threshold "by trial and error".
* F_T^slip is the largest F_T over samples 0..k_slip: with a monotone spring force this is F_T
  at slip onset (the paper's definition); it stays right when the force drops during the slide.
* s_k = clip(1 - F_T[k] / F_T^slip, 0, 1) for k < k_slip and s_k = 0 for k >= k_slip.
* A series without detected gross slip has no F_T^slip; `label_series` says so
  (`gross_slip_index == -1`) and training skips it (the paper's series all slip).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GROSS_SLIP_MM = 0.02          # travel per 500 ms that counts as gross slip (paper)
GROSS_SLIP_SPAN_S = 0.5       # second half of the paper's T = 1.0 s window
MOCAP_AVERAGE_S = 0.025       # half-width of the mocap averaging around a time point


@dataclass(frozen=True)
class SeriesLabels:
    """Pseudo-stick ratio of one series and how it was found."""

    pseudo_stick_ratio: np.ndarray   # (n_periods,) in [0, 1]
    gross_slip_index: int            # k_slip, -1 when no gross slip was detected
    tangential_force_slip_n: float   # F_T^slip (nan without gross slip)
    travel_mm: np.ndarray            # (n_periods,) travel over the 500 ms ending at each sample


def mocap_position_at(mocap_t_s: np.ndarray, mocap_y_mm: np.ndarray, t_s: np.ndarray,
                      half_width_s: float = MOCAP_AVERAGE_S) -> np.ndarray:
    """Return the mean mocap position within +-half_width_s of each time in t_s (vectorized).

    Falls back to linear interpolation where no mocap sample lies in the interval.
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    csum = np.concatenate([[0.0], np.cumsum(mocap_y_mm)])
    lo = np.searchsorted(mocap_t_s, t_s - half_width_s, side="left")
    hi = np.searchsorted(mocap_t_s, t_s + half_width_s, side="right")
    count = hi - lo
    mean = (csum[hi] - csum[lo]) / np.maximum(count, 1)
    interp = np.interp(t_s, mocap_t_s, mocap_y_mm)
    return np.where(count > 0, mean, interp)


def gross_slip_travel_mm(mocap_t_s: np.ndarray, mocap_y_mm: np.ndarray,
                         period_end_s: np.ndarray) -> np.ndarray:
    """Return the object travel (mm) over the 500 ms ending at each period end."""
    y_end = mocap_position_at(mocap_t_s, mocap_y_mm, period_end_s)
    y_start = mocap_position_at(mocap_t_s, mocap_y_mm, period_end_s - GROSS_SLIP_SPAN_S)
    return y_end - y_start


def pseudo_stick_ratio(tangential_force_n: np.ndarray, travel_mm: np.ndarray) -> SeriesLabels:
    """Return the pseudo-stick ratio for one series from F_T and the 500 ms travel per sample."""
    tangential_force_n = np.asarray(tangential_force_n, dtype=np.float64)
    travel_mm = np.asarray(travel_mm, dtype=np.float64)
    slipping = np.flatnonzero(travel_mm >= GROSS_SLIP_MM)
    n = len(tangential_force_n)
    if len(slipping) == 0:
        return SeriesLabels(np.full(n, np.nan), -1, float("nan"), travel_mm)
    k_slip = int(slipping[0])
    ft_slip = float(np.max(tangential_force_n[: k_slip + 1]))
    if ft_slip <= 1e-9:
        s = np.zeros(n)
    else:
        s = np.clip(1.0 - tangential_force_n / ft_slip, 0.0, 1.0)
    s[k_slip:] = 0.0
    return SeriesLabels(s, k_slip, ft_slip, travel_mm)


def label_series(series) -> SeriesLabels:
    """Return the pseudo-stick ratio labels of a loaded `Series` (mocap + F_T only)."""
    travel = gross_slip_travel_mm(series.mocap_t_s, series.mocap_y_mm, series.period_end_s)
    return pseudo_stick_ratio(series.tangential_force_n, travel)


def label_error_vs_truth(pseudo: np.ndarray, stick_area_ratio: np.ndarray,
                         load_ratio_stick: np.ndarray) -> dict:
    """Return RMSE and mean bias of the pseudo label against the simulator's true ratios."""
    out = {}
    for name, truth in (("stick_area_ratio", stick_area_ratio), ("load_ratio_stick", load_ratio_stick)):
        ok = np.isfinite(pseudo) & np.isfinite(truth)
        if not ok.any():
            out[name] = {"rmse": float("nan"), "bias": float("nan"), "n": 0}
            continue
        err = pseudo[ok] - truth[ok]
        out[name] = {"rmse": float(np.sqrt(np.mean(err ** 2))), "bias": float(np.mean(err)),
                     "n": int(ok.sum())}
    return out
