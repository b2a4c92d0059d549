"""PZT white-noise injection: the band-limited noise, its ramps and clip, and the output backends.

The paper drives a piezo stack (APA50XS through its amplifier) with white noise band-limited to
10–1100 Hz at an intensity I in dB, 0 dB being the amplifier's rated input. Labs do it from a sound
card (AC-coupled: fine for zero-mean noise). `Injector` makes the signal block by block: Gaussian
noise through a Butterworth band-pass as second-order sections whose state carries over between
blocks (no seams), scaled to unit RMS in the band, times a gain `rated_rms * 10**(I/20)` that
moves linearly over `ramp_s` whenever the target changes (start, stop, new intensity), then
clipped hard at `clip_level` (the output's full scale). Values are in the output's full-scale
units (±1.0 = the sound card's full scale).

Backends: `SoundDeviceBackend` (PortAudio through `sounddevice`, the `[hardware]` extra; the card
pulls blocks in its callback and reports underflows), `FileBackend` (a WAV file paced by an
injected clock, for tests and dry runs: a file has no clock of its own) and `NullBackend`
(backend `none`: no output).
"""
from __future__ import annotations

import math
import wave
from pathlib import Path

import numpy as np
from scipy import signal

BACKENDS = ("sounddevice", "file", "none")


class Injector:
    """Blocks of band-limited Gaussian noise with ramped gain and a hard clip.

    `set(enabled, intensity_db)` sets the target; `block(n)` returns the next n samples
    (float32). `gain` is the current RMS gain (full-scale units), `clipped_samples` counts the
    samples the clip changed.
    """

    def __init__(self, fs_hz: float, band_hz: tuple[float, float] = (10.0, 1100.0), order: int = 6,
                 rated_rms: float = 0.25, clip_level: float = 1.0, ramp_s: float = 0.03, seed: int = 0):
        low, high = band_hz
        if not 0 < low < high < fs_hz / 2:
            raise ValueError(f"band {low}-{high} Hz must lie inside (0, {fs_hz / 2:g}) Hz")
        self.fs_hz, self.band_hz = float(fs_hz), (float(low), float(high))
        self.sos = signal.butter(order, [low, high], btype="bandpass", fs=fs_hz, output="sos")
        self.zi = np.zeros((self.sos.shape[0], 2))
        # white noise of unit variance through the filter has variance mean(|H|^2) over (0, fs/2)
        _, h = signal.sosfreqz(self.sos, worN=1 << 15, fs=fs_hz)
        self.unit = 1.0 / math.sqrt(float(np.mean(np.abs(h) ** 2)))
        self.rng = np.random.default_rng(seed)
        self.rated_rms, self.clip_level = rated_rms, clip_level
        self.ramp_samples = max(1, int(round(ramp_s * fs_hz)))
        self.enabled, self.intensity_db = False, 0.0
        self.gain = 0.0
        self.target = 0.0
        self._step = 0.0
        self.clipped_samples = 0

    def target_gain(self, enabled: bool, intensity_db: float) -> float:
        """Return the RMS gain of (enabled, I): rated_rms * 10**(I/20), or 0 when off."""
        return self.rated_rms * 10.0 ** (intensity_db / 20.0) if enabled else 0.0

    def set(self, enabled: bool, intensity_db: float) -> None:
        """Sets the target; the gain reaches it linearly in one ramp from where it is now."""
        if not math.isfinite(intensity_db):
            raise ValueError(f"intensity must be finite, got {intensity_db}")
        self.enabled, self.intensity_db = bool(enabled), float(intensity_db)
        target = self.target_gain(enabled, intensity_db)
        if target != self.target:
            self.target = target
            self._step = (target - self.gain) / self.ramp_samples

    @property
    def ramping(self) -> bool:
        return self.gain != self.target

    def block(self, n: int) -> np.ndarray:
        """Return the next n output samples (float32, full-scale units)."""
        noise, self.zi = signal.sosfilt(self.sos, self.rng.standard_normal(n), zi=self.zi)
        if self.gain == self.target:
            gain = np.full(n, self.gain)
        else:
            gain = self.gain + self._step * np.arange(1, n + 1)
            done = (gain >= self.target) if self._step > 0 else (gain <= self.target)
            gain[done] = self.target
            self.gain = float(gain[-1])
        out = noise * self.unit * gain
        clipped = np.abs(out) > self.clip_level
        if clipped.any():
            self.clipped_samples += int(clipped.sum())
            np.clip(out, -self.clip_level, self.clip_level, out=out)
        return out.astype(np.float32)


class NullBackend:
    """Discards the samples (a dry run of the node without an output)."""

    name = "none"
    pulls = False

    def write(self, samples: np.ndarray) -> None:
        pass

    def close(self) -> None:
        pass


class FileBackend:
    """Writes the samples to a 16-bit mono WAV file; the node paces it with its clock."""

    name = "file"
    pulls = False

    def __init__(self, path: str | Path, fs_hz: int):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._wav = wave.open(str(self.path), "wb")
        self._wav.setnchannels(1)
        self._wav.setsampwidth(2)
        self._wav.setframerate(int(fs_hz))

    def write(self, samples: np.ndarray) -> None:
        pcm = np.clip(np.rint(samples * 32767.0), -32767, 32767).astype("<i2")
        self._wav.writeframes(pcm.tobytes())

    def close(self) -> None:
        if self._wav is not None:
            self._wav.close()
            self._wav = None


def load_sounddevice():
    """The sounddevice module, or RuntimeError saying what to install (PortAudio is a system
    library: its absence is an OSError at import)."""
    try:
        import sounddevice as sd
    except (ImportError, OSError) as exc:
        raise RuntimeError(f"the PZT's sound card needs the sounddevice package and PortAudio "
                           f"(pip install -e '.[hardware]'; apt install libportaudio2): {exc}") from None
    return sd


def output_device(device: str) -> int | str | None:
    """sounddevice's device argument from a launch arg: '' the default output (None), digits an
    index (sounddevice searches a string as a name: ':=3' never found device 3), else a name."""
    device = str(device).strip()
    return None if not device else int(device) if device.isdigit() else device


def check_output_device(device: str = "", fs_hz: int = 48000) -> str:
    """"" when sounddevice loads and `device` ('' = the default output) takes a mono float32
    stream at fs_hz, else the line naming what is wrong (rig_check's)."""
    try:
        sd = load_sounddevice()
        sd.check_output_settings(device=output_device(device), channels=1, dtype="float32", samplerate=fs_hz)
    except RuntimeError as exc:
        return f"pzt: {exc}"
    except Exception as exc:     # sounddevice.PortAudioError, ValueError (no such device)
        return (f"pzt: sound card {device or '(the default output)'} cannot play mono float32 at "
                f"{fs_hz} Hz: {exc}")
    return ""


class SoundDeviceBackend:
    """A sound card through PortAudio: the card pulls each block in its callback."""

    name = "sounddevice"
    pulls = True

    def __init__(self, injector: Injector, fs_hz: int, block: int, device: str = ""):
        sd = load_sounddevice()
        self.injector = injector
        self.underflows = 0

        def callback(outdata, frames, time_info, status):
            if status.output_underflow:
                self.underflows += 1
            outdata[:, 0] = injector.block(frames)

        self.stream = sd.OutputStream(samplerate=fs_hz, blocksize=block, channels=1, dtype="float32",
                                      device=output_device(device), callback=callback)
        self.stream.start()

    def close(self) -> None:
        self.stream.stop()
        self.stream.close()


def read_wav(path: str | Path) -> tuple[np.ndarray, int]:
    """Return (samples in full-scale units, sample rate) of a 16-bit mono WAV file."""
    with wave.open(str(path), "rb") as wav:
        if wav.getsampwidth() != 2 or wav.getnchannels() != 1:
            raise ValueError(f"{path}: expected 16-bit mono PCM")
        data = np.frombuffer(wav.readframes(wav.getnframes()), dtype="<i2")
        return data.astype(np.float64) / 32767.0, wav.getframerate()


class Pacer:
    """Paces a push backend (file, none) by a clock, as a sound card's buffer would.

    `blocks_due(now_s)` returns (silent, noisy): the blocks to write now so that `buffer_blocks`
    stay queued ahead of the sink, which consumes `fs_hz` samples per second from the first call.
    When the sink has consumed more than was written, it ran dry: one underflow is counted and
    the gap is filled with silence, so the output's timeline stays true to the clock.
    """

    def __init__(self, fs_hz: float, block: int, buffer_blocks: int = 4):
        self.fs_hz, self.block, self.buffer_blocks = fs_hz, block, buffer_blocks
        self.t0: float | None = None
        self.written = 0
        self.underflows = 0

    def blocks_due(self, now_s: float) -> tuple[int, int]:
        if self.t0 is None:
            self.t0 = now_s
        consumed = int((now_s - self.t0) * self.fs_hz // self.block)
        silent = max(0, consumed - self.written)
        if silent:
            self.underflows += 1
        noisy = consumed + self.buffer_blocks - self.written - silent
        self.written += silent + noisy
        return silent, noisy
