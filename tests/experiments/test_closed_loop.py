"""The in-process closed loop (`experiments.closed_loop`, which validation and diagnosis run) is the
node graph's lock-step loop: for one seed and method, `launch stabilize.yaml` (rig_sim, estimator,
grip controller and supervisor as processes) and `run_loop` give the same per-period trace.

The one documented difference: the supervisor judges the travel of the last mocap pose of a
period (what a rig measures), which `run_loop` exposes as `LoopPeriod.travel_mm`.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from incipient_slip import control
from incipient_slip.experiments import closed_loop as loop
from incipient_slip.models.estimator_core import default_model_path, load_model
from incipient_slip.sim.rig import Rig
from incipient_slip.sim.scene import load_scene

STABILIZE = Path(__file__).parents[2] / "launch" / "stabilize.yaml"
STEPS, SEED = 12, 3


def graph_run(tmp_path: Path, method: str, label: str) -> dict:
    summary = tmp_path / f"{method}.json"
    done = subprocess.run([sys.executable, "-m", "incipient_slip.graph.launch", str(STABILIZE),
                           f"method:={method}", f"label:={label}", f"steps:={STEPS}", f"seed:={SEED}", "quiet:=true",
                           f"summary:={summary}", "--graph", f"loop-{method}"],
                          env={k: v for k, v in os.environ.items() if k != "SLIP_GRAPH_DIR"},
                          capture_output=True, text=True, timeout=300)
    assert done.returncode in (0, 1) and summary.exists(), done.stderr[-3000:]
    return json.loads(summary.read_text())


def same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("method, label", [("injection", "measured-ratio"), ("e10", "pseudo")])
def test_the_in_process_loop_gives_the_graphs_per_period_trace(tmp_path, method, label):
    summary = graph_run(tmp_path, method, label)
    scene = load_scene(control.SCENE_OF_METHOD[method])
    rig = Rig(scene, scene.materials[0], SEED)
    model = load_model(default_model_path(method, label), method=method)
    periods = list(loop.run_loop(rig, loop.model_estimate(model),
                                 rules=control.SupervisorRules(max_steps=STEPS)))
    tr = summary["traces"]
    assert tr["step"] == [p.step for p in periods] == list(range(1, STEPS + 1))
    for key, mine in (("force_kpa", [p.force_kpa for p in periods]),
                      ("command_kpa", [p.command_kpa for p in periods]),
                      ("stick_ratio_estimate", [p.estimate for p in periods]),
                      ("stick_ratio_true", [p.out.load_ratio_stick for p in periods]),
                      ("tangential_force_n", [p.out.tangential_force_n for p in periods]),
                      ("travel_mm", [p.travel_mm for p in periods])):
        assert all(same(a, b) for a, b in zip(tr[key], mine)), (key, tr[key], mine)
    assert tr["hold"] == [p.hold for p in periods]
    assert math.isnan(periods[0].estimate) and periods[0].hold          # the window fills in period 0
    assert any(p.command_kpa != p.force_kpa for p in periods)           # the law acted
    assert summary["outcome"] == (periods[-1].verdict.kind or "success")
    # what the two loops judge differs by the mocap's noise only
    assert np.allclose([p.travel_mm for p in periods], [p.out.object_y_mm for p in periods], atol=0.03)
