import json
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from incipient_slip.models.estimator_core import ModelFileError, load_model
from incipient_slip.models.features import feature_spec
from incipient_slip.models.modelfile import Model, rbf_of_dot, read_model_file, save_model


def _model(method="injection", kind="kernel"):
    spec = feature_spec(method)
    rng = np.random.default_rng(0)
    n = spec.n_features
    return Model(spec=spec, kind=kind, mean=rng.normal(size=n), scale=rng.random(n) + 0.5,
                 weights=rng.normal(size=7 if kind == "kernel" else n), intercept=0.4,
                 centers=rng.normal(size=(7, n)) if kind == "kernel" else None, gamma=0.01)


@pytest.mark.parametrize("kind", ["kernel", "linear"])
def test_model_file_round_trip_predicts_identically(tmp_path, kind):
    m = _model(kind=kind)
    path = save_model(m, tmp_path / "m.npz", {"hyper_parameters": {"C": 1.0}})
    back = read_model_file(path)
    X = np.random.default_rng(1).normal(size=(4, m.spec.n_features))
    np.testing.assert_array_equal(back.predict_raw(X), m.predict_raw(X))
    assert back.header["hyper_parameters"] == {"C": 1.0}
    assert "numpy" in back.header["versions"]


@pytest.mark.parametrize("kernel", ["rbf", "linear", "poly"])
def test_prediction_of_many_rows_in_blocks_is_each_row_s_own(kernel):
    """predict_raw expands PREDICT_ROWS rows at a time (no 1 GB temporaries on a held-out set):
    every row equals that row predicted alone, to the last bits BLAS rounds differently with the
    batch size (1e-12 relative; it also rounds them differently with its thread count)."""
    from incipient_slip.models.modelfile import PREDICT_ROWS
    m = _model()
    m.kernel = kernel
    X = np.random.default_rng(2).normal(size=(2 * PREDICT_ROWS + 5, m.spec.n_features))
    got = m.predict_raw(X)
    assert got.shape == (len(X),)
    alone = np.array([m.predict_raw(X[i])[0] for i in range(0, len(X), 97)])
    np.testing.assert_allclose(got[::97], alone, rtol=1e-12, atol=1e-12)


def test_model_file_holds_no_pickled_objects(tmp_path):
    path = save_model(_model(), tmp_path / "m.npz")
    with np.load(path, allow_pickle=False) as data:   # would raise on an object array
        assert set(data.files) == {"header", "mean", "scale", "weights", "intercept", "centers"}
    with zipfile.ZipFile(path) as z:
        assert all(name.endswith(".npy") for name in z.namelist())


def test_load_model_refuses_a_spec_that_does_not_match_the_stream(tmp_path):
    path = save_model(_model("e19", kind="linear"), tmp_path / "e19.npz")
    with pytest.raises(ModelFileError, match=r"feature_spec.stream is 'electrodes' but the stream has 'pac'"):
        load_model(path, stream="pac")
    with pytest.raises(ModelFileError, match="rate_hz"):
        load_model(path, rate_hz=2200)
    assert load_model(path, stream="electrodes", rate_hz=100, method="e19").method == "e19"


def test_load_model_refuses_an_edited_spec(tmp_path):
    path = save_model(_model(), tmp_path / "m.npz")
    with np.load(path) as d:
        arrays = {k: d[k] for k in d.files}
    header = json.loads(arrays["header"].tobytes())
    header["feature_spec"]["bin_hz"] = 5.0
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    np.savez(tmp_path / "edited.npz", **arrays)
    with pytest.raises(ModelFileError, match="feature_spec_hash"):
        load_model(tmp_path / "edited.npz")


def test_load_model_names_a_missing_file(tmp_path):
    with pytest.raises(ModelFileError, match="does not exist"):
        load_model(tmp_path / "nope.npz")


def test_load_model_refuses_a_file_that_is_not_a_model(tmp_path):
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    with pytest.raises(ModelFileError, match="not a model file"):
        load_model(tmp_path / "x.npz")


@pytest.mark.parametrize("seed", range(20))
def test_random_bytes_or_an_object_array_never_suggest_unpickling(tmp_path, seed):
    """numpy's own error for these advises `allow_pickle`: loading a model must never say so."""
    rng = np.random.default_rng(seed)
    path = tmp_path / "m.npz"
    if seed == 0:        # a real zip whose member is an object array (numpy: "pickled data")
        np.savez(path, header=np.array([{"a": 1}], dtype=object))
    else:
        path.write_bytes(rng.integers(0, 256, size=int(rng.integers(1, 5000)), dtype=np.uint8).tobytes())
    with pytest.raises(ModelFileError, match="not a (readable )?model file") as info:
        load_model(path)
    assert "pickle" not in str(info.value).lower()


def test_predictions_are_clipped_to_unit_interval():
    m = _model(kind="linear")
    X = np.random.default_rng(2).normal(size=(50, m.spec.n_features)) * 100
    p = m.predict(X)
    assert p.min() >= 0 and p.max() <= 1


@given(st.integers(1, 40), st.integers(1, 40), st.integers(1, 12), st.floats(1e-4, 50.0), st.integers(0, 2**32 - 1))
@settings(max_examples=60, deadline=None)
def test_rbf_of_dot_is_the_textbook_expression_bit_for_bit(n_a, n_b, dim, gamma, seed):
    """The in-place kernel gives exactly exp(-gamma * max(|a|^2 + |b|^2 - 2 a.b, 0)), duplicates
    (distance 0, rounding below 0: the clip) and far rows (underflow to 0) included."""
    rng = np.random.default_rng(seed)
    A = rng.normal(0, 3, (n_a, dim))
    B = np.vstack([A[: n_b // 2], rng.normal(0, 3, (n_b - n_b // 2, dim))])   # some exact duplicates
    ref_sq = np.einsum("ij,ij->i", A, A)[:, None] + np.einsum("ij,ij->i", B, B)[None, :] - 2.0 * (A @ B.T)
    ref = np.exp(-gamma * np.maximum(ref_sq, 0.0))
    got = rbf_of_dot(np.einsum("ij,ij->i", A, A), np.einsum("ij,ij->i", B, B), A @ B.T, gamma)
    np.testing.assert_array_equal(got, ref)
    assert np.all((got >= 0) & (got <= 1))
