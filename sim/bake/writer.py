"""A bake's caches written while it runs: each chunk goes once, straight into every cache.

    chunk c's arrays --BakeWriter.append--> OUT/.partial/.bake.npz.tmp   (caches.NpzInPlace: the layout is
                                                                          fixed up front, frames land at
                                                                          their offsets)
                                          OUT/.partial/.bake.pc2.tmp   (fixed-size frames at their offsets)
                                          OUT/.partial/.bake.tmp.usdc  (caches.UsdAppender: saved per chunk)
    all chunks -> BakeWriter.finish: the npz's central directory written, each file renamed into OUT

Memory holds one chunk whatever the clip's length (the USD crate writer drops the samples it saved;
nothing is concatenated). The npz is always written in .partial, even when the bake was not asked for
it: it is the store an interrupted bake goes on from. `progress()` (each frame member's CRC so far)
goes into the chunk's marker file with the particle state; a resumed bake reopens the npz with the
progress of its last finished chunk, overwrites whatever a killed chunk left after it, and writes the
USD again from the frames the npz holds (a crate file cannot be cut back). A cache appears under its
final name only once it is complete (a rename), so none that looks complete is ever partial.
"""
from __future__ import annotations

import contextlib
import json
import os

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.sim.bake.caches import (
    FRAME_KEYS,
    NPZ_KEYS,
    PC2_HEADER_BYTES,
    BakeData,
    NpzInPlace,
    UsdAppender,
    npz_arrays,
    pc2_header,
    require_finite,
)

NPZ_TMP, PC2_TMP = ".bake.npz.tmp", ".bake.pc2.tmp"
USD_TMP = {"usdc": ".bake.tmp.usdc", "usda": ".bake.tmp.usda"}
CHUNK_KEYS = {"skin_static": "skin_static", "skin_final": "skin_final", "skin_lbs": "skin_lbs",
              "joint_world": "joint_world", "muscle_cvs_static": "cvs_static", "muscle_cvs_dynamic": "cvs_dynamic",
              "chain_world": "chain_world", "chain_tips_static": "chain_tips_static",
              "chain_tips_final": "chain_tips_final", "chain_delta": "chain_delta", "activation": "activation"}
"""The npz's frame members (besides times) and the name of each in a chunk's arrays (sim/bake/baker.py)."""


def _cannot_write(path: str, e: OSError) -> InputError:
    return InputError(f"cannot write: {e.strerror or e}; the bake so far is kept (run again with --resume)", path)


class BakeWriter:
    """The caches of one bake (sim.bake.setup.BakeSetup), filled chunk by chunk (see the module).

    setup : the bake's setup (times, character, rig, formats, params).
    partial : the unfinished bake's folder (OUT/.partial), where the caches grow.
    progress : None to start; else the `progress()` stored with the last finished chunk and the number
        of frames those chunks hold, (dict, frames), to go on.
    smooth : whether chunks bring the smooth skin ("skin_lbs").
    """

    def __init__(self, setup, partial: str, progress: tuple[dict, int] | None = None, smooth: bool = True):
        self.setup, self.partial = setup, partial
        rig, character = setup.rig, setup.character
        T, V, J, N = len(setup.times), character.num_vertices, len(setup.joint_names), int(rig.cv_offsets[-1])
        self.T, self.frames = T, 0
        shapes = {"skin_static": (T, V, 3), "skin_final": (T, V, 3), "skin_lbs": (T, V, 3), "joint_world": (T, J, 4, 4),
                  "muscle_cvs_static": (T, N, 3), "muscle_cvs_dynamic": (T, N, 3)}
        if not smooth:
            del shapes["skin_lbs"]
        chains = {}
        if getattr(setup, "chains", None) is not None:      # the swung chains' joints and tips (sim/bake/baker.py)
            ch = setup.chains
            if ch.skin is not None:                         # made with the setup (sim.chain.build.make)
                moved, cs = list(ch.moved), ch.skin
            else:
                from jiggle.rig.skin.chain_skin import ChainSkin
                from jiggle.sim.chain.simulate import riders_of
                moved = [int(j) for j in ch.links.joints] + [j for j, _ in riders_of(ch.model, character.parents)]
                cs = ChainSkin(character, moved)
            verts = cs.vertices
            C = len(ch.chains)
            shapes.update({"chain_world": (T, len(moved), 4, 4), "chain_tips_static": (T, C, 3),
                           "chain_tips_final": (T, C, 3), "chain_delta": (T, len(verts), 3)})
            chains = {"chain_names": tuple(character.joint_names[j] for j in moved),
                      "chain_world": np.tile(np.eye(4, dtype=np.float32), (1, len(moved), 1, 1)),
                      "chain_tip_names": tuple(ch.chains.names), "chain_tips_static": np.zeros((1, C, 3), np.float32),
                      "chain_tips_final": np.zeros((1, C, 3), np.float32), "chain_vertices": verts,
                      "chain_weight": cs.weight, "chain_delta": np.zeros((1, len(verts), 3), np.float32)}
        if getattr(setup, "activation", None) is not None:   # each muscle's activation (--activation on)
            shapes["activation"] = (T, rig.M)
            chains["activation"] = np.zeros((1, rig.M), np.float32)
        self.head = BakeData(skin_static=np.zeros((1, V, 3), np.float32), skin_final=np.zeros((1, V, 3), np.float32),
                             skin_rest=np.asarray(character.vertices) * setup.scale, faces=character.faces, fps=setup.fps, times=setup.times[:1],
                             joint_names=setup.joint_names, joint_world=np.tile(np.eye(4, dtype=np.float32), (1, J, 1, 1)),
                             muscle_names=tuple(rig.names), muscle_cvs_static=np.zeros((1, N, 3), np.float32),
                             muscle_cvs_dynamic=np.zeros((1, N, 3), np.float32), muscle_cv_offsets=rig.cv_offsets,
                             muscle_faces=rig.surface_faces,
                             params=json.dumps(setup.params, sort_keys=True, allow_nan=False),
                             **skin_parts(character), **chains)
        whole = npz_arrays(self.head)
        members = {"format": whole.pop("format")}
        for name in NPZ_KEYS:
            if name in shapes:
                members[name] = (shapes[name], np.float32)
            elif name == "times":
                members[name] = np.asarray(setup.times, np.float64)
            elif name in whole and name not in FRAME_KEYS:
                members[name] = whole[name]
        self.keys = [k for k in CHUNK_KEYS if k in shapes]
        self.paths = {"npz": os.path.join(partial, NPZ_TMP)}
        crcs = None
        if progress is not None:
            crcs, self.frames = progress[0], int(progress[1])
        try:
            self.npz = NpzInPlace(self.paths["npz"], members, crcs, {k: self.frames for k in self.keys})
        except OSError as e:
            raise _cannot_write(self.paths["npz"], e) from None
        self.pc2 = None
        if "pc2" in setup.formats:
            self.paths["pc2"] = path = os.path.join(partial, PC2_TMP)
            self._frame_bytes = V * 12
            try:
                if progress is None or not os.path.isfile(path):
                    with open(path, "wb") as fh:
                        fh.write(pc2_header(V, T, setup.fps, float(setup.times[0])))
                self.pc2 = open(path, "r+b")
            except OSError as e:
                raise _cannot_write(path, e) from None
        self.usd = None
        usd = [f for f in setup.formats if f in USD_TMP]
        if usd:
            fmt = usd[0]
            self.paths[fmt] = path = os.path.join(partial, USD_TMP[usd[0]])
            with contextlib.suppress(FileNotFoundError):
                os.remove(path)             # a crate file cannot be cut back: written again from the npz
            P = rig.surface(rig.rest_cvs).shape[1]
            self.usd = UsdAppender(path, self.head, T, (T, rig.M, P, 3), fmt)
            for f0 in range(0, self.frames, setup.chunk):
                f1 = min(self.frames, f0 + setup.chunk)
                self._usd(f0, self.npz.read("skin_static", f0, f1), self.npz.read("skin_final", f0, f1),
                          self.npz.read("muscle_cvs_dynamic", f0, f1))

    def append(self, f0: int, arrays: dict) -> dict:
        """Write frames f0, f0 + 1, ... (a chunk's arrays, named as CHUNK_KEYS says) into every cache and
        return the progress to store with the chunk. Every array is checked finite first: a NaN stops
        the bake naming it and the frame, and nothing of the chunk is written."""
        if f0 != self.frames:
            raise InputError(f"chunk at frame {f0} does not go on from frame {self.frames}", self.partial)
        for key in self.keys:
            require_finite(key, arrays[CHUNK_KEYS[key]], FRAME_KEYS[key], first=f0)
        try:
            for key in self.keys:
                self.npz.write(key, f0, arrays[CHUNK_KEYS[key]])
            if self.pc2 is not None:
                final = np.ascontiguousarray(arrays["skin_final"], dtype="<f4")
                self.pc2.seek(PC2_HEADER_BYTES + f0 * self._frame_bytes)
                self.pc2.write(memoryview(final).cast("B"))
                self.pc2.flush()
            if self.usd is not None:
                self._usd(f0, arrays["skin_static"], arrays["skin_final"], arrays["cvs_dynamic"])
            crcs, _ = self.npz.progress()
        except OSError as e:
            raise _cannot_write(self.partial, e) from None
        self.frames = f0 + len(arrays["skin_static"])
        _return_free_memory()
        return crcs

    def _usd(self, f0: int, static, final, cvs) -> None:
        muscles = self.setup.rig.surface(np.asarray(cvs, dtype=np.float64)).astype(np.float32)
        self.usd.append(f0, {"skin_static": static, "skin_final": final, "muscles": muscles})

    def finish(self, out_dir: str, names: dict) -> dict:
        """Complete every cache and rename it into out_dir under `names` ({format: file name}); the npz
        store is removed when npz was not asked for. Returns {format: path}."""
        out = {}
        try:
            self.npz.finish()
            if self.pc2 is not None:
                self.pc2.close()
            if self.usd is not None:
                self.usd.finish()
                self.usd = None
            for fmt, name in names.items():
                out[fmt] = dst = os.path.join(out_dir, name)
                os.replace(self.paths[fmt], dst)
                os.chmod(dst, 0o644)
        except OSError as e:
            raise _cannot_write(out_dir, e) from None
        if "npz" not in names:
            with contextlib.suppress(FileNotFoundError):
                os.remove(self.paths["npz"])
        return out

    def close(self) -> None:
        """Release the files (an interrupted bake: they stay in .partial to go on from)."""
        self.npz.close()
        if self.pc2 is not None:
            self.pc2.close()
        self.usd = None


def skin_parts(character) -> dict:
    """BakeData's part_names and part_offsets from the meshes a character was merged from
    (Character.meta["parts"]: [(name, first vertex, vertex count), ...] in vertex order), or {}."""
    parts = character.meta.get("parts")
    if not parts:
        return {}
    names = tuple(str(p[0]) for p in parts)
    offsets = np.array([int(p[1]) for p in parts] + [int(parts[-1][1]) + int(parts[-1][2])], np.int64)
    return {"part_names": names, "part_offsets": offsets}


def _return_free_memory() -> None:
    """Hand the heap's free pages back to the system (glibc's malloc_trim; nothing elsewhere). The chunk's
    arrays are freed in this thread among the small blocks USD keeps for its samples; without this the
    holes they leave count in the process's memory and it grows with the clip. With it a 10,000-frame bake
    of the 30k body peaks at 1.26x a 100-frame one. glibc's mmap threshold is left to rise as it does:
    fixing it at 128 kB (every large block its own mapping) kept the peak at 1.16x, but then every
    chunk-sized temporary is a fresh mapping whose pages fault in, and the bake ran 1.3-1.6x slower.
    A few milliseconds per chunk."""
    import ctypes
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
