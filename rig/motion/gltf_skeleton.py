"""A character's skeleton from a skinned glTF 2.0 file (.glb or .gltf), and `describe_gltf`.

The file is read with :mod:`rig.motion.gltf_io`, whose docstring states the readings of axes, joints
and rigid frames. One more, for the bind pose:

- Skinning, as the spec says: a vertex v of the skinned mesh goes to
  ``sum_k w_k * G_k(t) @ IBM_k @ v`` with G_k the joint's global transform through every node above
  it (joints or not: an armature's scale and rotation count) and IBM_k its inverse bind matrix; the
  transform of the skinned mesh's own node is ignored (spec 3.7.3.3).
- Rigid joints: every joint and every node above it must scale uniformly and positively
  (rig.motion.gltf_io.check_uniform_scale), so ``Z_UP @ G_k = W_k @ c_k`` with W_k rigid (the joint's
  world, metres) and c_k the joint's accumulated uniform scale (0.01 under a centimetre armature).
- Placement of the skin (`mesh_world`, M): the mesh space of the vertices is put in the world where
  the skin stands when the skeleton is at its rest pose (node TRS): M = Z_UP @ G_r(rest) @ IBM_r for
  the first skin joint r in tree order (the root joint). For a file bound in its rest pose (as
  exporters write) every joint gives the same M, and the placement of the mesh node does not matter.
  When that M is not a rotation times a uniform scale (inverse bind matrices that scale or shear
  against the nodes, as jiggle writes for such a character), the world transform of the first node
  using the skin is taken instead; so it is when the two agree within 1e-6 (the same placement,
  without the rounding of the float32 inverse bind matrix). A joint scale within SCALE_RTOL of 1
  (float32 noise) counts as 1.
- Bind matrices: ``B_k = M @ inverse(IBM_k) / c_k`` (the 3x3 part divided by c_k), so that
  ``W_k(t) @ inverse(B_k) @ (M @ v) = Z_UP @ G_k(t) @ IBM_k @ v``: posing the rest skin ``M @ v`` with
  rigid joint transforms is the spec's skinning. The joints' bind world transforms are the rigid
  parts of B_k (exact when the file is consistent, as every exporter writes it). Nodes added to close
  the tree (not in the skin) take their rest world transform as bind.
- Scale must not be animated: c_k is read in the rest pose (rig.motion.gltf_anim warns when an
  animation changes it).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.motion import quat
from jiggle.rig.motion.clip import Clip, joint_index, local_from_world
from jiggle.rig.motion.gltf_io import (
    SCALE_RTOL,
    Z_UP,
    GltfDocument,
    check_uniform_scale,
    joint_tree,
    polar_rotation,
    rigid_locals,
    scale_problem,
    trs_matrix,
    world_chain,
)


# ---------------------------------------------------------------------------------- the skeleton
@dataclass(frozen=True, eq=False)
class CharacterSkeleton:
    """A skinned character's joint tree and bind pose (Z-up, metres). Arrays are read-only.

    Attributes
    ----------
    joint_names : (J,) node names (see the module docstring for unnamed or repeated names).
    parents : (J,) int32, parent index or -1, parents first.
    nodes : (J,) int64, glTF node index of each joint.
    skin_joint : (J,) int64, index of the joint in the skin's `joints` list, -1 for nodes added to
        close the tree.
    bind_world : (J, 4, 4) float64, rigid world transform of each joint in the bind pose (rotation
        orthonormal, position exact), metres.
    bind_rotations : (J, 4) float64 w,x,y,z, bind-pose local rotation (parent frame; world for a root).
    bind_translations : (J, 3) float64 metres, bind-pose local translation.
    rest_rotations : (J, 4) float64 w,x,y,z, local rotation from the node TRS (the file's rest pose).
    rest_translations : (J, 3) float64 metres, local translation from the node TRS (scale folded in).
    inverse_bind_matrices : (J, 4, 4) float64, as stored in the file (glTF Y-up mesh space; identity for
        added nodes), kept for skinning.
    mesh_world : (4, 4) float64, M: Z-up placement of the skin's vertex space (module docstring); the
        rest skin is ``M @ POSITION``, metres.
    bind_matrices : (J, 4, 4) float64, B_k = M @ inverse(IBM_k) / c_k (module docstring): the transform
        from each joint's space to the rest skin, metres; `bind_world` for added nodes.
    joint_scale : (J,) float64, c_k: each joint's accumulated uniform scale in the rest pose.
    name, source : file stem and path.
    meta : the skin's index and name.
    """

    joint_names: tuple[str, ...]
    parents: np.ndarray
    nodes: np.ndarray
    skin_joint: np.ndarray
    bind_world: np.ndarray
    bind_rotations: np.ndarray
    bind_translations: np.ndarray
    rest_rotations: np.ndarray
    rest_translations: np.ndarray
    inverse_bind_matrices: np.ndarray
    mesh_world: np.ndarray
    bind_matrices: np.ndarray
    joint_scale: np.ndarray
    name: str = ""
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("joint_names", tuple(self.joint_names))
        set_("parents", frozen_array(self.parents, np.int32))
        for k in ("nodes", "skin_joint"):
            set_(k, frozen_array(getattr(self, k), np.int64))
        for k in ("bind_world", "bind_rotations", "bind_translations", "rest_rotations", "rest_translations",
                  "inverse_bind_matrices", "mesh_world", "bind_matrices", "joint_scale"):
            set_(k, frozen_array(getattr(self, k)))

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def index(self, name: str) -> int:
        return joint_index(self.joint_names, name, self.source)

    @property
    def bind_positions(self) -> np.ndarray:
        """(J, 3) metres, world joint positions in the bind pose."""
        return self.bind_world[:, :3, 3]

    def to_clip(self, fps: float = 30.0) -> Clip:
        """A one-frame Clip of the bind pose (offsets and rest rotations are the bind-local transforms),
        so the character's skeleton feeds `sim.drive.skeleton.Skeleton`. `fps` only labels the frame."""
        return Clip(joint_names=self.joint_names, parents=self.parents, offsets=self.bind_translations,
                    rest_rotations=self.bind_rotations, rotations=self.bind_rotations[None],
                    translations=self.bind_translations[None], fps=fps, name=self.name, source=self.source,
                    meta={"format": "glTF skin bind pose", **self.meta})


def _mesh_world(doc: GltfDocument, skin: int) -> np.ndarray:
    users = doc.skin_users(skin)
    if not users:
        return Z_UP.copy()
    n = users[0]
    chain = ([n] + doc.ancestors(n))[::-1]
    return Z_UP @ world_chain(chain, {i: _local_matrix(doc, i) for i in chain})


def _local_matrix(doc: GltfDocument, i: int) -> np.ndarray:
    t, r, s, m = doc.node_trs(i)
    return m if m is not None else trs_matrix(t, r, s)


def read_gltf_skeleton(path: str | os.PathLike, skin: int = 0) -> CharacterSkeleton:
    """Read skin number `skin` of a glTF/GLB file: joints, bind pose and rest pose (Z-up, metres)."""
    doc = GltfDocument(path)
    g = doc.gltf
    if not g.skins:
        raise InputError(f"the file has no skin (it holds {doc.contents()}); a character needs a skinned mesh",
                         doc.path, field="skins")
    if not isinstance(skin, (int, np.integer)) or not 0 <= skin < len(g.skins):
        raise InputError(f"skin {skin!r} does not exist; the file has skins 0..{len(g.skins) - 1}", doc.path,
                         field="skin")
    sk = g.skins[skin]
    if not sk.joints:
        raise InputError("the skin lists no joints", doc.path, field=f"skins[{skin}].joints")
    for k in sk.joints:
        if not 0 <= k < len(g.nodes):
            raise InputError(f"joint {k} is not a node index", doc.path, field=f"skins[{skin}].joints")
    order, parents = joint_tree(doc, list(sk.joints))
    J = len(order)
    skin_joint = np.array([sk.joints.index(n) if n in sk.joints else -1 for n in order])
    if sk.inverseBindMatrices is not None:
        ibm_raw = doc.accessor(sk.inverseBindMatrices, f"skins[{skin}].inverseBindMatrices")
        if not np.all(np.isfinite(ibm_raw)):
            raise InputError("inverse bind matrices must be finite numbers", doc.path,
                             field=f"skins[{skin}].inverseBindMatrices")
        if ibm_raw.shape != (len(sk.joints), 16):
            raise InputError(f"expected {len(sk.joints)} MAT4 inverse bind matrices, found {ibm_raw.shape[0]} "
                             f"of {ibm_raw.shape[1]} values", doc.path, field=f"skins[{skin}].inverseBindMatrices")
        ibm_skin = ibm_raw.reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
    else:
        ibm_skin = np.broadcast_to(np.eye(4), (len(sk.joints), 4, 4))  # spec: identity when absent

    # Rigid joints: uniform positive scale on every joint and every node above the tree.
    for n in dict.fromkeys(order + [a for j, n in enumerate(order) if parents[j] < 0 for a in doc.ancestors(n)]):
        check_uniform_scale(doc, n)

    # Rest pose from the node TRS.
    trs = [doc.node_trs(n) for n in order]
    local_m = np.stack([m if m is not None else trs_matrix(t, r, s) for t, r, s, m in trs])[None]
    local_r = np.stack([r for _, r, _, _ in trs])[None]
    above = np.empty((1, J, 4, 4))
    for j, n in enumerate(order):
        chain = doc.ancestors(n)[::-1]
        above[0, j] = Z_UP @ world_chain(chain, {i: _local_matrix(doc, i) for i in chain}) \
            if parents[j] < 0 else np.eye(4)
    rest_rot, rest_tra, rest_world = rigid_locals(parents, above, local_m, local_r)
    rest_world = rest_world[0]
    scale = np.cbrt(np.linalg.det(rest_world[:, :3, :3]))  # c_k > 0 (checked above)

    # Bind pose from the inverse bind matrices.
    ibm = np.stack([ibm_skin[k] if k >= 0 else np.eye(4) for k in skin_joint])
    inv_ibm = np.empty((J, 4, 4))
    for j in range(J):
        if skin_joint[j] >= 0:
            try:
                inv_ibm[j] = np.linalg.inv(ibm[j])
            except np.linalg.LinAlgError:
                raise InputError(f"inverse bind matrix of joint {doc.node_names[order[j]]!r} is singular",
                                 doc.path, field=f"skins[{skin}].inverseBindMatrices") from None
    root = int(np.nonzero(skin_joint >= 0)[0][0])
    mesh_world = rest_world[root] @ ibm[root]
    user_world = _mesh_world(doc, skin)
    size = max(float(np.abs(mesh_world[:3, :3]).max()), 1e-12)
    if scale_problem(mesh_world[:3, :3]) is not None or np.abs(user_world - mesh_world).max() <= 1e-6 * size:
        mesh_world = user_world  # the fallback, or the same placement without the float32 IBM's rounding
    scale = np.where(np.abs(scale - 1.0) <= SCALE_RTOL, 1.0, scale)  # float32 noise (0.99999994) is 1
    unscale = np.ones((J, 4))
    unscale[:, :3] = 1.0 / scale[:, None]
    bind_full = np.empty((J, 4, 4))
    for j in range(J):
        bind_full[j] = (mesh_world @ inv_ibm[j] if skin_joint[j] >= 0 else rest_world[j]) * unscale[j]
    bind_r = polar_rotation(bind_full[:, :3, :3])
    bind_world = np.zeros((J, 4, 4))
    bind_world[:, :3, :3] = quat.to_matrix(bind_r)
    bind_world[:, :3, 3] = bind_full[:, :3, 3]
    bind_world[:, 3, 3] = 1.0
    bind_m = np.where((skin_joint >= 0)[:, None, None], bind_full, bind_world)
    b_rot, b_tra = local_from_world(parents, bind_r, bind_full[:, :3, 3])
    return CharacterSkeleton(
        joint_names=[doc.node_names[n] for n in order], parents=parents, nodes=order, skin_joint=skin_joint,
        bind_world=bind_world, bind_rotations=b_rot, bind_translations=b_tra,
        rest_rotations=rest_rot[0], rest_translations=rest_tra[0], inverse_bind_matrices=ibm,
        mesh_world=mesh_world, bind_matrices=bind_m, joint_scale=scale,
        name=os.path.splitext(os.path.basename(doc.path))[0], source=doc.path,
        meta={"skin": int(skin), "skin_name": sk.name or ""})


# ---------------------------------------------------------------------------------- inspect
def _triangles(mode: int, n: int) -> int:
    if mode == 4:
        return n // 3
    if mode in (5, 6):
        return max(n - 2, 0)
    return 0


def describe_gltf(path: str | os.PathLike) -> dict:
    """What a glTF/GLB file holds, for `jiggle inspect`.

    Returns a dict: format, vertices and faces (triangles) summed over every mesh primitive, meshes,
    primitives, skins ([{name, joints}]), joints (count in the first skin), joint_names (first skin,
    tree order), animations ([{name, duration_s, channels}]), height_m (z extent of every mesh
    instance's vertices placed by its node, Z-up metres; skinned meshes at their bind placement) and
    bounds_m (min xyz then max xyz).
    """
    doc = GltfDocument(path)
    g = doc.gltf
    verts = faces = prims = 0
    for mi, m in enumerate(g.meshes):
        for pi, p in enumerate(m.primitives):
            prims += 1
            pos = getattr(p.attributes, "POSITION", None)
            nv = g.accessors[pos].count if pos is not None and 0 <= pos < len(g.accessors) else 0
            verts += nv
            mode = 4 if p.mode is None else p.mode
            n_idx = g.accessors[p.indices].count if p.indices is not None else nv
            faces += _triangles(mode, n_idx)
    pts = []
    for i, nd in enumerate(g.nodes):
        if nd.mesh is None or not 0 <= nd.mesh < len(g.meshes):
            continue
        chain = ([i] + doc.ancestors(i))[::-1]
        w = Z_UP @ world_chain(chain, {k: _local_matrix(doc, k) for k in chain})
        for pi, p in enumerate(g.meshes[nd.mesh].primitives):
            pos = getattr(p.attributes, "POSITION", None)
            if pos is None:
                continue
            v = doc.accessor(pos, f"meshes[{nd.mesh}].primitives[{pi}].attributes.POSITION")
            pts.append(v @ w[:3, :3].T + w[:3, 3])
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    anims = []
    for ai, a in enumerate(g.animations):
        t_max = 0.0
        for si, s in enumerate(a.samplers):
            acc = g.accessors[s.input] if s.input is not None and 0 <= s.input < len(g.accessors) else None
            if acc is not None and acc.max:
                t_max = max(t_max, float(acc.max[0]))
            elif acc is not None:
                t_max = max(t_max, float(doc.accessor(s.input).max(initial=0.0)))
        anims.append({"name": a.name or f"animation{ai}", "duration_s": round(t_max, 6),
                      "channels": len(a.channels)})
    skins = [{"name": s.name or f"skin{k}", "joints": len(s.joints or [])} for k, s in enumerate(g.skins)]
    names: list[str] = []
    if g.skins and g.skins[0].joints:
        order, _ = joint_tree(doc, list(g.skins[0].joints))
        names = [doc.node_names[n] for n in order]
    for i in range(len(g.accessors)):  # every accessor's byte range against its buffer, as a reader would
        doc.accessor(i, f"accessors[{i}]")
    return {
        "format": "GLB" if doc._bin is not None or str(doc.path).lower().endswith(".glb") else "glTF",
        "vertices": int(verts), "faces": int(faces), "meshes": len(g.meshes), "primitives": prims,
        "skins": skins, "joints": skins[0]["joints"] if skins else 0, "joint_names": names,
        "animations": anims,
        "height_m": round(float(np.ptp(pts[:, 2])), 4) if len(pts) else 0.0,
        "bounds_m": ((pts.min(0).round(4) + 0.0).tolist() + (pts.max(0).round(4) + 0.0).tolist()) if len(pts) else [],
    }
