"""The Mandelbulb (White and Nylander's power-8 3D Mandelbrot) by distance-estimated ray marching.

In spherical coordinates (r, theta, phi), "z^p" raises r to the p-th power and multiplies both
angles by p; the set is the points c whose orbit z <- z^p + c (z_0 = 0) stays bounded. Outside it,

    DE(c) = 0.5 log(r) r / |dz|,   |dz| <- p r^(p-1) |dz| + 1,

bounds the distance to the set from below, so a ray can safely advance by DE (sphere tracing) until
DE falls below the size of a pixel at that distance. The surface is shaded with difflab's one
illumination model (`difflab.lighting.warp_model`), the normal being the gradient of DE (central
differences) and each light's visibility a soft-shadow march towards it (Quilez's
min(k h / t), k = `softness`; hard shadows with `softness=0`). The polar axis is world y.
"""

from __future__ import annotations

import math

import numpy as np
from .._warp import wp

from ..lighting.warp_model import (LightW, MaterialW, ambient_term, light_term,
                                   light_vector, lights_to_warp, materials_to_warp)
from ..renderers.camera import CameraW, camera_struct, primary_ray
from ..renderers.launch import launch_rows, resolve_device
from ..vocabulary import SPECULAR_MODELS
from ..scene import Camera, Light, Material
from ._checks import FractalError, check_float, check_image_size, check_int, check_vec

wp.set_module_options({"enable_backward": False})

BOUND_RADIUS = 1.25  # every power-8 bulb point lies within this sphere: marching starts on it
BAILOUT = 2.0
DEFAULT_LIGHTS = (
    Light(type="directional", direction=(-0.5, -1.0, -0.35), intensity=(0.95, 0.9, 0.8)),
    Light(type="point", position=(-3.0, 1.0, 3.0), intensity=(0.25, 0.3, 0.4)),
)
DEFAULT_MATERIAL = Material(ka=(0.9, 0.75, 0.6), kd=(0.85, 0.65, 0.45), ks=(0.35, 0.35, 0.35), n=24.0)


@wp.struct
class BulbW:
    """The fractal and the march's knobs."""

    power: float
    iterations: int
    max_steps: int
    pixel_cone: float  # world size of a pixel per unit distance: hit when DE < 0.5 pixel_cone t
    softness: float  # soft-shadow k; 0 = hard shadows
    shadows: int


@wp.func
def bulb_distance(c: wp.vec3, power: float, iterations: int):
    """Distance estimate from c to the Mandelbulb (0.5 log r r / dr), >= 0 up to round-off."""
    z = c
    dr = float(1.0)
    r = wp.length(z)
    for _ in range(iterations):
        if r > BAILOUT:
            break
        theta = wp.acos(wp.clamp(z[1] / wp.max(r, 1.0e-20), -1.0, 1.0)) * power  # polar angle from +y
        phi = wp.atan2(z[2], z[0]) * power
        dr = power * wp.pow(r, power - 1.0) * dr + 1.0
        zr = wp.pow(r, power)
        z = zr * wp.vec3(wp.sin(theta) * wp.cos(phi), wp.cos(theta), wp.sin(theta) * wp.sin(phi)) + c
        r = wp.length(z)
    return 0.5 * wp.log(wp.max(r, 1.0e-20)) * r / dr


@wp.func
def bulb_normal(p: wp.vec3, h: float, power: float, iterations: int):
    """Unit gradient of the distance estimate by central differences of step h."""
    ex = wp.vec3(h, 0.0, 0.0)
    ey = wp.vec3(0.0, h, 0.0)
    ez = wp.vec3(0.0, 0.0, h)
    g = wp.vec3(bulb_distance(p + ex, power, iterations) - bulb_distance(p - ex, power, iterations),
                bulb_distance(p + ey, power, iterations) - bulb_distance(p - ey, power, iterations),
                bulb_distance(p + ez, power, iterations) - bulb_distance(p - ez, power, iterations))
    if wp.length(g) == 0.0:  # catch a flat spot: no gradient to normalise
        return wp.vec3(0.0, 1.0, 0.0)
    return wp.normalize(g)


@wp.func
def sphere_span(origin: wp.vec3, direction: wp.vec3, radius: float):
    """(t_enter, t_exit) of a unit-direction ray through the origin-centred sphere; t_exit < 0 if missed."""
    b = wp.dot(origin, direction)
    disc = b * b - (wp.dot(origin, origin) - radius * radius)
    if disc < 0.0:
        return 0.0, -1.0
    root = wp.sqrt(disc)
    return wp.max(-b - root, 0.0), -b + root


@wp.func
def shadow_visibility(p: wp.vec3, l: wp.vec3, d: float, bulb: BulbW, eps: float):
    """Visibility in [0, 1] of a light at distance d in direction l from p (p already off the surface)."""
    t_enter, t_exit = sphere_span(p, l, BOUND_RADIUS)
    t_end = wp.min(t_exit, d)
    t = wp.max(t_enter, eps)
    res = float(1.0)
    for _ in range(bulb.max_steps):
        if t >= t_end:
            break
        h = bulb_distance(p + t * l, bulb.power, bulb.iterations)
        if h < eps:
            return 0.0
        if bulb.softness > 0.0:
            res = wp.min(res, bulb.softness * h / t)
        t = t + h
    return wp.clamp(res, 0.0, 1.0)


@wp.kernel
def mandelbulb_kernel(row0: int, cam: CameraW, bulb: BulbW, lights: wp.array(dtype=LightW),
                      materials: wp.array(dtype=MaterialW), specular_model: int, ambient: wp.vec3,
                      background: wp.vec3, image: wp.array3d(dtype=float)):
    """One pixel: march the primary ray to the bulb and shade the hit, or write the background."""
    i, j = wp.tid()
    row = row0 + i
    origin, direction = primary_ray(cam, float(j) + 0.5, float(row) + 0.5)
    colour = background
    t_enter, t_exit = sphere_span(origin, direction, BOUND_RADIUS)
    t = t_enter
    hit = int(0)
    for _ in range(bulb.max_steps):
        if t > t_exit:
            break
        h = bulb_distance(origin + t * direction, bulb.power, bulb.iterations)
        if h < 0.5 * bulb.pixel_cone * t:
            hit = 1
            break
        t = t + h
    if hit == 1:
        p = origin + t * direction
        eps = wp.max(0.5 * bulb.pixel_cone * t, 1.0e-5)
        normal = bulb_normal(p, eps, bulb.power, bulb.iterations)
        v = -direction
        mat = materials[0]
        colour = ambient_term(mat, ambient)
        p_off = p + 2.0 * eps * normal  # step off the surface: no self-shadowing acne
        for k in range(lights.shape[0]):
            l, d = light_vector(lights[k], p)
            visibility = float(1.0)
            if bulb.shadows == 1 and wp.dot(normal, l) > 0.0:
                visibility = shadow_visibility(p_off, l, d, bulb, eps)
            colour = colour + visibility * light_term(lights[k], mat, specular_model, normal, v, l, d)
    image[row, j, 0] = colour[0]
    image[row, j, 1] = colour[1]
    image[row, j, 2] = colour[2]


def mandelbulb(width: int = 320, height: int = 240, eye=(2.0, 1.6, 2.4), target=(0.0, -0.1, 0.0),
               fov_y: float = 40.0, lights=None, material=None, *, ambient=(0.15, 0.15, 0.18),
               background=(0.0, 0.0, 0.0), specular: str = "phong", power: float = 8.0,
               iterations: int = 10, max_steps: int = 256, shadows: bool = True, softness: float = 16.0,
               device: str = "cpu", threads: int | None = None, progress=None) -> np.ndarray:
    """Render the Mandelbulb, lit by the illumination model with (soft) shadows.

    Arguments:
        width, height: pixels (> 0).
        eye, target, fov_y: a perspective camera (y up, fov_y in degrees), as in scene files.
        lights: difflab.scene Light objects (default: a warm directional key and a cool point fill).
        material: a difflab.scene Material (default: a warm, slightly glossy one).
        ambient: Ia, linear RGB. background: colour of rays that miss.
        specular: "phong" | "blinn" | "torrance".
        power: the bulb's exponent p (> 1; 8 is the classic bulb); iterations: orbit length (1..64).
        max_steps: march steps per ray (1..10^4). shadows: trace shadow rays; softness: soft-shadow
            k (> 0; penumbra narrows as k grows) or 0 for hard shadows.
        device: "cpu" or "cuda[:N]"; threads: CPU worker threads (default all cores).
        progress: None, or called as progress(rows_done, height) while the rows are rendered, rows_done
            increasing to height (`launch.launch_rows`: a long render in bands of ~0.1 s).

    Returns:
        (height, width, 3) float32 linear RGB, unclamped.
    """
    width, height = check_image_size(width, height)
    camera = Camera(eye=tuple(check_vec("eye", eye, 3)), target=tuple(check_vec("target", target, 3)),
                    fov_y=check_float("fov_y", fov_y, 0.0, 180.0, lo_open=True, hi_open=True),
                    width=width, height=height)
    lights = DEFAULT_LIGHTS if lights is None else tuple(lights)
    for k, light in enumerate(lights):
        if not isinstance(light, Light):
            raise FractalError(f"lights[{k}]: expected a difflab.scene.Light, got {type(light).__name__}")
    material = DEFAULT_MATERIAL if material is None else material
    if not isinstance(material, Material):
        raise FractalError(f"material: expected a difflab.scene.Material, got {type(material).__name__}")
    if specular not in SPECULAR_MODELS:
        raise FractalError(f"specular: expected one of {sorted(SPECULAR_MODELS)}, got {specular!r}")
    bulb = BulbW()
    bulb.power = check_float("power", power, 1.0, 64.0, lo_open=True)
    bulb.iterations = check_int("iterations", iterations, 1, 64)
    bulb.max_steps = check_int("max_steps", max_steps, 1, 10_000)
    bulb.softness = check_float("softness", softness, 0.0, 1.0e6)
    bulb.shadows = 1 if shadows else 0
    bulb.pixel_cone = 2.0 * math.tan(math.radians(camera.fov_y) / 2.0) / height
    ambient = check_vec("ambient", ambient, 3)
    background = check_vec("background", background, 3)
    device = resolve_device(device)

    image = wp.empty((height, width, 3), dtype=float, device=device)
    inputs = [camera_struct(camera, width, height), bulb, lights_to_warp(lights, device),
              materials_to_warp([material], device), SPECULAR_MODELS[specular], wp.vec3(*ambient),
              wp.vec3(*background), image]
    launch_rows(mandelbulb_kernel, (height, width), inputs, device, threads,
                row_work=width * bulb.iterations * bulb.max_steps, progress=progress)  # (a row's primary march at most)
    return image.numpy()
