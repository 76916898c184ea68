"""Rasterizer stage 5 under flat and Gouraud shading: the mesh's own shading points (Phong's are its
samples, `resolve`). Flat: a point per face, at its centroid with the face normal; Gouraud: two per
vertex, with the vertex normal and its negation (OpenGL's two-sided lighting)."""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import MaterialW
from ...vocabulary import FLAT
from ..camera import CameraW, view_direction
from .resolve import PointsW, RasterMeshW, make_point, store_point

wp.set_module_options({"enable_backward": False})


@wp.func(inline=True)
def mesh_point(mesh: RasterMeshW, materials: wp.array(dtype=MaterialW), cam: CameraW, shading: int, k: int):
    """Shading point k of flat or Gouraud shading. Flat: face k's centroid, with the face normal
    turned toward the viewer. Gouraud: two points per vertex, the front copy (k < V) with the vertex
    normal, the back copy (k - V) with its negation, for back-facing triangles (OpenGL's two-sided
    lighting)."""
    if shading == FLAT:
        f = k
        p = (mesh.vertices[mesh.faces[f, 0]] + mesh.vertices[mesh.faces[f, 1]] + mesh.vertices[mesh.faces[f, 2]]) / 3.0
        view = view_direction(cam, p)
        normal = mesh.face_normal[f]
        if wp.dot(normal, view) < 0.0:
            normal = -normal
        return make_point(p, normal, normal, view, mesh.face_material[f], materials, mesh, mesh.face_object[f],
                          mesh.face_normal[f])
    n_vertices = mesh.vertices.shape[0]
    v = k % n_vertices
    p = mesh.vertices[v]
    normal = mesh.normals[v]
    if k >= n_vertices:
        normal = -normal
    return make_point(p, normal, normal, view_direction(cam, p), mesh.vertex_material[v], materials, mesh,
                      mesh.vertex_object[v], mesh.normals[v])


@wp.kernel
def mesh_points_kernel(begin: int, end: int, chunk: int, mesh: RasterMeshW, materials: wp.array(dtype=MaterialW),
                       cam: CameraW, shading: int, points: PointsW):
    """Stage 5 for flat / Gouraud shading: points [begin, end), `chunk` per thread."""
    first = begin + wp.tid() * chunk
    for k in range(first, wp.min(first + chunk, end)):
        store_point(points, k, mesh_point(mesh, materials, cam, shading, k))
