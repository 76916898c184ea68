"""4x4 homogeneous transforms (column vectors, p' = M @ [x, y, z, 1]), right-handed, degrees."""

from __future__ import annotations

import numpy as np


def _vec3(value, what: str, allow_scalar: bool = False) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if allow_scalar and arr.ndim == 0:
        arr = np.full(3, float(arr))
    if arr.shape != (3,):
        raise ValueError(f"{what} must be 3 numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite, got {arr.tolist()}")
    return arr


def rotation_matrix(axis, degrees: float) -> np.ndarray:
    """(4, 4) rotation by `degrees` about the unit direction `axis` through the origin,
    right-handed (counter-clockwise looking down the axis towards the origin; Rodrigues' formula).
    `rotation_matrix((0, 0, 1), 90)` maps (1, 0, 0) to (0, 1, 0)."""
    a = _vec3(axis, "axis")
    length = np.linalg.norm(a)
    if length == 0.0:
        raise ValueError("axis must not be the zero vector")
    x, y, z = a / length
    t = np.radians(float(degrees))
    c, s = np.cos(t), np.sin(t)
    # Exact values at multiples of 90 degrees keep axis rotations free of 1e-17 noise.
    if float(degrees) % 90.0 == 0.0:
        c, s = float(np.round(c)), float(np.round(s))
    C = 1.0 - c
    m = np.eye(4)
    m[:3, :3] = [
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ]
    return m


def translation_matrix(offset) -> np.ndarray:
    """(4, 4) translation by `offset`."""
    m = np.eye(4)
    m[:3, 3] = _vec3(offset, "translate")
    return m


def scale_matrix(scale) -> np.ndarray:
    """(4, 4) scale about the origin; `scale` is a number or 3 numbers."""
    return np.diag(np.append(_vec3(scale, "scale", allow_scalar=True), 1.0))


def transform_matrix(translate=(0.0, 0.0, 0.0), rotate_deg=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0),
                     matrix=None) -> np.ndarray:
    """(4, 4) M = matrix @ T @ Rz @ Ry @ Rx @ S.

    Applied to a point: first scale `S` (a number or 3 numbers, about the origin), then rotate
    about the x axis by rotate_deg[0], then about y by rotate_deg[1], then about z by
    rotate_deg[2] (all about the origin, right-handed, degrees), then translate, and finally the
    optional `matrix` (row-major 4x4, i.e. `matrix[i][j]` is row i, column j).
    """
    r = _vec3(rotate_deg, "rotate_deg")
    m = (translation_matrix(translate)
         @ rotation_matrix((0, 0, 1), r[2])
         @ rotation_matrix((0, 1, 0), r[1])
         @ rotation_matrix((1, 0, 0), r[0])
         @ scale_matrix(scale))
    if matrix is not None:
        extra = np.asarray(matrix, dtype=np.float64)
        if extra.shape != (4, 4) or not np.all(np.isfinite(extra)):
            raise ValueError(f"matrix must be a finite 4x4 array, got shape {extra.shape}")
        m = extra @ m
    return m


def apply_to_points(matrix, points) -> np.ndarray:
    """(N, 3) points mapped by the 4x4 `matrix` (homogeneous divide when the last row is not
    [0, 0, 0, 1])."""
    m = np.asarray(matrix, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    h = p @ m[:3, :3].T + m[:3, 3]
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0]):
        h = h / (p @ m[3, :3] + m[3, 3])[:, None]
    return h


def apply_to_normals(matrix, normals) -> np.ndarray:
    """(N, 3) normals mapped by the inverse-transpose of the 3x3 part of `matrix`, renormalised
    (zero rows stay zero)."""
    m = np.asarray(matrix, dtype=np.float64)[:3, :3]
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3) @ np.linalg.inv(m)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)
