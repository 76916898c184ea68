"""The lecture's texture-mapping chain as matrices: texture (u, v) -> object -> world -> camera ->
screen, composed into one 3x3 projective map, and the mip pyramid the filters read."""

from __future__ import annotations

import numpy as np

from ..renderers.camera import projection_matrix, view_matrix
from ..renderers.compile import object_mesh
from ..renderers.texture.store import mip_pyramid as pyramid


def texture_to_object(mesh) -> np.ndarray:
    """(3, 3) TO of a planar mesh whose uvs are an affine parameterisation (a builtin quad): the
    columns are dp/du, dp/dv and the point at uv = (0, 0), so p = TO @ (u, v, 1), solved by least
    squares over every vertex."""
    uv1 = np.c_[mesh.uvs, np.ones(len(mesh.uvs))]
    solution, *_ = np.linalg.lstsq(uv1, mesh.vertices, rcond=None)
    return solution.T


def texture_to_screen(scene, index: int = 0) -> np.ndarray:
    """(3, 3) TS = CS · OC · TO of the scene's object `index` (a planar, affinely parameterised mesh
    such as a builtin quad): (u, v, 1) -> (x w, y w, w) with (x, y) raster coordinates (pixel (i, j)
    centred at (j + 0.5, i + 0.5)). The object's model transform is already in its world-space mesh
    (OC = view), CS is the projection followed by the viewport, dropping depth. The inverse maps
    raster points back to (u, v): both are projective maps."""
    cam = scene.camera
    to = texture_to_object(object_mesh(scene.objects[index]))
    viewport = np.array([[cam.width / 2, 0, 0, cam.width / 2], [0, -cam.height / 2, 0, cam.height / 2], [0, 0, 0, 1.0]])
    cs = viewport @ projection_matrix(cam)  # 3 x 4: clip -> (x w, y w, w)
    oc = view_matrix(cam)
    return cs @ oc @ np.vstack([to, [0.0, 0.0, 1.0]])


def apply_projective(matrix, points) -> np.ndarray:
    """(N, 2) points mapped by a 3x3 projective `matrix` (homogeneous divide)."""
    p = np.c_[np.asarray(points, float), np.ones(len(points))] @ np.asarray(matrix, float).T
    return p[:, :2] / p[:, 2:]


def mip_pyramid(image) -> list[np.ndarray]:
    """The mip levels of an (H, W, C) image as the texture filters use them: level 0 is the image,
    each next level half as wide and high (rounded down) and the mean of its exact footprint on the
    previous one (the 2x2 box mean for even sizes; every level keeps the image's mean), down to 1 x 1."""
    return pyramid(np.asarray(image, np.float32))
