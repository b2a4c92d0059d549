"""Data sets on disk (docs/design.md format), independence of worker count, and the CLI contract."""
import json

import numpy as np
import pytest

from incipient_slip.cli import main
from incipient_slip.sim import load_scene
from incipient_slip.sim.dataset import write_dataset
from incipient_slip.sim.protocols import COLLECTION_FORCES_KPA, collection_forces_kpa

KEYS = {"pac_counts": np.int16, "electrode_counts": np.uint16, "pdc_counts": np.uint16, "tac_counts": np.uint16,
        "tdc_counts": np.uint16, "mocap_t_s": np.float64, "mocap_y_mm": np.float64, "period_end_s": np.float64,
        "normal_force_kpa": np.float64, "tangential_force_n": np.float64, "actuator_mm": np.float64,
        "object_y_mm": np.float64, "stick_area_ratio": np.float64, "load_ratio_stick": np.float64,
        "gross_slip": np.bool_}


def test_dataset_matches_the_documented_format(tmp_path):
    write_dataset(load_scene("paper"), 2, 7, tmp_path, workers=1, steps=12, progress=False)
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["format"] == "incipient-slip-dataset" and meta["version"] == 1 and meta["injection"] is True
    assert meta["n_series"] == 2 and meta["steps"] == 12 and meta["pac_pa_per_count"] == 0.37
    with np.load(tmp_path / "series_00001.npz") as z:
        for key, dtype in KEYS.items():
            assert z[key].dtype == dtype, key
        assert z["pac_counts"].shape == (12 * 1100,) and z["electrode_counts"].shape == (12 * 50, 19)
        assert z["mocap_t_s"].shape == (12 * 60,) and z["normal_force_kpa"].shape == (12,)
        assert str(z["material"]) == "abs" and bool(z["injection"]) and z["seed"].dtype == np.int64
        assert set(np.round(z["normal_force_kpa"], 1)) <= set(COLLECTION_FORCES_KPA)


def test_dataset_is_independent_of_worker_count(tmp_path):
    scene = load_scene("electrodes_only")
    write_dataset(scene, 3, 11, tmp_path / "a", workers=1, steps=8, progress=False)
    write_dataset(scene, 3, 11, tmp_path / "b", workers=2, steps=8, progress=False)
    for i in range(3):
        with np.load(tmp_path / "a" / f"series_{i:05d}.npz") as a, np.load(tmp_path / "b" / f"series_{i:05d}.npz") as b:
            for key in a.files:
                assert np.array_equal(a[key], b[key]), key


def test_dataset_on_dask_is_byte_identical_to_the_pool_for_1_and_2_workers(tmp_path, dask_client):
    scene = load_scene("electrodes_only")
    write_dataset(scene, 3, 11, tmp_path / "pool", workers=2, steps=8, progress=False)
    for n in (1, 2):
        write_dataset(scene, 3, 11, tmp_path / f"dask{n}", steps=8, progress=False, client=dask_client(n))
    for name in ["meta.json"] + [f"series_{i:05d}.npz" for i in range(3)]:
        pool = (tmp_path / "pool" / name).read_bytes()
        assert all((tmp_path / f"dask{n}" / name).read_bytes() == pool for n in (1, 2)), name


def test_collection_redraws_force_each_period_from_the_paper_grid():
    f = collection_forces_kpa(3, 450)
    assert set(f) <= set(COLLECTION_FORCES_KPA) and len(set(f)) == 13
    assert np.mean(f[1:] != f[:-1]) > 0.8


def _run(argv):
    return main(argv, modules=("incipient_slip.lab.cli",))          # registers `slip dataset`


@pytest.mark.parametrize("argv, needle", [
    (["dataset", "--scene", "nope", "--series", "1", "--out", "X"], "scene not found: nope"),
    (["dataset", "--scene", "paper", "--series", "0", "--out", "X"], "--series must be >= 1"),
    (["dataset", "--scene", "paper", "--series", "1", "--out", "X", "--materials", "wood"], "unknown material(s) wood"),
    (["dataset", "--scene", "paper", "--series", "1", "--out", "X", "--workers", "0"], "--workers must be >= 1"),
    (["dataset", "--scene", "paper", "--series", "1", "--out", "X", "--scheduler", "localhost:8786"],
     "--scheduler 'localhost:8786': expected tcp://host:port"),
    (["dataset", "--scene", "paper", "--series", "1", "--out", "X", "--scheduler", "tcp://127.0.0.1:1"],
     "--scheduler tcp://127.0.0.1:1: no dask scheduler answered"),
])
def test_bad_cli_input_exits_2_with_a_named_error(argv, needle, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("incipient_slip.cluster.CONNECT_TIMEOUT_S", 1.0)
    argv = [str(tmp_path / "out") if a == "X" else a for a in argv]
    assert _run(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_cli_dataset_writes_series(tmp_path):
    assert _run(["dataset", "--scene", "mechanics", "--series", "2", "--seed", "1", "--out", str(tmp_path),
                 "--steps", "5", "--workers", "1", "--quiet"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["meta.json", "series_00000.npz", "series_00001.npz"]


def test_cli_help_explains_the_commands(capsys):
    with pytest.raises(SystemExit):
        _run(["dataset", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "materials[i % n]" in text and "independent of --workers" in text
    assert "--dask" in text and "--scheduler tcp://HOST:PORT" in text


def test_dataset_series_equals_a_plain_step_period_loop():
    from incipient_slip.sim import Rig
    from incipient_slip.sim.dataset import simulate_series
    scene = load_scene("paper")
    data = simulate_series(scene, "tpu", 1234, steps=6)
    rig = Rig(scene, "tpu", 1234)
    outs = [rig.step_period(float(f)) for f in collection_forces_kpa(1234, 6)]
    assert np.array_equal(data["pac_counts"], np.concatenate([o.pac_counts for o in outs]))
    assert np.array_equal(data["electrode_counts"], np.concatenate([o.electrode_counts for o in outs]))
    assert np.array_equal(data["object_y_mm"], [o.object_y_mm for o in outs])


def _same_arrays(a: dict, b: dict):
    assert set(a) == set(b)
    for key in a:
        assert a[key].dtype == b[key].dtype and np.array_equal(a[key], b[key]), key


def _variant(name, params):
    import dataclasses
    return dataclasses.replace(load_scene(name), params=params)


@pytest.mark.parametrize("material,seed,lag", [("pla", 5, 0.0), ("tpu", 77, 0.0), ("abs", 3, 1.0)])
def test_series_of_views_equal_each_scene_simulated_on_its_own(material, seed, lag):
    # one run of paper gives no_injection's P_AC (its own modal filter state) and electrodes_only's
    # and mechanics' series exactly; the full 450 steps cover stick, slides (split periods) and re-sticks
    import copy
    from incipient_slip.sim.dataset import simulate_series
    params = copy.deepcopy(load_scene("paper").params)
    params["stick_slip"]["friction_limit_lag_s"] = lag
    paper = _variant("paper", params)
    views = [_variant(n, params) for n in ("no_injection", "electrodes_only", "mechanics")]
    together = simulate_series(paper, material, seed, 450, views)
    alone = [simulate_series(sc, material, seed, 450) for sc in [paper] + views]
    assert together[0]["gross_slip"].any() and not together[0]["gross_slip"].all()
    for t, a in zip(together, alone):
        _same_arrays(t, a)
    assert not np.array_equal(together[0]["pac_counts"], together[1]["pac_counts"])


def test_dataset_with_views_equals_each_data_set_written_on_its_own(tmp_path):
    scenes = {n: load_scene(n) for n in ("paper", "no_injection", "electrodes_only")}
    write_dataset(scenes["paper"], 3, 11, tmp_path / "one" / "paper", workers=2, steps=8, progress=False,
                  views={tmp_path / "one" / n: scenes[n] for n in ("no_injection", "electrodes_only")})
    for n, sc in scenes.items():
        write_dataset(sc, 3, 11, tmp_path / "each" / n, workers=1, steps=8, progress=False)
        assert (tmp_path / "one" / n / "meta.json").read_text() == (tmp_path / "each" / n / "meta.json").read_text()
        for i in range(3):
            with np.load(tmp_path / "one" / n / f"series_{i:05d}.npz") as a, \
                    np.load(tmp_path / "each" / n / f"series_{i:05d}.npz") as b:
                _same_arrays(dict(a), dict(b))


def test_views_that_do_not_follow_from_the_run_are_refused():
    import copy
    from incipient_slip.sim.dataset import view_kind
    paper, no_inj = load_scene("paper"), load_scene("no_injection")
    assert view_kind(no_inj, paper) == "without_pzt" and view_kind(load_scene("electrodes_only"), paper) == "no_pac"
    assert view_kind(paper, paper) == "same"
    params = copy.deepcopy(paper.params)
    params["electrodes"]["drift_counts"] += 1.0
    other = [_variant("no_injection", params),       # other parameters
             paper,                                  # more effects than the run has
             ]
    for view, source in zip(other, (paper, no_inj)):
        with pytest.raises(ValueError):
            view_kind(view, source)
    with pytest.raises(ValueError):                  # a louder PZT is not the same P_AC
        import dataclasses
        view_kind(dataclasses.replace(paper, injection_db=6.0), paper)


def test_series_are_bit_identical_to_the_committed_reference():
    # every array of data-collection series (each scene, material, two seeds), series written with
    # views, a parameter variant and closed-loop runs (PZT switched, actuator held), the signal
    # path's floats behind the counts (filter and electrode states after every period, its
    # functions' unquantized outputs) equal, bit for bit, what the simulator computed when
    # tests/data/sim_series.json was written (speed work must not change results;
    # make_sim_series.py says when to regenerate it)
    import importlib.util
    import json
    from pathlib import Path
    data = Path(__file__).resolve().parents[1] / "data"
    spec = importlib.util.spec_from_file_location("make_sim_series", data / "make_sim_series.py")
    make = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make)
    recorded = json.loads((data / "sim_series.json").read_text())
    got = make.digests()
    assert set(got) == set(recorded)
    differ = {case: [k for k in recorded[case] if got[case].get(k) != recorded[case][k]]
              for case in recorded if got[case] != recorded[case]}
    assert not differ, f"arrays differ from the reference: {differ}"


def test_an_interrupted_data_set_has_no_meta_and_is_made_again(tmp_path, monkeypatch):
    """meta.json is written last: a crash half-way once left a directory that looked finished
    to the experiments' cache (and, with no series file, failed every rerun)."""
    from incipient_slip.experiments.datasets import _reusable, ensure_dataset
    from incipient_slip.models import dataset as ds
    from incipient_slip.sim import dataset as sim_dataset
    scene, out = load_scene("paper"), tmp_path / "paper"
    real_worker = sim_dataset._worker

    def crash_at_series_2(job):
        if job[3] == 2:
            raise RuntimeError("killed")
        return real_worker(job)
    monkeypatch.setattr(sim_dataset, "_worker", crash_at_series_2)
    with pytest.raises(RuntimeError, match="killed"):
        write_dataset(scene, 4, 7, out, workers=1, steps=12, progress=False)
    assert not (out / "meta.json").exists() and len(list(out.glob("series_*.npz"))) == 2
    with pytest.raises(ds.DatasetError, match="meta.json"):
        ds.read_meta(out)
    assert not _reusable(scene, 4, 7, 12, out)
    monkeypatch.setattr(sim_dataset, "_worker", real_worker)
    ensure_dataset(scene, 4, 7, out, workers=1, steps=12, progress=False)
    assert ds.read_meta(out)["n_series"] == 4 and len(ds.series_paths(out)) == 4
    # a finished set whose series files went missing is not reused either (it raised before)
    for p in out.glob("series_*.npz"):
        p.unlink()
    assert not _reusable(scene, 4, 7, 12, out)


def test_overwriting_a_data_set_with_fewer_series_leaves_none_of_the_old_ones(tmp_path, capsys):
    out = tmp_path / "set"
    assert main(["dataset", "--scene", "paper", "--series", "4", "--seed", "7", "--steps", "12",
                 "--workers", "1", "--out", str(out), "--quiet"]) == 0
    assert main(["dataset", "--scene", "paper", "--series", "2", "--seed", "3", "--steps", "12",
                 "--workers", "1", "--out", str(out), "--quiet"]) == 2      # refused without --overwrite
    assert main(["dataset", "--scene", "paper", "--series", "2", "--seed", "3", "--steps", "12",
                 "--workers", "1", "--out", str(out), "--quiet", "--overwrite"]) == 0
    assert sorted(p.name for p in out.glob("series_*.npz")) == ["series_00000.npz", "series_00001.npz"]
    (out / "meta.json").unlink()                                             # as a crash leaves it
    assert main(["dataset", "--scene", "paper", "--series", "2", "--out", str(out), "--quiet"]) == 2
    assert "an unfinished data set (no meta.json)" in capsys.readouterr().err


def test_training_on_a_scene_without_the_methods_sensor_names_the_sensor(tmp_path, capsys):
    write_dataset(load_scene("mechanics"), 2, 7, tmp_path / "mech", workers=1, steps=12, progress=False)
    assert main(["train", "--method", "e19", "--data", str(tmp_path / "mech"), "--quick",
                 "--out", str(tmp_path / "e19.npz")]) == 2
    err = capsys.readouterr().err
    assert "hold no electrode samples: scene 'mechanics' does not simulate them" in err, err


def test_a_shipped_model_is_not_scored_on_the_series_it_was_trained_on(tmp_path, capsys):
    """The shipped models were trained on seed 7's sets: a small seed-7 set holds their training
    series. The check once keyed series on the simulator's code version, and a later edit of a
    comment in sim/ turned it off for every model."""
    from incipient_slip.paths import model_dir
    shipped = str(model_dir() / "e1.npz")
    data = tmp_path / "paper_s7"
    write_dataset(load_scene("paper"), 10, 7, data, workers=2, progress=False)
    assert main(["evaluate", "--data", str(data), "--model", shipped]) == 2
    assert "are series this model was trained on" in capsys.readouterr().err
    other = tmp_path / "paper_s8"
    write_dataset(load_scene("paper"), 10, 8, other, workers=2, progress=False)
    assert main(["evaluate", "--data", str(other), "--model", shipped]) == 0
