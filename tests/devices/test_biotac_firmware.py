"""The bridge firmware's frame code (firmware/biotac_bridge/biotac_frame.cpp), compiled on this
machine with the system C++ compiler, packs exactly the bytes the Python side packs and parses."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.devices import biotac as bt

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware" / "biotac_bridge"
CXX = shutil.which("g++") or shutil.which("c++") or shutil.which("clang++")


def line_dialogue(exe: Path, check):
    """Runs `exe` and yields ask(request) -> its answer line; `check(proc, request, answer)` gives
    (ok, message) for the answer's assertion. The process must exit 0 when its stdin closes."""
    proc = subprocess.Popen([str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def ask(request: str) -> str:
        proc.stdin.write(request + "\n")
        proc.stdin.flush()
        answer = proc.stdout.readline().strip()
        ok, message = check(proc, request, answer)
        assert ok, message
        return answer

    yield ask
    proc.stdin.close()
    assert proc.wait(timeout=10) == 0


@pytest.fixture(scope="module")
def host_test(tmp_path_factory):
    """A running host_test process; requests go to its stdin, answers come from its stdout."""
    if CXX is None:
        pytest.skip("no C++ compiler (g++, c++ or clang++) on PATH: the firmware's host test cannot be built")
    exe = tmp_path_factory.mktemp("fw") / "host_test"
    build = subprocess.run([CXX, "-std=c++17", "-Wall", "-Wextra", "-Werror", "-O1", f"-I{FIRMWARE}",
                            str(FIRMWARE / "test" / "host_test.cpp"), str(FIRMWARE / "biotac_frame.cpp"),
                            "-o", str(exe)], capture_output=True, text=True, timeout=120)
    assert build.returncode == 0, build.stderr
    yield from line_dialogue(exe, lambda proc, request, answer: (
        answer, f"host_test exited (code {proc.poll()}) on {request!r}"))


def test_firmware_schedule_is_the_python_schedule(host_test):
    assert bytes.fromhex(host_test("schedule")) == bt.FRAME_SCHEDULE


def test_firmware_command_bytes_and_parity_match(host_test):
    assert bytes.fromhex(host_test("commands")) == bytes(bt.with_odd_parity(0x40 | i) for i in range(64))
    assert bytes.fromhex(host_test("parity")) == bytes(bt.with_odd_parity(i) for i in range(128))


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300))
def test_firmware_crc_matches(host_test, data):
    assert int(host_test(f"crc {data.hex() or '-'}"), 16) == bt.crc16(data)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, bt.MAX_BIOTACS), counter=st.integers(0, 2**32 - 1),
       time_us=st.integers(0, 2**32 - 1), status=st.integers(0, 0xFFFF),
       pattern=st.integers(0, 0xFFFF), data=st.data())
def test_firmware_data_frame_is_byte_identical_and_parses(host_test, n, counter, time_us, status, pattern, data):
    replies = data.draw(st.binary(min_size=88 * n, max_size=88 * n))
    packed = bytes.fromhex(host_test(f"data {counter} {time_us} {n} {status} {pattern} {replies.hex()}"))
    assert packed == bt.pack_data_frame(counter, time_us, replies, n, status=status, pattern=pattern)
    [frame] = bt.FrameParser().feed(packed)
    assert frame == bt.DataFrame(n, counter, time_us, pattern, replies, status)


@settings(max_examples=60, deadline=None)
@given(sensor=st.integers(0, bt.MAX_BIOTACS - 1), pid=st.sampled_from(sorted(bt.PROPERTY_NAMES)),
       payload=st.binary(max_size=bt.PROPERTY_MAX_BYTES))
def test_firmware_property_frame_is_byte_identical_and_parses(host_test, sensor, pid, payload):
    packed = bytes.fromhex(host_test(f"prop {sensor} {pid} {payload.hex() or '-'}"))
    assert packed == bt.pack_property_frame(sensor, pid, payload)
    assert bt.FrameParser().feed(packed) == [bt.PropertyFrame(sensor, pid, payload)]


def test_firmware_refuses_what_python_refuses(host_test):
    assert host_test("data 0 0 6 0 0 " + "00" * 88 * 6).startswith("error")
    with pytest.raises(ValueError):
        bt.pack_data_frame(0, 0, b"\0" * 88 * 6, 6)
    assert host_test("prop 0 21 " + "41" * 65).startswith("error")
    with pytest.raises(ValueError):
        bt.pack_property_frame(0, 21, b"A" * 65)


# --- the sketch itself (biotac_bridge.ino: setup(), loop()) against a stub Arduino API ---------

SKETCH = FIRMWARE / "biotac_bridge.ino"
STUB = FIRMWARE / "test" / "stub"


def build_sketch(tmp_path, sketch_text: str | None = None):
    """Compiles test/sketch_test.cpp with the sketch (or a variant of its text); the result."""
    sketch_dir = FIRMWARE
    if sketch_text is not None:               # a variant: the same files, this sketch text
        sketch_dir = tmp_path / "biotac_bridge"
        (sketch_dir / "test").mkdir(parents=True)
        (sketch_dir / "biotac_bridge.ino").write_text(sketch_text)
        (sketch_dir / "test" / "sketch_test.cpp").write_text((FIRMWARE / "test" / "sketch_test.cpp").read_text())
    exe = tmp_path / "sketch_test"
    build = subprocess.run([CXX, "-std=c++17", "-Wall", "-Wextra", "-Werror", "-O1", f"-I{FIRMWARE}", f"-I{STUB}",
                            str(sketch_dir / "test" / "sketch_test.cpp"), str(FIRMWARE / "biotac_frame.cpp"),
                            "-o", str(exe)], capture_output=True, text=True, timeout=120)
    return build, exe


@pytest.fixture
def sketch(tmp_path):
    """ask(request) -> answer line, against a running build of the sketch on the stub."""
    if CXX is None:
        pytest.skip("no C++ compiler (g++, c++ or clang++) on PATH: the sketch cannot be built")
    build, exe = build_sketch(tmp_path)
    assert build.returncode == 0, build.stderr
    yield from line_dialogue(exe, lambda proc, request, answer: (
        answer and not answer.startswith("error"), f"sketch_test: {answer!r} on {request!r}"))


def frames_out(ask) -> list:
    out = ask("out")
    return [] if out == "-" else bt.FrameParser().feed(bytes.fromhex(out))


def test_the_sketch_streams_frames_the_host_parses(sketch):
    sketch("host S")
    sketch(f"loop {2 * bt.SLOTS_PER_FRAME}")
    frames = frames_out(sketch)
    assert [(f.counter, f.status, f.n_biotacs) for f in frames] == [(0, bt.STATUS_STARTED, 1), (1, 0, 1)]
    assert frames[1].device_time_us - frames[0].device_time_us in (9999, 10000, 10001)
    sketch("host X")
    sketch(f"loop {bt.SLOTS_PER_FRAME}")
    assert frames_out(sketch) == []


def test_a_frame_dropped_on_a_full_usb_queue_is_reported_by_the_next_frame(sketch):
    sketch("host S")
    sketch(f"loop {bt.SLOTS_PER_FRAME}")
    assert [f.counter for f in frames_out(sketch)] == [0]
    sketch("usb 0")                                        # the host stopped reading
    sketch(f"loop {bt.SLOTS_PER_FRAME}")
    assert frames_out(sketch) == []
    sketch("usb 4096")
    sketch(f"loop {2 * bt.SLOTS_PER_FRAME}")
    frames = frames_out(sketch)
    assert [f.counter for f in frames] == [2, 3]           # the counter went on through the drop
    assert frames[0].status == bt.STATUS_TX_DROPPED        # and the next frame says so, once
    assert frames[1].status == 0


@pytest.mark.parametrize("n", [0, bt.MAX_BIOTACS + 1])
def test_a_sketch_for_zero_or_too_many_sensors_does_not_build(tmp_path, n):
    if CXX is None:
        pytest.skip("no C++ compiler on PATH")
    text = SKETCH.read_text()
    assert "constexpr uint8_t N_BIOTACS = 1;" in text
    build, _ = build_sketch(tmp_path, text.replace("constexpr uint8_t N_BIOTACS = 1;",
                                                   f"constexpr uint8_t N_BIOTACS = {n};"))
    assert build.returncode != 0 and "N_BIOTACS must be 1 to 5" in build.stderr


ARM_CXX = shutil.which("arm-none-eabi-g++")


def test_the_sketch_compiles_for_the_teensy_4_cpu(tmp_path):
    """Cortex-M7 with its FPU, as the Teensy 4.0/4.1 (Debian: gcc-arm-none-eabi and
    libstdc++-arm-none-eabi-newlib); against the stub API, the Teensyduino core not being in
    any registry this project uses. Catches what only a 32-bit ARM build says (int widths,
    warnings as errors)."""
    if ARM_CXX is None:
        pytest.skip("no arm-none-eabi-g++ (apt-get install gcc-arm-none-eabi libstdc++-arm-none-eabi-newlib)")
    unit = tmp_path / "sketch.cpp"
    unit.write_text('#include <Arduino.h>\n#include "biotac_bridge.ino"\n')
    flags = ["-mcpu=cortex-m7", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv5-d16", "-std=gnu++17", "-O2",
             "-Wall", "-Wextra", "-Werror", "-fno-exceptions", "-fno-rtti", f"-I{FIRMWARE}", f"-I{STUB}"]
    for source in (unit, FIRMWARE / "biotac_frame.cpp"):
        build = subprocess.run([ARM_CXX, *flags, "-c", str(source), "-o", str(tmp_path / f"{source.stem}.o")],
                               capture_output=True, text=True, timeout=120)
        assert build.returncode == 0, build.stderr
