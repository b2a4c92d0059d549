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
    proc = subprocess.Popen([str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def ask(request: str) -> str:
        proc.stdin.write(request + "\n")
        proc.stdin.flush()
        answer = proc.stdout.readline().strip()
        assert answer, f"host_test exited (code {proc.poll()}) on {request!r}"
        return answer

    yield ask
    proc.stdin.close()
    assert proc.wait(timeout=10) == 0


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
