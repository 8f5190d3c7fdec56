"""Test helper: Blender's own evaluation of a file's skinned mesh at given frames, in a Blender subprocess (the bpy
module of .venv/blender, JIGGLE_BPY_PYTHON or the blender program: rig.motion.fbx.blender_command)."""
from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

SCRIPT = r'''
import json, sys
import bpy
import numpy as np
src, out, fps, frames = sys.argv[-4], sys.argv[-3], float(sys.argv[-2]), json.loads(sys.argv[-1])
bpy.ops.wm.read_factory_settings(use_empty=True)
if fps > 0:
    bpy.context.scene.render.fps = int(round(fps))     # the importer turns key seconds into frames at this rate
if src.lower().endswith(".fbx"):
    bpy.ops.import_scene.fbx(filepath=src, anim_offset=0.0)
else:
    bpy.ops.import_scene.gltf(filepath=src)
mesh = [o for o in bpy.data.objects if o.type == "MESH"][0]
res = []
for f in frames:
    bpy.context.scene.frame_set(f)
    ev = mesh.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    M = np.array(ev.matrix_world)
    res.append([(M @ np.r_[v.co[:], 1.0])[:3] for v in me.vertices])
    ev.to_mesh_clear()
np.save(out, np.array(res))
'''


def blender_frames(path, frames: list[int], tmp_path, fps: float = 0.0) -> np.ndarray:
    """(F, V, 3) world positions (Blender's Z-up, metres) of the file's first mesh at each frame, as Blender's
    importer (FBX or glTF, by the extension) and depsgraph evaluate it; fps > 0 sets the scene's rate before
    the import. Skips the test without Blender."""
    from jiggle.rig.motion.fbx import blender_command
    if blender_command("x.py") is None:
        pytest.skip("no Blender here (bpy in .venv/blender, JIGGLE_BPY_PYTHON or JIGGLE_BLENDER_EXE)")
    script, out = tmp_path / "blender_eval.py", tmp_path / "blender_eval.npy"
    script.write_text(SCRIPT)
    r = subprocess.run(blender_command(str(script)) + [str(path), str(out), str(fps), json.dumps(frames)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and out.exists(), r.stdout[-1500:] + r.stderr[-1500:]
    return np.load(out)
