"""The experiments whose quick budget takes seconds, run end to end on the simulated rig.

Estimation and model regeneration share the data-set and training path; the diagnosis runs the
closed loop in-process. Calibration (~15 s) and accuracy-vs-time (~1 min) are covered by their
render tests only, to keep `make test` short.
"""
import json

import numpy as np

from incipient_slip import control
from incipient_slip.cli import main
from incipient_slip.models.features import METHODS
from incipient_slip.models.modelfile import read_model_file


def _reproduce(name, tmp_path, *extra):
    assert main(["reproduce", name, "--quick", "--quiet", "--out", str(tmp_path), *extra]) == 0
    return json.loads((tmp_path / "results.json").read_text())


def test_estimation_trains_and_scores_the_six_methods_on_shared_held_out_series(tmp_path):
    results = _reproduce("estimation", tmp_path)
    meta = json.loads(next((tmp_path / "data").glob("paper_*/meta.json")).read_text())
    assert meta["scene"] == "paper" and meta["created_by"].startswith("incipient_slip.sim")
    for study in (results["paper_rule"], results["incipient"]):
        assert [r["method"] for r in study["table"]] == list(METHODS)
        assert all(np.isfinite(r["rmse_mean"]) and np.isfinite(r["top10_mean"]) for r in study["table"])
    page = (tmp_path / "estimation.md").read_text()
    assert "<!-- BEGIN estimation-paper-rule -->" in page and "| injection (ours) |" in page
    assert len(list((tmp_path / "figures").glob("est_*.png"))) >= 5


def test_models_regeneration_is_deterministic_and_leaves_models_dir_alone(tmp_path):
    runs = []
    for k in range(2):
        results = _reproduce("models", tmp_path / f"run{k}", "--methods", "e4", "e1", "--series", "10",
                             "--data", str(tmp_path / "data"))
        assert results["seed"] == 7 and set(results["models"]) == {"e4", "e1"}
        runs.append({m: read_model_file(tmp_path / f"run{k}" / "models" / f"{m}.npz") for m in ("e4", "e1")})
    for m in ("e4", "e1"):
        a, b = runs[0][m], runs[1][m]
        np.testing.assert_array_equal(a.centers, b.centers)
        np.testing.assert_array_equal(a.weights, b.weights)
        assert a.header == b.header
        assert a.header["regen"]["command"] == "slip reproduce models" and a.header["after_slip"] == "drop"


def test_diagnosis_compares_estimate_label_and_truth_per_period(tmp_path):
    results = _reproduce("diagnosis", tmp_path)
    assert set(results["loops"]) == {"injection/0", "e19/0"} and set(results["oracle"]) == {"0"}
    records = json.loads((tmp_path / "diagnosis_records.json").read_text())
    rows = records["oracle"]["0"]
    assert results["steps"] == control.MAX_STEPS      # the quick preview runs the paper's full loops
    assert len(rows) == results["steps"] and all(0.0 <= r["pseudo"] <= 1.0 for r in rows)
    assert (tmp_path / "figures" / "stab_diagnosis.png").is_file()
    assert "<!-- BEGIN diagnosis-loops -->" in (tmp_path / "stabilization.md").read_text()
