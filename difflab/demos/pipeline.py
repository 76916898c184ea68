"""The pipeline's geometry stage for figures: a scene's triangles pushed through the model, viewing
and projection transforms to raster coordinates (the lecture's "wireframe view of the test scene")."""

from __future__ import annotations

import numpy as np

from .. import geometry
from ..renderers.camera import projection_matrix, view_matrix
from ..renderers.compile import object_mesh
from ..scene import Mesh, Sphere


def wireframe(scene, width: int | None = None, height: int | None = None) -> np.ndarray:
    """(E, 2, 2) raster coordinates of every triangle edge of the scene's meshes and spheres (spheres
    as 12 x 24 uv spheres; planes are left out: they are infinite), seen by the scene's camera at
    width x height pixels (default: the camera's). Edges with an end behind the near plane are
    dropped (the pipeline would clip them)."""
    width, height = width or scene.camera.width, height or scene.camera.height
    view_proj = projection_matrix(scene.camera, width, height) @ view_matrix(scene.camera)
    segments = []
    for obj in scene.objects:
        if isinstance(obj, Mesh):
            mesh = object_mesh(obj)
        elif isinstance(obj, Sphere):
            mesh = geometry.uv_sphere(obj.radius, obj.center, 12, 24)
        else:
            continue
        clip = np.c_[mesh.vertices, np.ones(len(mesh.vertices))] @ view_proj.T
        raster = geometry.ndc_to_raster(clip[:, :3] / clip[:, 3:], width, height)
        edges = np.unique(np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
        front = (clip[edges, 2] >= -clip[edges, 3]).all(axis=1)
        segments.append(raster[edges[front]])
    return np.concatenate(segments) if segments else np.zeros((0, 2, 2))
