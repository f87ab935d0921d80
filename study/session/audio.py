"""Masking audio: continuous white noise with cues and tones mixed in, through sounddevice/PortAudio.

Section 4.5.3: the subject wears headphones playing white noise "at a high
volume" to mask the sounds of tapping; a recorded voice tells them to tap and a
low tone marks taps whose force exceeded the amplifier limit.

The noise is generated block by block inside the PortAudio callback from a
seeded PCG64 generator (Gaussian, RMS set by ``level_dbfs``), so it never
repeats (no stored loop). The spoken cues ("Tap now.", "Stop. Please rate.")
are synthesized once when the session starts with ``espeak-ng -w`` (Debian
package espeak-ng), resampled to the stream rate and scaled to ``cue_level_db``
relative to the noise; the callback mixes these precomputed arrays in. Without
espeak-ng the cues are synthesized chimes, and :attr:`MaskingAudio.cue_source`
says so and why.
"""

from __future__ import annotations

import math
import subprocess
import tempfile
import threading
import time
import wave
from pathlib import Path

import numpy as np

from plumbing import sysdeps


class AudioUnavailable(ValueError):
    """PortAudio or an output device is missing (a real session refuses to start)."""


def load_sounddevice():
    """Import sounddevice with PortAudio from an explicit path (see :func:`plumbing.sysdeps.import_sounddevice`).

    The library provisioned in ``<repo>/.deps`` (``make test``) is used first, else
    the system's; a missing PortAudio becomes a clear :class:`AudioUnavailable`.
    """
    try:
        return sysdeps.import_sounddevice()
    except OSError as exc:  # the wheel does not bundle PortAudio on Linux
        raise AudioUnavailable(f"masking audio needs PortAudio ({exc}); 'make test' provisions it into "
                               f"{sysdeps.deps_root()}, or install it with 'apt-get install libportaudio2' "
                               "(or 'make system-deps')") from None


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


#: The phrases the protocol speaks, by cue name: the tap cue when the operator
#: has confirmed (section 4.5.3, "a recorded voice in the headphones") and the
#: rating prompt when the tap window ends (taps after it count as overpowering).
CUE_PHRASES = {"tap": "Tap now.", "rate": "Stop. Please rate."}
#: a two-interval forced-choice session asks "which one?" instead of a rating
CHOICE_PHRASES = {"tap": "Tap now.", "rate": "Stop. Which one?"}


class SpeechUnavailable(RuntimeError):
    """espeak-ng is not installed or could not speak (the cues fall back to chimes)."""


def chime(freqs_hz, fs_hz: float, amplitude: float = 0.4) -> np.ndarray:
    """Notes of 0.12 s each at ``freqs_hz`` with 30 ms gaps (raised-cosine ramps), float32."""
    gap = np.zeros(int(0.03 * fs_hz), np.float32)
    parts = []
    for f in freqs_hz:
        parts += [tone(f, 0.12, fs_hz, amplitude), gap]
    return np.concatenate(parts)


def chime_cue(fs_hz: float, amplitude: float = 0.4) -> np.ndarray:
    """Fallback 'tap now' cue: three rising notes (C5 E5 G5), 0.12 s each with 30 ms gaps."""
    return chime((523.25, 659.25, 783.99), fs_hz, amplitude)


#: Fallback chimes by cue name when espeak-ng is missing: rising for "tap", falling (G5 C5) for "rate".
CHIME_NOTES_HZ = {"tap": (523.25, 659.25, 783.99), "rate": (783.99, 523.25)}


def active_rms(y: np.ndarray, fs_hz: float, frame_s: float = 0.02, floor_db: float = 30.0) -> float:
    """RMS over the active part of a cue: the ``frame_s`` frames within ``floor_db`` of the loudest frame.

    A simplified active speech level (in the spirit of ITU-T P.56): pauses
    between and around words do not lower the level, so a phrase with a pause
    is as loud as one without.

    Parameters
    ----------
    y : ndarray, shape (n,)
        Cue samples (full scale 1.0).
    fs_hz : float
        Sample rate.

    Returns
    -------
    float
        RMS of the active frames (same unit as ``y``); 0 for silence.
    """
    n = max(1, int(round(frame_s * fs_hz)))
    m = len(y) // n
    if m == 0:
        return float(np.sqrt(np.mean(np.square(y, dtype=np.float64)))) if len(y) else 0.0
    power = np.mean(np.square(y[:m * n].reshape(m, n), dtype=np.float64), axis=1)
    if power.max() <= 0.0:
        return 0.0
    active = power >= power.max() * 10.0 ** (-floor_db / 10.0)
    return float(np.sqrt(power[active].mean()))


def speak(text: str, fs_hz: float, voice: str = "en", speed_wpm: int = 150, exe: str | None = None) -> np.ndarray:
    """Speak ``text`` with espeak-ng (``espeak-ng -w file.wav``) and return it at ``fs_hz``.

    espeak-ng writes 16-bit mono WAV at its own rate (22 050 Hz); the samples
    are read with the stdlib ``wave`` module, resampled with
    :func:`scipy.signal.resample_poly` and trimmed of leading and trailing
    silence (below 1 % of the peak).

    Parameters
    ----------
    text : str
        The phrase.
    fs_hz : float
        Output sample rate (rounded to an integer).
    voice, speed_wpm : str, int
        espeak-ng ``-v`` voice and ``-s`` words per minute.
    exe : str, optional
        Path of the program; default: ``espeak-ng`` provisioned in ``<repo>/.deps/bin``, else on ``PATH``
        (:func:`plumbing.sysdeps.tool`).

    Returns
    -------
    ndarray, shape (n,), float64
        The speech, peak 1.0.

    Raises
    ------
    SpeechUnavailable
        espeak-ng is not found, fails, or produces no sound (the message says which).
    """
    exe = exe or sysdeps.tool("espeak-ng")
    if exe is None:
        raise SpeechUnavailable("espeak-ng not found in .deps/bin or on PATH (Debian package espeak-ng: "
                                "'make test' provisions it, or 'make system-deps')")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cue.wav"
        try:
            subprocess.run([exe, "-v", voice, "-s", str(int(speed_wpm)), "-w", str(path), text], check=True,
                           capture_output=True, timeout=10)
            with wave.open(str(path), "rb") as w:
                rate, width, channels = w.getframerate(), w.getsampwidth(), w.getnchannels()
                raw = w.readframes(w.getnframes())
        except subprocess.CalledProcessError as exc:
            err = exc.stderr.decode(errors="replace").strip() or f"exit code {exc.returncode}"
            raise SpeechUnavailable(f"espeak-ng failed to speak {text!r}: {err}") from None
        except (OSError, subprocess.SubprocessError, wave.Error, EOFError) as exc:
            raise SpeechUnavailable(f"espeak-ng failed to speak {text!r}: {exc}") from None
    if width != 2:
        raise SpeechUnavailable(f"espeak-ng wrote {8 * width}-bit samples for {text!r}; expected 16-bit WAV")
    y = np.frombuffer(raw, "<i2").astype(np.float64).reshape(-1, channels).mean(axis=1)
    peak = float(np.max(np.abs(y))) if y.size else 0.0
    if peak == 0.0:
        raise SpeechUnavailable(f"espeak-ng produced silence for {text!r} (voice {voice!r})")
    loud = np.flatnonzero(np.abs(y) >= 0.01 * peak)
    y = y[loud[0]:loud[-1] + 1] / peak
    # only spoken cues need it: a session without them starts without scipy.signal
    from scipy.signal import resample_poly  # deferred: 1.0 s of CPU to import

    fs_out = int(round(fs_hz))
    g = math.gcd(fs_out, int(rate))
    y = resample_poly(y, fs_out // g, int(rate) // g)
    return y / np.max(np.abs(y))


def make_cues(fs_hz: float, target_rms: float, phrases: dict | None = None) -> tuple[dict, str, bool]:
    """Synthesize the protocol's cues once, each scaled to an active RMS of ``target_rms``.

    Parameters
    ----------
    fs_hz : float
        Stream sample rate.
    target_rms : float
        Active RMS (:func:`active_rms`) of every cue, full scale 1.0.
    phrases : dict, optional
        Cue name -> phrase; default :data:`CUE_PHRASES`.

    Returns
    -------
    cues : dict of str -> ndarray (float32)
    source : str
        What made them: ``"espeak-ng (voice en)"`` or ``"synthesized chime (<why espeak-ng was not used>)"``.
    spoken : bool
        True when the cues are speech.

    Raises
    ------
    ValueError
        A cue would clip at this level (its peak above 0.99 of full scale).
    """
    phrases = dict(CUE_PHRASES if phrases is None else phrases)
    try:
        raw = {name: speak(text, fs_hz) for name, text in phrases.items()}
        source, spoken = "espeak-ng (voice en)", True
    except SpeechUnavailable as exc:
        raw = {name: chime(CHIME_NOTES_HZ.get(name, CHIME_NOTES_HZ["tap"]), fs_hz, 1.0).astype(np.float64)
               for name in phrases}
        source, spoken = f"synthesized chime ({exc})", False
    cues = {}
    for name, y in raw.items():
        y = y * (target_rms / active_rms(y, fs_hz))
        peak = float(np.max(np.abs(y)))
        if peak > 0.99:
            raise ValueError(f"the {name!r} cue ({source.split(' (')[0]}) would clip: its peak would be "
                             f"{peak:.2f} of full scale at an active RMS of {20 * math.log10(target_rms):.1f} dBFS; "
                             f"lower cue_level_db or masking_level_dbfs by at least "
                             f"{20 * math.log10(peak / 0.99):.1f} dB")
        cues[name] = y.astype(np.float32)
    return cues, source, spoken


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
    cue_level_db : float
        Active RMS of the spoken cues (or the fallback chimes) relative to the
        noise RMS, dB (0: as loud as the noise).
    phrases : dict, optional
        Cue name -> phrase (:data:`CUE_PHRASES`, or :data:`CHOICE_PHRASES` for a forced-choice session);
        the names ``tap`` and ``rate`` are required.

    Attributes
    ----------
    cues : dict of str -> ndarray
        The cues by name (:data:`CUE_PHRASES`), float32 at ``fs_hz``.
    cue_source : str
        ``"espeak-ng (voice en)"`` or ``"synthesized chime (<reason>)"``.
    cue_spoken : bool
        Whether the cues are speech.
    """

    def __init__(self, level_dbfs: float = -20.0, fs_hz: float = 44100.0, seed: int = 0, device=None,
                 channels: int = 1, blocksize: int = 1024, cue_level_db: float = 0.0,
                 phrases: dict | None = None) -> None:
        if not (math.isfinite(level_dbfs) and level_dbfs <= -3.0):
            raise ValueError(f"masking level_dbfs must be finite and <= -3 dBFS (headroom for cues), got {level_dbfs}")
        if not math.isfinite(cue_level_db):
            raise ValueError(f"cue_level_db must be finite, got {cue_level_db}")
        if channels not in (1, 2):
            raise ValueError(f"audio channels must be 1 or 2, got {channels}")
        self.level_dbfs = float(level_dbfs)
        self.rms = 10.0 ** (level_dbfs / 20.0)
        self.cue_level_db = float(cue_level_db)
        self.fs_hz = float(fs_hz)
        self.device = device
        self.channels = channels
        self.blocksize = int(blocksize)
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._noise = np.zeros(self.blocksize, np.float32)
        self._cues: list[list] = []          # [array, read position], played in turn
        self._overlays: list[list] = []      # [array, read position], mixed over whatever plays
        self._lock = threading.Lock()
        self._stream = None
        self.frames_played = 0
        self.status_flags = 0
        # synthesized once here (session start), never in the callback
        self.cues, self.cue_source, self.cue_spoken = make_cues(self.fs_hz, self.rms * 10.0 ** (cue_level_db / 20.0),
                                                                phrases)
        self.tap_cue = self.cues["tap"]
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
            # the spoken cues one after another (a cue asked for while another plays waits for it: two voices
            # at once are unintelligible), the low tone mixed at once (an alarm does not queue)
            at = 0
            cues = self._cues
            while cues and at < frames:
                arr, pos = cues[0]
                n = min(frames - at, arr.shape[0] - pos)
                noise[at:at + n] += arr[pos:pos + n]
                at += n
                if pos + n >= arr.shape[0]:
                    cues.pop(0)
                else:
                    cues[0][1] = pos + n
            for tone in self._overlays:
                arr, pos = tone
                n = min(frames, arr.shape[0] - pos)
                noise[:n] += arr[pos:pos + n]
                tone[1] = pos + n
            if self._overlays:
                self._overlays = [t for t in self._overlays if t[1] < t[0].shape[0]]
        np.clip(noise, -1.0, 1.0, out=noise)
        for ch in range(outdata.shape[1]):
            outdata[:, ch] = noise
        self.frames_played += frames

    # -- control -----------------------------------------------------------
    def start(self) -> "MaskingAudio":
        """Open the PortAudio output stream and start the masking noise; returns self. AudioError if no output device."""
        sd = load_sounddevice()
        check_output_device(self.device)
        self._stream = sd.OutputStream(samplerate=self.fs_hz, blocksize=self.blocksize, device=self.device,
                                       channels=self.channels, dtype="float32", callback=self._callback)
        self._stream.start()
        return self

    def play(self, samples: np.ndarray) -> None:
        """Mix ``samples`` (float32, full scale 1.0) into the output after the cues already asked for.

        Cues play in turn, never over each other: one asked for while another still plays starts
        where that one ends (at once otherwise, from the next block on).
        """
        with self._lock:
            self._cues.append([np.asarray(samples, np.float32), 0])

    def overlay(self, samples: np.ndarray) -> None:
        """Mix ``samples`` into the output from the next block on, over any cue playing (an alarm)."""
        with self._lock:
            self._overlays.append([np.asarray(samples, np.float32), 0])

    def cue(self, name: str) -> None:
        """Mix the cue ``name`` (a key of :attr:`cues`) into the output."""
        self.play(self.cues[name])

    def cue_tap(self) -> None:
        """'Tap now.' (the operator has confirmed the sample)."""
        self.play(self.cues["tap"])

    def cue_rate(self) -> None:
        """'Stop. Please rate.' (the tap window has ended)."""
        self.play(self.cues["rate"])

    def cue_low_tone(self) -> None:
        """Play the low tone (a clipped tap, section 4.5.3) over the noise, at once (over a cue if one plays)."""
        self.overlay(self.low_tone)

    def wait_cues(self, timeout_s: float) -> bool:
        """Wait until the cues asked for have been handed to PortAudio (at most ``timeout_s``).

        Called before :meth:`stop` at the end of a session so the last
        "Stop. Please rate." is not cut off. Returns True when none is pending.
        """
        deadline = time.monotonic() + timeout_s
        while self._stream is not None and self._stream.active:
            with self._lock:
                if not self._cues and not self._overlays:
                    return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return not self._cues and not self._overlays

    def stop(self) -> None:
        """Stop the stream; what was handed to PortAudio still plays (``Pa_StopStream``)."""
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
        self.rate_cues = 0
        self.low_tones = 0

    def start(self) -> "SilentAudio":
        """Nothing to start (no audio); returns self."""
        return self

    def cue_tap(self) -> None:
        """Count a "tap" cue (no sound)."""
        self.tap_cues += 1

    def cue_rate(self) -> None:
        """Count a "rate" cue (no sound)."""
        self.rate_cues += 1

    def cue_low_tone(self) -> None:
        """Count a low tone (no sound)."""
        self.low_tones += 1

    def wait_cues(self, timeout_s: float) -> bool:
        """True at once: nothing is ever pending."""
        return True

    def stop(self) -> None:
        """Nothing to stop."""
        pass
