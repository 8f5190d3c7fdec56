"""Blender's soft body on jiggle's particles: run by Blender's Python (the `bpy` wheel), not by jiggle's.

    .venv/blender/bin/python benchmarks/blender_softbody.py IN.npz OUT.npz PARAMS_JSON

benchmarks/bench_particles.py writes IN.npz and reads OUT.npz; this script imports nothing of jiggle
(bpy pins numpy < 2, jiggle needs >= 2: the two talk through files).

IN.npz: rest (N, 3) metres, the particles' rest positions (the mesh's vertices); edges (E, 2), the
model's springs (the mesh's edges, Blender's edge springs); goal (N,) in [0, 1), each vertex's goal
(Blender's "final goal" f: its goal spring is ks = 1 / (1 - f goal_spring) - 1 per unit mass; softbody.cc's
_final_goal is (goal_min + weight (goal_max - goal_min))^4, so the vertex group "goal" holds f^(1/4));
goals (F + 1, N, 3) metres, the goal positions at frames 0..F (30 fps).

The scene: one mesh object at the origin, two modifiers in this order:
1. Mesh Cache (format PC2, written here from `goals`, frame time mode, scene play mode): overwrites the
   vertices with the goals of the scene's frame, linearly interpolated between frames;
2. Soft Body: its goals are the vertices the modifiers above give (Blender interpolates them
   linearly inside a frame), goal weights the vertex group "goal" (goal_min 0, goal_max 1), edge
   springs on the mesh's edges (pull, push, damping), no bending springs, no collisions, no
   aerodynamics, gravity off (the soft body's own and its effector weight), the Heun solver with
   step_min = step_max = steps per frame, so every frame takes exactly that many steps: softbody.cc's
   softbody_step takes steps of dtime / step_min while the error is small and never shorter than
   dtime / step_max, and with the two equal the step neither shrinks nor grows (each step is Heun's two
   force evaluations). use_auto_step off.

Scene frames 1..F + 1 are times 0..F / 30 s: frame 1 is the point cache's start (the soft body is
placed on its goals, no step), frames 2..F + 1 are F simulated frames. Timed: scene.frame_set over
frames 2..F + 1, each evaluating the depsgraph (mesh cache read, soft body step, point cache write in
memory); the reset to frame 1 and the evaluated positions read at a few frames stay outside the timer.
Before each run a soft body setting is written again, which frees the point cache, so each repeat
simulates rather than reads the cache (the repeats' times are returned; their positions must agree).

Checks written to OUT.npz's info: with the soft body off the evaluated vertices are the goals (the
mesh cache plays the goals in the right frames); with it on they differ (it simulates: max and mean
offsets); the step count: softbody.cc prints "needed N steps/frame" after every frame of more than one
step when use_diagnose is on (a 10-frame run with it, stdout caught), and a short run at twice the
steps per frame takes about twice as long.

PARAMS_JSON: steps_per_frame, goal_spring, goal_friction, pull, push, damping, mass, friction (the soft
body's settings of the same names), and optionally fps (30), threads (1), repeats (3), use_edges (true).

OUT.npz: seconds (R,) per timed repeat; sampled (K,) frame indices into 0..F and positions (K, N, 3)
(the last repeat); info (JSON string).
"""
import json
import os
import re
import struct
import sys
import tempfile
import time

import bpy
import numpy as np


def write_pc2(path, frames):
    """A PC2 point cache: frames (F, N, 3) float32, start frame 0, one sample per frame."""
    frames = np.ascontiguousarray(frames, dtype="<f4")
    with open(path, "wb") as fh:
        fh.write(b"POINTCACHE2\0" + struct.pack("<iiffi", 1, frames.shape[1], 0.0, 1.0, frames.shape[0]))
        fh.write(frames.tobytes())


def positions(obj):
    """(N, 3) the object's evaluated vertex positions (object space = world: the object is at the origin)."""
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    mesh = ev.to_mesh()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3)


def main():
    src, out, params = sys.argv[-3], sys.argv[-2], json.loads(sys.argv[-1])
    d = np.load(src)
    rest, edges, goal, goals = d["rest"], d["edges"], d["goal"], d["goals"]
    frames = len(goals) - 1
    steps, repeats = int(params["steps_per_frame"]), int(params.get("repeats", 3))

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = int(params.get("fps", 30)), 1.0
    scene.frame_start, scene.frame_end = 1, frames + 1
    scene.use_gravity = False
    scene.render.threads_mode = "FIXED"            # the soft body's force threads (softbody.cc sb_cf_threads_run)
    scene.render.threads = int(params.get("threads", 1))

    mesh = bpy.data.meshes.new("particles")
    mesh.from_pydata(rest.tolist(), edges.tolist(), [])
    mesh.update()
    obj = bpy.data.objects.new("particles", mesh)
    scene.collection.objects.link(obj)
    group = obj.vertex_groups.new(name="goal")
    weight = np.asarray(goal, dtype=np.float64) ** 0.25        # _final_goal = weight^4 (goal_min 0, goal_max 1)
    for w in np.unique(weight):
        group.add(np.flatnonzero(weight == w).tolist(), float(w), "REPLACE")

    tmp = tempfile.mkdtemp(prefix="jiggle_softbody_")
    pc2 = os.path.join(tmp, "goals.pc2")
    write_pc2(pc2, goals)
    cache = obj.modifiers.new("goals", "MESH_CACHE")
    cache.cache_format, cache.filepath = "PC2", pc2
    cache.time_mode, cache.play_mode = "FRAME", "SCENE"
    cache.frame_start, cache.frame_scale = 1.0, 1.0
    cache.interpolation = "LINEAR"
    cache.deform_mode = "OVERWRITE"
    cache.forward_axis, cache.up_axis = "POS_Y", "POS_Z"

    mod = obj.modifiers.new("softbody", "SOFT_BODY")
    sb = obj.soft_body
    sb.use_goal, sb.vertex_group_goal = True, "goal"
    sb.goal_min, sb.goal_max, sb.goal_default = 0.0, 1.0, 0.7
    sb.goal_spring, sb.goal_friction = params["goal_spring"], params["goal_friction"]
    sb.use_edges = bool(params.get("use_edges", True))
    sb.pull, sb.push, sb.damping = params["pull"], params["push"], params["damping"]
    sb.bend, sb.plastic, sb.spring_length = 0.0, 0, 0
    sb.use_stiff_quads = sb.use_self_collision = sb.use_edge_collision = sb.use_face_collision = False
    sb.aero = 0
    sb.mass, sb.friction, sb.speed = params["mass"], params["friction"], 1.0
    sb.gravity = 0.0
    sb.effector_weights.gravity = 0.0
    sb.use_auto_step = False
    sb.step_min = sb.step_max = steps
    mod.point_cache.frame_start, mod.point_cache.frame_end = 1, frames + 1
    info = {"blender": bpy.app.version_string, "vertices": len(mesh.vertices), "edges": len(mesh.edges),
            "threads": scene.render.threads, "steps_per_frame": [sb.step_min, sb.step_max],
            "frames": frames}

    # 1. the goals play: soft body off, the evaluated vertices are the goals of the frame
    mod.show_viewport = False
    err = 0.0
    for f in sorted({0, frames // 3, frames}):
        scene.frame_set(f + 1)
        err = max(err, float(np.abs(positions(obj) - goals[f]).max()))
    info["goal_playback_max_err_m"] = err
    mod.show_viewport = True

    def reset():
        sb.step_min = sb.step_min                   # an RNA write: the point cache is freed (outdated)
        scene.frame_set(1)

    def simulate(last, sample=()):
        """Seconds of frame_set over frames 1..last + 1 (times 0..last), positions at the `sample` frames."""
        reset()
        got, secs = {}, 0.0
        for f in range(1, last + 1):
            t = time.perf_counter()
            scene.frame_set(f + 1)
            secs += time.perf_counter() - t
            if f in sample:
                got[f] = positions(obj)
        return secs, got

    # 2. the step count: softbody.cc prints "needed N steps/frame" after each frame of more than one
    # step when use_diagnose is on (C stdout: caught on file descriptor 1)
    log = os.path.join(tmp, "diagnose.txt")
    sb.use_diagnose = True
    sys.stdout.flush()
    saved = os.dup(1)
    with open(log, "w") as fh:
        os.dup2(fh.fileno(), 1)
        try:
            simulate(min(frames, 10))
        finally:
            os.dup2(saved, 1)
            os.close(saved)
    sb.use_diagnose = False
    with open(log) as fh:
        info["diagnose_steps_per_frame"] = [int(n) for n in re.findall(r"needed (\d+) steps/frame", fh.read())]
    os.remove(log)
    # and the time: a short run at steps and at 2 x steps per frame
    short = min(frames, 30)
    t1 = min(simulate(short)[0] for _ in range(2))
    sb.step_min = sb.step_max = 2 * steps
    t2 = min(simulate(short)[0] for _ in range(2))
    sb.step_min = sb.step_max = steps
    info["short_run_frames"] = short
    info["time_ratio_2x_steps"] = t2 / t1

    # 3. the timed runs
    sample = sorted({1, 2, frames // 4, frames // 2, 3 * frames // 4, frames})
    seconds, runs = [], []
    for _ in range(repeats):
        s, got = simulate(frames, sample)
        seconds.append(s)
        runs.append(np.stack([got[f] for f in sample]))
    info["repeats_equal"] = bool(all(np.array_equal(runs[0], r) for r in runs[1:]))
    dev = np.linalg.norm(runs[-1] - goals[sample], axis=2)
    info["max_offset_m"] = float(dev.max())
    info["mean_offset_m"] = float(dev.mean())
    np.savez(out, seconds=np.array(seconds), sampled=np.array(sample), positions=runs[-1], info=json.dumps(info))
    os.remove(pc2)
    os.rmdir(tmp)


main()
