"""The zoo: every shared character on every cycle it loops, baked with the defaults, measured by `jiggle compare`,
in one table (issue 43, part 5).

    .venv/bin/python benchmarks/zoo.py [--out out/zoo] [--jobs 2] [--characters Horse,Frog] [--quick]

For each character under ../shared/assets/characters/ (zoo/*.glb, *.glb, fbx/*.fbx with an animation) and each
of its cycles (the animations a game loops: Walk, Run, Gallop, Idle*, Flying_Idle, Fast_Flying, Dance; a file's
only animation when none is so named), plus a CMU run (09_11) retargeted onto every biped (inspect's body plan),
or the CMU run alone for a character without animations; and the characters built for issue 61 (BUILT, written by
built_jobs from tests/gear_builds.py; --no-built leaves them out; not in the Gallery):

    jiggle bake --character FILE --animation NAME --out DIR --formats npz -q
    jiggle compare DIR --no-video -q

then reads DIR/metrics.json, DIR/bake.json and DIR/bake.npz. A bake the command refuses (exit code 2) is a row
"refused" with its one-line "jiggle: error: ..." message; any other failure is "crashed" with the last line of
its stderr. Nothing here stops the table.

Columns: peak jiggle (metrics skin.max_mm: the largest |skin_final - skin_swung| over vertices and frames, the
tissue's own: skin_swung is the skin following the swung chains, skin_static without chains) as a percentage of
the character's size (the largest extent of the rest skin's bounding box, bake.npz skin_rest, in the bake's
metres); torn edges, gradient p99.9, folds over LBS, hard stops, the percentage of muscle-frames near the reach
(metrics.json); the loop wrap (`loop_wrap`: the jump of the tissue's offset d = skin_final - skin_swung from the
last frame to the first, max over vertices, in mm and over the median frame-to-frame step of d); the chains
(bake.json "chains": how many, the smallest swing share among them, the tip's largest distance from its animated
place over the chain's length, and their penetrations into the body or the floor); the bake's and compare's wall
time. `pass` checks issue 43's targets: baked, 0 torn edges, gradient p99.9 <= 0.5, folds <= 1.1x LBS, peak <=
1.5% of the size, no chain penetration and, on each zoo character's most vigorous cycle (Run, Gallop, Fast_Flying,
else Walk), peak >= 0.3% of the size and every chain swinging >= 5% of its length.

Writes RESULTS.md and RESULTS.json (default benchmarks/results/zoo; with --quick OUT/zoo) and, unless --quick,
the Gallery page of the docs: docs/gallery.md and per character its most vigorous cycle as a video in
docs/images/gallery/ (motion_video: NAME.webm and NAME.mp4, 1056 x 400 at the cycle's rate, and the poster NAME.png).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))
CHARACTERS = ASSETS / "characters"
CMU_CLIP = ASSETS / "mocap" / "cmu_bvh" / "09_11.bvh"            # subject 9: run, 1.4 s

# Cycles: the animations a game plays in a loop, matched on the name's last "|" part (FBX takes are
# "Armature|Armature|idle"), case-insensitive; hit reactions are not cycles.
CYCLE = re.compile(r"^(walk|walking|run|running|gallop|idle(_\d+|_headlow)?|flying_idle|fast_flying|dance)$", re.I)
# The most vigorous cycle of a zoo character, first found wins: peak >= 0.3% of its size and every chain swinging
# >= 5% of its length are asked there.
VIGOROUS = ("run", "running", "gallop", "fast_flying", "walk", "walking")

# Issue 43's targets, and the chains': on the most vigorous cycle every chain swings at least chain_swing_min_pct of
# its length (a chain that hangs still reads as a rigid bone), and no chain passes into the body anywhere.
TARGETS = {"torn_edges": 0, "gradient_p999": 0.5, "folds_over_lbs": 1.1, "peak_max_pct": 1.5, "peak_min_pct": 0.3,
           "chain_swing_min_pct": 5.0, "chain_penetrations": 0}

BAKE_TIMEOUT_S = 900


@dataclass
class Job:
    """One bake: a character on a clip."""
    character: str                      # display name: the file's stem
    file: str                           # the character file
    clip: str                           # display name: the animation, or "CMU 09_11 (run)"
    animation: str | None = None        # --animation NAME (the character's own clip)
    clip_file: str | None = None        # --clip FILE (a retargeted clip)
    zoo: bool = False                   # a zoo/ character
    vigorous: bool = False              # its most vigorous cycle: peak >= 0.3% and chain swing >= 5% asked
    extra: tuple = ()                   # more bake arguments (a built character's --height)
    built: bool = False                 # a character built here (built_jobs), not a shared file

    @property
    def slug(self) -> str:
        return re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{self.character}__{self.clip}").strip("_")


@dataclass
class Row:
    character: str
    clip: str
    status: str                         # baked | refused | crashed | timeout
    message: str | None = None          # the refusal's or crash's one line
    frames: int | None = None
    vertices: int | None = None
    muscles: int | None = None
    size_m: float | None = None
    peak_mm: float | None = None
    peak_pct: float | None = None
    sustained_pct: float | None = None  # RMS over one period of the per-frame largest jiggle, % of the size
    peak_frame: int | None = None
    torn_edges: int | None = None
    gradient_p999: float | None = None
    folds_over_lbs: float | None = None  # compare's ratio; when LBS has none, the final skin's own count
    folds_final: int | None = None      # folded edges summed over the clip: the final skin's, LBS's
    folds_lbs: int | None = None
    hard_stops: int | None = None
    near_limit_pct: float | None = None
    wrap_mm: float | None = None
    wrap_ratio: float | None = None
    wrap_from: str | None = None        # "metrics" (compare's loop key) or "bake.npz"
    chains: int | None = None           # chains swung (bake.json "chains"; 0 without)
    chain_swing_min_pct: float | None = None    # the smallest swing share among them, % of the chain's length
    chain_penetrations: int | None = None       # link-frames sunk into the body or the floor, all chains
    bake_s: float | None = None
    compare_s: float | None = None
    seconds: float | None = None
    vigorous: bool = False
    zoo: bool = False
    built: bool = False
    passed: bool = False
    fails: list = field(default_factory=list)
    compare_error: str | None = None
    out: str | None = None


def jiggle_command() -> list[str]:
    """The `jiggle` of this interpreter's environment (JIGGLE_CMD overrides it: a command line)."""
    if os.environ.get("JIGGLE_CMD"):
        return os.environ["JIGGLE_CMD"].split()
    exe = Path(sys.executable).parent / "jiggle"
    return [str(exe)] if exe.exists() else [shutil.which("jiggle") or "jiggle"]


def code_version(cmd: list[str]) -> str:
    """Which jiggle was measured: JIGGLE_CODE when set (with JIGGLE_CMD, e.g. a snapshot of a commit), else this
    checkout's commit, marked when rig/, sim/ or jiggle/ have uncommitted changes."""
    if os.environ.get("JIGGLE_CODE"):
        return os.environ["JIGGLE_CODE"]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              timeout=30).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "rig", "sim", "jiggle"], cwd=ROOT,
                               capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    where = " ".join(cmd) if os.environ.get("JIGGLE_CMD") else "this checkout"
    return f"{head}{' + uncommitted changes' if dirty and not os.environ.get('JIGGLE_CMD') else ''} ({where})"


def loop_wrap(skin_final: np.ndarray, skin_static: np.ndarray) -> tuple[float, float]:
    """The pop a looping cycle shows where it wraps.

    skin_final, skin_static: (T, V, 3) float, metres. d = skin_final - skin_static, the jiggle offset (pass the
    skin following the swung chains, `swung_skin`, as skin_static to measure the tissue alone).
    Returns (wrap_mm, ratio): wrap_mm = max over vertices of |d[T-1] - d[0]| in mm; ratio = wrap_mm over the median
    over t of max over vertices |d[t+1] - d[t]| (mm), the clip's typical frame-to-frame step (inf when that is 0
    and the wrap is not, 0 when both are). Fewer than 2 frames: (0, 0).
    """
    d = np.asarray(skin_final, np.float64) - np.asarray(skin_static, np.float64)
    if d.shape[0] < 2:
        return 0.0, 0.0
    wrap = float(np.linalg.norm(d[-1] - d[0], axis=-1).max()) * 1e3
    steps = np.linalg.norm(np.diff(d, axis=0), axis=-1).max(axis=1) * 1e3        # (T-1,) mm
    step = float(np.median(steps))
    if step == 0.0:
        return wrap, (0.0 if wrap == 0.0 else math.inf)
    return wrap, wrap / step


def swung_skin(z) -> np.ndarray:
    """(T, V, 3) float32 metres: an open bake.npz's skin following its swung chains without tissue jiggle,
    skin_static + chain_delta on chain_vertices (sim.bake.caches.BakeData.skin_swung); skin_static without chains."""
    static = z["skin_static"]
    if "chain_vertices" not in z.files or not len(z["chain_vertices"]):
        return static
    out = np.array(static)
    out[:, z["chain_vertices"]] += z["chain_delta"]
    return out


def chain_figures(row: "Row", summary: dict | None) -> None:
    """The row's chain columns from bake.json (`summary`, the whole file): the count of chains (0 without a
    "chains" section), the smallest swing_share among them in %, and their penetrations summed."""
    chains = (summary or {}).get("chains")
    per = [c for c in (chains.get("chains") or []) if isinstance(c, dict)] if isinstance(chains, dict) else []
    row.chains = len(per)
    shares = [c["swing_share"] for c in per if isinstance(c.get("swing_share"), (int, float))]
    row.chain_swing_min_pct = 100 * min(shares) if shares else None
    pens = [c["penetrations"] for c in per if isinstance(c.get("penetrations"), int)]
    row.chain_penetrations = sum(pens) if per else None


def inspect(path: Path, cmd: list[str]) -> dict:
    # no -q: `inspect --json -q` prints nothing
    p = subprocess.run(cmd + ["inspect", "--json", str(path)], capture_output=True, text=True, timeout=300)
    try:
        return json.loads(p.stdout)
    except ValueError:
        return {"kind": "error", "error": last_line(p.stderr) or f"inspect: exit code {p.returncode}"}


def character_files() -> list[tuple[Path, bool]]:
    """(file, is_zoo) for every shared character file, zoo first."""
    out = [(p, True) for p in sorted((CHARACTERS / "zoo").glob("*.glb"))]
    out += [(p, False) for p in sorted(CHARACTERS.glob("*.glb"))]
    out += [(p, False) for p in sorted((CHARACTERS / "fbx").glob("*.fbx"))]
    return out


def cycles_of(animations: list[str]) -> list[str]:
    """The looping cycles among a file's animations: by name, one per last "|" part (the first in sorted
    order: FBX's shape-key actions "Key|Armature|idle" come after "Armature|Armature|idle"), or its only one."""
    seen, out = set(), []
    for name in sorted(animations):
        short = name.split("|")[-1].lower()
        if CYCLE.match(short) and short not in seen:
            seen.add(short)
            out.append(name)
    if not out and len(animations) == 1:
        out = list(animations)
    order = {"run": 0, "running": 0, "gallop": 0, "fast_flying": 0, "walk": 1, "walking": 1}
    return sorted(out, key=lambda n: (order.get(n.split("|")[-1].lower(), 2), n))


def plan(characters: set[str] | None, quick: bool, cmd: list[str]) -> tuple[list[Job], list[dict]]:
    """The bakes to run, and the files left out with why."""
    jobs, skipped = [], []
    for path, zoo in character_files():
        if characters and path.stem.lower() not in characters:
            continue
        info = inspect(path, cmd)
        if info.get("kind") != "character":
            skipped.append({"file": str(path.relative_to(CHARACTERS)), "why": info.get("error") or
                            f"not a character ({info.get('kind')}: no mesh)"})
            continue
        names = [a["name"] for a in info.get("animations", [])]
        cyc = cycles_of(names)
        vig = next((n for v in VIGOROUS for n in cyc if n.split("|")[-1].lower() == v), None) if zoo else None
        mine = [Job(path.stem, str(path), n.split("|")[-1], animation=n, zoo=zoo, vigorous=(n == vig)) for n in cyc]
        biped = (info.get("body_plan") or {}).get("kind") == "biped"
        if (biped or not names) and CMU_CLIP.is_file():
            mine.append(Job(path.stem, str(path), "CMU 09_11 (run)", clip_file=str(CMU_CLIP), zoo=zoo))
        if quick:
            mine = mine[:1]
        jobs += mine
    return jobs, skipped


BUILT = ("BirdBlob", "MushroomBlob", "Soldier", "SoldierTiny", "CesiumManStylised")
"""The characters built for issue 61 (tests/gear_builds.py), baked beside the shared ones: the wild characters the
shared zoo lacks (a soft body over a chain of head joints, a creature whose calm cycle swings harder than its vigorous
one, a Mixamo soldier in gear at real size and in a file a hundred times too small, a rig bound bone by bone)."""
BUILT_CLIP = ASSETS / "mocap" / "cmu_bvh" / "02_03.bvh"


def built_jobs(folder: Path, characters: set[str] | None) -> list[Job]:
    """The BUILT characters written into `folder` as glb files, and their bakes (all when `characters` is None, else
    those named, lower case): the blobs on their own cycles (creatures: their most vigorous cycle asked to jiggle
    visibly), the soldiers on their own CMU 02_03 (the tiny one with its real height), the bone-by-bone CesiumMan
    on CMU 02_03 retargeted."""
    want = [n for n in BUILT if characters is None or n.lower() in characters]
    if not want or not BUILT_CLIP.is_file():
        return []
    sys.path.insert(0, str(ROOT / "tests"))
    import warnings

    from gear_builds import abrupt, bird_blob, mixamo_named, mushroom_blob, soldier

    from jiggle.rig.character.gltf_write import write_character
    from jiggle.rig.character.load import body_character, load_character
    from jiggle.rig.motion.mocap import load_clip
    folder.mkdir(parents=True, exist_ok=True)
    jobs = []
    if "BirdBlob" in want:
        character, walk = bird_blob()
        write_character(character, folder / "BirdBlob.glb", animations={"Walk": walk})
        jobs.append(Job("BirdBlob", str(folder / "BirdBlob.glb"), "Walk", animation="Walk", zoo=True, vigorous=True,
                        built=True))
    if "MushroomBlob" in want:
        character, clips = mushroom_blob(walk_frames=60, walk=(0.5, 0.1, 0.6, 0.1), run=(0.1, 0.04, 0.05, 0.0))
        write_character(character, folder / "MushroomBlob.glb", animations=clips)
        jobs += [Job("MushroomBlob", str(folder / "MushroomBlob.glb"), n, animation=n, zoo=True, vigorous=n == "Run",
                     built=True) for n in ("Run", "Walk")]
    if {"Soldier", "SoldierTiny"} & set(want):
        clip = mixamo_named(load_clip(str(BUILT_CLIP)))
        man = soldier(abrupt(body_character(clip), list(clip.joint_names)))
        height = float(np.ptp(np.asarray(man.vertices)[:, 2]))
        for name, k in (("Soldier", 1.0), ("SoldierTiny", 0.01)):
            if name in want:
                write_character(man.scaled(k), folder / f"{name}.glb", animations={"walk": clip.scaled(k)})
                jobs.append(Job(name, str(folder / f"{name}.glb"), "walk (CMU 02_03)", animation="walk", built=True,
                                extra=("--height", f"{height:.4f}") if k != 1.0 else ()))
    cesium = CHARACTERS / "CesiumMan.glb"
    if "CesiumManStylised" in want and cesium.is_file():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ch = load_character(str(cesium))
        write_character(abrupt(ch, list(ch.joint_names)), folder / "CesiumManStylised.glb", source=str(cesium),
                        animations={"walk": load_clip(str(cesium))})
        jobs.append(Job("CesiumManStylised", str(folder / "CesiumManStylised.glb"), "CMU 02_03 (run)",
                        clip_file=str(BUILT_CLIP), built=True))
    return jobs


def last_line(text: str, prefix: str | None = None) -> str:
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    if prefix:
        hits = [ln for ln in lines if ln.startswith(prefix)]
        if hits:
            return hits[-1]
    return lines[-1] if lines else ""


def short_paths(text: str) -> str:
    """Asset paths in a message, relative to the assets folder (the table is read on other machines)."""
    for root in {str(ASSETS), str(ASSETS.resolve()), os.path.relpath(ASSETS)}:
        text = text.replace(root.rstrip("/") + "/", "")
    return text


def run_job(job: Job, out_root: Path, cmd: list[str], frames: int | None, activation: str | None = None) -> Row:
    out = out_root / job.slug
    if out.exists():
        shutil.rmtree(out)
    row = Row(job.character, job.clip, "baked", vigorous=job.vigorous, zoo=job.zoo, built=job.built, out=str(out))
    args = cmd + ["bake", "--character", job.file, "--out", str(out), "--formats", "npz", "-q", *job.extra]
    if job.animation is not None:
        args += ["--animation", job.animation]
    if job.clip_file is not None:
        args += ["--clip", job.clip_file]
    if frames:
        args += ["--frames", str(frames)]
    if activation:
        args += ["--activation", activation]
    t = time.perf_counter()
    try:
        p = subprocess.run(args, capture_output=True, text=True, timeout=BAKE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        row.status, row.message = "timeout", f"the bake ran past {BAKE_TIMEOUT_S} s"
        row.bake_s = row.seconds = round(time.perf_counter() - t, 1)
        return row
    row.bake_s = round(time.perf_counter() - t, 1)
    if p.returncode != 0:
        row.status = "refused" if p.returncode == 2 else "crashed"
        row.message = short_paths(last_line(p.stderr, "jiggle: error:") or f"exit code {p.returncode}")
        row.seconds = row.bake_s
        row.fails = [row.status]
        return row
    t = time.perf_counter()
    c = subprocess.run(cmd + ["compare", str(out), "--no-video", "-q"], capture_output=True, text=True,
                       timeout=BAKE_TIMEOUT_S)
    row.compare_s = round(time.perf_counter() - t, 1)
    row.seconds = round(row.bake_s + row.compare_s, 1)
    if c.returncode != 0:
        row.compare_error = last_line(c.stderr, "jiggle: error:") or f"exit code {c.returncode}"
    measure(row, out)
    judge(row)
    return row


def measure(row: Row, out: Path) -> None:
    """Fill the row's figures from the bake's files and the compare's metrics.json (when it ran)."""
    try:
        summary = json.loads((out / "bake.json").read_text())
    except (OSError, ValueError):
        summary = None
    chain_figures(row, summary)
    with np.load(out / "bake.npz") as z:
        rest = z["skin_rest"] if "skin_rest" in z.files else z["skin_static"][0]
        final, static = z["skin_final"], swung_skin(z)            # the tissue's jiggle, not the chains' swing
        row.frames, row.vertices = int(final.shape[0]), int(final.shape[1])
        row.size_m = float((rest.max(axis=0) - rest.min(axis=0)).max())
        row.muscles = int(len(z["muscle_names"])) if "muscle_names" in z.files else None
        wrap, ratio = loop_wrap(final, static)
        diff = np.linalg.norm(final.astype(np.float64) - static, axis=-1)
        if row.peak_mm is None:
            row.peak_mm = float(diff.max()) * 1e3
        loop = (summary or {}).get("loop") or {}
        row.sustained_pct = sustained(diff, bool(loop.get("on") and loop.get("repeats_first")), row.size_m)
    row.wrap_mm, row.wrap_ratio, row.wrap_from = wrap, ratio, "bake.npz"
    mpath = out / "metrics.json"
    if not mpath.is_file():
        row.peak_pct = 100 * row.peak_mm / 1e3 / row.size_m if row.size_m else None
        return
    m = json.loads(mpath.read_text())
    g = lambda d, *keys: _get(d, keys)                                   # noqa: E731
    row.peak_mm = g(m, "skin", "max_mm")
    row.peak_frame = g(m, "skin", "max_frame")
    row.torn_edges = g(m, "skin_quality", "worst", "jiggle", "torn_edges_max")
    row.gradient_p999 = g(m, "skin_quality", "worst", "jiggle", "gradient_p999_max")
    folds = g(m, "skin_quality", "targets", "folds_added_over_lbs")
    row.folds_over_lbs = folds.get("value") if isinstance(folds, dict) else None
    for attr, skin in (("folds_final", "final"), ("folds_lbs", "lbs")):
        mean = g(m, "skin_quality", "worst", skin, "folded_edges_mean")
        setattr(row, attr, None if mean is None or row.frames is None else int(round(mean * row.frames)))
    row.hard_stops = g(m, "limits", "hard_stops_total")
    near = g(m, "limits", "near_limit_fraction_all")
    row.near_limit_pct = None if near is None else 100 * near
    loop = m.get("loop")                                                  # compare's own, when it has one
    if isinstance(loop, dict) and loop.get("wrap_mm") is not None:
        row.wrap_mm, row.wrap_ratio, row.wrap_from = loop["wrap_mm"], loop.get("wrap_ratio"), "metrics"
    if row.peak_mm is not None and row.size_m:
        row.peak_pct = 100 * row.peak_mm / 1e3 / row.size_m


def sustained(diff: np.ndarray, repeats_first: bool, size_m: float | None) -> float | None:
    """% of size_m (metres): the RMS over the frames of the largest jiggle per frame, diff (T, V) metres, over one
    period (a loop whose last frame repeats the first counts it once). Where the peak is one moment, this is how
    hard the cycle keeps the tissue moving: a cycle that is still but for one stroke (a horse pawing once in its
    Idle_2) rings once as high as a walk does at every step, and sustains a fraction of it."""
    per_frame = np.asarray(diff, np.float64).max(axis=1) if np.size(diff) else np.zeros(0)
    if repeats_first and len(per_frame) > 2:
        per_frame = per_frame[:-1]
    if not len(per_frame) or not size_m:
        return None
    return 100.0 * float(np.sqrt(np.mean(per_frame ** 2))) / size_m


IDLE = re.compile(r"idle", re.IGNORECASE)


def idle_order(rows: list[Row]) -> list[dict]:
    """Per zoo character with an Idle cycle and another cycle of its own (mocap clips left out): its Idle (the
    shortest idle-named cycle: Idle before Idle_2, Flying_Idle for a flyer) against every other cycle it has (its
    idle variants too), by peak and by sustained jiggle (% of size): issue 49's order. And its idle variants (Idle_2,
    Idle_Headlow: an idle with a stroke in it) against its cycles that are not idles, both ways: a variant's one paw
    can peak above a calm walk while sustaining far below it."""
    out = []
    for name in dict.fromkeys(r.character for r in rows):
        own = [r for r in rows if r.character == name and r.status == "baked" and not r.clip.startswith("CMU")]
        idles = sorted((r for r in own if IDLE.search(r.clip)), key=lambda r: (len(r.clip), r.clip))
        if not idles or len(own) < 2:
            continue
        the, variants = idles[0], idles[1:]
        moving = [r for r in own if not IDLE.search(r.clip)]
        rec = {"character": name, "idle": the.clip}

        def against(a_rows, b_rows, k):
            hi = max(a_rows, key=lambda r: getattr(r, k) or 0.0)
            lo = min(b_rows, key=lambda r: getattr(r, k) or math.inf)
            a, b = getattr(hi, k), getattr(lo, k)
            return {"idle": hi.clip, "idle_pct": a, "other": lo.clip, "other_pct": b,
                    "below": a is not None and b is not None and a < b}
        others = [r for r in own if r is not the]
        for k in ("peak_pct", "sustained_pct"):
            rec[k] = against([the], others, k)
            if variants and moving:
                rec[f"variants_{k}"] = against(variants, moving, k)
        out.append(rec)
    return out


def idle_lines(order: list[dict]) -> list[str]:
    def cell(d):
        return f"{d['idle']} {fmt(d['idle_pct'], 3)}% | {d['other']} {fmt(d['other_pct'], 3)}% | " \
               f"{'yes' if d['below'] else '**no**'}"
    lines = ["## Idle below every other cycle", "",
             "Per character, its Idle (the shortest idle-named cycle) against the lowest of every other cycle it has, "
             "its idle variants included (one tissue per character: the jiggle follows how vigorous the motion is). "
             "**peak**: the table's; **sustained**: the RMS over one period of the largest jiggle per frame.", "",
             "| character | Idle: peak | lowest other: peak | below | Idle: sustained | lowest other: sustained | below |",
             "|---|---|---|---|---|---|---|"]
    for o in order:
        lines.append(f"| {o['character']} | {cell(o['peak_pct'])} | {cell(o['sustained_pct'])} |")
    var = [o for o in order if "variants_peak_pct" in o]
    if var:
        lines += ["", "Idle variants (an idle with a stroke in it: a paw, a head toss) against the cycles that are not "
                  "idles:", "",
                  "| character | highest variant: peak | lowest moving: peak | below | highest variant: sustained | "
                  "lowest moving: sustained | below |", "|---|---|---|---|---|---|---|"]
        for o in var:
            lines.append(f"| {o['character']} | {cell(o['variants_peak_pct'])} | {cell(o['variants_sustained_pct'])} |")
    return lines + [""]


def _get(d, keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def judge(row: Row) -> None:
    f = []
    if row.compare_error:
        f.append("compare failed")
    if row.torn_edges is None or row.torn_edges > TARGETS["torn_edges"]:
        f.append(f"torn {row.torn_edges}")
    if row.gradient_p999 is None or not row.gradient_p999 <= TARGETS["gradient_p999"]:
        f.append(f"gradient {fmt(row.gradient_p999, 2)}")
    if row.folds_over_lbs is not None and not row.folds_over_lbs <= TARGETS["folds_over_lbs"]:
        f.append(f"folds {folds_text(row)}")
    if row.peak_pct is None or not math.isfinite(row.peak_pct) or row.peak_pct > TARGETS["peak_max_pct"]:
        f.append(f"peak {fmt(row.peak_pct, 2)}% > {TARGETS['peak_max_pct']}%")
    elif row.vigorous and row.peak_pct < TARGETS["peak_min_pct"]:
        f.append(f"peak {fmt(row.peak_pct, 2)}% < {TARGETS['peak_min_pct']}% on its most vigorous cycle")
    if row.chain_penetrations is not None and row.chain_penetrations > TARGETS["chain_penetrations"]:
        f.append(f"chain penetrations {row.chain_penetrations}")
    if (row.vigorous and row.chains and (row.chain_swing_min_pct is None
                                         or not row.chain_swing_min_pct >= TARGETS["chain_swing_min_pct"])):
        f.append(f"chain swing {fmt(row.chain_swing_min_pct, 1)}% < {TARGETS['chain_swing_min_pct']:g}% "
                 "on its most vigorous cycle")
    row.fails, row.passed = f, not f


def folds_text(r: Row) -> str:
    """The folds column: compare's ratio, or "N (LBS 0)" when LBS folds nothing (the ratio is then a count)."""
    if r.folds_lbs == 0:
        return f"{fmt(r.folds_final)} (LBS 0)"
    return f"{fmt(r.folds_over_lbs, 2)}x"


def fmt(v, nd=1) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.{nd}f}"
    return str(v)


HEAD = ["character", "clip", "bake", "peak (% size)", "sustained (% size)", "peak mm / size m", "torn edges", "gradient p99.9",
        "folds / LBS", "hard stops", "near reach (%)", "loop wrap mm (x step)", "chains", "chain swing min (%)",
        "chain pen.", "s", "pass"]


def md_row(r: Row, picture: str | None = None) -> str:
    name = r.character + (" *" if r.vigorous else "")
    if r.status != "baked":
        msg = (r.message or "").replace("|", "\\|")
        msg = msg if len(msg) <= 220 else msg[:217] + "..."
        cells = [name, r.clip, f"**{r.status}**: {msg}"] + ["-"] * (len(HEAD) - 5) + [fmt(r.seconds), "fail"]
    else:
        wrap = "-" if r.wrap_mm is None else f"{r.wrap_mm:.1f} ({fmt(r.wrap_ratio, 1)}x)"
        cells = [name, r.clip, "baked", fmt(r.peak_pct, 2), fmt(r.sustained_pct, 3),
                 f"{fmt(r.peak_mm, 1)} / {fmt(r.size_m, 2)}",
                 fmt(r.torn_edges), fmt(r.gradient_p999, 2), folds_text(r), fmt(r.hard_stops),
                 fmt(r.near_limit_pct, 1), wrap, fmt(r.chains), fmt(r.chain_swing_min_pct, 1),
                 fmt(r.chain_penetrations), fmt(r.seconds),
                 "pass" if r.passed else "fail: " + "; ".join(r.fails)]
    return "| " + " | ".join(str(c) for c in cells) + " |"


def table(rows: list[Row]) -> list[str]:
    return ["| " + " | ".join(HEAD) + " |", "|" + " --- |" * len(HEAD)] + [md_row(r) for r in rows]


def summary(rows: list[Row]) -> str:
    n = sum(r.passed for r in rows)
    counts = {s: sum(r.status == s for r in rows) for s in ("baked", "refused", "crashed", "timeout")}
    extra = ", ".join(f"{v} {k}" for k, v in counts.items() if v)
    return f"{n} of {len(rows)} bakes pass ({extra})"


LEGEND = """\
Columns: **peak** is the tissue's largest |skin_final - skin_swung| over vertices and frames (compare's `skin.max_mm`;
skin_swung follows the swung chains, so a tail's swing is not jiggle), as a percentage of the character's size (the largest extent of its rest skin's bounding box, in the bake's metres);
**sustained** the RMS over one period of the largest |skin_final - skin_swung| per frame, as a percentage of the size;
**torn edges** the most edges the jiggle stretches or squeezes past their length in one frame; **gradient
p99.9** the worst frame's 99.9th percentile of the jiggle's displacement gradient; **folds / LBS** the final
skin's folded edges summed over the clip over LBS's (where LBS folds none: the final skin's count, "N (LBS 0)"); **hard stops** substeps where tissue stopped dead at its
reach; **near reach** the percentage of muscle-frames with a CV at >= 0.9 x its reach; **loop wrap** the jump of
the tissue's offset (final - swung) from the last frame to the first, max over vertices, and that over the
median frame-to-frame step; **chains** the chains swung (tails, ears, wing fingers), **chain swing min** the
smallest among them of the tip's largest distance from its animated place over the chain's length, **chain pen.**
link-frames sunk into the body or the floor (bake.json "chains"); **s** the bake's and the compare's wall time.
* marks a zoo character's most vigorous cycle, where the peak must also reach 0.3% of the size and every chain
swing at least 5% of its length. **pass**: issue 43's targets (baked, 0 torn edges, gradient p99.9 <= 0.5, folds
<= 1.1x LBS, peak <= 1.5% of the size) and no chain penetration.
"""


def write_results(stem: Path, rows: list[Row], skipped: list[dict], meta: dict) -> None:
    stem.parent.mkdir(parents=True, exist_ok=True)
    lines = ["# The zoo: every shared character, every cycle", "",
             f"`{meta['command']}` on {meta['machine']}: {meta['bakes']} bakes in {meta['wall_s']:.0f} s "
             f"(jobs {meta['jobs']}), jiggle {meta['code']}. {summary(rows)}.", "", *table(rows), "", LEGEND, "",
             *idle_lines(idle_order(rows))]
    if skipped:
        lines += ["Left out: " + "; ".join(f"{s['file']} ({s['why']})" for s in skipped) + ".", ""]
    stem.with_suffix(".md").write_text("\n".join(lines))
    stem.with_suffix(".json").write_text(json.dumps({"meta": meta, "targets": TARGETS, "skipped": skipped,
                                                     "rows": [clean(asdict(r)) for r in rows],
                                                     "idle_order": idle_order(rows)}, indent=1))


def clean(d: dict) -> dict:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


VIDEO_PANEL, VIDEO_RATE, VIDEO_FRAMES = (528, 400), (24.0, 30.0), 150
"""A gallery animation: two panels of this size in pixels (swung | final: 1056 x 400, twice the GIFs it replaced in
both directions), played at the cycle's own rate (every frame of a bake at 24-30 fps; every k-th of a faster one,
and a slower one's frames with linear in-betweens, so the rate lands in that band), at most this many frames (a
longer clip is cut to its first)."""
VIDEO_CODECS = (("webm", "libvpx-vp9", ["-crf", "36", "-b:v", "0", "-row-mt", "1", "-deadline", "good"]),
                ("mp4", "libx264", ["-crf", "27", "-preset", "slow", "-movflags", "+faststart"]))
"""The files each animation is written as: VP9 in WebM (what Chromium and Firefox play first, a third of the size)
and H.264 in MP4 (Safari's), both silent and looping in the page."""
HEAT = ["#c9b79c", "#e0894a", "#c0262b", "#5c0a3a"]
"""The final skin's colours, from the skin's own (not moved) to dark red (the most the tissue moved)."""


def motion_video(bake_dir: Path, stem: Path) -> dict | None:
    """The gallery's animation of a bake (bake.npz, bake.json): the skin with its chains swung (left: the static
    muscles, the chains as they swing) beside the final skin (right), the final one coloured by how far the tissue
    moved it (its distance from the left one, so the chains, swung on both, are not counted), at the cycle's own
    rate, looping as the cycle loops (a closed cycle's last frame, the first again, is left out so the wrap is one
    ordinary step). Seen across the body's long horizontal axis, following the body. Writes stem.webm, stem.mp4 and
    stem.png (the poster: the frame the tissue moved most). Returns {"frames", "fps", "peak_mm", "size", "poster"}
    or None when the bake has no frames."""
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")     # headless, as compare renders
    import imageio.v2 as iio
    import pyvista as pv
    from matplotlib.colors import LinearSegmentedColormap

    from jiggle.sim.bake.caches import read_npz
    data = read_npz(str(bake_dir / "bake.npz"))
    swung, final, faces, fps = data.skin_swung(), data.skin_final, data.faces, float(data.fps)
    summary = json.loads((bake_dir / "bake.json").read_text()) if (bake_dir / "bake.json").is_file() else {}
    loop = summary.get("loop") or {}
    T = len(swung) - (1 if loop.get("on") and loop.get("repeats_first") and len(swung) > 2 else 0)
    if T < 1:
        return None
    step = max(1, math.ceil(fps / VIDEO_RATE[1] - 1e-9))
    up = max(1, math.ceil(VIDEO_RATE[0] * step / fps - 1e-9))   # a slower clip (a 15 fps game cycle): in-betweens
    picks = list(range(0, T, step))[:VIDEO_FRAMES]
    rate = fps * up / step
    if up > 1:      # each frame and its next (the first after the last: the cycle loops) blended linearly
        nxt = picks[1:] + picks[:1]
        u = np.arange(up) / up
        swung = np.concatenate([(1 - w) * swung[a] + w * swung[b] for a, b in zip(picks, nxt) for w in u]
                               ).reshape(-1, *swung.shape[1:])
        final = np.concatenate([(1 - w) * final[a] + w * final[b] for a, b in zip(picks, nxt) for w in u]
                               ).reshape(-1, *final.shape[1:])
        picks = list(range(len(swung)))
    cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
    size = float(np.ptp(swung[0], axis=0).max())
    flat = swung[0][:, :2] - swung[0][:, :2].mean(0)
    long_axis = np.linalg.eigh(flat.T @ flat)[1][:, -1]
    side = np.array([-long_axis[1], long_axis[0], 0.0])
    moved = np.linalg.norm(final - swung, axis=2)
    top = max(float(np.percentile(moved[picks], 99.5)), 1e-6)
    heat = LinearSegmentedColormap.from_list("moved", HEAT)
    W, H = VIDEO_PANEL
    frames = []
    for k in picks:
        pl = pv.Plotter(off_screen=True, shape=(1, 2), window_size=(2 * W, H), border=False)
        c = 0.5 * (swung[k].min(0) + swung[k].max(0))           # the box's centre: a dense head does not lift it
        # far enough that a tail or wing swung past the rest skin's extent stays in the panel (30 degree view)
        cam = [tuple(c - 2.1 * size * side + [0, 0, 0.15 * size]), tuple(c), (0, 0, 1)]
        pl.subplot(0, 0)
        pl.add_mesh(pv.PolyData(swung[k], cells), color=HEAT[0], smooth_shading=True)
        pl.add_text("static muscles, chains swung", font_size=9, color="#444444", position="upper_left")
        pl.camera_position = cam
        pl.subplot(0, 1)
        mesh = pv.PolyData(final[k], cells)
        mesh.point_data["moved"] = moved[k]
        pl.add_mesh(mesh, scalars="moved", cmap=heat, clim=(0.0, top), show_scalar_bar=False, smooth_shading=True)
        pl.add_text(f"final: red = the tissue moved, up to {1e3 * top:.0f} mm", font_size=9, color="#444444",
                    position="upper_left")
        pl.camera_position = cam
        frames.append(np.asarray(pl.screenshot(return_img=True))[..., :3])
        pl.close()
    for ext, codec, params in VIDEO_CODECS:
        path = stem.with_suffix("." + ext)
        tmp = path.with_name(path.stem + ".partial." + ext)             # never a half-written video looking whole
        with iio.get_writer(str(tmp), fps=rate, codec=codec, pixelformat="yuv420p", macro_block_size=8,
                            ffmpeg_params=params, ffmpeg_log_level="error") as w:
            for f in frames:
                w.append_data(f)
        os.replace(tmp, path)
    peak = int(np.argmax(moved[picks].max(axis=1)))
    iio.imwrite(str(stem.with_suffix(".png")), frames[peak])
    return {"frames": len(frames), "fps": round(rate, 3), "peak_mm": round(1e3 * top, 1), "size": [2 * W, H],
            "poster": picks[peak]}


GALLERY_COLUMNS = (("character", "clip", "peak (% size)", "torn edges", "gradient p99.9", "folds / LBS", "chains",
                    "chain swing min (%)", "pass"),
                   ("character", "clip", "peak mm / size m", "hard stops", "near reach (%)", "loop wrap mm (x step)",
                    "chain pen.", "s"))
"""The gallery's two narrower tables (columns of HEAD): each fits the docs' width."""


def narrow_tables(rows: list[Row]) -> list[str]:
    out = []
    full = [md_row(r) for r in rows]
    for cols in GALLERY_COLUMNS:
        idx = [HEAD.index(c) for c in cols]
        out += ["| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols)]
        for line in full:
            cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
            out.append("| " + " | ".join(cells[i] if i < len(cells) else "-" for i in idx) + " |")
        out.append("")
    return out


def write_gallery(docs: Path, rows: list[Row], meta: dict) -> None:
    """docs/gallery.md and docs/images/gallery/<character>.webm, .mp4 and .png: a column in which each character
    plays its most vigorous cycle (motion_video: swung | final, at the cycle's rate, its poster the frame the tissue
    moved most), then the numbers in two tables that fit the page."""
    img_dir = docs / "images" / "gallery"
    img_dir.mkdir(parents=True, exist_ok=True)
    for old in list(img_dir.glob("*.gif")) + list(img_dir.glob("*.png")) + list(img_dir.glob("*.webm")) + \
            list(img_dir.glob("*.mp4")):
        old.unlink()                            # the animations and stills of earlier runs
    rows = [r for r in rows if not r.built]     # the shared characters' page; the built ones are in the results
    shown = {}
    for name in dict.fromkeys(r.character for r in rows):
        mine = [r for r in rows if r.character == name and r.out and (Path(r.out) / "bake.npz").is_file()]
        # its most vigorous cycle, else the clip it jiggles most on (a game character's own, on ties)
        mine.sort(key=lambda r: (not r.vigorous, -(r.peak_pct or 0.0), r.clip.startswith("CMU")))
        if not mine:
            continue
        info = motion_video(Path(mine[0].out), img_dir / name)
        if info is not None:
            shown[name] = (mine[0], info)
    lines = ["# Gallery", "",
             "Every character of the shared test assets (`../shared/assets/characters/`: the zoo of CC0 game "
             "characters, CesiumMan, RiggedFigure, RobotExpressive and the FBX files) baked with the defaults by "
             "`benchmarks/zoo.py`, each playing its most vigorous cycle at its own rate, looping as the cycle loops. "
             "Left: the skin over the static muscles, its [chains](tutorials/chains.md) (tails, ears, wing fingers) "
             "swung; right: the final skin, coloured by how far the tissue (muscles and fat) moved it from the left "
             "one. The still before it plays is the frame the tissue moved most.", ""]
    for name, (r, info) in shown.items():
        chains = f", {r.chains} chain{'s' * (r.chains != 1)}" if r.chains else ""
        w, h = info["size"]
        # raw HTML: its paths are the page's own (gallery/index.html), one folder below the site's root
        lines += ['<figure markdown style="margin:0 0 1rem 0">', "",
                  f'<video autoplay loop muted playsinline preload="metadata" width="{w}" height="{h}" '
                  f'style="width:100%;height:auto" poster="../images/gallery/{name}.png" '
                  f'title="{name} on {r.clip}">'
                  f'<source src="../images/gallery/{name}.webm" type="video/webm">'
                  f'<source src="../images/gallery/{name}.mp4" type="video/mp4"></video>', "",
                  f"<figcaption>{name}, {r.clip}{chains}: peak {fmt(r.peak_pct, 2)}% of its size; {info['frames']} "
                  f"frames at {info['fps']:g} fps</figcaption>", "", "</figure>", ""]
    missing = sorted({r.character for r in rows} - set(shown))
    if missing:
        lines += ["No animation (no bake): " + ", ".join(missing) + ".", ""]
    lines += ["## The numbers", "",
              f"{summary(rows)}. Run: {meta['date']}, {meta['wall_s']:.0f} s on {meta['machine']}.", "",
              "```", "python benchmarks/zoo.py --jobs 2", "```", "", *narrow_tables(rows), LEGEND]
    (docs / "gallery.md").write_text("\n".join(lines))


def rows_from(results: Path) -> tuple[list[Row], dict]:
    """The rows and meta a run wrote to RESULTS.json."""
    data = json.loads(results.read_text())
    names = {f.name for f in fields(Row)}
    return [Row(**{k: v for k, v in r.items() if k in names}) for r in data["rows"]], data["meta"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/zoo", help="the bakes' folder (default: out/zoo)")
    ap.add_argument("--quick", action="store_true", help="a small subset: 2 characters, 1 cycle each, 12 frames")
    ap.add_argument("--characters", default=None, help="comma-separated file stems (Horse,Frog,CesiumMan)")
    ap.add_argument("--jobs", type=int, default=1, help="bakes in parallel processes (default: 1)")
    ap.add_argument("--frames", type=int, default=None, help="only the first N frames of each bake")
    ap.add_argument("--activation", choices=("on", "off"), default=None,
                    help="every bake's --activation (default: the bake's own default)")
    ap.add_argument("--results", default=None,
                    help="write RESULTS.md and .json (default: benchmarks/results/zoo; with --quick OUT/zoo)")
    ap.add_argument("--no-built", action="store_true",
                    help="leave out the characters built for issue 61 (BUILT: blobs, soldiers, a stylised rig)")
    ap.add_argument("--regallery", action="store_true",
                    help="only write the gallery again from the last run's RESULTS.json and its bakes in --out")
    ap.add_argument("--gallery", default=None,
                    help="a docs folder to write gallery.md and images/gallery/ into (default: docs; none with "
                         "--quick)")
    a = ap.parse_args(argv)
    if not CHARACTERS.is_dir():
        print(f"zoo: no shared characters at {CHARACTERS}", file=sys.stderr)
        return 1
    if a.regallery:
        stem = Path(a.results) if a.results else ROOT / "benchmarks" / "results" / "zoo"
        rows, meta = rows_from(stem.with_suffix(".json"))
        write_gallery(Path(a.gallery) if a.gallery else ROOT / "docs", rows, meta)
        return 0
    cmd = jiggle_command()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    chars = {c.strip().lower() for c in a.characters.split(",")} if a.characters else None
    if a.quick and not chars:
        chars = {"horse", "cesiumman"}
    frames = a.frames or (12 if a.quick else None)
    t0 = time.perf_counter()
    jobs, skipped = plan(chars, a.quick, cmd)
    if not a.quick and not a.no_built:
        jobs += built_jobs(out / "built", chars)
    print(f"zoo: {len(jobs)} bakes of {len({j.character for j in jobs})} characters, jobs {a.jobs}", flush=True)

    def one(job):
        r = run_job(job, out, cmd, frames, a.activation)
        tail = r.message if r.status != "baked" else ("pass" if r.passed else "fail: " + "; ".join(r.fails))
        print(f"  {r.character:16s} {r.clip:18s} {r.status:8s} {fmt(r.peak_pct, 2):>6s}%  {fmt(r.seconds):>6s} s"
              f"  {tail}", flush=True)
        return r

    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as ex:
        rows = list(ex.map(one, jobs))
    wall = time.perf_counter() - t0
    meta = {"command": "python benchmarks/zoo.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "machine": f"{os.cpu_count()} CPU cores", "jobs": a.jobs, "bakes": len(rows), "frames": frames,
            "wall_s": round(wall, 1), "code": code_version(cmd), "date": time.strftime("%Y-%m-%d"),
            "summary": summary(rows)}
    print("\n".join(table(rows)))
    print(summary(rows) + f"; {wall:.0f} s")
    stem = Path(a.results) if a.results else (out / "zoo" if a.quick else ROOT / "benchmarks" / "results" / "zoo")
    write_results(stem, rows, skipped, meta)
    docs = Path(a.gallery) if a.gallery else (None if a.quick else ROOT / "docs")
    if docs is not None:
        write_gallery(docs, rows, meta)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
