"""A skinned character: rest skin, faces, skeleton, bind transforms and top-k skin weights.

Built once when a scene loads and never changed while a clip plays. Posing takes bone world
transforms (from the MuJoCo skeleton driver, `sim.drive.skeleton.Skeleton.world`) in the character's joint
order and returns skinned vertex positions:

    skin matrix of joint j  S_j = W_j(t) @ inverse(B_j)
    vertex                  x_v = sum_i w_vi S_{j_vi} @ rest_v          (LBS; DQS optional)

where W_j(t) is the rigid world transform of joint j and B_j its bind matrix, the transform that
takes the joint's space to the rest skin. For a glTF file B_j = mesh placement @ inverse(IBM_j), so
S_j equals the spec's "global transform x inverse bind matrix" applied to the file's vertices.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.character.painted_maps import PaintedMaps
from jiggle.rig.character.vrm_springs import scaled_springs
from jiggle.rig.motion.clip import Clip, joint_index, local_from_world
from jiggle.rig.motion.gltf_io import polar_rotation

PLAUSIBLE_HEIGHT_M = (0.05, 10.0)
"""A character or creature outside this height (metres: a mouse to a giraffe) was probably read in the
wrong unit."""


@dataclass(frozen=True, eq=False)
class Character:
    """A skinned character in jiggle's world (Z-up, metres). Arrays are read-only.

    Attributes
    ----------
    vertices : (V, 3) float64 metres, rest skin (the bind pose).
    faces : (F, 3) int32 vertex indices, counter-clockwise seen from outside where the source says so.
    normals : (V, 3) float64 unit rest normals.
    uvs : (V, 2) float32 texture coordinates, or None when the source has none.
    joint_names : (J,) joint names, parents first.
    parents : (J,) int32 parent index or -1.
    bind_world : (J, 4, 4) float64 rigid world transform of each joint in the bind pose, metres.
    bind_matrices : (J, 4, 4) float64 transform from each joint's space to the rest skin; equals
        `bind_world` unless the file's inverse bind matrices scale or shear.
    joints : (V, k) int32 joint index of each influence, strongest first.
    weights : (V, k) float32 influence weights, rows summing to 1, descending.
    skeleton : one-frame Clip of the bind pose, to drive with `sim.drive.skeleton.Skeleton`.
    name, source : a label and the file it came from ("" when generated).
    meta : how it was made: {"weights": "file" | "bone heat", "unit_scale": metres per file unit, ...}.
    maps : the maps painted on the skin (rig.character.painted_maps.PaintedMaps: where jiggle shows, and
        each muscle's shell influence), or None.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray | None
    joint_names: tuple[str, ...]
    parents: np.ndarray
    bind_world: np.ndarray
    bind_matrices: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    skeleton: Clip
    name: str = ""
    source: str = ""
    meta: dict = field(default_factory=dict)
    maps: PaintedMaps | None = None

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("joint_names", tuple(self.joint_names))
        for k in ("vertices", "normals", "bind_world", "bind_matrices"):
            set_(k, frozen_array(getattr(self, k)))
        set_("faces", frozen_array(self.faces, np.int32))
        set_("parents", frozen_array(self.parents, np.int32))
        set_("joints", frozen_array(self.joints, np.int32))
        set_("weights", frozen_array(self.weights, np.float32))
        if self.uvs is not None:
            set_("uvs", frozen_array(self.uvs, np.float32))
        V, J = len(self.vertices), len(self.joint_names)
        assert self.vertices.shape == (V, 3) and self.normals.shape == (V, 3)
        assert self.joints.shape == self.weights.shape == (V, self.joints.shape[1])
        assert self.bind_world.shape == self.bind_matrices.shape == (J, 4, 4) and self.parents.shape == (J,)
        assert self.skeleton.joint_names == self.joint_names
        if self.maps is not None and self.maps.num_vertices not in (None, V):
            raise InputError(f"the painted maps have {self.maps.num_vertices} vertices, the skin {V}",
                             self.source or None, field="maps")

    # ------------------------------------------------------------------ sizes
    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def influences(self) -> int:
        """k, the number of influences kept per vertex."""
        return self.joints.shape[1]

    @property
    def height(self) -> float:
        """Extent of the rest skin along z, metres."""
        return float(np.ptp(self.vertices[:, 2])) if self.num_vertices else 0.0

    def index(self, name: str) -> int:
        return joint_index(self.joint_names, name, self.source)

    @property
    def bind_positions(self) -> np.ndarray:
        """(J, 3) metres, joint positions in the bind pose."""
        return self.bind_world[:, :3, 3]

    def dominant_joint(self) -> np.ndarray:
        """(V,) int32, the strongest influence of each vertex."""
        return self.joints[:, 0]

    # ------------------------------------------------------------------ posing
    def skin_matrices(self, world: np.ndarray) -> np.ndarray:
        """Skin matrices (..., J, 4, 4) from rigid joint world transforms `world` (..., J, 4, 4) metres
        (e.g. `rig.motion.clip.transforms(*skeleton.world(times))`), in the character's joint order."""
        world = np.asarray(world, dtype=np.float64)
        if world.shape[-3:] != (self.num_joints, 4, 4):
            raise ValueError(f"world transforms must be (..., {self.num_joints}, 4, 4), got {world.shape}")
        return world @ np.linalg.inv(self.bind_matrices)

    def joint_order(self, names) -> np.ndarray:
        """(J,) index into `names` of each of the character's joints (to reorder a driver's bodies);
        InputError naming the first joint missing from `names`."""
        lookup = {n: i for i, n in enumerate(names)}
        missing = [n for n in self.joint_names if n not in lookup]
        if missing:
            raise InputError(f"the motion has no joint {missing[0]!r} of the character "
                             f"({len(missing)} of {self.num_joints} missing); retarget the clip onto the character",
                             self.source or None, field="joints")
        return np.array([lookup[n] for n in self.joint_names])

    def scaled(self, factor: float) -> "Character":
        """The same character with every length times `factor` (skin, joints, skeleton; rotations, weights and
        maps kept); meta["unit_scale"] (metres per file unit) and the lengths of meta["spring_bones"] are scaled
        alike."""
        if factor == 1.0:
            return self
        f = float(factor)

        def moved(m):
            m = np.array(m)
            m[..., :3, 3] *= f
            return m
        sk = self.skeleton
        skeleton = replace(sk, offsets=np.asarray(sk.offsets) * f, translations=np.asarray(sk.translations) * f,
                           end_offsets=np.asarray(sk.end_offsets) * f)
        meta = {**self.meta, "unit_scale": self.meta.get("unit_scale", 1.0) * f}
        if self.meta.get("spring_bones"):
            meta["spring_bones"] = scaled_springs(self.meta["spring_bones"], f)
        return replace(self, vertices=np.asarray(self.vertices) * f, bind_world=moved(self.bind_world),
                       bind_matrices=moved(self.bind_matrices), skeleton=skeleton, meta=meta)

    def with_weights(self, joints: np.ndarray, weights: np.ndarray, how: str) -> "Character":
        """The same character with other skin weights (V, k); `how` is recorded in meta["weights"]."""
        return replace(self, joints=joints, weights=weights, meta={**self.meta, "weights": how})


# ---------------------------------------------------------------------------------- helpers
def bind_clip(joint_names, parents, bind_world: np.ndarray, name: str = "", source: str = "",
              fps: float = 30.0) -> Clip:
    """One-frame Clip whose rest pose has world transforms `bind_world` (J, 4, 4) (rigid part used)."""
    rot, tra = local_from_world(parents, polar_rotation(bind_world[:, :3, :3]), bind_world[:, :3, 3])
    return Clip(joint_names=tuple(joint_names), parents=parents, offsets=tra, rest_rotations=rot,
                rotations=rot[None], translations=tra[None], fps=fps, name=name, source=source,
                meta={"format": "bind pose"})


def check_height(height: float, path: str | None, unit_option: str = "--unit") -> None:
    """Warn when a character's height (metres) is implausible (outside PLAUSIBLE_HEIGHT_M), naming the
    unit that would make it plausible and how to say so."""
    lo, hi = PLAUSIBLE_HEIGHT_M
    if lo <= height <= hi:
        return
    unit = guess_unit(height)
    hint = f"; the file is probably in {UNIT_NAMES[unit]}: pass {unit_option} {unit}" if unit else \
        f"; pass {unit_option} with the file's metres per unit"
    where = f"{path}: " if path else ""
    warnings.warn(f"{where}the character is {height:.4g} m tall, outside the plausible {lo:g}-{hi:g} m{hint}",
                  JiggleWarning, stacklevel=3)


TEMPLATE_HEIGHT_M = {"human": (1.7, 1.0, 2.5)}
"""metres: (the size a template's defaults are made for, the least and the most height it takes as it is). A
character its template calls human but whose file says 0.22 m or 4.5 m tall is simulated at 1.7 m and its
result scaled back (sim.bake.setup); quadrupeds (a cat to a horse) and the generic template take any size."""


def template_scale(template: str, height: float) -> float:
    """The factor that brings a character `height` metres tall to the size its template's defaults are made for
    (TEMPLATE_HEIGHT_M), or 1.0 when its height is within the template's range or the template has none."""
    if template not in TEMPLATE_HEIGHT_M or not np.isfinite(height) or height <= 0:
        return 1.0
    nominal, lo, hi = TEMPLATE_HEIGHT_M[template]
    return 1.0 if lo <= height <= hi else nominal / height


UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
UNIT_NAMES = {"m": "metres", "cm": "centimetres", "mm": "millimetres", "in": "inches", "ft": "feet"}
AUTO_UNITS = ("cm", "mm")
"""Units `--unit auto` tries, in order, when a file read as metres has an implausible height: exports
in centimetres are by far the commonest (Maya, Unreal, FBX-derived glTF), then millimetres (CAD)."""


def guess_unit(height: float) -> str | None:
    """The first unit of AUTO_UNITS (then inches) that makes `height` (file units read as metres)
    plausible, or None when metres already is or none does."""
    lo, hi = PLAUSIBLE_HEIGHT_M
    if not np.isfinite(height) or lo <= height <= hi:
        return None
    return next((u for u in AUTO_UNITS + ("in",) if lo <= height * UNITS[u] <= hi), None)


def unit_scale(unit: str | float | None, path: str | None = None) -> float | None:
    """Metres per file unit from a name in UNITS or a positive number; None or "auto" give None: the
    unit is then found from the height by :func:`resolve_unit`."""
    if unit is None or unit == "auto":
        return None
    if isinstance(unit, str) and unit in UNITS:
        return UNITS[unit]
    try:
        s = float(unit)
    except (TypeError, ValueError):
        s = float("nan")
    if not np.isfinite(s) or s <= 0:
        raise InputError(f"unit must be auto, one of {', '.join(UNITS)} or a positive number of metres per unit, "
                         f"got {unit!r}", path, field="unit")
    return s


def resolve_unit(unit: str | float | None, height: float, path: str | None = None,
                 unit_option: str = "--unit") -> float:
    """Metres per file unit for a character whose height is `height` file units.

    unit : a unit name or number (that, see :func:`unit_scale`), or None / "auto": metres when the
        height read as metres is plausible (PLAUSIBLE_HEIGHT_M), else the unit :func:`guess_unit`
        finds, said in a JiggleWarning with the option that keeps metres; else metres (the height
        check then warns).
    """
    s = unit_scale(unit, path)
    if s is not None:
        return s
    guess = guess_unit(height)
    if guess is None:
        return 1.0
    where = f"{path}: " if path else ""
    warnings.warn(f"{where}{height:.4g} units tall: read in {UNIT_NAMES[guess]} ({height * UNITS[guess]:.3g} m); "
                  f"pass {unit_option} m to read it in metres", JiggleWarning, stacklevel=3)
    return UNITS[guess]


def nearest_joint(points: np.ndarray, joint_positions: np.ndarray) -> np.ndarray:
    """(P,) index of the nearest joint to each point (P, 3)."""
    from scipy.spatial import cKDTree
    return cKDTree(joint_positions).query(points)[1].astype(np.int32)


def clean_weights(joints: np.ndarray, weights: np.ndarray, num_joints: int, positions: np.ndarray,
                  joint_positions: np.ndarray, k: int, path: str | None, what: str
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Validate raw skin weights (V, m) from a file and keep the top k, renormalised.

    Errors: joint indices outside [0, num_joints) on an influence with non-zero weight, NaN or
    negative weights. Warnings: rows whose weights do not sum to 1 within 1e-3 (renormalised),
    rows with no weight at all (given to the nearest joint).
    """
    joints = np.asarray(joints)
    weights = np.asarray(weights, dtype=np.float64)
    if not np.all(np.isfinite(weights)):
        bad = int(np.argwhere(~np.isfinite(weights))[0, 0])
        raise InputError(f"weights are not finite (NaN or infinite), first at vertex {bad}", path, field=what)
    if np.any(weights < -1e-6):
        bad = int(np.argwhere(weights < -1e-6)[0, 0])
        raise InputError(f"negative weights, first at vertex {bad}", path, field=what)
    weights = np.maximum(weights, 0.0)
    live = weights > 0
    out_of_range = live & ((joints < 0) | (joints >= num_joints))
    if np.any(out_of_range):
        v, c = np.argwhere(out_of_range)[0]
        raise InputError(f"joint index {int(joints[v, c])} at vertex {int(v)} is out of range: the skin has "
                         f"{num_joints} joints (0..{num_joints - 1})", path, field=what)
    joints = np.where(live, joints, 0)
    total = weights.sum(1)
    empty = total <= 0
    if np.any(empty):
        n = int(empty.sum())
        warnings.warn(f"{path + ': ' if path else ''}{what}: {n} vertices have no weight; each is bound to "
                      f"its nearest joint", JiggleWarning, stacklevel=3)
        joints = joints.copy()
        weights = weights.copy()
        joints[empty, 0] = nearest_joint(positions[empty], joint_positions)
        weights[empty, 0] = 1.0
        total = weights.sum(1)
    off = np.abs(total - 1.0) > 1e-3
    if np.any(off):
        warnings.warn(f"{path + ': ' if path else ''}{what}: the weights of {int(off.sum())} vertices do not sum "
                      f"to 1 (from {total[off].min():.4g} to {total[off].max():.4g}); renormalised",
                      JiggleWarning, stacklevel=3)
    return normalise_weights(joints, weights, k=k)


def drop_degenerate_faces(vertices: np.ndarray, faces: np.ndarray, path: str | None) -> np.ndarray:
    """Faces (F, 3) without repeated indices or zero area; warns how many were dropped."""
    f = np.asarray(faces)
    if len(f) == 0:
        return f.reshape(0, 3)
    rep = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    v = vertices[f]
    area2 = np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    scale = max(float(np.ptp(vertices, axis=0).max()), 1e-12) if len(vertices) else 1.0
    bad = rep | (area2 <= (1e-12 * scale) ** 2)
    if np.any(bad):
        warnings.warn(f"{path + ': ' if path else ''}{int(bad.sum())} of {len(f)} faces are degenerate "
                      f"(repeated vertex or zero area) and were dropped", JiggleWarning, stacklevel=3)
    return f[~bad]


def require_finite_positions(vertices: np.ndarray, path: str | None, what: str = "positions") -> None:
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if np.any(bad):
        raise InputError(f"{int(bad.sum())} vertex positions are not finite (NaN or infinite), first at vertex "
                         f"{int(np.argmax(bad))}", path, field=what)


def end_sites(clip: Clip) -> np.ndarray:
    """(J, 3) rest world position of each joint's end site (the farthest one when a joint has
    several), NaN rows for joints without one."""
    rot, pos = clip.rest_world()
    out = np.full((clip.num_joints, 3), np.nan)
    if len(clip.end_parents):
        tips = clip.end_world(rot[None], pos[None])[0]
        far = np.full(clip.num_joints, -1.0)
        for e, tip in zip(clip.end_parents, tips):
            d = float(np.linalg.norm(tip - pos[e]))
            if d > far[e]:
                far[e], out[e] = d, tip
    return out


def normalise_weights(joints, weights, k: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Keep each vertex's k largest influences and renormalise them to sum 1.

    Parameters
    ----------
    joints : (V, m) int, joint indices (any m >= 0).
    weights : (V, m) float, >= 0, not NaN.
    k : influences kept per vertex.

    Returns
    -------
    joints : (V, k) int32, sorted by descending weight; slots with weight 0 (dropped or padding
        when m < k) hold joint 0, so they never index a missing joint.
    weights : (V, k) float32, each row summing to 1.

    Raises
    ------
    InputError (ValueError) naming how many vertices have all-zero weights: there is no sensible
    joint to give them, the caller must decide.
    """
    joints = np.asarray(joints)
    weights = np.asarray(weights)
    if k < 1:
        raise InputError(f"k must be >= 1, got {k}", field="k")
    if joints.ndim != 2 or weights.shape != joints.shape:
        raise InputError(f"expected joints and weights of one shape (V, m), got {joints.shape} "
                         f"and {weights.shape}", field="weights")
    if not np.issubdtype(joints.dtype, np.integer):
        raise InputError(f"expected an integer array, got dtype {joints.dtype}", field="joints")
    weights = weights.astype(np.float64)
    bad = ~np.isfinite(weights) | (weights < 0.0)
    if np.any(bad):
        raise InputError(f"{np.unique(np.nonzero(bad)[0]).size} vertices have negative, NaN or "
                         f"inf weights", field="weights")
    V, m = joints.shape
    if m < k:
        joints = np.concatenate([joints, np.zeros((V, k - m), joints.dtype)], axis=1)
        weights = np.concatenate([weights, np.zeros((V, k - m))], axis=1)
    order = np.argsort(-weights, axis=1, kind="stable")[:, :k]
    joints = np.take_along_axis(joints, order, axis=1)
    weights = np.take_along_axis(weights, order, axis=1)
    total = weights.sum(axis=1)
    empty = np.nonzero(total <= 0.0)[0]
    if empty.size:
        raise InputError(f"{empty.size} vertices have all-zero weights (first: "
                         f"{empty[:5].tolist()})", field="weights")
    joints = np.where(weights > 0.0, joints, 0)
    return joints.astype(np.int32), (weights / total[:, None]).astype(np.float32)
