"""The validation experiment's closed loop and report (the full sweep is an experiment, not a test)."""
import pytest

from incipient_slip.errors import UsageError

from incipient_slip import control
from incipient_slip.experiments import mechanics_fit, validation as val
from incipient_slip.experiments.validation import merging, report, spec, tasks
from incipient_slip.sim.scene import load_scene


def test_no_action_keeps_the_initial_grip_and_runs_every_step():
    p = load_scene("mechanics").params
    r = tasks.closed_loop("none", p, "pla", 3, None, 40)
    assert r["steps"] == 40 and r["success"] is None and r["fn"] == control.DEFAULT_INITIAL_FORCE_KPA


def test_oracle_loop_is_deterministic_and_ends_by_the_papers_rules():
    p = load_scene("mechanics").params
    a = tasks.closed_loop("oracle", p, "nylon", 5, None, 120)
    b = tasks.closed_loop("oracle", p, "nylon", 5, None, 120)
    assert a == b
    if a["success"]:
        assert a["steps"] == 120 and a["y"] <= control.FAILURE_TRAVEL_MM and a["fn"] < control.SAFETY_LIMIT_KPA
    elif a["steps"] < 120:            # the paper's protocol: only the F_N limit ends a run early
        assert a["end"] == "F_N" and a["fn"] >= control.SAFETY_LIMIT_KPA - 1e-9
    else:                             # judged on the end state
        assert a["end"] == "y" and a["y"] > control.FAILURE_TRAVEL_MM


def test_a_run_past_the_travel_limit_goes_on_unless_stop_on_travel():
    # a weak grip on nylon lets y pass 1.5 mm long before 450 steps: the paper's protocol runs on
    p = load_scene("mechanics").params
    full = tasks.closed_loop("none", p, "nylon", 1, None, 450)
    assert full["steps"] == 450 and full["y"] > control.FAILURE_TRAVEL_MM
    # s_d = 0 lowers the grip every period: the object slides past 1.5 mm and the force never nears 6 kPa
    early = tasks.closed_loop("oracle", p, "nylon", 1, None, 450, s_d=0.0, stop_on_travel=True)
    late = tasks.closed_loop("oracle", p, "nylon", 1, None, 450, s_d=0.0)
    assert early["end"] == "y" and early["steps"] < 450 and early["success"] is False
    assert late["steps"] == 450 and late["end"] == "y" and late["success"] is False


def test_summary_and_render_label_the_simulated_rig():
    runs = [{"success": True, "end": "steps", "y": 1.0, "fn": 4.0, "steps": 450, "material": "pla"},
            {"success": False, "end": "y", "y": 2.0, "fn": 3.0, "steps": 100, "material": "abs"}]
    s = merging.summarize(runs)
    assert s["success"] == 0.5 and s["y"] == pytest.approx(1.5) and s["steps"] == pytest.approx(275)
    table = {m: s for m in spec.TABLE_METHODS + ("oracle",)}
    res = {"budget": "quick", "runs": 2, "series": 10, "steps": 450, "figure": "validation_success.png",
           "points": {"fitted": {"table": table, "consistent": True, "sweep_table": {},
                                 "fit": {"values": {"pre_slip.bulk_shear_n_per_mm": 0.2,
                                                    "stick_slip.spring_n_per_mm": 0.024}}}}}
    blocks = val.render(res)
    assert set(blocks) == {"validation-fitted", "validation-set", "validation-answer"}
    assert "At the fitted point:** injection 0.5" in blocks["validation-answer"]
    assert all("Simulated rig" in b for b in blocks.values())
    assert "| success rate, paper | – | 0.3 | 0.0 | 0.1 | 1.0 | 0.8 | 1.0 |" in blocks["validation-fitted"]


def test_the_answer_has_a_row_per_label_and_counts_each_label_on_its_own_points():
    held = merging.summarize([{"success": True, "end": "steps", "y": 1.0, "fn": 4.0, "steps": 450, "material": "pla"}])
    lost = merging.summarize([{"success": False, "end": "F_N", "y": 0.5, "fn": 6.0, "steps": 300, "material": "pla"}])
    bias = [{"bin": "1.1-2 kPa", "mean": -0.01, "sd": 0.01, "n": 9}]
    point = {"table": {m: held if m == "oracle" else lost for m in spec.TABLE_METHODS + ("oracle",)},
             "consistent": True, "fit": {},
             "labels": {"pseudo": {"label_error_by_fn": [{"bin": "1.1-2 kPa", "mean": -0.12, "sd": 0.1, "n": 9}],
                                   "rmse": {"injection": 0.1}, "rmse_truth": {"injection": 0.4}},
                        "measured-ratio": {"label_error_by_fn": bias, "rmse": {"injection": 0.15},
                                           "rmse_truth": {"injection": 0.16},
                                           "table": {m: held for m in spec.LABEL_METHODS}}}}
    text = report.render_answer({"runs": 10, "steps": 450, "points": {"fitted": point, "lag 1 s": point}})
    assert "| lag 1 s | pseudo | 1.0 | 0.0 | 0.0 | 0.0 | 1.1-2 kPa -0.12 |" in text
    assert "| lag 1 s | measured-ratio | 1.0 | 1.0 | 1.0 | 1.0 | 1.1-2 kPa -0.01 |" in text
    assert "injection (pseudo) holds (success >= 0.8) at 0 of 2 points" in text
    assert "injection (measured-ratio) holds (success >= 0.8) at 2 of 2 points" in text
    assert "With the measured-ratio label: injection 1.0" in text
    assert "injection 0.150 / 0.160" in text
    assert "with the point's own friction lag: 0 where it has none, identified where it has one) holds at 2 of 2" in text


def test_a_point_with_a_friction_lag_also_runs_the_label_with_that_lag_identified():
    params = load_scene("paper").params
    assert list(tasks.label_rows(params)) == ["pseudo", "measured-ratio"]
    lagged = {**params, "stick_slip": {**params["stick_slip"], "friction_limit_lag_s": 0.5}}
    rows = tasks.label_rows(lagged)
    assert rows["measured-ratio, lag identified"].friction_lag_s == 0.5


@pytest.mark.parametrize("opts, needle", [({"runs": 0}, "--runs"), ({"scheduler": "localhost:8786"}, "--scheduler"),
                                          ({"sweep_at": ["beta 7, lag 0, mu spread 1"]}, "not a point of the joint set"),
                                          ({"sweep_at": ["beta 1, lag 1, mu spread 0.7"]}, "needs the joint results")])
def test_bad_options_are_named_errors(opts, needle, tmp_path):
    from incipient_slip.experiments.settings import Settings
    with pytest.raises(UsageError, match=needle):
        val.run(Settings(budget="quick", work=tmp_path, progress=False, options=opts))


@pytest.mark.slow
@pytest.mark.timeout(400)      # ~60 s on a quiet machine, ~180 s seen under load 8-10
def test_results_do_not_depend_on_the_worker_count(tmp_path):
    from incipient_slip.experiments.settings import Settings
    tables = []
    for workers in (1, 2):
        opts = {"points": ["fitted", "beta 0.75"], "runs": 1, "series": 10, "steps": 4, "workers": workers,
                "refits": ((5, 1, 2),)}
        res = val.run(Settings(budget="quick", work=tmp_path / f"w{workers}", progress=False, options=opts))
        tables.append({n: (p["fit"]["values"], p["runs"], p["rmse"]) for n, p in res["points"].items()})
    assert tables[0] == tables[1]


def test_joint_set_runs_the_table_only_where_the_open_loop_refit_allows(tmp_path, monkeypatch):
    """Two joint points on an in-process cluster (so the patched consistency rule reaches the
    workers): the consistent one gets its Table, the other is reported as excluded, and both are
    in the rendered block and the figure."""
    from dask.distributed import LocalCluster
    from incipient_slip.experiments.settings import Settings

    monkeypatch.setattr(spec, "JOINT", {"pre_slip.bulk_stiffening_exponent": (0.5,),
                                        "stick_slip.friction_limit_lag_s": (0.0, 0.5),
                                        "stick_slip.mu_spread_scale": (1.0,)})
    monkeypatch.setattr(mechanics_fit, "consistent_with_open_loop", lambda summ: summ["lag"] == 0.0)
    real_summary = mechanics_fit.mechanics_summary

    def tagged(scene, *a, **k):
        return {**real_summary(scene, *a, **k), "lag": scene.params["stick_slip"]["friction_limit_lag_s"]}
    monkeypatch.setattr(mechanics_fit, "mechanics_summary", tagged)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        opts = {"joint": True, "runs": 1, "series": 6, "steps": 3, "refits": ((4, 1, 1),),
                "scheduler": cluster.scheduler_address}
        res = val.run(Settings(budget="quick", work=tmp_path, progress=False, options=opts))
    pts = res["joint"]["points"]
    assert list(pts) == ["beta 0.5, lag 0, mu spread 1", "beta 0.5, lag 0.5, mu spread 1"]
    assert pts["beta 0.5, lag 0, mu spread 1"]["consistent"] and "table" in pts["beta 0.5, lag 0, mu spread 1"]
    assert not pts["beta 0.5, lag 0.5, mu spread 1"]["consistent"] and "table" not in pts["beta 0.5, lag 0.5, mu spread 1"]
    assert res["points"] == {} and (tmp_path / "figures" / res["joint_figure"]).read_bytes()[:4] == b"\x89PNG"
    block = val.render(res)["validation-joint"]
    assert "2 points, 1 consistent" in block and "Simulated rig" in block
    assert block.count("| beta 0.5, lag 0, mu spread 1 |") == 2 and block.count("| beta 0.5, lag 0.5, mu spread 1 |") == 1


@pytest.mark.parametrize("with_docs", [True, False])
def test_a_run_into_the_docs_without_joint_keeps_the_committed_joint_set(tmp_path, with_docs):
    """`slip reproduce validation` (and `all`) without --joint wrote a page without the joint set
    the committed page had (its hours of refits lost); into the docs it now keeps what it does not
    rerun, as --keep does. Without docs (a preview, --out) nothing is kept."""
    import json
    import shutil
    from dask.distributed import LocalCluster
    from incipient_slip.experiments.settings import Settings
    from incipient_slip.paths import docs_dir

    docs = tmp_path / "docs"
    (docs / "figures").mkdir(parents=True)
    shutil.copy(docs_dir() / "figures" / val.RESULTS, docs / "figures" / val.RESULTS)
    committed = json.loads((docs / "figures" / val.RESULTS).read_text())
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        opts = {"points": ["fitted"], "runs": 1, "series": 6, "steps": 3, "refits": ((4, 1, 1),),
                "scheduler": cluster.scheduler_address}
        res = val.run(Settings(budget="quick", work=tmp_path / "work", docs=docs if with_docs else None,
                               progress=False, options=opts))
    if with_docs:
        assert res["joint"] == committed["joint"] and res["joint_figure"] == committed["joint_figure"]
        assert set(res["points"]) == set(committed["points"])           # the others kept as committed
        assert res["points"]["beta 0.75"] == committed["points"]["beta 0.75"]
        assert res["points"]["fitted"]["runs"] != committed["points"]["fitted"]["runs"]   # rerun (3 steps)
    else:
        assert "joint" not in res and list(res["points"]) == ["fitted"]


def test_the_plan_names_what_runs_and_what_is_kept_and_starts_nothing(tmp_path, capsys):
    from incipient_slip.cli import main
    assert main(["reproduce", "validation", "--plan", "--quick", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "2 runs per method" in text and "fitted, beta 1.25, mu spread 1, lag 1 s" in text
    assert not (tmp_path / "results.json").exists()          # nothing ran
    assert main(["reproduce", "validation", "--plan", "--joint", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "joint set: 12 refits" in text and "none run and none kept" in text
