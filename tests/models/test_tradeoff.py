import json

import pytest

from incipient_slip.models.tradeoff import pareto_front


def test_pareto_front_keeps_only_undominated_points_sorted_by_delay():
    pts = [{"delay_s": 1.0, "rmse": 0.2}, {"delay_s": 0.5, "rmse": 0.3}, {"delay_s": 2.0, "rmse": 0.25},
           {"delay_s": 2.0, "rmse": 0.1}, {"delay_s": 0.5, "rmse": 0.35}]
    assert [(p["delay_s"], p["rmse"]) for p in pareto_front(pts)] == [(0.5, 0.3), (1.0, 0.2), (2.0, 0.1)]


@pytest.mark.slow
def test_accuracy_vs_time_quick_writes_table_figure_and_scale_study(tmp_path):
    from test_cli import run
    assert run(["reproduce", "accuracy-vs-time", "--quick", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "tradeoff.json").read_text())
    assert {p["sweep"] for p in result["sweeps"]["points"]} == {"window", "bins", "band", "model", "size"}
    assert result["scale"]["nystroem"] and result["scale"]["exact"]
    md = (tmp_path / "accuracy-vs-time.md").read_text()
    assert "simulated rig" in md and "Recommendation" in md
    assert (tmp_path / "figures" / "est_pareto.png").is_file()
