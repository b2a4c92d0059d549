"""The calibration experiment: objective reads only the pre-registered targets, params written with
provenance, the target table, bad input as named errors."""
import math
import shutil

import numpy as np
import pytest

from incipient_slip.errors import UsageError

from incipient_slip.experiments import calibration as cal
from incipient_slip.experiments import mechanics_fit as fit
from incipient_slip.sim.scene import PARAMS_DIR, load_params


ON_TARGET = {"T1": 1.5, "T2": 0.4, "T3": 1.0, "T4": 2.48, "T4_slid": 1.0,
             "T7": {"1.1": 1.5, "2.3": 1.5, "3.5": 1.5, "4.7": 1.5, "5.9": 1.5}}


def test_objective_is_zero_exactly_on_the_targets_and_penalises_a_missing_slip():
    on = ON_TARGET
    assert fit.mechanics_objective(on) == 0.0 and fit.consistent_with_open_loop(on)
    assert fit.mechanics_objective({**on, "T3": 0.9}) == pytest.approx(10.0 * 9.0)
    assert fit.mechanics_objective({**on, "T1": 1.7}) == pytest.approx(1.0)
    assert fit.mechanics_objective({**on, "T1": math.nan}) >= 1e6


def test_amendment_2_no_action_must_slide_and_the_range_must_hold_at_every_level():
    on = ON_TARGET
    # T4'(b): fewer than 60 % of no-action runs sliding is penalised like a missing slip, and inconsistent
    assert fit.mechanics_objective({**on, "T4_slid": 0.4}) == pytest.approx(20.0)
    assert not fit.consistent_with_open_loop({**on, "T4_slid": 0.4})
    # T7: a level outside 1.1-1.9 mm costs (distance / 0.2 mm)^2; inside the band costs nothing
    assert fit.mechanics_objective({**on, "T7": {**on["T7"], "5.9": 2.3}}) == pytest.approx(4.0)
    assert fit.mechanics_objective({**on, "T7": {**on["T7"], "5.9": 1.85}}) == 0.0
    assert not fit.consistent_with_open_loop({**on, "T7": {**on["T7"], "1.1": 1.0}})
    assert fit.mechanics_objective({**on, "T7": {**on["T7"], "1.1": math.nan}}) == pytest.approx(25.0)


def test_the_slide_start_is_y_where_the_slide_starts_not_after_it():
    from incipient_slip.sim.rig import Rig
    from incipient_slip.sim.scene import load_scene, with_effects
    rig = Rig(with_effects(load_scene("paper"), fit.MECHANICS), "pla", 3)
    run = fit.run_mechanics(rig, np.full(3000, 2.3), stop_at_slip=True)
    k = fit.first_rule(run)
    assert k == len(run["travel_mm"]) - 1 > 0, "no gross slip under a ramp at 2.3 kPa"
    start = fit.slide_start_mm(run, rig.spring_n_per_mm, k)
    # the slide starts after the pad sheared to its limit: at or beyond the last stuck y,
    # and before where the period's slide carried the object
    assert run["object_y_mm"][k - 1] - 1e-9 <= start <= run["object_y_mm"][k] + 1e-9
    assert math.isnan(fit.slide_start_mm(run, rig.spring_n_per_mm, 0))       # no slide in the first period


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
                                                                      "skip_estimation": True,
                                                                      "skip_beta_interval": True})
    from incipient_slip.sim.scene import PARAMS_DIR
    shipped = (PARAMS_DIR / "default.yaml").read_bytes()
    res = cal.run(s)
    assert sorted(r["id"] for r in res["targets"]) == sorted(t for t in fit.TARGETS if t != "T6")
    block = cal.render(res)["calibration-table"]
    assert "Simulated rig" in block and "| T4 |" in block and "`stick_slip.spring_n_per_mm`" in block
    assert (PARAMS_DIR / "default.yaml").read_bytes() == shipped     # only --write-params writes it


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


def test_beta_interval_on_two_processes_gives_the_rows_of_one():
    from incipient_slip.sim.scene import load_scene
    args = (load_scene("paper"), 6, 1, 3)
    one = fit.beta_interval(*args, grid=(0.75, 1.25), maxfev=3, progress=False)
    two = fit.beta_interval(*args, grid=(0.75, 1.25), maxfev=3, progress=False, workers=2)
    assert [r["beta"] for r in one] == [0.75, 1.25] and one == two
