"""Masking audio: continuous white noise with cues and tones mixed in, through sounddevice/PortAudio.

Section 4.5.3: the subject wears headphones playing white noise "at a high
volume" to mask the sounds of tapping; a recorded voice tells them to tap and a
low tone marks taps whose force exceeded the amplifier limit.

The noise is generated block by block inside the PortAudio callback from a
seeded PCG64 generator (Gaussian, RMS set by ``level_dbfs``), so it never
repeats (no stored loop). Cues are precomputed arrays mixed in by the callback.
The spoken cue is spoken by ``espeak-ng`` when it is installed; otherwise it is
a synthesized three-note rising chime ("tap now") — :attr:`MaskingAudio.cue_source`
says which.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import numpy as np


class AudioUnavailable(ValueError):
    """PortAudio or an output device is missing (a real session refuses to start)."""


def load_sounddevice():
    """Import sounddevice, turning a missing PortAudio into a clear :class:`AudioUnavailable`."""
    try:
        import sounddevice
    except OSError as exc:  # the wheel does not bundle PortAudio on Linux
        raise AudioUnavailable(f"masking audio needs PortAudio ({exc}); install it with "
                               "'apt-get install libportaudio2' (or 'make system-deps')") from None
    return sounddevice


def check_output_device(device=None) -> str:
    """Return the name of the output device PortAudio would use, or raise :class:`AudioUnavailable`."""
    sd = load_sounddevice()
    try:
        info = sd.query_devices(device, "output")
    except Exception as exc:  # sounddevice raises ValueError/PortAudioError for "no device"
        raise AudioUnavailable(f"masking audio needs an audio output device, PortAudio found none ({exc}); "
                               "connect headphones or run with --device sim") from None
    return str(info["name"])


def tone(freq_hz: float, duration_s: float, fs_hz: float, amplitude: float, ramp_s: float = 0.01) -> np.ndarray:
    """A sine tone with raised-cosine on/off ramps (no clicks), float32."""
    n = int(round(duration_s * fs_hz))
    t = np.arange(n) / fs_hz
    y = amplitude * np.sin(2 * math.pi * freq_hz * t)
    nr = min(int(ramp_s * fs_hz), n // 2)
    if nr:
        ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(nr) / nr)
        y[:nr] *= ramp
        y[n - nr:] *= ramp[::-1]
    return y.astype(np.float32)


def low_tone(fs_hz: float, amplitude: float = 0.5) -> np.ndarray:
    """The saturation cue: 180 Hz for 0.3 s."""
    return tone(180.0, 0.3, fs_hz, amplitude)


def chime_cue(fs_hz: float, amplitude: float = 0.4) -> np.ndarray:
    """Synthesized 'tap now' cue: three rising notes (C5 E5 G5), 0.12 s each with 30 ms gaps."""
    gap = np.zeros(int(0.03 * fs_hz), np.float32)
    parts = []
    for f in (523.25, 659.25, 783.99):
        parts += [tone(f, 0.12, fs_hz, amplitude), gap]
    return np.concatenate(parts)


def spoken_cue(text: str, fs_hz: float, amplitude: float = 0.5) -> np.ndarray | None:
    """Speak ``text`` with espeak-ng into an array at ``fs_hz``; None when espeak-ng is not installed."""
    exe = shutil.which("espeak-ng")
    if exe is None:
        return None
    from scipy.io import wavfile
    from scipy.signal import resample_poly

    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "cue.wav"
        try:
            subprocess.run([exe, "-w", str(wav), text], check=True, capture_output=True, timeout=10)
            rate, data = wavfile.read(wav)
        except (OSError, subprocess.SubprocessError, ValueError):
            return None
    y = data.astype(np.float64)
    if y.ndim > 1:
        y = y.mean(axis=1)
    peak = np.max(np.abs(y)) or 1.0
    g = math.gcd(int(fs_hz), int(rate))
    y = resample_poly(y / peak, int(fs_hz) // g, int(rate) // g)
    return (amplitude * y).astype(np.float32)


class MaskingAudio:
    """White-noise masker with mixed-in cues, running in PortAudio's callback thread.

    Parameters
    ----------
    level_dbfs : float
        RMS level of the noise relative to digital full scale (sine-free
        definition: RMS 1.0 = 0 dBFS), e.g. -20 dBFS -> RMS 0.1.
    fs_hz : float
        Output sample rate.
    seed : int
        Seed of the noise generator (the noise is different for every seed
        and never loops).
    device : int | str | None
        PortAudio output device (None: the default).
    channels : int
        1 (mono) or 2 (same signal on both ears).
    blocksize : int
        Frames per callback.
    """

    def __init__(self, level_dbfs: float = -20.0, fs_hz: float = 44100.0, seed: int = 0, device=None,
                 channels: int = 1, blocksize: int = 1024) -> None:
        if not (math.isfinite(level_dbfs) and level_dbfs <= -3.0):
            raise ValueError(f"masking level_dbfs must be finite and <= -3 dBFS (headroom for cues), got {level_dbfs}")
        if channels not in (1, 2):
            raise ValueError(f"audio channels must be 1 or 2, got {channels}")
        self.level_dbfs = float(level_dbfs)
        self.rms = 10.0 ** (level_dbfs / 20.0)
        self.fs_hz = float(fs_hz)
        self.device = device
        self.channels = channels
        self.blocksize = int(blocksize)
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._noise = np.zeros(self.blocksize, np.float32)
        self._cues: list[list] = []          # [array, read position]
        self._lock = threading.Lock()
        self._stream = None
        self.frames_played = 0
        self.status_flags = 0
        cue = spoken_cue("Tap now", self.fs_hz)
        self.cue_source = "espeak-ng" if cue is not None else "synthesized chime (espeak-ng not installed)"
        self.tap_cue = cue if cue is not None else chime_cue(self.fs_hz)
        self.low_tone = low_tone(self.fs_hz)

    # -- PortAudio callback ------------------------------------------------
    def _callback(self, outdata, frames, time_info, status) -> None:
        if status:
            self.status_flags += 1
        if frames > self._noise.shape[0]:
            self._noise = np.zeros(frames, np.float32)
        noise = self._noise[:frames]
        self._rng.standard_normal(frames, dtype=np.float32, out=noise)
        noise *= self.rms
        with self._lock:
            cues = self._cues
            for cue in cues:
                arr, pos = cue
                n = min(frames, arr.shape[0] - pos)
                noise[:n] += arr[pos:pos + n]
                cue[1] = pos + n
            if cues:
                self._cues = [c for c in cues if c[1] < c[0].shape[0]]
        np.clip(noise, -1.0, 1.0, out=noise)
        for ch in range(outdata.shape[1]):
            outdata[:, ch] = noise
        self.frames_played += frames

    # -- control -----------------------------------------------------------
    def start(self) -> "MaskingAudio":
        sd = load_sounddevice()
        check_output_device(self.device)
        self._stream = sd.OutputStream(samplerate=self.fs_hz, blocksize=self.blocksize, device=self.device,
                                       channels=self.channels, dtype="float32", callback=self._callback)
        self._stream.start()
        return self

    def play(self, samples: np.ndarray) -> None:
        """Mix ``samples`` (float32, full scale 1.0) into the output from the next block on."""
        with self._lock:
            self._cues.append([np.asarray(samples, np.float32), 0])

    def cue_tap(self) -> None:
        self.play(self.tap_cue)

    def cue_low_tone(self) -> None:
        self.play(self.low_tone)

    def stop(self) -> None:
        if self._stream is not None:
            try:
                self._stream.stop()
                self._stream.close()
            finally:
                self._stream = None

    def __enter__(self) -> "MaskingAudio":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


class SilentAudio:
    """Stand-in used by sim sessions without ``--audio``: plays nothing and counts the cues it was asked for."""

    cue_source = "none (sim session runs silently)"
    level_dbfs = None

    def __init__(self) -> None:
        self.tap_cues = 0
        self.low_tones = 0

    def start(self) -> "SilentAudio":
        return self

    def cue_tap(self) -> None:
        self.tap_cues += 1

    def cue_low_tone(self) -> None:
        self.low_tones += 1

    def stop(self) -> None:
        pass
