"""`slip collect` (a collection session on any rig) and `slip dataset` (a data set from the simulated
rig, or `--from-recordings` from a session's recordings): a lab's way from its rig to `slip train`."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from incipient_slip.errors import UsageError

PAPER_MATERIALS = ("pla", "abs", "petg", "nylon", "tpu")


def cmd_dataset(args) -> int:
    if not args.from_recordings:
        from incipient_slip.sim.cli import cmd_dataset as simulated
        return simulated(args)
    from .recordings import NORMAL_FORCE_SOURCES, RecordingError, import_recordings, recordings_of
    if args.scene or args.series is not None:
        raise UsageError("--from-recordings takes its series from the recordings: drop --scene and --series")
    if args.normal_force not in NORMAL_FORCE_SOURCES:
        raise UsageError(f"--normal-force must be one of {', '.join(NORMAL_FORCE_SOURCES)}")
    if args.spring_n_per_mm is not None and not args.spring_n_per_mm > 0:
        raise UsageError(f"--spring-n-per-mm must be > 0, got {args.spring_n_per_mm}")
    if args.rig_config and args.spring_n_per_mm is None:       # the rig's own calibration (slip calibrate spring)
        from incipient_slip.devices import calibration
        spring = calibration.load(args.rig_config).get("spring", {}).get("spring_n_per_mm")
        if spring is None:
            raise UsageError(f"{args.rig_config}: its calibration has no spring constant; run `slip calibrate "
                             f"spring --config {args.rig_config}` or give --spring-n-per-mm")
        args.spring_n_per_mm = float(spring)
        print(f"spring constant {args.spring_n_per_mm:g} N/mm from the calibration of {args.rig_config}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a directory")
    if out.is_dir() and any(out.rglob("series_*.npz")) and not args.overwrite:
        raise UsageError(f"--out {out} already holds a data set; pass --overwrite or choose another directory")
    try:
        todo, _ = recordings_of(args.from_recordings)
    except (RecordingError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    t0 = time.perf_counter()
    bar = None
    if not args.quiet and sys.stderr.isatty():
        from tqdm import tqdm
        bar = tqdm(total=len(todo), unit="recording", desc="importing")
    try:
        report = import_recordings(args.from_recordings, out, spring_n_per_mm=args.spring_n_per_mm,
                                   normal_force=args.normal_force, progress=bar.update if bar else None)
    finally:
        if bar:
            bar.close()
    out.mkdir(parents=True, exist_ok=True)
    (out / "import_report.json").write_text(json.dumps(report.to_plain(), indent=1))
    print(report.format())
    print(f"in {time.perf_counter() - t0:.1f} s; the report: {out / 'import_report.json'}")
    return 0 if report.imported else 1


def cmd_collect(args) -> int:
    from .session import SessionError, open_session, plan_session, run_session
    try:
        planned = plan_session(args.rig, args.materials, args.series_per_material, args.seed, args.injection,
                               args.steps, args.params or "")
        session = open_session(args.out, planned)
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    bad = [a for a in args.launch_arg if ":=" not in a]
    if bad:
        raise UsageError(f"--launch-arg takes name:=value, got {bad[0]!r}")
    done = sum(s.status == "done" for s in session.series)
    print(f"session {args.out}: {len(session.series)} series on rig {args.rig} ({done} done before); "
          f"manifest {Path(args.out) / 'session.json'}", flush=True)
    launch_args = list(args.launch_arg)
    if args.rig == "sim":
        launch_args.append(f"speed:={args.speed}")
    prompt = None
    if args.rig == "hardware" and not args.no_prompt:
        def prompt(text):
            input(text + " ")
    try:
        done = run_session(session, args.out, launch_args=launch_args, prompt=prompt,
                           log=lambda line: print(line, flush=True))
    except KeyboardInterrupt:
        return 130
    failed = [s for s in session.series if s.status == "failed"]
    print(f"{done} of {len(session.series)} series done" + (
        f"; {len(failed)} failed (run the same command again to retry them; each one's exit and last lines "
        "are in session.json)" if failed else "")
        + (f"; next: slip dataset --from-recordings {args.out} --out DATASET" if done else ""))
    return 0 if done == len(session.series) else 1


def register(subparsers) -> None:
    """Add `slip dataset` and `slip collect` to the `slip` command."""
    from incipient_slip.sim.cli import add_arguments
    p = subparsers.add_parser("dataset", help="a data set for slip train: simulated (--scene) or from a "
                              "session's recordings (--from-recordings)")
    add_arguments(p)
    p.description += (" With --from-recordings DIR instead: the series of a collection session (slip collect) "
                      "or of a directory of collect.yaml recordings, on any rig, become the same data-set "
                      "format: the streams as recorded, F_N per period from the robot (else P_DC), F_T from the "
                      "spring's extension (stage position less the object's travel); a recording that cannot "
                      "be a series (missing topic, seq gap, clock jump, unfinished file, too few periods) is "
                      "left out and named in the report (printed, and import_report.json in --out). A session "
                      "with and without injection gives OUT/injection and OUT/no_injection. "
                      "docs/hardware/workflow.md")
    p.add_argument("--from-recordings", metavar="DIR", help="a session directory (slip collect) or a directory "
                   "of collection recordings (*.mcap) to import instead of simulating")
    p.add_argument("--spring-n-per-mm", type=float, metavar="K", help="--from-recordings: the spring constant "
                   "(N/mm) measured on your rig (else --rig-config's calibration; default: the simulated rig's for "
                   "sim and emulated recordings)")
    p.add_argument("--rig-config", metavar="FILE", help="--from-recordings: your rig.yaml; the spring constant "
                   "comes from the calibration it names (slip calibrate spring --config FILE)")
    p.add_argument("--normal-force", default="auto", metavar="auto|robot|pdc", help="--from-recordings: F_N per "
                   "period from the robot's applied force (robot), P_DC above its tare (pdc), or robot where "
                   "recorded else pdc (auto, the default)")
    p.set_defaults(func=cmd_dataset)

    c = subparsers.add_parser(
        "collect", help="a collection session: the paper's series (materials x series x injection) as recordings",
        description="Run the paper's data collection as one `launch collect.yaml` per series: series i is "
        "material MATERIALS[i % n] with seed series_seed(--seed, i) (slip dataset's rule), each with the PZT "
        "noise on and/or off (--injection), one MCAP recording per series under OUT/injection and "
        "OUT/no_injection, and OUT/session.json saying what each file is and whether it is done. Rerun the "
        "same command to resume after a crash, Ctrl-C or failed series (only the missing ones run); another "
        "plan in the same OUT is refused. On rig hardware it asks before each series (reset the object, "
        "change the material). Then: slip dataset --from-recordings OUT --out DATASET. "
        "docs/hardware/workflow.md")
    c.add_argument("--out", required=True, help="session directory (created; resumed when it holds this session)")
    c.add_argument("--rig", default="sim", choices=("sim", "emulated", "hardware"), help="which rig (default sim)")
    c.add_argument("--materials", nargs="+", default=list(PAPER_MATERIALS), metavar="NAME",
                   help=f"objects, in order (default: {' '.join(PAPER_MATERIALS)})")
    c.add_argument("--series-per-material", type=int, default=100, metavar="N", help="series of each material "
                   "(default 100, the paper's)")
    c.add_argument("--seed", type=int, default=0, help="session seed (default 0): F_N draws and the simulated rig")
    c.add_argument("--injection", default="both", choices=("both", "on", "off"), help="PZT noise on, off or both "
                   "(default both: the injection method's and the vibrotactile baseline's data)")
    c.add_argument("--steps", type=int, default=450, help="periods per series (default 450, the paper's)")
    c.add_argument("--params", metavar="OVERLAY", help="an identified rig's params overlay (rig sim)")
    c.add_argument("--speed", type=float, default=50.0, help="rig sim: x real time (default 50: 8 s a series on "
                   "2 quiet cores; a series that loses messages on a busy machine fails and is rerun: lower it)")
    c.add_argument("--launch-arg", action="append", default=[], metavar="NAME:=VALUE",
                   help="passed to each launch (e.g. rig_config:=my_rig.yaml biotac_port:=/dev/ttyACM1)")
    c.add_argument("--no-prompt", action="store_true", help="rig hardware: do not ask before each series")
    c.set_defaults(func=cmd_collect)
