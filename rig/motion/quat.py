"""Quaternions and rotations as NumPy arrays.

Convention inside jiggle: unit quaternions stored **w, x, y, z** (MuJoCo's order), float64, shape
(..., 4), acting on column vectors. Warp stores x, y, z, w: convert only with :func:`to_xyzw` /
:func:`from_xyzw`, the single place where the two orders meet.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def to_xyzw(q: np.ndarray) -> np.ndarray:
    """(..., 4) w,x,y,z -> (..., 4) x,y,z,w (Warp, SciPy order)."""
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def from_xyzw(q: np.ndarray) -> np.ndarray:
    """(..., 4) x,y,z,w (Warp, SciPy order) -> (..., 4) w,x,y,z."""
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    """Identity quaternions of shape (*shape, 4)."""
    q = np.zeros((*shape, 4))
    q[..., 0] = 1.0
    return q


def normalize(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b (apply b, then a), broadcasting over leading axes."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def conj(q: np.ndarray) -> np.ndarray:
    """Conjugate, the inverse of a unit quaternion."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4)."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def from_matrix(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions with w >= 0."""
    shape = m.shape[:-2]
    q = from_xyzw(Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat())
    return canonical(q).reshape(*shape, 4)


def canonical(q: np.ndarray) -> np.ndarray:
    """Flip signs so that w >= 0 (the same rotation)."""
    return np.where(q[..., :1] < 0.0, -q, q)


def from_euler(angles: np.ndarray, order: str, degrees: bool = True) -> np.ndarray:
    """Quaternions from Euler angles applied in `order` as intrinsic rotations.

    angles : (..., k) in the order given; order : e.g. "ZYX" means R = Rz @ Ry @ Rx, the BVH
    and Acclaim reading of a channel list "Zrotation Yrotation Xrotation".
    """
    a = np.asarray(angles, dtype=float)
    shape = a.shape[:-1]
    flat = a.reshape(-1, a.shape[-1])
    if flat.shape[0] == 0:
        return identity(shape)
    q = from_xyzw(Rotation.from_euler(order.upper(), flat, degrees=degrees).as_quat())
    return q.reshape(*shape, 4)


def from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """axis (..., 3) unit, angle (...) radians -> (..., 4)."""
    half = 0.5 * np.asarray(angle)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation taking direction a (..., 3) onto direction b (..., 3).

    For opposite directions any perpendicular axis is used.
    """
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    d = np.sum(a * b, axis=-1, keepdims=True)
    c = np.cross(a, b)
    q = np.concatenate([1.0 + d, c], axis=-1)
    opposite = (1.0 + d[..., 0]) < 1e-9
    if np.any(opposite):
        ax = np.cross(a, np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(ax, axis=-1) < 1e-6
        ax = np.where(small[..., None], np.cross(a, np.array([0.0, 1.0, 0.0])), ax)
        ax = ax / np.linalg.norm(ax, axis=-1, keepdims=True)
        q = np.where(opposite[..., None], np.concatenate([np.zeros_like(d), ax], axis=-1), q)
    return normalize(q)


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation from a to b (..., 4) at t (...) in [0, 1], shortest path."""
    t = np.asarray(t, dtype=float)[..., None]
    d = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(d < 0.0, -b, b)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    near = s < 1e-6
    safe = np.where(near, 1.0, s)
    wa = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(near, t, np.sin(t * theta) / safe)
    return normalize(wa * a + wb * b)


def make_continuous(q: np.ndarray, axis: int = 0) -> np.ndarray:
    """Flip signs along `axis` so consecutive quaternions lie in the same hemisphere."""
    q = np.moveaxis(np.asarray(q, dtype=float), axis, 0)
    if q.shape[0] < 2:
        return np.moveaxis(q.copy(), 0, axis)
    step = np.where(np.sum(q[1:] * q[:-1], axis=-1) < 0.0, -1.0, 1.0)
    sign = np.concatenate([np.ones_like(step[:1]), np.cumprod(step, axis=0)], axis=0)
    return np.moveaxis(q * sign[..., None], 0, axis)


def to_rotvec(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions -> (..., 3) rotation vectors (axis times angle in radians, <= pi)."""
    q = canonical(q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    ang = 2.0 * np.arctan2(s, q[..., 0])
    return q[..., 1:] * np.where(s > 1e-12, ang / np.where(s > 1e-12, s, 1.0), 2.0)[..., None]


def angle(q: np.ndarray) -> np.ndarray:
    """Rotation angle in radians, in [0, pi]."""
    return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))
