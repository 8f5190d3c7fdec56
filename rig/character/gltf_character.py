"""A skinned character from a glTF 2.0 file (.glb / .gltf), read with pygltflib (trimesh drops skins).

Every mesh primitive skinned by the chosen skin (any number of nodes, meshes and primitives) is
merged into one skin with consistent indices; vertices are never merged, so UV seams stay split as
the file has them. Mesh nodes that hang rigidly under a joint of the skin (a prop, an eye) join the
skin bound to that joint with weight 1. Other meshes are left out with a notice.

Readings (see rig.motion.gltf_io for axes, joints and rigid frames):
- Rest skin: each skinned primitive's POSITION placed by the skeleton's skin placement
  (`CharacterSkeleton.mesh_world`, M; rig.motion.gltf_skeleton says how it is found): Z-up metres,
  the bind pose. The skinned mesh node's own transform is ignored, as the spec says; the scale of an
  armature above the skeleton (0.01 in a centimetre export) is folded in, so the skin comes out in
  metres. Bind matrices are `CharacterSkeleton.bind_matrices`, so `Character.pose` with the joints'
  rigid world transforms is the spec's skinning (sum_k w_k * G_k @ IBM_k @ v, turned Z-up).
- Parts: ``meta["parts"]`` lists every merged primitive as ``[name, first vertex, vertex count]``
  (JSON-able, in vertex order): the name is the node's (unique, rig.motion.gltf_io), with
  ``.<primitive index>`` added when its mesh has several primitives. ``meta["unit_scale"]`` is the
  extra unit applied on top (1 for a file in metres, as the spec says). ``meta["spring_bones"]``: the VRM
  spring bones (VRMC_springBone or VRM 0.x) as chains of the character's joints, in metres and Z-up
  (rig.character.vrm_springs), when the file defines any.
- Weights: JOINTS_n / WEIGHTS_n sets 0, 1, ... concatenated, checked, then the top k kept and
  renormalised (see rig.character.character.clean_weights for what is an error and what a warning).
- Triangles: modes 4 (triangles), 5 (strip) and 6 (fan); points and lines are skipped with a notice.
"""
from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.character.character import (
    Character,
    check_height,
    clean_weights,
    drop_degenerate_faces,
    require_finite_positions,
    resolve_unit,
)
from jiggle.rig.character.vrm_springs import read_vrm_springs
from jiggle.rig.motion.gltf_io import Z_UP, GltfDocument, trs_matrix, world_chain
from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton


def gltf_has_skin(path: str | os.PathLike) -> bool:
    """True when the glTF file has at least one skin used by a mesh node."""
    doc = GltfDocument(path)
    return any(nd.skin is not None and nd.mesh is not None for nd in doc.gltf.nodes)


def triangles(mode: int, indices: np.ndarray) -> np.ndarray:
    """(F, 3) triangles from a primitive's index list (n,) for glTF modes 4, 5, 6."""
    n = len(indices)
    if mode == 4:
        return indices[: n - n % 3].reshape(-1, 3)
    if mode == 5:  # strip: odd triangles flip to keep the winding
        i = np.arange(max(n - 2, 0))
        even = i % 2 == 0
        a = np.where(even, indices[i], indices[i + 1])
        b = np.where(even, indices[i + 1], indices[i])
        return np.stack([a, b, indices[i + 2]], 1)
    if mode == 6:
        i = np.arange(1, max(n - 1, 1))
        return np.stack([np.full(len(i), indices[0]), indices[i], indices[i + 1]], 1) if n >= 3 else \
            np.zeros((0, 3), indices.dtype)
    return np.zeros((0, 3), indices.dtype)


def _node_world(doc: GltfDocument, i: int) -> np.ndarray:
    chain = ([i] + doc.ancestors(i))[::-1]
    loc = {}
    for k in chain:
        t, r, s, m = doc.node_trs(k)
        loc[k] = m if m is not None else trs_matrix(t, r, s)
    return Z_UP @ world_chain(chain, loc)


def _rigid_place(doc: GltfDocument, skel, t: int, i: int) -> np.ndarray:
    """Rest placement of mesh node `i` hanging under tree joint `t`: the joint's bind matrix times its
    scale c and the node transforms from the joint down to `i`, so that posing the joint rigidly moves
    it as the spec's node hierarchy does (exact also when the bind pose is not the rest pose)."""
    chain = []
    k = i
    while k != int(skel.nodes[t]):
        chain.append(k)
        k = int(doc.node_parent[k])
    loc = {}
    for k in chain:
        tt, r, sc, m = doc.node_trs(k)
        loc[k] = m if m is not None else trs_matrix(tt, r, sc)
    c = np.diag([skel.joint_scale[t]] * 3 + [1.0])
    return skel.bind_matrices[t] @ c @ world_chain(chain[::-1], loc)


def _placed_meshes(doc: GltfDocument, skel, skin: int) -> tuple[list, list[str]]:
    """The mesh nodes of skin `skin`'s character: ([(node, placement (4, 4), rigid tree joint or None)], names
    of the meshes left out). A node the skin deforms is placed by glTF's skinning rule (skel.mesh_world: its
    own transform ignored, the nodes above the skeleton's root included); a mesh hanging under a joint of
    the tree rides it rigidly; any other mesh is left out."""
    g = doc.gltf
    node_to_tree = {int(n): t for t, n in enumerate(skel.nodes)}
    placed, skipped, used_meshes = [], [], set()
    for ni, nd in enumerate(g.nodes):
        if nd.mesh is None or not 0 <= nd.mesh < len(g.meshes):
            continue
        if nd.skin == skin:
            if nd.mesh in used_meshes:
                continue  # the same mesh skinned twice by one skin lands in the same place
            used_meshes.add(nd.mesh)
            placed.append((ni, skel.mesh_world, None))
            continue
        rigid_joint = next((node_to_tree[a] for a in doc.ancestors(ni) if a in node_to_tree), None)
        if nd.skin is not None or rigid_joint is None:
            skipped.append(g.meshes[nd.mesh].name or f"mesh{nd.mesh}")
            continue
        placed.append((ni, _rigid_place(doc, skel, rigid_joint, ni), rigid_joint))
    return placed, skipped


def skin_points(path: str | os.PathLike, skin: int = 0) -> np.ndarray:
    """(V, 3) float64: the rest positions of skin `skin`'s character as :func:`read_gltf_character` places
    them (Z-up, the file's units read as metres, before any --unit): what `jiggle inspect` measures, so
    that inspect and the bake read one file one way."""
    skel = read_gltf_skeleton(path, skin)
    doc = GltfDocument(path)
    out = []
    for ni, place, _ in _placed_meshes(doc, skel, skin)[0]:
        mesh = doc.gltf.meshes[doc.gltf.nodes[ni].mesh]
        for pi, prim in enumerate(mesh.primitives):
            if (4 if prim.mode is None else prim.mode) not in (4, 5, 6) or getattr(prim.attributes, "POSITION", None) is None:
                continue
            v = doc.accessor(prim.attributes.POSITION, f"meshes[{doc.gltf.nodes[ni].mesh}].primitives[{pi}].attributes.POSITION")
            out.append(v[:, :3] @ place[:3, :3].T + place[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


def _influence_sets(attrs) -> list[tuple[int, int]]:
    """(JOINTS_n, WEIGHTS_n) accessor pairs of a primitive, n = 0, 1, ..."""
    out, n = [], 0
    while True:
        j = getattr(attrs, f"JOINTS_{n}", None)
        w = getattr(attrs, f"WEIGHTS_{n}", None)
        if j is None and w is None:
            return out
        if j is None or w is None:
            return out + [(j, w)]
        out.append((j, w))
        n += 1


def read_gltf_character(path: str | os.PathLike, skin: int = 0, k: int = 4,
                        unit: str | float | None = None, jiggle_attribute: str | None = None) -> Character:
    """Read skin number `skin` of a glTF/GLB file and every mesh it deforms as a Character.

    Painted maps (rig.character.painted_maps) come with it, in ``Character.maps``: the jiggle map from
    each primitive's `jiggle_attribute` (default ``_JIGGLE``; or a vertex colour's channel, "COLOR_0.r"),
    influence maps from its ``_SHELL_<MUSCLE>`` attributes; None when no primitive has any.
    ``meta["primitives"]`` lists ``[mesh, primitive, first vertex, count]`` of every merged primitive,
    in vertex order (what rig.character.gltf_maps writes the maps back to).

    k : influences kept per vertex (top k by weight, renormalised).
    unit : metres per file unit when the file is not in metres as the spec says (see
        rig.character.character.unit_scale); None or "auto": metres unless the height is implausible
        and centimetres or millimetres make it plausible (rig.character.character.resolve_unit).
    """
    skel = read_gltf_skeleton(path, skin)
    doc = GltfDocument(path)
    p = doc.path
    tree_of_skin = _tree_of_skin(doc, skel, skin)
    from jiggle.rig.character.painted_maps import assemble, parse_jiggle_attribute
    jiggle_attribute = parse_jiggle_attribute(jiggle_attribute)
    placed, skipped = _placed_meshes(doc, skel, skin)
    merged = _Merge(doc, tree_of_skin, skin, jiggle_attribute, skipped)
    for ni, place, rigid_joint in placed:
        for pi, prim in enumerate(doc.gltf.meshes[doc.gltf.nodes[ni].mesh].primitives):
            merged.add(ni, pi, prim, place, rigid_joint)
    if not merged.pos:
        raise InputError(f"skin {skin} deforms no triangle mesh", p, field=f"skins[{skin}]")
    if merged.skipped:
        warnings.warn(f"{p}: left out of the character: {', '.join(merged.skipped)}", JiggleWarning, stacklevel=2)

    vertices = np.concatenate(merged.pos)
    s = resolve_unit(unit, float(np.ptp(vertices[:, 2])), p)
    vertices = vertices * s
    raw_j, raw_w = merged.influences()
    faces = drop_degenerate_faces(vertices, np.concatenate(merged.faces), p)
    bind_world, bind_m = _scaled_binds(skel, s)
    joints, weights = clean_weights(raw_j, raw_w, skel.num_joints, vertices, bind_world[:, :3, 3], k, p,
                                    "JOINTS/WEIGHTS")
    normals = _unit_normals(merged.nrm if merged.has_normals else None, vertices, faces)
    springs = read_vrm_springs(p, skel.joint_names, s, doc=doc)
    character = Character(
        vertices=vertices, faces=faces, normals=normals,
        uvs=np.concatenate(merged.uv) if merged.has_uvs and merged.uv else None,
        joint_names=skel.joint_names, parents=skel.parents, bind_world=bind_world, bind_matrices=bind_m,
        joints=joints, weights=weights, skeleton=skel.to_clip().scaled(s), name=skel.name, source=p,
        meta={"weights": "file", "unit_scale": s, "skin": skel.meta.get("skin", skin), "parts": merged.parts,
              "primitives": merged.prims, **({"spring_bones": springs} if springs else {})},
        maps=assemble(merged.maps, len(vertices), os.path.basename(p)))
    check_height(character.height, p)
    return character


def _scaled_binds(skel, s: float) -> tuple[np.ndarray, np.ndarray]:
    """The skeleton's bind world transforms and bind matrices (J, 4, 4), translations scaled by `s` (the
    file unit in metres)."""
    bind_world = skel.bind_world.copy()
    bind_world[:, :3, 3] *= s
    bind_m = np.array(skel.bind_matrices)
    bind_m[:, :3, 3] *= s
    return bind_world, bind_m


def _tree_of_skin(doc: GltfDocument, skel, skin: int) -> np.ndarray:
    """(skin joints,) int64: the tree joint of each joint of skin `skin`, -1 where the tree has none."""
    tree_of_skin = np.full(len(doc.gltf.skins[skin].joints), -1, np.int64)
    for t, sj in enumerate(skel.skin_joint):
        if sj >= 0:
            tree_of_skin[sj] = t
    return tree_of_skin


@dataclass
class _Merge:
    """The triangle primitives of a skin's character merged one by one into one skin, in vertex order.

    Per primitive: `pos` (n, 3) placed positions in file units; `nrm` (n, 3) placed normals (not unit);
    `uv` (n, 2); `faces` (f, 3) int64 into the merged vertices; `jnt` (n, w) int64 tree joints (-1 for
    an out-of-range index of weight 0) and `wgt` (n, w) their weights; `parts`, `prims`, `maps` as
    the Character's meta and painted maps read them. `skipped`: what is left out, for the notice.
    """
    doc: GltfDocument
    tree_of_skin: np.ndarray
    skin: int
    jiggle_attribute: str
    skipped: list
    pos: list = field(default_factory=list)
    nrm: list = field(default_factory=list)
    uv: list = field(default_factory=list)
    faces: list = field(default_factory=list)
    jnt: list = field(default_factory=list)
    wgt: list = field(default_factory=list)
    parts: list = field(default_factory=list)
    prims: list = field(default_factory=list)
    maps: list = field(default_factory=list)
    has_normals: bool = True
    has_uvs: bool = True
    offset: int = 0

    def add(self, ni: int, pi: int, prim, place: np.ndarray, rigid_joint: int | None) -> None:
        """Merge primitive `pi` of mesh node `ni`, placed by `place` (4, 4), bound with weight 1 to tree
        joint `rigid_joint` or, when None, by its own JOINTS_n / WEIGHTS_n; points and lines are skipped."""
        from jiggle.rig.character.painted_maps import primitive_maps
        doc, g = self.doc, self.doc.gltf
        nd = g.nodes[ni]
        what = f"meshes[{nd.mesh}].primitives[{pi}]"
        mode = 4 if prim.mode is None else prim.mode
        if mode not in (4, 5, 6):
            self.skipped.append(f"{what} (mode {mode}, not triangles)")
            return
        a = prim.attributes
        v, idx = _primitive_geometry(doc, prim, what)
        nv, offset = len(v), self.offset
        self.pos.append(v @ place[:3, :3].T + place[:3, 3])
        if getattr(a, "NORMAL", None) is not None:
            self.nrm.append(doc.accessor(a.NORMAL, f"{what}.attributes.NORMAL") @ place[:3, :3].T)
        else:
            self.has_normals = False
        if getattr(a, "TEXCOORD_0", None) is not None:
            self.uv.append(doc.accessor(a.TEXCOORD_0, f"{what}.attributes.TEXCOORD_0")[:, :2])
        else:
            self.has_uvs = False
        self.faces.append(triangles(mode, idx) + offset)
        several = len(g.meshes[nd.mesh].primitives) > 1
        self.parts.append([doc.node_names[ni] + (f".{pi}" if several else ""), int(offset), int(nv)])
        self.prims.append([int(nd.mesh), int(pi), int(offset), int(nv)])
        self.maps.append((int(offset), int(nv), primitive_maps(doc, a, nv, what, self.jiggle_attribute)))
        if rigid_joint is not None:
            self.jnt.append(np.full((nv, 1), rigid_joint))
            self.wgt.append(np.ones((nv, 1)))
        else:
            jv, wv = _skin_influences(doc, a, nv, what, self.tree_of_skin, self.skin)
            self.jnt.append(jv)
            self.wgt.append(wv)
        self.offset += nv

    def influences(self) -> tuple[np.ndarray, np.ndarray]:
        """(V, w) int64 joints and (V, w) weights of every merged vertex, padded with joint 0 and weight 0
        to the widest primitive's w."""
        width = max(w.shape[1] for w in self.wgt)
        pad = lambda a, fill: np.pad(a, ((0, 0), (0, width - a.shape[1])), constant_values=fill)  # noqa: E731
        raw_j = np.concatenate([pad(a, 0) for a in self.jnt])
        raw_w = np.concatenate([pad(a, 0.0) for a in self.wgt])
        return raw_j, raw_w


def _primitive_geometry(doc: GltfDocument, prim, what: str) -> tuple[np.ndarray, np.ndarray]:
    """A triangle primitive's checked POSITION (n, 3), file units, and index list (m,) int64 into it."""
    p = doc.path
    a = prim.attributes
    if getattr(a, "POSITION", None) is None:
        raise InputError("a primitive without POSITION", p, field=f"{what}.attributes")
    v = doc.accessor(a.POSITION, f"{what}.attributes.POSITION")
    if v.shape[1] != 3:
        raise InputError(f"POSITION must be VEC3, found {v.shape[1]} components", p,
                         field=f"{what}.attributes.POSITION")
    require_finite_positions(v, p, f"{what}.attributes.POSITION")
    nv = len(v)
    idx = doc.accessor(prim.indices, f"{what}.indices")[:, 0].astype(np.int64) \
        if prim.indices is not None else np.arange(nv)
    if len(idx) and (idx.min() < 0 or idx.max() >= nv):
        raise InputError(f"index {int(idx.max())} is past the primitive's {nv} vertices", p,
                         field=f"{what}.indices")
    return v, idx


def _skin_influences(doc: GltfDocument, a, nv: int, what: str, tree_of_skin: np.ndarray,
                     skin: int) -> tuple[np.ndarray, np.ndarray]:
    """A skinned primitive's JOINTS_n / WEIGHTS_n sets side by side, checked: (nv, w) int64 tree joints
    (-1 where an index out of the skin's range carries weight 0) and (nv, w) weights."""
    p = doc.path
    sets = _influence_sets(a)
    if not sets:
        raise InputError("a primitive of the skinned mesh has no JOINTS_0/WEIGHTS_0", p,
                         field=f"{what}.attributes")
    js, ws = [], []
    for n, (ja, wa) in enumerate(sets):
        if ja is None or wa is None:
            raise InputError(f"JOINTS_{n} and WEIGHTS_{n} must come together", p,
                             field=f"{what}.attributes")
        jv = doc.accessor(ja, f"{what}.attributes.JOINTS_{n}")
        wv = doc.accessor(wa, f"{what}.attributes.WEIGHTS_{n}")
        if len(jv) != nv or len(wv) != nv or jv.shape[1] != wv.shape[1]:
            raise InputError(f"JOINTS_{n}/WEIGHTS_{n} do not match POSITION ({nv} vertices)", p,
                             field=f"{what}.attributes")
        js.append(jv)
        ws.append(wv)
    jv = np.concatenate(js, 1).astype(np.int64)
    bad = (jv < 0) | (jv >= len(tree_of_skin))
    live = np.concatenate(ws, 1) > 0
    if np.any(bad & live):
        vtx, c = np.argwhere(bad & live)[0]
        raise InputError(f"joint index {int(jv[vtx, c])} at vertex {int(vtx)} is out of range: skin "
                         f"{skin} has {len(tree_of_skin)} joints (0..{len(tree_of_skin) - 1})", p,
                         field=f"{what}.attributes.JOINTS")
    return np.where(bad, -1, tree_of_skin[np.clip(jv, 0, len(tree_of_skin) - 1)]), np.concatenate(ws, 1)


def _unit_normals(nrm: list | None, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit normals: the file's (`nrm`, per primitive) normalised, the mesh's own where a file
    normal is zero or where the file has none (`nrm` None)."""
    if nrm is not None:
        normals = np.concatenate(nrm)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.where(length > 1e-12, normals / np.maximum(length, 1e-12), 0.0)
        if np.any(length[:, 0] <= 1e-12):
            from jiggle.rig.character.normals import vertex_normals
            normals = np.where(length > 1e-12, normals, vertex_normals(vertices, faces))
    else:
        from jiggle.rig.character.normals import vertex_normals
        normals = vertex_normals(vertices, faces)
    return normals
