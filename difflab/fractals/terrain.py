"""Fractal terrain as a triangle mesh (y up), with height bands for materials (water, grass, rock, snow)."""

from __future__ import annotations

import numpy as np

from ..geometry import TriMesh, vertex_normals
from ._checks import FractalError, check_float, check_int
from .heightfield import MAX_LEVEL, diamond_square, midpoint_displacement

TERRAIN_METHODS = {"diamond_square": diamond_square, "midpoint": midpoint_displacement}
#: Band names, lowest first, and their diffuse colours (linear RGB).
TERRAIN_BANDS = ("water", "grass", "rock", "snow")
TERRAIN_COLORS = {
    "water": (0.02, 0.08, 0.35),
    "grass": (0.10, 0.35, 0.06),
    "rock": (0.30, 0.24, 0.18),
    "snow": (0.90, 0.90, 0.95),
}
#: Default band boundaries as fractions of the height range (water below 0.35, snow above 0.8).
TERRAIN_LEVELS = (0.35, 0.6, 0.8)


def grid_faces(n: int) -> np.ndarray:
    """Faces of an (n + 1) x (n + 1) vertex grid, vertex (i, j) at index i (n + 1) + j: each cell
    split along its (i, j)-(i+1, j+1) diagonal, counter-clockwise seen from +y."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()  # (i, j)
    b = a + 1  # (i, j + 1)
    c = a + n + 2  # (i + 1, j + 1)
    d = a + n + 1  # (i + 1, j)
    return np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)]).astype(np.int64)


def terrain(level: int = 6, hurst: float = 0.8, seed: int = 0, size: float = 10.0, height: float = 2.0,
            method: str = "diamond_square") -> TriMesh:
    """A fractal landscape: a height grid turned into a mesh centred on the origin, y up.

    Vertex (i, j) of the (2^level + 1)^2 grid lies at x = (j / 2^level - 1/2) size,
    z = (i / 2^level - 1/2) size, y = height * h[i, j], with h from `diamond_square` or
    `midpoint_displacement` (sigma = 1). The same seed at a lower level gives exactly every
    2^(L - l)-th vertex of the finer mesh.

    Arguments:
        level: 1..12 refinement steps.
        hurst: Hurst exponent in (0, 1) (roughness: lower is rougher).
        seed: integer >= 0.
        size: side of the square in world units (> 0).
        height: vertical scale in world units (>= 0).
        method: "diamond_square" (grid) or "midpoint" (Fournier-Fussell-Carpenter triangles).

    Returns:
        TriMesh with area-weighted vertex normals and uvs (j, i) / 2^level.
    """
    if method not in TERRAIN_METHODS:
        raise FractalError(f"method: expected one of {sorted(TERRAIN_METHODS)}, got {method!r}")
    size = check_float("size", size, 0.0, lo_open=True)
    height = check_float("height", height, 0.0)
    level = check_int("level", level, 1, MAX_LEVEL)  # level 0 is a single cell corner set: no mesh
    h = TERRAIN_METHODS[method](level, hurst, seed)
    n = h.shape[0] - 1
    t = np.arange(n + 1) / n
    zz, xx = np.meshgrid(t, t, indexing="ij")
    vertices = np.stack([(xx - 0.5) * size, height * h, (zz - 0.5) * size], axis=-1).reshape(-1, 3)
    faces = grid_faces(n)
    uvs = np.stack([xx, zz], axis=-1).reshape(-1, 2)
    return TriMesh(vertices, faces, normals=vertex_normals(vertices, faces), uvs=uvs, name="terrain")


def _heights(mesh_or_heights) -> np.ndarray:
    if isinstance(mesh_or_heights, TriMesh):
        return mesh_or_heights.vertices[:, 1]
    return np.asarray(mesh_or_heights, dtype=np.float64).ravel()


def terrain_bands(mesh_or_heights, levels=TERRAIN_LEVELS) -> np.ndarray:
    """Band index per vertex (0 water, 1 grass, 2 rock, 3 snow) by height.

    Arguments:
        mesh_or_heights: a TriMesh (its y) or an array of heights.
        levels: three increasing fractions of the height range [min, max] where bands change.

    Returns:
        (V,) int64.
    """
    y = _heights(mesh_or_heights)
    levels = np.asarray(levels, dtype=np.float64)
    if levels.shape != (3,) or not np.all(np.isfinite(levels)) or np.any(np.diff(levels) <= 0):
        raise FractalError(f"levels: expected 3 increasing fractions, got {levels.tolist()}")
    span = np.ptp(y)
    t = (y - y.min()) / span if span > 0 else np.zeros_like(y)
    return np.searchsorted(levels, t, side="right").astype(np.int64)


def terrain_colors(mesh_or_heights, levels=TERRAIN_LEVELS) -> np.ndarray:
    """Per-vertex diffuse colours (V, 3) float64 from `terrain_bands` and `TERRAIN_COLORS`."""
    palette = np.array([TERRAIN_COLORS[name] for name in TERRAIN_BANDS])
    return palette[terrain_bands(mesh_or_heights, levels)]


def terrain_parts(mesh: TriMesh, levels=TERRAIN_LEVELS) -> dict[str, TriMesh]:
    """The terrain split into one mesh per band (a face goes to the band of its highest vertex),
    for renderers that take one material per object. Bands with no faces are left out."""
    band = terrain_bands(mesh, levels)[mesh.faces].max(axis=1)
    parts = {}
    for k, name in enumerate(TERRAIN_BANDS):
        faces = mesh.faces[band == k]
        if len(faces):
            parts[name] = TriMesh(mesh.vertices, faces, normals=mesh.normals, uvs=mesh.uvs, name=f"terrain/{name}")
    return parts
