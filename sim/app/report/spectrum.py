"""The amplitude spectrum and its dominant frequency, as `jiggle compare` reads them off a muscle's CV offsets or a
chain's tip offset (sim.app.report.compare, sim.app.report.chains)."""
from __future__ import annotations

import numpy as np

STILL = 1e-6
"""metres: a muscle whose amplitude never exceeds this (a micrometre) does not move (no frequency)."""
MIN_FRAMES = 8
"""Fewer frames than this give no dominant frequency."""
MIN_CYCLES = 2
"""A dominant frequency needs at least this many periods in the clip; a slower peak in the spectrum
cannot be told from a drift, so the frequency is then None ("too short to resolve")."""


def muscle_spectrum(d: np.ndarray, offsets: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """(freqs (K,) Hz, amplitude (K, M) metres): each muscle's amplitude spectrum.

    Every CV offset component (x, y, z) minus its mean over time is Hann-windowed and Fourier
    transformed over the frames (taken as evenly spaced at fps, K = T // 2 + 1 bins of fps / T Hz);
    the powers are summed over xyz and averaged over the muscle's CVs, so a muscle's spectrum is the
    RMS over its CVs of their vector amplitude: a CV swinging A sin(2 pi f t) along any direction gives
    A at f (the window's gain is divided out). Summing powers (not averaging offset vectors) keeps
    modes in which CVs move against each other (a belly breathing in and out)."""
    T = d.shape[0]
    freqs = np.fft.rfftfreq(T, 1.0 / fps)
    M = len(offsets) - 1
    amp = np.zeros((len(freqs), M))
    if T < 2:
        return freqs, amp
    w = np.hanning(T)
    gain = w.sum() / 2.0                    # a unit sinusoid's peak |X| under the window
    for m in range(M):
        a, b = offsets[m], offsets[m + 1]
        if b > a:
            x = d[:, a:b] - d[:, a:b].mean(axis=0)
            X = np.fft.rfft(x * w[:, None, None], axis=0)
            amp[:, m] = np.sqrt((np.abs(X) ** 2).sum(axis=2).mean(axis=1)) / gain
    return freqs, amp


def dominant_frequency(freqs: np.ndarray, amp: np.ndarray, frames: int, moving: bool) -> float | None:
    """Hz of the largest peak of one spectrum amp (K,), refined by a parabola through the log
    amplitudes of the peak bin and its neighbours; None when the muscle does not move, the clip has
    fewer than MIN_FRAMES frames, or the peak lies below MIN_CYCLES periods per clip."""
    if not moving or frames < MIN_FRAMES or len(amp) < 3 or not np.any(amp[1:] > 0):
        return None
    k = 1 + int(np.argmax(amp[1:]))
    if k < MIN_CYCLES:
        return None
    delta = 0.0
    if k + 1 < len(amp) and amp[k - 1] > 0 and amp[k + 1] > 0:
        lo, mid, hi = np.log(amp[k - 1]), np.log(amp[k]), np.log(amp[k + 1])
        den = lo - 2.0 * mid + hi
        delta = float(np.clip(0.5 * (lo - hi) / den, -0.5, 0.5)) if den < 0 else 0.0
    return float(freqs[k] + delta * (freqs[1] - freqs[0]))
