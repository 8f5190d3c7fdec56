"""`jiggle compare OUT_DIR`: what the jiggle did to a bake, as numbers, plots, pictures and one report.

Reads OUT_DIR/bake.npz (sim.bake.caches) and writes into OUT_DIR, each file atomically (rig.base.atomic), an
earlier run's outputs replaced. Only those are: compare.json records every file a run writes (see
sim.bake.baker.COMPARE_RECORD), a new run (or bake) removes or overwrites only files so recorded, and a
name below already taken by a file of the user's is written as NAME.jiggle.EXT instead (the report and
metrics.json's "files" name what was written):

metrics.json      the numbers below, strict JSON (no NaN: a missing value is null), units in key names
displacement.npz  per-vertex skin displacement: max_m (V,) and rms_m (V,) float32 metres, over time
amplitude.png     per-muscle jiggle amplitude over time (the largest 8 labelled, the rest grey)
limits.png        per-muscle largest offset over its reach over time, the tissue law's onset and the
                  near-limit line marked (muscles with a reach only)
energy.png        per-muscle jiggle energy over time
spectrum.png      per-muscle amplitude spectrum, the dominant frequency marked
displacement.png  the skin's largest and RMS displacement per frame, and a histogram over vertices
chains.png        for a bake with chains: each chain's tip offset over time and its height, animated and swung
                  (sim.app.report.chains; metrics.json "chains")
quality.png       skin quality per frame: folded edges of the LBS, static and final skins, jiggle
                  tears (sim.app.report.skin_quality)
contacts.png      for a bake with collisions (its bake.json has "contacts"): the deepest particle
                  penetration per frame and the skin vertices inside another part's capsule per frame,
                  static and final skin (see :func:`collision_metrics`)
activation.png    for a bake with activation (--activation on): the hardest-working muscles' activation over
                  time above their jiggle amplitude (metrics.json "activation")
peak.png          static | dynamic skin at the peak frame (sim.app.report.compare_render), unless render=False
quality_closeups.png  the worst frames for skin quality, close up, static | final, unless render=False
glb_closeup.png   for a bake with a glb (--formats glb): its worst frame close up, skin_final | played from the
                  glb (sim.app.report.glb; metrics.json "glb": the file's fit per frame), unless render=False
clip.mp4          the same over the whole clip (clip.gif when ffmpeg fails), unless render/video False
report.html       one self-contained page with all of it (sim.app.report.page)

Definitions (the bake's muscle CVs are the *blended* ones, so everything here is what the skin gets):

- the reference skin: what the tissue's jiggle is measured from, BakeData.skin_swung(): skin_static plus what the
  swung chains add (chain_delta), so a tail swinging a metre is not a metre of jiggle and an edge the chain turns
  rigidly is not torn; skin_static itself for a bake without chains (the same numbers as before chains). The
  displacement, the peak frame, the skin quality's jiggle gradient, the loop wrap and the pictures use it; the
  chains themselves are measured in metrics.json's "chains" (sim.app.report.chains);
- skin displacement of vertex v at frame t: |skin_final - reference| (metres);
- muscle amplitude a_m(t): the largest CV distance |dynamic - static| over the muscle's CVs;
  its RMS is sqrt(mean_t a_m(t)^2);
- jiggle energy (see :func:`muscle_energy`), the dominant frequency (see :func:`muscle_spectrum`);
- settle time: as `jiggle simulate` (sim.app.outputs.simulate.settle_time).
"""
from __future__ import annotations

import json
import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError
from jiggle.sim.app.report import skin_quality
from jiggle.sim.app.outputs.simulate import SETTLE_FRACTION, SETTLE_WINDOW, settle_time
from jiggle.sim.app.report.plots import plot_contacts, pyplot, save_figure
from jiggle.sim.app.report.spectrum import MIN_CYCLES, MIN_FRAMES, STILL, dominant_frequency, muscle_spectrum
from jiggle.sim.bake.baker import COMPARE_NAMES, COMPARE_RECORD, COMPARE_RECORD_FORMAT, SUMMARY, compare_files, remove_listed
from jiggle.sim.bake.caches import BakeData, read_npz

FORMAT = "jiggle.compare/1"
BAKE = "bake.npz"
PARTIAL = ".partial"
TOP = 8
"""Muscles labelled in the plots (the largest peaks)."""
NEAR_LIMIT = 0.9
"""A CV at >= this fraction of its reach is near its limit (sim.jiggle.tissue_law.NEAR)."""
NEAR_LIMIT_FLAG = 0.05
"""The report flags a muscle near its limit in more than this fraction of the frames."""



# ---------------------------------------------------------------------------------------- input
def load_bake(out_dir: str | os.PathLike) -> BakeData:
    """OUT_DIR/bake.npz read back; InputError naming the path for a missing folder or cache and for
    an unfinished bake (only a `.partial/` folder there)."""
    out_dir = os.fspath(out_dir)
    if not os.path.exists(out_dir):
        raise InputError(f"no such folder; run `jiggle bake ... --out {out_dir}` first", out_dir)
    if not os.path.isdir(out_dir):
        raise InputError("expected the folder a bake wrote (jiggle bake --out OUT_DIR), found a file",
                         out_dir)
    path = os.path.join(out_dir, BAKE)
    if not os.path.exists(path):
        if os.path.isdir(os.path.join(out_dir, PARTIAL)):
            raise InputError(f"the bake is unfinished (only {PARTIAL}/ is there, no {BAKE}); run "
                             f"`jiggle bake --resume --out {out_dir}` to finish it", out_dir)
        raise InputError(f"no {BAKE} here; run `jiggle bake ... --out {out_dir}` first", path)
    return read_npz(path)


def _number(value, least: float = 0.0, strict: bool = True) -> float | None:
    """A finite float above `least` (at least `least` when not strict) from hand-written params, else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    ok = math.isfinite(value) and (value > least if strict else value >= least)
    return value if ok else None


def read_params(text: str, names) -> tuple[dict, list[dict]]:
    """The bake's params JSON as (whole dict, one dict per muscle of `names`: mass_kg, frequency_hz,
    damping_ratio, kind, each None when absent or unusable). Tolerant: test data may lack any key."""
    try:
        params = json.loads(text)
    except ValueError:
        params = {}
    params = params if isinstance(params, dict) else {}
    table = params.get("muscles")
    table = table if isinstance(table, dict) else {}
    # a character simulated at its template's size has its caches at the file's size (bake.json size_scale: the
    # simulated metres per file metre); its reach, a simulated length, is compared with them at the file's size
    size = _number(params.get("size_scale")) or 1.0
    muscles = []
    for name in names:
        entry = table.get(name)
        entry = entry if isinstance(entry, dict) else {}
        kind = entry.get("kind")
        # bake.json names them frequency and damping (the scene's keys); older bakes frequency_hz, damping_ratio.
        # A keyed value (a curve) is no one number: None
        reach = _number(entry.get("reach_m"))
        muscles.append({"mass_kg": _number(entry.get("mass_kg")), "reach_m": None if reach is None else reach / size,
                        "strength": _number(entry.get("strength"), strict=False),
                        "frequency_hz": _number(entry.get("frequency", entry.get("frequency_hz"))),
                        "damping_ratio": _number(entry.get("damping", entry.get("damping_ratio")), strict=False),
                        "kind": kind if isinstance(kind, str) else None})
    return params, muscles


# ---------------------------------------------------------------------------------------- skin
def reference_skin(data: BakeData) -> tuple[np.ndarray, str]:
    """(skin (T, V, 3) float32 metres, its name): what the tissue's jiggle is measured from (see the module):
    data.skin_swung() and "skin_swung" for a bake whose chains move skin, else data.skin_static (the same array)
    and "skin_static"."""
    if data.chain_vertices is None or not len(data.chain_vertices):
        return data.skin_static, "skin_static"
    return data.skin_swung(), "skin_swung"


def skin_displacement(static: np.ndarray, final: np.ndarray, chunk: int = 32) -> np.ndarray:
    """(T, V) float32 metres: |final - static| per frame and vertex, from (T, V, 3) skins.

    Differences are taken in float64 a few frames at a time, so a long bake needs no (T, V, 3)
    float64 temporary."""
    T, V = static.shape[:2]
    out = np.empty((T, V), np.float32)
    for a in range(0, T, chunk):
        d = final[a:a + chunk].astype(np.float64) - static[a:a + chunk]
        out[a:a + chunk] = np.sqrt(np.einsum("tvi,tvi->tv", d, d))
    return out


def _summary(x: np.ndarray) -> dict:
    """max, mean, p50, p95, p99 of x (metres) in mm."""
    if x.size == 0:
        return {k: None for k in ("max_mm", "mean_mm", "p50_mm", "p95_mm", "p99_mm")}
    p50, p95, p99 = np.percentile(x, (50, 95, 99))
    return {"max_mm": 1e3 * float(x.max()), "mean_mm": 1e3 * float(x.mean()),
            "p50_mm": 1e3 * float(p50), "p95_mm": 1e3 * float(p95), "p99_mm": 1e3 * float(p99)}


def skin_metrics(disp: np.ndarray, times: np.ndarray, chunk: int = 32) -> tuple[dict, dict, dict]:
    """From disp (T, V) metres: (skin facts, peak-frame facts, arrays).

    arrays: max_m / rms_m (V,) per vertex over time, frame_max_m / frame_rms_m (T,) per frame over
    vertices (float64). The peak frame is the frame whose largest vertex displacement is largest.
    Squares are summed in float64 a few frames at a time (no (T, V) float64 copy)."""
    T, V = disp.shape
    vmax = disp.max(axis=0).astype(np.float64) if V else np.zeros(0)
    fmax = disp.max(axis=1).astype(np.float64) if V else np.zeros(T)
    sq_v, sq_f = np.zeros(V), np.zeros(T)
    for a in range(0, T, chunk):
        d2 = disp[a:a + chunk].astype(np.float64) ** 2
        sq_v += d2.sum(axis=0)
        sq_f[a:a + chunk] = d2.sum(axis=1)
    vrms = np.sqrt(sq_v / T)
    frms = np.sqrt(sq_f / V) if V else np.zeros(T)
    k = int(np.argmax(fmax))
    v = int(np.argmax(disp[k])) if V else None
    skin = {"displacement": "|skin_final - skin_static| per vertex and frame",
            "max_mm": 1e3 * float(fmax[k]), "mean_mm": 1e3 * float(disp.mean(dtype=np.float64)) if V else None,
            "max_vertex": v, "max_frame": k, "max_time_s": float(times[k]),
            "per_vertex_max": _summary(vmax), "per_vertex_rms": _summary(vrms)}
    peak = {"frame": k, "time_s": float(times[k]),
            "rule": "the frame whose largest vertex displacement is largest",
            "max_mm": 1e3 * float(fmax[k]), "rms_mm": 1e3 * float(frms[k]),
            "total_frame": int(np.argmax(frms)),
            "total_rule": "total_frame: the frame with the largest RMS (total) displacement over vertices"}
    return skin, peak, {"max_m": vmax, "rms_m": vrms, "frame_max_m": fmax, "frame_rms_m": frms}


# ---------------------------------------------------------------------------------------- muscles
def muscle_offsets(data: BakeData) -> np.ndarray:
    """(T, N, 3) float64 metres: every CV's offset d = dynamic - static."""
    return data.muscle_cvs_dynamic.astype(np.float64) - data.muscle_cvs_static


def muscle_amplitude(d: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(T, M) metres: each muscle's largest CV distance |d| per frame (0 for a muscle without CVs).

    d : (T, N, 3) metres, CV offsets. offsets : (M + 1,) muscle m owns CVs offsets[m]:offsets[m + 1]."""
    dist = np.linalg.norm(d, axis=2)
    M = len(offsets) - 1
    out = np.zeros((d.shape[0], M))
    for m in range(M):                  # analysis after the bake, a few dozen muscles: clarity first
        a, b = offsets[m], offsets[m + 1]
        if b > a:
            out[:, m] = dist[:, a:b].max(axis=1)
    return out


def muscle_energy(d: np.ndarray, times: np.ndarray, offsets: np.ndarray, masses: np.ndarray,
                  omegas: np.ndarray) -> np.ndarray:
    """(T, M) jiggle energy per muscle and frame: J (or J/kg with masses of 1, see below).

    Each CV is a harmonic oscillator around its goal (the static CV), so its energy is kinetic plus
    spring energy of the offset::

        E_m(t) = sum over CVs c of muscle m of 0.5 m_c (|v_c(t)|^2 + w_m^2 |d_c(t)|^2)

    d : (T, N, 3) metres, d_c = dynamic - static. v_c = dd_c/dt (m/s) by central differences over
        `times` (np.gradient; one-sided at the ends; 0 for a single frame).
    times : (T,) seconds. offsets : (M + 1,) CV ranges.
    masses : (M,) kg, the muscle's mass shared evenly by its CVs (m_c = mass / CVs); 1 for J/kg.
    omegas : (M,) rad/s, w = 2 pi frequency_hz of the muscle's goal spring: the nominal one (a
        particle's own also scales with its goal weight and the strength, sim.jiggle.params), so the
        spring term is the energy of a muscle-wide oscillator, comparable between muscles and bakes.
    """
    T = d.shape[0]
    v = np.gradient(d, times, axis=0) if T > 1 else np.zeros_like(d)
    per_cv = np.einsum("tni,tni->tn", v, v), np.einsum("tni,tni->tn", d, d)
    M = len(offsets) - 1
    out = np.zeros((T, M))
    for m in range(M):
        a, b = offsets[m], offsets[m + 1]
        if b > a:
            m_c = masses[m] / (b - a)
            out[:, m] = 0.5 * m_c * (per_cv[0][:, a:b].sum(axis=1) + omegas[m] ** 2 * per_cv[1][:, a:b].sum(axis=1))
    return out


def limit_fraction(d: np.ndarray, offsets: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(T, M) each muscle's largest CV offset per frame as a fraction of its reach (0 where the reach is
    unknown or none). d : (T, N, 3) metres, CV offsets; reach : (M,) metres (nan: none)."""
    rho = np.zeros((d.shape[0], len(offsets) - 1))
    amp = muscle_amplitude(d, offsets)
    ok = np.isfinite(reach) & (reach > 0)
    rho[:, ok] = amp[:, ok] / reach[ok]
    return rho


def limit_advice(name: str, p: dict) -> str:
    """What to change for a muscle that spends too long near its limit (the scene's keys)."""
    z, j = p.get("damping_ratio"), p.get("strength")
    tips = []
    if z is not None and z < 0.5:
        tips.append(f"raise its damping (now {z:g}) so each swing loses more")
    if j is not None and j > 0:
        tips.append(f"lower its strength (now {j:g}: the swing scales with it)")
    tips.append("or raise max_offset if this tissue may move further")
    return f"[jiggle.muscles.{name}]: " + "; ".join(tips)


# ---------------------------------------------------------------------------------------- analysis
def analyse(data: BakeData, tissue: dict | None = None) -> dict:
    """Everything compare measures, before anything is written. Keys (arrays float64 unless said):

    params, per_muscle : read_params of the bake's params.
    reference : (T, V, 3) float32 metres, the skin the jiggle is measured from (data.skin_swung(): skin_static
    for a bake without chains); reference_name : "skin_static" or "skin_swung".
    disp : (T, V) float32 metres, skin displacement |final - reference|; skin, peak, skin_arrays : skin_metrics.
    amplitude (T, M) metres; freqs (K,) Hz and spectrum (K, M) metres (muscle_spectrum);
    dominant_hz : M floats or None; energy (T, M) in energy_unit ("J", or "J/kg" when any muscle
    lacks mass_kg, so that one plot has one unit); order : muscle indices, largest peak first;
    muscles : name -> JSON-ready facts, in that order.
    """
    T, V = data.skin_static.shape[:2]
    times, names, offsets = data.times, list(data.muscle_names), data.muscle_cv_offsets
    params, per_muscle = read_params(data.params, names)
    reference, ref_name = reference_skin(data)
    disp = skin_displacement(reference, data.skin_final)
    skin, peak, arrays = skin_metrics(disp, times)
    if ref_name != "skin_static":
        skin["displacement"] = ("|skin_final - skin_swung| per vertex and frame (skin_swung = skin_static + "
                                "chain_delta: the skin following the swung chains; the tissue's jiggle alone)")

    d = muscle_offsets(data)
    amp = muscle_amplitude(d, offsets)
    freqs, spectrum = muscle_spectrum(d, offsets, data.fps)
    peaks = amp.max(axis=0)
    reach = np.array([np.nan if p["reach_m"] is None else p["reach_m"] for p in per_muscle])
    rho = limit_fraction(d, offsets, reach)
    tissue = tissue if isinstance(tissue, dict) else {}
    stops = tissue.get("hard_stops") if isinstance(tissue.get("hard_stops"), dict) else {}
    dominant = [dominant_frequency(freqs, spectrum[:, m], T, bool(peaks[m] > STILL)) for m in range(len(names))]
    # masses: all muscles in J only when every muscle has one, so the energy plot has one unit
    per_kg = any(p["mass_kg"] is None for p in per_muscle)
    masses = np.array([1.0 if per_kg else p["mass_kg"] for p in per_muscle])
    omega_src = [("params", p["frequency_hz"]) if p["frequency_hz"] is not None else
                 ("measured", dominant[m]) if dominant[m] is not None else (None, 0.0)
                 for m, p in enumerate(per_muscle)]
    omegas = np.array([2.0 * np.pi * f for _, f in omega_src])
    energy = muscle_energy(d, times, offsets, masses, omegas)
    energy_unit = "J/kg" if per_kg else "J"
    order = [int(i) for i in np.argsort(-peaks, kind="stable")]

    muscles = {}
    for m in order:
        a, e, p = amp[:, m], energy[:, m], per_muscle[m]
        k, ke = int(np.argmax(a)), int(np.argmax(e))
        settle = settle_time(times, a, k) if a[k] > STILL else 0.0
        muscles[names[m]] = {
            "kind": p["kind"], "cvs": int(offsets[m + 1] - offsets[m]),
            "peak_mm": 1e3 * a[k], "peak_time_s": times[k], "peak_frame": k,
            "rms_mm": 1e3 * math.sqrt(float((a ** 2).mean())), "end_mm": 1e3 * a[-1],
            "peak_energy_j": e[ke], "peak_energy_time_s": times[ke], "mean_energy_j": float(e.mean()),
            "dominant_hz": dominant[m], "settle_s": settle,
            "mass_kg": p["mass_kg"], "frequency_hz": p["frequency_hz"], "damping_ratio": p["damping_ratio"],
            "energy_frequency_hz": omega_src[m][1] if omega_src[m][0] else None,
            "energy_frequency_from": omega_src[m][0],
            "reach_mm": 1e3 * reach[m] if np.isfinite(reach[m]) else None,
            "peak_reach_fraction": float(rho[:, m].max()) if np.isfinite(reach[m]) and T else None,
            "near_limit_fraction": float((rho[:, m] >= NEAR_LIMIT).mean()) if np.isfinite(reach[m]) and T else None,
            "hard_stops": int(stops[names[m]]) if isinstance(stops.get(names[m]), int) else None,
        }
    limits = limit_summary(names, per_muscle, rho, reach, stops)
    return {"params": params, "per_muscle": per_muscle, "reference": reference, "reference_name": ref_name,
            "disp": disp, "skin": skin, "peak": peak,
            "skin_arrays": arrays, "amplitude": amp, "freqs": freqs, "spectrum": spectrum, "dominant_hz": dominant,
            "energy": energy, "energy_unit": energy_unit, "order": order, "muscles": muscles, "limits": limits,
            "reach_fraction": rho}


def limit_summary(names, per_muscle, rho: np.ndarray, reach: np.ndarray, stops: dict) -> dict:
    """metrics.json's "limits": how much of the clip the muscles spend near their reach (rho (T, M) of
    :func:`limit_fraction`), the hard stops of bake.json's "tissue", and a flag with advice for each muscle
    near its limit in more than NEAR_LIMIT_FLAG of the frames."""
    has = np.isfinite(reach)
    near = rho[:, has] >= NEAR_LIMIT
    flags = []
    for m in np.flatnonzero(has):
        frac = float((rho[:, m] >= NEAR_LIMIT).mean()) if len(rho) else 0.0
        if frac > NEAR_LIMIT_FLAG:
            flags.append({"muscle": names[m], "near_limit_fraction": frac, "advice": limit_advice(names[m], per_muscle[m])})
    flags.sort(key=lambda f: -f["near_limit_fraction"])
    total = sum(int(v) for v in stops.values() if isinstance(v, int)) if stops else None
    return {"near": NEAR_LIMIT, "flag_above": NEAR_LIMIT_FLAG,
            "rule": f"a muscle is near its limit in a frame when one of its CVs is at >= {NEAR_LIMIT:g} x its reach "
                    "(reach_m in bake.json; the bake's blended CVs)",
            "near_limit_fraction_all": float(near.mean()) if near.size else None,
            "muscles_near_limit": int(near.any(axis=0).sum()) if near.size else 0,
            "muscles_with_reach": int(has.sum()),
            "worst": dict(zip(("muscle", "near_limit_fraction"),
                              max(((names[m], float((rho[:, m] >= NEAR_LIMIT).mean())) for m in np.flatnonzero(has)),
                                  key=lambda x: x[1], default=(None, None)))),
            "hard_stops_total": total, "flags": flags}


# ---------------------------------------------------------------------------------------- plots
def _curves(ax, times, values, names, order, top):
    """The `top` first muscles of `order` as labelled lines, the rest thin grey without a label."""
    for m in order[top:]:
        ax.plot(times, values[:, m], color="0.75", lw=0.7)
    for m in order[:top]:
        ax.plot(times, values[:, m], lw=1.4, label=names[m])
    _legend(ax, order)
    ax.grid(alpha=0.3)
    ax.set_xlabel("time (s)")


def _legend(ax, order):
    """The legend right of the axes, where it hides no curve."""
    if len(order):
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)


def plot_amplitude(path, times, amp, names, order, top=TOP, title=""):
    """amplitude.png: amplitude (T, M) metres over time, shown in mm."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 4))
    _curves(ax, times, 1e3 * amp, names, order, top)
    ax.set_ylabel("jiggle amplitude (mm)\nmax |dynamic - static| CV")
    ax.set_title(title or "muscle jiggle amplitude")
    return save_figure(fig, path)


def plot_limits(path, times, rho, names, order, top=TOP, title=""):
    """limits.png: each muscle's largest CV offset over its reach (T, M) over time, the tissue law's onset
    (linear below it) and the near-limit line marked; the muscles nearest their reach labelled."""
    from jiggle.sim.jiggle.tissue_law import ONSET
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 4))
    _curves(ax, times, rho, names, order, top)
    for level, label, style in ((ONSET, "linear below", ":"), (NEAR_LIMIT, "near the limit", "--")):
        ax.axhline(level, color="k", lw=0.8, ls=style)
        ax.annotate(label, (times[0] if len(times) else 0.0, level), xytext=(2, 2), textcoords="offset points",
                    fontsize=8, color="k")
    ax.set_ylim(0.0, max(1.05, float(rho.max()) * 1.05) if rho.size else 1.05)
    ax.set_ylabel("offset / reach\nlargest CV")
    ax.set_title(title or "how near each muscle comes to its reach (the tissue law stiffens above the dotted line)")
    return save_figure(fig, path)


def plot_energy(path, times, energy, names, order, unit, top=TOP, title=""):
    """energy.png: energy (T, M) in `unit` over time."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 4))
    _curves(ax, times, energy, names, order, top)
    ax.set_ylabel(f"jiggle energy ({unit})")
    ax.set_title(title or "muscle jiggle energy: 0.5 m (|v|^2 + w^2 |d|^2) over CVs")
    return save_figure(fig, path)


def plot_spectrum(path, freqs, amp, names, order, dominant, top=TOP, title=""):
    """spectrum.png: amplitude spectra (K, M) metres in mm, a dot on each dominant frequency."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 4))
    for m in order[top:]:
        ax.plot(freqs, 1e3 * amp[:, m], color="0.75", lw=0.7)
    for m in order[:top]:
        line, = ax.plot(freqs, 1e3 * amp[:, m], lw=1.4,
                        label=names[m] + ("" if dominant[m] is None else f" ({dominant[m]:.2f} Hz)"))
        if dominant[m] is not None:
            k = int(np.argmin(np.abs(freqs - dominant[m])))     # the dot at the peak bin's height
            ax.plot([dominant[m]], [1e3 * amp[k, m]], "o", color=line.get_color())
            ax.axvline(dominant[m], color=line.get_color(), ls=":", lw=0.8)
    _legend(ax, order)
    ax.grid(alpha=0.3)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude (mm)\nRMS over CVs, Hann window")
    ax.set_title(title or "muscle jiggle spectrum (dots: dominant frequency)")
    return save_figure(fig, path)


def plot_displacement(path, times, arrays, peak_frame, title=""):
    """displacement.png: per-frame largest and RMS skin displacement (mm) over time, the peak frame
    marked; beside it a histogram of the per-vertex largest displacement."""
    plt = pyplot()
    fig, (ax, hx) = plt.subplots(1, 2, figsize=(11, 4), gridspec_kw={"width_ratios": [2, 1]})
    ax.plot(times, 1e3 * arrays["frame_max_m"], lw=1.4, label="largest vertex")
    ax.plot(times, 1e3 * arrays["frame_rms_m"], lw=1.4, label="RMS over vertices")
    ax.axvline(times[peak_frame], color="0.4", ls=":", lw=1.0, label=f"peak frame {peak_frame}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("skin displacement (mm)\n|final - static|")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title or "skin displacement per frame")
    vmax = 1e3 * arrays["max_m"]
    hx.hist(vmax, bins=40, color=(0.85, 0.45, 0.2))
    hx.set_yscale("log")                      # most of a body stays put: a linear axis shows one bar
    hx.set_xlabel("largest displacement per vertex (mm)")
    hx.set_ylabel("vertices (log)")
    hx.grid(alpha=0.3)
    return save_figure(fig, path)


# ---------------------------------------------------------------------------------------- collisions
def read_contacts(out_dir: str, key: str = "contacts") -> dict | None:
    """The "contacts" of OUT_DIR/bake.json (a bake with collisions, sim.bake.baker), or None: no bake.json,
    an unreadable one, or a bake without collisions. key: another section ("tissue": the hard stops)."""
    try:
        with open(os.path.join(out_dir, SUMMARY), encoding="utf-8") as fh:
            summary = json.load(fh)
    except (OSError, ValueError):
        return None
    contacts = summary.get(key) if isinstance(summary, dict) else None
    return contacts if isinstance(contacts, dict) else None


def collision_metrics(contacts: dict, times: np.ndarray) -> dict:
    """metrics.json's "collisions" from bake.json's "contacts" and the bake's frame times (T,) seconds:

    frames_in_contact, max_penetration_mm (the deepest particle penetration before correction), floor_m,
    friction, colliders (count); pairs: per (muscle, what it hit) the frames in contact, the deepest
    penetration (mm) and the summed impulse (N s), deepest first; skin_inside: per skin (static, final) the
    most and the mean skin vertices of one body part inside another part's capsule per frame, the frames
    where the final skin has more than the static, the worst frame of the final skin, and the final vertices the
    jiggle took into a capsule that were pulled back (frames, most in a frame, the longest pull in mm); per_frame:
    T values each of max_penetration_mm, impulse_Ns, muscle and hit (the deepest contact's), skin_inside_static,
    skin_inside_final and skin_pulled_back. A per-frame list whose length is not T (a bake cut short) is left out."""
    T = len(times)
    per = contacts.get("per_frame") if isinstance(contacts.get("per_frame"), dict) else {}
    out = {"method": contacts.get("method"), "friction": contacts.get("friction"), "floor_m": contacts.get("floor_m"),
           "colliders": len(contacts.get("colliders") or ()), "pairs_checked": contacts.get("pairs_checked"),
           "frames_in_contact": int(contacts.get("frames_in_contact") or 0),
           "max_penetration_mm": float(contacts.get("max_penetration_mm") or 0.0),
           "pairs": [p for p in (contacts.get("pairs") or []) if isinstance(p, dict)], "per_frame": {}}
    for key in ("max_penetration_mm", "impulse_Ns", "muscle", "hit"):
        if isinstance(per.get(key), list) and len(per[key]) == T:
            out["per_frame"][key] = per[key]
    si = contacts.get("skin_inside")
    if isinstance(si, dict) and all(isinstance(si.get(k), list) and len(si[k]) == T for k in ("static", "final")):
        s, f = np.asarray(si["static"], np.int64), np.asarray(si["final"], np.int64)
        out["skin_inside"] = {
            "rule": "skin vertices of one body part (its dominant joint) inside another part's bone capsule "
                    "(not the bones meeting it at a joint), per frame",
            "max_static": int(s.max()) if T else 0, "max_final": int(f.max()) if T else 0,
            "mean_static": float(s.mean()) if T else 0.0, "mean_final": float(f.mean()) if T else 0.0,
            "frames_final_above_static": int((f > s).sum()),
            "worst_final_frame": int(np.argmax(f)) if T else None}
        out["per_frame"]["skin_inside_static"] = s.tolist()
        out["per_frame"]["skin_inside_final"] = f.tolist()
        if isinstance(si.get("kept_out"), list) and len(si["kept_out"]) == T:
            k = np.asarray(si["kept_out"], np.int64)
            out["skin_inside"].update({"pulled_back_frames": int((k > 0).sum()), "max_pulled_back": int(k.max()),
                                       "max_pull_mm": float(si.get("max_pull_mm") or 0.0),
                                       "pull_back": si.get("method")})
            out["per_frame"]["skin_pulled_back"] = k.tolist()
    return out


# ---------------------------------------------------------------------------------------- json
def clean(value, digits: int = 9):
    """`value` as strict JSON: numpy numbers to Python, floats to `digits` significant digits,
    NaN and infinities to None; dicts, lists and tuples recursively."""
    if isinstance(value, dict):
        return {str(k): clean(v, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [clean(v, digits) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return float(f"{value:.{digits}g}") if math.isfinite(value) else None
    return value if value is None or isinstance(value, str) else str(value)


def _write_json(path: str, doc: dict) -> str:
    with atomic_path(path) as tmp, open(tmp, "w") as fh:
        json.dump(doc, fh, indent=2, allow_nan=False)
    return path


def _label(value) -> str | None:
    """A short name for a params "clip" / "character" entry: a string, or a dict with a name, a file,
    a built-in scene or a generated body (as sim.bake.setup writes them)."""
    if isinstance(value, str):
        return value
    if isinstance(value, dict):
        if isinstance(value.get("name"), str):
            return value["name"]
        for key in ("file", "path"):
            if isinstance(value.get(key), str):
                return os.path.basename(value[key])
        if isinstance(value.get("builtin"), str):
            return f"the built-in {value['builtin']}"
        if "generated" in value:
            return "a generated body"
    return None


# ---------------------------------------------------------------------------------------- all
@contextmanager
def _timed(timings: dict, key: str):
    """Records timings[key]: the seconds (time.perf_counter) the with-block took, when it returns."""
    t0 = time.perf_counter()
    yield
    timings[key] = time.perf_counter() - t0


@dataclass(frozen=True)
class _Run:
    """One compare's outputs while it writes them: OUT_DIR, the files an earlier run recorded (own, from
    compare.json), the name each output is written under (as_name, see _names), what this run wrote (files:
    key -> path, in writing order, metrics.json's "files") and how long each step took (timings: key -> seconds,
    metrics.json's "timings_s")."""
    out_dir: str
    own: set
    as_name: dict
    timings: dict
    files: dict = field(default_factory=dict)

    @classmethod
    def claim(cls, out_dir: str, timings: dict) -> _Run:
        """The names this run writes under, recorded in compare.json before anything else is written, so a run cut
        short leaves no file of its own that a later run would not remove."""
        own = compare_files(out_dir)
        as_name = _names(out_dir, own)
        _write_json(os.path.join(out_dir, as_name[COMPARE_RECORD]),     # before writing: what this run may write
                    {"format": COMPARE_RECORD_FORMAT, "files": sorted(own | set(as_name.values()))})
        return cls(out_dir, own, as_name, timings)

    def path(self, name: str) -> str:
        """Where the output `name` (of the module docstring) is written."""
        return os.path.join(self.out_dir, self.as_name[name])

    def finish(self) -> None:
        """Removes an earlier run's outputs not written again (pictures beside these numbers would read as this
        run's) and records in compare.json what this run wrote."""
        written = {os.path.basename(p) for p in self.files.values()} | {self.as_name[COMPARE_RECORD]}
        remove_listed(self.out_dir, self.own - written)
        _write_json(os.path.join(self.out_dir, self.as_name[COMPARE_RECORD]), {"format": COMPARE_RECORD_FORMAT,
                                                                             "files": sorted(written)})


def compare(out_dir: str, *, render: bool = True, video: bool = True,
            progress: Callable[[int], None] | None = None) -> dict:
    """Analyse OUT_DIR/bake.npz and write the files of the module docstring into OUT_DIR.

    render : False skips peak.png and the video (metrics, plots and report.html are still written).
    video : False skips only the video.
    progress : called as progress(n) with the frames just rendered (n = 1 per frame, as tqdm's
        update), 1 + len(sim.app.report.compare_render.video_frames(T)) calls in all with render and video.
    Returns {"files": {key: path}, "metrics": the metrics.json dict}; keys of files: metrics,
    displacement, amplitude, energy, spectrum, displacement_plot, quality_plot, chains_plot (a bake with
    chains), contacts_plot (a bake with collisions), activation_plot (a bake with activation), peak, video, report.
    InputError for a missing, unfinished or unreadable bake.
    """
    out_dir = os.fspath(out_dir)
    timings = {}
    with _timed(timings, "read_s"):
        data = load_bake(out_dir)
    with _timed(timings, "analysis_s"):
        tissue = read_contacts(out_dir, "tissue")
        an = analyse(data, tissue)
    run = _Run.claim(out_dir, timings)
    with _timed(timings, "plots_s"):
        _write_plots(run, data, an)
    with _timed(timings, "quality_s"):
        quality_m = skin_quality.measure(data, an["reference"], an["reference_name"])
        quality = skin_quality.summarise(quality_m, data.times)
        if (solid := skin_quality.fem_target(read_contacts(out_dir, "fem"))) is not None:
            quality["targets"]["fem_inverted_tets"] = solid
        run.files["quality_plot"] = skin_quality.plot_quality(run.path("quality.png"), data.times, quality)
    chains = _chains(run, data, an, quality_m)
    collisions = _collisions(run, data.times)
    activation = _activation(run, data, an)
    pictures = bool(render and data.skin_static.shape[1])
    video_info = _render(run, data, an, quality_m, quality, video, progress) if pictures else None
    glb = _glb(run, data, pictures)

    run.files["metrics"] = run.path("metrics.json")
    run.files["report"] = run.path("report.html")
    metrics = clean(_metrics(data, an, tissue, run, quality=quality, chains=chains, collisions=collisions, glb=glb,
                             video=video_info))
    if activation is not None:
        metrics["activation"] = activation
    _write_json(run.files["metrics"], metrics)
    from jiggle.sim.app.report.page import write_report
    with _timed(timings, "report_s"):
        write_report(run.files["report"], metrics, run.files)
    metrics["timings_s"] = clean(timings)
    run.finish()
    return {"files": run.files, "metrics": metrics}


def _write_plots(run: _Run, data: BakeData, an: dict) -> None:
    """displacement.npz (per-vertex max_m, rms_m (V,) float32 metres) and the plots of the muscles and the skin:
    amplitude, limits (muscles with a reach only), energy, spectrum, displacement; an is analyse's."""
    times, names, order = data.times, list(data.muscle_names), an["order"]
    arrays, energy = an["skin_arrays"], an["energy"]
    with atomic_path(run.path("displacement.npz")) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, max_m=arrays["max_m"].astype(np.float32), rms_m=arrays["rms_m"].astype(np.float32))
    run.files["displacement"] = run.path("displacement.npz")
    run.files["amplitude"] = plot_amplitude(run.path("amplitude.png"), times, an["amplitude"], names, order)
    rho = an["reach_fraction"]
    if an["limits"]["muscles_with_reach"]:
        by_rho = [int(i) for i in np.argsort(-rho.max(axis=0), kind="stable")] if rho.size else []
        run.files["limits_plot"] = plot_limits(run.path("limits.png"), times, rho, names, by_rho)
    by_energy = [int(i) for i in np.argsort(-energy.max(axis=0), kind="stable")]
    run.files["energy"] = plot_energy(run.path("energy.png"), times, energy, names, by_energy, an["energy_unit"])
    run.files["spectrum"] = plot_spectrum(run.path("spectrum.png"), an["freqs"], an["spectrum"], names, order,
                                          an["dominant_hz"])
    run.files["displacement_plot"] = plot_displacement(run.path("displacement.png"), times, arrays,
                                                       an["peak"]["frame"])


def _chains(run: _Run, data: BakeData, an: dict, quality_m: dict) -> dict | None:
    """metrics.json's "chains" and chains.png (sim.app.report.chains); None, and no plot, for a bake without
    chains. quality_m: skin_quality.measure's."""
    if data.chain_tip_names is None:
        return None
    from jiggle.sim.app.report.chains import chain_metrics, plot_chains
    with _timed(run.timings, "chains_s"):
        chains, chain_arrays = chain_metrics(data, read_contacts(run.out_dir, "chains"), quality_m["quality"],
                                             an["reference"])
        run.files["chains_plot"] = plot_chains(run.path("chains.png"), data.times, list(data.chain_tip_names),
                                               chains, chain_arrays)
    return chains


def _activation(run: _Run, data: BakeData, an: dict) -> dict | None:
    """metrics.json's "activation" (per muscle its peak and mean, and when it peaked; the rule) and activation.png
    (sim.app.report.plots.plot_activation); None, and no plot, for a bake without activation."""
    if data.activation is None:
        return None
    from jiggle.sim.app.report.plots import plot_activation
    a = np.asarray(data.activation, np.float64)
    names = list(data.muscle_names)
    order = [int(i) for i in np.argsort(-a.mean(axis=0), kind="stable")]
    run.files["activation_plot"] = plot_activation(run.path("activation.png"), data.times, a, an["amplitude"], names,
                                                   order)
    return {"rule": "bake.npz's activation: each muscle's, from the clip's joint torques (bake.json params.activation)",
            "muscles": {names[m]: {"peak": float(a[:, m].max()), "mean": float(a[:, m].mean()),
                                   "peak_time_s": float(data.times[int(np.argmax(a[:, m]))])}
                        for m in order if a[:, m].max() > 0}}


def _collisions(run: _Run, times: np.ndarray) -> dict | None:
    """metrics.json's "collisions" (collision_metrics) and contacts.png; None, and no plot, for a bake without
    collisions. times : (T,) seconds."""
    contacts = read_contacts(run.out_dir)
    collisions = collision_metrics(contacts, times) if contacts is not None else None
    if collisions is not None:
        run.files["contacts_plot"] = plot_contacts(run.path("contacts.png"), times, collisions)
    return collisions


def _render(run: _Run, data: BakeData, an: dict, quality_m: dict, quality: dict, video: bool,
            progress: Callable[[int], None] | None) -> dict | None:
    """The pictures: peak.png and the video (sim.app.report.compare_render), then the skin quality's close-ups of
    its worst frames; returns metrics.json's "video" (None without one). quality_m, quality: skin_quality's
    measure and summarise."""
    from jiggle.sim.app.report.compare_render import render_outputs
    rendered = render_outputs(data, an["peak"]["frame"], an["disp"], run.out_dir, video=video, progress=progress,
                              name=run.as_name.__getitem__, reference=an["reference"])
    run.files.update(rendered["files"])
    run.timings.update(rendered["timings"])
    with _timed(run.timings, "quality_render_s"):
        closeups = skin_quality.render_closeups(data, quality_m, quality["worst_frames"], an["disp"],
                                                run.path("quality_closeups.png"), reference=an["reference"])
        if closeups:
            run.files["quality_closeups"] = closeups
    return rendered.get("video")


def _glb(run: _Run, data: BakeData, pictures: bool) -> dict | None:
    """metrics.json's "glb" (sim.app.report.glb) for a bake that wrote bake.glb, and glb_closeup.png with
    pictures; None for a bake without a glb."""
    if not ("glb" in (read_contacts(run.out_dir, "files") or {})
            and os.path.isfile(os.path.join(run.out_dir, "bake.glb"))):
        return None
    from jiggle.sim.app.report.glb import glb_check
    with _timed(run.timings, "glb_s"):
        glb, drawn = glb_check(run.out_dir, data, run.path("glb_closeup.png") if pictures else None)
        if drawn:
            run.files["glb_closeup"] = drawn
    return glb


def _metrics(data: BakeData, an: dict, tissue: dict | None, run: _Run, *, quality: dict, chains: dict | None,
             collisions: dict | None, glb: dict | None, video: dict | None) -> dict:
    """metrics.json's dict before clean(): the bake, analyse's numbers (an) and the rules behind them, the sections
    a bake has (chains, collisions, glb: None leaves one out), the video, the files written so far and the
    timings (run.timings itself, not a copy). tissue: bake.json's "tissue" (read_contacts) or None."""
    T, V = data.skin_static.shape[:2]
    times, names, params = data.times, list(data.muscle_names), an["params"]
    energy_unit = an["energy_unit"]
    return {
        "format": FORMAT, "bake": os.path.abspath(os.path.join(run.out_dir, BAKE)),
        "title": _title(params),
        "source": {"clip": params.get("clip"), "character": params.get("character"),
                   **{k: params[k] for k in ("scene", "template", "drive", "skinning") if k in params}},
        "settings": params.get("settings") if isinstance(params.get("settings"), dict) else {},
        "frames": T, "fps": data.fps, "duration_s": float(times[-1] - times[0]) if T else 0.0,
        "start_s": float(times[0]), "end_s": float(times[-1]), "vertices": V, "muscle_count": len(names),
        "reference": an["reference_name"],
        "skin": an["skin"], "peak": an["peak"], "skin_quality": quality,
        **({"chains": chains} if chains is not None else {}),
        **({"collisions": collisions} if collisions is not None else {}),
        **({"glb": glb} if glb is not None else {}),
        "loop": loop_metrics(data, params, an["reference"]),
        "amplitude": "largest CV distance |dynamic - static| (the bake's blended CVs); rms: over time",
        "energy": "per muscle, sum over its CVs of 0.5 m_cv (|v|^2 + w^2 |d|^2); d = dynamic - static, "
                  "v = dd/dt (central differences), m_cv = mass_kg / CVs, w = 2 pi frequency_hz "
                  "(params; else the measured dominant frequency)"
                  + ("; params lack masses, so m_cv = 1 / CVs: energy per kg" if energy_unit == "J/kg" else ""),
        "energy_unit": energy_unit,
        "frequency_method": "Hann-windowed FFT of every CV's offset (mean removed), power summed over xyz "
                            "and averaged over the muscle's CVs; largest peak, parabolic refinement; null "
                            f"when the muscle stays within {STILL * 1e3:g} mm, the clip has fewer than "
                            f"{MIN_FRAMES} frames or the peak is below {MIN_CYCLES} periods per clip",
        "frequency_resolution_hz": data.fps / T,
        "settle_rule": f"amplitude below {SETTLE_FRACTION:g} x its peak for {SETTLE_WINDOW:g} s (or to the "
                       "end), seconds after the peak; null: never",
        "muscles": an["muscles"],
        "limits": {**an["limits"], "hard_stop_rule": (tissue or {}).get("hard_stop_rule")},
        "video": video,
        "files": {k: os.path.basename(v) for k, v in run.files.items()},
        "timings_s": run.timings,
    }


def loop_metrics(data, params: dict, reference: np.ndarray | None = None) -> dict:
    """metrics.json's "loop": how the bake wraps when played as a cycle (sim.bake.loop.wrap_figures on the jiggle
    offset d = skin_final - reference, mm; reference (T, V, 3) metres, the skin the jiggle is measured from,
    default reference_skin(data): skin_swung with chains, else skin_static; a chain's own wrap is in "chains"):
    wrap_mm, the jump from the last frame to the first, over the median frame-to-frame step (wrap_ratio) and the
    largest (step_max_mm). A loop bake (`jiggle bake --loop`, params
    "loop" on) of a closed cycle writes one period with its last frame repeating the first: wrap_mm is then the
    seam's mismatch (0 when the steady state was reached) and wrap_step_mm, from the second-to-last frame to the
    first, the step a player looping frames 0..T-2 takes there (an ordinary one); an open cycle's frames end one
    before the first again, so its wrap_mm (= wrap_step_mm) is that ordinary step. A plain bake's wrap_mm is the
    pop it would show looped."""
    from jiggle.sim.bake.loop import wrap_figures
    lp = params.get("loop") if isinstance(params.get("loop"), dict) else {}
    on = bool(lp.get("on"))
    first = on and bool(lp.get("repeats_first", True))
    if reference is None:
        reference = reference_skin(data)[0]
    out = wrap_figures(data.skin_final, reference, repeats_first=first)
    ref = "skin_static" if reference is data.skin_static else "skin_swung"
    return {"looped": on, "kind": lp.get("kind"), "why": lp.get("why"), "repeats_first": first, **out,
            "rule": f"d = skin_final - {ref}; wrap = max over vertices |d[T-1] - d[0]|; step = max over vertices "
                    "|d[t+1] - d[t]|; where frame T-1 repeats frame 0 (repeats_first) the wrap is the seam's mismatch "
                    "and wrap_step_mm = max |d[0] - d[T-2]| the step across it, else wrap_step_mm = wrap_mm"}


def _names(out_dir: str, own: set[str]) -> dict:
    """{name of the module docstring, and COMPARE_RECORD: the name to write it under}: the name itself
    when it is free or an earlier compare's (`own`), else NAME.jiggle.EXT, NAME.jiggle2.EXT, ... the
    first of those free or own, so a file of the user's is never overwritten."""
    out, taken = {}, set()
    for name in (*COMPARE_NAMES, COMPARE_RECORD):
        stem, ext = os.path.splitext(name)
        for k in range(1, 1000):
            cand = name if k == 1 else f"{stem}.jiggle{'' if k == 2 else k - 1}{ext}"
            if cand not in taken and (cand in own or not os.path.lexists(os.path.join(out_dir, cand))):
                break
        else:
            raise InputError(f"no free name for {name}", out_dir)
        out[name] = cand
        taken.add(cand)
    return out


def _title(params: dict) -> str:
    clip, character = _label(params.get("clip")), _label(params.get("character"))
    parts = [p for p in (clip, character and f"on {character}") if p]
    return "jiggle compare" + (f": {' '.join(parts)}" if parts else "")
