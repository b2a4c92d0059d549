"""Estimator core: load a model file and turn a live stream into stick-ratio estimates.

The estimator node is a thin wrapper around this module:

    model = load_model(default_model_path("injection"), stream="pac", rate_hz=2200)
    est = StreamingEstimator(model)
    est.push(stamp_ns, seq, counts)                 # every /biotac/pac (or /biotac/slow) message
    stick_ratio, valid, reason = est.estimate(window_end_ns)   # every 500 ms of stamps

Frames: P_AC frames are int16 counts, 22 samples per 10 ms, stamped at their last sample;
slow frames carry the 19 electrode counts of one 10 ms frame (or (n, 19) for n frames, the last
stamped `stamp_ns`). Sample times are reconstructed backwards from the frame stamp at the
stream rate. The window ending at `window_end_ns` is the samples with stamp in
[end - T, end), exactly as `features.series_features` cuts a recorded series.

Validity: a seq gap (lost messages) or a stamp going backwards empties the buffer, and the
estimate is invalid ("seq gap" / "stamp went backwards") until T seconds of contiguous samples
have arrived again ("filling" before that); a stream whose newest sample is older than
`stale_after_ns` before the window end is "stale". Malformed frames raise `StreamError` and
leave the buffer as it was (the node counts and drops them). Nothing here blocks or sleeps.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from .features import FEATURE_CODE_VERSION, N_ELECTRODES, FeatureSpec, phi
from .modelfile import Model, ModelFileError, read_model_file

__all__ = ["Model", "ModelFileError", "StreamError", "Estimate", "StreamingEstimator",
           "load_model", "default_model_path", "estimate_window", "limit_blas_threads"]

OK, FILLING, SEQ_GAP, STALE, BACKWARDS, NO_DATA = (
    "ok", "filling", "seq gap", "stale", "stamp went backwards", "no data")


class StreamError(ValueError):
    """A frame does not fit the stream the model expects (shape, dtype, channel count)."""


class Estimate(NamedTuple):
    stick_ratio: float     # in [0, 1]; nan when invalid
    valid: bool
    reason: str            # "ok" or why the estimate is invalid


def limit_blas_threads(n: int = 1):
    """Limit BLAS/OpenMP threads of this process to n; returns the threadpoolctl controller.

    One window is a small matrix product: a multi-threaded BLAS only adds wake-up latency (and
    on a busy 2-core machine, tail latency), so the estimator node calls this once at start.
    """
    from threadpoolctl import threadpool_limits
    return threadpool_limits(limits=n)


def default_model_path(method: str) -> Path:
    """Return the shipped model file of a method: model_dir()/<method>.npz."""
    from ..paths import model_dir
    return model_dir() / f"{method}.npz"


def load_model(path: str | Path | None = None, *, method: str | None = None,
               stream: str | None = None, rate_hz: float | None = None,
               window_s: float | None = None) -> Model:
    """Return the Model in `path` (default: the shipped file of `method`), checked.

    Refuses (ModelFileError naming file, field, found and expected value) a file whose
    feature code version differs from this code's, whose stored spec hash does not match its
    spec, or whose spec does not match the given stream kind ("pac" / "electrodes"), stream
    rate, method or window length.
    """
    if path is None:
        if method is None:
            raise ModelFileError("load_model needs a path or a method")
        path = default_model_path(method)
    model = read_model_file(path)
    spec, header = model.spec, model.header
    if spec.code_version != FEATURE_CODE_VERSION:
        raise ModelFileError(f"{path}: feature_spec.code_version is {spec.code_version}, this code "
                             f"computes version {FEATURE_CODE_VERSION}; retrain (`slip reproduce models`)")
    if header.get("feature_spec_hash") != spec.spec_hash():
        raise ModelFileError(f"{path}: feature_spec_hash {header.get('feature_spec_hash')} does not "
                             f"match its feature_spec ({spec.spec_hash()}); file edited or corrupt")
    expected = {"method": method, "stream": stream, "rate_hz": rate_hz, "window_s": window_s}
    for name, want in expected.items():
        have = getattr(spec, name)
        if want is not None and (have != want if isinstance(want, str) else not np.isclose(float(have), float(want))):
            raise ModelFileError(f"{path}: feature_spec.{name} is {have!r} but the stream has "
                                 f"{want!r}; use a model trained for this stream")
    if model.kind == "kernel" and model.centers.shape[1] != spec.n_features:
        raise ModelFileError(f"{path}: centers have {model.centers.shape[1]} features, spec "
                             f"{spec.method} computes {spec.n_features}")
    if len(model.mean) != spec.n_features:
        raise ModelFileError(f"{path}: mean has {len(model.mean)} features, spec computes {spec.n_features}")
    return model


def estimate_window(model: Model, window: np.ndarray) -> float:
    """Return the stick-ratio estimate of one raw window ((N,) P_AC or (M, 19) electrodes)."""
    return float(model.predict(phi(window, model.spec))[0])


class StreamingEstimator:
    """Buffers one stream and estimates the stick ratio of the window ending at a stamp."""

    def __init__(self, model: Model, stale_after_ns: int = 50_000_000, capacity_s: float | None = None):
        self.model = model
        self.spec: FeatureSpec = model.spec
        self.rate_hz = float(self.spec.rate_hz)
        self.period_ns = 1e9 / self.rate_hz
        self.window_n = self.spec.window_samples
        self.window_ns = int(round(self.spec.window_s * 1e9))
        self.stale_after_ns = int(stale_after_ns)
        cap = self.window_n + int(round((capacity_s or 2.0) * self.rate_hz))
        self._cap = cap
        shape = (2 * cap,) if self.spec.stream == "pac" else (2 * cap, N_ELECTRODES)
        self._values = np.zeros(shape, dtype=np.float32)
        self._stamps = np.zeros(2 * cap, dtype=np.int64)
        self._n = 0
        self._last_seq: int | None = None
        self._last_stamp: int | None = None
        self._invalid_reason = FILLING
        self.gaps = 0
        self.backwards = 0

    def reset(self, reason: str = FILLING) -> None:
        """Empty the buffer; estimates are invalid with `reason` until it refills."""
        self._n = 0
        self._invalid_reason = reason

    def push(self, stamp_ns: int, seq: int, samples) -> None:
        """Add one frame (P_AC counts or electrode counts) stamped at its last sample."""
        if self.spec.stream == "pac":
            self.push_pac(stamp_ns, seq, samples)
        else:
            self.push_slow(stamp_ns, seq, samples)

    def push_pac(self, stamp_ns: int, seq: int, counts) -> None:
        """Add a P_AC frame: 1-D integer counts (22 per 10 ms frame at 2200 Hz)."""
        if self.spec.stream != "pac":
            raise StreamError(f"model {self.spec.method} reads electrodes, got a P_AC frame")
        counts = np.asarray(counts)
        if counts.ndim != 1 or counts.size == 0 or counts.dtype.kind not in "iu":
            raise StreamError(f"P_AC frame must be 1-D integer counts, got shape {counts.shape} "
                              f"dtype {counts.dtype}")
        self._append(int(stamp_ns), int(seq), counts)

    def push_slow(self, stamp_ns: int, seq: int, electrode_counts) -> None:
        """Add slow frame(s): 19 electrode counts, or (n, 19) for n consecutive frames."""
        if self.spec.stream != "electrodes":
            raise StreamError(f"model {self.spec.method} reads P_AC, got an electrode frame")
        e = np.asarray(electrode_counts)
        if e.ndim == 1:
            e = e[None]
        if e.ndim != 2 or e.shape[1] != N_ELECTRODES or e.dtype.kind not in "iuf":
            raise StreamError(f"electrode frame must hold {N_ELECTRODES} counts per frame, got "
                              f"shape {np.asarray(electrode_counts).shape}")
        if e.dtype.kind == "f" and not np.isfinite(e).all():
            raise StreamError("electrode frame holds non-finite values")
        self._append(int(stamp_ns), int(seq), e)

    def _append(self, stamp_ns: int, seq: int, values: np.ndarray) -> None:
        if self._last_seq is not None:
            if seq != self._last_seq + 1:
                self.gaps += 1
                self.reset(SEQ_GAP)
            elif stamp_ns <= self._last_stamp:
                self.backwards += 1
                self.reset(BACKWARDS)
        self._last_seq, self._last_stamp = seq, stamp_ns
        n = len(values)
        if n > self._cap:
            values, n = values[-self._cap:], self._cap
        if self._n + n > len(self._stamps):
            keep = self._cap - n
            self._values[:keep] = self._values[self._n - keep:self._n]
            self._stamps[:keep] = self._stamps[self._n - keep:self._n]
            self._n = keep
        back = np.arange(n - 1, -1, -1, dtype=np.float64) * self.period_ns
        self._stamps[self._n:self._n + n] = stamp_ns - np.round(back).astype(np.int64)
        self._values[self._n:self._n + n] = values
        self._n += n

    def window(self, window_end_ns: int) -> tuple[np.ndarray | None, str]:
        """Return (raw window, "ok") or (None, reason) for the window ending at window_end_ns."""
        if self._last_stamp is None:
            return None, NO_DATA
        if window_end_ns - self._last_stamp > self.stale_after_ns:
            return None, STALE
        stamps = self._stamps[:self._n]
        # samples sit on a grid of one period: "stamp < end" tested at end - period / 2 is immune
        # to the +-1 ns of reconstructing sample stamps from the frame stamp
        stop = int(np.searchsorted(stamps, window_end_ns - self.period_ns / 2, side="left"))
        start = stop - self.window_n
        # half a sample of slack for stamp rounding; a full window starts at end - T
        if start < 0 or stamps[start] < window_end_ns - self.window_ns - self.period_ns / 2:
            return None, self._invalid_reason
        if stop == self._n and window_end_ns - stamps[stop - 1] > 1.5 * self.period_ns:
            return None, FILLING   # the stream has not reached the window end yet
        return self._values[start:stop], OK

    def estimate(self, window_end_ns: int) -> Estimate:
        """Return (stick_ratio, valid, reason) for the window [end - T, end) of stamps."""
        w, reason = self.window(int(window_end_ns))
        if w is None:
            return Estimate(float("nan"), False, reason)
        return Estimate(float(self.model.predict(phi(w[None], self.spec))[0]), True, OK)
