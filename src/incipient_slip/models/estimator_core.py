"""Estimator core: load a model file and turn a live stream into stick-ratio estimates.

The estimator node is a thin wrapper around this module:

    model = load_model(default_model_path("injection"), stream="pac", rate_hz=2200)
    est = StreamingEstimator(model)
    est.push(stamp_ns, seq, counts)                 # every /biotac/pac (or /biotac/slow) message
    stick_ratio, valid, reason = est.estimate(window_end_ns)   # every 500 ms of stamps

`PeriodEstimator` adds the scheduling the node needs: which period boundaries a frame makes
due, catch-up over holes, resync after stamp jumps, the wall-clock watchdog.

Frames: P_AC frames are int16 counts, 22 samples per 10 ms, stamped at their last sample;
slow frames carry the 19 electrode counts of one 10 ms frame (or (n, 19) for n frames, the last
stamped `stamp_ns`). Sample times are reconstructed backwards from the frame stamp at the
stream rate; they are kept as int64 offsets from the buffer's first frame, so any uint64 stamp
works. The window ending at `window_end_ns` is the samples with stamp in
[end - T, end), exactly as `features.series_features` cuts a recorded series.

Validity: a seq gap (lost messages) or a stamp going backwards empties the buffer, and the
estimate is invalid ("seq gap" / "stamp went backwards") until T seconds of contiguous samples
have arrived again ("filling" before that); a stream whose newest sample is older than
`stale_after_ns` before the window end is "stale". Malformed frames raise `StreamError` and
leave the buffer as it was (the node counts and drops them). Nothing here blocks or sleeps.
"""
from __future__ import annotations

import time
from collections import deque
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..messages import PAC_SAMPLES_PER_FRAME, PERIOD_NS
from .features import FEATURE_CODE_VERSION, N_ELECTRODES, FeatureSpec, phi
from .modelfile import Model, ModelFileError, read_model_file

__all__ = ["Model", "ModelFileError", "StreamError", "Estimate", "StreamingEstimator",
           "PeriodEstimate", "PeriodEstimator", "load_model", "default_model_path", "estimate_window", "limit_blas_threads"]

MAX_STAMP_NS = (1 << 64) - 1   # stamps are uint64 on the wire
MAX_CATCH_UP = 20          # boundaries estimated at once after a hole; beyond it, resynchronize
_MAX_REL_NS = 1 << 62      # buffer stamps are int64 offsets from the buffer's first frame
OK, FILLING, SEQ_GAP, STALE, BACKWARDS, NO_DATA = (
    "ok", "filling", "seq gap", "stale", "stamp went backwards", "no data")
# each of the stream's reasons as the closed set the wire carries (messages.ESTIMATE_CAUSES)
CAUSE_OF_REASON = {OK: "ok", FILLING: "filling", SEQ_GAP: "seq_gap", STALE: "stale", BACKWARDS: "backwards",
                   NO_DATA: "no_data"}


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


def default_model_path(method: str, label: str = "pseudo") -> Path:
    """Return the shipped model file of a method trained on `label`: model_dir()/<method>.npz for the
    paper's pseudo label, model_dir()/<label>/<method>.npz for another (docs/estimation.md)."""
    from ..paths import model_dir
    from .labels import LabelRule
    LabelRule(label)                                  # an unknown label is named here
    return model_dir() / f"{method}.npz" if label == "pseudo" else model_dir() / label / f"{method}.npz"


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
    if Path(path).is_dir():
        raise ModelFileError(f"model file {path} is a directory; give a model file in it "
                             f"(e.g. {Path(path) / 'injection.npz'})")
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
            hint = f" (it is a model of method {spec.method!r}: method:={spec.method})" if name == "method" else ""
            raise ModelFileError(f"{path}: feature_spec.{name} is {have!r} but the stream has "
                                 f"{want!r}; use a model trained for this stream{hint}")
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
        self._origin_ns = 0               # stamp that buffer stamp 0 stands for
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
        # Sample stamps are kept relative to the buffer's first frame, so that any uint64 stamp
        # (up to 2^64 - 1) fits the int64 buffer; a jump of centuries starts the buffer afresh.
        if self._n == 0 or stamp_ns - self._origin_ns > _MAX_REL_NS:
            self._n, self._origin_ns = 0, stamp_ns
        n = len(values)
        if n > self._cap:
            values, n = values[-self._cap:], self._cap
        if self._n + n > len(self._stamps):
            keep = self._cap - n
            self._values[:keep] = self._values[self._n - keep:self._n]
            self._stamps[:keep] = self._stamps[self._n - keep:self._n]
            self._n = keep
        back = np.arange(n - 1, -1, -1, dtype=np.float64) * self.period_ns
        self._stamps[self._n:self._n + n] = (stamp_ns - self._origin_ns) - np.round(back).astype(np.int64)
        self._values[self._n:self._n + n] = values
        self._n += n

    def window(self, window_end_ns: int) -> tuple[np.ndarray | None, str]:
        """Return (raw window, "ok") or (None, reason) for the window ending at window_end_ns."""
        if self._last_stamp is None:
            return None, NO_DATA
        if window_end_ns - self._last_stamp > self.stale_after_ns:
            return None, STALE
        stamps = self._stamps[:self._n]
        window_end_ns -= self._origin_ns          # relative, as the buffer's stamps
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


class PeriodEstimate(NamedTuple):
    """The estimate of period k: the window [B - T, B) ending at the boundary B = (k+1) period."""

    period: int
    window_end_ns: int
    stick_ratio: float
    valid: bool
    reason: str
    latency_ns: int        # time spent computing it
    cause: str = "unknown"  # the reason as one of messages.ESTIMATE_CAUSES


class PeriodEstimator:
    """Schedules one estimate per period boundary from the frames' stamps (the estimator node's core).

    Each `frame()` returns the estimates that became due: every boundary B <= the frame's last
    sample gets exactly one estimate, in order. Boundaries a hole in the stream skipped are
    estimated (invalid) with the data before them, up to MAX_CATCH_UP at once; a longer jump of
    the stamps, or a stamp going backwards (the source restarted its clock), resynchronizes at
    the new stamps. A seq gap (`gap()`) empties the buffer, so no estimate is valid until a full
    window has arrived after it. `tick(now_s)` is the wall-clock watchdog: after
    `wall_timeout_s` without a frame it gives one invalid "stale" estimate for the next boundary
    and empties the buffer. A PZT state that contradicts the model (`pzt()`) makes estimates
    invalid. Frames that do not fit the stream are refused and counted; nothing raises.
    """

    def __init__(self, model: Model, period_ns: int = PERIOD_NS, stale_after_ns: int = 50_000_000,
                 wall_timeout_s: float = 0.0):
        self.stream = StreamingEstimator(model, stale_after_ns=stale_after_ns)
        self.method = model.spec.method
        self.injection = model.spec.injection
        self.period_ns = int(period_ns)
        sample_ns = 1e9 / model.spec.rate_hz
        self.half_sample_ns = int(sample_ns // 2)
        self.frame_span_ns = round(((PAC_SAMPLES_PER_FRAME if model.spec.stream == "pac" else 1) - 1)
                                   * sample_ns)
        self.complete_ns = int(1.5 * sample_ns)   # a frame ending within this of B completes it
        self.wall_timeout_s = wall_timeout_s
        self.next_end_ns: int | None = None   # the next boundary B to estimate
        self.last_stamp_ns: int | None = None
        self.last_frame_s: float | None = None
        self.stalled = False
        self.pzt_problem = ""
        self.published = self.invalid = self.refused = self.resyncs = 0
        self.latencies_ns: deque = deque(maxlen=10_000)   # the newest, for the shutdown line

    def gap(self) -> None:
        """Messages were lost (seq gap): empty the buffer before the next frame goes in."""
        self.stream.reset(SEQ_GAP)

    def pzt(self, enabled: bool) -> str:
        """Records the PZT state; returns the contradiction with the model ("" when none)."""
        if self.injection is None or enabled == self.injection:
            self.pzt_problem = ""
        else:
            self.pzt_problem = (f"PZT is {'on' if enabled else 'off'} but the {self.method} model "
                                f"was trained with injection {'on' if self.injection else 'off'}")
        return self.pzt_problem

    def frame(self, stamp_ns: int, seq: int, samples, now_s: float) -> tuple[list[PeriodEstimate], str]:
        """Return (estimates now due, warning or "") after one frame stamped at its last sample."""
        if stamp_ns > MAX_STAMP_NS - self.period_ns:
            self.refused += 1
            return [], f"refused frame seq {seq}: stamp {stamp_ns} leaves no period boundary below 2^64"
        self.last_frame_s, self.stalled = now_s, False
        first_ns = stamp_ns - self.frame_span_ns
        if self.next_end_ns is None or stamp_ns <= self.last_stamp_ns:
            # first frame, or the source restarted its clock: the next boundary after this frame
            self.next_end_ns = max(first_ns // self.period_ns + 1, 1) * self.period_ns
        self.last_stamp_ns = stamp_ns
        out, warning = self._until(first_ns + self.half_sample_ns)   # boundaries before it (a hole)
        try:
            self.stream.push(stamp_ns, seq, samples)
        except StreamError as exc:
            self.refused += 1
            return out, f"refused frame seq {seq}: {exc}"
        more, jumped = self._until(stamp_ns + self.complete_ns)       # boundaries it completes
        return out + more, warning or jumped

    def tick(self, now_s: float) -> list[PeriodEstimate]:
        """The watchdog: one invalid "stale" estimate once no frame came for wall_timeout_s."""
        if (self.wall_timeout_s <= 0 or self.last_frame_s is None or self.stalled
                or now_s - self.last_frame_s < self.wall_timeout_s):
            return []
        self.stalled = True
        self.stream.reset(STALE)
        out = [self._estimate(self.next_end_ns, f"{STALE}: no frame for {self.wall_timeout_s} s", "stale")]
        self.next_end_ns += self.period_ns
        return out

    def _until(self, limit_ns: int) -> tuple[list[PeriodEstimate], str]:
        due = (limit_ns - self.next_end_ns) // self.period_ns + 1
        warning = ""
        if due > MAX_CATCH_UP:
            self.resyncs += 1
            warning = f"stamps jumped {due - 1} periods ahead; resynchronizing"
            self.stream.reset(STALE)
            self.next_end_ns += (due - 1) * self.period_ns
        out = []
        while self.next_end_ns <= limit_ns:
            out.append(self._estimate(self.next_end_ns))
            self.next_end_ns += self.period_ns
        return out, warning

    def _estimate(self, end_ns: int, reason: str = "", cause: str = "unknown") -> PeriodEstimate:
        t = time.perf_counter_ns()
        if reason:
            ratio, valid = float("nan"), False
        else:
            ratio, valid, reason = self.stream.estimate(end_ns)
            cause = CAUSE_OF_REASON.get(reason, "unknown")
            if valid and self.pzt_problem:
                ratio, valid, reason, cause = float("nan"), False, self.pzt_problem, "pzt_mismatch"
        latency = time.perf_counter_ns() - t
        self.latencies_ns.append(latency)
        self.published += 1
        self.invalid += not valid
        return PeriodEstimate(end_ns // self.period_ns - 1, end_ns, ratio, valid, reason, latency, cause)
