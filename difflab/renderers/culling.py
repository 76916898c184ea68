"""Back faces that cannot show: when the z-buffers of both renderers (the rasterizer's, and the ray
tracer's item buffer) may leave them out without changing a frame.

A set of triangles whose pieces are closed solids facing out (`geometry.solid_pieces`), none of
them passing through itself (`raytrace/selfcross.py`: a self-intersection can turn a region inside
out), seen by a camera whose near plane lies in front of all of them: every primary ray then starts
outside every solid, so along it each back face the ray meets (leaving a solid) comes after the front
face through which it entered that solid -- the back faces never are the nearest triangle (bar depth
ties: see the rasterizer's tests). Open meshes, planes' grids or inside-out pieces make no solid:
nothing is culled then.
"""

from __future__ import annotations

import itertools

import numpy as np

from .._warp import wp
from ..geometry import solid_pieces
from .camera import camera_frame
from .raytrace.selfcross import passes_through_itself

SOLIDS = "solid triangles"  # compiled.built key prefix: per triangle count, their bounding box when solids, else None
NEAR_MARGIN = 1.0e-4  # back faces are culled when the triangles lie this far (relative) beyond the near plane


def culls_back_faces(compiled, n_faces: int, n_vertices: int, threads: int | None = None) -> bool:
    """Whether a z-buffer of the compiled scene's first `n_faces` triangles (on its first `n_vertices`
    vertices) may leave their back faces out (module doc): the triangles are closed solids facing out,
    no piece passes through itself, and their bounding box lies beyond the near plane by NEAR_MARGIN
    (relative to the coordinates' size). The triangles are asked once per compiled scene and count;
    the camera's 8 box corners are tested on each call (nothing kept per camera)."""
    key = (SOLIDS, n_faces, n_vertices)
    if key not in compiled.built:
        compiled.built[key] = solid_box(compiled, n_faces, n_vertices, threads)
    box = compiled.built[key]
    if box is None:
        return False
    camera = compiled.scene.camera
    corners = np.array(list(itertools.product(*zip(*box))), np.float64)
    eye = np.asarray(camera.eye, np.float64)
    size = camera.near + np.abs(corners).max() + np.abs(eye).max()
    return bool(((corners - eye) @ camera_frame(camera)[2]).min() > camera.near + NEAR_MARGIN * size)


def solid_box(compiled, n_faces: int, n_vertices: int, threads: int | None = None):
    """The bounding box (lower, upper corner) of the first `n_faces` triangles when they are solids
    not passing through themselves (`culls_back_faces`), else None."""
    vertices = compiled.arrays["vertices"].numpy()[:n_vertices]
    faces = compiled.faces[:n_faces]
    pieces = solid_pieces(vertices, faces)
    if pieces is None:
        return None
    if n_faces == compiled.n_mesh_faces:
        compiled.traceable()  # the mesh faces' BVH, which rays use too
        bvh = compiled.built["bvh"]
    else:  # more triangles than the mesh objects' (tessellated spheres): a BVH for this test only
        bvh = wp.Mesh(points=compiled.arrays["vertices"], indices=wp.array(
            np.ascontiguousarray(faces).ravel(), dtype=wp.int32, device=compiled.device))
    if passes_through_itself(bvh, *pieces, threads=threads):
        return None
    return vertices.min(axis=0), vertices.max(axis=0)
