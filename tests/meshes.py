"""Small test meshes shared by the skin tests."""
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
