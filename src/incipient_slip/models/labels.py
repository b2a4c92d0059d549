"""Labels: the paper's pseudo-stick ratio s = 1 - F_T / F_T^slip, one per 500 ms sample.

The rule (paper, "Labeling pseudo-stick ratio"):

* Sample k is the window ending at the end of period k (`period_end_s[k]`).
* Gross slip starts at the first sample k_slip whose object travel in the *second half of the
  paper's 1.0 s window* - the 500 ms period ending at `period_end_s[k]` - is >= 0.02 mm, read
  from the mocap stream. The paper looks at the second half because the soft fingertip deforms
  (the object moves without slipping) right after each actuator step and F_N change; we
  therefore measure the travel *within* the period, from the mean mocap position over its
  first `EARLY_S` (25 ms, 3 samples at 120 Hz) to the mean over its last `LATE_S` (50 ms),
  so the deformation jump at the period start is excluded while a slide (which takes ~100 ms
  in the simulated rig) is caught. Averaging keeps mocap jitter (0.005 mm) far below 0.02 mm.
  The rule is fixed to the paper's 0.5 s period even when another feature window T is
  studied, so labels never depend on the feature choice.
* F_T^slip is the largest F_T over samples 0..k_slip: with a monotone spring force this is F_T
  at slip onset (the paper's definition); it stays right when the force drops during the slide.
* s_k = clip(1 - F_T[k] / F_T^slip, 0, 1) for k < k_slip and s_k = 0 for k >= k_slip.
* A series without detected gross slip has no F_T^slip; `label_series` says so
  (`gross_slip_index == -1`) and training skips it (the paper's series all slip).

EXTENSION, not the paper's method: `training_labels(..., label="true-ratio")` replaces the pseudo
label by the simulator's true load ratio `load_ratio_stick` = 1 - Q / (mu_s F_N) of period k for
the window ending at period k (0 where the simulator flags gross slip, or has no value). Only a
simulated data set stores it; it tests whether the pseudo label is why the closed loop fails
(docs/stabilization.md). The window selection (and the gross-slip onset used by
after_slip="drop") stays the paper's mocap rule, so only the target changes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from incipient_slip.messages import PERIOD_NS

GROSS_SLIP_MM = 0.02          # travel per 500 ms that counts as gross slip (paper)
GROSS_SLIP_SPAN_S = PERIOD_NS / 1e9   # second half of the paper's T = 1.0 s window (= one period)
EARLY_S = 0.025               # mocap averaged over the first 25 ms of the period ...
LATE_S = 0.05                 # ... and over its last 50 ms
LABELS = ("pseudo", "true-ratio")   # "pseudo": the paper's rule (default); "true-ratio": extension


@dataclass(frozen=True)
class SeriesLabels:
    """Pseudo-stick ratio of one series and how it was found."""

    pseudo_stick_ratio: np.ndarray   # (n_periods,) in [0, 1]
    gross_slip_index: int            # k_slip, -1 when no gross slip was detected
    tangential_force_slip_n: float   # F_T^slip (nan without gross slip)
    travel_mm: np.ndarray            # (n_periods,) travel over the 500 ms ending at each sample


def mocap_mean_between(mocap_t_s: np.ndarray, mocap_y_mm: np.ndarray, t0_s: np.ndarray,
                       t1_s: np.ndarray) -> np.ndarray:
    """Return the mean mocap position over [t0, t1) for each pair (vectorized).

    Falls back to linear interpolation at the interval's middle where it holds no sample.
    """
    t0_s, t1_s = np.asarray(t0_s, dtype=np.float64), np.asarray(t1_s, dtype=np.float64)
    csum = np.concatenate([[0.0], np.cumsum(mocap_y_mm)])
    lo = np.searchsorted(mocap_t_s, t0_s - 1e-9, side="left")
    hi = np.searchsorted(mocap_t_s, t1_s - 1e-9, side="left")
    count = hi - lo
    mean = (csum[hi] - csum[lo]) / np.maximum(count, 1)
    interp = np.interp(0.5 * (t0_s + t1_s), mocap_t_s, mocap_y_mm)
    return np.where(count > 0, mean, interp)


def gross_slip_travel_mm(mocap_t_s: np.ndarray, mocap_y_mm: np.ndarray,
                         period_end_s: np.ndarray) -> np.ndarray:
    """Return the object travel (mm) within the 500 ms period ending at each period end."""
    start = np.asarray(period_end_s, dtype=np.float64) - GROSS_SLIP_SPAN_S
    y_early = mocap_mean_between(mocap_t_s, mocap_y_mm, start, start + EARLY_S)
    y_late = mocap_mean_between(mocap_t_s, mocap_y_mm, period_end_s - LATE_S, period_end_s)
    return y_late - y_early


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


def true_ratio_label(load_ratio_stick: np.ndarray, gross_slip: np.ndarray | None = None) -> np.ndarray:
    """Return the simulator's true load ratio per period as a label (EXTENSION, not the paper's).

    s_k = clip(load_ratio_stick[k], 0, 1); 0 where the simulator flags gross slip or stores nan.
    """
    s = np.clip(np.nan_to_num(np.asarray(load_ratio_stick, dtype=np.float64), nan=0.0), 0.0, 1.0)
    if gross_slip is not None:
        s = np.where(np.asarray(gross_slip, dtype=bool), 0.0, s)
    return s


def training_labels(series, lab: SeriesLabels, label: str = "pseudo") -> np.ndarray:
    """Return the per-period training target of a series for the label option `label`."""
    if label == "pseudo":
        return lab.pseudo_stick_ratio
    if label == "true-ratio":
        if not np.isfinite(series.load_ratio_stick).any():
            raise ValueError(f"series {series.index}: no load_ratio_stick stored; --label true-ratio "
                             "needs a simulated data set")
        return true_ratio_label(series.load_ratio_stick, series.gross_slip)
    raise ValueError(f"label {label!r} unknown; expected one of {', '.join(LABELS)}")
