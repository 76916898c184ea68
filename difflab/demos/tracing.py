"""Ray-tracing figures that need more than a render: forward tracing from the light (to show why
it wastes rays) and the light buffer's candidate counts."""

from __future__ import annotations

import numpy as np

from .. import geometry
from ..renderers.compile import compile_scene
from ..renderers.raytrace.lightbuffer import build_light_buffer

# The forward-tracing scene: a unit-diameter ball on a 6 x 6 floor, a point light, a pinhole eye.
BALL_CENTER, BALL_RADIUS, FLOOR_HALF = np.array([0.0, 0.5, 0.0]), 0.5, 3.0
LIGHT = np.array([1.5, 2.5, 1.0])
EYE, TARGET = np.array([0.0, 1.2, 3.5]), np.array([0.0, 0.4, 0.0])


def hit_ball(origin, direction):
    """Nearest t > 1e-9 of unit rays against the ball, or inf."""
    oc = BALL_CENTER - origin
    h = (direction * oc).sum(-1)
    disc = BALL_RADIUS ** 2 - ((oc - h[:, None] * direction) ** 2).sum(-1)
    s = np.sqrt(np.maximum(disc, 0.0))
    t = np.where(h - s > 1e-9, h - s, h + s)
    return np.where((disc >= 0) & (t > 1e-9), t, np.inf)


def forward_trace(n_rays: int = 200_000, pupil_radius: float = 0.05, width: int = 64, height: int = 48,
                  fov_y: float = 40.0, seed: int = 0) -> dict:
    """Trace `n_rays` forward, the lecture's "direct" way: from the light, uniformly over all
    directions, to the first surface (ball or floor), then one diffuse (cosine-distributed) bounce;
    a ray counts only if that bounce passes through the eye's pupil (radius `pupil_radius`)
    unblocked by the ball. Returns counts ("emitted", "hit_scene", "reached_eye", "in_view": those
    arriving from inside the field of view) and "image": per pixel of a width x height pinhole view
    from the eye, how many rays arrived through it."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_ball = hit_ball(np.broadcast_to(LIGHT, d.shape), d)
    t_floor = np.where(d[:, 1] < 0, -LIGHT[1] / np.where(d[:, 1] < 0, d[:, 1], -1.0), np.inf)
    p_floor = LIGHT + t_floor[:, None] * d
    t_floor = np.where((np.abs(p_floor[:, 0]) <= FLOOR_HALF) & (np.abs(p_floor[:, 2]) <= FLOOR_HALF), t_floor, np.inf)
    t = np.minimum(t_ball, t_floor)
    hit = np.isfinite(t)
    p = LIGHT + t[hit, None] * d[hit]
    normal = np.where((t_ball[hit] <= t_floor[hit])[:, None], (p - BALL_CENTER) / BALL_RADIUS, [0.0, 1.0, 0.0])
    bounce = rng.normal(size=p.shape)
    bounce = normal + bounce / np.linalg.norm(bounce, axis=1, keepdims=True)  # cosine-distributed about the normal
    bounce /= np.linalg.norm(bounce, axis=1, keepdims=True)
    s = ((EYE - p) * bounce).sum(-1)  # the bounce's closest approach to the eye
    miss = np.linalg.norm(p + s[:, None] * bounce - EYE, axis=1)
    arrived = (s > 0) & (miss < pupil_radius) & (hit_ball(p + 1e-6 * normal, bounce) >= s)
    view_proj = geometry.perspective(fov_y, width / height, 0.1, 100.0) @ geometry.look_at(EYE, TARGET)
    xy = np.floor(geometry.ndc_to_raster(geometry.apply_to_points(view_proj, p[arrived]), width, height)).astype(int)
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < width) & (xy[:, 1] >= 0) & (xy[:, 1] < height)
    image = np.zeros((height, width), np.int64)
    np.add.at(image, (xy[inside, 1], xy[inside, 0]), 1)
    return {"emitted": n_rays, "hit_scene": int(hit.sum()), "reached_eye": int(arrived.sum()),
            "in_view": int(inside.sum()), "image": image}


def forward_scene(width: int, height: int, fov_y: float = 40.0) -> dict:
    """The forward-tracing scene in the scene format, for the backward (Whitted) render beside it."""
    return {"camera": {"eye": EYE.tolist(), "target": TARGET.tolist(), "fov_y": fov_y, "width": width, "height": height},
            "ambient": [0.0, 0.0, 0.0], "background": [0.15, 0.15, 0.2],
            "lights": [{"type": "point", "position": LIGHT.tolist(), "intensity": [1.5, 1.5, 1.5]}],
            "materials": {"m": {"kd": [0.8, 0.8, 0.8]}},
            "objects": [{"type": "sphere", "center": BALL_CENTER.tolist(), "radius": BALL_RADIUS, "material": "m"},
                        {"type": "mesh", "builtin": "quad", "resolution": 1, "material": "m",
                         "transform": {"scale": 2 * FLOOR_HALF}}],
            "render": {"method": "raytrace", "max_depth": 1}}


def light_buffer_counts(scene, resolution: int | None = None) -> list:
    """Per light of `scene`, the number of candidate occluders in every light-buffer cell, (6, R, R)
    ordered +x, -x, +y, -y, +z, -z (None for a directional light); R = `resolution` (None: scaled
    to the mesh size, as renders use)."""
    return build_light_buffer(compile_scene(scene), resolution).counts
