"""Writes tests/data/demo.mcap: 2 s of a synthetic rig, the recording `launch demo.yaml` replays.

    .venv/bin/python tests/data/make_demo_mcap.py [OUT.mcap]

The signals are synthetic (numpy, seeded), not the simulator's: band-limited white noise on
P_AC while the PZT injects (10-1100 Hz in the paper; the band stops at 1000 Hz here, below Nyquist), a P_DC ramp as the finger presses, the
object creeping then slipping along the rail, and the actuator stepping every 500 ms. They
only exercise the graph; they say nothing about the physics. Stamps start at 0 and follow the
time base of docs/design.md (P_AC frames every 10 ms stamped at their last sample, slow
channels 100 Hz, mocap 120 Hz, periods of 500 ms). The output is byte-for-byte reproducible.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy import signal

from incipient_slip.messages import (PAC_SAMPLES_PER_FRAME, ActuatorState, BiotacPac, BiotacSlow,
                                     ObjectPose, PztState)
from incipient_slip.graph.bag import BagWriter

DURATION_S = 2.0
PAC_HZ, SLOW_HZ, MOCAP_HZ, PERIOD_S = 2200, 100, 120, 0.5
LOG_EPOCH_NS = 1_700_000_000_000_000_000   # fixed "receive" clock so the file is reproducible
LOG_LATENCY_NS = 200_000                    # a plausible 0.2 ms from stamp to recorder


def messages(seed: int = 0):
    """(stamp_ns, topic, message) of the whole recording, unsorted."""
    rng = np.random.default_rng(seed)
    n_pac = int(DURATION_S * PAC_HZ)
    sos = signal.butter(4, [10, 1000], btype="bandpass", fs=PAC_HZ, output="sos")
    noise = signal.sosfilt(sos, rng.normal(0.0, 400.0, n_pac))
    pac = np.clip(np.round(noise), -2047, 2047).astype("<i2")
    for j in range(n_pac // PAC_SAMPLES_PER_FRAME):
        last = (j + 1) * PAC_SAMPLES_PER_FRAME - 1
        stamp = round(last * 1e9 / PAC_HZ)
        frame = pac[j * PAC_SAMPLES_PER_FRAME:(j + 1) * PAC_SAMPLES_PER_FRAME]
        yield stamp, BiotacPac(pac_counts=frame, stamp_ns=stamp, seq=j)
    for i in range(int(DURATION_S * SLOW_HZ)):
        stamp = round((i + 1) * 1e9 / SLOW_HZ)
        t = stamp / 1e9
        pdc = int(1800 + 600 * min(t / 1.0, 1.0) + rng.normal(0, 3))
        electrodes = np.clip(2500 + 300 * np.sin(np.arange(19) + t) + rng.normal(0, 5, 19), 0, 4095)
        yield stamp, BiotacSlow(electrode_counts=electrodes.astype("<u2"), pdc_counts=pdc,
                                tac_counts=2000, tdc_counts=2100, pdc_tare_counts=1800,
                                stamp_ns=stamp, seq=i)
    for i in range(int(DURATION_S * MOCAP_HZ)):
        stamp = round((i + 1) * 1e9 / MOCAP_HZ)
        t = stamp / 1e9
        travel_mm = 0.05 * t + (2.0 * (t - 1.5) if t > 1.5 else 0.0)  # creep, then gross slip
        yield stamp, ObjectPose(position_mm=[0.0, travel_mm + rng.normal(0, 0.01), 50.0],
                                orientation_xyzw=[0.0, 0.0, 0.0, 1.0], stamp_ns=stamp, seq=i)
    for k in range(int(DURATION_S / PERIOD_S)):
        stamp = round((k + 1) * PERIOD_S * 1e9)
        yield stamp, ActuatorState(position_mm=(k + 1) * 23.0 / 450, period=k + 1,
                                   stamp_ns=stamp, seq=k)
        yield stamp, PztState(enabled=True, intensity_db=0.0, stamp_ns=stamp, seq=k)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0]) if argv else Path(__file__).with_name("demo.mcap")
    ordered = sorted(messages(), key=lambda item: (item[0], type(item[1]).__name__))
    with BagWriter(out, metadata={"created_unix_ns": str(LOG_EPOCH_NS),
                                  "source": "tests/data/make_demo_mcap.py (synthetic signals)"},
                   flush_s=None) as bag:   # chunks by size, not by time: the same bytes every run
        for stamp, msg in ordered:
            bag.write(msg.TOPIC, msg, log_time_ns=LOG_EPOCH_NS + stamp + LOG_LATENCY_NS)
    print(f"wrote {out}: {sum(bag.counts.values())} messages, {out.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
