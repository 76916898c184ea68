"""The media a primary ray starts in: where its Beer absorption begins.

A ray refracted into an object travels in its medium until it leaves through a surface's back side,
carrying the transparent objects it is inside (`nesting.MediaW`, innermost first). Which objects
hold a point is found by walking a ray from it (`media_at`) through every surface it crosses (each
walked on from just past it: `trace.past_surface`), keeping a depth count: +1 entering a surface
(hitting the side its stored normal points to: outward for spheres, the plane's normal, the winding
normal for triangles), -1 leaving one. Each crossing that takes the count to a new low leaves an
object the point is inside: the first the innermost, the next the one around it, and so on, out to
`nesting.MEDIA_DEPTH` of them or to an opaque one (kt = 0: no medium in it, nor past it for a ray
that cannot leave it). Closed objects give the same answer along any walk. A plane, or a mesh that
is not closed, has no inside of its own: its back side counts as inside, as for the rays refracted
through it, so a point is in its medium when the walk meets its back first (a slab of two planes
facing out: entered, then left -- no medium).

The near plane clips as the rasterizer's does: a primary ray is traced from where it crosses the
near plane, and what lies before that -- surfaces, and the media they bound -- is not seen. So the
ray travels in the medium holding that near-plane point, and absorbs in it from where it entered
it: from its start (the eye; an orthographic ray's point on the eye's plane) when no surface lies
between the start and the near plane -- the image does not depend on `near` while the near plane is
inside the eye's medium -- else from the last such (clipped) surface. An eye inside a bubble that
lies wholly before the near plane sees what is behind the bubble unabsorbed, as the rasterizer
shows it without the bubble.

Cost: a perspective camera's media are walked once per frame, from the eye along the view
direction; each ray then looks back from its near-plane point for a clipped surface (one short
ray), and walks only if it finds one -- and only when some surface comes within the ball around
the eye that holds the near plane's corners (`per_ray_check`). An orthographic camera's rays start
at different points: each walks from its own near-plane point, when some transparent object may
contain one of them (its bounds, a plane's back half-space, any transparent mesh, meet the ball
around the view volume's part before the near plane).
"""

from __future__ import annotations

import math

import numpy as np
from ..._warp import wp

from ...lighting.warp_model import MaterialW
from ...scene import Plane, Sphere
from ..camera import camera_frame, half_height
from ..intersect import HIT_NONE, HitW, SceneGeomW, closest_hit
from ..launch import load_kernels
from ..trace import SPAWN_GRAZING, hit_point, ray_offset, spawn_origin
from .nesting import MEDIA_DEPTH, MediaW, coincident, no_media, outward

wp.set_module_options({"enable_backward": False})

MAX_CROSSINGS = 256  # surfaces a walk crosses before it gives up (the point then is in no medium)


@wp.func
def walked(materials: wp.array(dtype=MaterialW), media: MediaW, depth: int, lowest: int, hit: HitW,
           direction: wp.vec3):
    """A walk's (media, depth, lowest depth, stop) after it crosses `hit` (module doc)."""
    if wp.dot(direction, hit.normal) < 0.0:
        return media, depth + 1, lowest, 0
    if depth - 1 >= lowest:
        return media, depth - 1, lowest, 0
    if materials[hit.material].kt <= 0.0 or media.count == MEDIA_DEPTH:  # an opaque one: no medium in it or past it
        return media, depth - 1, depth - 1, 1
    return outward(media, hit.object, hit.material), depth - 1, depth - 1, 0  # leaves an object around the point


@wp.func
def media_at(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), point: wp.vec3, direction: wp.vec3, probe: int):
    """The transparent objects around `point`, innermost first (`nesting.MediaW`; module doc: the
    walk along unit `direction`). With `probe`, a surface coincident with one crossed (within its
    offset: `nesting.coincident`) is crossed with it, as the tracer's rays cross it."""
    media = no_media()
    depth = int(0)
    lowest = int(0)
    origin = point
    for crossing in range(MAX_CROSSINGS):
        hit = closest_hit(geom, origin, direction, 0.0, wp.inf, -1)
        if hit.kind == HIT_NONE:
            break
        p = hit_point(geom, hit, origin, direction)
        offset = ray_offset(geom, hit, p)
        origin = spawn_origin(p, hit.normal, direction, offset)
        media, depth, lowest, stop = walked(materials, media, depth, lowest, hit, direction)
        if probe == 1 and stop == 0:
            other = coincident(geom, hit.object, p, direction,
                               offset / wp.max(wp.abs(wp.dot(direction, hit.normal)), SPAWN_GRAZING))
            if other.kind != HIT_NONE:
                media, depth, lowest, stop = walked(materials, media, depth, lowest, other, direction)
        if stop == 1:
            break
    return media


@wp.func
def primary_medium(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), start: wp.vec3, direction: wp.vec3,
                   near: float, eye_media: MediaW, perspective: int, probe: int):
    """A primary ray's media and the point its absorption counts from (module doc): the ray leaves
    `start` along unit `direction` and is traced from `near` further on; `eye_media` are the eye's
    (`camera_media`), which a perspective ray keeps when no surface lies before its near plane."""
    origin = start + near * direction
    clipped = closest_hit(geom, origin, -direction, 0.0, near, -1)  # the last surface before the near plane
    if clipped.kind == HIT_NONE:
        if perspective == 1:
            return eye_media, start
        return media_at(geom, materials, origin, direction, probe), start
    return media_at(geom, materials, origin, direction, probe), origin - clipped.t * direction


@wp.kernel
def eye_media_kernel(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), eye: wp.vec3, direction: wp.vec3,
                     probe: int, out: wp.array(dtype=MediaW)):
    out[0] = media_at(geom, materials, eye, direction, probe)


def near_ball(camera) -> tuple[np.ndarray, float]:
    """Centre and radius of a ball holding every primary ray from its start to the near plane: around
    the eye out to the near plane's corners (perspective), or around the middle of the view volume's
    box before the near plane (orthographic)."""
    right, up, forward = camera_frame(camera)
    half_h = half_height(camera)
    half_w = half_h * camera.width / camera.height
    eye = np.asarray(camera.eye, float)
    if camera.projection == "perspective":
        return eye, camera.near * math.sqrt(1.0 + half_w ** 2 + half_h ** 2)
    return eye + 0.5 * camera.near * forward, math.sqrt(half_w ** 2 + half_h ** 2 + (0.5 * camera.near) ** 2)


def per_ray_check(compiled, transparent: set) -> bool:
    """Whether primary rays must find their medium each (`primary_medium`), `transparent` being the
    ids of the materials with kt > 0 (module doc): for a perspective camera, whether some surface
    comes within `near_ball` (a sphere's shell, a plane, the meshes' bounding box); for an
    orthographic one, whether some transparent object may hold a point of it (a sphere's ball, a
    plane's back half-space, any transparent mesh: an open one holds what lies behind it)."""
    scene = compiled.scene
    centre, radius = near_ball(scene.camera)
    perspective = scene.camera.projection == "perspective"
    for obj in scene.objects:
        if not perspective and scene.material_index(obj.material) not in transparent:
            continue
        if isinstance(obj, Sphere):
            gap = float(np.linalg.norm(centre - np.asarray(obj.center))) - obj.radius
            if (abs(gap) if perspective else gap) <= radius:
                return True
        elif isinstance(obj, Plane):
            side = float(np.dot(centre - np.asarray(obj.point), obj.normal))
            if (abs(side) if perspective else side) <= radius:
                return True
    if not perspective:
        return bool(np.isin(compiled.face_material, list(transparent)).any())
    if compiled.vertices.shape[0] == 0:
        return False
    nearest = np.clip(centre, compiled.vertices.min(axis=0), compiled.vertices.max(axis=0))  # the box's nearest point
    return bool(np.linalg.norm(centre - nearest) <= radius)


def transparent_objects(compiled) -> int:
    """How many of the scene's objects are transparent (kt > 0), counted once per set of transparent
    materials (the objects of a compiled scene do not change)."""
    scene = compiled.scene
    transparent = tuple(sorted(name for name, m in scene.materials.items() if m.kt > 0))
    kept = compiled.built.get("transparent objects")
    if kept is None or kept[0] != transparent:
        kept = (transparent, sum(obj.material in transparent for obj in scene.objects))
        compiled.built["transparent objects"] = kept
    return kept[1]


def camera_media(compiled) -> tuple[tuple, bool]:
    """(the transparent objects around the perspective camera's eye, innermost first, as (object id,
    material id) pairs -- () for none or an orthographic camera; whether primary rays check their
    own media, `per_ray_check`), for the compiled scene; ((), False) without a transparent material.
    The last camera's answer is kept with the compiled scene: the frames of one view (a fit's, an
    animation's still camera) do not walk again (the check's loop over the objects cost 43 ms a
    frame with 20k spheres)."""
    scene = compiled.scene
    transparent = {i for i, name in enumerate(scene.material_names) if scene.materials[name].kt > 0}
    if not transparent:
        return (), False
    key = (scene.camera, tuple(sorted(transparent)))
    kept = compiled.built.get("camera media")
    if kept is not None and kept[0] == key:
        return kept[1]
    check = per_ray_check(compiled, transparent)
    media = ((), check)
    if scene.camera.projection == "perspective":
        load_kernels(compiled.device, eye_media_kernel)
        out = wp.empty(1, dtype=MediaW, device=compiled.device)
        forward = np.asarray(camera_frame(scene.camera)[2], np.float32)
        wp.launch(eye_media_kernel, dim=1, inputs=[compiled.traceable(), compiled.materials,
                                                    wp.vec3(*scene.camera.eye), wp.vec3(*forward),
                                                    int(transparent_objects(compiled) >= 2), out],
                  device=compiled.device)
        found = out.numpy()[0]
        pairs = tuple((int(found["objects"][k]), int(found["materials"][k])) for k in range(int(found["count"])))
        media = (pairs, check)
    compiled.built["camera media"] = (key, media)  # (two threads may both walk: the same answer)
    return media
