"""`TriMesh`: an immutable, validated triangle mesh (numpy arrays), and `concatenate`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from difflab.errors import MeshError

from .normals import vertex_normals
from .transforms import apply_to_normals, unit_linear_part


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.array(array, copy=True)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class TriMesh:
    """A triangle mesh.

    - `vertices` (V, 3) float64, finite.
    - `faces` (F, 3) int64 indices into `vertices`, F >= 1; counter-clockwise seen from the front
      (the right-hand rule gives the outward/front face normal).
    - `normals` (V, 3) float64 per-vertex shading normals, or None (then renderers use
      `vertex_normals` or flat face normals).
    - `uvs` (V, 2) float64 texture coordinates, or None.
    - `welds` (V,) int64 position numbers, or None (every vertex its own): vertices with one number
      are copies of one position -- an OBJ `v` split at a uv seam, its `v` index -- and share one
      smooth normal (`smooth_normals`), as the unsplit surface gives them.

    The arrays are converted to those dtypes, copied and made read-only, so a TriMesh never changes
    after construction. Invalid input raises `MeshError` naming the problem. `name` is a free label
    (a file path for loaded meshes) used in error messages.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    name: str = "mesh"
    welds: np.ndarray | None = None

    def __post_init__(self) -> None:
        where = self.name
        try:
            vertices = np.asarray(self.vertices, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise MeshError(f"{where}: vertices are not numeric: {exc}") from None
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise MeshError(f"{where}: vertices must have shape (V, 3), got {vertices.shape}")
        if not np.all(np.isfinite(vertices)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(vertices), axis=1))[0])
            raise MeshError(f"{where}: vertex {bad} is not finite: {vertices[bad].tolist()}")

        faces_in = np.asarray(self.faces)
        if faces_in.size and not (np.issubdtype(faces_in.dtype, np.integer)
                                  or (np.issubdtype(faces_in.dtype, np.floating)
                                      and np.all(np.isfinite(faces_in))
                                      and np.all(faces_in == np.round(faces_in)))):
            raise MeshError(f"{where}: face indices must be integers, got dtype {faces_in.dtype}")
        faces = faces_in.astype(np.int64)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise MeshError(f"{where}: faces must have shape (F, 3), got {faces.shape}")
        if faces.shape[0] == 0:
            raise MeshError(f"{where}: mesh has no faces")
        n_vertices = vertices.shape[0]
        out_of_range = (faces < 0) | (faces >= n_vertices)
        if np.any(out_of_range):
            f = int(np.flatnonzero(np.any(out_of_range, axis=1))[0])
            raise MeshError(
                f"{where}: face {f} has index out of range {faces[f].tolist()} "
                f"(mesh has {n_vertices} vertices)")

        normals = self.normals
        if normals is not None:
            normals = np.asarray(normals, dtype=np.float64)
            if normals.shape != (n_vertices, 3):
                raise MeshError(f"{where}: normals must have shape ({n_vertices}, 3), "
                                f"got {normals.shape}")
            if not np.all(np.isfinite(normals)):
                raise MeshError(f"{where}: normals are not all finite")
            normals = _frozen(normals)
        uvs = self.uvs
        if uvs is not None:
            uvs = np.asarray(uvs, dtype=np.float64)
            if uvs.shape != (n_vertices, 2):
                raise MeshError(f"{where}: uvs must have shape ({n_vertices}, 2), got {uvs.shape}")
            if not np.all(np.isfinite(uvs)):
                raise MeshError(f"{where}: uvs are not all finite")
            uvs = _frozen(uvs)
        welds = self.welds
        if welds is not None:
            welds = np.asarray(welds)
            if welds.shape != (n_vertices,) or not np.issubdtype(welds.dtype, np.integer) or np.any(welds < 0):
                raise MeshError(f"{where}: welds must be ({n_vertices},) integers >= 0, got {welds.dtype} {welds.shape}")
            welds = _frozen(welds.astype(np.int64))

        object.__setattr__(self, "vertices", _frozen(vertices))
        object.__setattr__(self, "faces", _frozen(faces))
        object.__setattr__(self, "normals", normals)
        object.__setattr__(self, "uvs", uvs)
        object.__setattr__(self, "welds", welds)

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    def bounds(self) -> np.ndarray:
        """(2, 3): the axis-aligned bounding box, [min corner, max corner]."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def smooth_normals(self) -> np.ndarray:
        """(V, 3) the mesh's normals, or where it has none its smooth vertex normals
        (`vertex_normals`, area-weighted) summed over each position's copies (`welds`)."""
        return self.normals if self.normals is not None else vertex_normals(self.vertices, self.faces, welds=self.welds)

    def transformed(self, matrix) -> "TriMesh":
        """A new mesh with every vertex mapped by the 4x4 `matrix` (column vectors: p' = M p).

        Points get the full affine map (with a homogeneous divide if the last row is not
        [0, 0, 0, 1]); normals get the inverse-transpose of the upper-left 3x3 block and are
        renormalised (`apply_to_normals`: no overflow for tiny or huge scales; zero normals stay zero). If the 3x3 block has a negative determinant (a
        mirror), the face winding is reversed so that faces stay counter-clockwise seen from the
        outside. A singular matrix raises `MeshError`. uvs are unchanged.
        """
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise MeshError(
                f"{self.name}: transform must be a finite 4x4 matrix, got shape {m.shape}")
        linear = m[:3, :3]
        try:
            _, sign = unit_linear_part(linear)  # singular only at det exactly 0: relative, any scale
        except ValueError as exc:
            raise MeshError(f"{self.name}: transform: {exc}") from None
        homogeneous = np.concatenate([self.vertices, np.ones((self.n_vertices, 1))], axis=1)
        mapped = homogeneous @ m.T
        w = mapped[:, 3:4]
        if np.allclose(m[3], [0.0, 0.0, 0.0, 1.0]):
            points = mapped[:, :3]
        else:
            if np.any(np.abs(w) < 1e-300):
                raise MeshError(f"{self.name}: projective transform sends a vertex to infinity")
            points = mapped[:, :3] / w
        normals = None if self.normals is None else apply_to_normals(linear, self.normals)
        faces = self.faces if sign > 0 else self.faces[:, ::-1]
        return TriMesh(points, faces, normals, self.uvs, name=self.name, welds=self.welds)


def concatenate(meshes: Iterable[TriMesh], name: str = "mesh") -> TriMesh:
    """One mesh holding all of `meshes` (faces re-indexed). Normals and uvs are kept only if every
    mesh has them; `welds` if any has them (numbered apart per mesh). An empty list raises `MeshError`."""
    meshes = list(meshes)
    if not meshes:
        raise MeshError(f"{name}: cannot concatenate an empty list of meshes")
    for i, mesh in enumerate(meshes):
        if not isinstance(mesh, TriMesh):
            raise MeshError(f"{name}: item {i} is {type(mesh).__name__}, not a TriMesh")
    offsets = np.cumsum([0] + [m.n_vertices for m in meshes[:-1]])
    vertices = np.concatenate([m.vertices for m in meshes])
    faces = np.concatenate([m.faces + off for m, off in zip(meshes, offsets)])
    normals = (np.concatenate([m.normals for m in meshes])
               if all(m.normals is not None for m in meshes) else None)
    uvs = (np.concatenate([m.uvs for m in meshes])
           if all(m.uvs is not None for m in meshes) else None)
    welds = None
    if any(m.welds is not None for m in meshes):
        own = [m.welds if m.welds is not None else np.arange(m.n_vertices) for m in meshes]
        starts = np.cumsum([0] + [int(w.max()) + 1 for w in own[:-1]])
        welds = np.concatenate([w + start for w, start in zip(own, starts)])
    return TriMesh(vertices, faces, normals, uvs, name=name, welds=welds)


def weld(vertices: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices closer than about `tol` (coordinates snapped to a grid of `tol`).

    Returns (unique_vertices, inverse) with `unique_vertices[inverse] ~= vertices`. The first
    occurrence of each position is kept, in order of first appearance. Points that straddle a grid
    cell boundary by less than `tol` may stay separate; meshes built from shared control points
    (the teapot) give bitwise-equal duplicates, which always merge.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    keys = np.round(vertices / tol).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    # Renumber in order of first appearance so the result does not depend on lexicographic order.
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return vertices[first[order]], rank[inverse]
