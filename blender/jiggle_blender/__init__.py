"""jiggle for Blender: a thin client of the `jiggle` command (a separate install; Warp and the rest never load in
Blender). The sidebar's Jiggle tab bakes the active armature's skinned meshes and its action:

1. the armature and its meshes are exported to a temporary glTF with Blender's own exporter (the action over the
   scene's frame range, sampled at the scene's rate; kept beside the bake as ARMATURE.jiggle.glb);
2. `jiggle bake --character that.glb --formats npz,pc2 --progress json` runs in a subprocess; its JSON lines
   drive Blender's progress bar and the status line (frames done, frames/s, time left); Esc or Cancel stops it
   and removes what it wrote;
3. the result comes back "exact": a Mesh Cache modifier right after the Armature modifier replaces its
   deformation with the baked skin (a PC2 cache in the mesh's own space and vertex order, made from the bake's
   npz beside it, so nothing is transformed twice); "Compare" switches it between the final and the static skin;
4. a bake with chains (tails, ears, hair: bake.npz's chain_names) keys their swung bones in an action of the
   add-on's own on its NLA track "jiggle chains", laid over the user's animation by an Action constraint on each
   chain bone (add_chains); the user's action, its keys and other tracks are untouched, a new bake replaces the
   track, and Compare mutes it with the cache.

Errors (no jiggle command, a rig it refuses) are Blender reports with the command's own message; the scene is
left as it was. The bake's files are the command's, bit for bit what `jiggle bake` writes for the same glTF.
"""
from __future__ import annotations

import json
import os
import queue
import shutil
import subprocess
import tempfile
import threading

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, PointerProperty, StringProperty

MODIFIER = "Jiggle"
FINAL_CACHE, STATIC_CACHE = "blender_final.pc2", "blender_static.pc2"


# ------------------------------------------------------------------------------------------ the command
def jiggle_command(context) -> str | None:
    prefs = context.preferences.addons[__package__].preferences if __package__ in context.preferences.addons \
        else None
    path = bpy.path.abspath(prefs.jiggle_path) if prefs and prefs.jiggle_path else ""
    if path:
        return path if os.path.isfile(path) and os.access(path, os.X_OK) else None
    return shutil.which("jiggle")


def armature_and_meshes(context):
    """(the armature, its skinned meshes) of the active object (an armature, or a mesh it deforms)."""
    ob = context.active_object
    if ob is None:
        return None, []
    arm = ob if ob.type == "ARMATURE" else next(
        (m.object for m in getattr(ob, "modifiers", []) if m.type == "ARMATURE" and m.object), None)
    if arm is None:
        return None, []
    meshes = [o for o in context.scene.objects if o.type == "MESH" and any(
        m.type == "ARMATURE" and m.object == arm for m in o.modifiers)]
    return arm, meshes


def bake_arguments(context, s, glb: str, out: str) -> list[str]:
    scene = context.scene
    fps = s.fps or scene.render.fps / scene.render.fps_base
    formats = "npz,pc2,glb" if s.result == "BONES" else "npz,pc2"
    args = ["bake", "--character", glb, "--out", out, "--formats", formats, "--progress", "json",
            "--fps", f"{fps:g}"]
    if s.result == "BONES" and s.jiggle_bones > 0:
        args += ["--jiggle-bones", str(s.jiggle_bones)]
    if s.template:
        args += ["--template", s.template]
    if s.use_strength:
        args += ["--strength", f"{s.strength:g}"]
    for item in [x.strip() for x in s.muscles.split(",") if x.strip()]:
        args += ["--strength", item]
    if s.blend != 1.0:
        args += ["--blend", f"{s.blend:g}"]
    if s.collisions:
        args += ["--collisions"]
    if s.activation != "DEFAULT":
        args += ["--activation", s.activation.lower()]
    if s.chains.strip() and s.chains.strip() != "auto":
        args += [f"--chains={s.chains.strip()}"]
    for flag, text in (("--chain-stiffness", s.chain_stiffness), ("--chain-damping", s.chain_damping),
                       ("--chain-gravity", s.chain_gravity), ("--chain-drag", s.chain_drag)):
        for item in [x.strip() for x in text.split(";") if x.strip()]:      # ";": keys hold commas
            args += [flag, item]
    return args


def _pump(stream, sink) -> None:
    """Every line of a subprocess's stream to sink(line), until it closes (a reader thread's loop)."""
    for line in stream:
        sink(line)


class BakeJob:
    """`jiggle bake ... --progress json` running in a subprocess: its JSON lines as events, its stderr kept for the
    error it prints, and a cancel that stops it and removes what it wrote (its .partial folder, and the output
    folder when the job made it). Plain Python: the modal operator polls it on a timer."""

    def __init__(self, argv: list[str], out: str):
        self.argv, self.out = argv, out
        self.out_existed = os.path.isdir(out)
        self.proc = None
        self._lines: queue.Queue = queue.Queue()
        self._err: list[str] = []

    def start(self, env: dict | None = None) -> None:
        self.proc = subprocess.Popen(self.argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env=env)
        self._threads = [threading.Thread(target=_pump, args=(stream, sink), daemon=True)
                         for stream, sink in ((self.proc.stdout, self._lines.put), (self.proc.stderr, self._err.append))]
        for t in self._threads:
            t.start()

    def wait(self) -> int:
        """The exit code, once the process and its readers are done."""
        code = self.proc.wait()
        for t in self._threads:
            t.join(timeout=10)
        return code

    def events(self) -> list[dict]:
        """The JSON lines read since the last call."""
        out = []
        while not self._lines.empty():
            try:
                out.append(json.loads(self._lines.get_nowait()))
            except ValueError:
                continue
        return out

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def error(self) -> str:
        lines = [ln for ln in "".join(self._err).strip().splitlines() if ln.strip()]
        return lines[-1] if lines else f"jiggle bake failed (exit {self.proc.returncode})"

    def cancel(self) -> None:
        if self.running():
            self.proc.terminate()
            self.wait()
        self.discard()

    def discard(self) -> None:
        """Remove what the bake wrote: its unfinished part, and the folder if the job made it."""
        shutil.rmtree(os.path.join(self.out, ".partial"), ignore_errors=True)
        if not self.out_existed:
            shutil.rmtree(self.out, ignore_errors=True)


# ------------------------------------------------------------------------------------------ the caches
def write_pc2(path: str, frames, start: float, rate: float) -> None:
    import numpy as np
    frames = np.ascontiguousarray(frames, dtype="<f4")
    T, V = frames.shape[:2]
    tmp = path + ".part"
    with open(tmp, "wb") as fh:
        fh.write(b"POINTCACHE2\0" + np.array([1, V], "<i4").tobytes() + np.array([start, rate], "<f4").tobytes()
                 + np.array([T], "<i4").tobytes())
        fh.write(frames.tobytes())
    os.replace(tmp, path)


def file_unit(data) -> float:
    """Metres per unit of the baked character's file (bake.npz's params "file_unit_m"; 1 for older bakes): the bake
    reads a file in centimetres as metres, and Blender imported its glTF a unit a Blender unit."""
    import json
    try:
        return float(json.loads(str(data["params"])).get("file_unit_m") or 1.0)
    except (KeyError, ValueError, TypeError, AttributeError):
        return 1.0


def vertex_map(context, mesh, data, frame: int):
    """(pick (V_blender,): the bake's vertex each Blender vertex is, the mesh's world matrix (4, 4)): where each
    stood at the bake's first frame (the glTF splits vertices at UV seams; the copies move alike)."""
    import numpy as np
    from mathutils.kdtree import KDTree
    first = (data["skin_lbs"][0] if "skin_lbs" in data.files else data["skin_static"][0]) / file_unit(data)
    mod = mesh.modifiers.get(MODIFIER)           # a last bake's cache: the mesh as the armature alone deforms it
    shown = mod.show_viewport if mod is not None else None
    if mod is not None:
        mod.show_viewport = False
    try:
        context.scene.frame_set(frame)
        ev = mesh.evaluated_get(context.evaluated_depsgraph_get())
        me = ev.to_mesh()
        world = np.array(ev.matrix_world)
        pts = np.array([v.co[:] for v in me.vertices])
        ev.to_mesh_clear()
    finally:
        if mod is not None:
            mod.show_viewport = shown
    pts = pts @ world[:3, :3].T + world[:3, 3]
    tree = KDTree(len(first))
    for i, p in enumerate(first):
        tree.insert(p.tolist(), i)
    tree.balance()
    found = [tree.find(p.tolist()) for p in pts]
    far = max(f[2] for f in found)
    if far > 1e-3:
        raise RuntimeError(f"the baked skin does not lie on {mesh.name!r} (a vertex {far * 1000:.1f} mm away): "
                           "bake it again from this file")
    return np.array([f[1] for f in found]), world


def mesh_caches(context, mesh, out: str, frame_start: int) -> tuple[str, str]:
    """The bake's final and static skins as PC2 caches in `mesh`'s own space and vertex order: each Blender vertex
    takes the bake's vertex where it stood at the first frame (the glTF splits vertices at UV seams; a split
    vertex's copies move alike), its positions brought into the object's space."""
    import numpy as np
    data = np.load(os.path.join(out, "bake.npz"))
    pick, world = vertex_map(context, mesh, data, frame_start)
    inv = np.linalg.inv(world)
    paths = []
    for key, name in (("skin_final", FINAL_CACHE), ("skin_static", STATIC_CACHE)):
        skin = data[key][:, pick].astype(np.float64) / file_unit(data)
        local = skin @ inv[:3, :3].T + inv[:3, 3]
        path = os.path.join(out, f"{mesh.name}.{name}")
        write_pc2(path, local, 0.0, 1.0)              # sample k at cache frame k: the modifier maps the scene
        paths.append(path)
    return paths[0], paths[1]


def add_cache(mesh, path: str, frame_start: int, rate: float):
    """A Mesh Cache modifier right after the Armature one, overwriting its deformation; `rate`: the bake's frames
    per second."""
    mod = mesh.modifiers.get(MODIFIER) or mesh.modifiers.new(MODIFIER, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = path
    mod.deform_mode = "OVERWRITE"
    mod.time_mode = "FRAME"
    mod.play_mode = "SCENE"
    scene = bpy.context.scene
    mod.frame_scale = rate / (scene.render.fps / scene.render.fps_base)    # cache frames per scene frame
    mod.frame_start = float(frame_start) * mod.frame_scale     # Blender plays cache frame f * scale - frame_start
    mod.interpolation = "LINEAR"
    mod.forward_axis, mod.up_axis = "POS_Y", "POS_Z"
    names = [m.name for m in mesh.modifiers]
    arm = next((i for i, m in enumerate(mesh.modifiers) if m.type == "ARMATURE"), None)
    if arm is not None:
        mesh.modifiers.move(names.index(mod.name), arm + 1)
    return mod


# ------------------------------------------------------------------------------------------ jiggle bones
_COMPONENTS = {5120: ("<i1", 127.0), 5121: ("<u1", 255.0), 5122: ("<i2", 32767.0), 5123: ("<u2", 65535.0),
               5125: ("<u4", None), 5126: ("<f4", None)}
_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def read_glb(path: str):
    """(the glTF JSON, accessor(i) -> array) of a .glb, normalized integers mapped to [-1, 1] / [0, 1]."""
    import struct
    import numpy as np
    with open(path, "rb") as fh:
        data = fh.read()
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + n])
    blob = data[20 + n + 8:]

    def accessor(i):
        a = doc["accessors"][i]
        view = doc["bufferViews"][a["bufferView"]]
        dtype, norm = _COMPONENTS[a["componentType"]]
        k = _SIZES[a["type"]]
        start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
        out = np.frombuffer(blob, dtype, a["count"] * k, start).reshape(a["count"], k).astype(np.float64)
        if a.get("normalized") and norm:
            out = np.maximum(out / norm, -1.0)
        return out
    return doc, accessor


def _trs(t, q_xyzw):
    from mathutils import Matrix, Quaternion
    q = Quaternion((q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]))
    return Matrix.Translation(t) @ q.to_matrix().to_4x4()


def add_jiggle_bones(context, arm, meshes, glb: str, first: int) -> int:
    """The glb's jiggle bones into `arm`: bones with their hosts' rest pose (children of the hosts), their keys in
    a new action on an NLA track of their own (the armature's action and keys untouched), and the glb's weights
    on the meshes' vertex groups (the jiggle bones' groups added). Returns the bones added."""
    import numpy as np
    from mathutils import Matrix
    doc, acc = read_glb(glb)
    nodes = doc["nodes"]
    parent = {c: i for i, nd in enumerate(nodes) for c in nd.get("children", [])}
    jig = [i for i, nd in enumerate(nodes) if "_jiggle_" in nd.get("name", "")]
    bones = arm.data.bones
    missing = [nodes[parent[i]]["name"] for i in jig if nodes[parent[i]]["name"] not in bones]
    if missing:
        raise RuntimeError(f"the glb's jiggle bones hang under bones this armature lacks ({missing[0]}, ...)")
    # world rest of the glb's nodes (glTF Y-up) from their own transforms
    def local(i):
        nd = nodes[i]
        return _trs(nd.get("translation", (0, 0, 0)), nd.get("rotation", (0, 0, 0, 1)))
    def world(i):
        m = local(i)
        while i in parent:
            i = parent[i]
            m = local(i) @ m
        return m
    to_arm = arm.matrix_world.inverted() @ Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))
    # the bones, at their hosts' rest
    ctx_obj = context.view_layer.objects.active
    context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        for i in jig:
            host = arm.data.edit_bones[nodes[parent[i]]["name"]]
            eb = arm.data.edit_bones.get(nodes[i]["name"]) or arm.data.edit_bones.new(nodes[i]["name"])
            eb.head, eb.tail, eb.roll = host.head.copy(), host.tail.copy(), host.roll
            eb.parent, eb.use_connect, eb.use_deform = host, False, True
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
        context.view_layer.objects.active = ctx_obj
    # their keys: basis = Y^-1 L Y, L the glb's local transform under the host, Y the host's node -> bone frame
    anim = doc["animations"][0]
    samplers = anim["samplers"]
    keys = {}
    for ch in anim["channels"]:
        node, path = ch["target"]["node"], ch["target"]["path"]
        if node in jig:
            keys[(node, path)] = acc(samplers[ch["sampler"]]["output"])
    times = acc(samplers[0]["input"])[:, 0]
    # a looping bake (jiggle bake --loop): the glb's extras say so (asset.extras.jiggle.loop)
    looped = bool((((doc.get("asset") or {}).get("extras") or {}).get("jiggle") or {}).get("loop", {}).get("on"))
    action = bpy.data.actions.new(f"{arm.name}.jiggle")
    slot = action.slots.new(id_type="OBJECT", name=arm.name)
    from bpy_extras.anim_utils import action_ensure_channelbag_for_slot
    bag = action_ensure_channelbag_for_slot(action, slot)
    scene = context.scene
    frames = first + times * scene.render.fps / scene.render.fps_base   # another rate than the scene's: between frames
    for i in jig:
        name = nodes[i]["name"]
        host = nodes[parent[i]]["name"]
        Y = (to_arm @ world(parent[i])).inverted() @ bones[host].matrix_local
        t = keys.get((i, "translation"), np.tile(nodes[i].get("translation", (0, 0, 0)), (len(times), 1)))
        r = keys.get((i, "rotation"), np.tile(nodes[i].get("rotation", (0, 0, 0, 1)), (len(times), 1)))
        loc, rot = np.empty((len(times), 3)), np.empty((len(times), 4))
        for k in range(len(times)):
            basis = Y.inverted() @ _trs(t[k], r[k]) @ Y
            loc[k], rot[k] = basis.to_translation(), basis.to_quaternion()
        for k in range(1, len(rot)):                                   # one hemisphere: keys interpolate the short way
            if np.dot(rot[k], rot[k - 1]) < 0:
                rot[k] = -rot[k]
        arm.pose.bones[name].rotation_mode = "QUATERNION"
        for path, values in (("location", loc), ("rotation_quaternion", rot)):
            for c in range(values.shape[1]):
                fc = bag.fcurves.new(f'pose.bones["{name}"].{path}', index=c, group_name=name)
                fc.keyframe_points.add(len(frames))
                fc.keyframe_points.foreach_set("co", np.c_[frames, values[:, c]].ravel().tolist())
                fc.keyframe_points.foreach_set("interpolation", [1] * len(frames))       # LINEAR, as the glb
                if looped:      # one period whose last key repeats the first: the keys repeat past both ends
                    fc.modifiers.new(type="CYCLES")
                fc.update()
    ad = arm.animation_data or arm.animation_data_create()
    track = ad.nla_tracks.new()
    track.name = "jiggle"
    strip = track.strips.new(action.name, int(frames[0]), action)
    strip.action_slot = slot
    # the weights: each Blender vertex takes those of the glb vertex it is (the glb's vertices are the bake's)
    prim = doc["meshes"][0]["primitives"][0]
    sets = [(acc(prim["attributes"][f"JOINTS_{s}"]).astype(int), acc(prim["attributes"][f"WEIGHTS_{s}"]))
            for s in range(4) if f"JOINTS_{s}" in prim["attributes"]]
    skin_joints = [nodes[j]["name"] for j in doc["skins"][0]["joints"]]
    deform = set(bones.keys())
    with np.load(os.path.join(os.path.dirname(glb), "bake.npz")) as data:
        picks = {mesh.name: vertex_map(context, mesh, data, first)[0] for mesh in meshes}
    for mesh in meshes:
        groups = {g.name: g for g in mesh.vertex_groups}
        for i in jig:
            if nodes[i]["name"] not in groups:
                groups[nodes[i]["name"]] = mesh.vertex_groups.new(name=nodes[i]["name"])
        index = {g.index: g for g in mesh.vertex_groups}
        pick = picks[mesh.name]
        for v in mesh.data.vertices:
            k = int(pick[v.index])
            for ge in list(v.groups):
                g = index.get(ge.group)
                if g is not None and g.name in deform:
                    g.remove([v.index])
            for J, W in sets:
                for j, w in zip(J[k], W[k]):
                    if w > 0:
                        groups[skin_joints[j]].add([v.index], float(w), "REPLACE")
    return len(jig)


# ------------------------------------------------------------------------------------------ chains
CHAINS = "jiggle chains"        # the add-on's NLA track, and the Action constraint it puts on each chain bone
_OURS = "jiggle"                # the ID property marking the action it made ("chains")


def chain_bases(arm, data):
    """({bone: (T, 4, 4) its basis per bake frame}, [the chain bones it cannot key]): each chain bone's swung pose
    (bake.npz's chain_world) as Blender's rest-relative local transform, the matrix its location and rotation make:

        basis = (R_p^-1 @ R_b)^-1 @ (W_p^-1 @ W_b)

    R the rest (bone.matrix_local, armature space), W world transforms in jiggle's world (metres, Z-up): W_b its
    chain_world, W_p its parent's (its chain_world when the parent swings too, else the animated joint_world; the
    armature object itself for a root bone), their relative translation brought into armature units. jiggle's joint
    frames are the glTF's nodes', and Blender's exporter writes each bone's own frame there, so W's axes are the
    bone's. The default inheritance (rotation and full scale from the parent) is assumed. A bone the armature lacks,
    or whose parent the bake does not carry, is returned in the list."""
    import numpy as np
    names = [str(n) for n in data["chain_names"]]
    world = {n: data["chain_world"][:, i].astype(np.float64) for i, n in enumerate(names)}
    joints = {str(n): i for i, n in enumerate(data["joint_names"])}
    fu = file_unit(data)                                        # metres per Blender unit
    M = np.array(arm.matrix_world, dtype=np.float64)
    s = float(np.cbrt(abs(np.linalg.det(M[:3, :3]))))            # the armature object's (uniform) scale
    obj = np.eye(4)
    obj[:3, :3], obj[:3, 3] = M[:3, :3] / s, M[:3, 3] * fu        # the object's frame in jiggle's world
    bones, out, skipped = arm.data.bones, {}, []
    for n in names:
        b = bones.get(n)
        p = b.parent if b is not None else None
        if b is None or (p is not None and p.name not in world and p.name not in joints):
            skipped.append(n)
            continue
        if p is None:
            Wp, rest = obj[None], np.array(b.matrix_local)
        else:
            Wp = world[p.name] if p.name in world else data["joint_world"][:, joints[p.name]].astype(np.float64)
            rest = np.array(p.matrix_local.inverted() @ b.matrix_local)
        rel = np.linalg.inv(Wp) @ world[n]
        rel[:, :3, 3] /= fu * s
        out[n] = np.linalg.inv(rest) @ rel
    return out, skipped


def _rotations(basis, mode: str):
    """(T, k) the rotations of bases (T, 4, 4) in a pose bone's rotation mode, continuous from key to key."""
    import numpy as np
    from mathutils import Matrix
    out, prev = [], None
    for m in basis:
        q = Matrix(m.tolist()).to_quaternion()
        if mode == "QUATERNION":
            r = np.array(q)
            if prev is not None and np.dot(r, prev) < 0:                 # one hemisphere: the short way
                r = -r
        elif mode == "AXIS_ANGLE":
            axis, angle = q.to_axis_angle()
            r = np.array((angle, *axis))
        else:
            r = np.array(q.to_euler(mode, *([] if prev is None else [prev])))
        out.append(r)
        prev = r if mode != "AXIS_ANGLE" else None
    return np.array(out)


def _key(bag, path: str, values, frames, group: str) -> None:
    import numpy as np
    values = np.asarray(values, dtype=np.float64).reshape(len(frames), -1)
    for c in range(values.shape[1]):
        fc = bag.fcurves.new(path, index=c, group_name=group)
        fc.keyframe_points.add(len(frames))
        fc.keyframe_points.foreach_set("co", np.c_[frames, values[:, c]].ravel().tolist())
        fc.keyframe_points.foreach_set("interpolation", [1] * len(frames))              # LINEAR, as the cache
        fc.update()


def add_chains(context, arm, data, first: int):
    """The bake's swung chains (bake.npz's chain_names, chain_world) keyed on `arm`, frame k of the bake at scene
    frame first + k (in the scene's rate): returns (the bones keyed, the chain bones skipped).

    The user's action keeps playing untouched, and it is evaluated on top of every NLA track, so the swing is laid
    over it by the bones' constraints rather than by the track alone. One action of the add-on's own,
    ARMATURE.jiggle_chains, holds two slots: "bones", each chain bone's location and rotation (in its own rotation
    mode), and the armature's slot, the constraints' clock, which the NLA track "jiggle chains" plays. Each chain
    bone gets a last Action constraint "jiggle chains" that replaces its local transform with the "bones" slot at
    that clock; its influence follows the track's mute (a driver), so muting the track in the NLA editor or with
    Compare gives the user's animation back. The pose bones' own properties are never written."""
    import numpy as np
    from bpy_extras.anim_utils import action_ensure_channelbag_for_slot
    bases, skipped = chain_bases(arm, data)
    if not bases:
        return [], skipped
    scene = context.scene
    times = np.asarray(data["times"], dtype=np.float64)
    frames = first + (times - times[0]) * scene.render.fps / scene.render.fps_base
    lo, hi = int(np.floor(frames[0])), int(np.ceil(frames[-1]))
    hi = max(hi, lo + 1)
    action = bpy.data.actions.new(f"{arm.name}.jiggle_chains")
    action[_OURS] = "chains"
    clock = action.slots.new(id_type="OBJECT", name=arm.name)
    keyed = action.slots.new(id_type="OBJECT", name="bones")
    bones_bag = action_ensure_channelbag_for_slot(action, keyed)
    clock_bag = action_ensure_channelbag_for_slot(action, clock)
    path_of = {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}
    for name, basis in bases.items():
        pb = arm.pose.bones[name]
        _key(bones_bag, f'pose.bones["{name}"].location', basis[:, :3, 3], frames, name)
        _key(bones_bag, f'pose.bones["{name}"].{path_of.get(pb.rotation_mode, "rotation_euler")}',
             _rotations(basis, pb.rotation_mode), frames, name)
        con = pb.constraints.new("ACTION")
        con.name = CHAINS
        con.action, con.action_slot = action, keyed
        con.mix_mode, con.owner_space = "REPLACE", "LOCAL"
        con.use_eval_time = True
        con.frame_start, con.frame_end = lo, hi                  # eval_time 0..1 plays these frames of "bones"
        _key(clock_bag, f'pose.bones["{name}"].constraints["{CHAINS}"].eval_time', [0.0, 1.0],
             np.array([lo, hi], dtype=np.float64), name)
        fc = con.driver_add("influence")
        var = fc.driver.variables.new()
        var.name, var.type = "muted", "SINGLE_PROP"
        var.targets[0].id_type, var.targets[0].id = "OBJECT", arm
        var.targets[0].data_path = f'animation_data.nla_tracks["{CHAINS}"].mute'
        fc.driver.type, fc.driver.expression = "SCRIPTED", "1 - muted"           # a simple expression: no Python
    ad = arm.animation_data or arm.animation_data_create()
    track = ad.nla_tracks.new()
    track.name = CHAINS
    strip = track.strips.new(action.name, lo, action)
    strip.action_slot = clock
    return list(bases), skipped


def chain_parts(arm):
    """(the add-on's chains track or None, its actions, [(pose bone, constraint)]) on `arm`."""
    ad = arm.animation_data
    track = ad.nla_tracks.get(CHAINS) if ad else None
    actions = [s.action for s in track.strips if s.action is not None and s.action.get(_OURS) == "chains"] \
        if track else []
    cons = [(pb, c) for pb in arm.pose.bones for c in pb.constraints
            if c.name == CHAINS and c.type == "ACTION" and (c.action is None or c.action.get(_OURS) == "chains")]
    return track, actions, cons


def remove_chains(arm) -> None:
    """What add_chains made on `arm` (the track, its action, the constraints and their drivers), nothing else."""
    track, actions, cons = chain_parts(arm)
    for pb, con in cons:
        con.driver_remove("influence")
        pb.constraints.remove(con)
    if track is not None:
        arm.animation_data.nla_tracks.remove(track)
    for a in actions:
        if a.users == 0:
            bpy.data.actions.remove(a)


class chains_off:
    """While in the block, the add-on's chains on `arm` do not move its bones (what is exported is the user's
    animation); as they were after."""

    def __init__(self, arm):
        self.track, _, cons = chain_parts(arm)
        self.cons = [c for _, c in cons]

    def __enter__(self):
        self.kept = (self.track.mute if self.track else None, [c.mute for c in self.cons])
        if self.track:
            self.track.mute = True
        for c in self.cons:
            c.mute = True
        return self

    def __exit__(self, *exc):
        if self.track:
            self.track.mute = self.kept[0]
        for c, m in zip(self.cons, self.kept[1]):
            c.mute = m
        return False


# ------------------------------------------------------------------------------------------ properties, UI
class JigglePreferences(bpy.types.AddonPreferences):
    bl_idname = __package__
    jiggle_path: StringProperty(name="jiggle command", subtype="FILE_PATH", default="",
                                description="The jiggle program; empty: the one on PATH")

    def draw(self, context):
        self.layout.prop(self, "jiggle_path")
        found = jiggle_command(context)
        self.layout.label(text=f"found: {found}" if found else "jiggle not found: install it, or give its path")


class JiggleSettings(bpy.types.PropertyGroup):
    action: PointerProperty(name="Action", type=bpy.types.Action, description="The action to bake; empty: the "
                            "armature's own")
    use_range: BoolProperty(name="Frame range", default=False, description="Bake these frames, not the scene's")
    frame_start: bpy.props.IntProperty(name="Start", default=1)
    frame_end: bpy.props.IntProperty(name="End", default=250)
    fps: FloatProperty(name="Output fps", default=0.0, min=0.0, description="Frames per second of the bake; 0: the "
                       "scene's")
    out_dir: StringProperty(name="Output", subtype="DIR_PATH", default="//jiggle_bake",
                            description="The folder the bake writes (bake.npz, bake.pc2, bake.json)")
    template: StringProperty(name="Template", default="", description="Muscle template: empty for auto, human, "
                             "quadruped or a .toml file")
    use_strength: BoolProperty(name="Strength", default=False, description="Scale every muscle's jiggle")
    strength: FloatProperty(name="Strength", default=1.0, min=0.0, soft_max=4.0)
    muscles: StringProperty(name="Per muscle", default="", description="Per-muscle strengths, NAME=VALUE, "
                            "comma-separated (the CLI's --strength NAME=VALUE)")
    blend: FloatProperty(name="Blend", default=1.0, min=0.0, max=1.0, description="0: static muscles, 1: jiggle")
    collisions: BoolProperty(name="Collisions", default=False)
    activation: EnumProperty(name="Activation", items=[
        ("DEFAULT", "Default", "jiggle's default (the CLI's --activation left out)"),
        ("ON", "On", "Each muscle works as the motion's own forces ask: a loaded muscle stiffens and bulges "
                     "(--activation on)"),
        ("OFF", "Off", "Every muscle as soft as at rest (--activation off)")], default="DEFAULT")
    chains: StringProperty(name="Chains", default="auto", description="Tails, ears, hair and wing fingers that swing: "
                           "auto, none, or joints (globs) that start one, comma-separated (the CLI's --chains)")
    chain_stiffness: StringProperty(name="Chain stiffness", default="", description="Per chain (its root joint, or a "
                                    "glob) NAME=Hz, ';'-separated; keys as [[t, v], ...] (--chain-stiffness)")
    chain_damping: StringProperty(name="Chain damping", default="", description="Per chain NAME=RATIO, ';'-separated "
                                  "(--chain-damping)")
    chain_gravity: StringProperty(name="Chain gravity", default="", description="Per chain NAME=SHARE of g, "
                                  "';'-separated (--chain-gravity)")
    chain_drag: StringProperty(name="Chain drag", default="", description="Per chain NAME=SHARE of air's density, "
                               "';'-separated (--chain-drag)")
    result: EnumProperty(name="Result", items=[
        ("EXACT", "Exact", "A Mesh Cache modifier plays the baked skin"),
        ("BONES", "Bones", "Jiggle bones (the glb's) added to the armature with their own action on an NLA track, "
                           "and their weights on the mesh: what a game engine plays")], default="EXACT")
    jiggle_bones: bpy.props.IntProperty(name="Jiggle bones", default=0, min=0, description="0: the template's "
                                        "default (the CLI's --jiggle-bones)")
    showing: StringProperty(default="")


class JIGGLE_PT_panel(bpy.types.Panel):
    bl_label = "Jiggle"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Jiggle"

    def draw(self, context):
        s = context.scene.jiggle
        arm, meshes = armature_and_meshes(context)
        col = self.layout.column()
        if arm is None:
            col.label(text="Select an armature or a mesh it deforms")
        else:
            action = arm.animation_data.action.name if arm.animation_data and arm.animation_data.action else "none"
            col.label(text=f"{arm.name}: {len(meshes)} mesh(es), action {action}")
            sc = context.scene
            col.label(text=f"frames {sc.frame_start}-{sc.frame_end} at {sc.render.fps / sc.render.fps_base:g} fps")
        col.prop(s, "action")
        row = col.row()
        row.prop(s, "use_range", text="")
        sub = row.row(align=True)
        sub.enabled = s.use_range
        sub.prop(s, "frame_start")
        sub.prop(s, "frame_end")
        col.prop(s, "fps")
        col.prop(s, "out_dir")
        col.prop(s, "template")
        row = col.row()
        row.prop(s, "use_strength", text="")
        row.prop(s, "strength")
        col.prop(s, "muscles")
        col.prop(s, "blend")
        col.prop(s, "collisions")
        col.prop(s, "activation")
        col.prop(s, "chains")
        for name in ("chain_stiffness", "chain_damping", "chain_gravity", "chain_drag"):
            col.prop(s, name)
        col.prop(s, "result")
        if s.result == "BONES":
            col.prop(s, "jiggle_bones")
        col.operator("jiggle.bake", icon="PHYSICS")
        row = col.row()
        row.operator("jiggle.compare", text="Show static" if s.showing != "static" else "Show final")
        row.operator("jiggle.open_report")


# ------------------------------------------------------------------------------------------ operators
class JIGGLE_OT_bake(bpy.types.Operator):
    """Export the character, run `jiggle bake`, play the result (Esc cancels)"""
    bl_idname = "jiggle.bake"
    bl_label = "Bake jiggle"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return armature_and_meshes(context)[0] is not None

    def prepare(self, context) -> bool:
        self.cmd = jiggle_command(context)
        if self.cmd is None:
            self.report({"ERROR"}, "jiggle: the jiggle command was not found: install jiggle (its README) and put it "
                                   "on PATH, or set its path in the add-on's preferences")
            return False
        self.arm, self.meshes = armature_and_meshes(context)
        if not self.meshes:
            self.report({"ERROR"}, f"jiggle: {self.arm.name} deforms no mesh (an Armature modifier pointing at it)")
            return False
        s = context.scene.jiggle
        self.out = bpy.path.abspath(s.out_dir)
        self.tmp = tempfile.mkdtemp(prefix="jiggle_blender_")
        glb = os.path.join(self.tmp, "character.glb")
        scene = context.scene
        kept = {o: o.select_get() for o in scene.objects}
        active = context.view_layer.objects.active
        ad = self.arm.animation_data or self.arm.animation_data_create()
        action, span = ad.action, (scene.frame_start, scene.frame_end)
        try:                               # the action and frame range asked for, for the export only
            if s.action is not None:
                ad.action = s.action
            if s.use_range:
                scene.frame_start, scene.frame_end = s.frame_start, max(s.frame_end, s.frame_start + 1)
            self.first = scene.frame_start     # the exporter samples from here: the bake's first frame
            for o in scene.objects:
                o.select_set(o == self.arm or o in self.meshes)
            with chains_off(self.arm):     # the user's animation, not the last bake's swing on it
                bpy.ops.export_scene.gltf(filepath=glb, use_selection=True, export_animations=True,
                                          export_animation_mode="ACTIVE_ACTIONS", export_frame_range=True,
                                          export_force_sampling=True, export_apply=False)
        finally:
            for o, sel in kept.items():
                o.select_set(sel)
            context.view_layer.objects.active = active
            if ad.action != action:
                ad.action = action
            scene.frame_start, scene.frame_end = span
        self.job = BakeJob([self.cmd] + bake_arguments(context, s, glb, self.out), self.out)
        return True

    def execute(self, context):              # blocking (scripts, background): the same command, waited for
        if not self.prepare(context):
            return {"CANCELLED"}
        self.job.start()
        return self.finish(context)

    def invoke(self, context, event):
        if not self.prepare(context):
            return {"CANCELLED"}
        self.job.start()
        wm = context.window_manager
        self.timer = wm.event_timer_add(0.2, window=context.window)
        wm.progress_begin(0, 100)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self.job.cancel()
            self._cleanup(context)
            self.report({"WARNING"}, "jiggle: bake cancelled; nothing was kept")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        for msg in self.job.events():
            if msg.get("event") == "progress" and msg.get("total"):
                context.window_manager.progress_update(int(100 * msg["frames"] / msg["total"]))
                eta = msg.get("eta_s")
                context.workspace.status_text_set(
                    f"jiggle: {msg['frames']}/{msg['total']} frames, {msg.get('fps', 0):.0f} frames/s"
                    + (f", {eta:.0f} s left" if eta is not None else ""))
        if self.job.running():
            return {"RUNNING_MODAL"}
        return self.finish(context)

    def finish(self, context):
        if self.job.wait() != 0:
            self.job.discard()
            self._cleanup(context)
            self.report({"ERROR"}, self.job.error())
            return {"CANCELLED"}
        skipped = []
        try:
            start = self.first
            remove_chains(self.arm)          # the last bake's: this one replaces them
            if context.scene.jiggle.result == "BONES":
                add_jiggle_bones(context, self.arm, self.meshes, os.path.join(self.out, "bake.glb"), start)
            else:
                import numpy as np
                with np.load(os.path.join(self.out, "bake.npz")) as data:
                    rate = float(data["fps"])
                for mesh in self.meshes:
                    final, _static = mesh_caches(context, mesh, self.out, start)
                    add_cache(mesh, final, start, rate)
            import numpy as np
            with np.load(os.path.join(self.out, "bake.npz")) as data:
                if "chain_names" in data.files:
                    skipped = add_chains(context, self.arm, data, start)[1]
        except (OSError, RuntimeError, KeyError) as e:
            self._cleanup(context)
            self.report({"ERROR"}, f"jiggle: {e}")
            return {"CANCELLED"}
        context.scene.jiggle.showing = "final"
        kept = os.path.join(self.out, f"{bpy.path.clean_name(self.arm.name)}.jiggle.glb")
        shutil.copyfile(os.path.join(self.tmp, "character.glb"), kept)     # what was baked: `jiggle bake` again
        self._cleanup(context)
        if skipped:
            self.report({"WARNING"}, f"jiggle: chain bones {self.arm.name} lacks (or whose parent the bake does "
                                     f"not carry) were not keyed: {', '.join(skipped)}")
        self.report({"INFO"}, f"jiggle: baked into {self.out}")
        return {"FINISHED"}

    def _cleanup(self, context):
        """The timer, the progress bar and status line, the exported glTF's folder."""
        wm = context.window_manager
        if getattr(self, "timer", None) is not None:
            wm.event_timer_remove(self.timer)
            self.timer = None
            wm.progress_end()
            context.workspace.status_text_set(None)
        shutil.rmtree(getattr(self, "tmp", ""), ignore_errors=True)


class JIGGLE_OT_compare(bpy.types.Operator):
    """Switch the baked skin between final (with jiggle) and static (muscles without jiggle, chains unswung)"""
    bl_idname = "jiggle.compare"
    bl_label = "Compare"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        s = context.scene.jiggle
        to = "static" if s.showing != "static" else "final"
        arm, meshes = armature_and_meshes(context)
        track = chain_parts(arm)[0] if arm is not None else None
        n = 0
        if track is not None:                      # the swung chains go with the jiggle (the constraints follow)
            track.mute = to == "static"
            n += 1
        for mesh in meshes:
            mod = mesh.modifiers.get(MODIFIER)
            if mod is None:
                continue
            a, b = (FINAL_CACHE, STATIC_CACHE) if to == "static" else (STATIC_CACHE, FINAL_CACHE)
            mod.filepath = mod.filepath.replace(a, b)
            n += 1
        if not n:
            self.report({"ERROR"}, "jiggle: nothing baked on this character yet")
            return {"CANCELLED"}
        s.showing = to
        return {"FINISHED"}


class JIGGLE_OT_open_report(bpy.types.Operator):
    """Open the bake's report (`jiggle compare` writes it the first time)"""
    bl_idname = "jiggle.open_report"
    bl_label = "Open report"

    def execute(self, context):
        import webbrowser
        out = bpy.path.abspath(context.scene.jiggle.out_dir)
        report = os.path.join(out, "report.html")
        if not os.path.isfile(report):
            cmd = jiggle_command(context)
            if cmd is None or not os.path.isfile(os.path.join(out, "bake.npz")):
                self.report({"ERROR"}, "jiggle: no bake to report on (bake first)")
                return {"CANCELLED"}
            r = subprocess.run([cmd, "-q", "compare", "--no-video", out], capture_output=True, text=True)
            if r.returncode != 0:
                self.report({"ERROR"}, (r.stderr.strip().splitlines() or ["jiggle compare failed"])[-1])
                return {"CANCELLED"}
        webbrowser.open("file://" + report)
        return {"FINISHED"}


CLASSES = (JigglePreferences, JiggleSettings, JIGGLE_PT_panel, JIGGLE_OT_bake, JIGGLE_OT_compare,
           JIGGLE_OT_open_report)


def register():
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.Scene.jiggle = PointerProperty(type=JiggleSettings)


def unregister():
    del bpy.types.Scene.jiggle
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
