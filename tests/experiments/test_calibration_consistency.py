"""The shipped simulator is the one the calibration page describes: every fitted value on the page
(docs/figures/calibration_results.json, which renders docs/calibration.md) is the value in
sim/params/default.yaml, to the digits the params file keeps."""
import json

import pytest

from incipient_slip.paths import docs_dir
from incipient_slip.sim.scene import load_params


def test_the_shipped_params_are_the_calibration_pages_fit():
    results = json.loads((docs_dir() / "figures" / "calibration_results.json").read_text())
    values, _, _ = load_params("default")
    assert results["fitted"], "the page holds no fitted values"
    for key, fitted in results["fitted"].items():
        section, name = key.split(".")
        assert values[section][name] == pytest.approx(fitted, rel=1e-5), key


class _Started(Exception):
    pass


@pytest.mark.parametrize("shipped_k_b", [0.3, 0.7])
def test_the_fit_starts_at_its_fixed_start_whatever_the_params_file_holds(monkeypatch, tmp_path, shipped_k_b):
    """A start read from the params file the fit writes made every rerun a new fit."""
    import dataclasses

    from incipient_slip.experiments import calibration
    from incipient_slip.experiments.settings import Settings
    from incipient_slip.sim import scene as scene_mod

    real_load = scene_mod.load_scene

    def load_scene(name):       # the params file as another fit (or a hand edit) left it
        sc = real_load(name)
        params = {k: dict(v) if isinstance(v, dict) else v for k, v in sc.params.items()}
        params["pre_slip"]["bulk_shear_n_per_mm"] = shipped_k_b
        params["stick_slip"]["mu_spread_scale"] = 1.2
        return dataclasses.replace(sc, params=params)

    seen = {}

    def fit_mechanics(scene, *args, **kwargs):
        seen.update({key: scene.params[key[0]][key[1]] for key in calibration.FITTED})
        raise _Started

    monkeypatch.setattr(scene_mod, "load_scene", load_scene)
    monkeypatch.setattr(calibration, "fit_mechanics", fit_mechanics)
    with pytest.raises(_Started):
        calibration.run(Settings(budget="quick", work=tmp_path, progress=False))
    assert seen == calibration.START
