"""The calibration experiment: objective reads only the pre-registered targets, params written with
provenance, the target table, bad input as named errors."""
import math
import shutil

import pytest

from incipient_slip.errors import UsageError

from incipient_slip.experiments import calibration as cal
from incipient_slip.sim.scene import PARAMS_DIR, load_params


def test_objective_is_zero_exactly_on_the_targets_and_penalises_a_missing_slip():
    on = {"T1": 1.5, "T2": 0.4, "T3": 1.0, "T4": 2.48}
    assert cal.mechanics_objective(on) == 0.0
    assert cal.mechanics_objective({**on, "T3": 0.9}) == pytest.approx(10.0 * 9.0)
    assert cal.mechanics_objective({**on, "T1": 1.7}) == pytest.approx(1.0)
    assert cal.mechanics_objective({**on, "T1": math.nan}) >= 1e6


def test_write_params_rewrites_value_and_source_and_keeps_the_file_loadable(tmp_path):
    path = tmp_path / "p.yaml"
    shutil.copy(PARAMS_DIR / "default.yaml", path)
    cal.write_params(path, {"pre_slip.bulk_shear_n_per_mm": (0.123456789, "fitted (test): T1"),
                            "stick_slip.spring_n_per_mm": (0.0271, "fitted (test): T4")})
    values, units, _ = load_params(path)
    assert values["pre_slip"]["bulk_shear_n_per_mm"] == pytest.approx(0.123457)
    assert values["stick_slip"]["spring_n_per_mm"] == pytest.approx(0.0271)
    assert units["p.yaml:pre_slip.bulk_shear_n_per_mm"] == "N/mm"
    assert 'source: "fitted (test): T1"' in path.read_text()
    with pytest.raises(KeyError, match="nope"):
        cal.write_params(path, {"pre_slip.nope": (1.0, "x")})


@pytest.mark.parametrize("item", ["pre_slip.bulk_shear_n_per_mm", "x=1", "stick_slip.spring_n_per_mm=inf"])
def test_bad_overrides_are_named(item):
    with pytest.raises(UsageError, match="--set"):
        cal.parse_overrides([item])


def test_every_parameter_has_a_unit_and_a_source_fit_or_stated_assumption():
    raw = (PARAMS_DIR / "default.yaml").read_text()
    values, units, _ = load_params("default")
    assert units and all(u for u in units.values())
    import yaml
    doc = yaml.safe_load(raw)

    def leaves(node):
        if isinstance(node, dict) and "value" in node:
            yield node
        elif isinstance(node, dict):
            for v in node.values():
                yield from leaves(v)
    words = ("assumption", "fitted", "paper", "prior", "BioTac", "datasheet", "manual", "OptiTrack", "12-bit", "numerical")
    for leaf in leaves(doc):
        assert any(w in leaf["source"] for w in words), leaf


def test_quick_calibration_prints_a_target_row_for_every_preregistered_target(tmp_path):
    from incipient_slip.experiments.settings import Settings
    s = Settings(budget="quick", work=tmp_path, progress=False, options={"series": 5, "runs": 1, "maxfev": 3,
                                                                      "skip_estimation": True})
    res = cal.run(s)
    assert [r["id"] for r in res["targets"]] == [t for t in cal.TARGETS if t != "T6"]
    block = cal.render(res)["calibration-table"]
    assert "Simulated rig" in block and "| T4 |" in block and "`stick_slip.spring_n_per_mm`" in block
    assert res["params_written"] == ""


def test_estimation_pattern_items_follow_the_preregistered_rules():
    base = {"rmse": 0.15, "top10": 0.3, "rmse_s_above_0.7": 0.3, "rmse_s_mid": 0.2,
            "by_material": {"pla": 0.15, "tpu": 0.16}}
    scores = {m: dict(base) for m in ("injection", "e19", "e10", "e4")}
    scores["injection"] = {**base, "top10": 0.25}
    scores["vibrotactile"] = {**base, "rmse": 0.4, "top10": 0.6}
    scores["e1"] = {**base, "rmse": 0.4, "top10": 0.6}
    items = cal.pattern_items(scores)
    assert all(ok for ok, _ in items.values()) and cal.pattern_objective(items) == 0.0
    scores["e19"] = {**base, "rmse_s_above_0.7": 0.1}          # electrodes best near full stick: (d) fails
    items = cal.pattern_items(scores)
    assert not items["d"][0] and cal.pattern_objective(items) == 0.5
