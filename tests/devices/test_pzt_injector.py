"""PZT noise injection (devices/pzt.py, nodes/pzt_injector.py) recorded through the file backend:
the band holds the power, the gain follows I in dB, ramps are linear over ramp_s, the clip is
hard, underflows are counted, and the node ramps to zero when the graph's heartbeat stops."""
from __future__ import annotations

import os
from signal import SIGTERM

import numpy as np
import pytest
from scipy import signal

from incipient_slip.devices import pzt
from incipient_slip.graph.runtime import Node
from incipient_slip.messages import Heartbeat, PztCommand, PztOutput, PztState
from waiting import spin_until

FS, BLOCK = 48000, 480


def record(tmp_path, schedule, seconds, **kw):
    """Runs an Injector into a WAV file on an injected clock; schedule: {time_s: (enabled, dB)}."""
    injector = pzt.Injector(FS, **kw)
    out = pzt.FileBackend(tmp_path / "pzt.wav", FS)
    pacer = pzt.Pacer(FS, BLOCK, buffer_blocks=1)
    t, k = 0.0, 0
    pending = sorted(schedule.items())
    injector.changed_at = []        # the sample each change took effect at
    while t <= seconds:
        while pending and pending[0][0] <= t:
            injector.set(*pending.pop(0)[1])
            injector.changed_at.append(pacer.written * BLOCK)
        silent, noisy = pacer.blocks_due(t)
        out.write(np.zeros(silent * BLOCK, np.float32))
        for _ in range(noisy):
            out.write(injector.block(BLOCK))
        k += 1
        t = (k * BLOCK + 0.5) / FS      # the clock advances one block per step
    out.close()
    assert pacer.underflows == 0
    samples, fs = pzt.read_wav(tmp_path / "pzt.wav")
    assert fs == FS
    return samples, injector, pacer


def test_band_power_is_inside_10_to_1100_hz(tmp_path):
    x, _, _ = record(tmp_path, {0.0: (True, 0.0)}, 4.0)
    f, psd = signal.welch(x[FS // 10:], fs=FS, nperseg=1 << 14)
    inside = (f >= 10) & (f <= 1100)
    passband = psd[(f >= 100) & (f <= 900)].mean()
    # a 6th-order Butterworth edge leaves ~6 % of the power in its skirt just outside the band
    assert psd[inside].sum() / psd.sum() > 0.92
    assert psd[(f >= 2150) & (f <= 2250)].mean() < 10 ** (-30 / 10) * passband     # one octave up
    assert psd[(f >= 3000) & (f <= 20000)].mean() < 10 ** (-40 / 10) * passband
    assert psd[(f > 0) & (f <= 3)].mean() < 10 ** (-20 / 10) * passband


@pytest.mark.parametrize("intensity_db", [0.0, -6.0, -20.0])
def test_rms_follows_intensity_in_db(tmp_path, intensity_db):
    x, _, _ = record(tmp_path, {0.0: (True, intensity_db)}, 3.0, rated_rms=0.2)
    rms = np.sqrt(np.mean(x[FS // 5:] ** 2))
    assert rms == pytest.approx(0.2 * 10 ** (intensity_db / 20), rel=0.05)


def test_start_stop_and_intensity_changes_ramp_linearly_over_ramp_s(tmp_path):
    ramp_s = 0.03
    x, injector, _ = record(tmp_path, {0.0: (True, 0.0), 1.0: (True, -6.0), 2.0: (False, -6.0)}, 3.0,
                            ramp_s=ramp_s, seed=4)
    # the same seed without ramps gives the noise itself: the ratio is the gain, sample by sample
    ref_injector = pzt.Injector(FS, ramp_s=ramp_s, seed=4, rated_rms=1.0, clip_level=1e9)
    ref_injector.gain = ref_injector.target = 1.0
    ref = np.concatenate([ref_injector.block(BLOCK) for _ in range(len(x) // BLOCK)])
    n = int(ramp_s * FS)
    quant = 1.5 / 32767

    def gain_matches(start, g0, g1):
        idx = np.arange(start, start + n)
        expected_gain = g0 + (g1 - g0) * (np.arange(1, n + 1) / n)
        assert np.abs(x[idx] - ref[idx] * expected_gain).max() < quant
        after = np.arange(start + n, start + n + 1000)
        assert np.abs(x[after] - ref[after] * g1).max() < quant

    # each change takes effect at the next block the sink has not queued yet
    start, change, stop = injector.changed_at
    assert start == 0 and 0 <= change - FS <= 2 * BLOCK and 0 <= stop - 2 * FS <= 2 * BLOCK
    gain_matches(start, 0.0, 0.25)
    gain_matches(change, 0.25, 0.25 * 10 ** (-6 / 20))
    gain_matches(stop, 0.25 * 10 ** (-6 / 20), 0.0)
    assert np.all(x[stop + n:] == 0.0)


def test_clip_is_hard_and_counted(tmp_path):
    x, injector, _ = record(tmp_path, {0.0: (True, 12.0)}, 1.0, rated_rms=0.5, clip_level=0.8)
    assert np.abs(x).max() <= 0.8 + 1 / 32767
    assert injector.clipped_samples > 0
    assert np.sum(np.abs(x) >= 0.8 - 1 / 32767) == pytest.approx(injector.clipped_samples, rel=0.01)


def test_a_late_clock_is_an_underflow_filled_with_silence():
    pacer = pzt.Pacer(FS, BLOCK, buffer_blocks=2)
    assert pacer.blocks_due(0.0) == (0, 2)
    assert pacer.blocks_due(0.01) == (0, 1)
    assert pacer.blocks_due(0.1) == (7, 2)         # consumed 10 blocks, 3 were written
    assert pacer.underflows == 1
    assert pacer.written == 12


def test_band_outside_the_nyquist_range_is_refused():
    with pytest.raises(ValueError, match="band"):
        pzt.Injector(2000, band_hz=(10.0, 1100.0))


class Commander(Node):
    def __init__(self, graph_dir):
        super().__init__("test_commander", graph_dir=graph_dir, heartbeat_s=0)
        self.states, self.outputs = [], []
        self.create_subscription(PztState, self.states.append)
        self.create_subscription(PztOutput, self.outputs.append)
        self.cmd = self.create_publisher(PztCommand)
        self.hb = self.create_publisher(Heartbeat)

    def spin_until(self, predicate, proc, timeout_s=30.0, beat=True):
        def spin():
            if beat:
                self.hb.publish(Heartbeat(node=self.name, pid=os.getpid()))
            self.spin_once(0.02)
        spin_until(spin, predicate, timeout_s, [proc], "the pzt injector")


def test_node_ramps_to_zero_when_the_heartbeat_stops_and_on_shutdown(graph, tmp_path):
    wav = tmp_path / "out.wav"
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.pzt_injector", "backend:=file", f"path:={wav}",
                        "heartbeat_timeout_s:=0.5", "state_period_s:=0.05"])
    probe = Commander(graph.dir)
    try:
        while not probe.cmd.wait_for_subscribers(1, 0.1):
            assert proc.poll() is None, proc.stderr.read().decode()
        command = PztCommand(enabled=True, intensity_db=0.0)
        probe.cmd.publish(command)

        def playing():
            if probe.states and not probe.states[-1].enabled and probe.outputs:
                probe.cmd.publish(command)     # a stall of this process looked like a dead graph
            return probe.outputs and probe.outputs[-1].output_rms == pytest.approx(0.25)

        probe.spin_until(playing, proc)
        assert probe.states[-1].enabled and probe.states[-1].band_high_hz == 1100.0
        # the graph goes silent: no heartbeat, no command
        probe.spin_until(lambda: not probe.states[-1].enabled and probe.outputs[-1].output_rms == 0.0,
                         proc, beat=False)
    finally:
        probe.close()
    proc.terminate()
    assert proc.wait(10) == 128 + SIGTERM
    assert "no heartbeat from the graph" in proc.stderr.read().decode()
    x, fs = pzt.read_wav(wav)
    on = np.flatnonzero(np.abs(x) > 0)
    assert len(on) > fs * 0.3                        # it did play
    assert np.all(x[on[-1] + 1:] == 0.0) and len(x) > on[-1] + 1


@pytest.mark.parametrize("argv, message", [
    (["backend:=speaker"], "backend"),
    (["backend:=none", "ramp_s:=0.2"], "ramp_s"),
    (["backend:=none", "band_high_hz:=30000", "sample_rate_hz:=48000"], "band"),
])
def test_node_refuses_bad_parameters_in_one_line(argv, message):
    import subprocess
    import sys
    proc = subprocess.run([sys.executable, "-m", "incipient_slip.nodes.pzt_injector", *argv],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_sounddevice_backend_fills_the_cards_buffers_and_counts_its_underflows(monkeypatch):
    """PortAudio is not installed here: a stand-in `sounddevice` calls the callback as the
    library does (outdata (frames, channels) float32, a status with output_underflow)."""
    import sys
    import types

    class Status:
        def __init__(self, underflow):
            self.output_underflow = underflow

    class OutputStream:
        def __init__(self, samplerate, blocksize, channels, dtype, device, callback):
            self.args = (samplerate, blocksize, channels, dtype, device)
            self.callback, self.blocks, self.state = callback, [], "new"

        def start(self):
            self.state = "started"
            for underflow in (False, True, False):
                out = np.zeros((self.args[1], self.args[2]), dtype=self.args[3])
                self.callback(out, self.args[1], None, Status(underflow))
                self.blocks.append(out)

        def stop(self):
            self.state = "stopped"

        def close(self):
            self.state = "closed"

    monkeypatch.setitem(sys.modules, "sounddevice", types.SimpleNamespace(OutputStream=OutputStream))
    injector = pzt.Injector(FS, ramp_s=0.02)
    injector.set(True, 0.0)
    backend = pzt.SoundDeviceBackend(injector, FS, BLOCK, device="")
    assert backend.stream.args == (FS, BLOCK, 1, "float32", None)
    assert backend.underflows == 1
    played = np.concatenate([b[:, 0] for b in backend.stream.blocks])
    assert np.abs(played[:10]).max() < 0.05 and np.abs(played).max() > 0.1     # ramped in
    backend.close()
    assert backend.stream.state == "closed"
