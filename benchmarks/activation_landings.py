"""Muscle activation from the motion's own loads on the shared jump and run: the quadriceps, hamstrings, glutes and
calves over time beside the ground's push, each group's activation after the landings against mid-flight, and the
jiggle at the landings with activation on against off.

    python benchmarks/activation_landings.py [--out benchmarks/results]

For CMU 02_04 (a jump) and 02_03 (a run), on the generated body and on CesiumMan (the clip retargeted): the joint
torques (sim.drive.inverse.joint_torques, the body's mass from its skin's volume at BODY_DENSITY and real size) and
the activations (sim.jiggle.activation.activations) at 120 Hz. A landing is a sample where the floor's push rises
through the body's weight after at least AIR_S with none; "after" is the LANDED_S that follow, "mid-flight" the
middle third of the stretch before it with no push. Then the clip baked with --activation on and off: the
quadriceps' and every fat part's peak jiggle in the LANDED_JIGGLE_S after each landing. Writes
activation_landings.md / .json and activation_landings/*.png.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ASSETS = HERE.parent.parent / "shared" / "assets"
CLIPS = {"02_04": "jump", "02_03": "run"}
CHARACTERS = {"generated": None, "CesiumMan": "characters/CesiumMan.glb"}
GROUPS = {"quadriceps": "quadriceps", "hamstrings": "hamstrings", "glute": "glute", "calf": "calf"}
RATE = 120.0
AIR_S = 0.08
LANDED_S = 0.2
LANDED_JIGGLE_S = 0.3
"""seconds after a landing whose jiggle the bakes with activation on and off are compared over."""


def fit_for(clip_path: str, character: str | None):
    """(fit, world_at, mass kg) of a bake's setup steps for the clip on the character."""
    from jiggle.sim.bake.setup import BakeRequest, _character, _drive, _fit, _inputs, _scene
    from jiggle.sim.drive.inverse import BODY_DENSITY
    req = BakeRequest(clip=clip_path, character=character)
    log = lambda s: None  # noqa: E731
    scene = _scene(req, None)
    inputs = _inputs(req, scene, None, "particles")
    fit = _fit(req, inputs, _character(req, inputs, None, None, log), None, None, log)
    v = np.asarray(fit.character.vertices, np.float64)
    f = np.asarray(fit.character.faces)
    volume = abs(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum()) / 6.0
    mass = BODY_DENSITY * volume * fit.size.scale ** 3
    times = np.arange(0.0, fit.clip.duration, 1.0 / RATE)
    return fit, _drive(fit.clip, "kinematic", times, log), mass, times


def landings(push: np.ndarray, weight: float, times: np.ndarray) -> list[tuple[int, int]]:
    """[(first sample in the air, landing sample)]: the push rises through the weight after AIR_S of none."""
    air = push <= 1e-6
    out, start = [], None
    for k in range(len(push)):
        if air[k]:
            start = k if start is None else start
        elif start is not None:
            if times[k] - times[start] >= AIR_S:
                out.append((start, k))
            start = None
    return out


def case(clip: str, character: str, out: Path) -> dict:
    from jiggle.sim.drive.inverse import joint_torques
    from jiggle.sim.jiggle.activation import activations
    path = str(ASSETS / "mocap" / "cmu_bvh" / f"{clip}.bvh")
    fit, world_at, mass, times = fit_for(path, str(ASSETS / CHARACTERS[character]) if CHARACTERS[character] else None)
    joint_torques(fit.clip.scaled(fit.size.scale), times[:3], mass, roles=fit.mus.roles)        # imports (scipy.signal) off the clock
    t0 = time.perf_counter()
    loads = joint_torques(fit.clip.scaled(fit.size.scale), times, mass, roles=fit.mus.roles)
    t1 = time.perf_counter()
    act = activations(fit.mus.rig, world_at, loads, fit.clip.parents, fit.character.bind_world, times,
                      scale=fit.size.scale, roles=fit.mus.roles)
    t2 = time.perf_counter()
    names = list(fit.mus.rig.names)
    weight = 9.81 * mass
    push = np.interp(times, loads.times, loads.ground[:, 2])
    group = {g: [i for i, n in enumerate(names) if key in n and fit.mus.rig.kinds[i] != "fat"]
             for g, key in GROUPS.items()}
    events = landings(push, weight, times)
    rows = []
    for g, idx in group.items():
        a = act.activation[:, idx].mean(axis=1)
        after = [a[(times >= times[k]) & (times < times[k] + LANDED_S)].mean() for _, k in events]
        air = [a[s + (k - s) // 3:k - (k - s) // 3].mean() for s, k in events]      # mid-flight: its middle third
        rows.append({"group": g, "after_landing": float(np.mean(after)) if after else None,
                     "in_air": float(np.mean(air)) if air else None, "peak": float(a.max()), "mean": float(a.mean())})
    plot(out / f"{clip}_{character}.png", times, push / weight, act.activation, group,
         f"CMU {clip} ({CLIPS[clip]}) on the {character} body: {len(events)} landings")
    return {"clip": clip, "character": character, "mass_kg": mass, "landings": [float(times[k]) for _, k in events],
            "groups": rows, "saturated_share": float(act.saturated.any(axis=1).mean()), "duration_s": float(times[-1]),
            "inverse_s": t1 - t0, "activation_s": t2 - t1,
            "jiggle": landing_jiggle(path, CHARACTERS[character], [float(times[k]) for _, k in events],
                                     landing_sides(loads, fit.mus.roles, [float(times[k]) for _, k in events]))}


def landing_sides(loads, roles: dict, landed: list[float]) -> list[set]:
    """Per landing (seconds `landed`), the sides ("left", "right") whose foot or toe the floor pushes then or within
    LANDED_S after (a run lands on one foot, a jump on both)."""
    out = []
    for t in landed:
        near = (loads.times >= t - 1e-9) & (loads.times <= t + LANDED_S)
        out.append({side for side in ("left", "right")
                    if loads.contact[near][:, [roles[f"{side}_foot"], roles[f"{side}_toe"]]].any()})
    return out


def landing_jiggle(clip_path: str, character: str | None, landed: list[float], sides: list[set]) -> dict:
    """The clip baked with --activation on and off (`jiggle bake`, npz): each muscle's peak jiggle (its CVs' largest
    move from their static place) over the LANDED_JIGGLE_S after each landing (seconds `landed`), on over off, for
    the quadriceps of the leg that lands (`sides`: landing_sides; a run's swinging leg is not loaded) and every fat
    part (over every landing)."""
    import tempfile

    from jiggle.sim.app.cli import main
    from jiggle.sim.bake.caches import read_npz
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        bakes = {}
        for mode in ("on", "off"):
            args = ["-q", "bake", "--clip", clip_path, "--out", f"{tmp}/{mode}", "--formats", "npz",
                    "--activation", mode]
            if character:
                args += ["--character", str(ASSETS / character)]
            assert main(args) == 0, mode
            bakes[mode] = read_npz(f"{tmp}/{mode}/bake.npz")
        kinds = json.loads(open(f"{tmp}/on/bake.json").read())["params"]["muscles"]
        on, off = bakes["on"], bakes["off"]
        o = on.muscle_cv_offsets

        def peak(d, m, side=None):
            window = np.zeros(len(d.times), bool)
            for t, landing in zip(landed, sides):
                if side is None or side in landing:
                    window |= (d.times >= t) & (d.times < t + LANDED_JIGGLE_S)
            sl = slice(o[m], o[m + 1])
            return float(np.linalg.norm(d.muscle_cvs_dynamic[window, sl] - d.muscle_cvs_static[window, sl],
                                        axis=2).max()) if window.any() else float("nan")
        for m, n in enumerate(on.muscle_names):
            side = "left" if n.startswith("left") else "right" if n.startswith("right") else None
            if "quadriceps" in n:
                out[n] = {"kind": kinds[n]["kind"], "on_mm": 1e3 * peak(on, m, side), "off_mm": 1e3 * peak(off, m, side)}
            elif kinds[n]["kind"] == "fat":
                out[n] = {"kind": "fat", "on_mm": 1e3 * peak(on, m), "off_mm": 1e3 * peak(off, m)}
    return out


def plot(path: Path, times, push, activation, group, title) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True, height_ratios=(1, 2))
    ax.plot(times, push, color="0.3")
    ax.axhline(1.0, color="0.7", lw=0.8, ls="--")
    ax.set_ylabel("floor's push\n(body weights)")
    ax.set_title(title)
    for g, idx in group.items():
        if idx:
            bx.plot(times, activation[:, idx].mean(axis=1), label=g)
    bx.set_ylabel("activation (mean of the\ngroup's muscles)")
    bx.set_xlabel("time (s)")
    bx.set_ylim(0, 1.02)
    bx.legend(loc="upper right", fontsize=8)
    for a in (ax, bx):
        a.grid(alpha=0.3)
    save_figure(fig, path, 90)


def save_figure(fig, path: Path, dpi: int) -> None:
    """A matplotlib figure laid out tight and saved to `path` (its folder made), then closed."""
    import matplotlib.pyplot as plt
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def write(results: list[dict], out: Path, seconds: float) -> None:
    lines = ["# Muscle activation at landings (benchmarks/activation_landings.py)", "",
             f"`python benchmarks/activation_landings.py`: {len(results)} cases in {seconds:.0f} s. Joint torques by "
             "inverse dynamics with the ground (sim/drive/inverse.py), activations by least-effort static "
             "optimization (sim/jiggle/activation.py), at 120 Hz. Per muscle group (both sides' mean): its mean "
             f"activation in the {LANDED_S:g} s after each landing and mid-flight before it (the middle third of the "
             "stretch with no push: the push-off's fall and the landing's pre-activation left out), and the ratio.", "",
             "| clip | body | mass kg | landings | group | after landing | mid-flight | ratio | peak |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for g in r["groups"]:
            a, b = g["after_landing"], g["in_air"]
            ratio = f"{a / b:.1f}" if a is not None and b else ("-" if a is None else "inf")
            lines.append(f"| {r['clip']} | {r['character']} | {r['mass_kg']:.0f} | {len(r['landings'])} | {g['group']} | "
                         f"{'-' if a is None else f'{a:.3f}'} | {'-' if b is None else f'{b:.3f}'} | {ratio} | "
                         f"{g['peak']:.2f} |")
    lines += ["", f"Peak jiggle in the {LANDED_JIGGLE_S:g} s after each landing, `jiggle bake` with `--activation on` "
              "over `off` (each muscle's control points' largest move from their static place): the quadriceps of "
              "the leg that lands stiffened (at most 0.8; a run's swinging leg is not loaded), every fat part as "
              "before (within 20%).", "",
              "| clip | body | part | kind | on mm | off mm | on / off |", "|---|---|---|---|---|---|---|"]
    for r in results:
        for n, j in r["jiggle"].items():
            ratio = j["on_mm"] / j["off_mm"] if j["off_mm"] > 0 else float("nan")
            ok = ratio <= 0.8 if j["kind"] != "fat" else abs(ratio - 1.0) <= 0.2
            lines.append(f"| {r['clip']} | {r['character']} | {n} | {j['kind']} | {j['on_mm']:.2f} | {j['off_mm']:.2f} "
                         f"| {ratio:.2f}{'' if ok else ' **(no)**'} |")
    lines += ["", "Cost per case (one run, this machine, beside other work; the clip's duration in brackets): " + ", ".join(
        f"{r['clip']} {r['character']} ({r['duration_s']:.1f} s): inverse dynamics {r['inverse_s']:.1f} s, "
        f"activations {r['activation_s']:.1f} s"
        for r in results) + ".", ""]
    lines += [f"![{r['clip']} {r['character']}](activation_landings/{r['clip']}_{r['character']}.png)" for r in results]
    (out / "activation_landings.md").write_text("\n".join(lines) + "\n")
    (out / "activation_landings.json").write_text(json.dumps(results, indent=1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "results"))
    args = ap.parse_args(argv)
    if not (ASSETS / "mocap" / "cmu_bvh").is_dir():
        print(f"skipped: no shared CMU clips at {ASSETS / 'mocap' / 'cmu_bvh'}")
        return 0
    out = Path(args.out)
    t = time.perf_counter()
    results = []
    for clip in CLIPS:
        for character in CHARACTERS:
            if CHARACTERS[character] and not (ASSETS / CHARACTERS[character]).is_file():
                continue
            r = case(clip, character, out / "activation_landings")
            results.append(r)
            print(clip, character, [(g["group"], g["after_landing"], g["in_air"]) for g in r["groups"]], flush=True)
    write(results, out, time.perf_counter() - t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
