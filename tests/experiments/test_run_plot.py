"""`slip run plot`: the figure of one run summary; bad summaries are one line on stderr, exit 2."""
import json

import pytest
from hypothesis import HealthCheck, example, given, settings, strategies as st

from incipient_slip.cli import main
from incipient_slip.control import RunJudge, SupervisorRules, Verdict
from incipient_slip.errors import UsageError
from incipient_slip.experiments import run_plot
from incipient_slip.messages import PERIOD_NS

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
RECORDED = dict(method="injection", s_d=0.3, k=2.0, seed=4, material="pla", rig="sim", pzt_on=True, wall_s=1.0)


def judged_summary(periods: int = 12, verdict: Verdict | None = None, truth: bool = True) -> dict:
    """The summary a supervisor writes after `periods` periods of a simulated run."""
    judge = RunJudge(SupervisorRules(max_steps=450))
    for k in range(periods):
        judge.robot(max(k * PERIOD_NS, 1), 2.9 - 0.1 * k, now_s=0.0)
        judge.pose((k + 1) * PERIOD_NS - 1, 0.05 * k, now_s=0.0)
        judge.estimate(k, 0.8 - 0.04 * k, k > 0)
        if truth:
            judge.truth_of(k, 0.95 - 0.02 * k, 0.01 * k)
        judge.command(k, k == 0, 2.8 - 0.1 * k, now_s=0.0)
        judge.close(0.0)
    if verdict is not None:
        judge.end(verdict)
    return judge.summary(**RECORDED)


def write(path, summary):
    path.write_text(json.dumps(summary, indent=1, allow_nan=True))
    return path


def test_the_figure_of_a_summary_is_a_png_with_the_run_in_its_title(tmp_path, monkeypatch, capsys):
    source = write(tmp_path / "run.json", judged_summary())
    titles = []
    real_save = run_plot.save
    monkeypatch.setattr(run_plot, "save", lambda fig, path: (titles.append(fig._suptitle.get_text()),
                                                             real_save(fig, path))[1])
    assert main(["run", "plot", str(source), "-o", str(tmp_path / "fig" / "run.png")]) == 0
    png = (tmp_path / "fig" / "run.png").read_bytes()
    assert png.startswith(PNG_SIGNATURE) and len(png) > 10_000
    title = titles[0]
    for needle in ("simulated rig, not a measurement", "injection (ours)", "s_d 0.3", "seed 4",
                   "12 / 450 steps"):
        assert needle in title, title
    assert "wrote" in capsys.readouterr().out
    # default output: beside the summary
    assert main(["run", "plot", str(source)]) == 0 and (tmp_path / "run.png").read_bytes().startswith(PNG_SIGNATURE)



def test_an_output_without_a_suffix_says_the_file_it_wrote(tmp_path, capsys):
    """matplotlib adds .png to such a name; the tool said 'wrote fig' of a file named fig.png."""
    source = write(tmp_path / "run.json", judged_summary())
    assert main(["run", "plot", str(source), "-o", str(tmp_path / "fig")]) == 0
    assert f"wrote {tmp_path / 'fig.png'} " in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png", "run.json"]     # and nothing else

def test_the_figure_has_three_panels_with_the_limits_and_the_truth_dashed(tmp_path, monkeypatch):
    figs = []
    monkeypatch.setattr(run_plot, "save", lambda fig, path: figs.append(fig))
    run_plot.plot_run(run_plot.load_summary(write(tmp_path / "run.json", judged_summary())), tmp_path / "x.png")
    ax_s, ax_f, ax_y = figs[0].axes
    labels = {ax: [line.get_label() for line in ax.get_lines()] for ax in (ax_s, ax_f, ax_y)}
    assert any("simulator's truth" in label for label in labels[ax_s])
    assert [line.get_linestyle() for line in ax_s.get_lines() if "truth" in line.get_label()] == ["--"]
    assert any(label.startswith("target s_d = 0.3") for label in labels[ax_s])
    assert any("safety limit 6 kPa" in label for label in labels[ax_f])
    assert any("failure limit 1.5 mm" in label for label in labels[ax_y])


def test_an_interrupted_run_and_one_without_truth_or_periods_still_plot(tmp_path):
    for i, summary in enumerate((judged_summary(7, Verdict("interrupted", "interrupted after 7 steps")),
                                 judged_summary(5, truth=False), judged_summary(0, Verdict("interrupted", "x")))):
        out = run_plot.plot_run(run_plot.load_summary(write(tmp_path / f"{i}.json", summary)), tmp_path / f"{i}.png")
        assert out.read_bytes().startswith(PNG_SIGNATURE)


@pytest.mark.parametrize("text, needle", [
    (None, "no such file"),
    ("", "invalid JSON"),
    ("[1, 2]", "not a run summary"),
    ('{"outcome": "success"}', "not a run summary"),
    ('{"outcome": "success", "traces": {"travel_mm": [1, "a"]}}', "not a list of numbers"),
    ('{"outcome": "success", "traces": {"travel_mm": [1], "force_kpa": [1, 2]}}', "different lengths"),
])
def test_a_missing_or_broken_summary_is_one_line_and_exit_2(text, needle, tmp_path, capsys):
    path = tmp_path / "run.json"
    if text is not None:
        path.write_text(text)
    assert main(["run", "plot", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("slip run plot: error: ") and needle in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run.png").exists()


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.floats(0.0, 0.999))
def test_a_truncated_summary_is_refused(tmp_path, cut):
    text = json.dumps(judged_summary(6), indent=1, allow_nan=True)
    path = tmp_path / "cut.json"
    path.write_text(text[:int(cut * len(text))])
    with pytest.raises(UsageError, match="cut.json"):
        run_plot.load_summary(path)


JSON = st.recursive(st.none() | st.booleans() | st.floats(allow_nan=True) | st.integers() | st.text(max_size=4),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
                    max_leaves=12)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(traces=st.dictionaries(st.sampled_from(run_plot.NUMERIC_TRACES + ("hold", "other")), JSON, max_size=5),
       outcome=st.one_of(st.just("failure"), JSON))
def test_any_json_loads_as_equal_length_traces_or_is_a_usage_error(tmp_path, traces, outcome):
    path = tmp_path / "any.json"
    path.write_text(json.dumps({"outcome": outcome, "traces": traces}, allow_nan=True))
    try:
        summary = run_plot.load_summary(path)
    except UsageError:
        return
    lengths = {len(v) for v in summary["traces"].values()}
    assert len(lengths) == 1
    assert all(isinstance(v, float) for key in run_plot.NUMERIC_TRACES for v in summary["traces"][key])
    assert all(isinstance(v, bool) for v in summary["traces"]["hold"])


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@example(values=[1.7976931348623157e308])         # found by hypothesis: limits overflowed to inf
@example(values=[1.7976931348623157e308, -9.9792015476736e291])   # and a singular transform
@given(values=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=6))
def test_any_numbers_in_the_traces_plot(tmp_path, values):
    """Hand-edited summaries: NaN, infinities, huge numbers still give a figure, never a crash."""
    summary = judged_summary(len(values))
    for key in ("travel_mm", "force_kpa", "stick_ratio_estimate", "stick_ratio_true", "command_kpa"):
        summary["traces"][key] = values
    out = run_plot.plot_run(run_plot.load_summary(write(tmp_path / "v.json", summary)), tmp_path / "v.png")
    assert out.read_bytes().startswith(PNG_SIGNATURE)
