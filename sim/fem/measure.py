"""What a simulated part does, measured the same way for the FEM and the particles.

Offsets: surface points or CVs (F, S, 3) minus their goal (F, S, 3): the static shape (FEM: every vertex's goal from
its loft coordinates; particles: the static CVs), in world axes (or turned by a frame's rotation when given). The
same quantity for both solvers: dynamic - static.
- peak displacement: the largest |offset| over frames and points, metres;
- the signal: the mean offset over the surface (the part's centre of mass wobbling about its place, its
  fundamental mode), projected on its principal direction (the direction it swings in most);
- dominant frequency: the peak of the signal's spectrum (Hann window, zero-padded, parabolic peak), Hz;
- ring-down (after the drive stops at t_stop): a least-squares fit of y = A exp(-zeta w t) cos(w_d t + phi) + c,
  w_d = w sqrt(1 - zeta^2), started from the spectrum's peak: the natural frequency w / 2 pi (Hz) and the
  damping ratio zeta; the logarithmic decrement delta = 2 pi zeta / sqrt(1 - zeta^2) (the log of the ratio of
  successive peaks). The log decrement of successive peaks is the same thing for a clean single mode; the fit
  also holds when the part rings for only one or two periods (zeta ~0.3-0.5 as muscle has);
- decrement (after t_stop): the logarithmic decrement as its definition reads it, from the signal's successive
  extrema (each swing's turning point, alternately on either side of where it settles): delta = 2 x the fall of
  ln|extremum| per extremum, a least-squares line through the first extrema above the noise. Two modes of
  different damping (a part that both sways and bulges) make the single-mode fit's zeta depend on its window; the
  extrema are what an eye or a plot reads.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Ringdown:
    """frequency_hz : natural frequency of the fitted mode, Hz. damping_ratio : zeta. amplitude : metres at t_stop.
    rms : metres, the fit's residual."""

    frequency_hz: float
    damping_ratio: float
    amplitude: float
    rms: float

    @property
    def log_decrement(self) -> float:
        """delta = 2 pi zeta / sqrt(1 - zeta^2): ln of the ratio of successive peaks."""
        z = min(self.damping_ratio, 0.999)
        return 2.0 * math.pi * z / math.sqrt(1.0 - z * z)


def goal_offsets(points: np.ndarray, goals: np.ndarray, rotations: np.ndarray | None = None) -> np.ndarray:
    """(F, S, 3) metres: points (F, S, 3) minus goals (F, S, 3), turned by R^T of rotations (F, 3, 3) (None: world)."""
    d = np.asarray(points, dtype=np.float64) - np.asarray(goals, dtype=np.float64)
    return d if rotations is None else np.einsum("fji,fsj->fsi", rotations, d)


def peak_displacement(offsets: np.ndarray) -> float:
    """metres: the largest |offset| of offsets (F, S, 3)."""
    return float(np.linalg.norm(offsets, axis=-1).max()) if offsets.size else 0.0


def offset_magnitude(offsets: np.ndarray) -> np.ndarray:
    """(F,) metres: the largest |offset| over the points of each frame of offsets (F, S, 3) (what the plots show)."""
    return np.linalg.norm(np.asarray(offsets, dtype=np.float64), axis=-1).max(axis=-1)


def detrend(signal: np.ndarray, times: np.ndarray, window: float = 0.5) -> np.ndarray:
    """signal (F,) minus its moving average over `window` seconds (a centred box, shrunk at the ends): the slow
    trend of a clip's drive (quasi-static offsets under a held acceleration) taken out, the wobble kept."""
    y = np.asarray(signal, dtype=np.float64)
    dt = float(np.mean(np.diff(times))) if len(times) > 1 else 1.0
    n = max(1, int(round(window / dt)) // 2)
    c = np.concatenate([[0.0], np.cumsum(y)])
    i = np.arange(len(y))
    lo, hi = np.maximum(i - n, 0), np.minimum(i + n + 1, len(y))
    return y - (c[hi] - c[lo]) / (hi - lo)


def principal_signal(offsets: np.ndarray) -> np.ndarray:
    """(F,) metres: the mean offset (F, 3) over the surface projected on its principal direction."""
    m = np.asarray(offsets, dtype=np.float64).mean(axis=1)
    c = m - m.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    return m @ vt[0]


def dominant_frequency(signal: np.ndarray, times: np.ndarray, fmin: float = 0.3) -> float:
    """Hz: the peak above fmin of the spectrum of signal (F,) sampled evenly at times (F,) (mean removed, Hann
    window, zero-padded 8x, refined by a parabola through the peak bin); 0 for a flat signal."""
    y = np.asarray(signal, dtype=np.float64)
    if len(y) < 4 or np.ptp(y) == 0:
        return 0.0
    dt = float(np.mean(np.diff(times)))
    n = 8 * len(y)
    spec = np.abs(np.fft.rfft((y - y.mean()) * np.hanning(len(y)), n))
    f = np.fft.rfftfreq(n, dt)
    spec[f < fmin] = 0.0
    k = int(np.argmax(spec))
    if 0 < k < len(spec) - 1:
        a, b, c = spec[k - 1], spec[k], spec[k + 1]
        den = a - 2 * b + c
        shift = 0.5 * (a - c) / den if den != 0 else 0.0
        return float((k + shift) * (f[1] - f[0]))
    return float(f[k])


def ringdown(signal: np.ndarray, times: np.ndarray, t_stop: float, window: float | None = None) -> Ringdown:
    """The free decay of signal (F,) metres at times (F,) seconds after t_stop (see the module), fitted over the
    `window` seconds after t_stop (None: to the end). A window of ~3 periods of the expected mode keeps a heavily
    damped fundamental (gone in one period) from being outweighed by a weak, slower mode ringing on after it."""
    from scipy.optimize import least_squares
    keep = times >= t_stop - 1e-12
    if window is not None:
        keep &= times <= t_stop + window + 1e-12
    t, y = times[keep] - t_stop, np.asarray(signal, dtype=np.float64)[keep]
    c0 = float(np.mean(y[len(y) // 2:]))
    f0 = max(dominant_frequency(y, t + t_stop), 1.0 / max(t[-1], 1e-9))
    w0 = 2 * math.pi * f0
    A0 = float(np.max(np.abs(y - c0)))

    def model(p):
        A, zeta, w, phi, c = p
        zeta = min(max(zeta, 0.0), 0.95)
        return A * np.exp(-zeta * w * t) * np.cos(w * math.sqrt(1 - zeta ** 2) * t + phi) + c

    best = None
    for phi in np.linspace(0, 2 * math.pi, 8, endpoint=False):       # a few starts: the phase is not known
        for z0 in (0.05, 0.3):
            r = least_squares(lambda p: model(p) - y, [A0, z0, w0, phi, c0],
                              bounds=([0, 0, 0.3 * w0, -10, -np.inf], [np.inf, 0.95, 3 * w0, 10, np.inf]))
            if best is None or r.cost < best.cost:
                best = r
    A, zeta, w, _, _ = best.x
    return Ringdown(frequency_hz=float(w / (2 * math.pi)), damping_ratio=float(zeta), amplitude=float(A),
                    rms=float(np.sqrt(np.mean(best.fun ** 2))))


def decrement(signal: np.ndarray, times: np.ndarray, t_stop: float, most: int = 6, floor: float = 0.05
              ) -> tuple[float, int]:
    """(delta, n): the logarithmic decrement per period of signal (F,) at times (F,) seconds after t_stop, from its
    successive extrema about its final value (see the module): delta = -2 x the slope of ln|extremum| against
    its index, fitted to the first `most` extrema down to `floor` x the first's; n the extrema used (nan below 2)."""
    keep = times >= t_stop - 1e-12
    y = np.asarray(signal, dtype=np.float64)[keep]
    y = y - y[-max(len(y) // 10, 1):].mean()              # about where it settles
    if len(y) < 3:
        return float("nan"), 0
    s = np.sign(y)
    amps, i = [], 0
    while i < len(y):                                     # one extremum per run of a sign: its largest |y|
        j = i
        while j < len(y) and s[j] == s[i]:
            j += 1
        if s[i] != 0:
            amps.append(float(np.abs(y[i:j]).max()))
        i = j
    if amps and amps[0] < max(amps):                      # a swing still building at the stop: from the largest
        amps = amps[int(np.argmax(amps)):]
    amps = [a for a in amps[:most] if a >= floor * amps[0]] if amps else []
    if len(amps) < 2:
        return float("nan"), len(amps)
    slope = np.polyfit(np.arange(len(amps)), np.log(amps), 1)[0]
    return float(-2.0 * slope), len(amps)


__all__ = ["Ringdown", "decrement", "goal_offsets", "peak_displacement", "offset_magnitude", "detrend", "principal_signal", "dominant_frequency",
           "ringdown"]
