"""The latency the device path adds per period: rig:=emulated against rig:=sim, side by side.

    python bench/bench_emulated.py [--steps 20] [--rounds 2] [--seed 0]

Each round runs `launch stabilize.yaml` twice in private graphs, once with the simulated rig in
real time (`rig:=sim lockstep:=false`: rig_sim publishes each message when its stamp is due) and
once with `rig:=emulated` (every device node against the emulators), with a recorder in the same
graph. Per period k, from the recorder's receive times (one clock):

* decision = GripCommand(period=k) - ActuatorState(period=k), both as the recorder receives
  them: from the period's tick to the grip controller's answer. The simulated rig releases the
  tick at its stamp, right after the period's last P_AC frame. On the emulated rig the estimator
  cuts periods at tick 0's time + k periods (`period_origin:=tick`) and the stage's move is
  blocking, so the BioTac frame that closes period k (frames every 10 ms, the reader polls every
  5 ms) can arrive before tick k: the answer may precede the tick (negative values).
* actuation (emulated only) = RobotState(period=k) - GripCommand(period=k): the ur5 node's moveL
  on the fake controller until it reports the press done (the simulated rig applies F_N at its
  next period without a robot).

Prints medians with p10..p90 per rig, pooled over rounds, and the median ratio. Machine: shared
and noisy; the simulated contact behind both rigs.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from incipient_slip.devices.natnet_emulator import free_udp_port_pair  # noqa: E402
from incipient_slip.graph.bag import read_bag          # noqa: E402
from incipient_slip.messages import decode_any          # noqa: E402




def run(rig: str, steps: int, seed: int, work: Path) -> dict[str, list[float]]:
    """Runs one launch with a recorder; returns per-period latencies in ms."""
    graph = Path(tempfile.mkdtemp(prefix="bench-emu-", dir="/tmp"))
    env = dict(os.environ, SLIP_GRAPH_DIR=str(graph), PYTHONUNBUFFERED="1")
    bag = work / f"{rig}.mcap"
    recorder = subprocess.Popen([sys.executable, "-m", "incipient_slip.graph.recorder", f"path:={bag}",
                                 "topics:=[/actuator/state, /grip/command, /robot/state]"],
                                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    args = [f"rig:={rig}", f"steps:={steps}", f"seed:={seed}", "quiet:=true",
            f"summary:={work / (rig + '.json')}"]
    if rig == "sim":
        args.append("lockstep:=false")
    else:
        args += [f"emu_dir:={work / 'emu'}", f"emu_natnet_port:={free_udp_port_pair()}",
                 f"emu_address:=127.0.{random.randint(1, 254)}.{random.randint(2, 254)}"]
    try:
        time.sleep(0.5)        # the recorder subscribes before the rig's first tick (no handshake here)
        launch = subprocess.run([sys.executable, "-m", "incipient_slip.graph.launch", "stabilize.yaml", *args],
                                env=env, capture_output=True, text=True, timeout=300, cwd=ROOT / "launch")
        if launch.returncode not in (0, 1):
            raise SystemExit(f"{rig}: launch exit {launch.returncode}\n{launch.stderr[-3000:]}")
    finally:
        os.killpg(recorder.pid, signal.SIGTERM)
        recorder.wait(10)
        shutil.rmtree(graph, ignore_errors=True)
    tick, command, pressed = {}, {}, {}
    for record in read_bag(bag):
        msg = decode_any(record.body, record.topic)
        if record.topic == "/actuator/state":
            tick.setdefault(msg.period, record.log_time_ns)
        elif record.topic == "/grip/command":
            command.setdefault(msg.period, record.log_time_ns)
        elif record.topic == "/robot/state" and msg.period >= 0:
            pressed.setdefault(msg.period, record.log_time_ns)
    summary = json.loads((work / (rig + ".json")).read_text())
    print(f"  {rig}: {summary['outcome']} after {summary['steps']} steps ({summary['detail']})", flush=True)
    out = {"decision": [(command[k] - tick[k]) / 1e6 for k in tick if k in command],
           "actuation": [(pressed[k] - command[k]) / 1e6 for k in command if k in pressed]}
    return out


def describe(values: list[float]) -> str:
    if not values:
        return "n/a"
    v = np.asarray(values)
    return f"{np.median(v):7.2f} ms (p10..p90 {np.percentile(v, 10):.2f}..{np.percentile(v, 90):.2f}, n={v.size})"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20, help="periods per run (default 20)")
    parser.add_argument("--rounds", type=int, default=2, help="sim/emulated pairs (default 2)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    pooled = {rig: {"decision": [], "actuation": []} for rig in ("sim", "emulated")}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for rig in ("sim", "emulated") if r % 2 == 0 else ("emulated", "sim"):
                work = Path(tmp) / f"{rig}{r}"
                work.mkdir()
                res = run(rig, args.steps, args.seed, work)
                for key in res:
                    pooled[rig][key] += res[key]
                print(f"round {r} {rig:8s} decision {describe(res['decision'])}", flush=True)
    print("\nsimulated contact behind both rigs; shared noisy machine")
    for rig in ("sim", "emulated"):
        print(f"{rig:8s} tick -> grip command  {describe(pooled[rig]['decision'])}")
    print(f"emulated grip command -> press done (ur5, fake UR)  {describe(pooled['emulated']['actuation'])}")
    sim_med, emu_med = np.median(pooled["sim"]["decision"]), np.median(pooled["emulated"]["decision"])
    print(f"device path: tick -> command median {emu_med - sim_med:+.2f} ms vs sim; the press adds "
          f"{np.median(pooled['emulated']['actuation']):.1f} ms before F_N moves")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
