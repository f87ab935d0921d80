"""Finding a spoken cue in what PortAudio played: espeak-ng's own rendering of the words, cross-correlated."""

import subprocess
import tempfile

import numpy as np
from scipy import signal
from scipy.io import wavfile

from plumbing import sysdeps
from tests.support.needs import need

FS = 44100


def espeak_reference(text, fs_hz=FS):
    """The phrase as espeak-ng speaks it (the runner's voice and speed), resampled here to the stream rate."""
    need("espeak-ng")
    exe = sysdeps.tool("espeak-ng")
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([exe, "-v", "en", "-s", "150", "-w", f"{tmp}/ref.wav", text], check=True, timeout=30)
        rate, y = wavfile.read(f"{tmp}/ref.wav")
    loud = np.flatnonzero(np.abs(y) >= 0.01 * np.abs(y).max())  # documented: silence around the phrase trimmed
    y = y[loud[0]:loud[-1] + 1]
    g = np.gcd(fs_hz, rate)
    return signal.resample_poly(y.astype(np.float64), fs_hz // g, rate // g)


def find_cue(x, ref):
    """Normalized cross-correlation of the recorded stream with ``ref`` at every lag (1 = identical shape).

    The stream (millions of samples: the null sink has no clock) is correlated in overlap-added blocks and its
    energy under the sliding window is a difference of running sums: the values of one FFT over the whole
    stream (to ~1e-13) for a seventh of its CPU.
    """
    c = signal.oaconvolve(x, ref[::-1], mode="valid")
    run = np.concatenate(([0.0], np.cumsum(np.square(x))))
    energy = (run[len(ref):] - run[:-len(ref)]).clip(1e-20)
    return c / (np.sqrt(energy) * np.linalg.norm(ref))
