"""Rendered images against closed forms, one formula per test, so that a wrong exponent, a wrong
power of the distance or a wrong level of detail turns a test red: Schlick's Fresnel seen from
both sides of an interface, point-light attenuation in both renderers, fog, mip-map levels and
sphere uv in the ray tracer. Pixel positions are computed here from the camera, not read back
from the renderer."""

import math

import numpy as np
import pytest

from conftest import scene_dict
from difflab import render, render_frame
from difflab._warp import wp
from difflab.renderers.raytrace.optics import beer, fresnel, reflect, refract
from difflab.vocabulary import FRESNEL_MODES
from difflab.renderers.texture.store import TextureStore, sample

ORTHO = {"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic", "ortho_height": 2.0,
         "width": 16, "height": 16, "near": 0.1, "far": 20}


def ortho_pixel_centres(width, height, half_height=1.0):
    """World (x, y) of the pixel centres of ORTHO-like cameras (eye on +z looking down -z)."""
    half_width = half_height * width / height
    x = -half_width + (np.arange(width) + 0.5) * 2 * half_width / width
    y = half_height - (np.arange(height) + 0.5) * 2 * half_height / height
    return np.meshgrid(x, y)


# ---- Schlick's Fresnel ----------------------------------------------------------------------


def schlick(cos_i, eta):
    """F = R0 + (1 - R0)(1 - c)^5, R0 = ((1 - eta)/(1 + eta))^2, c = cos_i for eta <= 1 and cos_t
    for eta > 1 (1 under total internal reflection)."""
    r0 = ((1 - eta) / (1 + eta)) ** 2
    sin2_t = eta * eta * (1 - cos_i * cos_i)
    if eta == 1:  # no interface: nothing reflects (the formula's (1 - c)^5 would)
        return 0.0
    if sin2_t >= 1:
        return 1.0
    c = cos_i if eta <= 1 else math.sqrt(1 - sin2_t)
    return r0 + (1 - r0) * (1 - c) ** 5


@wp.kernel(enable_backward=False)
def optics_kernel(d: wp.array(dtype=wp.vec3), normal: wp.array(dtype=wp.vec3), eta: wp.array(dtype=float),
                  alpha: wp.array(dtype=wp.vec3), length: wp.array(dtype=float), r: wp.array(dtype=wp.vec3),
                  ok: wp.array(dtype=int), t: wp.array(dtype=wp.vec3), f: wp.array2d(dtype=float),
                  absorbed: wp.array(dtype=wp.vec3)):
    k = wp.tid()
    cos_i = -wp.dot(d[k], normal[k])
    r[k] = reflect(d[k], normal[k])
    refracts, direction = refract(d[k], normal[k], eta[k])
    ok[k] = refracts
    t[k] = direction
    for mode in range(3):
        f[k, mode] = fresnel(mode, cos_i, eta[k])
    absorbed[k] = beer(alpha[k], length[k])


def test_optics_functions_against_their_formulas():
    """The ray tree's optics on 2000 random incidences (float64 formulas from the module doc):
    mirror r = d - 2 (d.N) N; Snell t = eta d + (eta cos_i - sqrt(k)) N, k = 1 - eta^2 (1 - cos_i^2),
    none where k < 0; F = 0 (none), Schlick and the exact dielectric F (1 under total internal
    reflection; exactly 0 at eta = 1); Beer exp(-alpha l), exactly 1 where alpha = 0 (also at l = inf), 0 at l = inf."""
    rng = np.random.default_rng(11)
    n = 2000
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    d = rng.normal(size=(n, 3))
    d -= np.maximum(np.sum(d * normal, 1), 0)[:, None] * normal * 2  # travel toward the surface
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    eta = rng.choice([1 / 1.5, 1.5, 1 / 2.4, 2.4, 1.0, 1.33], n)
    alpha = rng.uniform(0, 2, (n, 3)) * (rng.random((n, 3)) < 0.7)
    length = np.where(rng.random(n) < 0.1, np.inf, rng.uniform(0, 5, n))
    f32 = lambda a, dtype=wp.vec3: wp.array(np.asarray(a, np.float32), dtype=dtype)  # noqa: E731
    out = [wp.zeros(n, dtype=wp.vec3), wp.zeros(n, dtype=int), wp.zeros(n, dtype=wp.vec3), wp.zeros((n, 3), dtype=float),
           wp.zeros(n, dtype=wp.vec3)]
    wp.launch(optics_kernel, dim=n, inputs=[f32(d), f32(normal), f32(eta, float), f32(alpha), f32(length, float), *out])
    r, ok, t, f, absorbed = (a.numpy() for a in out)
    d, normal, eta = (np.asarray(a, np.float32).astype(np.float64) for a in (d, normal, eta))
    cos_i = -np.sum(d * normal, 1)
    np.testing.assert_allclose(r, d + 2 * cos_i[:, None] * normal, atol=2e-6)
    k = 1 - eta ** 2 * (1 - cos_i ** 2)
    clear = np.abs(k) > 1e-4  # not at the critical angle
    assert np.array_equal(ok[clear] == 1, k[clear] >= 0) and (k < 0).sum() > 100
    through = clear & (k >= 0)
    t_want = eta[:, None] * d + (eta * cos_i - np.sqrt(np.maximum(k, 0)))[:, None] * normal
    np.testing.assert_allclose(t[through], t_want[through], atol=2e-5)
    assert np.all(t[~ok.astype(bool)] == 0.0)
    assert FRESNEL_MODES == {"none": 0, "schlick": 1, "exact": 2}  # the kernel's columns
    np.testing.assert_array_equal(f[:, 0], 0.0)
    assert (eta == 1).sum() > 100 and np.all(f[eta == 1] == 0.0)  # no interface: exactly 0 in every form
    want_schlick = np.array([schlick(c, e) for c, e in zip(cos_i, eta)])
    np.testing.assert_allclose(f[clear, 1], want_schlick[clear], atol=2e-6)
    cos_t = np.sqrt(np.maximum(k, 0))
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (eta * cos_t - cos_i) / (eta * cos_t + cos_i)
    np.testing.assert_allclose(f[clear, 2], np.where(k < 0, 1.0, 0.5 * (rs ** 2 + rp ** 2))[clear], atol=2e-6)
    alpha32 = np.asarray(alpha, np.float32).astype(np.float64)
    length32 = np.asarray(length, np.float32).astype(np.float64)[:, None]
    with np.errstate(invalid="ignore"):
        want_beer = np.where(alpha32 > 0, np.exp(-alpha32 * length32), 1.0)
    np.testing.assert_allclose(absorbed, want_beer, rtol=2e-6, atol=1e-30)
    assert np.all(absorbed[alpha32 == 0] == 1.0)


@pytest.mark.parametrize("side, angle_deg", [("above", 30), ("above", 60), ("above", 80),
                                             ("below", 20), ("below", 35), ("below", 40), ("below", 60)])
def test_schlick_fresnel_weights_reflection_and_refraction_at_oblique_angles(side, angle_deg):
    """A dark interface y = 0 (ior 1.5, kr = 1, kt = 1/2) under a white background, seen at angle
    theta from its normal by an orthographic camera: every pixel is kr F + kt (1 - F), both
    children meeting the background. From above the ray enters the denser side (eta = 1/1.5, c =
    cos_i); from below it leaves it (eta = 1.5, c = cos_t, and F = 1 past the critical 41.8 deg)."""
    theta = math.radians(angle_deg)
    sign = 1.0 if side == "above" else -1.0
    camera = dict(ORTHO, eye=[5 * math.sin(theta), sign * 5 * math.cos(theta), 0], up=[0, 0, 1], width=4, height=4)
    glass = {"ka": [0, 0, 0], "kd": [0, 0, 0], "kr": 1.0, "kt": 0.5, "ior": 1.5}
    scene = scene_dict([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "glass"}],
                       {"glass": glass}, camera=camera, background=[1, 1, 1],
                       render={"max_depth": 2, "fresnel": "schlick"})
    f = schlick(math.cos(theta), 1 / 1.5 if side == "above" else 1.5)
    image = render(scene, method="raytrace")
    np.testing.assert_allclose(image, f + 0.5 * (1 - f), atol=2e-6)


def exact_fresnel(cos_i, eta):
    """Unpolarised dielectric reflectance (r_s^2 + r_p^2) / 2 for eta = n1 / n2 (1 under TIR)."""
    sin2_t = eta * eta * (1 - cos_i * cos_i)
    if sin2_t >= 1:
        return 1.0
    cos_t = math.sqrt(1 - sin2_t)
    r_s = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_p = (eta * cos_t - cos_i) / (eta * cos_t + cos_i)
    return 0.5 * (r_s * r_s + r_p * r_p)


@pytest.mark.parametrize("eta", [1 / 1.5, 1 / 1.333, 1.5, 1 / 2.4])
def test_the_reference_fresnel_is_fresnels_sine_and_tangent_laws(eta):
    """exact_fresnel, the oracle the renders are held to, is written in the same cosine form as
    `optics.fresnel_exact`; so it is checked against Fresnel's own laws, a different form: r_s =
    -sin(i - t) / sin(i + t), r_p = tan(i - t) / tan(i + t) with sin t = eta sin i (Snell), at 12
    angles below the critical one; ((1 - eta) / (1 + eta))^2 head-on; r_p = 0 at Brewster's angle
    tan i = 1 / eta; 1 past the critical angle."""
    for i in np.linspace(0.05, min(1.5, math.asin(min(1.0, 1 / eta)) - 1e-3), 12):
        t = math.asin(eta * math.sin(i))
        r_s, r_p = -math.sin(i - t) / math.sin(i + t), math.tan(i - t) / math.tan(i + t)
        assert exact_fresnel(math.cos(i), eta) == pytest.approx(0.5 * (r_s * r_s + r_p * r_p), rel=1e-12)
    assert exact_fresnel(1.0, eta) == pytest.approx(((1 - eta) / (1 + eta)) ** 2, rel=1e-12)
    brewster = math.atan(1 / eta)
    t = math.asin(eta * math.sin(brewster))
    r_s = math.sin(brewster - t) / math.sin(brewster + t)
    assert exact_fresnel(math.cos(brewster), eta) == pytest.approx(0.5 * r_s * r_s, rel=1e-12)  # r_p = 0
    if eta > 1:
        assert exact_fresnel(math.cos(math.asin(1 / eta) + 1e-3), eta) == 1.0


def interface_scene(side, angle_deg, material, fresnel):
    """The interface y = 0 (`material`, no local light) under a white background, seen at angle
    theta from its normal, from above (entering, eta = 1 / ior) or below (leaving, eta = ior) by a
    4x4 orthographic camera at depth 2: every child ray meets the background."""
    theta = math.radians(angle_deg)
    sign = 1.0 if side == "above" else -1.0
    camera = dict(ORTHO, eye=[5 * math.sin(theta), sign * 5 * math.cos(theta), 0], up=[0, 0, 1], width=4, height=4)
    return scene_dict([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "m"}],
                      {"m": {"ka": [0, 0, 0], "kd": [0, 0, 0], **material}}, camera=camera, background=[1, 1, 1],
                      render={"max_depth": 2, "fresnel": fresnel})


@pytest.mark.parametrize("fresnel, form", [("exact", exact_fresnel), ("schlick", schlick)])
@pytest.mark.parametrize("side, angle_deg", [("above", 0), ("above", 50), ("above", 70), ("below", 0),
                                             ("below", 30), ("below", 60)])
def test_fresnel_weights_an_opaque_mirror(fresnel, form, side, angle_deg):
    """An opaque mirror (kr = 0.8, kt = 0, ior 1.5) with Fresnel on reflects kr F(cos theta, 1 / ior),
    as a transparent one does from outside (POV-Ray's `reflection {0, 1 fresnel on}`): head-on
    0.8 x 0.04. An opaque object has no inside, so its back is seen from outside too: the same F
    from below (there used to be total internal reflection, F = 1, past 41.8 deg from below)."""
    scene = interface_scene(side, angle_deg, {"kr": 0.8, "ior": 1.5}, fresnel)
    f = form(math.cos(math.radians(angle_deg)), 1 / 1.5)
    np.testing.assert_allclose(render(scene, method="raytrace"), 0.8 * f, atol=2e-6)


QUAD = [[-20, 0, -20], [20, 0, -20], [20, 0, 20], [-20, 0, 20]]
#: The interface y = 0 as four surfaces an opaque mirror must not tell apart: a plane with normal +y
#: or -y, a two-triangle quad wound with normal +y or -y.
OPAQUE_SHEETS = {"plane +y": {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]},
                 "plane -y": {"type": "plane", "point": [0, 0, 0], "normal": [0, -1, 0]},
                 "mesh +y": {"type": "mesh", "vertices": QUAD, "faces": [[0, 2, 1], [0, 3, 2]]},
                 "mesh -y": {"type": "mesh", "vertices": QUAD, "faces": [[0, 1, 2], [0, 2, 3]]}}


@pytest.mark.parametrize("fresnel, form", [("exact", exact_fresnel), ("schlick", schlick)])
@pytest.mark.parametrize("sheet", list(OPAQUE_SHEETS))
@pytest.mark.parametrize("side, angle_deg", [("above", 30), ("above", 60), ("below", 30), ("below", 60)])
def test_an_opaque_fresnel_mirror_ignores_winding_and_normal_sign(fresnel, form, sheet, side, angle_deg):
    """An opaque (kt = 0) Fresnel mirror of ior 1.5 has no inside: from either side, whatever its
    triangles' winding or its plane's normal sign, it reflects kr F(cos theta, 1 / 1.5) -- at 60 deg
    too, past the 41.8 deg where a ray leaving glass would be totally reflected. It used to take
    eta = 1.5 on the back side (F = 1 past 41.8 deg: 0.95 brighter there)."""
    scene = interface_scene(side, angle_deg, {"kr": 0.8, "ior": 1.5}, fresnel)
    scene["objects"] = [{**OPAQUE_SHEETS[sheet], "material": "m"}]
    f = form(math.cos(math.radians(angle_deg)), 1 / 1.5)
    np.testing.assert_allclose(render(scene, method="raytrace"), 0.8 * f, atol=2e-6)


@pytest.mark.parametrize("fresnel, form", [("exact", exact_fresnel), ("schlick", schlick)])
@pytest.mark.parametrize("ior", [1e-3, 1e3])
@pytest.mark.parametrize("side, angle_deg", [("above", 0), ("above", 30), ("below", 0), ("below", 30)])
def test_fresnel_at_the_ends_of_the_accepted_ior_range(fresnel, form, ior, side, angle_deg):
    """At ior 1e-3 and 1e3 (the accepted range: `material.IOR_RANGE`) the float32 optics still give
    an opaque mirror's kr F(cos, 1 / ior), from either side, to float32 precision: head-on
    F = ((1 - eta) / (1 + eta))^2 = 0.996, at 30 degrees total internal reflection (F = 1) where
    eta = 1e3 (ior 1e-3), F(cos, 1e-3) where ior is 1e3. Beyond the range eta^2 overflows float32
    (ior 1e30 rendered wrong without a sign) and the scene is refused."""
    scene = interface_scene(side, angle_deg, {"kr": 1.0, "ior": ior}, fresnel)
    eta = 1 / ior
    np.testing.assert_allclose(render(scene, method="raytrace"), form(math.cos(math.radians(angle_deg)), eta),
                               rtol=2e-6, atol=2e-6)


@pytest.mark.parametrize("kr", [0.0, 0.3])
@pytest.mark.parametrize("side, angle_deg", [("above", 30), ("above", 80), ("below", 20), ("below", 40),
                                             ("below", 45), ("below", 60), ("below", 70)])
def test_plain_weights_move_the_refracted_share_to_the_reflection_under_tir(kr, side, angle_deg):
    """Without Fresnel weighting (kt = 0.5, ior 1.5) the reflected ray takes kr and the refracted
    one kt; past the critical angle seen from below (41.8 deg) no ray refracts and the reflected
    one takes kr + kt (POV-Ray's total internal reflection): every pixel is kr + kt (it was kr
    under TIR, black glass with the docs' kr = 0). With Fresnel weighting the refracted share
    kt (1 - F) is 0 there: `test_schlick_fresnel_weights_reflection_and_refraction_at_oblique_angles`."""
    scene = interface_scene(side, angle_deg, {"kr": kr, "kt": 0.5, "ior": 1.5}, "none")
    np.testing.assert_allclose(render(scene, method="raytrace"), kr + 0.5, atol=2e-6)


@pytest.mark.parametrize("fresnel", ["exact", "schlick"])
@pytest.mark.parametrize("side, angle_deg", [("above", 0), ("above", 60), ("above", 85), ("below", 30),
                                             ("below", 85)])
def test_fresnel_at_ior_1_is_exactly_zero(fresnel, side, angle_deg):
    """At ior 1 there is no interface: F = 0 exactly in both forms, so a clear sheet (kt = 1, kr = 0)
    passes the white background at exactly 1 and its recorded F is 0 at every hit (at 85 deg a
    4x4 orthographic view meets the sheet with 12 of its rays, the others start past it). Schlick's
    R0 + (1 - R0)(1 - cos)^5 is (1 - cos)^5 there (0.62 of the light kept at 85 deg), the exact
    form's float32 rounding up to ~6e-10."""
    scene = interface_scene(side, angle_deg, {"kt": 1.0, "ior": 1.0}, fresnel)
    frame = render_frame(scene, method="raytrace")
    np.testing.assert_array_equal(frame.image, 1.0)
    tree = frame.ray_tree
    hits = tree.material == 0
    assert hits.sum() >= 8 and np.all(tree.fresnel[hits] == 0.0) and np.all(tree.fresnel_t[hits] == 1.0)


# ---- point-light attenuation ----------------------------------------------------------------


@pytest.mark.parametrize("method", ["raster", "raytrace"])
def test_attenuated_point_light_on_a_plane(method):
    """A Lambertian plane z = 0 facing the camera, a point light at height h: at pixel (x, y),
    d = |light - (x, y, 0)| and I = Ip kd (h / d) / (kc + kl d + kq d^2)."""
    light = np.array([0.3, -0.2, 0.8])
    kc, kl, kq = 0.5, 0.4, 0.9
    kd = np.array([1.0, 0.5, 0.25])
    ip = np.array([1.0, 2.0, 3.0])
    scene = scene_dict([{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "material": "m"}],
                       {"m": {"kd": kd.tolist(), "ks": [0, 0, 0]}}, camera=ORTHO,
                       lights=[{"type": "point", "position": light.tolist(), "intensity": ip.tolist(),
                                "attenuation": [kc, kl, kq]}],
                       render={"shading": "phong", "max_depth": 1})
    x, y = ortho_pixel_centres(16, 16)
    d = np.sqrt((light[0] - x) ** 2 + (light[1] - y) ** 2 + light[2] ** 2)
    want = (ip * kd) * (light[2] / d / (kc + kl * d + kq * d * d))[..., None]
    np.testing.assert_allclose(render(scene, method=method), want, rtol=2e-5, atol=1e-6)


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("thickness", [1e-150, 1e-160, 1e-250])
def test_a_box_squashed_to_a_sheet_is_lit_face_on(method, thickness):
    """A unit box scaled to `thickness` in z, seen face-on under a directional light along
    -(1, 1, 3): over its footprint |x|, |y| < 1/2 every pixel is kd (N.L) = kd 3 / sqrt(11), however
    thin the box (the rasterizer drew it black below ~1e-154: |A^-T n|^2 overflowed)."""
    kd = np.array([0.7, 0.5, 0.3])
    scene = scene_dict([{"type": "mesh", "builtin": "box", "material": "m",
                         "transform": {"scale": [1, 1, thickness]}}], {"m": {"kd": kd.tolist()}}, camera=ORTHO,
                       lights=[{"type": "directional", "direction": [-1, -1, -3]}])
    x, y = ortho_pixel_centres(16, 16)
    inside = (np.abs(x) < 0.5) & (np.abs(y) < 0.5)
    want = np.where(inside[..., None], kd * 3 / math.sqrt(11), 0.0)
    np.testing.assert_allclose(render(scene, method=method), want, atol=1e-6)


# ---- fog --------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("fog", [{"mode": "linear", "start": 3.5, "end": 7.0}, {"mode": "linear", "start": 5.0, "end": 5.4},
                                 {"mode": "exp", "density": 0.15}, {"mode": "exp2", "density": 0.12}])
def test_fog_blends_by_eye_depth(method, fog):
    """A tilted plane 0.6 y + 0.8 z = 0 lit only by ambient (colour C = ka) seen by a perspective
    camera at (0, 0, 5) looking down -z: the ray through the pixel centre with camera-space
    direction (xc, yc, -1) meets it at eye depth t = 5 b / (b - a yc), and the pixel is
    f C + (1 - f) C_fog with OpenGL's f(t) clamped to [0, 1]."""
    w, h, fov = 16, 12, 40.0
    camera = {"eye": [0, 0, 5], "target": [0, 0, 0], "fov_y": fov, "width": w, "height": h, "near": 0.1, "far": 30}
    ka = np.array([0.2, 0.4, 0.9])
    fog_color = np.array([0.7, 0.6, 0.1])
    scene = scene_dict([{"type": "plane", "point": [0, 0, 0], "normal": [0, 0.6, 0.8], "material": "m"}],
                       {"m": {"ka": ka.tolist(), "kd": [0, 0, 0]}}, camera=camera, ambient=(1, 1, 1),
                       fog=dict(fog, color=fog_color.tolist()), render={"max_depth": 1})
    tan = math.tan(math.radians(fov) / 2)
    yc = (1 - 2 * (np.arange(h) + 0.5) / h) * tan
    depth = np.broadcast_to((5 * 0.8 / (0.8 - 0.6 * yc))[:, None], (h, w))
    if fog["mode"] == "linear":
        f = (fog["end"] - depth) / (fog["end"] - fog["start"])
    elif fog["mode"] == "exp":
        f = np.exp(-fog["density"] * depth)
    else:
        f = np.exp(-(fog["density"] * depth) ** 2)
    f = np.clip(f, 0, 1)[..., None]
    assert np.ptp(f) > 0.05  # the fog varies over the image
    if fog.get("end") == 5.4:  # nearer than start and farther than end: the clamp on both sides matters
        assert (f == 1).any() and (f == 0).any()
    np.testing.assert_allclose(render(scene, method=method), f * ka + (1 - f) * fog_color, rtol=2e-5, atol=1e-6)


# ---- mip-map levels ---------------------------------------------------------------------------


def bilinear_reference(level, u, v):
    """Bilinear lookup with repeat wrap in one level stored bottom row first (texel centres at
    ((c + 0.5) / W, (r + 0.5) / H)), in float64."""
    h, w = level.shape[:2]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = math.floor(x), math.floor(y)
    fx, fy = x - x0, y - y0
    t = lambda r, c: level[r % h, c % w].astype(np.float64)  # noqa: E731
    bottom = (1 - fx) * t(y0, x0) + fx * t(y0, x0 + 1)
    top = (1 - fx) * t(y0 + 1, x0) + fx * t(y0 + 1, x0 + 1)
    return (1 - fy) * bottom + fy * top


@pytest.mark.parametrize("longer", ["dx", "dy"])
@pytest.mark.parametrize("lod", [-0.5, 0.6, 1.6, 2.3, 3.45])
def test_mip_levels_follow_the_level_of_detail(lod, longer):
    """A 32x16 texture whose levels all differ (random texels): a footprint whose longer Jacobian
    column (d(uv)/dx or d(uv)/dy) is rho = 2^lod level-0 texels long (and not along an axis) is
    read, with mipmap, in level round(lod) and, with trilinear, as the lerp of levels floor(lod)
    and floor(lod) + 1 by frac(lod); lod <= 0 (magnification) reads level 0 with both."""
    image = np.random.default_rng(5).random((16, 32, 3)).astype(np.float32)
    store = TextureStore.from_images([image])
    levels = store.pyramids[0]
    w, h = 32, 16
    rho = 2.0 ** lod
    uv = np.array([[0.37, 0.61]])
    duv_dx = np.array([[rho * 0.6 / w, rho * 0.8 / h]])  # rho texels long
    duv_dy = np.array([[-rho * 0.4 / w, rho * 0.3 / h]])  # half as long: it must not set the level
    if longer == "dy":
        duv_dx, duv_dy = duv_dy, duv_dx
    ref = [bilinear_reference(level, *uv[0]) for level in levels]
    mipmap = sample(store, 0, uv, duv_dx, duv_dy, filter="mipmap")[0]
    np.testing.assert_allclose(mipmap, ref[max(int(math.floor(lod + 0.5)), 0)], atol=2e-6)
    lower, frac = int(math.floor(lod)), lod - math.floor(lod)
    trilinear = sample(store, 0, uv, duv_dx, duv_dy, filter="trilinear")[0]
    want = ref[0] if lod <= 0 else (1 - frac) * ref[lower] + frac * ref[lower + 1]
    np.testing.assert_allclose(trilinear, want, atol=2e-6)
    # the levels differ by far more than the tolerance, so a neighbouring level would fail
    assert min(np.abs(a - b).max() for a, b in zip(ref, ref[1:])) > 0.01


def test_a_zero_or_non_finite_footprint_reads_level_0():
    """texture_lod gives NO_LOD (magnification: bilinear in level 0) for a footprint of length 0, one
    whose squared length overflows float32 to inf, and a NaN one."""
    image = np.random.default_rng(6).random((16, 32, 3)).astype(np.float32)
    store = TextureStore.from_images([image])
    uv = np.array([[0.37, 0.61]] * 3)
    duv_dx = np.array([[0.0, 0.0], [1e30, 0.0], [np.nan, 0.0]])
    want = bilinear_reference(store.pyramids[0][0], *uv[0])
    for filter in ("mipmap", "trilinear"):
        out = sample(store, 0, uv, duv_dx, np.zeros_like(duv_dx), filter=filter)
        np.testing.assert_allclose(out, np.broadcast_to(want, out.shape), atol=2e-6, err_msg=filter)


def test_a_footprint_at_or_past_the_last_level_reads_the_last_level():
    """The 32x16 texture has levels 0..5 (level 5: the 1x1 mean). A footprint of exactly 32 texels
    (lod 5.0, exact in float32) and one of 128 (lod 7) read level 5 with mipmap and trilinear, and
    nothing of the next texture in the store (NaN texels: even a weight-0 read would show)."""
    image = np.random.default_rng(7).random((16, 32, 3)).astype(np.float32)
    store = TextureStore.from_images([image, np.full((2, 2, 3), np.nan, np.float32)])
    last = store.pyramids[0][-1][0, 0]
    uv = np.array([[0.37, 0.61]] * 2)
    duv_dx = np.array([[1.0, 0.0], [4.0, 0.0]])  # 32 and 128 level-0 texels
    for filter in ("mipmap", "trilinear"):
        out = sample(store, 0, uv, duv_dx, np.zeros_like(duv_dx), filter=filter)
        np.testing.assert_allclose(out, np.broadcast_to(last, out.shape), rtol=1e-6, err_msg=filter)


# ---- sphere uv in the ray tracer ---------------------------------------------------------------


def test_sphere_uv_in_the_ray_tracer(tmp_path):
    """A unit sphere textured with linear ramps (red = u ramp, green = v ramp; bilinear lookup of a
    ramp is linear in uv), lit by ambient only through ka: each pixel shows the texel at
    u = lon / 2 pi, lon = atan2(-z, x) in [0, 2 pi), and v = acos(-y) / pi, of its hit point."""
    tw, th = 64, 32
    ramp_u = np.arange(tw) / (tw - 1)
    ramp_v = np.arange(th) / (th - 1)
    texture = np.zeros((th, tw, 3), np.float32)
    texture[..., 0] = ramp_u[None, :]
    texture[..., 1] = ramp_v[::-1, None]  # image row 0 is the top (v = 1)
    np.save(tmp_path / "ramps.npy", texture)
    camera = dict(ORTHO, eye=[0.5, 1.0, 5], width=32, height=32, ortho_height=2.4)
    ball = {"ka": [1, 1, 1], "kd": [0, 0, 0], "texture": str(tmp_path / "ramps.npy"), "texture_target": "ka", "filter": "bilinear"}
    scene = scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "ball"}], {"ball": ball},
                       camera=camera, ambient=(1, 1, 1), render={"max_depth": 1})
    image = render(scene, method="raytrace")
    # primary rays of the orthographic camera: origin on the image plane, direction toward the target
    eye = np.array(camera["eye"], float)
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, [0, 1, 0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    a, b = ortho_pixel_centres(32, 32, 1.2)
    origin = eye + a[..., None] * right + b[..., None] * up
    proj = origin @ forward
    closest = origin - proj[..., None] * forward
    r2 = np.sum(closest ** 2, -1)
    p = closest - np.sqrt(np.maximum(1 - r2, 0))[..., None] * forward  # the near root
    lon = np.mod(np.arctan2(-p[..., 2], p[..., 0]), 2 * np.pi)
    u, v = lon / (2 * np.pi), np.arccos(np.clip(-p[..., 1], -1, 1)) / np.pi
    # away from the silhouette, the seam (u = 0) and the poles, where the ramp wraps or pinches
    keep = (r2 < 0.9) & (u * tw > 1.0) & (u * tw < tw - 1.0) & (v * th > 1.0) & (v * th < th - 1.0)
    assert keep.sum() > 300
    np.testing.assert_allclose(image[keep, 0], ((u * tw - 0.5) / (tw - 1))[keep], atol=2e-5)
    np.testing.assert_allclose(image[keep, 1], ((v * th - 0.5) / (th - 1))[keep], atol=2e-5)
