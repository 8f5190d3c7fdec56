"""Fuzzing every input format jiggle reads: seeded mutations of small valid files (numbers replaced by
1e300, -1, nan, 0, a huge integer; lines deleted, duplicated or swapped; truncation; flipped bytes in a
GLB's binary chunk; changed indices in its JSON chunk) run through the CLI (`jiggle inspect FILE`) or,
for the files without a cheap command, through their reader wrapped the way the CLI wraps it (an
InputError is exit 2 with its message on one line).

Every input must end with exit 0, or exit 2 and exactly one stderr line "jiggle: error: ...", with no
traceback, within a time bound and without a jump in peak memory. The test runs a fixed seed over
800 inputs (about 20 s); benchmarks/bench_fuzz.py runs thousands and prints a table.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import random
import resource
import shutil
import signal
import struct
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))
TIME_LIMIT = 10.0           # seconds per input: a hang fails
MEMORY_JUMP_MB = 1024       # growth of the peak resident size on one input: beyond it, a failure

BAD_NUMBERS = ["1e300", "-1e300", "-1", "nan", "-nan", "inf", "-inf", "0", "-0", "1e-300", "1e-320",
               "99999999999999999999999999999", "-99999999999999999999", "2147483648", "4294967297",
               "1e9", "0x10", "1_000", "", "abc", "1e3", "12345678", "-12345678", "0.0000001"]
JSON_NUMBERS = [-1, 0, 1, 2, 3, 7, 255, 65535, 2 ** 31, 2 ** 32 + 1, 2 ** 63, 10 ** 30, -(2 ** 31),
                1e300, -1e300, 0.5, 1e-300, float("nan"), float("inf")]
JSON_ODD = [None, True, "x", [], {}, [1, 2], "0", -1, 1e300]


# ----------------------------------------------------------------------------------------- seeds

def _write_seeds(d: Path) -> dict[str, list[Path]]:
    """Small valid inputs of every format under `d`: {format: [paths]} (formats whose real asset is
    absent are left out)."""
    seeds: dict[str, list[Path]] = {}
    d.mkdir(parents=True, exist_ok=True)
    bvh = ASSETS / "mocap" / "cmu_bvh" / "02_03.bvh"
    if bvh.exists():
        lines = bvh.read_text().splitlines()
        i = next(k for k, ln in enumerate(lines) if ln.startswith("Frames:"))
        (d / "clip.bvh").write_text("\n".join(lines[:i] + ["Frames: 4", lines[i + 1]] + lines[i + 2:i + 6]) + "\n")
        seeds["bvh"] = [d / "clip.bvh"]
    asf, amc = ASSETS / "mocap" / "cmu_amc" / "01.asf", ASSETS / "mocap" / "cmu_amc" / "01_01.amc"
    if asf.exists() and amc.exists():
        shutil.copy(asf, d / "skel.asf")
        seeds["asf"] = [d / "skel.asf"]
        lines = []
        with open(amc) as fh:        # the header and three frames
            for ln in fh:
                if ln.strip() == "4":
                    break
                lines.append(ln)
        (d / "clip.amc").write_text("".join(lines))
        seeds["amc"] = [d / "clip.amc"]
    glbs = [p for p in (ASSETS / "characters" / "RiggedFigure.glb", ASSETS / "characters" / "CesiumMan.glb")
            if p.exists()]
    if glbs:
        seeds["glb"] = []
        for p in glbs:
            shutil.copy(p, d / p.name)
            seeds["glb"].append(d / p.name)
    try:
        import trimesh
        box = trimesh.creation.box()
        seeds["mesh"] = []
        for ext in ("obj", "ply", "stl"):
            box.export(d / f"box.{ext}")
            seeds["mesh"].append(d / f"box.{ext}")
        (d / "box_ascii.ply").write_bytes(trimesh.exchange.ply.export_ply(box, encoding="ascii"))
        (d / "box_ascii.stl").write_text(trimesh.exchange.stl.export_stl_ascii(box))
        seeds["mesh"] += [d / "box_ascii.ply", d / "box_ascii.stl"]
    except ImportError:     # pragma: no cover - trimesh is a dependency
        pass
    scenes = d / "scenes"
    shutil.copytree(ROOT / "scenes", scenes, ignore=shutil.ignore_patterns("__pycache__", "*.py"))
    seeds["scene"] = [scenes / "default.toml", scenes / "simple_arm.toml"]
    seeds["keyframes"] = [scenes / "motions" / "jumping_jacks.toml"]
    tdir = ROOT / "rig" / "muscle" / "templates"
    shutil.copy(tdir / "human.toml", d / "human.toml")
    shutil.copy(tdir / "human.xml", d / "human.xml")
    seeds["template"] = [d / "human.toml", d / "human.xml"]
    shutil.copy(ROOT / "rig" / "motion" / "presets" / "cmu.toml", d / "jointmap.toml")
    seeds["jointmap"] = [d / "jointmap.toml"]
    import numpy as np

    from jiggle.rig.anatomy.markers import HUMAN, write_markers
    rng = np.random.default_rng(0)
    write_markers(d / "markers.toml", [s.name for s in HUMAN], rng.normal(0, 0.3, (len(HUMAN), 3)), "fuzz")
    seeds["markers"] = [d / "markers.toml"]
    return seeds


# ------------------------------------------------------------------------------------- mutations

def _mutate_text(data: bytes, rnd: random.Random) -> bytes:
    text = data.decode("utf-8", errors="replace")
    lines = text.splitlines(keepends=True)
    op = rnd.randrange(10)
    if op <= 3:        # a number replaced (the most useful mutation: ranges, NaN, huge counts)
        import re
        spans = [m.span() for m in re.finditer(r"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", text)]
        if spans:
            for _ in range(1 + (op == 3) * rnd.randrange(4)):
                a, b = rnd.choice(spans)
                text = text[:a] + rnd.choice(BAD_NUMBERS) + text[b:]
                spans = [m.span() for m in re.finditer(r"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", text)]
                if not spans:
                    break
            return text.encode()
    if op == 4 and lines:     # a line deleted
        del lines[rnd.randrange(len(lines))]
    elif op == 5 and lines:   # a line duplicated
        k = rnd.randrange(len(lines))
        lines.insert(k, lines[k])
    elif op == 6 and len(lines) > 1:   # two lines swapped
        a, b = rnd.randrange(len(lines)), rnd.randrange(len(lines))
        lines[a], lines[b] = lines[b], lines[a]
    elif op == 7:             # truncated
        return data[:rnd.randrange(len(data) + 1)]
    elif op == 8:             # bytes flipped
        b = bytearray(data)
        for _ in range(rnd.randrange(1, 6)):
            if b:
                b[rnd.randrange(len(b))] = rnd.randrange(256)
        return bytes(b)
    else:                     # a word replaced by another word of the file, or removed
        words = text.split()
        if words:
            w = rnd.choice(words)
            text = text.replace(w, rnd.choice(words + [""]), 1)
            return text.encode()
    return "".join(lines).encode()


def _json_paths(node, path=()):
    if isinstance(node, dict):
        for k, v in node.items():
            yield path + (k,), v
            yield from _json_paths(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node[:64]):
            yield path + (i,), v
            yield from _json_paths(v, path + (i,))


def _set(doc, path, value):
    for k in path[:-1]:
        doc = doc[k]
    if value is _DELETE:
        del doc[path[-1]]
    else:
        doc[path[-1]] = value


_DELETE = object()


def _glb_chunks(data: bytes):
    """(json dict, bin bytes) of a GLB, or None when it is not one."""
    if len(data) < 20 or data[:4] != b"glTF":
        return None
    jlen = struct.unpack_from("<I", data, 12)[0]
    try:
        doc = json.loads(data[20:20 + jlen])
    except ValueError:
        return None
    rest = data[20 + jlen:]
    binary = rest[8:8 + struct.unpack_from("<I", rest, 0)[0]] if len(rest) >= 8 else b""
    return doc, binary


def _glb(doc, binary: bytes) -> bytes:
    j = json.dumps(doc, separators=(",", ":"), allow_nan=True).encode()
    j += b" " * (-len(j) % 4)
    binary += b"\0" * (-len(binary) % 4)
    out = struct.pack("<I", len(j)) + b"JSON" + j
    if binary:
        out += struct.pack("<I", len(binary)) + b"BIN\0" + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(out)) + out


def _mutate_glb(data: bytes, rnd: random.Random) -> bytes:
    parsed = _glb_chunks(data)
    op = rnd.randrange(10)
    if parsed is None or op == 0:       # raw: truncated, or header bytes changed
        b = bytearray(data)
        if rnd.random() < 0.5:
            return bytes(b[:rnd.randrange(len(b) + 1)])
        for _ in range(rnd.randrange(1, 4)):
            b[rnd.randrange(min(len(b), 32))] = rnd.randrange(256)
        return bytes(b)
    doc, binary = parsed
    if op <= 2:      # the binary chunk: bytes flipped, NaN/huge floats written, or cut short
        b = bytearray(binary)
        kind = rnd.randrange(3)
        if kind == 0:
            for _ in range(rnd.randrange(1, 64)):
                b[rnd.randrange(len(b))] = rnd.randrange(256)
        elif kind == 1:
            val = rnd.choice([float("nan"), float("inf"), 1e30, -1e30, 3e38])
            for _ in range(rnd.randrange(1, 32)):
                k = rnd.randrange(len(b) // 4) * 4
                struct.pack_into("<f", b, k, val)
        else:
            b = b[:rnd.randrange(len(b) + 1)]
        return _glb(doc, bytes(b))
    paths = list(_json_paths(doc))
    for _ in range(1 + rnd.randrange(3)):
        if not paths:
            break
        path, value = rnd.choice(paths)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            choice = rnd.random()
            new = _DELETE if choice < 0.4 else rnd.choice(JSON_ODD)
        elif rnd.random() < 0.15:
            new = _DELETE
        elif isinstance(value, int):
            new = rnd.choice(JSON_NUMBERS + [value + 1, value - 1, value * 2])
        else:
            new = rnd.choice([float("nan"), float("inf"), -value, 0.0, value * 1e30, 1e300])
        if new is _DELETE and isinstance(path[-1], int):
            new = None
        try:
            _set(doc, path, new)
        except (KeyError, IndexError, TypeError):
            pass
        paths = list(_json_paths(doc))
    return _glb(doc, binary)


def mutate(fmt: str, data: bytes, rnd: random.Random) -> bytes:
    if fmt == "glb":
        return _mutate_glb(data, rnd)
    if fmt == "mesh" and not data[:64].isascii():
        if rnd.random() < 0.5:
            return data[:rnd.randrange(len(data) + 1)]
        b = bytearray(data)
        for _ in range(rnd.randrange(1, 16)):
            k = rnd.randrange(len(b))
            if rnd.random() < 0.5 and k + 4 <= len(b):
                struct.pack_into("<f", b, k, rnd.choice([float("nan"), float("inf"), 1e30]))
            elif rnd.random() < 0.5 and k + 4 <= len(b):
                struct.pack_into("<I", b, k, rnd.choice([0xFFFFFFFF, 2 ** 31, 10 ** 9, 0]))
            else:
                b[k] = rnd.randrange(256)
        return bytes(b)
    return _mutate_text(data, rnd)


# -------------------------------------------------------------------------------------- running

class Hang(BaseException):
    """Raised by the alarm: the input took longer than the time bound."""


def _alarm(signum, frame):
    raise Hang()


def _reader_call(fmt: str, path: str):
    """The reader of a format without a cheap CLI command, called as the CLI would."""
    if fmt == "scene":
        from jiggle.sim.bake.scene import load_scene
        load_scene(path)
    elif fmt == "keyframes":
        from jiggle.rig.motion.keyframes import read_keyframes
        read_keyframes(path)
    elif fmt == "template":
        from jiggle.rig.muscle.template import read_template
        read_template(path)
    elif fmt == "jointmap":
        from jiggle.rig.motion.retarget import JointMap
        JointMap.load(path)
    elif fmt == "markers":
        from jiggle.rig.anatomy.markers import HUMAN, read_markers
        read_markers(path, [s.name for s in HUMAN])
    else:
        raise AssertionError(fmt)


def run_one(fmt: str, path: str, time_limit: float = TIME_LIMIT) -> tuple[int | None, str]:
    """Run one input: (exit code, stderr), or (None, why) when it broke a rule (traceback, other
    exception, hang, memory)."""
    from jiggle.rig.base.errors import InputError
    from jiggle.sim.app.cli import main
    err, out = io.StringIO(), io.StringIO()
    peak0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, time_limit)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            if fmt in ("bvh", "asf", "amc", "glb", "mesh"):
                code = main(["inspect", path])
            else:
                try:
                    _reader_call(fmt, path)
                    code = 0
                except InputError as e:
                    print(f"jiggle: error: {e}", file=sys.stderr)
                    code = 2
    except Hang:
        return None, f"no answer within {time_limit} s"
    except SystemExit as e:
        return None, f"SystemExit({e.code}): {err.getvalue()[-500:]}"
    except BaseException as e:    # noqa: BLE001 - anything escaping is a bug to report
        tb = "".join(traceback.format_exception(type(e), e, e.__traceback__)[-6:])
        return None, f"{type(e).__name__}: {e}\n{tb}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    grew = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak0) / 1024
    stderr = err.getvalue()
    if grew > MEMORY_JUMP_MB:
        return None, f"peak memory grew by {grew:.0f} MB"
    if "Traceback" in stderr:
        return None, f"traceback on stderr:\n{stderr[-2000:]}"
    if code == 2:
        lines = [ln for ln in stderr.splitlines() if ln.strip()]
        errs = [ln for ln in lines if ln.startswith("jiggle: error:")]
        if len(errs) != 1 or errs[0] != lines[-1] or not errs[0][len("jiggle: error:"):].strip():
            return None, f"exit 2 without exactly one 'jiggle: error:' line:\n{stderr[-2000:]}"
    elif code != 0:
        return None, f"exit {code}:\n{stderr[-2000:]}"
    return code, stderr


@dataclass
class Tally:
    inputs: int = 0
    ok: int = 0
    user_error: int = 0
    failures: list = field(default_factory=list)     # (saved path, why)
    seconds: float = 0.0


def fuzz(seed: int, counts: dict[str, int], work: Path, keep: Path | None = None,
         time_limit: float = TIME_LIMIT) -> dict[str, Tally]:
    """Mutate each format's seeds counts[fmt] times (seeded), run each input; {fmt: Tally}. Failing
    inputs are copied under `keep` (when given) for reproduction."""
    import warnings
    seeds = _write_seeds(work / "seeds")
    rnd = random.Random(seed)
    out: dict[str, Tally] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for fmt, n in counts.items():
            if fmt not in seeds:
                continue
            tally = out.setdefault(fmt, Tally())
            t0 = time.perf_counter()
            for i in range(n):
                src = seeds[fmt][i % len(seeds[fmt])]
                data = mutate(fmt, src.read_bytes(), rnd)
                if rnd.random() < 0.3:      # sometimes two mutations
                    data = mutate(fmt, data, rnd)
                dst = src.with_name(f"fuzz_{src.stem}{src.suffix}")   # beside the seed: relative paths work
                dst.write_bytes(data)
                code, why = run_one(fmt, str(dst), time_limit)
                tally.inputs += 1
                if code == 0:
                    tally.ok += 1
                elif code == 2:
                    tally.user_error += 1
                else:
                    saved = str(dst)
                    if keep is not None:
                        keep.mkdir(parents=True, exist_ok=True)
                        saved = str(keep / f"{fmt}_{seed}_{i}{src.suffix}")
                        Path(saved).write_bytes(data)
                        if fmt == "amc":
                            shutil.copy(src.with_name("skel.asf"), keep / "skel.asf")
                    tally.failures.append((saved, why))
                dst.unlink()
            tally.seconds += time.perf_counter() - t0
    return out


# The test's share: 800 inputs under a fixed seed, one test per format (~20 s in all on 2 cores).
SEED = 20260425
COUNTS = {"bvh": 100, "asf": 80, "amc": 80, "glb": 60, "mesh": 100, "scene": 80, "keyframes": 80,
          "template": 80, "jointmap": 60, "markers": 80}


@pytest.mark.parametrize("fmt", list(COUNTS))
def test_fuzz_reader(fmt, tmp_path):
    """Mutated inputs of one format: exit 0, or exit 2 with one 'jiggle: error:' line; never a
    traceback, a hang or a jump in memory (failing inputs are kept under tmp_path/failing)."""
    if not (ASSETS / "mocap").exists():
        pytest.skip(f"shared assets not found under {ASSETS}")
    # a hang is caught per input (TIME_LIMIT); the whole run's time is no assert (it doubles on a loaded machine:
    # the glb share took 39 s beside two bakes), benchmarks/bench_fuzz.py reports it
    res = fuzz(SEED + len(fmt), {fmt: COUNTS[fmt]}, tmp_path, keep=tmp_path / "failing")
    if fmt not in res:
        pytest.skip(f"no seed input for {fmt} (asset absent)")
    t = res[fmt]
    report = [f"{path}: {why}" for path, why in t.failures[:3]]
    assert not t.failures, f"{len(t.failures)} of {t.inputs} {fmt} inputs broke the rules:\n\n" + "\n\n".join(report)
    assert t.inputs == COUNTS[fmt]
    assert t.user_error > 0 and t.ok + t.user_error == t.inputs


def _replace_line(src: Path, dst: Path, old: str, new: str) -> int:
    """Copy src to dst with the first line starting with `old` (stripped) replaced by `new`; its 1-based number."""
    lines = src.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.strip().startswith(old))
    lines[k] = new
    dst.write_text("\n".join(lines) + "\n")
    return k + 1


@pytest.mark.parametrize("fmt,old,new,match", [
    ("bvh", "OFFSET", "OFFSET 0 1e9 0", "OFFSET: .* m long; expected at most 1000 m"),
    ("bvh", "Frame Time:", "Frame Time: 0", "Frame Time must be > 0"),
    ("bvh", "Frame Time:", "Frame Time: nan", "Frame Time is nan"),
    ("bvh", "Frame Time:", "Frame Time: inf", "Frame Time is inf"),
    ("bvh", "Frame Time:", "Frame Time: 1e-300", "outside the physical range"),
    ("asf", "length 0.45", "length 1e-12", "units length: .* expected at most 1000 m"),
    ("asf", "position", "position 0 0 1e9", "root position: .* expected at most 1000 m"),
    ("asf", "length 2.40479", "length 1e8", "length: .* expected at most 1000 m"),
    ("amc", "root 9.37216", "root 9e9 0 0 0 0 0", "root: frame 1 places 'root' .* expected at most 1000 m"),
    ("keyframes", "fps", "fps = 0", "fps: expected a positive number"),
    ("keyframes", "fps", "fps = 1e300", "fps: expected a positive number"),
    ("keyframes", "cycles", "cycles = 1000000000", "cycles: expected a whole number"),
])
def test_physical_ranges_refused_with_file_and_line(tmp_path, fmt, old, new, match):
    """Numbers beyond a physical range (offsets over 1 km, frame times <= 0 or non-finite, absurd rates)
    end as one error line naming the file and the line."""
    import re
    if not (ASSETS / "mocap").exists():
        pytest.skip(f"shared assets not found under {ASSETS}")
    seeds = _write_seeds(tmp_path / "seeds")
    if fmt not in seeds:
        pytest.skip(f"no seed input for {fmt}")
    src = seeds[fmt][0]
    dst = src.with_name(f"bad{src.suffix}")
    if fmt == "amc":        # the skeleton beside it is found by its name only when it is the only .asf
        line = _replace_line(src, src, old, new)
        dst = src
    else:
        line = _replace_line(src, dst, old, new)
    code, err = run_one(fmt, str(dst))
    assert code == 2, err
    msg = err.strip()
    where = f"{dst}:{line if fmt != 'amc' else line - 1}: "
    assert msg.startswith(f"jiggle: error: {where}"), (msg, where)
    assert re.search(match, msg), msg
