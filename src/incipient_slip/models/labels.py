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

The measured load ratio (`label="measured-ratio"`; derivation in docs/estimation.md, "A label a lab
can measure"): the paper's label is the constant-F_N case of Cattaneo-Mindlin's s = 1 - Q / (mu F_N);
under the paper's own per-period F_N redraw it keeps mu F_N, not mu, so

* F_hat_k: F_N of period k through a first-order lag `friction_lag_s` (an identified rig's
  `stick_slip.friction_limit_lag_s`; 0, the default, is F_N itself);
* mu_hat (per series): the largest F_T,k / F_hat_k the contact held, over the periods the paper's
  rule does not flag as sliding (a lower bound of mu that the series reaches again and again: at
  its creeps below the 0.02 mm rule and whenever it re-sticks after a slide);
* s_k = clip(1 - F_T,k / (mu_hat F_hat_k), 0, 1), and 0 in a period flagged as sliding, after the
  first onset too (a re-stuck contact has a well-defined ratio).
Only measured quantities: F_T from the spring (k_s (u - y)), F_N, the mocap's travel.

EXTENSION, not the paper's method: `training_labels(..., label="true-ratio")` replaces the pseudo
label by the simulator's true load ratio `load_ratio_stick` = 1 - Q / (mu_s F_N) of period k for
the window ending at period k (0 where the simulator flags gross slip, or has no value). Only a
simulated data set stores it; it tests whether the pseudo label is why the closed loop fails
(docs/stabilization.md). The window selection (and the gross-slip onset used by
after_slip="drop") stays the paper's mocap rule, so only the target changes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from incipient_slip.messages import PERIOD_NS

MIN_LOAD_KPA = 0.01           # below this F_N a contact carries no load worth a ratio (label 0)
GROSS_SLIP_MM = 0.02          # travel per 500 ms that counts as gross slip (paper)
GROSS_SLIP_SPAN_S = PERIOD_NS / 1e9   # second half of the paper's T = 1.0 s window (= one period)
EARLY_S = 0.025               # mocap averaged over the first 25 ms of the period ...
LATE_S = 0.05                 # ... and over its last 50 ms
# "pseudo": the paper's rule (default); "measured-ratio": measured quantities under a per-period F_N;
# "true-ratio": the simulator's truth (an extension no lab can measure)
LABELS = ("pseudo", "measured-ratio", "true-ratio")
SHIPPED_LABELS = ("pseudo", "measured-ratio")   # models/<method>.npz and models/measured-ratio/<method>.npz
DEFAULT_LABEL = "measured-ratio"                # the estimator's shipped model when nothing says otherwise


@dataclass(frozen=True)
class LabelRule:
    """A training label and its one parameter: the friction limit's lag behind F_N (measured-ratio only)."""

    name: str = "pseudo"
    friction_lag_s: float = 0.0

    def __post_init__(self):
        if self.name not in LABELS:
            raise ValueError(f"label {self.name!r} unknown; expected one of {', '.join(LABELS)}")
        if not (math.isfinite(self.friction_lag_s) and self.friction_lag_s >= 0.0):
            raise ValueError(f"friction lag must be a finite number >= 0 s, got {self.friction_lag_s!r}")
        if self.friction_lag_s and self.name != "measured-ratio":
            raise ValueError(f"a friction lag is an input of the measured-ratio label only, not of {self.name!r}")

    def __str__(self) -> str:
        return self.name if not self.friction_lag_s else f"{self.name} (friction lag {self.friction_lag_s:g} s)"


def rule_of_header(header: dict) -> LabelRule:
    """Return the label a model file was trained on (its header's label and friction lag)."""
    return LabelRule(header.get("label") or "pseudo", float(header.get("friction_lag_s") or 0.0))


def label_rule(label) -> LabelRule:
    """Return the LabelRule of a label name or rule (a name alone has no friction lag)."""
    return label if isinstance(label, LabelRule) else LabelRule(str(label))


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


def lagged_force(normal_force_kpa: np.ndarray, lag_s: float, period_s: float = GROSS_SLIP_SPAN_S) -> np.ndarray:
    """Return F_N per period through a first-order lag of `lag_s` (0: F_N itself), from its first value."""
    fn = np.asarray(normal_force_kpa, dtype=np.float64)
    if lag_s <= 0.0 or len(fn) == 0:
        return fn.copy()
    from scipy.signal import lfilter
    keep = math.exp(-period_s / lag_s)
    out, _ = lfilter([1.0 - keep], [1.0, -keep], fn[1:], zi=[keep * fn[0]])
    return np.concatenate([fn[:1], out])


def held_friction_coefficient(tangential_force_n: np.ndarray, friction_force_kpa: np.ndarray,
                              sliding: np.ndarray) -> float:
    """Return mu_hat (N per kPa): the largest F_T / F the contact held in a period not flagged as
    sliding; nan when no such period carried load."""
    ft = np.abs(np.asarray(tangential_force_n, dtype=np.float64))
    fn = np.asarray(friction_force_kpa, dtype=np.float64)
    held = ~np.asarray(sliding, dtype=bool) & (fn >= MIN_LOAD_KPA) & np.isfinite(ft) & np.isfinite(fn)
    if not held.any():
        return math.nan
    mu = float(np.max(ft[held] / fn[held]))
    return mu if 0 < mu < math.inf else math.nan


def measured_ratio_label(tangential_force_n: np.ndarray, normal_force_kpa: np.ndarray, travel_mm: np.ndarray,
                         friction_lag_s: float = 0.0) -> np.ndarray:
    """Return s_k = clip(1 - F_T,k / (mu_hat F_hat_k), 0, 1), 0 in sliding periods (module docstring)."""
    sliding = np.asarray(travel_mm, dtype=np.float64) >= GROSS_SLIP_MM
    f_hat = lagged_force(normal_force_kpa, friction_lag_s)
    mu = held_friction_coefficient(tangential_force_n, f_hat, sliding)
    if not math.isfinite(mu):
        return np.where(sliding, 0.0, np.nan)
    limit = mu * f_hat
    with np.errstate(over="ignore"):            # a tiny limit: the ratio is huge, the label 0
        ratio = np.divide(np.abs(np.asarray(tangential_force_n, dtype=np.float64)), limit,
                          out=np.full(len(limit), np.inf), where=f_hat >= MIN_LOAD_KPA)
    return np.where(sliding, 0.0, np.clip(1.0 - ratio, 0.0, 1.0))


def training_labels(series, lab: SeriesLabels, label="pseudo") -> np.ndarray:
    """Return the per-period training target of a series for the label (a name or a LabelRule)."""
    rule = label_rule(label)
    label = rule.name
    if label == "pseudo":
        return lab.pseudo_stick_ratio
    if label == "measured-ratio":
        return measured_ratio_label(series.tangential_force_n, series.normal_force_kpa, lab.travel_mm,
                                    rule.friction_lag_s)
    if label == "true-ratio":
        if not np.isfinite(series.load_ratio_stick).any():
            raise ValueError(f"series {series.index}: no load_ratio_stick stored; --label true-ratio "
                             "needs a simulated data set")
        return true_ratio_label(series.load_ratio_stick, series.gross_slip)
    raise ValueError(f"label {label!r} unknown; expected one of {', '.join(LABELS)}")
