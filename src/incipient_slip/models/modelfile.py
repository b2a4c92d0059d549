"""Model files: arrays plus a JSON header in one `.npz`, never a pickle.

Every regressor we ship reduces to one of two closed forms on standardized features
z = (phi - mean) / scale:

* `kernel`: f(z) = sum_j w_j k(z, c_j) + b, with k rbf / linear / poly. An exact SVR stores its
  support vectors as centres c_j and dual coefficients as w_j; a Nystroem + linear model stores
  its landmark points as centres and w = N^T beta (normalization matrix N, linear weights beta),
  which is the same expansion.
* `linear`: f(z) = w . z + b.

The estimate is clipped to [0, 1] (a stick ratio); `predict_raw` gives the unclipped value.

File layout (`numpy.savez_compressed`, loaded with `allow_pickle=False`): `header` is the UTF-8
JSON as a uint8 array; `mean`, `scale`, `weights`, `intercept` and (kernel) `centers` are
float64 arrays. The header holds method, feature spec (+ hash), kind and kernel parameters,
hyper-parameters, training data hash, metrics and library versions.
"""
from __future__ import annotations

import json
import platform
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..paths import written_atomically
from .features import FeatureSpec

MODEL_FORMAT = "incipient-slip-model"
MODEL_VERSION = 1
PREDICT_ROWS = 2048      # rows per kernel expansion in predict_raw


class ModelFileError(ValueError):
    """A model file is missing, malformed, or does not fit the stream; the message says which."""


@dataclass
class Model:
    """A trained slip model f: arrays plus its header; prediction straight from the arrays."""

    spec: FeatureSpec
    kind: str                     # "kernel" or "linear"
    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray
    intercept: float
    centers: np.ndarray | None = None
    kernel: str = "rbf"
    gamma: float = 1.0
    coef0: float = 0.0
    degree: int = 3
    header: dict = field(default_factory=dict)

    def __post_init__(self):
        self.mean = np.ascontiguousarray(self.mean, dtype=np.float64)
        self.scale = np.ascontiguousarray(self.scale, dtype=np.float64)
        self.weights = np.ascontiguousarray(self.weights, dtype=np.float64).ravel()
        self._inv_scale = 1.0 / self.scale
        if self.kind == "kernel":
            self.centers = np.ascontiguousarray(self.centers, dtype=np.float64)
            self._center_sq = np.einsum("ij,ij->i", self.centers, self.centers)
        elif self.kind != "linear":
            raise ModelFileError(f"model kind {self.kind!r} unknown (kernel or linear)")

    @property
    def method(self) -> str:
        return self.spec.method

    def predict_raw(self, features: np.ndarray) -> np.ndarray:
        """Return the unclipped regression output for (n, n_features) features.

        Many rows go through the kernel expansion PREDICT_ROWS at a time: a held-out set of 22 000
        windows against 7000 support vectors would otherwise make several 1.2 GB temporaries
        (4x slower, docs/performance.md). Each row's value is its own; BLAS rounds the last bits
        of a few rows differently with the batch's size (as it does with its thread count)."""
        z = (np.atleast_2d(np.asarray(features, dtype=np.float64)) - self.mean) * self._inv_scale
        if z.shape[1] != len(self.mean):
            raise ModelFileError(f"model {self.method} expects {len(self.mean)} features, got {z.shape[1]}")
        if self.kind == "linear":
            return z @ self.weights + self.intercept
        if len(z) > PREDICT_ROWS:
            return np.concatenate([self._expand(z[a:a + PREDICT_ROWS]) for a in range(0, len(z), PREDICT_ROWS)])
        return self._expand(z)

    def _expand(self, z: np.ndarray) -> np.ndarray:
        dot = z @ self.centers.T
        if self.kernel == "rbf":
            k = rbf_of_dot(np.einsum("ij,ij->i", z, z), self._center_sq, dot, self.gamma)
        elif self.kernel == "linear":
            k = dot
        elif self.kernel == "poly":
            k = (self.gamma * dot + self.coef0) ** self.degree
        else:
            raise ModelFileError(f"kernel {self.kernel!r} unknown")
        return k @ self.weights + self.intercept

    def predict(self, features: np.ndarray) -> np.ndarray:
        """Return the stick-ratio estimate in [0, 1] for (n, n_features) features."""
        return np.clip(self.predict_raw(features), 0.0, 1.0)


def rbf_of_dot(a_sq: np.ndarray, b_sq: np.ndarray, dot: np.ndarray, gamma: float) -> np.ndarray:
    """Return exp(-gamma * max(|a|^2 + |b|^2 - 2 a.b, 0)) for every row pair, given `dot` = A @ B.T
    (overwritten): the same floats as that expression, in two arrays instead of seven (the
    expansion of a held-out set is memory-bound)."""
    sq = np.add.outer(a_sq, b_sq)
    dot *= 2.0                                   # exact: a power of two
    sq -= dot
    np.maximum(sq, 0.0, out=sq)
    sq *= -gamma
    return np.exp(sq, out=sq)


def _versions() -> dict:
    import scipy
    import sklearn
    return {"python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "scikit-learn": sklearn.__version__}


def save_model(model: Model, path: str | Path, extra_header: dict | None = None) -> Path:
    """Write a model file; returns the path. The header gains format, spec and versions."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = dict(model.header)
    header.update(extra_header or {})
    header.update({
        "format": MODEL_FORMAT, "version": MODEL_VERSION, "method": model.method,
        "feature_spec": model.spec.to_dict(), "feature_spec_hash": model.spec.spec_hash(),
        "kind": model.kind, "kernel": model.kernel, "gamma": model.gamma, "coef0": model.coef0,
        "degree": model.degree, "intercept": model.intercept,
    })
    header.setdefault("versions", _versions())
    arrays = {"mean": model.mean, "scale": model.scale, "weights": model.weights,
              "intercept": np.array([model.intercept])}
    if model.kind == "kernel":
        arrays["centers"] = model.centers
    text = json.dumps(header, sort_keys=True, indent=1, default=_json_default)
    arrays["header"] = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    with written_atomically(path) as tmp, open(tmp, "wb") as f:     # a file: numpy adds no .npz to it
        np.savez_compressed(f, **arrays)
    model.header = header
    return path


def _json_default(obj):
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")    # a zip's first local header, or an empty zip


def read_model_file(path: str | Path) -> Model:
    """Return the Model stored in a file, without checking it against any stream."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"model file {path} does not exist (train one with `slip train` "
                             "or regenerate the shipped ones with `slip reproduce models`)")
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic not in _ZIP_MAGIC:     # np.load would try it as .npy, then as a pickle
        raise ModelFileError(f"{path}: not a model file (a model file is a .npz zip archive, as "
                             f"`slip train` writes; this file starts with {magic!r})")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as exc:  # zip/npz errors come in many types
        # numpy's text may advise unpickling (allow_pickle): a model file never holds objects
        why = ("it holds object arrays, which a model file never does" if "pickle" in str(exc)
               else f"{type(exc).__name__}: {exc}")
        raise ModelFileError(f"{path}: not a readable model file ({why})") from None
    if "header" not in arrays:
        raise ModelFileError(f"{path}: no 'header' array; not an incipient-slip model file")
    try:
        header = json.loads(arrays["header"].tobytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"{path}: header is not UTF-8 JSON ({exc})") from None
    if header.get("format") != MODEL_FORMAT or header.get("version") != MODEL_VERSION:
        raise ModelFileError(f"{path}: format {header.get('format')!r} version "
                             f"{header.get('version')!r}, expected {MODEL_FORMAT!r} {MODEL_VERSION}")
    try:
        spec = FeatureSpec.from_dict(header["feature_spec"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: feature_spec invalid ({exc})") from None
    for key in ("mean", "scale", "weights", "intercept"):
        if key not in arrays:
            raise ModelFileError(f"{path}: missing array {key!r}")
    return Model(spec=spec, kind=header["kind"], mean=arrays["mean"], scale=arrays["scale"],
                 weights=arrays["weights"], intercept=float(arrays["intercept"][0]),
                 centers=arrays.get("centers"), kernel=header.get("kernel", "rbf"),
                 gamma=float(header.get("gamma", 1.0)), coef0=float(header.get("coef0", 0.0)),
                 degree=int(header.get("degree", 3)), header=header)
