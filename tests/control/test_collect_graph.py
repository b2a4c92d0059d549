"""launch collect.yaml for real: the collection protocol through the graph lands in an MCAP file
holding exactly what the in-process simulator produces for the same series."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from incipient_slip.messages import decode_any
from incipient_slip.graph.bag import read_bag
from incipient_slip.sim.protocols import run_collection
from incipient_slip.sim.rig import Rig, load_scene

STEPS = 6


@pytest.mark.timeout(90)
def test_collect_launch_records_every_period_of_the_series(graph, tmp_path):
    out = tmp_path / "series.mcap"
    proc = graph.spawn([sys.executable, "-m", "incipient_slip.graph.launch", "collect.yaml",
                        f"steps:={STEPS}", "speed:=50", "seed:=3", "material:=pla", f"out:={out}"])
    _, err = proc.communicate(timeout=80)
    assert proc.returncode == 0, err.decode()[-3000:]

    by_topic: dict[str, list] = {}
    for record in read_bag(out):
        by_topic.setdefault(record.topic, []).append(decode_any(record.body, record.topic))
    pac = by_topic["/biotac/pac"]
    assert len(pac) == 50 * STEPS and [m.seq for m in pac] == list(range(50 * STEPS))
    assert len(by_topic["/actuator/state"]) == STEPS

    rig = Rig(load_scene("paper"), "pla", 3)
    periods = run_collection(rig, STEPS)
    expected = np.concatenate([p.pac_counts for p in periods])
    assert np.array_equal(np.concatenate([m.pac_counts for m in pac]), expected)
