import numpy as np

from incipient_slip.models.pipeline import load_all_windows, run_study


def test_a_study_trained_on_a_pool_of_methods_equals_the_study_trained_in_process(fake_injection_dir,
                                                                                  fake_no_injection_dir):
    """run_study(workers=2) trains the methods two at a time in forked processes (one BLAS thread
    each): the same choices and models, the predictions to the last bits BLAS rounds differently
    with its thread count (1e-12), and the windows read in two processes are the same (==)."""
    dirs = {"paper": fake_injection_dir, "no_injection": fake_no_injection_dir}
    methods = ["injection", "vibrotactile", "e4"]
    one = load_all_windows(dirs, methods, progress=False)
    two = load_all_windows(dirs, methods, progress=False, workers=2)
    for m in methods:
        np.testing.assert_array_equal(two[m].X, one[m].X)
        np.testing.assert_array_equal(two[m].y, one[m].y)
    kw = dict(methods=methods, quick=True, max_train=300, grid_max=200, progress=False, windows=one)
    a, b = run_study(dirs, **kw), run_study(dirs, workers=2, **kw)
    assert a.test_series == b.test_series
    for m in methods:
        ra, rb = a.results[m], b.results[m]
        assert ra.report["params"] == rb.report["params"] and ra.report["grid"] == rb.report["grid"]
        np.testing.assert_array_equal(ra.model.weights, rb.model.weights)
        np.testing.assert_array_equal(ra.model.centers, rb.model.centers)
        np.testing.assert_allclose(rb.pred, ra.pred, rtol=1e-12, atol=1e-12)
    for ta, tb in zip(a.table(), b.table()):
        assert ta["method"] == tb["method"] and ta["params"] == tb["params"]
        np.testing.assert_allclose(tb["rmse_mean"], ta["rmse_mean"], rtol=1e-12)


def test_the_data_hash_is_of_the_data_not_of_the_simulator_source(fake_injection_dir, tmp_path):
    """A refactor of sim/ that keeps every array changes meta.json's physics_fingerprint (a hash
    of the source); before, that changed every shipped model's training_data_hash, so a fresh
    `slip reproduce models` could not give the committed files. A changed series still counts."""
    import json
    import shutil

    from incipient_slip.models.dataset import dataset_hash, series_paths
    copy = tmp_path / "copy"
    shutil.copytree(fake_injection_dir, copy)
    meta = json.loads((copy / "meta.json").read_text())
    meta["physics_fingerprint"] = "0123456789abcdef"
    (copy / "meta.json").write_text(json.dumps(meta, indent=3))
    assert dataset_hash(copy) == dataset_hash(fake_injection_dir)
    first = series_paths(copy)[0]
    first.write_bytes(first.read_bytes()[:100] + b"x" + first.read_bytes()[101:])
    assert dataset_hash(copy) != dataset_hash(fake_injection_dir)
