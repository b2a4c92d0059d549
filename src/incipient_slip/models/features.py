"""Feature functions phi for the six methods, vectorized over windows.

Two kinds of stream and two kinds of phi:

* **P_AC spectrum** (methods `injection`, `vibrotactile`): a window of T seconds of P_AC counts
  (2200 Hz) -> remove the window mean -> Hann taper -> `numpy.fft.rfft` -> magnitude scaled to
  an amplitude in counts (|X| * 2 / sum(taper)) -> keep the band 10-1100 Hz -> average the
  magnitude in bins of `bin_hz` (10 Hz: 109 features at T = 1 s) -> log10(amplitude + 1e-3).
  Why bins: under white-noise injection each raw FFT bin is a chi-distributed estimate with
  ~50 % relative scatter; averaging 10 bins (10 Hz at 1 Hz resolution) cuts that by ~3x and the
  feature count by 10x, and the structural modes the contact shifts are tens of Hz wide. Why
  log: the modal response spans decades and contact changes it multiplicatively, so log
  amplitudes make those changes additive and comparable across bands (an SVR with an RBF
  kernel on standardized log amplitudes). The 1e-3 count floor only guards log(0).
* **Electrode time average** (methods `e19`, `e10`, `e4`, `e1`): the mean of the raw 12-bit
  counts of the chosen electrodes over the window (100 Hz frames).

Electrode subsets (1-based BioTac numbers). The paper sparsifies "at equal intervals": E10 takes
every other electrode (`linspace(1, 19, 10)` = E1, E3, ..., E19), E4 takes `round(linspace(1,
19, 4))` = E1, E7, E13, E19, and E1 is the single electrode "in the center": we take E17, the
pad-midline electrode (y = 0 on the contact face, z = -5.08 mm) nearest the centroid of the 19
electrode positions, i.e. the one under the middle of the contact patch.

A window ends at `end` and holds the samples with time in [end - T, end): for a stream at rate
r whose sample i is at i / r, that is indices round(end * r) - round(T * r) ... round(end * r) - 1.
The estimator core uses the same convention on message stamps.

Everything that changes phi is in `FeatureSpec`; its `spec_hash` (with FEATURE_CODE_VERSION,
bumped whenever this file changes what phi computes) is stored in every model file.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, replace
from functools import lru_cache

import numpy as np

from incipient_slip.messages import ELECTRODE_COUNT as N_ELECTRODES
from incipient_slip.messages import METHODS as WIRE_METHODS
from incipient_slip.messages import PAC_RATE_HZ, SLOW_RATE_HZ

FEATURE_CODE_VERSION = 1
LOG_FLOOR_COUNTS = 1e-3

METHODS = tuple(m for m in WIRE_METHODS if m != "none")    # the six estimation methods

ELECTRODE_SUBSETS = {
    "e19": tuple(range(1, 20)),
    "e10": tuple(int(v) for v in np.linspace(1, 19, 10).round()),
    "e4": tuple(int(v) for v in np.linspace(1, 19, 4).round()),
    "e1": (17,),
}


@dataclass(frozen=True)
class FeatureSpec:
    """Everything that defines phi for one method (stored in model files as JSON)."""

    method: str
    stream: str                       # "pac" or "electrodes"
    rate_hz: int
    window_s: float = 1.0
    band_hz: tuple = (10.0, 1100.0)   # spectrum only
    bin_hz: float = 10.0              # spectrum only
    log10: bool = True                # spectrum only
    taper: str = "hann"               # spectrum only
    electrodes: tuple = ()            # electrodes only, 1-based
    injection: bool | None = None     # which P_AC data the method expects (None for electrodes)
    code_version: int = FEATURE_CODE_VERSION

    @property
    def window_samples(self) -> int:
        return int(round(self.window_s * self.rate_hz))

    @property
    def n_features(self) -> int:
        if self.stream == "electrodes":
            return len(self.electrodes)
        return spectrum_bin_matrix(self.window_samples, self.rate_hz, tuple(self.band_hz),
                                   self.bin_hz).shape[1]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["band_hz"] = list(self.band_hz)
        d["electrodes"] = list(self.electrodes)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "FeatureSpec":
        d = dict(d)
        d["band_hz"] = tuple(float(v) for v in d.get("band_hz", (10.0, 1100.0)))
        d["electrodes"] = tuple(int(v) for v in d.get("electrodes", ()))
        known = {f for f in cls.__dataclass_fields__}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"feature spec has unknown fields {sorted(unknown)}")
        return cls(**d)

    def spec_hash(self) -> str:
        """Return a 16-hex hash of the canonical JSON of this spec."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def feature_spec(method: str, window_s: float = 1.0, **overrides) -> FeatureSpec:
    """Return the default FeatureSpec of a method (the paper's), with optional overrides."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if method in ("injection", "vibrotactile"):
        spec = FeatureSpec(method=method, stream="pac", rate_hz=PAC_RATE_HZ, window_s=window_s,
                           injection=(method == "injection"))
    else:
        spec = FeatureSpec(method=method, stream="electrodes", rate_hz=SLOW_RATE_HZ,
                           window_s=window_s, band_hz=(), bin_hz=0.0, log10=False, taper="",
                           electrodes=ELECTRODE_SUBSETS[method])
    return replace(spec, **overrides) if overrides else spec


@lru_cache(maxsize=64)
def spectrum_bin_matrix(n_samples: int, rate_hz: float, band_hz: tuple, bin_hz: float) -> np.ndarray:
    """Return the (n_rfft, n_bins) float32 matrix that averages rfft bins into feature bins.

    Bins are [lo + j*bin_hz, lo + (j+1)*bin_hz) within [lo, hi] (the last bin ends at hi
    inclusive); a bin with no FFT line (window too short for that resolution) is dropped.
    """
    freqs = np.fft.rfftfreq(n_samples, 1.0 / rate_hz)
    lo, hi = float(band_hz[0]), float(band_hz[1])
    if not 0 <= lo < hi:
        raise ValueError(f"band {band_hz} Hz: need 0 <= low < high")
    if bin_hz <= 0:
        raise ValueError(f"bin width {bin_hz} Hz must be > 0")
    n_bins = int(np.ceil((hi - lo) / bin_hz - 1e-9))
    in_band = (freqs >= lo) & (freqs <= hi)
    which = np.minimum(((freqs - lo) // bin_hz).astype(np.int64), n_bins - 1)
    matrix = np.zeros((len(freqs), n_bins), dtype=np.float64)
    rows = np.flatnonzero(in_band)
    matrix[rows, which[rows]] = 1.0
    counts = matrix.sum(axis=0)
    matrix = matrix[:, counts > 0] / counts[counts > 0]
    if matrix.shape[1] == 0:
        raise ValueError(f"band {band_hz} Hz has no FFT line at {n_samples} samples / {rate_hz} Hz")
    return matrix.astype(np.float32)


@lru_cache(maxsize=16)
def _taper(n_samples: int, kind: str) -> np.ndarray:
    if kind == "hann":
        w = np.hanning(n_samples)
    elif kind in ("", "none", "boxcar"):
        w = np.ones(n_samples)
    else:
        raise ValueError(f"taper {kind!r} unknown (hann or none)")
    return (w * (2.0 / w.sum())).astype(np.float32)


def phi_spectrum(windows: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """Return (n_windows, n_bins) float32 log10 band amplitudes of P_AC windows (n, N) counts."""
    windows = np.asarray(windows, dtype=np.float32)
    if windows.ndim == 1:
        windows = windows[None, :]
    n = spec.window_samples
    if windows.shape[1] != n:
        raise ValueError(f"P_AC window has {windows.shape[1]} samples, spec {spec.method} "
                         f"needs {n} ({spec.window_s} s at {spec.rate_hz} Hz)")
    return _binned(_magnitudes(windows, spec.taper), spec)


def _magnitudes(windows: np.ndarray, taper: str) -> np.ndarray:
    """Return the float32 rfft magnitudes of float32 windows, each demeaned and tapered: the
    part of phi_spectrum that depends only on the window length and taper."""
    x = windows - windows.mean(axis=1, keepdims=True)
    x *= _taper(windows.shape[1], taper)
    return np.abs(np.fft.rfft(x, axis=1)).astype(np.float32)


def _binned(mag: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """Return phi from `_magnitudes`: the spec's bins of its band, log10 when the spec says."""
    amp = mag @ spectrum_bin_matrix(spec.window_samples, spec.rate_hz, tuple(spec.band_hz), spec.bin_hz)
    return np.log10(amp + LOG_FLOOR_COUNTS) if spec.log10 else amp


def phi_electrodes(windows: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """Return (n_windows, n_electrodes) float32 time averages of electrode windows (n, M, 19)."""
    windows = np.asarray(windows)
    if windows.ndim == 2:
        windows = windows[None]
    if windows.shape[2] != N_ELECTRODES:
        raise ValueError(f"electrode window has {windows.shape[2]} channels, expected {N_ELECTRODES}")
    idx = np.asarray(spec.electrodes) - 1
    return windows[:, :, idx].astype(np.float64).mean(axis=1).astype(np.float32)


def phi(windows: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """Return phi of raw windows for the spec's method (dispatch on the stream kind)."""
    return phi_spectrum(windows, spec) if spec.stream == "pac" else phi_electrodes(windows, spec)


def window_stops(end_s: np.ndarray, rate_hz: float) -> np.ndarray:
    """Return the exclusive stop index of the window ending at each time (samples < end)."""
    return np.round(np.asarray(end_s, dtype=np.float64) * rate_hz).astype(np.int64)


def valid_window_mask(end_s: np.ndarray, spec: FeatureSpec, n_stream_samples: int) -> np.ndarray:
    """Return which window ends have a full window inside a stream of n samples."""
    stops = window_stops(end_s, spec.rate_hz)
    return (stops - spec.window_samples >= 0) & (stops <= n_stream_samples)


def series_features(series, spec: FeatureSpec, end_s: np.ndarray | None = None,
                    chunk: int = 512) -> np.ndarray:
    """Return phi for windows of one series ending at end_s (default: every period end).

    The caller keeps only valid windows (`valid_window_mask`); an invalid end raises.
    """
    return series_feature_sets(series, [spec], end_s, chunk)[0]


def series_feature_sets(series, specs, end_s: np.ndarray | None = None, chunk: int = 512) -> list[np.ndarray]:
    """Return `series_features` of each spec on the same window ends. P_AC specs that differ
    only after the FFT (bins, band, log) share one FFT of each window: the same floats as one
    spec at a time, for a fraction of the work (a sweep of bin widths and bands)."""
    end_s = series.period_end_s if end_s is None else np.asarray(end_s)
    out: list = [None] * len(specs)
    same_fft: dict = {}
    for i, spec in enumerate(specs):
        if spec.stream == "pac":
            same_fft.setdefault((spec.rate_hz, spec.window_samples, spec.taper), []).append(i)
        else:
            out[i] = _electrode_features(series, spec, end_s)
    for (rate_hz, n, taper), idx in same_fft.items():
        stops = window_stops(end_s, rate_hz)
        stream = series.pac_counts
        if (stops - n < 0).any() or (stops > len(stream)).any():
            raise ValueError("window outside the P_AC stream; filter with valid_window_mask")
        for i in idx:
            out[i] = np.empty((len(stops), specs[i].n_features), dtype=np.float32)
        windows = np.lib.stride_tricks.sliding_window_view(stream, n)    # a view: row i = stream[i:i + n]
        for a in range(0, len(stops), chunk):
            mag = _magnitudes(np.asarray(windows[stops[a:a + chunk] - n], dtype=np.float32), taper)
            for i in idx:
                out[i][a:a + chunk] = _binned(mag, specs[i])
    return out


def _electrode_features(series, spec: FeatureSpec, end_s: np.ndarray) -> np.ndarray:
    stops = window_stops(end_s, spec.rate_hz)
    n = spec.window_samples
    counts = series.electrode_counts
    if (stops - n < 0).any() or (stops > len(counts)).any():
        raise ValueError("window outside the electrode stream; filter with valid_window_mask")
    idx = np.asarray(spec.electrodes) - 1
    csum = np.concatenate([np.zeros((1, len(idx))), np.cumsum(counts[:, idx].astype(np.float64), axis=0)])
    return ((csum[stops] - csum[stops - n]) / n).astype(np.float32)
