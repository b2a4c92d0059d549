"""Small results of each experiment, in the shape its run() returns, for render() tests."""
from __future__ import annotations

import json
from pathlib import Path

from incipient_slip.models.features import METHODS
from incipient_slip.paths import docs_dir


def _study(p_holm: float) -> dict:
    table = [{"method": m, "n_series": 5, "rmse_mean": 0.1 + 0.01 * i, "rmse_std": 0.01,
              "top10_mean": 0.2 + 0.01 * i, "top10_std": 0.02, "kind": "svr",
              "params": {"kernel": "rbf", "C": 1.0, "gamma": 0.01}, "n_train_windows": 100,
              "n_support": 50, "train_s": 1.0, "p_rmse": None if m == "injection" else p_holm,
              "p_top10": None if m == "injection" else p_holm,
              "by_material": {"pla": {"rmse": 0.1, "top10": 0.2, "n_series": 3},
                              "abs": {"rmse": 0.2, "top10": 0.3, "n_series": 2}}}
             for i, m in enumerate(METHODS)]
    tests = {m: {"t": 3.0, "p": p_holm, "p_holm": p_holm, "stars": "**" if p_holm < 0.01 else "",
                 "n": 5, "mean_diff": 0.02 * (i - 2) + 0.01} for i, m in enumerate(METHODS) if m != "injection"}
    return {"table": table, "tests_rmse": tests, "tests_top10": tests, "test_series": [1, 2, 3, 4, 5],
            "data_dirs": {"paper": "d"}, "timings": {}}


def estimation() -> dict:
    return {"budget": "quick", "series": 10, "steps": 200, "seed": 0, "max_train": 1000,
            "paper_rule": _study(0.001), "incipient": _study(0.2), "band_r_pooled": -0.5,
            "band_r_within": float("nan"), "elapsed_s": 90.0, "cores": "2 cores",
            "label_quality": {"pre_rmse_vs_stick_area": 0.4, "pre_rmse_vs_load_ratio": 0.3,
                              "post_rmse_vs_stick_area": 0.7, "post_fraction": 0.5,
                              "onset_exact_fraction": 1.0, "onset_offset_max": 0.0}}


def accuracy_vs_time() -> dict:
    def point(sweep, label, window_s, rmse):
        return {"sweep": sweep, "label": label, "window_s": window_s, "rmse": rmse, "top10": 2 * rmse,
                "train_s": 1.0, "latency_ms": 0.2, "n_train": 500, "delay_s": window_s + 0.0002}
    pts = [point("window", "T = 0.5 s", 0.5, 0.2), point("window", "T = 1 s", 1.0, 0.17),
           point("model", "ridge (linear)", 1.0, 0.3)]
    exact = [{"n": n, "fit_s": n / 1000, "rmse": 0.18, "top10": 0.3, "latency_ms": 0.1} for n in (500, 1000)]
    ny = [{"n_components": 300, "n": 4000, "fit_s": 2.0, "rmse": 0.175, "top10": 0.3, "latency_ms": 0.1}]
    return {"budget": "quick", "series": 10, "elapsed_s": 60.0,
            "sweeps": {"points": pts, "params": {"kernel": "rbf"}, "n_train_windows": 4000,
                       "n_test_series": 5, "elapsed_s": 50.0},
            "scale": {"params": {"kernel": "rbf"}, "n_train_windows": 4000, "exact": exact,
                      "exponent": 2.0, "predicted_exact_full_s": 64.0, "nystroem": ny,
                      "best_exact": exact[1], "n_test_series": 5}}


def models() -> dict:
    return {"series": 10, "steps": 200, "max_train": 500, "grid_max": 300, "seed": 7,
            "after_slip": "drop", "elapsed_s": 30.0,
            "models": {m: {"file": f"models/{m}.npz", "bytes": 2048, "support_vectors": 12,
                           "hyper_parameters": {"C": 0.3, "kernel": "rbf"}, "rmse": 0.15, "top10": 0.3}
                       for m in METHODS}}


def calibration() -> dict:
    """The committed results behind docs/calibration.md."""
    return json.loads((docs_dir() / "figures" / "calibration_results.json").read_text())


def validation() -> dict:
    """The committed results behind docs/validation.md."""
    return json.loads((docs_dir() / "figures" / "validation_results.json").read_text())


def stabilization() -> dict:
    """The committed results behind docs/stabilization.md."""
    return json.loads((docs_dir() / "figures" / "stab_results.json").read_text())


def diagnosis() -> dict:
    phase = {"ft_n": 0.19, "true": 0.6, "pseudo": 0.26, "est_injection": 0.28, "est_e19": 0.58}
    loop = {"end": "y > 1.5 mm", "steps": 195, "fn": 1.1, "y": 1.51, "est_last": 0.43, "pseudo_last": 0.02,
            "true_last": 0.01, "rmse_pseudo": 0.1, "rmse_true": 0.1, "n_diverged": 0,
            "rmse_pseudo_div": float("nan"), "rmse_true_div": float("nan"), "low_force_bias_vs_true": 0.25}
    oracle = {"end": "450 steps", "steps": 450, "fn": 4.05, "y": 0.91, "true_late": 0.3, "pseudo_late": 0.06,
              "est_injection_late": 0.09, "est_e19_late": 0.39, "rmse_injection_pseudo": 0.1,
              "rmse_injection_true": 0.23, "rmse_e19_pseudo": 0.35, "rmse_e19_true": 0.1}
    return {"material": "pla", "seeds": [0], "steps": 450,
            "slip": {"n_series": 20, "ft_slip_median_n": 0.258, "ft_slip_q25_n": 0.246, "ft_slip_q75_n": 0.269,
                     "fn_at_slip_median_kpa": 1.1, "k_slip_median": 200.0},
            "models": {m: {"sha256": "09c1d420" + "0" * 56, "training_data_hash": "c82730fd"}
                       for m in ("injection", "e19")},
            "loops": {"injection/0": loop, "e19/0": loop}, "oracle": {"0": oracle},
            "step": {"0/0.6": {"2 kPa": phase, "5 kPa": phase}}}


def identification() -> dict:
    rows = [{"set": i, "periods": 2400, "seconds": 0.4, "k_b": (0.5, 0.501), "beta": (1.0, 1.002),
             "mu": (0.55, 0.552), "lag": (0.3, 0.35)} for i in range(2)]
    return {"budget": "quick", "sets": 2, "first_seed": 0, "rows": rows,
            "largest": {"k_b": 0.002, "beta": 0.002, "mu": 0.004, "lag": 0.05}}


SAMPLES = {"calibration": calibration, "validation": validation, "estimation": estimation, "accuracy-vs-time": accuracy_vs_time,
           "models": models, "stabilization": stabilization, "diagnosis": diagnosis, "identification": identification}


def docs_page(name: str) -> Path:
    from incipient_slip.experiments import load
    return docs_dir() / load(name).DOC
