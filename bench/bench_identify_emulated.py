"""The emulated identification repeated: how far each of N runs lands from the hidden set.

    python bench/bench_identify_emulated.py [--runs 20] [--hogs 0] [--keep DIR]

Runs the slow test's launch (`launch identify.yaml rig:=emulated`, the hidden k_b 0.58 N/mm at
1 N, beta 0.85, mu 0.48 of tests/identify/test_identify.py, levels 2.3 and 1.1 kPa, 0.5 mm steps,
stiffness only) `--runs` times one after another beside `--hogs` CPU hogs, each in its own graph
directory, emulator directory, UR address and NatNet ports. Prints per run the identified k_b and
beta against the hidden ones, mu against the rig's own (the series' friction, drawn around the
hidden mu: `sim.Rig(...).mu_s`) and each ramp's k_b against k_b(F_N) at its median F_N, then the
spread. `--keep DIR` keeps every run's `identify_results.json` (every window's F_N, actuator
position and y, so its shear Q = k_s (u - y)) and log. docs/identification.md, "Identification to
10 %", gives what this showed. Real time: ~3 min a run on 2 cores.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(Path(__file__).parent))

from bench_emulated_load import start_hogs, stop_hogs  # noqa: E402

from incipient_slip.devices.natnet_emulator import free_udp_port_pair  # noqa: E402

K_REF, BETA, MU = 0.58, 0.85, 0.48          # the slow test's hidden set
PLAN = ["levels_kpa:=2.3,1.1", "step_mm:=0.5", "protocols:=stiffness"]


def hidden_scene(path: Path) -> Path:
    import yaml

    from incipient_slip.sim.scene import load_params

    pla = load_params("default")[0]["materials"]["pla"]
    path.write_text(yaml.safe_dump({
        "name": "hidden", "params": "default",
        "effects": ["contact", "stick_slip", "mocap", "pdc", "temperature", "electrodes", "adc"],
        "overrides": {"pre_slip": {"bulk_shear_n_per_mm": K_REF, "bulk_stiffening_exponent": BETA},
                      "materials": {"pla": {**pla, "mu_identified": MU}}}}))
    return path


def one_run(scene: Path, work: Path, timeout_s: float) -> tuple[int | None, str, float]:
    graph = Path(tempfile.mkdtemp(prefix="emu-id-", dir="/tmp"))
    env = dict(os.environ, SLIP_GRAPH_DIR=str(graph), PYTHONUNBUFFERED="1")
    args = ["identify.yaml", "rig:=emulated", f"scene:={scene}", f"out_dir:={work / 'out'}",
            f"emu_dir:={work / 'emu'}", f"emu_natnet_port:={free_udp_port_pair()}",
            f"emu_address:=127.0.{random.randint(1, 254)}.{random.randint(2, 254)}", *PLAN]
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "incipient_slip.graph.launch", *args], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT / "launch")
    try:
        _, err = proc.communicate(timeout=timeout_s)
        code = proc.returncode
    except subprocess.TimeoutExpired:
        proc.send_signal(2)
        _, err = proc.communicate()
        code = None
    finally:
        shutil.rmtree(graph, ignore_errors=True)
    return code, err, time.monotonic() - t0


def errors(results: dict, mu_rig: float) -> dict:
    """Relative k_b and mu errors, absolute beta error, and each ramp's k_b against k_b(its F_N)."""
    st, gain = results["stiffness"], results["inputs"]["newton_per_kpa"]
    ramps = [(r["fn_kpa"], r["k_b"] / (K_REF * (r["fn_kpa"] * gain) ** BETA) - 1)
             for r in results["levels"] if r["phase"] == "ramp"]
    return {"k_b": st.get("k_ref", math.nan) / K_REF - 1, "beta": st.get("beta", math.nan) - BETA,
            "mu": st.get("mu", math.nan) / mu_rig - 1, "ramps": ramps}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--hogs", type=int, default=0, help="busy-loop CPU hogs beside the runs (default 0)")
    parser.add_argument("--timeout", type=float, default=900.0)
    parser.add_argument("--keep", default="", help="keep each run's results and log in DIR/run<i>/")
    args = parser.parse_args(argv)
    from incipient_slip.sim.rig import Rig
    from incipient_slip.sim.scene import load_scene

    hogs = start_hogs(args.hogs)
    done: list[dict] = []
    try:
        with tempfile.TemporaryDirectory(prefix="emu-id-") as tmp:
            base = Path(args.keep) if args.keep else Path(tmp)
            scene = hidden_scene(Path(tmp) / "hidden.yaml")
            mu_rig = Rig(load_scene(str(scene)), "pla", 0).mu_s       # the emulated rig's seed
            print(f"{args.runs} runs beside {args.hogs} CPU hog(s); hidden k_b {K_REF} beta {BETA}, "
                  f"mu {MU} (the rig's own {mu_rig:.4f}); load {os.getloadavg()[0]:.1f}", flush=True)
            for i in range(args.runs):
                work = base / f"run{i}"
                work.mkdir(parents=True, exist_ok=True)
                code, err, wall = one_run(scene, work, args.timeout)
                (work / "stderr.log").write_text(err)
                out = work / "out" / "identify_results.json"
                if code != 0 or not out.exists():
                    why = [ln for ln in err.splitlines() if "FAULT" in ln or "stopped" in ln or "exit code" in ln]
                    print(f"run {i + 1:2d}: FAULT exit {code}, {wall:.0f} s, load {os.getloadavg()[0]:.1f}: "
                          f"{why[0][:160] if why else ''}", flush=True)
                    continue
                e = errors(json.loads(out.read_text()), mu_rig)
                done.append(e)
                print(f"run {i + 1:2d}: k_b {100 * e['k_b']:+5.1f} %, beta {e['beta']:+.3f}, mu {100 * e['mu']:+5.1f} %; "
                      f"ramps " + ", ".join(f"{f:.2f} kPa {100 * x:+.1f} %" for f, x in e["ramps"])
                      + f"; {wall:.0f} s, load {os.getloadavg()[0]:.1f}", flush=True)
    finally:
        stop_hogs(hogs)
    if done:
        print(f"{len(done)} of {args.runs} runs ended; largest |error|: k_b {100 * max(abs(e['k_b']) for e in done):.1f} %, "
              f"beta {max(abs(e['beta']) for e in done):.3f}, mu {100 * max(abs(e['mu']) for e in done):.1f} %")
    return 0 if len(done) == args.runs else 1


if __name__ == "__main__":
    raise SystemExit(main())
