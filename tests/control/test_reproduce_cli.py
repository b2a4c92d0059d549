"""`slip reproduce stabilization` end to end on a tiny budget (real node graphs, fork start)."""
from __future__ import annotations

import json
import math

import pytest

from incipient_slip import control
from incipient_slip.cli import main
from incipient_slip.control_cli import aggregate, run_score, t_test_p


@pytest.mark.timeout(90)
def test_quick_reproduce_runs_graphs_and_writes_results_not_docs(tmp_path, capsys):
    rc = main(["reproduce", "stabilization", "--quick", "--runs", "2", "--methods", "none", "injection",
               "--steps", "15", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "SIMULATED rig" in out and "injection (ours)" in out and "no action" in out
    cache = json.loads((tmp_path / "stab_results.json").read_text())
    runs = cache["table"]["runs_detail"]
    assert len(runs) == 4 and all(r["steps"] >= 1 for r in runs)
    assert all(r["launch_rc"] == {"success": 0, "failure": 1, "fault": 3}[r["outcome"]] for r in runs)
    assert (tmp_path / "stab_traces.png").exists()


def test_score_of_a_run_uses_its_own_success():
    ok = {"success": True, "final_travel_mm": 1.0, "final_force_kpa": 5.0}
    assert run_score(ok) == pytest.approx(control.score(1.0, 1.0, 5.0))
    assert math.isnan(run_score({"success": False, "final_travel_mm": float("nan"), "final_force_kpa": 2.0}))


def test_aggregate_and_t_test():
    runs = [{"success": i % 2 == 0, "final_travel_mm": 1.0 + 0.1 * i, "final_force_kpa": 4.0,
             "steps": 450, "outcome": "success" if i % 2 == 0 else "failure"} for i in range(4)]
    row = aggregate(runs)
    assert row["success_rate"] == 0.5 and row["outcomes"] == {"success": 2, "failure": 2, "fault": 0}
    assert t_test_p([1, 2, 3], [1, 2, 3]) == pytest.approx(1.0)
    assert t_test_p([1, 1.1, 0.9], [5, 5.1, 4.9]) < 0.01
