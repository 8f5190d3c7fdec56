"""Skinning: linear blend (LBS) and dual-quaternion (DQS) skinning of a rest mesh by skin matrices.

A skin matrix ``M_j`` (4x4, column vectors, metres) takes a rest-pose point to joint ``j``'s posed
frame: ``M_j = world_j @ inverse(bind_j)``. Each vertex has ``k`` influences (joint, weight).

- :func:`lbs_numpy`, :func:`dqs_numpy`: vectorised float64 references (no input checks: they are
  what the kernels are measured against).
- :class:`Skinner`: the Warp launcher (kernels in :mod:`rig.skin.skinning_kernels`); the rest mesh and
  influences are uploaded once, each call uploads only the matrices. `skin` / `launch` pose one
  frame; `skin_batch` / `launch_batch` pose T frames with one upload and one launch.
- :func:`character_skinner`, :func:`pose_character`: a Character's skin on the device, and posed.

Dual quaternions in NumPy are (..., 8): real part w, x, y, z then dual part w, x, y, z (the project's
w-first order, see :mod:`rig.motion.quat`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from jiggle.rig.base.errors import InputError
from jiggle.rig.character.normals import VertexNormals
from jiggle.rig.motion import quat
from jiggle.rig.skin import skinning_kernels as kernels
from jiggle.rig.skin.scratch import Scratch

METHODS = ("lbs", "dqs")


# ---------------------------------------------------------------------------------------------
# input checks


def check_influences(rest, joints, weights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated copies: rest (V, 3) float64, joints (V, k) int64, weights (V, k) float64.

    Raises InputError (a ValueError) naming the parameter: wrong shapes, non-finite rest
    positions, non-integer or negative joints, negative or NaN weights, vertices whose weights
    are all zero. Joint indices above the skeleton are caught where J is known (the matrices).
    """
    rest = np.asarray(rest)
    joints = np.asarray(joints)
    weights = np.asarray(weights)
    if rest.ndim != 2 or rest.shape[1] != 3 or not np.issubdtype(rest.dtype, np.number):
        raise InputError(f"expected a (V, 3) float array, got shape {rest.shape} "
                         f"dtype {rest.dtype}", field="rest")
    V = rest.shape[0]
    if joints.ndim != 2 or joints.shape[0] != V:
        raise InputError(f"expected shape (V, k) with V = {V}, got {joints.shape}", field="joints")
    if weights.shape != joints.shape:
        raise InputError(f"expected the shape of joints {joints.shape}, got {weights.shape}",
                         field="weights")
    if V and joints.shape[1] == 0:
        raise InputError("every vertex needs at least one influence (k >= 1)", field="joints")
    if not np.issubdtype(joints.dtype, np.integer):
        raise InputError(f"expected an integer array, got dtype {joints.dtype}", field="joints")
    if not np.issubdtype(weights.dtype, np.number):
        raise InputError(f"expected a float array, got dtype {weights.dtype}", field="weights")
    if not np.all(np.isfinite(rest)):
        raise InputError("rest positions contain NaN or inf", field="rest")
    if joints.size and joints.min() < 0:
        raise InputError(f"joint indices must be >= 0, found {joints.min()}", field="joints")
    weights = weights.astype(np.float64)
    bad = ~np.isfinite(weights) | (weights < 0.0)
    if np.any(bad):
        rows = np.unique(np.nonzero(bad)[0])
        raise InputError(f"{rows.size} vertices have negative, NaN or inf weights "
                         f"(first: {rows[:5].tolist()})", field="weights")
    empty = np.nonzero(weights.sum(axis=1) <= 0.0)[0]
    if empty.size:
        raise InputError(f"{empty.size} vertices have all-zero weights (first: "
                         f"{empty[:5].tolist()}); give them an influence or drop them",
                         field="weights")
    return rest.astype(np.float64), joints.astype(np.int64), weights


def check_matrices(matrices, num_joints_needed: int = 0) -> np.ndarray:
    """Skin matrices as a (J, 4, 4) float64 array, J > the largest joint index in use.

    num_joints_needed : the largest joint index referenced by the influences, plus one.
    """
    m = np.asarray(matrices)
    if m.ndim != 3 or m.shape[1:] != (4, 4) or not np.issubdtype(m.dtype, np.number):
        raise InputError(f"expected a (J, 4, 4) float array, got shape {m.shape} dtype {m.dtype}",
                         field="matrices")
    if m.shape[0] < num_joints_needed:
        raise InputError(f"joint index {num_joints_needed - 1} is out of range [0, {m.shape[0]}) "
                         f"for {m.shape[0]} skin matrices", field="joints")
    m = m.astype(np.float64)
    if not np.all(np.isfinite(m)):
        bad = np.unique(np.nonzero(~np.isfinite(m))[0])
        raise InputError(f"NaN or inf in the matrices of joints {bad[:5].tolist()}",
                         field="matrices")
    return m


def check_matrices_batch(matrices, num_joints_needed: int = 0) -> np.ndarray:
    """Skin matrices of T frames as a (T, J, 4, 4) float64 array (see :func:`check_matrices`)."""
    m = np.asarray(matrices)
    if m.ndim != 4 or m.shape[2:] != (4, 4) or not np.issubdtype(m.dtype, np.number):
        raise InputError(f"expected a (T, J, 4, 4) float array, got shape {m.shape} dtype {m.dtype}",
                         field="matrices")
    if m.shape[1] < num_joints_needed:
        raise InputError(f"joint index {num_joints_needed - 1} is out of range [0, {m.shape[1]}) "
                         f"for {m.shape[1]} skin matrices", field="joints")
    m = m.astype(np.float64)
    if not np.all(np.isfinite(m)):
        frame, joint = np.nonzero(~np.isfinite(m).all(axis=(2, 3)))
        raise InputError(f"NaN or inf in the matrices of (frame, joint) "
                         f"{list(zip(frame[:5].tolist(), joint[:5].tolist()))}", field="matrices")
    return m


def _needed(joints: np.ndarray) -> int:
    return int(joints.max()) + 1 if joints.size else 0


# ---------------------------------------------------------------------------------------------
# NumPy references


def matrices_to_dual_quats(matrices) -> np.ndarray:
    """Unit dual quaternions of the rigid part of skin matrices.

    Parameters
    ----------
    matrices : (J, 4, 4) float, metres. The rotation is the polar factor of the upper 3x3 block, so
        exporter scales of 1 +- 1e-6 are dropped; a mirrored block (det < 0) gets the nearest
        rotation (its smallest singular direction flipped). The translation is the last column.

    Returns
    -------
    (J, 8) float64: real w, x, y, z (the rotation q), dual w, x, y, z (= 0.5 * (0, t) * q).
    """
    m = np.asarray(matrices, np.float64)
    u, _, vt = np.linalg.svd(m[:, :3, :3])
    # singular values come sorted descending: a mirror is undone along the last, smallest one
    flip = np.ones((m.shape[0], 3))
    flip[:, 2] = np.sign(np.linalg.det(u @ vt))
    r = (u * flip[:, None, :]) @ vt
    real = quat.from_matrix(r)
    t = np.concatenate([np.zeros((m.shape[0], 1)), m[:, :3, 3]], axis=1)
    return np.concatenate([real, 0.5 * quat.mul(t, real)], axis=1)


def lbs_numpy(rest, joints, weights, matrices) -> np.ndarray:
    """Linear blend skinning: p = sum_i w_i * M_{j_i} @ [rest, 1].

    Parameters
    ----------
    rest : (V, 3) float, metres.
    joints : (V, k) int, indices into matrices.
    weights : (V, k) float, >= 0; used as given (see :func:`normalise_weights`).
    matrices : (J, 4, 4) float, skin matrices, metres.

    Returns
    -------
    (V, 3) float64, metres.
    """
    rest, weights = np.asarray(rest, np.float64), np.asarray(weights, np.float64)
    m = np.asarray(matrices, np.float64)[np.asarray(joints)]  # (V, k, 4, 4)
    posed = np.einsum("vkab,vb->vka", m[..., :3, :3], rest) + m[..., :3, 3]
    return np.einsum("vk,vka->va", weights, posed)


def dqs_numpy(rest, joints, weights, matrices) -> np.ndarray:
    """Dual-quaternion skinning (Kavan et al. 2008), same parameters and result as :func:`lbs_numpy`.

    Each vertex blends its joints' dual quaternions (:func:`matrices_to_dual_quats`) after flipping
    them into the hemisphere of its largest-weight influence, normalises the blend by the real
    part's length and applies it to the rest position. Weights need not sum to 1.
    """
    rest, weights = np.asarray(rest, np.float64), np.asarray(weights, np.float64)
    dq = matrices_to_dual_quats(matrices)[np.asarray(joints)]  # (V, k, 8)
    real, dual = dq[..., :4], dq[..., 4:]
    pivot = np.take_along_axis(real, np.argmax(weights, axis=1)[:, None, None], axis=1)
    w = np.where(np.sum(real * pivot, axis=-1) < 0.0, -weights, weights)
    br = np.einsum("vk,vkq->vq", w, real)
    bd = np.einsum("vk,vkq->vq", w, dual)
    n = np.linalg.norm(br, axis=1, keepdims=True)
    r, d = br / n, bd / n
    # translation = vector part of 2 * d * conj(r); exact for the blended, non-unit dual part too
    t = 2.0 * (r[:, :1] * d[:, 1:] - d[:, :1] * r[:, 1:] + np.cross(r[:, 1:], d[:, 1:]))
    return quat.rotate(r, rest) + t


# ---------------------------------------------------------------------------------------------
# Warp launcher


@dataclass(frozen=True)
class SkinModel:
    """The rest mesh and influences on the device; built once, never changed.

    rest : (V,) wp.vec3, metres. joints : (V*k,) int32, each vertex's influences sorted by
    descending weight (DQS pivots on the first). weights : (V*k,) float32. k : influences per
    vertex. num_joints_needed : largest joint index + 1 (0 when V == 0).
    """

    rest: wp.array
    joints: wp.array
    weights: wp.array
    k: int
    num_vertices: int
    num_joints_needed: int


class Skinner:
    """LBS and DQS of one rest mesh with Warp.

    Parameters
    ----------
    rest : (V, 3) float, rest positions, metres.
    joints : (V, k) int, joint index of each influence.
    weights : (V, k) float, >= 0, not NaN, not all zero in a row. LBS uses them as given (rows
        should sum to 1, see :func:`normalise_weights`); DQS is insensitive to their scale.
    faces : optional (F, 3) int triangles, for :meth:`normals`.
    device : Warp device for the model, the scratch buffers and every launch.

    Each call uploads only the (J, 4, 4) skin matrices (T of them for a batch); the positions
    buffers are reused. `thread_per_frame` (default: True on a GPU, False on the CPU) chooses the
    batched launch's threads: one per frame and vertex, or one per vertex running through the frames.
    """

    def __init__(self, rest, joints, weights, faces=None, device="cpu"):
        rest, joints, weights = check_influences(rest, joints, weights)
        order = np.argsort(-weights, axis=1, kind="stable")
        joints = np.take_along_axis(joints, order, axis=1)
        weights = np.take_along_axis(weights, order, axis=1)
        self.device = wp.get_device(device)
        V, k = joints.shape
        self.model = SkinModel(
            rest=wp.array(rest.astype(np.float32), dtype=wp.vec3, device=self.device),
            joints=wp.array(joints.astype(np.int32).ravel(), dtype=wp.int32, device=self.device),
            weights=wp.array(weights.astype(np.float32).ravel(), dtype=wp.float32,
                             device=self.device),
            k=int(k), num_vertices=int(V), num_joints_needed=_needed(joints))
        self.vertex_normals = None if faces is None else VertexNormals(faces, V)
        self._positions = wp.empty(V, dtype=wp.vec3, device=self.device)
        self._matrices = None
        self._real = None
        self._dual = None
        self._scratch = Scratch(self.device)      # the batched launch's buffers, sized (T, ...)
        # batched launches: a thread per frame and vertex (GPU) or per vertex, running through the frames
        # (CPU: Warp's CPU launch divides the index of every thread of a multi-dimensional launch)
        self.thread_per_frame = not self.device.is_cpu
        self.launches = 0
        """Warp launches made so far."""

    @property
    def num_vertices(self) -> int:
        return self.model.num_vertices

    def lbs(self, matrices) -> np.ndarray:
        """Linear blend skinning. matrices : (J, 4, 4) float -> (V, 3) float32, metres."""
        return self.skin(matrices, "lbs")

    def dqs(self, matrices) -> np.ndarray:
        """Dual-quaternion skinning. matrices : (J, 4, 4) float -> (V, 3) float32, metres."""
        return self.skin(matrices, "dqs")

    def skin(self, matrices, method: str = "lbs") -> np.ndarray:
        """Skinned positions, (V, 3) float32, metres, a new array (the device buffer is reused)."""
        out = self.launch(matrices, method).numpy()
        # on the CPU .numpy() is a view of the scratch buffer the next call overwrites
        return out.copy() if self.device.is_cpu else out

    def launch(self, matrices, method: str = "lbs") -> wp.array:
        """Skin on the device; returns the wrapper's (V,) wp.vec3 buffer, valid until the next call.

        For callers that keep working on the device (e.g. deformers in series).
        """
        if method not in METHODS:
            raise InputError(f"expected one of {METHODS}, got {method!r}", field="method")
        self._upload(matrices)
        model = self.model
        if model.num_vertices == 0:
            return self._positions
        if method == "lbs":
            wp.launch(kernels.lbs, dim=model.num_vertices, device=self.device,
                      inputs=[model.rest, model.joints, model.weights, model.k, self._matrices],
                      outputs=[self._positions])
            self.launches += 1
        else:
            self.launches += 2
            J = self._matrices.shape[0]
            wp.launch(kernels.dual_quats_from_matrices, dim=J, device=self.device,
                      inputs=[self._matrices], outputs=[self._real, self._dual])
            wp.launch(kernels.dqs, dim=model.num_vertices, device=self.device,
                      inputs=[model.rest, model.joints, model.weights, model.k,
                              self._real, self._dual],
                      outputs=[self._positions])
        return self._positions

    def skin_batch(self, matrices, method: str = "lbs") -> np.ndarray:
        """Skinned positions of T frames, (T, V, 3) float32, metres, a new array.

        matrices : (T, J, 4, 4) float, each frame's skin matrices, metres. Equal to :meth:`skin` frame
        by frame (the same per-vertex code), with one upload and one launch for all T frames.
        """
        out = self.launch_batch(matrices, method).numpy()
        return out.copy() if self.device.is_cpu else out

    def launch_batch(self, matrices, method: str = "lbs", out: wp.array | None = None) -> wp.array:
        """Skin T frames on the device in one launch (DQS: one more over the T * J matrices for
        their dual quaternions); on the CPU a thread per vertex, on a GPU one per frame and vertex.
        Returns the wrapper's (T, V) wp.vec3 buffer, valid until the next batched call
        (:meth:`launch`'s buffer is another one), or `out`.

        matrices : (T, J, 4, 4) float, metres.
        out : a (T, V) wp.vec3 array on this device to skin into instead (e.g. on the CPU a NumPy
            array the caller keeps, wrapped without a copy), or None.
        """
        if method not in METHODS:
            raise InputError(f"expected one of {METHODS}, got {method!r}", field="method")
        m = check_matrices_batch(matrices, self.model.num_joints_needed)
        T, J = m.shape[:2]
        model = self.model
        if out is None:
            out = self._scratch("positions", (T, model.num_vertices), wp.vec3)
        elif (not isinstance(out, wp.array) or out.dtype != wp.vec3 or out.shape != (T, model.num_vertices)
              or out.device != self.device):
            raise InputError(f"expected a ({T}, {model.num_vertices}) wp.vec3 array on {self.device}", field="out")
        if T == 0 or model.num_vertices == 0:
            return out
        mats = self._scratch("matrices", (T * J,), wp.mat44)
        mats.assign(m.reshape(T * J, 4, 4).astype(np.float32))
        stride = T if self.thread_per_frame else 1
        if method == "lbs":
            wp.launch(kernels.lbs_batch, dim=(stride, model.num_vertices), device=self.device,
                      inputs=[model.rest, model.joints, model.weights, model.k, mats, J, stride],
                      outputs=[out])
            self.launches += 1
        else:
            self.launches += 2
            real = self._scratch("real", (T * J,), wp.quat)
            dual = self._scratch("dual", (T * J,), wp.quat)
            wp.launch(kernels.dual_quats_from_matrices, dim=T * J, device=self.device,
                      inputs=[mats], outputs=[real, dual])
            wp.launch(kernels.dqs_batch, dim=(stride, model.num_vertices), device=self.device,
                      inputs=[model.rest, model.joints, model.weights, model.k, real, dual, J, stride],
                      outputs=[out])
        return out

    def normals(self, positions) -> np.ndarray:
        """Unit vertex normals of skinned positions (V, 3) or (N, V, 3), from the faces given."""
        if self.vertex_normals is None:
            raise InputError("the Skinner was built without faces", field="faces")
        return self.vertex_normals(positions)

    def _upload(self, matrices) -> None:
        m = check_matrices(matrices, self.model.num_joints_needed).astype(np.float32)
        J = m.shape[0]
        if self._matrices is None or self._matrices.shape[0] != J:
            self._matrices = wp.empty(J, dtype=wp.mat44, device=self.device)
            self._real = wp.empty(J, dtype=wp.quat, device=self.device)
            self._dual = wp.empty(J, dtype=wp.quat, device=self.device)
        self._matrices.assign(m)


def character_skinner(character, device: str = "cpu") -> Skinner:
    """A :class:`Skinner` holding `character`'s (rig.character.character.Character) rest skin and weights on `device`."""
    return Skinner(character.vertices, character.joints, character.weights, faces=character.faces, device=device)


def pose_character(character, world: np.ndarray, method: str = "lbs", device: str = "cpu") -> np.ndarray:
    """Skinned vertex positions (N, V, 3) float32 metres of `character` for joint world transforms
    (N, J, 4, 4) (or (V, 3) for one frame (J, 4, 4)), by "lbs" or "dqs"."""
    world = np.asarray(world, dtype=np.float64)
    single = world.ndim == 3
    mats = character.skin_matrices(world[None] if single else world)
    sk = character_skinner(character, device)
    out = np.stack([sk.skin(m, method=method) for m in mats]) if len(mats) else \
        np.zeros((0, character.num_vertices, 3), np.float32)
    return out[0] if single else out
