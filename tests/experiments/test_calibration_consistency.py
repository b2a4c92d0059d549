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
