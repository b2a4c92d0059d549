"""The viewer bridge's own work per lock-step period, in process, with a stalled client.

    make bench-bridge              # or: python bench/bench_bridge.py [--against REV] [--rounds 5]

What `bench/bench_loop.py --viewer stalled` makes the bridge do, without the loop around it:
a `LiveView` (graph/live_view.py) with one Foxglove client (a child process) that subscribes to
`/biotac/pac`, its audio channel, `/actuator/state` and `/pzt/state` and never reads again, and
the bodies of a lock-step period (50 P_AC frames of the simulated paper scene, the tick) passed
to `LiveView.forward` as the bridge node does. CPU per period = this process's CPU time (every
thread: the SDK's server threads' queueing and sending too), waited for until it settles, over
`--periods` periods, after 300 periods that fill the client's socket buffers (until then the
server still sends; after, it queues and drops: the steady state of a stalled client); the
XX
is not either: `bench/bench_loop.py` prints the whole process's.

`--against REV` also runs the same measurement on the project's `src/` at git revision REV,
alternated round by round, and prints both side by side (medians with the range).
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FILL_PERIODS = 300


def stalled_client(url: str) -> None:
    """Child process: bench_loop.py's stalled viewer on the bridge at `url` (subscribes to WANTED,
    never reads again); says so, and stays until the bench ends (its stdin closes)."""
    from bench_loop import stalled_viewer

    stalled_viewer(None, url)
    print("subscribed", flush=True)
    sys.stdin.read()


def period_bodies(n_periods: int) -> list[list[tuple[str, bytes]]]:
    """(topic, msgpack body) of each lock-step period as bench_loop.py publishes them."""
    from incipient_slip import control
    from incipient_slip.messages import ActuatorState, BiotacPac, PztState, encode
    from incipient_slip.nodes.rig_sim import FRAMES_PER_PERIOD, PERIOD_NS, pac_frame_stamps_ns
    from incipient_slip.sim.rig import Rig, load_scene

    scene = load_scene("paper")
    rig = Rig(scene, scene.materials[0], 0)
    pac = [rig.step_period(control.DEFAULT_INITIAL_FORCE_KPA).pac_counts for _ in range(8)]
    periods, seq = [], 0
    for k in range(n_periods):
        frames = pac[k % len(pac)].reshape(FRAMES_PER_PERIOD, -1)
        bodies = []
        for j, stamp in enumerate(pac_frame_stamps_ns(k).tolist()):
            bodies.append(("/biotac/pac", encode(BiotacPac(pac_counts=frames[j], stamp_ns=stamp, seq=seq))))
            seq += 1
        bodies.append(("/actuator/state", encode(ActuatorState(period=k, stamp_ns=(k + 1) * PERIOD_NS, seq=k))))
        if k == 0:
            bodies.append(("/pzt/state", encode(PztState(enabled=True, stamp_ns=1, seq=0))))
        periods.append(bodies)
    return periods


def cpu_ns() -> int:
    """This process's CPU time so far, all its threads."""
    return time.process_time_ns()


def settled_cpu_ns(quiet_s: float = 0.2, limit_s: float = 10.0) -> int:
    """cpu_ns once it grew < 1 ms in `quiet_s` (the SDK's threads done sending), less the idle
    use over the wait."""
    t0 = time.monotonic()
    now = cpu_ns()
    while True:
        time.sleep(quiet_s)
        before, now = now, cpu_ns()
        if now - before < 1_000_000 or time.monotonic() - t0 > limit_s:
            break
    return now - int((now - before) / quiet_s * (time.monotonic() - t0))


def measure(bodies: list, repeats: int) -> list[float]:
    """Child process: ms of CPU per period of `bodies`, `repeats` times, a stalled client attached."""
    from incipient_slip.graph.live_view import LiveView

    periods = len(bodies)
    view = LiveView("127.0.0.1", 0)
    for topic, type_name in (("/biotac/pac", "BiotacPac"), ("/actuator/state", "ActuatorState"),
                             ("/pzt/state", "PztState")):
        view.offer(topic, type_name)
    client = subprocess.Popen([sys.executable, __file__, "--stalled-client", f"ws://127.0.0.1:{view.port}"],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        if client.stdout.readline().strip() != "subscribed":
            raise SystemExit("bench-bridge: the stalled client did not subscribe")
        deadline = time.monotonic() + 30
        while view.watched() != {"/biotac/pac", "/actuator/state", "/pzt/state"} or \
                not all(view.channels[t].has_sinks() for t in ("/biotac/pac", "/actuator/state")):
            if time.monotonic() > deadline:
                raise SystemExit("bench-bridge: the subscriptions did not reach the server")
            time.sleep(0.01)
        out = []
        # first FILL_PERIODS not counted: until the client's socket buffers are full the server
        # still sends; after, a stalled client's messages are queued and dropped (the steady state)
        for r in range(-(-FILL_PERIODS // periods) + repeats):
            settled = settled_cpu_ns()
            for period in bodies:
                for topic, body in period:
                    view.forward(topic, body)
            if r * periods >= FILL_PERIODS:
                out.append((settled_cpu_ns() - settled) / 1e6 / periods)
        # the server complains of every message it can no longer send to the client, gone below
        os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
        return out
    finally:
        client.stdin.close()            # first: a client that never reads holds up a server's stop
        client.wait(10)
        view.close()


def source_tree(rev: str, directory: str) -> Path:
    """`directory`, where `src/` of git revision `rev` is now extracted."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", directory], input=archive, check=True)
    return Path(directory)


def run_child(src: Path, bodies: Path, repeats: int) -> list[float]:
    env = dict(os.environ, PYTHONPATH=str(src))
    out = subprocess.run([sys.executable, __file__, "--child", str(bodies), "--repeats", str(repeats)],
                         env=env, capture_output=True, text=True, timeout=600, cwd=tempfile.gettempdir())
    if out.returncode:
        raise SystemExit(f"bench-bridge: a run failed:\n{out.stderr[-2000:]}")
    got = json.loads(out.stdout.splitlines()[-1])
    if not Path(got["module"]).is_relative_to(src):
        raise SystemExit(f"bench-bridge: the run of {src} imported {got['module']}")
    return got["ms"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--against", metavar="REV", help="also measure src/ at this git revision, alternated")
    ap.add_argument("--rounds", type=int, default=5, help="child processes per variant (alternated)")
    ap.add_argument("--periods", type=int, default=100, help="lock-step periods per measurement")
    ap.add_argument("--repeats", type=int, default=3, help="measurements per child process")
    ap.add_argument("--child", metavar="BODIES", help=argparse.SUPPRESS)
    ap.add_argument("--stalled-client", metavar="URL", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.stalled_client:
        stalled_client(args.stalled_client)
        return 0
    if args.child:
        from incipient_slip.graph import live_view
        with open(args.child, "rb") as f:
            bodies = pickle.load(f)
        print(json.dumps({"ms": measure(bodies, args.repeats), "module": live_view.__file__}), flush=True)
        return 0
    variants = {"this tree": ROOT / "src"}
    temp = tempfile.mkdtemp(prefix="bench-bridge-")
    bodies = Path(temp) / "bodies.pickle"          # the same messages for every variant
    with open(bodies, "wb") as f:
        pickle.dump(period_bodies(args.periods), f)
    if args.against:
        variants[args.against] = source_tree(args.against, temp) / "src"
    runs: dict[str, list[float]] = {v: [] for v in variants}
    loads = []
    try:
        for r in range(args.rounds):
            names = list(variants)
            for v in names[r % len(names):] + names[:r % len(names)]:
                loads.append(os.getloadavg()[0])
                got = run_child(variants[v], bodies, args.repeats)
                runs[v] += got
                print(f"  round {r + 1}/{args.rounds} {v:>12}: " + ", ".join(f"{x:.3f}" for x in got)
                      + f" ms per period (load {loads[-1]:.1f})", flush=True)
    finally:
        shutil.rmtree(temp, ignore_errors=True)
    print(f"\nthe bridge's CPU per lock-step period, stalled client on P_AC, its audio, the tick and "
          f"PztState; {args.rounds} rounds x {args.repeats} x {args.periods} periods, load average "
          f"{min(loads):.1f}-{max(loads):.1f}, {os.cpu_count()} cores")
    print("| src | CPU per period, median (range) | ratio |")
    print("|---|---|---|")
    base = float(np.median(runs["this tree"]))
    for v, xs in runs.items():
        med = float(np.median(xs))
        print(f"| {v} | {med:.3f} ms ({min(xs):.3f}-{max(xs):.3f}) | {med / base:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
