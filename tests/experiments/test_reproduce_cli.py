"""`slip reproduce`: listing, bad input as one line with exit 2, rendering from saved results."""
import shutil

import pytest

from incipient_slip.cli import main
from incipient_slip.experiments import EXPERIMENTS
from incipient_slip.paths import repo_root


def test_list_names_every_experiment_and_its_page(capsys):
    assert main(["reproduce", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == list(EXPERIMENTS)
    assert all("(docs/" in line for line in lines)


@pytest.mark.parametrize("argv, needle", [
    (["reproduce", "estimation", "--quick", "--seed", "-1"], "--seed must be >= 0"),
    (["reproduce", "stabilization", "--quick", "--jobs", "0"], "--jobs must be >= 1"),
    (["reproduce", "estimation", "--quick", "--series", "5"], "--series must be >= 10"),
    (["reproduce", "stabilization", "--quick", "--tune-k", "1,x"], "--tune-k takes gains"),
    (["reproduce", "stabilization", "--quick", "--tune-k", "1,-2"], "finite and > 0"),
    (["reproduce", "stabilization", "--quick", "--s-d", "2"], "--s-d must be in [0, 1]"),
    (["reproduce", "stabilization", "--quick", "--model", "m.npz", "--methods", "none"], "exactly one --methods"),
    (["reproduce", "calibration", "--quick", "--scene", "mechanics"], "no 'injection' effect"),
    (["reproduce", "diagnosis", "--quick", "--seeds", "0,a"], "--seeds takes integers"),
])
def test_bad_input_is_one_line_on_stderr_and_exit_2(argv, needle, tmp_path, capsys):
    assert main(argv + ["--out", str(tmp_path)]) == 2
    out, err = capsys.readouterr()
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "PREVIEW" not in out          # checked before the banner: nothing was started


def test_reproduce_without_a_name_asks_for_one(capsys):
    assert main(["reproduce"]) == 2
    assert capsys.readouterr().err == "slip reproduce: error: name an experiment (slip reproduce --list shows them)\n"


def test_quick_and_full_together_are_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "models", "--quick", "--full"])
    assert exc.value.code == 2 and "not allowed with" in capsys.readouterr().err


def test_render_only_without_saved_results_names_the_file(tmp_path, capsys):
    assert main(["reproduce", "estimation", "--quick", "--render-only", "--out", str(tmp_path)]) == 2
    assert str(tmp_path / "results.json") in capsys.readouterr().err


def _docs_copy(tmp_path):
    docs = tmp_path / "docs"
    (docs / "figures").mkdir(parents=True)
    shutil.copy(repo_root() / "docs" / "stabilization.md", docs)
    for results in ("stab_results.json", "reproduce_times.json"):
        shutil.copy(repo_root() / "docs" / "figures" / results, docs / "figures")
    return docs


def test_render_only_rewrites_the_blocks_from_the_committed_results(tmp_path):
    docs = _docs_copy(tmp_path)
    page = docs / "stabilization.md"
    page.write_text(page.read_text().replace("| success rate ↑ (sim) |", "| stale |"))
    assert main(["reproduce", "stabilization", "--render-only", "--docs", str(docs), "--out", str(tmp_path)]) == 0
    assert page.read_text() == (repo_root() / "docs" / "stabilization.md").read_text()


def test_a_page_without_the_markers_is_one_line_exit_2(tmp_path, capsys):
    docs = _docs_copy(tmp_path)
    (docs / "stabilization.md").write_text("# hand-written, no markers\n")
    assert main(["reproduce", "stabilization", "--render-only", "--docs", str(docs), "--out", str(tmp_path)]) == 2
    assert "<!-- BEGIN stabilization-table -->" in capsys.readouterr().err
