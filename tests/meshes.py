"""Small test meshes and mesh measures shared by the tests."""
import numpy as np


def grid(n: int, size: float) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid of side `size` metres in the xy plane and its 2 (n-1)^2 triangles, all
    facing +z: vertices (n^2, 3) float64, faces (F, 3) int."""
    x, y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n), indexing="ij")
    verts = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            faces += [(a, b, c), (a, c, d)]
    return verts, np.array(faces)


def winding_numbers(vertices, faces, points, chunk: int = 64) -> np.ndarray:
    """(P,) generalized winding number of points (P, 3) for the mesh: the signed solid angles of all
    triangles (Van Oosterom-Strackee) summed over 4 pi; 1 inside a closed outward mesh, 0 outside.
    An independent NumPy reference, in chunks of points to bound memory."""
    v, f = np.asarray(vertices, float), np.asarray(faces)
    out = []
    for i in range(0, len(points), chunk):
        p = np.asarray(points[i:i + chunk], float)
        a, b, c = (v[f[:, k]][None] - p[:, None] for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
               + np.einsum("pfi,pfi->pf", c, a) * lb)
        out.append(np.arctan2(det, den).sum(axis=1) / (2 * np.pi))
    return np.concatenate(out) if out else np.zeros(0)
