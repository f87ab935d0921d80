"""Masking audio really goes through PortAudio: ALSA's default device is routed to a file and read back."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
from scipy import signal

ROOT = Path(__file__).resolve().parents[2]
FS = 44100


def play_through_alsa_file(tmp_path, level_dbfs, body):
    raw = tmp_path / "played.raw"
    conf = tmp_path / "asound.conf"
    conf.write_text(f'</usr/share/alsa/alsa.conf>\npcm.!default {{ type file slave.pcm "null" '
                    f'file "{raw}" format "raw" }}\n')
    script = textwrap.dedent(f"""
        import time
        from study.audio import MaskingAudio, check_output_device
        print(check_output_device())
        a = MaskingAudio(level_dbfs={level_dbfs}, fs_hz={FS}, seed=5)
        a.start()
        {body}
        a.stop()
        print(a.frames_played)
    """)
    env = dict(os.environ, ALSA_CONFIG_PATH=str(conf))
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
    x, _ = play_through_alsa_file(tmp_path, -30.0, body)
    f, t, z = signal.stft(x, FS, nperseg=2048)
    tone = np.abs(z[np.argmin(np.abs(f - 180.0))]) ** 2
    # the 0.3 s low tone stands > 20 dB above the noise in its bin, for about 0.3 s, exactly once
    loud = tone > 100 * np.median(tone)
    assert 0.2 < loud.sum() * (t[1] - t[0]) < 0.45
    assert np.all(np.diff(np.flatnonzero(loud)) == 1)


def test_real_session_without_audio_output_refuses(tmp_path):
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
