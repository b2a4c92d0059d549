import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.models.features import feature_spec
from incipient_slip.models.training import (grouped_folds, held_out_series, load_windows,
                                            split_train_test, train_model)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.sampled_from(["pla", "abs", "tpu", "wood", "rubber"]), min_size=2, max_size=120))
def test_held_out_series_is_about_ten_percent_per_material_and_never_a_whole_material(materials):
    sm = dict(enumerate(materials))
    test = set(held_out_series(sm).tolist())
    for mat in set(materials):
        idx = [i for i, m in sm.items() if m == mat]
        n_test = len(test.intersection(idx))
        assert n_test < len(idx) or len(idx) == 0
        assert n_test == (0 if len(idx) == 1 else min(max(int(np.ceil(0.1 * len(idx) - 1e-9)), 1), len(idx) - 1))


def test_held_out_series_is_the_same_for_any_data_set_with_the_same_series():
    sm = {i: ["pla", "abs", "tpu", "wood", "rubber"][i % 5] for i in range(500)}
    a = held_out_series(sm)
    b = held_out_series(dict(reversed(list(sm.items()))))
    np.testing.assert_array_equal(a, b)
    assert len(a) == 50


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 30), min_size=5, max_size=300), st.integers(2, 5))
def test_grouped_folds_never_share_a_series(groups, n_folds):
    groups = np.array(groups)
    for tr, va in grouped_folds(groups, n_folds):
        assert not set(groups[tr]) & set(groups[va])
        assert len(tr) + len(va) == len(groups)


def test_train_test_split_never_shares_a_series(fake_injection_dir):
    ws = load_windows(fake_injection_dir, feature_spec("e4"), progress=False)
    train, test = split_train_test(ws, held_out_series(ws.series_materials()))
    assert len(test.y) > 0 and len(train.y) > 0
    assert not set(train.series) & set(test.series)


@pytest.mark.parametrize("method,kind", [("injection", "svr"), ("e19", "svr"), ("injection", "nystroem"),
                                         ("e10", "linear")])
def test_model_trained_on_small_set_beats_constant_predictor(fake_injection_dir, method, kind):
    ws = load_windows(fake_injection_dir, feature_spec(method), progress=False)
    train, test = split_train_test(ws, held_out_series(ws.series_materials()))
    model = train_model(train, kind, quick=True, progress=False, n_components=200).model
    rmse = np.sqrt(np.mean((model.predict(test.X) - test.y) ** 2))
    constant = np.sqrt(np.mean((train.y.mean() - test.y) ** 2))
    assert rmse < 0.5 * constant


def test_exported_svr_predicts_like_sklearn(fake_injection_dir):
    from sklearn.svm import SVR
    from incipient_slip.models.training import model_from_svr
    ws = load_windows(fake_injection_dir, feature_spec("injection"), progress=False)
    X = ws.X.astype(np.float64)
    mean, scale = X.mean(0), X.std(0)
    for kernel in ("rbf", "linear", "poly"):
        svr = SVR(kernel=kernel, C=1.0, gamma="scale", degree=2).fit((X[:300] - mean) / scale, ws.y[:300])
        model = model_from_svr(svr, mean, scale, ws.spec)
        np.testing.assert_allclose(model.predict_raw(X[300:400]), svr.predict((X[300:400] - mean) / scale),
                                   atol=1e-8)


def test_vibrotactile_method_refuses_a_data_set_with_injection(fake_injection_dir):
    from incipient_slip.models.dataset import DatasetError
    with pytest.raises(DatasetError, match="injection"):
        load_windows(fake_injection_dir, feature_spec("vibrotactile"), progress=False)


def test_chunked_nystroem_ridge_equals_sklearn_nystroem_plus_ridge():
    from sklearn.kernel_approximation import Nystroem
    from sklearn.linear_model import Ridge
    from incipient_slip.models.training import (nystroem_basis, nystroem_solve, nystroem_sums,
                                                rbf_kernel)
    rng = np.random.default_rng(3)
    Z = rng.normal(size=(500, 6))
    y = np.sin(Z[:, 0]) + 0.1 * rng.normal(size=500)
    centers, norm = nystroem_basis(Z, 50, 0.2)
    w, b = nystroem_solve(nystroem_sums(Z, y, centers, norm, 0.2, chunk=64), norm, 1e-3)
    ny = Nystroem(gamma=0.2, n_components=50).fit(centers)   # same landmarks
    F = ny.transform(Z)
    ridge = Ridge(alpha=1e-3 * len(Z)).fit(F, y)
    np.testing.assert_allclose(rbf_kernel(Z, centers, 0.2) @ w + b, ridge.predict(F), atol=1e-6)


def test_grid_search_choice_is_the_same_in_process_on_a_local_pool_and_on_1_and_2_dask_workers(fake_injection_dir, dask_client):
    from incipient_slip.models.training import grid_search_svr, svr_grid
    ws = load_windows(fake_injection_dir, feature_spec("e4"), progress=False)
    X, y, g = ws.X.astype(np.float64)[:600], ws.y[:600], ws.series[:600]
    grid = svr_grid(X.shape[1], quick=True) + [dict(kernel="linear", C=1.0, epsilon=0.05)]
    local = grid_search_svr(X, y, g, grid, progress=False)
    assert len({r["rmse"] for r in local[1]}) == len(grid)       # the choice is not a tie
    for n in (1, 2):
        assert grid_search_svr(X, y, g, grid, progress=False, client=dask_client(n)) == local
    assert grid_search_svr(X, y, g, grid, progress=False, workers=2) == local     # a forked local pool


def test_a_shared_precomputed_rbf_kernel_gives_libsvm_rbf_dual_coefficients_bit_for_bit(fake_injection_dir):
    """The grid fits RBF candidates on one kernel matrix per (fold, gamma): libsvm must solve the
    same problem, so the support, dual coefficients and intercept are equal (==), and the
    predictions equal to the last bits (numpy forms the validation kernel, not libsvm)."""
    from sklearn.svm import SVR
    from incipient_slip.models.training import _rbf_kernels, _standardize, grouped_folds, svr_grid
    ws = load_windows(fake_injection_dir, feature_spec("injection"), progress=False)
    X, y = ws.X.astype(np.float64)[:700], ws.y[:700]
    mean, scale = _standardize(X)
    Z = (X - mean) / scale
    tr, va = next(grouped_folds(ws.series[:700], 3))
    for p in svr_grid(X.shape[1])[:24:5]:
        assert p["kernel"] == "rbf"
        own = SVR(cache_size=500, **p).fit(Z[tr], y[tr])
        K, K_va = _rbf_kernels(Z[tr], Z[va], p["gamma"])
        pre = SVR(kernel="precomputed", cache_size=500, C=p["C"], epsilon=p["epsilon"]).fit(K, y[tr])
        np.testing.assert_array_equal(pre.support_, own.support_)
        np.testing.assert_array_equal(pre.dual_coef_, own.dual_coef_)
        np.testing.assert_array_equal(pre.intercept_, own.intercept_)
        np.testing.assert_allclose(pre.predict(K_va), own.predict(Z[va]), rtol=0, atol=1e-12)


def test_grid_rows_and_choice_equal_one_libsvm_fit_per_candidate_and_fold(fake_injection_dir):
    """The grid's tasks (a shared kernel per gamma and fold) give the rows of fitting every
    candidate on every fold by itself; RMSEs to 1e-12 relative (the validation kernel's last
    bits, see above; 6e-15 on the study's 2000-window grids), and the same choice."""
    from sklearn.svm import SVR
    from incipient_slip.models.training import _standardize, grid_search_svr, grouped_folds, svr_grid
    ws = load_windows(fake_injection_dir, feature_spec("injection"), progress=False)
    X, y, g = ws.X.astype(np.float64)[:500], ws.y[:500], ws.series[:500]
    grid = svr_grid(X.shape[1])
    best, rows = grid_search_svr(X, y, g, grid, progress=False)
    mean, scale = _standardize(X)
    Z = (X - mean) / scale
    folds = list(grouped_folds(g, 3))
    ref = [np.sqrt(np.mean([np.mean((np.clip(SVR(cache_size=500, **p).fit(Z[tr], y[tr]).predict(Z[va]), 0, 1)
                                     - y[va]) ** 2) for tr, va in folds])) for p in grid]
    assert [r["params"] for r in rows] == grid
    np.testing.assert_allclose([r["rmse"] for r in rows], ref, rtol=1e-12, atol=0)
    assert best == grid[int(np.argmin(ref))]


def test_window_sets_read_once_for_many_specs_on_a_pool_equal_load_windows_per_spec(fake_injection_dir):
    from incipient_slip.models.training import load_window_sets
    # injection's variants share the FFT of each window (series_feature_sets): still the same floats
    specs = [feature_spec(m) for m in ("injection", "e19", "e1")] + [
        feature_spec("injection", bin_hz=25.0), feature_spec("injection", band_hz=(100.0, 400.0)),
        feature_spec("injection", window_s=0.5)]
    for after_slip in ("zero", "drop"):
        sets = load_window_sets(fake_injection_dir, specs, progress=False, after_slip=after_slip, workers=2)
        for spec, got in zip(specs, sets):
            one = load_windows(fake_injection_dir, spec, progress=False, after_slip=after_slip)
            assert got.spec == spec and got.data_hash == one.data_hash
            assert got.skipped_series == one.skipped_series
            for col in ("X", "y", "series", "material", "period", "stick_area_ratio", "load_ratio_stick",
                        "tangential_force_n", "normal_force_kpa", "post_slip"):
                np.testing.assert_array_equal(getattr(got, col), getattr(one, col))


def test_with_a_cache_a_repeated_grid_search_and_fit_train_nothing_and_give_the_same(fake_injection_dir, tmp_path,
                                                                                     monkeypatch):
    from sklearn.svm import SVR

    from incipient_slip import cache
    from incipient_slip.models.training import grid_search_svr, svr_grid, train_model
    ws = load_windows(fake_injection_dir, feature_spec("e4"), progress=False)
    X, y, g = ws.X.astype(np.float64)[:400], ws.y[:400], ws.series[:400]
    grid = svr_grid(X.shape[1], quick=True)
    fits, real_fit = [], SVR.fit
    monkeypatch.setattr(SVR, "fit", lambda self, *a, **k: fits.append(1) or real_fit(self, *a, **k))
    plain = grid_search_svr(X, y, g, grid, progress=False)
    model = train_model(ws, "svr", max_train=300, grid_max=200, quick=True, progress=False).model
    n_plain = len(fits)
    with cache.use(tmp_path / "cache"):
        first = grid_search_svr(X, y, g, grid, progress=False)
        cached_model = train_model(ws, "svr", max_train=300, grid_max=200, quick=True, progress=False).model
        assert len(fits) == 2 * n_plain                # the first pass with a cache fits everything
        again = grid_search_svr(X, y, g, grid, progress=False)
        again_model = train_model(ws, "svr", max_train=300, grid_max=200, quick=True, progress=False).model
    assert len(fits) == 2 * n_plain                    # the second fits nothing
    assert plain == first == again
    for m in (cached_model, again_model):
        np.testing.assert_array_equal(m.weights, model.weights)
        np.testing.assert_array_equal(m.centers, model.centers)
    assert cache.root() is None                        # off again after the block
    y2 = y.copy()
    y2[0] += 0.01
    with cache.use(tmp_path / "cache"):
        grid_search_svr(X, y2, g, grid, progress=False)
    assert len(fits) > 2 * n_plain                     # other data: another key, fitted again


def test_with_a_cache_windows_are_computed_once_per_data_set_and_spec(fake_injection_dir, tmp_path, monkeypatch):
    from incipient_slip import cache
    from incipient_slip.models import training
    plain = load_windows(fake_injection_dir, feature_spec("e4"), progress=False)
    calls, real = [], training.series_feature_sets
    monkeypatch.setattr(training, "series_feature_sets", lambda *a, **k: calls.append(1) or real(*a, **k))
    with cache.use(tmp_path / "cache"):
        first = load_windows(fake_injection_dir, feature_spec("e4"), progress=False)
        n = len(calls)
        again = load_windows(fake_injection_dir, feature_spec("e4"), progress=False)
        assert len(calls) == n > 0                           # read back, not computed
        load_windows(fake_injection_dir, feature_spec("e10"), progress=False)
        assert len(calls) > n                                # another spec is another key
    for ws in (first, again):
        np.testing.assert_array_equal(ws.X, plain.X)
        np.testing.assert_array_equal(ws.y, plain.y)
        assert ws.data_hash == plain.data_hash


def test_a_timed_fit_of_accuracy_vs_time_never_comes_from_the_cache(fake_injection_dir, tmp_path, monkeypatch):
    """accuracy vs time reports each fit's time: under `slip reproduce` (cache on) a repeated fit
    came from the cache and the page showed 'fit 0.0 s' for exact SVR. Timed fits bypass it."""
    from sklearn.svm import SVR

    from incipient_slip import cache
    from incipient_slip.experiments.accuracy_vs_time import fit_point
    ws = load_windows(fake_injection_dir, feature_spec("injection"), progress=False)
    fits, real_fit = [], SVR.fit
    monkeypatch.setattr(SVR, "fit", lambda self, *a, **k: fits.append(1) or real_fit(self, *a, **k))
    params = {"kernel": "rbf", "C": 1.0, "gamma": 0.01, "epsilon": 0.05}
    with cache.use(tmp_path / "cache"):
        first = fit_point("model", "exact SVR", ws, ws, "svr", params, 200)
        n_first = len(fits)
        again = fit_point("model", "exact SVR", ws, ws, "svr", params, 200)
        assert cache.root() == tmp_path / "cache"      # on again after each timed fit
    assert n_first >= 1 and len(fits) == 2 * n_first    # the second fit was done, not read back
    assert again.rmse == first.rmse
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*.pkl"))


def test_accuracy_vs_time_fits_a_setting_met_in_several_sweeps_once(fake_injection_dir, monkeypatch):
    """The paper's setting is a point of every sweep, and the size sweep's exact SVRs are the scale
    study's: each setting is fitted (and timed) once and reported under each sweep's own label;
    another setting is another fit."""
    from incipient_slip.experiments import accuracy_vs_time as avt
    ws = load_windows(fake_injection_dir, feature_spec("injection"), progress=False)
    calls, real = [], avt.fit_point
    monkeypatch.setattr(avt, "fit_point", lambda *a, **k: calls.append(a[:2]) or real(*a, **k))
    params = {"kernel": "rbf", "C": 1.0, "gamma": 0.01, "epsilon": 0.05}
    fits = avt.Fits()
    first = fits.point("window", "T = 1 s", ws, ws, "svr", params, 200)
    again = fits.point("size", "exact SVR n = 200", ws, ws, "svr", dict(params), 200)
    assert calls == [("window", "T = 1 s")]
    assert (again.sweep, again.label) == ("size", "exact SVR n = 200")
    assert (again.rmse, again.train_s, again.latency_ms) == (first.rmse, first.train_s, first.latency_ms)
    assert (first.sweep, first.label) == ("window", "T = 1 s")          # the first report is unchanged
    fits.point("size", "exact SVR n = 100", ws, ws, "svr", params, 100)
    fits.point("model", "C = 2", ws, ws, "svr", dict(params, C=2.0), 200)
    fits.point("model", "Nystroem 50", ws, ws, "nystroem", params, None, n_components=50)
    fits.point("scale", "Nystroem 60", ws, ws, "nystroem", params, None, n_components=60)
    assert len(calls) == 5


def test_relabelled_windows_equal_the_windows_loaded_with_that_label(fake_injection_dir):
    # the features are computed once; another label only replaces the target
    from incipient_slip.models.features import feature_spec
    from incipient_slip.models.labels import LabelRule
    from incipient_slip.models.training import load_windows, relabel, series_targets
    spec = feature_spec("e4")
    rules = [LabelRule("pseudo"), LabelRule("measured-ratio", 0.5)]
    base = load_windows(fake_injection_dir, spec, progress=False)
    targets = series_targets(fake_injection_dir, rules)
    for n, rule in enumerate(rules):
        direct = load_windows(fake_injection_dir, spec, progress=False, label=rule)
        moved = relabel(base, {i: t[n] for i, t in targets.items()})
        np.testing.assert_array_equal(moved.y, direct.y)
        np.testing.assert_array_equal(moved.X, direct.X)
        np.testing.assert_array_equal(moved.period, direct.period)
    assert any(not np.array_equal(t[0], t[1]) for t in targets.values())    # the two labels differ
