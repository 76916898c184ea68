"""Texture footprints of reflected and refracted rays: each ray carries its sample's ray
differentials (`surface.DifferentialsW`), reflected and refracted at every surface."""

import numpy as np
import pytest

from difflab import render, save_image
from difflab._warp import wp
from difflab.renderers.raytrace.optics import refract, refracted_differential


@wp.kernel(enable_backward=False)
def differential_kernel(d: wp.array(dtype=wp.vec3), dd: wp.array(dtype=wp.vec3), normal: wp.array(dtype=wp.vec3),
                        eta: wp.array(dtype=float), out: wp.array(dtype=wp.vec3)):
    k = wp.tid()
    ok, t = refract(d[k], normal[k], eta[k])
    out[k] = refracted_differential(dd[k], d[k], normal[k], t, eta[k])


def snell(d, normal, eta):
    """Float64 refracted unit directions (rows), Snell's law as `optics.refract` states it."""
    cos_i = -np.sum(d * normal, 1)
    k = 1 - eta ** 2 * (1 - cos_i ** 2)
    return eta[:, None] * d + (eta * cos_i - np.sqrt(k))[:, None] * normal


def test_the_refracted_differential_is_the_derivative_of_snells_law():
    """On 500 random incidences (eta 1 / 1.5, 1.5, 1 / 2.4, 1.33; cos_t > 0.2, away from total
    internal reflection): `refracted_differential` equals float64 central differences of Snell's law
    along a random change dd of the direction (d +- h dd normalised), within 1e-3 relative."""
    rng = np.random.default_rng(3)
    n = 500
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    d = rng.normal(size=(n, 3))
    d -= np.maximum(np.sum(d * normal, 1), 0)[:, None] * normal * 2
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    eta = rng.choice([1 / 1.5, 1.5, 1 / 2.4, 1.33], n)
    cos_t2 = 1 - eta ** 2 * (1 - np.sum(d * normal, 1) ** 2)
    keep = cos_t2 > 0.04
    d, normal, eta = d[keep], normal[keep], eta[keep]
    dd = rng.normal(size=d.shape)
    dd -= np.sum(dd * d, 1)[:, None] * d  # a change of a unit vector is perpendicular to it
    h = 1e-4
    unit = lambda v: v / np.linalg.norm(v, axis=1, keepdims=True)  # noqa: E731
    expected = (snell(unit(d + h * dd), normal, eta) - snell(unit(d - h * dd), normal, eta)) / (2 * h)
    out = wp.zeros(d.shape[0], dtype=wp.vec3)
    f32 = lambda a, t=wp.vec3: wp.array(np.asarray(a, np.float32), dtype=t)  # noqa: E731
    wp.launch(differential_kernel, dim=d.shape[0], inputs=[f32(d), f32(dd), f32(normal), f32(eta, float), out])
    got = out.numpy()
    err = np.linalg.norm(got - expected, axis=1) / np.linalg.norm(expected, axis=1)
    assert d.shape[0] > 300 and err.max() < 1e-3


def wall_scene(texture, eye, mirror, filter, camera=None):
    """A wall at z = 5 (facing -z) with `texture`, seen from `eye` looking at the origin, with or
    without a plane mirror (kr 1) at z = 0 facing +z."""
    objects = [{"type": "plane", "point": [-2, -2, 5], "normal": [0, 0, -1], "material": "wall"}]
    if mirror:
        objects.append({"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "material": "mirror"})
    return {"camera": {"eye": eye, "target": [0, 0, 0], "fov_y": 50, "width": 32, "height": 32, **(camera or {})},
            "ambient": [1, 1, 1], "lights": [],
            "materials": {"wall": {"ka": 1, "kd": 0, "texture": str(texture), "texture_target": "ka", "filter": filter},
                          "mirror": {"ka": 0, "kd": 0, "kr": 1}},
            "objects": objects, "render": {"method": "raytrace", "max_depth": 3}}


@pytest.mark.parametrize("filter", ["mipmap", "trilinear", "ewa"])
@pytest.mark.parametrize("camera", [None, {"projection": "orthographic", "ortho_height": 1.5}])
def test_a_texture_seen_in_a_plane_mirror_is_filtered_as_seen_directly(tmp_path, filter, camera):
    """A random 32 x 32 texture on a wall seen in a plane mirror from (0.3, 0.2, 3) is the left-right
    flip of the wall seen directly from the mirrored eye (0.3, 0.2, -3): within 1e-4 for the
    footprint-driven filters (measured 1e-6), perspective and orthographic. The mirror rays' cone of
    one angular spread for every pixel took too wide a footprint off the axis (here mipmap 0.034,
    trilinear 0.041, EWA 0.016) and none at all in an orthographic view (0.59, 0.35, 0.51)."""
    rng = np.random.default_rng(1)
    texture = rng.random((32, 32, 3)).astype(np.float32)
    texture[::8] = 1.0
    texture[:, ::8] = 0.0
    path = tmp_path / "tex.png"
    save_image(path, texture)
    seen = render(wall_scene(path, [0.3, 0.2, 3], True, filter, camera))
    direct = render(wall_scene(path, [0.3, 0.2, -3], False, filter, camera))[:, ::-1]
    assert seen.std() > 0.01  # (a texture minified to 0.5 +- 0.02: its footprint is what the filters follow)
    np.testing.assert_allclose(seen, direct, atol=1e-4)
