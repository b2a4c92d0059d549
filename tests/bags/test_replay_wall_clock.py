"""rig:=replay of a recording stamped on a wall clock (a real or emulated rig's) runs like the
replay of a simulated one: its periods come from the recording's own actuator ticks, not from
its stamps counted from 0."""
from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from incipient_slip.graph.bag import BagWriter, read_bag
from incipient_slip.messages import PERIOD_NS, encode

STEPS = 6
# host wall time as a device node stamps it (2026-11-28), not a whole number of periods
WALL_OFFSET_NS = 1_795_862_922_272_246_644
LAUNCH = [sys.executable, "-m", "incipient_slip.graph.launch"]


def _launch(graph, args: list[str], timeout: float) -> tuple[int, str]:
    proc = graph.spawn(LAUNCH + args)
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        pytest.fail(f"launch {' '.join(args)} still running after {timeout} s:\n{err.decode()[-4000:]}")
    return proc.returncode, err.decode()


def shifted_to_the_wall_clock(src, dst) -> None:
    """The same recording as a device rig would have stamped it: every stamp (and receive time)
    moved by WALL_OFFSET_NS, bodies re-encoded with the new stamp, seqs unchanged."""
    with BagWriter(dst, flush_s=None) as out:
        for rec in read_bag(src):
            msg = rec.message()
            moved = dataclasses.replace(msg, stamp_ns=msg.stamp_ns + WALL_OFFSET_NS)
            out.write(rec.topic, moved, log_time_ns=rec.log_time_ns + WALL_OFFSET_NS,
                      body=encode(moved))


@pytest.mark.timeout(400)
def test_a_wall_clock_recording_replays_as_its_simulated_twin(graph, tmp_path):
    sim = tmp_path / "sim.mcap"
    code, err = _launch(graph, ["collect.yaml", f"steps:={STEPS}", "speed:=50", f"out:={sim}"], 120)
    assert code == 0, err[-3000:]
    wall = tmp_path / "wall.mcap"
    shifted_to_the_wall_clock(sim, wall)
    first = min(r.stamp_ns for r in read_bag(wall, ["/biotac/pac"]))
    assert first // PERIOD_NS > 10**9       # stamp // T is no period of this run

    summaries, codes = {}, {}
    for name, path in (("sim", sim), ("wall", wall)):
        summary = tmp_path / f"{name}.json"
        codes[name], err = _launch(graph, ["stabilize.yaml", "rig:=replay", f"recording:={path}",
                                           f"steps:={STEPS}", f"summary:={summary}", "quiet:=true"], 120)
        # before: the wall-clock replay ended as a fault (exit 3), "estimate for period 3591724493
        # while the rig is at period 0"
        assert codes[name] in (0, 1), f"{name}: exit {codes[name]}\n{err[-4000:]}"
        summaries[name] = json.loads(summary.read_text())
    assert codes["wall"] == codes["sim"]
    sim_run, wall_run = summaries["sim"], summaries["wall"]
    assert wall_run["steps"] == sim_run["steps"] == STEPS
    for key in ("outcome", "final_travel_mm", "final_force_kpa"):
        assert wall_run[key] == sim_run[key], key
    # what the recording decides (the grip commands and holds also depend on the replay's timing)
    for key in ("period", "travel_mm", "force_kpa", "stick_ratio_estimate"):
        np.testing.assert_array_equal(np.array(wall_run["traces"][key], dtype=float),
                                      np.array(sim_run["traces"][key], dtype=float), err_msg=key)
