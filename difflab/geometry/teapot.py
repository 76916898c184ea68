"""The Utah teapot, tessellated from Newell's 32 bicubic Bezier patches."""

from __future__ import annotations

import numpy as np

from difflab.errors import MeshError
from difflab.limits import require_triangles

from .mesh import TriMesh, weld
from .normals import degenerate_faces, vertex_normals
from .teapot_data import TEAPOT_PATCHES_1BASED, TEAPOT_POINTS

WELD_TOLERANCE = 1e-9

# Classic data is z up with the spout toward +x; difflab is y up. Rotating -90 degrees about x
# maps (x, y, z) -> (x, z, -y): the spout stays at +x, the bottom (z = 0) lands on y = 0.
_Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0],
                          [0.0, 0.0, 1.0],
                          [0.0, -1.0, 0.0]])


def teapot_control_points() -> np.ndarray:
    """(306, 3) float64: the classic control points as listed (z up, spout toward +x)."""
    return np.array(TEAPOT_POINTS, dtype=np.float64)


def teapot_patches() -> np.ndarray:
    """(32, 16) int64: the patches' control-point indices, 0-based, row-major 4 x 4 per patch."""
    return np.array(TEAPOT_PATCHES_1BASED, dtype=np.int64) - 1


def _bernstein(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Bernstein basis and its derivative at parameters t: two (len(t), 4) arrays."""
    s = 1.0 - t
    basis = np.stack([s ** 3, 3 * t * s ** 2, 3 * t ** 2 * s, t ** 3], axis=-1)
    deriv = np.stack([-3 * s ** 2, 3 * s ** 2 - 6 * t * s, 6 * t * s - 3 * t ** 2, 3 * t ** 2],
                     axis=-1)
    return basis, deriv


def _grid_faces(n: int) -> np.ndarray:
    """Triangles of an (n+1) x (n+1) vertex grid (row a = t index, column b = s index), wound so
    that the face normal is along dP/ds x dP/dt."""
    a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    p00 = (a * (n + 1) + b).ravel()
    p01 = p00 + 1
    p10 = p00 + (n + 1)
    p11 = p10 + 1
    return np.concatenate([np.stack([p00, p01, p11], axis=1), np.stack([p00, p11, p10], axis=1)])


def evaluate_patches(resolution: int = 8):
    """Evaluate all 32 patches (classic z-up frame) on a (resolution+1)^2 grid of (s, t) in
    [0, 1]^2, s along a control-point row and t across rows.

    Returns (points, tangent_cross, uvs), shapes (32, (r+1)^2, 3), (32, (r+1)^2, 3) and
    ((r+1)^2, 2). `tangent_cross` = dP/ds x dP/dt, which points out of the teapot for every patch of
    the classic data; it is zero where a patch collapses to a point.
    """
    control = teapot_control_points()[teapot_patches()].reshape(32, 4, 4, 3)
    params = np.linspace(0.0, 1.0, resolution + 1)
    basis, deriv = _bernstein(params)
    points = np.einsum("ai,bj,pijk->pabk", basis, basis, control)
    d_s = np.einsum("ai,bj,pijk->pabk", basis, deriv, control)
    d_t = np.einsum("ai,bj,pijk->pabk", deriv, basis, control)
    cross = np.cross(d_s, d_t)
    t_grid, s_grid = np.meshgrid(params, params, indexing="ij")
    uvs = np.stack([s_grid, t_grid], axis=-1).reshape(-1, 2)
    n_grid = (resolution + 1) ** 2
    return points.reshape(32, n_grid, 3), cross.reshape(32, n_grid, 3), uvs


def teapot(resolution: int = 8, weld_vertices: bool = True) -> TriMesh:
    """The Utah teapot (Newell's 32 patches, including the 4 bottom patches), y up, standing on
    y = 0 with the spout toward +x; height 3.15, x from -3.0 (handle) to 3.525 (spout tip).

    Each patch is evaluated on a (resolution+1)^2 grid (2 * resolution^2 triangles per patch).
    With `weld_vertices` (default) duplicate vertices (within 1e-9) are merged so the mesh is
    connected along patch boundaries, and triangles that collapse (at the lid knob's top and the
    bottom centre) are dropped. Normals come from the analytic patch derivatives (dP/ds x dP/dt,
    outward), averaged over the patches that share a welded vertex; where the derivatives vanish
    (the collapsed points) the area-weighted face-averaged normal is used. The welded mesh has
    `uvs = None` (patch parameters disagree across patch seams); with `weld_vertices=False` every
    patch keeps its own vertices and uvs = (s, t) in [0, 1]^2 per patch, as in Blinn's textured
    teapots. Low resolutions (2..4) give the lecture's coarse "teapot-like mesh".

    The classic teapot is not closed: the lid sits in the rim with a gap, the spout and handle
    pierce the body, and the spout's tip is open.
    """
    if int(resolution) != resolution or int(resolution) < 1:
        raise MeshError(f"teapot: resolution must be an integer >= 1, got {resolution!r}")
    r = int(resolution)
    require_triangles(64 * r * r, f"teapot at resolution {r}", MeshError)
    points, cross, patch_uvs = evaluate_patches(r)
    n_grid = (r + 1) ** 2
    grid_faces = _grid_faces(r)
    faces = np.concatenate([grid_faces + k * n_grid for k in range(32)])
    points = points.reshape(-1, 3) @ _Z_UP_TO_Y_UP.T
    cross = cross.reshape(-1, 3) @ _Z_UP_TO_Y_UP.T
    length = np.linalg.norm(cross, axis=1)
    # Zero derivative where a patch collapses to a point (relative to the patch's scale).
    analytic_ok = length > 1e-9 * length.max()
    unit = np.zeros_like(cross)
    unit[analytic_ok] = cross[analytic_ok] / length[analytic_ok, None]

    if weld_vertices:
        vertices, inverse = weld(points, WELD_TOLERANCE)
        faces = inverse[faces]
        summed = np.zeros_like(vertices)
        np.add.at(summed, inverse, unit)
        count_ok = np.zeros(len(vertices))
        np.add.at(count_ok, inverse, analytic_ok.astype(np.float64))
        uvs = None
    else:
        vertices, summed, uvs = points, unit.copy(), np.tile(patch_uvs, (32, 1))
        count_ok = analytic_ok.astype(np.float64)

    # Drop triangles with a repeated vertex or (numerically) zero area.
    keep = ((faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])
            & (faces[:, 0] != faces[:, 2]))
    faces = faces[keep]
    faces = faces[~degenerate_faces(vertices, faces)]
    # Drop vertices no triangle uses any more (collapsed duplicates when not welding).
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    vertices, summed, count_ok = vertices[used], summed[used], count_ok[used]
    if uvs is not None:
        uvs = uvs[used]
    faces = remap[faces]

    normals = np.zeros_like(vertices)
    norm = np.linalg.norm(summed, axis=1)
    good = (count_ok > 0) & (norm > 1e-6)
    normals[good] = summed[good] / norm[good, None]
    fallback = vertex_normals(vertices, faces, weighting="area")
    normals[~good] = fallback[~good]
    return TriMesh(vertices, faces, normals, uvs, name=f"teapot(resolution={r})")
