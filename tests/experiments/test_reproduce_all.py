"""`slip reproduce all`, the measured times behind `--list` and every page's time block, and
quick budgets that keep the full runs' structure (full-length closed-loop runs, fewer of them)."""
import json
import shutil

from incipient_slip import control
from incipient_slip.cli import main
from incipient_slip.experiments import EXPERIMENTS, load
from incipient_slip.experiments.docs import replace_blocks
from incipient_slip.experiments.reproduce_all import ORDER, plan
from incipient_slip.experiments.settings import Settings
from incipient_slip.experiments.timing import load_times, time_block
from incipient_slip.paths import docs_dir


def test_the_plan_runs_every_experiment_once_and_models_before_what_loads_them():
    assert sorted(plan()) == sorted(EXPERIMENTS)
    assert ORDER.index("models") < min(ORDER.index("stabilization"), ORDER.index("diagnosis"))
    assert plan(["validation", "models"]) == ["models", "validation"]


def test_every_page_shows_the_committed_times_of_its_experiments():
    times = load_times()
    for name in EXPERIMENTS:
        module = load(name)
        page = (docs_dir() / module.DOC).read_text()
        assert replace_blocks(page, time_block(name, module, times)) == page, f"{module.DOC}: stale {name}-time"


def test_list_shows_full_and_quick_time_of_every_experiment(capsys):
    assert main(["reproduce", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(EXPERIMENTS) and all("2 cores: full " in line and ", quick " in line for line in lines)


def test_quick_budgets_run_the_full_length_loops():
    from incipient_slip.experiments import stabilization
    from incipient_slip.experiments.validation import planning, spec
    quick = Settings(budget="quick", progress=False)
    opts = stabilization.options(quick)
    assert opts["steps"] == control.MAX_STEPS and opts["runs"] < stabilization.options(Settings(budget="full"))["runs"]
    b = planning.budget(quick)
    assert b["steps"] == control.MAX_STEPS and set(b["points"]) <= set(spec.POINTS)
    assert all(hasattr(load(n), "QUICK") for n in EXPERIMENTS)


def test_all_quick_changes_no_docs_file_unless_asked_to_record_its_times(tmp_path, capsys):
    docs = tmp_path / "docs"
    (docs / "figures").mkdir(parents=True)
    shutil.copy(docs_dir() / "estimation.md", docs)
    before = {p: p.read_bytes() for p in docs.rglob("*") if p.is_file()}
    rc = main(["reproduce", "all", "--quick", "--only", "models", "--out", str(tmp_path / "all"), "--docs", str(docs)])
    assert rc == 0 and "docs/ unchanged" in capsys.readouterr().out
    assert {p: p.read_bytes() for p in docs.rglob("*") if p.is_file()} == before


def test_all_quick_runs_one_experiment_logs_it_and_records_its_time(tmp_path, capsys):
    docs = tmp_path / "docs"
    (docs / "figures").mkdir(parents=True)
    shutil.copy(docs_dir() / "estimation.md", docs)
    rc = main(["reproduce", "all", "--quick", "--only", "models", "--out", str(tmp_path / "all"),
               "--docs", str(docs), "--record-quick-times"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "[1/1] models" in out and "| models | ok |" in out and "PREVIEW" in out
    assert "held-out RMSE" in (tmp_path / "all" / "models.log").read_text()     # the experiment's own output
    entry = json.loads((docs / "figures" / "reproduce_times.json").read_text())["experiments"]["models"]["quick"]
    assert entry["seconds"] > 0 and len(entry["load_average"]) == 2
    page = (docs / "estimation.md").read_text()
    from incipient_slip.experiments.timing import duration     # '42 s', or '2.1 min' when slow (loaded)
    assert f"`slip reproduce models --quick` {duration(entry['seconds'])}" in page
    assert page.replace(page.split("<!-- BEGIN models-time -->")[1].split("<!-- END models-time -->")[0], "") == \
        (docs_dir() / "estimation.md").read_text().replace(
            (docs_dir() / "estimation.md").read_text().split("<!-- BEGIN models-time -->")[1]
            .split("<!-- END models-time -->")[0], "")          # only the time block changed


def test_an_identified_parameter_without_an_interval_adds_no_point():
    """An overlay entry whose interval is its value (or one end of it at the value) would repeat the
    identified rig's Table under another name: only distinct ends become points."""
    from incipient_slip.experiments.validation import overlays
    doc = {"provenance": {},
           "pre_slip": {"bulk_stiffening_exponent": {"value": 1.06, "unit": "-", "source": "x", "interval": [1.06, 1.06]},
                        "bulk_shear_n_per_mm": {"value": 0.5, "unit": "N/mm", "source": "x", "interval": [0.5, 0.6]}}}
    assert sorted(overlays.overlay_points(doc)) == ["identified", "pre_slip.bulk_shear_n_per_mm high 0.6"]
