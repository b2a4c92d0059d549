import json

import pytest

from fakedata import write_fake_dataset
from incipient_slip.cli import main


def run(argv):
    return main(argv, modules=("incipient_slip.models.cli",))


def test_train_writes_a_model_file_and_reports_held_out_rmse(fake_injection_dir, tmp_path, capsys):
    out = tmp_path / "e19.npz"
    assert run(["train", "--method", "e19", "--data", str(fake_injection_dir), "--quick",
                "--out", str(out)]) == 0
    assert out.is_file()
    assert "held-out" in capsys.readouterr().out


def test_evaluate_prints_rmse_top10_and_holm_p_values(fake_injection_dir, tmp_path, capsys):
    for m in ("injection", "e1"):
        run(["train", "--method", m, "--data", str(fake_injection_dir), "--quick", "--out", str(tmp_path / f"{m}.npz")])
    capsys.readouterr()
    assert run(["evaluate", "--data", str(fake_injection_dir), "--model", str(tmp_path / "injection.npz"),
                "--model", str(tmp_path / "e1.npz"), "--json", str(tmp_path / "s.json")]) == 0
    text = capsys.readouterr().out
    assert "top-10 %" in text and "e1" in text
    scores = json.loads((tmp_path / "s.json").read_text())
    assert scores["e1"]["p_rmse_holm"] is not None


def test_train_on_a_missing_data_set_names_it_and_exits_2(tmp_path, capsys):
    assert run(["train", "--method", "injection", "--data", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and "Traceback" not in err


def test_train_with_a_bad_scheduler_address_exits_2_with_one_line(fake_injection_dir, capsys):
    assert run(["train", "--method", "e4", "--data", str(fake_injection_dir), "--scheduler", "tcp://host"]) == 2
    err = capsys.readouterr().err
    assert "--scheduler 'tcp://host': expected tcp://host:port" in err and len(err.strip().splitlines()) == 1


def test_evaluate_with_a_broken_model_file_exits_2(fake_injection_dir, tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"junk")
    assert run(["evaluate", "--data", str(fake_injection_dir), "--model", str(bad)]) == 2
    assert "bad.npz" in capsys.readouterr().err


def test_unknown_method_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit) as exc:
        run(["train", "--method", "e7", "--data", "x"])
    assert exc.value.code == 2
    assert "invalid choice: 'e7'" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["train", "--help"], ["evaluate", "--help"]])
def test_help_explains_each_command(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        run(argv)
    assert exc.value.code == 0
    assert len(capsys.readouterr().out) > 200


def test_evaluate_refuses_held_out_series_the_model_was_trained_on(tmp_path, capsys):
    """Data sets of one seed share their series: a model trained on 20 series of seed 3 and
    scored on a 10-series set of seed 3 was once scored on series it had seen, silently."""
    big = write_fake_dataset(tmp_path / "big", n_series=20, seed=3)
    small = write_fake_dataset(tmp_path / "small", n_series=10, seed=3)     # big's first 10 series
    other = write_fake_dataset(tmp_path / "other", n_series=10, seed=4)
    model = tmp_path / "e1.npz"
    assert run(["train", "--method", "e1", "--data", str(big), "--quick", "--out", str(model)]) == 0
    capsys.readouterr()
    assert run(["evaluate", "--data", str(small), "--model", str(model)]) == 2
    err = capsys.readouterr().err
    assert "are series this model was trained on" in err and "--allow-train-overlap" in err
    assert run(["evaluate", "--data", str(small), "--model", str(model), "--allow-train-overlap"]) == 0
    assert "these scores flatter it" in capsys.readouterr().err
    assert run(["evaluate", "--data", str(other), "--model", str(model)]) == 0
    assert "trained on" not in capsys.readouterr().err


def test_train_refuses_to_replace_a_model_without_force(fake_injection_dir, tmp_path, capsys):
    out = tmp_path / "e1.npz"
    assert run(["train", "--method", "e1", "--data", str(fake_injection_dir), "--quick", "--out", str(out)]) == 0
    before = out.read_bytes()
    assert run(["train", "--method", "e1", "--data", str(fake_injection_dir), "--quick", "--out", str(out),
                "--kind", "linear"]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == before
    assert run(["train", "--method", "e1", "--data", str(fake_injection_dir), "--quick", "--out", str(out),
                "--kind", "linear", "--force"]) == 0
    assert out.read_bytes() != before


def test_train_with_the_measured_ratio_label_records_it_and_its_lag(fake_injection_dir, tmp_path, capsys):
    from incipient_slip.models.modelfile import read_model_file
    overlay = tmp_path / "identify_overlay.yaml"
    overlay.write_text("stick_slip:\n  friction_limit_lag_s: {value: 0.5, unit: s}\n")
    out = tmp_path / "e4.npz"
    assert run(["train", "--method", "e4", "--data", str(fake_injection_dir), "--quick", "--label",
                "measured-ratio", "--params", str(overlay), "--out", str(out)]) == 0
    assert "label measured-ratio (friction lag 0.5 s)" in capsys.readouterr().out
    header = read_model_file(out).header
    assert header["label"] == "measured-ratio" and header["friction_lag_s"] == 0.5


@pytest.mark.parametrize("argv, says", [
    (["--friction-lag-s", "0.5"], "inputs of --label measured-ratio"),
    (["--label", "measured-ratio", "--friction-lag-s", "-1"], ">= 0"),
    (["--label", "measured-ratio", "--params", "/nonexistent/overlay.yaml"], "cannot read the overlay"),
])
def test_train_names_a_bad_label_input_and_exits_2(fake_injection_dir, tmp_path, capsys, argv, says):
    assert run(["train", "--method", "e4", "--data", str(fake_injection_dir), "--quick",
                "--out", str(tmp_path / "m.npz"), *argv]) == 2
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err


@pytest.mark.parametrize("text, says", [
    ("stick_slip: [1, 2]\n", "no stick_slip.friction_limit_lag_s"),
    ("stick_slip:\n  friction_limit_lag_s: {value: 700, unit: ms}\n", "is in 'ms'"),
    ("stick_slip:\n  friction_limit_lag_s: {value: abc, unit: s}\n", "'abc' is not a finite number"),
    ("stick_slip:\n  friction_limit_lag_s: .inf\n", "not a finite number"),
    ("stick_slip: {friction_limit_lag_s: [\n", "not YAML (line"),
])
def test_a_bad_overlay_is_named_in_one_line(fake_injection_dir, tmp_path, capsys, text, says):
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text(text)
    assert run(["train", "--method", "e4", "--data", str(fake_injection_dir), "--quick", "--label",
                "measured-ratio", "--params", str(overlay), "--out", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_evaluate_names_each_models_label_and_warns_when_they_differ(fake_injection_dir, tmp_path, capsys):
    for label in ("pseudo", "measured-ratio"):
        assert run(["train", "--method", "e4", "--data", str(fake_injection_dir), "--quick", "--label", label,
                    "--out", str(tmp_path / f"{label}.npz")]) == 0
    capsys.readouterr()
    assert run(["evaluate", "--data", str(fake_injection_dir), "--model", str(tmp_path / "pseudo.npz"),
                "--model", str(tmp_path / "measured-ratio.npz")]) == 0
    out, err = capsys.readouterr()
    assert "pseudo" in out and "measured-ratio" in out.splitlines()[-1]
    assert "different labels" in err
