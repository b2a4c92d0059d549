"""Data sets reused only from the same physics; what the render functions compute."""
import json
import sys
from pathlib import Path

import pytest

from incipient_slip.experiments import accuracy_vs_time, diagnosis, estimation
from incipient_slip.experiments.datasets import ensure_dataset

sys.path.insert(0, str(Path(__file__).parent))
from samples import SAMPLES  # noqa: E402


def test_cached_data_set_from_other_physics_is_regenerated(tmp_path):
    """A data set cached before the simulator changed must not be reused."""
    out = tmp_path / "mech"
    ensure_dataset("mechanics", 2, 0, out, workers=1, steps=4, progress=False)
    meta = json.loads((out / "meta.json").read_text())
    first = (out / "series_00000.npz").stat().st_mtime_ns
    assert ensure_dataset("mechanics", 2, 0, out, workers=1, steps=4, progress=False) == out
    assert (out / "series_00000.npz").stat().st_mtime_ns == first   # reused while physics is the same
    meta["physics_fingerprint"] = "older-physics"
    (out / "meta.json").write_text(json.dumps(meta))
    ensure_dataset("mechanics", 2, 0, out, workers=1, steps=4, progress=False)
    assert json.loads((out / "meta.json").read_text())["physics_fingerprint"] != "older-physics"


def test_pareto_front_keeps_only_undominated_points_sorted_by_delay():
    pts = [{"delay_s": 1.0, "rmse": 0.2}, {"delay_s": 0.5, "rmse": 0.3}, {"delay_s": 2.0, "rmse": 0.25},
           {"delay_s": 2.0, "rmse": 0.1}, {"delay_s": 0.5, "rmse": 0.35}]
    front = accuracy_vs_time.pareto_front(pts)
    assert [(p["delay_s"], p["rmse"]) for p in front] == [(0.5, 0.3), (1.0, 0.2), (2.0, 0.1)]


def test_accuracy_vs_time_says_whether_the_scale_goal_was_met():
    blocks = accuracy_vs_time.render(SAMPLES["accuracy-vs-time"]())
    assert "(-2.8 % vs the best exact SVR; goal: within +5 %, met)" in blocks["tradeoff-scale"]
    assert "Pareto front (delay, RMSE): T = 0.5 s (0.50 s, 0.200); T = 1 s (1.00 s, 0.170)" in blocks["tradeoff-sweeps"]


def test_estimation_verdict_names_where_injection_is_better_worse_or_the_same():
    blocks = estimation.render(SAMPLES["estimation"]())
    assert ("Injection's RMSE is lower than vibrotactile; higher than E19, E10, E4, E1 (Holm-corrected"
            in blocks["estimation-paper-rule"])
    assert "not significantly different from vibrotactile, E19, E10, E4, E1" in blocks["estimation-incipient"]
    assert "mean R within one F_N level = –" in blocks["estimation-band"]      # NaN shown as a dash


def test_diagnosis_tables_show_the_loop_and_step_numbers():
    blocks = diagnosis.render(SAMPLES["diagnosis"]())
    assert "| injection loop, seed 0 | y > 1.5 mm | 195 | 1.10 | 1.51 | – | 0.43 / 0.02 / 0.01 | – / – (0) |" \
        in blocks["diagnosis-loops"]      # a record without the contact state's split shows a dash
    assert "| 0, 0.190 N | 0.60 → 0.60 | 0.26 | 0.28 → 0.28 | 0.58 → 0.58 |" in blocks["diagnosis-step"]


def test_diagnosis_splits_y_into_slide_pad_shear_and_interfacial_and_the_parts_add_up():
    from incipient_slip.models.estimator_core import load_model
    models = {m: load_model(method=m) for m in diagnosis.METHODS}
    rows = diagnosis.closed_loop("injection", "pla", 0, models, 0.26, steps=12, oracle=True)
    for r in rows:
        assert r["slide_mm"] + r["bulk_mm"] + r["interfacial_mm"] == pytest.approx(r["y_mm"], abs=1e-9)
        assert r["bulk_mm"] >= -1e-12 and r["interfacial_mm"] >= -1e-12     # rounding at Q ~ 0
    assert diagnosis._split_cell(diagnosis._split(rows[-1])).count(" + ") == 2


def test_accuracy_vs_time_latency_runs_on_one_blas_thread_like_the_estimator_node():
    """More threads than free cores make OpenMP spin on a shared machine (trees 40x slower)."""
    import numpy as np
    from threadpoolctl import threadpool_info, threadpool_limits
    seen = []
    with threadpool_limits(limits=2):
        accuracy_vs_time.latency_ms(lambda w: seen.append(max(i["num_threads"] for i in threadpool_info())),
                                    np.zeros(4), reps=3)
    assert set(seen) == {1}


def test_accuracy_vs_time_page_states_command_sizes_threads_and_load():
    results = SAMPLES["accuracy-vs-time"]()
    results.update(budget="full", series=200, default_series=500, jobs=1, load_average=[7.94, 9.1])
    results["sweeps"]["sizes"] = {"max_train": 4000, "grid_max": 1500, "hgb_max": 20000}
    text = accuracy_vs_time.render(results)["tradeoff-provenance"]
    assert "`slip reproduce accuracy-vs-time --series 200 --jobs 1`" in text
    assert "200 series of the paper scene" in text and "full budget" in text
    assert "at most 4000 windows (SVR grid search on 1500), gradient-boosted trees on at most 20000" in text
    assert "load average (1 min) 7.9-9.1" in text and "simulated rig, not measurements" in text


def test_accuracy_vs_time_recommendation_follows_the_numbers():
    results = SAMPLES["accuracy-vs-time"]()
    results["sweeps"]["points"][2]["latency_ms"] = 3.5
    text = accuracy_vs_time.render(results)["tradeoff-recommendation"]
    assert "is 0.20-3.50 ms over every setting" in text and "window length (0.5-1 s)" in text
    assert "Nystroem 300 + ridge (RMSE 0.175, fit 2 s) is within 5 % of the best exact SVR" in text
    results["scale"]["nystroem"][0]["rmse"] = 0.2
    text = accuracy_vs_time.render(results)["tradeoff-recommendation"]
    assert "more than 5 % worse than the best exact SVR (RMSE 0.180 on 1000 windows): keep the exact SVR" in text
