"""The one Settings of every experiment: budgets, options, where results and figures go."""
from pathlib import Path

import pytest

from incipient_slip.experiments.settings import Settings


def test_pick_takes_the_value_of_the_budget():
    assert Settings(budget="quick").pick(quick=2, full=10) == 2
    assert Settings(budget="full").pick(quick=2, full=10) == 10


@pytest.mark.parametrize("kw", [{"budget": "medium"}, {"jobs": 0}])
def test_a_bad_budget_or_job_count_is_refused(kw):
    with pytest.raises(ValueError):
        Settings(**kw)


def test_an_option_not_given_falls_back_to_the_default():
    s = Settings(options={"runs": None, "steps": 15})
    assert s.option("runs", 10) == 10 and s.option("steps", 450) == 15 and s.option("absent") is None


def test_figures_and_results_go_to_docs_when_docs_are_written():
    s = Settings(work=Path("w"), docs=Path("d"))
    assert s.figures == Path("d/figures") and s.results_file("x.json") == Path("d/figures/x.json")
    assert s.results_file(None) == Path("w/results.json")
    quick = Settings(work=Path("w"))
    assert quick.figures == Path("w/figures") and quick.results_file("x.json") == Path("w/results.json")
