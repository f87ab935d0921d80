"""Masking audio really goes through PortAudio: ALSA's default device is routed to a file and read back."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from tests.support.audio import FS, espeak_reference, find_cue
from tests.support.needs import need

ROOT = Path(__file__).resolve().parents[3]


def play_through_alsa_file(tmp_path, level_dbfs, body, extra="", **env_extra):
    need("portaudio")
    raw = tmp_path / "played.raw"
    conf = tmp_path / "asound.conf"
    conf.write_text(f'</usr/share/alsa/alsa.conf>\npcm.!default {{ type file slave.pcm "null" '
                    f'file "{raw}" format "raw" }}\n')
    script = textwrap.dedent(f"""
        import time
        from study.session.audio import MaskingAudio, check_output_device
        print(check_output_device())
        a = MaskingAudio(level_dbfs={level_dbfs}, fs_hz={FS}, seed=5, {extra})
        a.start()
        {body}
        a.stop()
        print(a.frames_played)
        print("XRUNS", a.status_flags)
    """)
    env = dict(os.environ, ALSA_CONFIG_PATH=str(conf), **env_extra)
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    x = np.fromfile(raw, dtype=np.float32)
    nz = np.flatnonzero(x)
    return x[nz[0]:], out.stdout


def test_white_noise_at_the_set_level_through_portaudio(tmp_path):
    # the null sink has no clock, so a few blocks "play" in microseconds: stop after ~1 M frames
    x, out = play_through_alsa_file(tmp_path, -26.0, "while a.frames_played < 1_000_000: time.sleep(0.001)")
    assert "default" in out
    assert len(x) >= 900_000
    rms = float(np.sqrt(np.mean(x.astype(np.float64) ** 2)))
    assert abs(20 * np.log10(rms) - (-26.0)) < 0.1, rms
    # flat spectrum: every 1/3-octave-ish band within 1 dB of the mean density, 50 Hz - 20 kHz
    f, p = signal.welch(x, FS, nperseg=4096)
    edges = np.geomspace(50, 20000, 14)
    bands = np.array([p[(f >= lo) & (f < hi)].mean() for lo, hi in zip(edges[:-1], edges[1:])])
    db = 10 * np.log10(bands / bands.mean())
    assert np.abs(db).max() < 1.0, db
    # expected one-sided density of white noise with this RMS
    assert abs(10 * np.log10(np.median(p) / (2 * rms ** 2 / FS))) < 0.5
    # Gaussian amplitude statistics (kurtosis 3), no clipping
    k = np.mean(x.astype(np.float64) ** 4) / rms ** 4
    assert 2.9 < k < 3.1
    assert np.abs(x).max() < 1.0
    # no loop: a 0.1 s block never reappears anywhere later (normalized cross-correlation)
    blk = x[:4410].astype(np.float64)
    rest = x[4410:].astype(np.float64)
    c = signal.correlate(rest, blk, mode="valid", method="fft") / (np.sqrt(np.sum(blk ** 2)) * rms * np.sqrt(4410))
    assert np.abs(c).max() < 0.1


def test_cues_are_mixed_into_the_noise(tmp_path):
    body = ("while a.frames_played < 200_000: time.sleep(0.001)\n"
            "a.cue_low_tone()\n"
            "while a.frames_played < 600_000: time.sleep(0.001)")
    body = body.replace("\n", "\n        ")
    x, out = play_through_alsa_file(tmp_path, -30.0, body)
    f, t, z = signal.stft(x, FS, nperseg=2048)
    tone = np.abs(z[np.argmin(np.abs(f - 180.0))]) ** 2
    # the 0.3 s low tone stands > 20 dB above the noise in its bin, for about 0.3 s, exactly once
    loud = np.flatnonzero(tone > 100 * np.median(tone))
    why = f"{_xruns(out)} underrun(s), {len(x)} frames in the file, loud STFT frames {loud.tolist()}"
    assert 0.2 < len(loud) * (t[1] - t[0]) < 0.45, why
    assert np.all(np.diff(loud) == 1), why


def _xruns(stdout: str) -> int:
    """The underruns the playback counted (PortAudio's callback status flags), from its printed ``XRUNS n``."""
    return int(next(ln for ln in stdout.splitlines() if ln.startswith("XRUNS")).split()[1])


def test_real_session_without_audio_output_refuses(tmp_path):
    need("portaudio")
    # this machine has no sound card: with ALSA's default config PortAudio finds no output device
    env = {k: v for k, v in os.environ.items() if k != "ALSA_CONFIG_PATH"}
    out = subprocess.run([sys.executable, "-m", "study", "run", "--device", "sim", "--audio", "on", "--subject", "A1",
                          "--seed", "1", "--out", str(tmp_path / "DATA")], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 2
    assert "masking audio needs an audio output device" in out.stderr
    assert not (tmp_path / "DATA" / "A1").exists()
    # a hardware session needs audio: refused before the device is opened
    out = subprocess.run([sys.executable, "-m", "study", "run", "--device", "serial:/dev/nonexistent",
                          "--participant", "keyboard", "--age", "30", "--gender", "female", "--handedness", "right",
                          "--experience", "none", "--subject", "A2", "--out", str(tmp_path / "DATA")], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "masking audio" in out.stderr, out.stderr


# -- spoken cues ------------------------------------------------------------------------------------------------

def active_level(y, fs_hz=FS):
    """RMS over the 20 ms frames within 30 dB of the loudest (the level definition of the docs)."""
    n = int(0.02 * fs_hz)
    p = np.mean(y[:len(y) // n * n].reshape(-1, n) ** 2, axis=1)
    return np.sqrt(p[p >= p.max() * 1e-3].mean())


def test_spoken_cues_are_played_through_portaudio_at_the_set_level(tmp_path):
    # the null sink has no clock: how many frames pass between two polls depends on the load, so each cue's
    # onset is checked against the frames played just before and just after it was asked for
    body = ("print(a.cue_source, a.cue_spoken)\n"
            "while a.frames_played < 100_000: time.sleep(0.001)\n"
            "f0 = a.frames_played; a.cue_tap(); f1 = a.frames_played\n"
            "while a.frames_played < f1 + 150_000: time.sleep(0.001)\n"
            "g0 = a.frames_played; a.cue_rate(); g1 = a.frames_played\n"
            "print(a.wait_cues(5.0))\n"
            "print('CUES', f0, f1, g0, g1)").replace("\n", "\n        ")
    x, out = play_through_alsa_file(tmp_path, -30.0, body, "cue_level_db=6.0")
    assert "\nTrue\n" in out  # the last cue was handed over in full before the stream stopped
    assert "espeak-ng (voice en) True" in out
    f0, f1, g0, g1 = (int(v) for v in next(ln for ln in out.splitlines() if ln.startswith("CUES")).split()[1:])
    x = x.astype(np.float64)
    noise_rms = np.sqrt(np.mean(x[:90_000] ** 2))
    assert abs(20 * np.log10(noise_rms) + 30.0) < 0.2
    for text, before, after in (("Tap now.", f0, f1), ("Stop. Please rate.", g0, g1)):
        ref = espeak_reference(text)
        rho = find_cue(x, ref)
        lag = int(np.argmax(rho))
        # found once, at high correlation, after it was asked for, and nowhere else; mixed from the next block
        # on (blocks of 1024 frames): not before it was asked for, at most two blocks after (plus the ~1%
        # leading silence the reference was trimmed of)
        assert rho[lag] > 0.75, (text, rho[lag])
        assert before - 2048 <= lag < after + 2 * 1024 + 4096, (text, lag, before, after)
        far = np.abs(np.arange(len(rho)) - lag) > len(ref)
        assert np.abs(rho[far]).max() < 0.25, text
        # level: least-squares gain of the reference in the stream -> active level 6 dB above the noise
        seg = x[lag:lag + len(ref)]
        gain = seg @ ref / (ref @ ref)
        level_db = 20 * np.log10(gain * active_level(ref) / noise_rms)
        assert abs(level_db - 6.0) < 0.5, (text, level_db)
        # what is left is the masking noise alone: the cue was added, not distorted or clipped
        resid = seg - gain * ref
        assert abs(20 * np.log10(np.sqrt(np.mean(resid ** 2)) / noise_rms)) < 0.3
    # the two phrases are different: the rating prompt does not match the tap cue
    tap = espeak_reference("Tap now.")
    rate = espeak_reference("Stop. Please rate.")
    assert np.abs(find_cue(np.concatenate([rate, np.zeros(len(tap))]), tap)).max() < 0.5


def test_without_espeak_ng_the_cues_are_chimes_and_say_so(tmp_path):
    # espeak-ng made unavailable: not provisioned (HFAM_DEPS_WITHOUT) and PATH holds only an empty folder
    # (python is called by its full path)
    empty = tmp_path / "bin"
    empty.mkdir()
    # the null sink has no clock: how many frames pass between two polls depends on the load, so each cue's
    # onset is checked against the frames played just before and just after it was asked for
    body = ("print(a.cue_source, a.cue_spoken)\n"
            "while a.frames_played < 100_000: time.sleep(0.001)\n"
            "f0 = a.frames_played; a.cue_tap(); f1 = a.frames_played\n"
            "while a.frames_played < f1 + 150_000: time.sleep(0.001)\n"
            "g0 = a.frames_played; a.cue_rate(); g1 = a.frames_played\n"
            "while a.frames_played < g1 + 150_000: time.sleep(0.001)\n"
            "print('CUES', f0, f1, g0, g1)").replace("\n", "\n        ")
    x, out = play_through_alsa_file(tmp_path, -30.0, body, "cue_level_db=6.0", PATH=str(empty),
                                  HFAM_DEPS_WITHOUT="espeak-ng")
    assert "synthesized chime (espeak-ng not found in .deps/bin or on PATH" in out and out.split("\n")[1].endswith("False")
    x = x.astype(np.float64)
    noise_rms = np.sqrt(np.mean(x[:90_000] ** 2))
    # the notes in the played stream, in time order: C5 E5 G5 rising (tap), then G5 C5 falling (rate)
    f, t, z = signal.stft(x, FS, nperseg=1024)
    onsets = []
    for freq in (523.25, 659.25, 783.99):
        power = np.abs(z[np.argmin(np.abs(f - freq))]) ** 2
        loud = np.flatnonzero(power > 30 * np.median(power))
        runs = np.split(loud, np.flatnonzero(np.diff(loud) > 2) + 1)
        onsets += [(t[r[0]], freq, (r[-1] - r[0] + 1) * (t[1] - t[0])) for r in runs if len(r)]
    onsets.sort()
    assert [o[1] for o in onsets] == [523.25, 659.25, 783.99, 783.99, 523.25], onsets
    assert all(0.08 < o[2] < 0.2 for o in onsets), onsets          # 0.12 s notes
    f0, f1, g0, g1 = (int(v) for v in next(ln for ln in out.splitlines() if ln.startswith("CUES")).split()[1:])
    # mixed from the next block on (blocks of 1024 frames): not before it was asked for, at most two blocks
    # after; 0.05 s for the STFT's frames (1024 samples) and the stream's first block
    assert f0 / FS - 0.05 < onsets[0][0] < (f1 + 2 * 1024) / FS + 0.05, (onsets[0], f0, f1)
    assert g0 / FS - 0.05 < onsets[3][0] < (g1 + 2 * 1024) / FS + 0.05, (onsets[3], g0, g1)
    # level: the chime's active RMS 6 dB above the noise (power of the notes minus the noise power)
    i0 = int(onsets[0][0] * FS)
    chime = x[i0:i0 + int(0.12 * FS)]
    level_db = 10 * np.log10((np.mean(chime ** 2) - noise_rms ** 2) / noise_rms ** 2)
    assert abs(level_db - 6.0) < 1.0, level_db


def test_espeak_ng_failing_or_a_clipping_level_is_reported(tmp_path, monkeypatch):
    from study.session.audio import MaskingAudio, active_rms, make_cues

    fake = tmp_path / "bin" / "espeak-ng"
    fake.parent.mkdir()
    fake.write_text("#!/bin/sh\necho 'no voice data' >&2\nexit 1\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", str(fake.parent))
    monkeypatch.setenv("HFAM_DEPS", "system")  # this fake, not a provisioned espeak-ng
    cues, source, spoken = make_cues(FS, 0.05)
    assert not spoken and "espeak-ng failed to speak 'Tap now.': no voice data" in source
    assert abs(active_rms(cues["tap"], FS) - 0.05) < 1e-4
    monkeypatch.undo()
    # a spoken cue 20 dB above -20 dBFS noise would clip: refused, naming the setting and the margin
    with pytest.raises(ValueError, match=r"would clip.*lower cue_level_db or masking_level_dbfs by at least"):
        MaskingAudio(level_dbfs=-20.0, cue_level_db=20.0)
    # pauses do not lower the active level
    tone = np.sin(np.arange(FS // 2) * 0.1)
    assert abs(active_rms(np.concatenate([tone, np.zeros(FS), tone]), FS) - np.sqrt(0.5)) < 0.01


def run_sim_session_with_audio(tmp_path, subject, *extra, **env_extra):
    need("portaudio")
    raw = tmp_path / f"{subject}.raw"
    conf = tmp_path / f"{subject}.conf"
    conf.write_text(f'</usr/share/alsa/alsa.conf>\npcm.!default {{ type file slave.pcm "null" '
                    f'file "{raw}" format "raw" }}\n')
    proto = tmp_path / "quick.toml"
    proto.write_text('tap_window_s = 1.0\nhoming_after_s = 0.5\nhoming_before_max_s = 0.2\n'
                     'familiarization_sample = ""\n')
    env = dict(os.environ, ALSA_CONFIG_PATH=str(conf), **env_extra)
    out = subprocess.run([sys.executable, "-m", "study", "run", "--device", "sim", "--participant", "simulated",
                          "--subject", subject, "--seed", "3", "--out", str(tmp_path / "DATA"), "--protocol",
                          str(proto), "--samples", "wood,firm", "--repetitions", "1", "--audio", "on", "--quiet",
                          *extra], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    return out, raw


def test_session_records_the_cue_source_and_speaks(tmp_path):
    out, raw = run_sim_session_with_audio(tmp_path, "V1", "--cue-level", "6", "--masking-level", "-30")
    assert out.returncode == 0, out.stderr
    assert "not spoken" not in out.stderr
    audio = json.loads((tmp_path / "DATA" / "V1" / "session.json").read_text())["audio"]
    assert audio == {"output": "default", "level_dbfs": -30.0, "cue_source": "espeak-ng (voice en)",
                     "cue_spoken": True, "cue_level_db": 6.0}
    x = np.fromfile(raw, dtype=np.float32).astype(np.float64)
    rho = find_cue(x[np.flatnonzero(x)[0]:], espeak_reference("Tap now."))
    # 2 demonstration + 2 testing trials. The null sink has no clock, so where the cues land in the stream (and
    # whether a tap cue overlaps a rating prompt or is cut by the end of the session) depends on thread
    # scheduling: ask for one clean cue and no more cues than trials; the exact mixing is tested above.
    peaks, _ = signal.find_peaks(rho, height=0.5, distance=int(0.7 * FS))
    assert 1 <= len(peaks) <= 4 and rho.max() > 0.8, rho[peaks]
    # and the rating prompt after each window
    assert find_cue(x[np.flatnonzero(x)[0]:], espeak_reference("Stop. Please rate.")).max() > 0.7
    # without espeak-ng: chimes, a warning, and session.json says so
    empty = tmp_path / "bin"
    empty.mkdir()
    out, _ = run_sim_session_with_audio(tmp_path, "V2", PATH=str(empty), HFAM_DEPS_WITHOUT="espeak-ng")
    assert out.returncode == 0, out.stderr
    assert "warning: the cues are chimes, not spoken: synthesized chime (espeak-ng not found in .deps/bin or on PATH" in out.stderr
    audio = json.loads((tmp_path / "DATA" / "V2" / "session.json").read_text())["audio"]
    assert audio["cue_spoken"] is False and audio["cue_source"].startswith("synthesized chime (espeak-ng not found")
    # a cue level that would clip is refused before the session starts
    out, _ = run_sim_session_with_audio(tmp_path, "V3", "--cue-level", "25")
    assert out.returncode == 2 and "would clip" in out.stderr, out.stderr
    assert not (tmp_path / "DATA" / "V3").exists()
