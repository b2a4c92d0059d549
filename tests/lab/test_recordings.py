"""From recordings to a data set: a collection session on the simulated rig (`slip collect`, real
launches and recordings) imports to the data set `slip dataset` writes in-process for the same
seeds, and every defect of a recording is a named drop."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from incipient_slip.graph.bag import BagWriter, read_bag
from incipient_slip.lab.recordings import RecordingError, import_recordings, read_series
from incipient_slip.lab.session import load_manifest
from incipient_slip.messages import ActuatorState, BiotacPac, RobotState
from incipient_slip.models.labels import label_series, measured_ratio_label
from incipient_slip.models.dataset import load_series
from incipient_slip.sim.dataset import write_dataset
from incipient_slip.sim.scene import load_scene

STEPS = 450          # the paper's: the object slides, so the labels have their onset
SEED = 5
MOCAP_NOISE_MM = 0.005


def slip(*args, env=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "incipient_slip.cli", *args], capture_output=True, text=True,
                          env=env, timeout=timeout)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Two series (pla, injection on) collected through `launch collect.yaml` by `slip collect`."""
    where = tmp_path_factory.mktemp("session")
    graph_dir = tempfile.mkdtemp(prefix="sg", dir="/tmp")
    env = dict(os.environ, SLIP_GRAPH_DIR=graph_dir, PYTHONUNBUFFERED="1")
    try:
        done = slip("collect", "--out", str(where), "--materials", "pla", "--series-per-material", "2",
                    "--injection", "on", "--steps", str(STEPS), "--seed", str(SEED), "--speed", "50", env=env)
    finally:
        shutil.rmtree(graph_dir, ignore_errors=True)
    assert done.returncode == 0, done.stdout + done.stderr
    return where, env


@pytest.fixture(scope="module")
def in_process(tmp_path_factory):
    out = tmp_path_factory.mktemp("in_process")
    write_dataset(load_scene("paper"), 2, SEED, out, materials=["pla"], workers=1, steps=STEPS, progress=False)
    return out


@pytest.fixture(scope="module")
def imported(session, tmp_path_factory):
    out = tmp_path_factory.mktemp("imported")
    report = import_recordings(session[0], out)
    assert not report.dropped and len(report.imported) == 2
    return out / "injection"


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("name", ["series_00000.npz", "series_00001.npz"])
def test_a_simulated_session_imports_to_the_in_process_data_set(imported, in_process, name):
    got, ref = np.load(imported / name), np.load(in_process / name)
    assert set(ref.files) <= set(got.files)
    for key in ("pac_counts", "electrode_counts", "pdc_counts", "tac_counts", "tdc_counts", "mocap_y_mm",
                "period_end_s", "normal_force_kpa", "actuator_mm", "stick_area_ratio", "load_ratio_stick",
                "gross_slip", "material", "injection", "seed"):
        assert np.array_equal(got[key], ref[key]), key            # exactly what the simulator made
    assert np.max(np.abs(got["mocap_t_s"] - ref["mocap_t_s"])) <= 1e-9       # stamps are integer ns
    # F_T and y are measured: the object's last mocap sample of the period (noise 0.005 mm, 8 ms
    # before the end) where the in-process set has the simulator's true y at the end
    k_s = load_scene("paper").params["stick_slip"]["spring_n_per_mm"]
    assert np.max(np.abs(got["object_y_mm"] - ref["object_y_mm"])) <= 5 * MOCAP_NOISE_MM
    assert np.max(np.abs(got["tangential_force_n"] - ref["tangential_force_n"])) <= 5 * MOCAP_NOISE_MM * k_s


@pytest.mark.slow
def test_labels_from_the_recordings_match_the_in_process_ones(imported, in_process):
    got, ref = load_series(imported / "series_00000.npz"), load_series(in_process / "series_00000.npz")
    lab_got, lab_ref = label_series(got), label_series(ref)
    assert lab_got.gross_slip_index == lab_ref.gross_slip_index > 0                   # the same onset of gross slip
    assert np.nanmax(np.abs(lab_got.pseudo_stick_ratio - lab_ref.pseudo_stick_ratio)) < 0.02
    m_got = measured_ratio_label(got.tangential_force_n, got.normal_force_kpa, lab_got.travel_mm)
    m_ref = measured_ratio_label(ref.tangential_force_n, ref.normal_force_kpa, lab_ref.travel_mm)
    assert np.isfinite(m_got).all() and np.max(np.abs(m_got - m_ref)) < 0.03


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_model_trained_on_the_import_equals_the_in_process_one(imported, in_process):
    """Trained on both sets (every series): with the simulator's true label the windows and targets
    are the same floats, so is the model; with the measured label it is close (F_T is measured)."""
    from incipient_slip.models.features import feature_spec
    from incipient_slip.models.training import load_windows, train_model
    spec = feature_spec("injection")
    preds = {}
    x = None
    for label in ("true-ratio", "measured-ratio"):
        sets = {name: load_windows(d, spec, label=label, progress=False)
                for name, d in (("imported", imported), ("in_process", in_process))}
        assert np.array_equal(sets["imported"].X, sets["in_process"].X)
        x = sets["in_process"].X if x is None else x
        for name, ws in sets.items():
            preds[name, label] = train_model(ws, "svr", quick=True, progress=False).model.predict(x)
    assert np.array_equal(preds["imported", "true-ratio"], preds["in_process", "true-ratio"])
    assert np.max(np.abs(preds["imported", "measured-ratio"] - preds["in_process", "measured-ratio"])) < 0.05


@pytest.mark.slow
def test_the_manifest_says_what_each_file_is_and_a_rerun_resumes(session):
    where, env = session
    manifest = load_manifest(where)
    assert [(e.index, e.status, e.material, e.injection, e.periods) for e in manifest.series] == [
        (0, "done", "pla", True, STEPS), (1, "done", "pla", True, STEPS)]
    assert all((where / e.file).is_file() for e in manifest.series) and not list(where.rglob("*.partial.mcap"))
    again = slip("collect", "--out", str(where), "--materials", "pla", "--series-per-material", "2",
                 "--injection", "on", "--steps", str(STEPS), "--seed", str(SEED), "--speed", "50", env=env)
    assert again.returncode == 0 and "(2 done before)" in again.stdout and "[" not in again.stdout
    other = slip("collect", "--out", str(where), "--materials", "pla", "abs", "--series-per-material", "2",
                 "--injection", "on", "--steps", str(STEPS), "--seed", str(SEED), env=env)
    assert other.returncode == 2 and "holds another session" in other.stderr and "materials" in other.stderr


# --- defects: each a named drop -----------------------------------------------------------------

def copy_recording(src: Path, dst: Path, keep=lambda rec, i: True, stamp=None, finish: bool = True) -> Path:
    """A copy of a recording with records left out or restamped (what a real rig's faults look like)."""
    import dataclasses

    from incipient_slip.lab.recordings import read_metadata
    from incipient_slip.messages import encode
    w = BagWriter(dst, metadata=read_metadata(src))
    count: dict = {}
    for rec in read_bag(src):
        i = count[rec.topic] = count.get(rec.topic, -1) + 1
        if not keep(rec, i):
            continue
        body, stamp_ns = rec.body, rec.stamp_ns
        if stamp is not None and stamp(rec, i) != rec.stamp_ns:
            stamp_ns = stamp(rec, i)
            body = encode(dataclasses.replace(rec.message(), stamp_ns=stamp_ns, seq=rec.message().seq))
        w.write_body(rec.topic, rec.type_name, body, log_time_ns=rec.log_time_ns, stamp_ns=stamp_ns, seq=rec.sequence)
    if finish:
        w.close()
    else:
        w.flush()
        w._file.close()          # a recorder killed mid-run: no summary, no footer
    return dst


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A short series through `launch collect.yaml` (12 periods: enough for every defect)."""
    out = tmp_path_factory.mktemp("short") / "series.mcap"
    graph_dir = tempfile.mkdtemp(prefix="sg", dir="/tmp")
    env = dict(os.environ, SLIP_GRAPH_DIR=graph_dir, PYTHONUNBUFFERED="1")
    try:
        done = subprocess.run([sys.executable, "-m", "incipient_slip.graph.launch", "collect.yaml", "steps:=12",
                               "speed:=50", "seed:=3", "material:=pla", f"out:={out}"],
                              capture_output=True, text=True, env=env, timeout=120)
    finally:
        shutil.rmtree(graph_dir, ignore_errors=True)
    assert done.returncode == 0, done.stderr[-3000:]
    return out


@pytest.mark.parametrize("fault, expected", [
    (dict(keep=lambda rec, i: not (rec.topic == BiotacPac.TOPIC and 100 <= i < 103)),
     "seq gap on /biotac/pac: 3 message"),
    (dict(keep=lambda rec, i: rec.topic != ActuatorState.TOPIC), "no messages on /actuator/state"),
    (dict(stamp=lambda rec, i: rec.stamp_ns + (2_000_000_000 if rec.topic == BiotacPac.TOPIC and i >= 500 else 0)),
     "clock jump on /biotac/pac: 2.010 s"),
    (dict(stamp=lambda rec, i: rec.stamp_ns - (3_000_000_000 if rec.topic == BiotacPac.TOPIC and i >= 500 else 0)),
     "clock went back on /biotac/pac"),
    (dict(keep=lambda rec, i: rec.topic != ActuatorState.TOPIC or i < 2), "only 2 period(s) recorded"),
    (dict(finish=False), "slip bag recover"),
])
def test_a_defective_recording_is_a_named_drop(recording, tmp_path, fault, expected):
    bad = copy_recording(recording, tmp_path / "bad.mcap", **fault)
    with pytest.raises(RecordingError, match=expected.replace("(", r"\(").replace(")", r"\)")):
        read_series(bad)


def test_a_session_import_reports_the_drops_and_keeps_the_rest(recording, tmp_path):
    src = tmp_path / "recordings"
    src.mkdir()
    shutil.copy(recording, src / "a_good.mcap")
    copy_recording(recording, src / "b_gap.mcap", keep=lambda rec, i: not (rec.topic == BiotacPac.TOPIC and i == 7))
    out = tmp_path / "data"
    done = slip("dataset", "--from-recordings", str(src), "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert "imported 1 series" in done.stdout and "b_gap.mcap: seq gap on /biotac/pac" in done.stdout
    report = json.loads((out / "import_report.json").read_text())
    assert [d["file"].endswith("b_gap.mcap") for d in report["dropped"]] == [True]
    assert sorted(p.name for p in (out / "injection").glob("series_*.npz")) == ["series_00000.npz"]


def test_a_real_rigs_recording_needs_its_spring_constant_and_takes_f_n_from_p_dc(recording, tmp_path):
    """A hardware recording (no robot in the launch: F_N held by hand) reads F_N from P_DC above
    its tare, and F_T needs the rig's measured spring constant."""
    from incipient_slip.lab.recordings import read_metadata
    meta = {**read_metadata(recording), "rig": "hardware"}
    dst = tmp_path / "hw.mcap"
    w = BagWriter(dst, metadata=meta)
    for rec in read_bag(recording):
        if rec.topic != RobotState.TOPIC:
            w.write_body(rec.topic, rec.type_name, rec.body, log_time_ns=rec.log_time_ns, stamp_ns=rec.stamp_ns,
                         seq=rec.sequence)
    w.close()
    with pytest.raises(RecordingError, match="spring constant is unknown"):
        read_series(dst)
    src = tmp_path / "hw"
    src.mkdir()
    dst.rename(src / "hw.mcap")
    dst = src / "hw.mcap"
    (tmp_path / "rig.yaml").write_text("calibration: cal.yaml\n")
    no_spring = slip("dataset", "--from-recordings", str(src), "--out", str(tmp_path / "d0"), "--rig-config",
                     str(tmp_path / "rig.yaml"))
    assert no_spring.returncode == 2 and "slip calibrate spring" in no_spring.stderr
    (tmp_path / "cal.yaml").write_text("spring: {spring_n_per_mm: 0.0327}\n")     # what slip calibrate writes
    done = slip("dataset", "--from-recordings", str(src), "--out", str(tmp_path / "d1"), "--rig-config",
                str(tmp_path / "rig.yaml"))
    assert done.returncode == 0, done.stdout + done.stderr
    report = json.loads((tmp_path / "d1" / "import_report.json").read_text())
    assert report["imported"][0]["spring_n_per_mm"] == 0.0327
    data, notes = read_series(dst, spring_n_per_mm=0.0327)
    sim, _ = read_series(recording)
    assert notes.normal_force_from == "pdc"
    # P_DC measures the applied F_N through the fingertip's noise and lag: close, not equal
    err = np.abs(data["normal_force_kpa"] - sim["normal_force_kpa"])
    assert np.median(err) < 0.3, np.median(err)
    assert np.isnan(data["stick_area_ratio"]).all() or np.isfinite(data["stick_area_ratio"]).all()


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_ctrl_c_keeps_the_running_series_pending_and_a_rerun_collects_only_it(tmp_path):
    import signal
    where = tmp_path / "session"
    graph_dir = tempfile.mkdtemp(prefix="sg", dir="/tmp")
    env = dict(os.environ, SLIP_GRAPH_DIR=graph_dir, PYTHONUNBUFFERED="1")
    args = [sys.executable, "-m", "incipient_slip.cli", "collect", "--out", str(where), "--materials", "pla",
            "--series-per-material", "2", "--injection", "on", "--steps", "120", "--speed", "10"]
    try:
        # Ctrl-C as a terminal delivers it: a test run in the background (nohup, `&`) ignores SIGINT and
        # its children would inherit that (then the SIGINT below was lost and series 1 ran to the end)
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        for line in proc.stdout:                       # series 0 done, series 1 (6 s at 10x) running
            if line.startswith("[1/2]"):
                break
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, out + err
        assert "series 1 stays pending" in out
        assert [(e.index, e.status) for e in load_manifest(where).series] == [(0, "done"), (1, "pending")]
        again = subprocess.run(args, capture_output=True, text=True, env=env, timeout=200)
        assert again.returncode == 0, again.stdout + again.stderr
        assert "(1 done before)" in again.stdout and "[2/2] series 1" in again.stdout and "[1/2]" not in again.stdout
        assert [e.status for e in load_manifest(where).series] == ["done", "done"]
        assert not list(where.rglob("*.partial.mcap"))
    finally:
        shutil.rmtree(graph_dir, ignore_errors=True)


def test_a_late_period_is_not_a_clock_fault(recording):
    """A real stage's move can end a period late (0.9 s, seen on the emulated rig under load): the
    streams stay whole, so the series imports with that period longer; a tick going back does not."""
    shift = lambda rec, i: rec.stamp_ns + (400_000_000 if rec.topic == ActuatorState.TOPIC and i == 6 else 0)
    # (F_N from P_DC: rig_sim's one RobotState per period sits at the unshifted period start)
    data, _ = read_series(copy_recording(recording, recording.parent / "late.mcap", stamp=shift), normal_force="pdc")
    assert np.diff(data["period_end_s"])[5] == pytest.approx(0.9)
    back = lambda rec, i: rec.stamp_ns - (900_000_000 if rec.topic == ActuatorState.TOPIC and i >= 6 else 0)
    with pytest.raises(RecordingError, match="clock went back on /actuator/state"):
        read_series(copy_recording(recording, recording.parent / "back.mcap", stamp=back))


def as_written_before_v2(body: bytes) -> bytes:
    """A body as the build before ActuatorState v2, SlipEstimate v2 and GripCommand v2 wrote it
    (`step_index`, no `cause`)."""
    import msgpack
    obj = msgpack.unpackb(body)
    if obj["type"] == "ActuatorState":
        obj = {("step_index" if k == "period" else k): v for k, v in obj.items()}
    elif obj["type"] in ("SlipEstimate", "GripCommand"):
        obj.pop("cause")
    else:
        return body
    return msgpack.packb({**obj, "v": 1})


def test_a_recording_of_the_older_schema_imports_as_today(recording, tmp_path):
    old = tmp_path / "old.mcap"
    from incipient_slip.lab.recordings import read_metadata
    w = BagWriter(old, metadata=read_metadata(recording))
    for rec in read_bag(recording):
        w.write_body(rec.topic, rec.type_name, as_written_before_v2(rec.body), log_time_ns=rec.log_time_ns,
                     stamp_ns=rec.stamp_ns, seq=rec.sequence)
    w.close()
    assert any(b"step_index" in rec.body for rec in read_bag(old, [ActuatorState.TOPIC]))
    (now, _), (before, _) = read_series(recording), read_series(old)
    assert sorted(now) == sorted(before)
    assert all(np.array_equal(now[key], before[key], equal_nan=np.asarray(now[key]).dtype.kind == "f") for key in now)
