"""Face normals, face areas and averaged vertex normals (for flat, Gouraud and Phong shading).

A face is *degenerate* when its area is below `DEGENERATE_RELATIVE_AREA` times the largest face
area of the mesh (or exactly zero). Degenerate faces get a zero face normal and are skipped when
vertex normals are averaged, so no NaN ever comes out of these functions.
"""

from __future__ import annotations

import numpy as np

from difflab.errors import MeshError

DEGENERATE_RELATIVE_AREA = 1e-12
WEIGHTINGS = ("area", "angle", "uniform")


def _check(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"faces must have shape (F, 3), got {f.shape}")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= v.shape[0]):
        raise MeshError(f"face index out of range (mesh has {v.shape[0]} vertices)")
    return v, f


def _cross(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Unnormalised face normals: (b - a) x (c - a), length = twice the face area."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return np.cross(b - a, c - a)


def _valid(cross: np.ndarray) -> np.ndarray:
    """Mask of non-degenerate faces, given their unnormalised normals."""
    twice_area = np.linalg.norm(cross, axis=1)
    if twice_area.size == 0:
        return np.zeros(0, dtype=bool)
    threshold = DEGENERATE_RELATIVE_AREA * twice_area.max()
    return (twice_area > threshold) & (twice_area > 0.0)


def face_areas(vertices, faces) -> np.ndarray:
    """(F,) triangle areas."""
    v, f = _check(vertices, faces)
    return 0.5 * np.linalg.norm(_cross(v, f), axis=1)


def degenerate_faces(vertices, faces) -> np.ndarray:
    """(F,) bool: True where a face is degenerate (see the module docstring)."""
    v, f = _check(vertices, faces)
    return ~_valid(_cross(v, f))


def face_normals(vertices, faces) -> np.ndarray:
    """(F, 3) unit face normals by the right-hand rule over (a, b, c); zero rows for degenerate
    faces."""
    v, f = _check(vertices, faces)
    cross = _cross(v, f)
    valid = _valid(cross)
    out = np.zeros_like(cross)
    out[valid] = cross[valid] / np.linalg.norm(cross[valid], axis=1, keepdims=True)
    return out


def _corner_angles(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(F, 3) interior angle of each triangle at each of its corners."""
    angles = np.zeros(f.shape, dtype=np.float64)
    for k in range(3):
        p = v[f[:, k]]
        e1 = v[f[:, (k + 1) % 3]] - p
        e2 = v[f[:, (k + 2) % 3]] - p
        # atan2(|e1 x e2|, e1 . e2) is accurate for all angles and never NaN.
        angles[:, k] = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=1),
                                  np.einsum("ij,ij->i", e1, e2))
    return angles


def vertex_normals(vertices, faces, weighting: str = "area", welds=None) -> np.ndarray:
    """(V, 3) unit vertex normals: the normalised sum of the normals of the adjacent faces.

    `weighting`:
    - "area" (default): each face normal weighted by the face's area (the sum of the
      unnormalised cross products), so large faces dominate;
    - "angle": weighted by the face's interior angle at the vertex (Thürmer & Wüthrich), which
      does not depend on how a flat region is triangulated;
    - "uniform": plain average of the unit face normals (Gouraud's original).

    Degenerate faces are skipped. A vertex with no non-degenerate adjacent face (unused, or only
    on degenerate faces) gets the zero vector (0, 0, 0); so does a vertex whose weighted normals
    cancel exactly. Callers that need a unit normal everywhere must handle zero rows.

    `welds` ((V,) integers >= 0, optional): vertices with one number are copies of one position
    (a vertex split at a uv seam): each gets the sum over all the copies' faces, so a seam shades
    as the unsplit surface.
    """
    if weighting not in WEIGHTINGS:
        raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    v, f = _check(vertices, faces)
    cross = _cross(v, f)
    valid = _valid(cross)
    f_ok = f[valid]
    cross = cross[valid]
    unit = cross / np.linalg.norm(cross, axis=1, keepdims=True) if cross.size else cross
    acc = np.zeros_like(v)
    if weighting == "area":
        for k in range(3):
            np.add.at(acc, f_ok[:, k], cross)
    elif weighting == "uniform":
        for k in range(3):
            np.add.at(acc, f_ok[:, k], unit)
    else:
        angles = _corner_angles(v, f_ok)
        for k in range(3):
            np.add.at(acc, f_ok[:, k], unit * angles[:, k:k + 1])
    if welds is not None:
        welds = np.asarray(welds)
        merged = np.zeros((int(welds.max()) + 1, 3))
        np.add.at(merged, welds, acc)
        acc = merged[welds]
    length = np.linalg.norm(acc, axis=1, keepdims=True)
    scale = np.abs(acc).max() if acc.size else 0.0
    ok = length > 1e-300 + 1e-15 * scale
    return np.divide(acc, length, out=np.zeros_like(acc), where=ok)
