"""Camera matrices (OpenGL conventions) and the camera as kernels see it.

World space is right-handed, y up; camera space looks down -z. `view_matrix` maps world to camera
space, `projection_matrix` camera to clip space (OpenGL's glFrustum / glOrtho forms, depth in
[-1, 1] after division), and the viewport maps NDC to raster coordinates with row 0 at the top:
x_raster = (x_ndc + 1) W / 2, y_raster = (1 - y_ndc) H / 2. Pixel (i, j) has its centre at
(j + 0.5, i + 0.5).

Rays are built from the camera's basis, not by unprojecting through the (float32) inverse
view-projection matrix, whose rounding grows with far / near and with the eye's distance from the
origin: raster point (x, y) has NDC (a, b) = (2 x / W - 1, 1 - 2 y / H) and camera-plane offset
a * half_w * right + b * half_h * up, where half_h = tan(fov_y / 2) (perspective) or ortho_height / 2
(orthographic) and half_w = half_h * W / H -- the same NDC as the projection matrices give.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from .._warp import wp

from ..geometry import look_at, orthographic, perspective


@wp.struct
class CameraW:
    """What kernels need of the camera. `width`, `height` are of the sample grid (pixels x sqrt(spp))."""

    eye: wp.vec3
    center: wp.vec3  # the target: orthographic rays' hits are computed from their points beside it (`line_point`)
    forward: wp.vec3  # unit view direction (camera -z)
    right: wp.vec3  # unit camera +x
    up: wp.vec3  # unit camera +y
    half_w: float  # half the view's width: at unit distance (perspective) or in scene units (orthographic)
    half_h: float  # half the view's height, likewise: tan(fov_y / 2) or ortho_height / 2
    near: float  # near plane's distance along `forward`
    view_proj: wp.mat44  # world -> clip
    perspective: int  # 1 perspective, 0 orthographic
    width: int
    height: int


def camera_frame(camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) unit vectors of the camera in world space (rows of the view matrix)."""
    m = view_matrix(camera)
    return m[0, :3], m[1, :3], -m[2, :3]


def view_matrix(camera) -> np.ndarray:
    """World -> camera space (4x4, float64): gluLookAt (`geometry.look_at`)."""
    return look_at(camera.eye, camera.target, camera.up)


def projection_matrix(camera, width: int | None = None, height: int | None = None) -> np.ndarray:
    """Camera -> clip space (4x4, float64): gluPerspective with vertical `fov_y`, or glOrtho with a
    view volume `ortho_height` tall (`geometry.perspective` / `geometry.orthographic`);
    aspect = width / height."""
    width = camera.width if width is None else width
    height = camera.height if height is None else height
    if camera.projection == "perspective":
        return perspective(camera.fov_y, width / height, camera.near, camera.far)
    return orthographic(camera.ortho_height, width / height, camera.near, camera.far)


def half_height(camera) -> float:
    """Half the view's height: at unit distance, tan(fov_y / 2) (perspective), or in scene units,
    ortho_height / 2 (orthographic)."""
    if camera.projection == "perspective":
        return math.tan(math.radians(camera.fov_y) / 2.0)
    return camera.ortho_height / 2.0


def pixel_size_at(camera, distance: float, height: int) -> float:
    """World-space height of one raster row at `distance` in front of the camera."""
    if camera.projection == "perspective":
        return 2.0 * distance * half_height(camera) / height
    return 2.0 * half_height(camera) / height


@functools.lru_cache(maxsize=64)
def camera_struct(camera, width: int, height: int) -> CameraW:
    """The `CameraW` for a sample grid of width x height (a scene `Camera`: frozen, so each one's
    struct is built once and shared -- read-only -- by later frames of that camera: ~0.3 ms of a
    small frame)."""
    view = view_matrix(camera)
    view_proj = projection_matrix(camera, width, height) @ view
    right, up, forward = camera_frame(camera)
    out = CameraW()
    out.eye = wp.vec3(*camera.eye)
    out.center = wp.vec3(*camera.target)
    out.forward, out.right, out.up = wp.vec3(*forward), wp.vec3(*right), wp.vec3(*up)
    out.half_h = half_height(camera)
    out.half_w = out.half_h * width / height
    out.near = float(camera.near)
    out.view_proj = wp.mat44(*view_proj.astype(np.float32).ravel())
    out.perspective = 1 if camera.projection == "perspective" else 0
    out.width, out.height = int(width), int(height)
    return out


@wp.func
def view_direction(cam: CameraW, p: wp.vec3):
    """Unit direction from p to the viewer: to the eye (perspective), or -forward (orthographic)."""
    if cam.perspective == 1:
        return wp.normalize(cam.eye - p)
    return -cam.forward


@wp.func
def primary_ray(cam: CameraW, x: float, y: float):
    """Origin and unit direction of the ray through raster point (x, y) of the grid `cam` was built
    for: from the eye along normalize(forward + offset) (perspective), or from the eye's plane at
    eye + offset along forward (orthographic); offset = a half_w right + b half_h up (module doc).
    Rays start there, not on the near plane: see `near_distance`."""
    offset = view_offset(cam, x, y)
    if cam.perspective == 1:
        return cam.eye, wp.normalize(cam.forward + offset)
    return cam.eye + offset, cam.forward


@wp.func
def view_offset(cam: CameraW, x: float, y: float):
    """a half_w right + b half_h up for raster point (x, y) (`primary_ray`)."""
    return (2.0 * x / float(cam.width) - 1.0) * cam.half_w * cam.right \
        + (1.0 - 2.0 * y / float(cam.height)) * cam.half_h * cam.up


@wp.func
def line_point(cam: CameraW, x: float, y: float):
    """A point of the orthographic `primary_ray` through raster point (x, y) near the scene, where
    float32 holds its line as precisely as the scene's coordinates: the target moved by the ray's
    offset (its origin on the eye's plane is rounded to ulps of the eye's coordinates, 2.4e-4 at
    5000, which the hits found from it would carry). A perspective ray's is the eye."""
    if cam.perspective == 1:
        return cam.eye
    return cam.center + view_offset(cam, x, y)


@wp.func
def near_distance(cam: CameraW, direction: wp.vec3):
    """How far a `primary_ray` of unit `direction` travels from its origin to the near plane."""
    return cam.near / wp.dot(direction, cam.forward)
