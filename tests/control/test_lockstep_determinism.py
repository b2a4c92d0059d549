"""Lock-step results are a function of the seed and the parameters, not of the CPU load.

The same seed is run twice through `launch stabilize.yaml` (rig_sim, estimator, grip controller,
supervisor and a recorder of every topic, as separate processes): once on a quiet machine and
once beside a CPU hog. Every recorded message and the run summary must be the
same, field by field, but for the wall-clock ones (a command's stamp, the estimator's latency).
The controller's estimate timeout is set to 2 ms, which any scheduler hiccup exceeds: in
lock-step it is a liveness warning only and must not change a single command.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from incipient_slip.graph.bag import read_bag

STABILIZE = Path(__file__).parents[2] / "launch" / "stabilize.yaml"
WALL_CLOCK_FIELDS = {"latency_ns"}                        # measured, not simulated
WALL_STAMPED_TOPICS = {"/grip/command", "/run/event"}    # stamped by the node's clock when sent
SKIPPED_TOPICS = {"/heartbeat"}                           # uptimes and counters of the processes


def run(tmp: Path, name: str, steps: int, env: dict, args: dict) -> tuple[dict, dict]:
    """One lock-step run; returns (summary without its wall time, {topic: [message fields]})."""
    summary, bag = tmp / f"{name}.json", tmp / f"{name}.mcap"
    launch = tmp / f"{name}.yaml"
    launch.write_text(json.dumps({"launch": [
        {"include": {"file": str(STABILIZE), "arg": [
            {"name": "steps", "value": str(steps)}, {"name": "seed", "value": "3"},
            {"name": "summary", "value": str(summary)}, {"name": "quiet", "value": "true"},
            {"name": "estimate_timeout_s", "value": "0.002"},
            *({"name": k, "value": v} for k, v in args.items())]}},
        {"node": {"pkg": "graph", "exec": "recorder", "param": [{"name": "path", "value": str(bag)}]}},
    ]}))
    done = subprocess.run([sys.executable, "-m", "incipient_slip.graph.launch", str(launch), "--graph", name],
                          env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode in (0, 1) and summary.exists(), done.stderr[-3000:]
    result = json.loads(summary.read_text())
    result.pop("wall_s")
    messages: dict[str, list] = {}
    for rec in read_bag(bag):
        if rec.topic in SKIPPED_TOPICS:
            continue
        msg = rec.message()
        fields = {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)
                  if f.name not in WALL_CLOCK_FIELDS and not (f.name == "stamp_ns" and rec.topic in WALL_STAMPED_TOPICS)}
        messages.setdefault(rec.topic, []).append(
            {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in fields.items()})
    # as JSON text: NaN (an invalid estimate) compares equal to itself there
    return json.dumps(result, sort_keys=True), {t: [json.dumps(m, sort_keys=True) for m in ms]
                                                for t, ms in messages.items()}


# a run that ends after its steps, and one that a verdict ends first (s_d 1 drives F_N up to the
# safety limit: failure in period 10); the graph once kept applying force for 5-11 periods after a
# verdict, so the two recordings of one seed differed in length (quiet vs under load)
ENDINGS = {"steps": ({}, "success"), "verdict": ({"s_d": "1.0", "k": "10.0"}, "failure")}


@pytest.mark.timeout(900)
@pytest.mark.parametrize("ending", sorted(ENDINGS))
def test_the_same_seed_gives_the_same_messages_and_verdict_quiet_and_under_a_cpu_hog(tmp_path, ending):
    env = {k: v for k, v in os.environ.items() if k != "SLIP_GRAPH_DIR"}
    # graphs of their own, out of everyone's way, under a path short enough for ipc sockets
    runtime = tempfile.mkdtemp(prefix="ls", dir="/tmp")
    env["XDG_RUNTIME_DIR"] = runtime
    steps = 12
    hogs = []
    try:
        args, outcome = ENDINGS[ending]
        quiet = run(tmp_path, "quiet", steps, env, args)
        hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(1)]
        loaded = run(tmp_path, "loaded", steps, env, args)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
        shutil.rmtree(runtime, ignore_errors=True)
    judged = json.loads(quiet[0])["steps"]
    assert json.loads(quiet[0])["outcome"] == outcome and (judged == steps) == (ending == "steps")
    # the recording ends at the last judged period: nothing of a period after it
    assert len(quiet[1]["/grip/command"]) == len(quiet[1]["/actuator/state"]) == judged
    assert quiet[0] == loaded[0]                      # verdict, counts, every per-period trace
    assert sorted(quiet[1]) == sorted(loaded[1])
    for topic in quiet[1]:
        assert quiet[1][topic] == loaded[1][topic], topic
