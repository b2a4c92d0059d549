"""Per-window estimate latency of the six shipped models (`make bench-estimator`).

For each method: the time of `StreamingEstimator.estimate` (cut the window from the buffer,
phi, predict) against a floor of the bare minimum for that method (numpy rfft of the window for
P_AC methods / the electrode mean for electrode methods, plus the bare kernel expansion on
ready features), measured interleaved in one run; median and p99 and their ratios. Then our
array predictor against scikit-learn's SVR.predict with the same number of support vectors.
Last line: `estimator p99 ms = X`, the worst p99 over the six methods.
"""
from __future__ import annotations

import sys
import time

import numpy as np

from incipient_slip.models.estimator_core import (StreamingEstimator, default_model_path,
                                                  limit_blas_threads, load_model)
from incipient_slip.models.features import METHODS, phi
from incipient_slip.messages import PAC_RATE_HZ, PAC_SAMPLES_PER_FRAME
from incipient_slip.models.training import model_from_svr

REPS = 600


def feed(est, model, seconds=3.0, seed=0):
    """Fill the estimator with `seconds` of synthetic frames; return the last stamp (ns)."""
    rng = np.random.default_rng(seed)
    if model.spec.stream == "pac":
        n_frames = int(seconds * 100)
        for j in range(n_frames):
            stamp = int(round(((j + 1) * PAC_SAMPLES_PER_FRAME - 1) * 1e9 / PAC_RATE_HZ))
            est.push(stamp, j, rng.normal(0, 80, PAC_SAMPLES_PER_FRAME).astype(np.int16))
        return int(round(n_frames * PAC_SAMPLES_PER_FRAME * 1e9 / PAC_RATE_HZ))
    n = int(seconds * 100)
    for j in range(n):
        est.push(int(round(j * 1e7)), j, (2000 + rng.normal(0, 20, 19)).astype(np.uint16))
    return int(round(n * 1e7))


def floor_fn(model):
    spec = model.spec
    feat = phi(np.zeros(spec.window_samples) if spec.stream == "pac" else np.zeros((spec.window_samples, 19)), spec)
    if spec.stream == "pac":
        w = np.random.default_rng(1).normal(0, 80, spec.window_samples)
        return lambda: (np.fft.rfft(w), model.predict_raw(feat))
    w = np.random.default_rng(1).normal(2000, 20, (spec.window_samples, 19))
    return lambda: (w.mean(axis=0), model.predict_raw(feat))


def interleaved(a, b, reps=REPS):
    ta, tb = np.empty(reps), np.empty(reps)
    for _ in range(20):
        a(), b()
    for i in range(reps):
        t0 = time.perf_counter(); a(); t1 = time.perf_counter(); b(); t2 = time.perf_counter()
        ta[i], tb[i] = t1 - t0, t2 - t1
    return ta * 1e3, tb * 1e3


def sklearn_comparison(model, reps=REPS):
    from sklearn.svm import SVR
    n_sv = len(model.centers) if model.kind == "kernel" else 500
    d = len(model.mean)
    rng = np.random.default_rng(2)
    X = rng.normal(size=(int(n_sv * 1.1) + 10, d))
    y = rng.random(len(X))
    svr = SVR(kernel="rbf", gamma=model.gamma if model.kind == "kernel" else 1.0 / d, C=1.0,
              epsilon=0.0).fit(X, y)
    ours = model_from_svr(svr, np.zeros(d), np.ones(d), model.spec)
    x1 = rng.normal(size=(1, d))
    xb = rng.normal(size=(100, d))
    assert np.allclose(ours.predict_raw(xb), svr.predict(xb), atol=1e-8)
    o1, s1 = interleaved(lambda: ours.predict_raw(x1), lambda: svr.predict(x1), reps)
    ob, sb = interleaved(lambda: ours.predict_raw(xb), lambda: svr.predict(xb), max(50, reps // 10))
    return len(svr.support_), np.median(o1), np.median(s1), np.median(ob), np.median(sb)


def main() -> int:
    limit_blas_threads(1)   # as the estimator node does
    import os
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"estimate latency per window (ms), {REPS} calls interleaved with the floor; "
          f"{os.cpu_count()} cores, load average {load:.1f}; BLAS limited to 1 thread")
    print(f"{'method':<13}{'n_sv':>6}{'median':>9}{'p99':>9}{'floor med':>11}{'floor p99':>11}{'x med':>8}{'x p99':>8}")
    p99s = {}
    for method in METHODS:
        model = load_model(default_model_path(method))
        est = StreamingEstimator(model)
        end = feed(est, model)
        assert est.estimate(end).valid, est.estimate(end)
        t_est, t_floor = interleaved(lambda: est.estimate(end), floor_fn(model))
        n_sv = len(model.centers) if model.kind == "kernel" else 0
        med, p99 = np.median(t_est), np.percentile(t_est, 99)
        fmed, fp99 = np.median(t_floor), np.percentile(t_floor, 99)
        p99s[method] = p99
        print(f"{method:<13}{n_sv:>6}{med:>9.3f}{p99:>9.3f}{fmed:>11.3f}{fp99:>11.3f}{med / fmed:>8.2f}{p99 / fp99:>8.2f}")
    model = load_model(default_model_path("injection"))
    n_sv, o1, s1, ob, sb = sklearn_comparison(model)
    print(f"predict, {n_sv} support vectors x {len(model.mean)} features: ours {o1:.3f} ms vs sklearn SVR "
          f"{s1:.3f} ms per window (sklearn/ours = {s1 / o1:.2f}); batch of 100: ours {ob:.3f} ms vs "
          f"{sb:.3f} ms ({sb / ob:.2f})")
    print(f"estimator p99 ms = {max(p99s.values()):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
