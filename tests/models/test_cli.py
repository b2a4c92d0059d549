import argparse
import json

import numpy as np
import pytest

from incipient_slip.models import cli


def run(argv):
    parser = argparse.ArgumentParser(prog="slip")
    sub = parser.add_subparsers(dest="command", required=True)
    rep = sub.add_parser("reproduce").add_subparsers(dest="experiment", required=True)
    cli.register(sub, rep)
    args = parser.parse_args(argv)
    return args.func(args)


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


@pytest.mark.parametrize("argv", [["train", "--help"], ["evaluate", "--help"], ["model", "regen", "--help"],
                                  ["reproduce", "estimation", "--help"]])
def test_help_explains_each_command(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        run(argv)
    assert exc.value.code == 0
    assert len(capsys.readouterr().out) > 200


def test_reproduce_estimation_quick_runs_on_the_simulated_rig(tmp_path):
    pytest.importorskip("incipient_slip.sim.dataset")
    assert run(["reproduce", "estimation", "--quick", "--out", str(tmp_path)]) == 0
    meta = json.loads(next((tmp_path / "data").glob("paper_*/meta.json")).read_text())
    assert meta["scene"] == "paper" and meta["created_by"].startswith("incipient_slip.sim")
    results = json.loads((tmp_path / "results.json").read_text())
    assert [r["method"] for r in results["table"]] == ["injection", "vibrotactile", "e19", "e10", "e4", "e1"]
    assert all(np.isfinite(r["rmse_mean"]) and np.isfinite(r["top10_mean"]) for r in results["table"])
    md = (tmp_path / "estimation.md").read_text()
    assert md.count("*Simulated rig.*") >= 4
    assert len(list((tmp_path / "figures").glob("est_*.png"))) >= 5


def test_cached_data_set_from_other_physics_is_regenerated(tmp_path):
    """A data set cached before the simulator changed must not be reused."""
    import json
    from incipient_slip.models.pipeline import ensure_dataset
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
