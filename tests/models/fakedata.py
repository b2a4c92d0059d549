"""A tiny writer of the documented data set format (docs/design.md), for unit tests only.

Physics-lite: F_T rises with the actuator, gross slip happens at a drawn F_T^slip, the P_AC
band amplitude near 200 Hz falls linearly with F_T (injection on) and the electrodes follow
F_N and F_T. Enough to check the pipeline end to end without the simulator.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy import signal

MATERIALS = ("pla", "abs", "tpu", "wood", "rubber")


def write_fake_dataset(out: Path, n_series: int = 10, n_periods: int = 40, injection: bool = True,
                       seed: int = 0) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"format": "incipient-slip-dataset", "version": 1, "scene": "fake", "scene_yaml": "",
            "seed": seed, "n_series": n_series, "materials": list(MATERIALS),
            "injection": injection, "pac_rate_hz": 2200, "slow_rate_hz": 100,
            "mocap_rate_hz": 120, "period_s": 0.5, "steps": n_periods,
            "pac_pa_per_count": 0.37, "pdc_pa_per_count": 36.5, "created_by": "tests fake"}
    (out / "meta.json").write_text(json.dumps(meta))
    sos_lo = signal.butter(2, [150, 260], btype="bandpass", fs=2200, output="sos")
    sos_hi = signal.butter(2, [500, 800], btype="bandpass", fs=2200, output="sos")
    for i in range(n_series):
        rng = np.random.default_rng([seed, i])
        period_end = 0.5 * np.arange(1, n_periods + 1)
        fn = rng.choice(np.arange(1.1, 6.0, 0.4), size=n_periods)
        slip_k = int(rng.integers(int(0.6 * n_periods), n_periods - 3))
        ft = np.linspace(0.0, 1.0, n_periods) * (n_periods - 1) / slip_k * 2.0
        ft_slip = ft[slip_k]
        s_true = np.clip(1 - ft / ft_slip, 0, 1)
        s_true[slip_k:] = 0
        y_end = np.where(np.arange(n_periods) < slip_k, 0.005 * np.arange(n_periods),
                         0.005 * slip_k + 0.2 * (np.arange(n_periods) - slip_k + 1))
        n_pac = int(period_end[-1] * 2200)
        t_pac = np.arange(n_pac) / 2200
        k_of = np.minimum(np.searchsorted(period_end, t_pac, side="right"), n_periods - 1)
        s_at = s_true[k_of]
        gain = 20.0 * (0.3 + s_at) if injection else 1.0 + 0.5 * rng.random(n_pac)
        lo = signal.sosfilt(sos_lo, rng.standard_normal(n_pac)) * gain
        hi = signal.sosfilt(sos_hi, rng.standard_normal(n_pac)) * 10.0
        pac = np.clip(np.round(lo + hi + rng.normal(0, 2, n_pac)), -2000, 2000).astype(np.int16)
        n_slow = int(period_end[-1] * 100)
        k_slow = np.minimum(np.searchsorted(period_end, np.arange(n_slow) / 100, side="right"), n_periods - 1)
        base = 2000 + 100 * fn[k_slow][:, None] * np.linspace(0.5, 1.5, 19)[None, :]
        elec = base + 80 * (1 - s_true[k_slow])[:, None] * np.linspace(-1, 1, 19)[None, :]
        elec = np.clip(elec + rng.normal(0, 8, elec.shape), 0, 4095).astype(np.uint16)
        mt = np.arange(0, period_end[-1], 1 / 120)
        my = np.interp(mt, np.concatenate([[0], period_end]), np.concatenate([[0], y_end]))
        my = my + rng.normal(0, 0.002, len(mt))
        np.savez(out / f"series_{i:05d}.npz", pac_counts=pac, electrode_counts=elec,
                 pdc_counts=np.zeros(n_slow, np.uint16), tac_counts=np.zeros(n_slow, np.uint16),
                 tdc_counts=np.zeros(n_slow, np.uint16), mocap_t_s=mt, mocap_y_mm=my,
                 period_end_s=period_end, normal_force_kpa=fn, tangential_force_n=ft,
                 actuator_mm=np.arange(n_periods) * 23 / 450, object_y_mm=y_end,
                 stick_area_ratio=s_true ** (2 / 3), load_ratio_stick=s_true,
                 gross_slip=np.arange(n_periods) >= slip_k, material=np.array(MATERIALS[i % 5]),
                 injection=np.array(injection),
                 seed=np.array(seed * 1_000_003 + i, np.int64))   # per series, from the set's seed as in real sets
    return out
