"""A collection session: the paper's data collection as many `launch collect.yaml` runs, one
recording per series, with a manifest that says what each file is and how far the session got.

Series i of a session with seed S is material materials[i % n] and seed `series_seed(S, i)`, the
rule of `slip dataset`, so a session on the simulated rig imports to the data set `slip dataset`
writes in-process (docs/design.md); with `injection both` each series is run with and without
the PZT noise (the same F_N draws), into injection/ and no_injection/.

The manifest (`session.json`) is rewritten (atomically) after every series: a crash or Ctrl-C
loses at most the series running then, which stays `pending` and is collected again on the next
start with the same plan (a plan that differs is refused, naming what differs). A series counts
as done only when its launch exited 0 and its recording is a finished file with every period.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

from incipient_slip.paths import written_atomically

MANIFEST = "session.json"
FORMAT = "incipient-slip-session"
VERSION = 1
RIGS = ("sim", "emulated", "hardware")
INJECTION = {"both": (True, False), "on": (True,), "off": (False,)}
PLAN_KEYS = ("rig", "materials", "series_per_material", "seed", "injection", "steps", "params")


class SessionError(ValueError):
    """A session directory or plan that cannot be used; the message says why and what to do."""


@dataclass
class SeriesEntry:
    """One series of the session and what became of it."""

    index: int
    material: str
    seed: int
    injection: bool
    file: str                  # relative to the session directory
    status: str = "pending"    # pending | done | failed
    exit_code: int | None = None
    seconds: float | None = None
    periods: int | None = None
    detail: str = ""


@dataclass
class Session:
    rig: str
    materials: list
    series_per_material: int
    seed: int
    injection: str
    steps: int
    params: str = ""
    series: list = field(default_factory=list)

    def plan(self) -> dict:
        return {k: getattr(self, k) for k in PLAN_KEYS}

    def to_plain(self) -> dict:
        return {"format": FORMAT, "version": VERSION, **self.plan(),
                "series": [asdict(s) for s in self.series]}


def plan_session(rig: str, materials, series_per_material: int, seed: int, injection: str = "both",
                 steps: int = 450, params: str = "") -> Session:
    """The session's series, in index order (which material and seed each one is)."""
    from incipient_slip.sim.rig import series_seed
    if rig not in RIGS:
        raise SessionError(f"rig {rig!r} is not one of {', '.join(RIGS)}")
    if injection not in INJECTION:
        raise SessionError(f"injection {injection!r} is not one of {', '.join(INJECTION)}")
    if not materials:
        raise SessionError("no materials given")
    if series_per_material < 1 or not 1 <= steps <= 100000:
        raise SessionError("series per material must be >= 1 and steps in 1..100000")
    session = Session(rig, list(materials), int(series_per_material), int(seed), injection, int(steps), params)
    n = len(materials) * series_per_material
    for inj in INJECTION[injection]:
        sub = "injection" if inj else "no_injection"
        for i in range(n):
            session.series.append(SeriesEntry(i, materials[i % len(materials)], series_seed(seed, i), inj,
                                              f"{sub}/series_{i:05d}.mcap"))
    return session


def load_manifest(where: str | Path) -> Session:
    path = Path(where) / MANIFEST
    try:
        plain = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise SessionError(f"{path}: cannot read the session manifest ({exc})") from None
    if plain.get("format") != FORMAT or plain.get("version") != VERSION:
        raise SessionError(f"{path}: not a version-{VERSION} session manifest")
    try:
        series = [SeriesEntry(**s) for s in plain.pop("series")]
        return Session(**{k: plain[k] for k in PLAN_KEYS}, series=series)
    except (KeyError, TypeError) as exc:
        raise SessionError(f"{path}: malformed session manifest ({exc})") from None


def save_manifest(session: Session, where: str | Path) -> None:
    where = Path(where)
    with written_atomically(where / MANIFEST) as tmp:      # whole or the previous one
        tmp.write_text(json.dumps(session.to_plain(), indent=1))


def open_session(where: str | Path, planned: Session) -> Session:
    """The session to run in `where`: the planned one, or the one there to resume (same plan)."""
    where = Path(where)
    if not (where / MANIFEST).is_file():
        if where.is_dir() and any(where.rglob("*.mcap")):
            raise SessionError(f"{where} holds recordings but no {MANIFEST}; choose an empty directory")
        return planned
    there = load_manifest(where)
    differs = {k: (there.plan()[k], v) for k, v in planned.plan().items() if there.plan()[k] != v}
    if differs:
        what = "; ".join(f"{k} {a!r} there, {b!r} asked" for k, (a, b) in differs.items())
        raise SessionError(f"{where} holds another session ({what}); resume it with its own arguments "
                           "or choose another directory")
    return there


def series_command(session: Session, entry: SeriesEntry, out: Path, launch_args=()) -> list[str]:
    """The `launch collect.yaml` command line of one series."""
    args = [f"rig:={session.rig}", f"material:={entry.material}", f"seed:={entry.seed}",
            f"injection:={'true' if entry.injection else 'false'}", f"steps:={session.steps}", f"out:={out}"]
    if session.params:
        args.append(f"params:={session.params}")
    return [sys.executable, "-m", "incipient_slip.graph.launch", "collect.yaml", *args, *launch_args]


def check_recording(path: Path, steps: int) -> tuple[int, str]:
    """(periods recorded, "" or what is wrong) of a series' recording."""
    from incipient_slip.graph.bag import BagError, bag_info
    from incipient_slip.messages import ActuatorState
    try:
        info = bag_info(path)
    except BagError as exc:
        return 0, exc.reason
    ticks = next((t.count for t in info.topics if t.topic == ActuatorState.TOPIC), 0)
    if ticks != steps:
        return ticks, f"{ticks} of {steps} periods recorded"
    from .recordings import TOPICS        # what the import reads: a message lost there drops the series
    lost = {t.topic: t.seq_gaps for t in info.topics if t.topic in TOPICS and t.seq_gaps}
    if lost:
        return ticks, "messages lost on the way to the recorder (" + ", ".join(
            f"{n} on {topic}" for topic, n in sorted(lost.items())) + "); a busy machine: a lower --speed"
    return ticks, ""


def run_session(session: Session, where: str | Path, *, launch_args=(), prompt=None, log=print) -> int:
    """Collect every series not done yet; return how many are done. Ctrl-C stops after saving the
    manifest (the running series stays pending) and re-raises KeyboardInterrupt.

    prompt(text): asked before each series on a real rig (change the object, reset it); None: none."""
    where = Path(where)
    for sub in {Path(s.file).parent for s in session.series}:
        (where / sub).mkdir(parents=True, exist_ok=True)
    save_manifest(session, where)
    todo = [s for s in session.series if s.status != "done"]
    if session.rig == "hardware":           # one object change per material
        todo.sort(key=lambda s: (s.material, not s.injection, s.index))
    total, done_before = len(session.series), len(session.series) - len(todo)
    durations: list[float] = []
    material = None
    try:
        for n, entry in enumerate(todo, 1):
            proc = None
            try:                    # Ctrl-C anywhere in a series (a prompt, the launch): it stays pending
                if prompt is not None:
                    change = f"put the {entry.material} object on the rail; " if entry.material != material else ""
                    prompt(f"series {entry.index} ({entry.material}, injection {'on' if entry.injection else 'off'}): "
                           f"{change}reset the object to its start and press Enter")
                material = entry.material
                final = where / entry.file
                partial = final.with_name(final.stem + ".partial.mcap")
                t0 = time.monotonic()
                with _sigint_deferred():    # a Ctrl-C inside Popen would orphan a launch we cannot stop
                    proc = subprocess.Popen(series_command(session, entry, partial, launch_args),
                                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
                _, err = proc.communicate()
            except KeyboardInterrupt:
                if proc is not None:
                    _stop(proc)
                entry.status, entry.detail = "pending", "interrupted"
                raise
            with _sigint_deferred():        # a finished series is booked whole, whenever Ctrl-C comes
                _book(entry, proc, err, partial, final, session.steps, t0)
                save_manifest(session, where)
                durations.append(entry.seconds)
                left = len(todo) - n
                eta = f", about {left * sorted(durations)[len(durations) // 2]:.0f} s left" if left else ""
                log(f"[{done_before + n}/{total}] series {entry.index} {entry.material} injection "
                    f"{'on' if entry.injection else 'off'}: {entry.status} in {entry.seconds:.1f} s"
                    + (f" ({entry.detail})" if entry.status != "done" else f" ({entry.periods} periods)") + eta)
    except KeyboardInterrupt:               # in a series, or between two (the next one waits)
        save_manifest(session, where)
        waiting = next((s for s in todo if s.status == "pending"), None)
        log(f"interrupted: series {waiting.index} stays pending; run the same command to resume" if waiting
            else "interrupted after the last series")
        raise
    return sum(s.status == "done" for s in session.series)


def _book(entry: SeriesEntry, proc: subprocess.Popen, err: bytes, partial: Path, final: Path, steps: int,
          t0: float) -> None:
    """Marks a finished series done (its recording renamed into place) or failed, with why."""
    entry.seconds = round(time.monotonic() - t0, 2)
    entry.exit_code = proc.returncode
    periods, problem = check_recording(partial, steps) if partial.exists() else (0, "no recording")
    entry.periods = periods
    if proc.returncode == 0 and not problem:
        os.replace(partial, final)
        entry.status, entry.detail = "done", ""
    else:
        tail = err.decode(errors="replace").strip().splitlines()[-3:]
        entry.status = "failed"
        entry.detail = f"exit {proc.returncode}; {problem or 'recording complete'}; " + " | ".join(tail)


@contextmanager
def _sigint_deferred():
    """Holds a SIGINT that comes inside the block and raises it (KeyboardInterrupt) at its end.

    Popen forks before it returns: a KeyboardInterrupt raised in between leaves the series' launch
    running with no handle to stop it (the rerun then shared the graph with it: 240 of 120 ticks)."""
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield                      # someone else owns SIGINT (not the main thread's default)
        return
    came: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, frame: came.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if came:
        raise KeyboardInterrupt


def _stop(proc: subprocess.Popen) -> None:
    """Stops a series' launch as Ctrl-C would (its recorder finishes the file), then harder."""
    for sig, wait in ((signal.SIGINT, 15.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(proc.pid, sig)
            proc.wait(wait)
            return
        except subprocess.TimeoutExpired:
            continue
        except ProcessLookupError:
            return
