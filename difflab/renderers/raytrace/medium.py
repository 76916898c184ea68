"""The medium the camera is in: where primary rays start their Beer absorption.

A ray refracted into an object travels in its medium (`RayW.medium`, its material) until it leaves
through a surface's back side (`surface.py`). A camera inside a transparent object starts its
primary rays in that object's medium: found once per frame by walking a ray from the eye along the
view direction through every surface it crosses (each crossing counted from `epsilon` past the last)
and keeping a depth count, +1 entering a surface (hitting the side its stored normal points to:
outward for spheres, the plane's normal, the winding normal for triangles), -1 leaving one. The
first crossing that takes the count below 0 leaves an object the eye was inside -- the innermost one
where objects nest -- and its material is the medium (if that object is transparent, kt > 0; an
opaque one has none). Closed objects give the same answer along any walk. A plane, or a mesh that
is not closed, has no inside of its own: its back side counts as inside, as for the rays refracted
through it, so the eye starts in its medium when the walk meets its back first (a slab of two
planes facing out: entered, then left -- no medium). An orthographic camera's rays all start in the
medium found at the eye.
"""

from __future__ import annotations

import numpy as np
from ..._warp import wp

from ...lighting.warp_model import MaterialW
from ..camera import camera_frame
from ..launch import load_kernels
from ..trace import HIT_NONE, SceneGeomW, closest_hit

wp.set_module_options({"enable_backward": False})

MAX_CROSSINGS = 256  # surfaces the walk crosses before it gives up (the eye then starts in no medium)


@wp.func
def eye_medium(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), eye: wp.vec3, direction: wp.vec3):
    """The material id of the medium containing `eye` (module doc), -1 for none."""
    depth = int(0)
    origin = eye
    for crossing in range(MAX_CROSSINGS):
        hit = closest_hit(geom, origin, direction, 0.0, wp.inf, -1)
        if hit.kind == HIT_NONE:
            break
        origin = origin + (hit.t + geom.epsilon) * direction
        if wp.dot(direction, hit.normal) < 0.0:
            depth = depth + 1
        else:
            depth = depth - 1
            if depth < 0:
                if materials[hit.material].kt > 0.0:
                    return hit.material
                return -1
    return -1


@wp.kernel
def eye_medium_kernel(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), eye: wp.vec3, direction: wp.vec3,
                      out: wp.array(dtype=wp.int32)):
    out[0] = eye_medium(geom, materials, eye, direction)


def camera_medium(compiled) -> int:
    """The material id of the medium the compiled scene's camera is in (-1: none); asked only when
    the scene has a transparent material."""
    scene = compiled.scene
    if not any(m.kt > 0 for m in scene.materials.values()):
        return -1
    load_kernels(compiled.device, eye_medium_kernel)
    out = wp.empty(1, dtype=wp.int32, device=compiled.device)
    forward = np.asarray(camera_frame(scene.camera)[2], np.float32)
    wp.launch(eye_medium_kernel, dim=1, inputs=[compiled.traceable(), compiled.materials,
                                                wp.vec3(*scene.camera.eye), wp.vec3(*forward), out],
              device=compiled.device)
    return int(out.numpy()[0])
