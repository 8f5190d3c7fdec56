"""`jiggle inspect`: what a file holds, as a dict (for --json) and as text."""
from __future__ import annotations

import os

import numpy as np

from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.motion.clip import Clip

MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".off")


def describe_clip(clip: Clip) -> dict:
    """Joints, frames, fps, duration, units, T-pose and extents of a clip."""
    _, rest = clip.rest_world()
    ends = clip.end_world(clip.rest_rotations[None], rest[None]) if len(clip.end_parents) else np.zeros((1, 0, 3))
    pts = np.concatenate([rest, ends[0]])
    root = clip.root_translation
    return {
        "kind": "clip", "name": clip.name, "format": clip.meta.get("format", ""),
        "joints": clip.num_joints, "joint_names": list(clip.joint_names), "end_sites": int(len(clip.end_parents)),
        "frames": clip.num_frames, "fps": clip.fps, "duration_s": round(clip.duration, 6),
        "units": clip.meta.get("units", "metres"), "tpose": clip.meta.get("tpose", "n/a"),
        "rest_height_m": round(float(np.ptp(pts[:, 2])), 4),
        "root_travel_m": round(float(np.linalg.norm(root[-1, :2] - root[0, :2])), 4),
        "root_height_range_m": [round(float(root[:, 2].min()), 4), round(float(root[:, 2].max()), 4)],
        "body_plan": body_plan(clip),
        "meta": {k: v for k, v in clip.meta.items() if k not in ("units", "tpose", "format")},
    }


def _body_clip(path: str) -> Clip:
    """The skeleton a glTF character's body plan is read from, as the fit reads it (rig.character.body_skeleton:
    helper bones off a weightless root set aside); the file's skeleton when the character cannot be read."""
    import warnings

    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.rig.character.body_skeleton import body_skeleton
    from jiggle.rig.character.gltf_character import read_gltf_character
    from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", JiggleWarning)
            return body_skeleton(read_gltf_character(path))[0]
    except InputError:
        return read_gltf_skeleton(path).to_clip()


def body_plan(clip: Clip) -> dict:
    """The skeleton's body plan (rig.motion.body_plan) and the template `--template auto` picks for it."""
    from jiggle.rig.motion.body_plan import detect_body_plan
    plan = detect_body_plan(clip)
    return {**plan.to_json(), "template": plan.template or "generic (tissue from the skin's segmentation by bone)"}


def tissue_plan(path: str) -> dict:
    """The template a bake with the defaults gives the character in `path` and why (rig.muscle.fit.choose_template),
    and the size it is simulated at when its file's size contradicts that template
    (rig.character.character.template_scale)."""
    import warnings

    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.rig.character.character import TEMPLATE_HEIGHT_M, template_scale
    from jiggle.rig.character.load import load_character
    from jiggle.rig.muscle.fit import choose_template
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        character = load_character(path)
        choice = choose_template(character)
    name = "generic" if choice.template is None else choice.template.name
    out = {"template": name, "why": choice.why}
    height = float(np.ptp(np.asarray(character.vertices)[:, 2]))
    k = template_scale(name, height)
    if k != 1.0:
        nominal, lo, hi = TEMPLATE_HEIGHT_M[name]
        out["size"] = (f"{height:.3g} m tall as read, outside the {name} template's {lo:g}-{hi:g} m: simulated at "
                       f"{nominal:g} m and the result scaled back to the file's size (--unit sets the file's unit "
                       f"instead)")
        character = character.scaled(k)
    out["real_size"] = _real_size(path, character)
    return out


def _real_size(path: str, character) -> str:
    """The real size a bake infers for the character (rig.character.real_size: its own walk cycle's period, else the
    file's unit), for its materials; --height overrides it."""
    from jiggle.rig.character.real_size import is_walk, real_size
    walk = None
    if str(path).lower().endswith((".glb", ".gltf")):
        from jiggle.rig.motion.gltf_io import GltfDocument
        from jiggle.rig.motion.mocap import load_clip
        names = [a.name or f"animation{k}" for k, a in enumerate(GltfDocument(path).gltf.animations)]
        k = next((k for k, n in enumerate(names) if is_walk(n)), None)
        if k is not None:
            walk = (names[k], float(load_clip(path, animation=k).duration))
    return real_size(character, None, walk).why + " (--height overrides it)"


def rigid_parts(path: str) -> dict:
    """The gear and hard shells a bake with the defaults keeps rigid (rig.character.gear.find_rigid): what,
    on which joints and why, and how --rigid overrides it."""
    import warnings

    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.rig.character.gear import find_rigid
    from jiggle.rig.character.load import load_character
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        r = find_rigid(load_character(path))
    if not r.any:
        return {"parts": "none: all the skin is tissue (--rigid NAME[,NAME] makes parts or joints rigid)"}
    out = {"vertices": f"{r.count} of {len(r.mask)}, {r.pieces} piece(s), following their bones without jiggle",
           "parts": list(r.parts) or "none wholly"}
    if r.partly:
        out["partly"] = {k: f"{v:.0%}" for k, v in r.partly.items()}
    out["joints"] = list(r.joints)
    out["why"] = ", ".join(f"{k}: {v} vertices" for k, v in r.why.items())
    out.update(_rule_lines(r))
    out["override"] = "--rigid none, --rigid=-NAME (a part or joint left soft), --rigid NAME (made rigid)"
    return out


def _rule_lines(r) -> dict:
    """inspect's "rules" (the rule that decided each rigidly bound or named piece, rig.character.gear.find_rigid:
    hard or flesh, how many pieces and vertices, which parts) and "flesh" (rigidly bound vertices left soft)."""
    out = {}
    if r.decided:
        out["rules"] = {f"{'hard' if g['hard'] else 'flesh'}, {g['rule']}":
                        f"{g['pieces']} piece(s), {g['vertices']} vertices ({', '.join(g['parts'][:6])}"
                        f"{' ...' if len(g['parts']) > 6 else ''})" for g in r.by_rule()}
    if r.soft:
        out["flesh"] = ", ".join(f"{k}: {v} vertices" for k, v in r.soft.items())
    return out


def simulated_muscles(path: str) -> dict:
    """Which muscles a bake with the defaults simulates: those none of whose skin is soft (every vertex they move is
    gear or a hard shell, rig.skin.muscle_skin.MuscleSkin.idle) drive nothing and are not simulated, nor counted
    in the near-reach and hard-stop figures."""
    import warnings

    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.rig.character.load import load_character
    from jiggle.rig.muscle.fit import fit_musculature
    from jiggle.rig.skin.muscle_skin import MuscleSkin
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        mus = fit_musculature(load_character(path), "auto")
        skin = MuscleSkin.from_musculature(mus, character_path=path)
    M, idle = mus.rig.M, np.asarray(skin.idle, bool)
    names = [mus.rig.names[m] for m in np.nonzero(idle)[0]]
    if not idle.any():
        return {"simulated": f"all {M} muscles"}
    if idle.all():
        return {"simulated": f"none: every one of the {M} muscles drives only hard skin (gear, plates, shards), so "
                             "nothing is simulated and no muscle nears its reach"}
    return {"simulated": f"{M - len(names)} of {M} muscles",
            "not_simulated": f"{len(names)}, none of whose skin is soft: {', '.join(names[:12])}"
                             f"{' ...' if len(names) > 12 else ''}"}


def chain_plan(path: str) -> dict:
    """The chains a bake with the defaults swings (rig.character.chains.find_chains over the tissue the default fit
    gives): each with its joints, why it was taken and its default parameters (sim.chain.params), and how --chains
    overrides it."""
    import warnings

    from jiggle.rig.base.errors import JiggleWarning
    from jiggle.rig.character.chains import chain_links, find_chains
    from jiggle.rig.character.load import load_character
    from jiggle.rig.muscle.fit import fit_musculature
    from jiggle.sim.bake.setup import tissue_joints
    from jiggle.sim.chain.params import chain_params
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JiggleWarning)
        character = load_character(path)
        mus = fit_musculature(character, "auto")
    found = find_chains(character, tissue_joints(mus.rig), set((mus.roles or {}).values()), "auto",
                        character.meta.get("spring_bones") or None)
    override = "--chains none, --chains=-NAME (a chain left on its bones), --chains NAME[,NAME] (joints that start one)"
    if not len(found):
        return {"chains": "none: every appendage follows its bones", "override": override}
    links = chain_links(character, found)
    size = float(np.ptp(np.asarray(character.vertices), axis=0).max())
    params = chain_params(found.names, links.length, size)
    rows = []
    for i, (c, p) in enumerate(zip(found.chains, params)):
        rows.append({"chain": c.name, "joints": [character.joint_names[j] for j in c.joints], "why": c.reason,
                     "length_m": round(float(links.length[i]), 4), "stiffness_hz": round(float(p.stiffness), 3),
                     "damping": p.damping})
    return {"chains": rows, "override": override}


def unit_note(height: float) -> dict:
    """What `--unit auto` makes of a character `height` file units tall (read as metres)."""
    from jiggle.rig.character.character import PLAUSIBLE_HEIGHT_M, UNIT_NAMES, UNITS, guess_unit
    unit = guess_unit(height)
    lo, hi = PLAUSIBLE_HEIGHT_M
    if unit is not None:
        return {"unit": f"probably {UNIT_NAMES[unit]}: {height:.4g} m is outside the plausible {lo:g}-{hi:g} m, "
                        f"{height * UNITS[unit]:.4g} m in {UNIT_NAMES[unit]}; --unit auto (the default) reads it so, "
                        f"--unit {unit} says it, --unit m keeps metres"}
    if lo <= height <= hi:
        return {"unit": "metres (the height is plausible)"}
    return {"unit": f"unknown: {height:.4g} m is outside the plausible {lo:g}-{hi:g} m in any usual unit; "
                    f"pass --unit with the file's metres per unit"}


def describe_mesh(path: str) -> dict:
    from jiggle.rig.character.mesh_io import read_trimesh
    v, f, _ = read_trimesh(path)
    return {"kind": "character", "format": os.path.splitext(path)[1][1:].upper(), "vertices": int(len(v)),
            "faces": int(len(f)), "joints": 0, "skins": 0, "animations": [],
            "bounds_m": v.min(0).round(4).tolist() + v.max(0).round(4).tolist() if len(v) else [],
            "note": "no skin: 'jiggle play CLIP --character FILE' computes automatic weights from the clip's "
                    "skeleton (bone heat); --unit and --up say the file's unit and up axis"}


def describe_mjcf(path: str) -> dict:
    import mujoco
    try:
        m = mujoco.MjModel.from_xml_path(path)
    except Exception as e:  # MuJoCo reports XML and schema errors as ValueError with the line
        raise InputError(f"not a loadable MJCF model: {e}", path) from None
    jt = {0: "free", 1: "ball", 2: "slide", 3: "hinge"}
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(m.njnt)]
    kinds = [jt[int(t)] for t in m.jnt_type]
    return {"kind": "mjcf", "bodies": int(m.nbody - 1), "joints": int(m.njnt), "nq": int(m.nq), "nv": int(m.nv),
            "joint_types": {k: kinds.count(k) for k in sorted(set(kinds))}, "joint_names": names,
            "total_mass_kg": round(float(np.sum(m.body_mass)), 3)}


def inspect_file(path: str, *, skeleton=None, animation=None, scale=None, tpose="auto") -> dict:
    """A description of any file jiggle reads: clip, character, or MJCF."""
    from jiggle.rig.motion.mocap import load_clip
    p = require_file(path)
    ext = os.path.splitext(p)[1].lower()
    if ext in (".bvh", ".amc", ".asf"):
        out = describe_clip(load_clip(p, skeleton=skeleton, scale=scale, tpose=tpose))
    elif ext in (".glb", ".gltf"):
        from jiggle.rig.motion.gltf_skeleton import describe_gltf
        out = {"kind": "character", **describe_gltf(p)}
        if out.get("skins"):
            # the character as the bake reads it: skin 0 posed by glTF's skinning rule at its bind pose
            from jiggle.rig.character.gltf_character import skin_points
            pts = skin_points(p, 0)
            if len(pts):
                out["height_m"] = round(float(np.ptp(pts[:, 2])), 4)
                out["bounds_m"] = (pts.min(0).round(4) + 0.0).tolist() + (pts.max(0).round(4) + 0.0).tolist()
                out["height_from"] = "skin 0 at its bind pose, by glTF's skinning rule (as bake reads it)"
        if "height_m" in out:
            out.update(unit_note(out["height_m"]))
        if out.get("skins"):
            out["body_plan"] = body_plan(_body_clip(p))
            try:        # a skeleton with a skin but no mesh (an FBX take) has neither
                out["tissue"] = tissue_plan(p)
                out["rigid"] = rigid_parts(p)
                if isinstance(out["rigid"], dict) and "vertices" in out["rigid"]:    # gear: which muscles still work
                    out["rigid"].update(simulated_muscles(p))
                out["chains"] = chain_plan(p)
            except InputError as e:
                out["tissue"] = {"template": None, "why": f"no tissue: {e.message}"}
        if out.get("animations"):
            out["clip"] = describe_clip(load_clip(p, animation=animation))
            if "body_plan" in out:      # the animation moves the character's own skeleton: its body, as read above
                out["clip"]["body_plan"] = out["body_plan"]
    elif ext == ".fbx":
        from jiggle.rig.motion.fbx import fbx_to_gltf, fbx_version
        kind, version = fbx_version(p)
        glb = fbx_to_gltf(p)
        try:
            read = inspect_file(glb, animation=animation)
        except InputError as e:
            raise InputError(f"{e.message} (read through Blender's importer)", p, field=e.field) from None
        out = {**read, "format": f"FBX {version / 1000:.1f} {kind} (read through Blender's importer, as glTF: "
                                 f"{glb})"}
        out.pop("file", None)
        if not out.get("vertices") and isinstance(out.get("clip"), dict):    # a skeleton with a take: a clip
            out = {**out["clip"], "format": out["format"]}
    elif ext in MESH_EXTENSIONS:
        out = describe_mesh(p)
    elif ext == ".xml":
        out = describe_mjcf(p)
    else:
        raise InputError(f"unknown file type {ext or '(no extension)'!r}; expected a clip (.bvh .amc .asf .glb "
                         f".gltf .fbx), a character (.glb .gltf .fbx .obj .ply .stl) or an MJCF (.xml)", p)
    return {"file": p, **out}


def format_report(report: dict, indent: str = "") -> str:
    """Readable text for an inspect report."""
    lines = []
    for k, v in report.items():
        if isinstance(v, dict) and v:
            lines.append(f"{indent}{k}:")
            lines.append(format_report(v, indent + "  "))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            lines.append(f"{indent}{k}:")
            for item in v:
                lines.append(f"{indent}  - " + ", ".join(f"{a}={b}" for a, b in item.items()))
        elif isinstance(v, list) and len(v) > 8 and all(isinstance(x, str) for x in v):
            lines.append(f"{indent}{k}: {', '.join(v)}")
        else:
            lines.append(f"{indent}{k}: {v}")
    return "\n".join(lines)
