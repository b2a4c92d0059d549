"""The shipped default models (models/*.npz, written by `slip reproduce models`) stay usable."""
import zipfile

import numpy as np
import pytest

from incipient_slip.models.estimator_core import default_model_path, load_model
from incipient_slip.models.features import METHODS, feature_spec, phi
from incipient_slip.models.modelfile import read_model_file


@pytest.mark.parametrize("method", METHODS)
def test_shipped_model_matches_the_current_feature_code(method):
    model = load_model(default_model_path(method), method=method)
    assert model.header["feature_spec_hash"] == feature_spec(method).spec_hash(), (
        f"models/{method}.npz was trained with another phi; run `slip reproduce models`")


@pytest.mark.parametrize("method", METHODS)
def test_shipped_model_is_small_data_at_the_papers_window(method):
    path = default_model_path(method)
    assert path.stat().st_size < 4 * 2 ** 20
    with zipfile.ZipFile(path) as z:
        assert all(n.endswith(".npy") for n in z.namelist())
    model = read_model_file(path)
    assert model.spec.window_s == 1.0
    assert {"training_data_hash", "hyper_parameters", "regen", "test_series"} <= set(model.header)


@pytest.mark.parametrize("method", METHODS)
def test_shipped_model_estimates_a_window_in_the_unit_interval(method):
    model = load_model(default_model_path(method))
    spec = model.spec
    rng = np.random.default_rng(0)
    w = rng.normal(0, 80, spec.window_samples) if spec.stream == "pac" else 2000 + rng.normal(0, 20, (spec.window_samples, 19))
    s = model.predict(phi(w, spec))
    assert s.shape == (1,) and 0.0 <= s[0] <= 1.0


def test_all_shipped_models_share_one_held_out_series_set():
    sets = {tuple(read_model_file(default_model_path(m)).header["test_series"]) for m in METHODS}
    assert len(sets) == 1
