"""Closed-loop latency: from a P_AC frame's publish to the grip command it causes.

    make bench-loop            # or: python bench/bench_loop.py [--periods 1500] [--method injection]

This process plays the rig (lock-step, like rig_sim): it publishes the 50 P_AC frames of a
period (simulated data from `sim.Rig`, paper scene, cycled), then the period's tick, and waits
for `GripCommand(period=k)`. The estimator (shipped model) and grip_controller run as real
processes in a private graph. Latency of period k = CLOCK_MONOTONIC (shared by all processes)
when the command arrives here minus just before the frame that completes the window
(the last P_AC frame of period k) was published. A real rig sends one frame per 10 ms; here the
first 49 frames of a period go out as a burst and the last one 3 ms later (`--gap-ms`), so the
timed frame does not queue behind the burst (which only lock-step produces).

Stages: phi and predict are timed in this process on the same windows with the same model
(their ratio splits the estimator's own compute time, which it reports in
`SlipEstimate.latency_ns`); control is the controller's work per estimate (`control.next_force`
plus building and encoding the command), timed here; transport is the rest (three hops:
rig -> estimator -> controller -> rig, with decode and dispatch). Last line: `loop p99 ms = X`.

`--viewer stalled` adds the viewer bridge (nodes/foxglove_bridge.py) as a third process and one
WebSocket client that subscribes to every channel and then never reads again: the cost a
stalled Foxglove puts on the loop (docs/performance.md, "Live view"); `--viewer attached`: the
bridge with no client (it then receives nothing but announcements).
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from incipient_slip import control
from incipient_slip.messages import (
    ActuatorState, BiotacPac, GripCommand, Heartbeat, PztState, SlipEstimate, encode,
)
from incipient_slip.models.estimator_core import default_model_path, load_model
from incipient_slip.models.features import phi
from incipient_slip.nodes.rig_sim import FRAMES_PER_PERIOD, PERIOD_NS, pac_frame_stamps_ns
from incipient_slip.graph.runtime import Node
from incipient_slip.sim.rig import Rig, load_scene

GOAL_P99_MS = 2.0


class BenchRig(Node):
    """Publishes P_AC frames period by period and times the grip command each period causes."""

    def __init__(self, graph_dir, pac_periods: np.ndarray):
        super().__init__("bench_rig", graph_dir=graph_dir, heartbeat_s=0)
        self.data = pac_periods                       # (n, 1100) int16 counts
        self.pac_pub = self.create_publisher(BiotacPac)
        self.tick_pub = self.create_publisher(ActuatorState)
        self.pzt_pub = self.create_publisher(PztState)
        self.commands: dict[int, int] = {}            # period -> monotonic ns received
        self.estimate_ns: dict[int, int] = {}         # period -> estimator compute ns
        self.sent_ns: dict[int, int] = {}             # period -> monotonic ns before its last frame
        self.holds = 0
        self.gap_s = 0.003
        self.heard = set()
        self.create_subscription(GripCommand, self.on_command)
        self.create_subscription(SlipEstimate, self.on_estimate)
        self.create_subscription(Heartbeat, lambda h: self.heard.add(h.node))

    def on_command(self, msg: GripCommand):
        self.commands[msg.period] = time.monotonic_ns()
        self.holds += msg.hold

    def on_estimate(self, msg: SlipEstimate):
        self.estimate_ns[msg.period] = msg.latency_ns

    def publish_period(self, k: int):
        frames = self.data[k % len(self.data)].reshape(FRAMES_PER_PERIOD, 22)
        stamps = pac_frame_stamps_ns(k).tolist()
        for j in range(FRAMES_PER_PERIOD - 1):
            self.pac_pub.publish(BiotacPac(pac_counts=frames[j], stamp_ns=stamps[j]))
        # A real rig sends a frame every 10 ms; lock-step sends the period as a burst. Let the
        # estimator drain the burst first so the timed frame does not queue behind 49 others.
        self.spin_for(self.gap_s)
        last = BiotacPac(pac_counts=frames[-1], stamp_ns=stamps[-1])
        self.sent_ns[k] = time.monotonic_ns()
        self.pac_pub.publish(last)
        self.tick_pub.publish(ActuatorState(period=k, stamp_ns=(k + 1) * PERIOD_NS))

    def spin_for(self, seconds: float):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.spin_once(max(0.0, end - time.monotonic()))

    def wait(self, predicate, timeout_s, what):
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise SystemExit(f"bench-loop: timed out waiting for {what}")
            self.spin_once(0.01)


def simulated_pac(n_periods: int, seed: int = 0) -> np.ndarray:
    """P_AC counts of n periods of the paper scene (injection on) at the initial grip force."""
    scene = load_scene("paper")
    rig = Rig(scene, scene.materials[0], seed)
    return np.stack([rig.step_period(control.DEFAULT_INITIAL_FORCE_KPA).pac_counts
                     for _ in range(n_periods)])


def stage_costs_ns(model, pac: np.ndarray, repeats: int = 200) -> dict:
    """Median ns of phi, predict (same model, 1 s windows) and the controller's per-estimate work."""
    n = int(round(model.spec.window_s * model.spec.rate_hz))
    stream = pac.reshape(-1)
    windows = [stream[i:i + n] for i in range(0, len(stream) - n, 1100)][:20]
    t_phi, t_pred, t_ctl = [], [], []
    law = control.ControlParams()
    for r in range(repeats):
        w = windows[r % len(windows)]
        t0 = time.perf_counter_ns()
        f = phi(w[None, :], model.spec)
        t1 = time.perf_counter_ns()
        s = float(model.predict(f)[0])
        t2 = time.perf_counter_ns()
        problem = control.problem_of(s, True, method="injection", expected_method="injection")
        d = control.next_force(2.9, s, law, problem)
        encode(GripCommand(normal_force_kpa=d.normal_force_kpa, hold=d.hold, period=r, reason=d.reason,
                           cause=d.cause, stamp_ns=1, seq=r))
        t3 = time.perf_counter_ns()
        t_phi.append(t1 - t0)
        t_pred.append(t2 - t1)
        t_ctl.append(t3 - t2)
    return {"phi": float(np.median(t_phi)), "predict": float(np.median(t_pred)),
            "control": float(np.median(t_ctl))}


def cpu_seconds(pid: int) -> float:
    """CPU time process `pid` has used so far, all its threads (Linux /proc schedstat, ns)."""
    total = 0
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/schedstat") as f:
                total += int(f.read().split()[0])
        except (FileNotFoundError, ProcessLookupError):      # a thread that just ended
            pass
    return total / 1e9


def settled_cpu(procs, quiet_s: float = 0.5, limit_s: float = 30.0) -> list[float]:
    """cpu_seconds of each process once together they used < 10 ms in `quiet_s` (or after
    `limit_s`), less what each uses when idle (timers, discovery) over that wait."""
    t0 = time.monotonic()
    now = [cpu_seconds(p.pid) for p in procs]
    while True:
        time.sleep(quiet_s)
        before, now = now, [cpu_seconds(p.pid) for p in procs]
        if sum(now) - sum(before) < 0.010 or time.monotonic() - t0 > limit_s:
            break
    waited = time.monotonic() - t0
    return [c - (c - b) / quiet_s * waited for c, b in zip(now, before)]


def bridge_url(proc) -> str:
    """The ws:// URL the bridge process prints on stderr when it serves."""
    for raw in proc.stderr:
        line = raw.decode(errors="replace")
        if "serving ws://" in line:
            return line.split("serving ", 1)[1].split()[0]
    raise SystemExit("bench-loop: the viewer bridge ended without serving")


def stalled_viewer(rig: "BenchRig", url: str):
    """A Foxglove protocol client that subscribes to every channel the bridge advertises for the
    rig's topics, then stops reading (its socket fills; the bridge must drop, not wait)."""
    import json as _json

    from websockets.sync.client import connect

    wanted = {"/biotac/pac", "/biotac/pac/audio", "/actuator/state", "/pzt/state"}

    def advertised(ws) -> dict[str, int]:
        channels: dict[str, int] = {}
        deadline = time.monotonic() + 30
        while not wanted <= set(channels):
            if time.monotonic() > deadline:
                raise SystemExit(f"bench-loop: the bridge did not advertise {sorted(wanted - set(channels))}")
            try:
                frame = ws.recv(timeout=0.1)
            except TimeoutError:
                continue
            if isinstance(frame, str) and _json.loads(frame)["op"] == "advertise":
                channels.update({c["topic"]: c["id"] for c in _json.loads(frame)["channels"]})
        return channels

    def connected():
        return connect(url, subprotocols=["foxglove.sdk.v1"], proxy=None, max_queue=1,
                       open_timeout=30, close_timeout=1, compression=None)

    # foxglove-sdk 0.30.3 may refuse a subscription to a channel it added while the client was
    # connecting (docs/tools.md): look with a first client, subscribe with a second
    with connected() as ws:
        advertised(ws)
    ws = connected().__enter__()
    channels = advertised(ws)
    ws.send(_json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": cid} for i, cid in enumerate(channels.values())]}))
    return ws


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--periods", type=int, default=1500, help="lock-step periods to time")
    ap.add_argument("--warmup", type=int, default=20, help="periods not timed (buffer filling)")
    ap.add_argument("--method", default="injection", choices=("injection", "vibrotactile"))
    ap.add_argument("--gap-ms", type=float, default=3.0, help="pause before the timed last frame")
    ap.add_argument("--model", type=Path, help="model file (default: the shipped models/METHOD.npz)")
    ap.add_argument("--viewer", choices=("none", "attached", "stalled"), default="none",
                    help="attached: the viewer bridge, no client; stalled: the bridge plus a "
                         "client that subscribes to everything and never reads")
    ap.add_argument("--viewer-priority", choices=("idle", "low", "normal"), default="low",
                    help="the bridge's `priority` param (default low, as the node's)")
    args = ap.parse_args(argv)

    model_path = args.model or default_model_path(args.method)
    model = load_model(model_path, method=args.method)
    pac = simulated_pac(40)
    directory = Path(tempfile.mkdtemp(prefix="bl", dir="/tmp"))
    env = dict(os.environ, SLIP_GRAPH_DIR=str(directory), PYTHONUNBUFFERED="1")
    procs = [subprocess.Popen([sys.executable, "-m", f"incipient_slip.nodes.{name}", *params],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              start_new_session=True)
             for name, params in (("estimator", [f"method:={args.method}", f"model:={model_path}",
                                                 "wall_timeout_s:=0"]),
                                  ("grip_controller", [f"method:={args.method}",
                                                       "estimate_timeout_s:=5.0"]),
                                  *([("foxglove_bridge", ["port:=0", f"priority:={args.viewer_priority}"])]
                                    if args.viewer != "none" else []))]
    viewer = None
    try:
        rig = BenchRig(directory, pac)
        rig.gap_s = args.gap_ms / 1000.0
        # handshakes: the nodes subscribed to what we publish, and we hear them
        for pub in (rig.pac_pub, rig.tick_pub):
            if not pub.wait_for_subscribers(1, 30):
                raise SystemExit(f"bench-loop: no subscriber to {pub.topic}")
        names = {"estimator", "grip_controller"} | ({"foxglove_bridge"} if args.viewer != "none" else set())
        # a bridge alone in its session at low priority starts slowly on a loaded machine
        rig.wait(lambda: names <= rig.heard, 30 if args.viewer == "none" else 120,
                 f"heartbeats of {', '.join(sorted(names))} (heard {', '.join(sorted(rig.heard)) or 'none'})")
        if args.viewer == "stalled":
            viewer = stalled_viewer(rig, bridge_url(procs[-1]))
            # the bridge receives a topic only while a client watches it: now it does
            for pub in (rig.pac_pub, rig.tick_pub):
                if not pub.wait_for_subscribers(2, 30):
                    raise SystemExit(f"bench-loop: the bridge did not subscribe to {pub.topic}")
        rig.pzt_pub.publish(PztState(enabled=True, stamp_ns=1))
        total = args.warmup + args.periods
        t_start = time.monotonic()
        cpu_start = [cpu_seconds(p.pid) for p in procs]
        for k in range(total):
            rig.publish_period(k)
            rig.wait(lambda: k in rig.commands, 10, f"GripCommand(period={k})")
        wall = time.monotonic() - t_start
        # a bridge at low priority may still be working through what the loop sent: count that too
        cpu_ms = [1e3 * (c1 - c0) / total for c0, c1 in zip(cpu_start, settled_cpu(procs))]
    finally:
        if viewer is not None:
            try:
                viewer.close()   # its close frame waits behind all it never read: may time out
            except Exception as exc:     # websockets' ConnectionClosedError, TimeoutError
                print(f"bench-loop: the stalled client's close: {exc}", file=sys.stderr)
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
        shutil.rmtree(directory, ignore_errors=True)

    timed = range(args.warmup, total)
    lat_ms = np.array([(rig.commands[k] - rig.sent_ns[k]) / 1e6 for k in timed])
    est_ms = np.array([rig.estimate_ns.get(k, 0) / 1e6 for k in timed])
    costs = stage_costs_ns(model, pac)
    split = costs["phi"] / (costs["phi"] + costs["predict"])
    median = float(np.median(lat_ms))
    p99 = float(np.percentile(lat_ms, 99))
    est_median = float(np.median(est_ms))
    ctl_ms = costs["control"] / 1e6
    stages = {"transport (3 hops, decode, dispatch)": max(0.0, median - est_median - ctl_ms),
              "phi (features)": est_median * split, "predict (model)": est_median * (1 - split),
              "control (law + command)": ctl_ms}
    print(f"bench-loop: {args.periods} lock-step periods ({args.warmup} warm-up), method {args.method}, "
          f"viewer {args.viewer}" + (f" (priority {args.viewer_priority})" if args.viewer != "none" else "") +
          f", load average {os.getloadavg()[0]:.1f}, "
          f"model {model_path.name} ({model.kind}), {os.cpu_count()} cores, {wall:.1f} s wall, "
          f"{rig.holds} holds")
    print(f"P_AC last frame publish -> GripCommand received: median {median:.3f} ms, "
          f"p90 {np.percentile(lat_ms, 90):.3f} ms, p99 {p99:.3f} ms, max {lat_ms.max():.3f} ms")
    print(f"estimator compute (its latency_ns): median {est_median:.3f} ms, "
          f"p99 {np.percentile(est_ms, 99):.3f} ms")
    print("share of the median by stage:")
    for name, ms in stages.items():
        print(f"  {name:<38} {ms:7.3f} ms  {100 * ms / median:5.1f} %")
    names = ["estimator", "grip_controller", "foxglove_bridge"][:len(procs)]
    print("CPU per period (all threads; the work, whatever the machine's load): " +
          ", ".join(f"{n} {ms:.2f} ms" for n, ms in zip(names, cpu_ms)))
    print(f"goal p99 <= {GOAL_P99_MS} ms: {'met' if p99 <= GOAL_P99_MS else 'NOT met'}")
    print(f"loop p99 ms = {p99:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
