"""The Whitted ray tracer against closed forms, the rasterizer, and its own recorded ray tree."""

import math

import numpy as np
import pytest
import warp as wp

from conftest import scene_dict
from difflab import RenderError, Scene, SceneError, render, render_frame
from difflab.renderers.camera import projection_matrix, view_matrix
from difflab.renderers.compile import compile_scene
from difflab.renderers.raytrace.driver import raytrace, sample_points
from difflab.renderers.raytrace.adaptive import raytrace_adaptive
from difflab.renderers.raytrace.optics import fresnel, refract
from difflab.vocabulary import FRESNEL_EXACT, FRESNEL_SCHLICK
from difflab.fit import evaluate_tree
from difflab.renderers.intersect import ray_plane, ray_sphere

wp.set_module_options({"enable_backward": False})
ORTHO = {"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic", "ortho_height": 2.4,
         "width": 48, "height": 48, "near": 0.1, "far": 20}


def trace(scene, **settings):
    scene = Scene.from_dict(scene) if isinstance(scene, dict) else scene
    if settings:
        scene = scene.with_overrides(render=settings)
    return raytrace(compile_scene(scene), scene.render, threads=2)


def primary_rays(camera, width, height):
    """Float64 near-plane origins and unit directions through pixel centres, unprojected through the
    float64 matrices: an independent model of `camera.primary_ray`'s rays."""
    cam = Scene.from_dict(scene_dict([], {"m": {}}, camera=camera)).camera
    inv = np.linalg.inv(projection_matrix(cam, width, height) @ view_matrix(cam))
    x, y = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    ndc = np.stack([2 * x / width - 1, 1 - 2 * y / height], -1)
    near = np.concatenate([ndc, -np.ones_like(x)[..., None], np.ones_like(x)[..., None]], -1) @ inv.T
    far = np.concatenate([ndc, np.ones_like(x)[..., None], np.ones_like(x)[..., None]], -1) @ inv.T
    near, far = near[..., :3] / near[..., 3:], far[..., :3] / far[..., 3:]
    d = far - near
    return near, d / np.linalg.norm(d, axis=-1, keepdims=True)


def sphere_t(o, d, c, r):
    """Nearest positive root of |o + t d - c| = r (float64), inf where missed."""
    oc = o - c
    b = np.sum(oc * d, -1)
    disc = b * b - (np.sum(oc * oc, -1) - r * r)
    t = -b - np.sqrt(np.maximum(disc, 0))
    return np.where((disc >= 0) & (t > 0), t, np.inf), disc


def near_edge(mask):
    """Pixels whose 3x3 neighbourhood is not uniform in `mask` (within one pixel of an edge)."""
    p = np.pad(mask, 1, mode="edge")
    out = np.zeros_like(mask)
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            out |= p[di:di + mask.shape[0], dj:dj + mask.shape[1]] != mask
    return out


# 1. Closed forms --------------------------------------------------------------------------------


@wp.kernel
def closed_forms_kernel(o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), c: wp.array(dtype=wp.vec3),
                        r: wp.array(dtype=float), ts: wp.array(dtype=float), tp: wp.array(dtype=float),
                        cos_i: wp.array(dtype=float), eta: wp.array(dtype=float), ok: wp.array(dtype=int),
                        t_dir: wp.array(dtype=wp.vec3), f_exact: wp.array(dtype=float),
                        f_schlick: wp.array(dtype=float)):
    k = wp.tid()
    ts[k] = ray_sphere(o[k], d[k], c[k], r[k], 0.0)
    tp[k] = ray_plane(o[k], d[k], c[k], wp.normalize(c[k] - o[k] + wp.vec3(0.3, 0.0, 0.0)), 0.0)
    # incidence in the x-z plane onto the normal +z
    sin_i = wp.sqrt(1.0 - cos_i[k] * cos_i[k])
    refracts, direction = refract(wp.vec3(sin_i, 0.0, -cos_i[k]), wp.vec3(0.0, 0.0, 1.0), eta[k])
    ok[k] = refracts
    t_dir[k] = direction
    f_exact[k] = fresnel(FRESNEL_EXACT, cos_i[k], eta[k])
    f_schlick[k] = fresnel(FRESNEL_SCHLICK, cos_i[k], eta[k])


def test_ray_sphere_plane_snell_and_fresnel_match_closed_forms():
    rng = np.random.default_rng(0)
    n = 4000
    o = rng.uniform(-5, 5, (n, 3))
    c = rng.uniform(-5, 5, (n, 3))
    r = rng.uniform(0.5, 3.0, n)
    aim = c + rng.uniform(-1, 1, (n, 3)) * r[:, None]
    d = (aim - o) / np.linalg.norm(aim - o, axis=1, keepdims=True)
    cos_i = rng.uniform(0.0, 1.0, n)
    eta = rng.choice([1 / 1.5, 1.5, 1 / 2.4, 2.4, 1.0], n)
    out = {k: wp.zeros(n, dtype=t) for k, t in [("ts", float), ("tp", float), ("ok", int), ("t_dir", wp.vec3),
                                                  ("fe", float), ("fs", float)]}
    f32 = lambda a, t=wp.vec3: wp.array(a.astype(np.float32), dtype=t)  # noqa: E731
    wp.launch(closed_forms_kernel, dim=n, inputs=[f32(o), f32(d), f32(c), f32(r, float), out["ts"], out["tp"],
                                                  f32(cos_i, float), f32(eta, float), out["ok"], out["t_dir"],
                                                  out["fe"], out["fs"]])
    o, d, c = (a.astype(np.float32).astype(np.float64) for a in (o, d, c))
    r = r.astype(np.float32).astype(np.float64)
    t_want, disc = sphere_t(o, d, c, r)
    t_want = np.where(np.isinf(t_want) & (disc >= 0), -np.sqrt(np.maximum(disc, 0)) - np.sum((o - c) * d, -1) + 2 *
                      np.sqrt(np.maximum(disc, 0)), t_want)  # from inside: the far root
    robust = np.abs(disc) > 1e-3 * r * r  # not grazing
    got = out["ts"].numpy()
    hit = robust & np.isfinite(t_want) & (t_want > 0.01)  # origins on the surface have no relative precision
    assert hit.sum() > n / 2
    np.testing.assert_allclose(got[hit], t_want[hit], rtol=1e-5)
    assert np.all(got[robust & ~np.isfinite(t_want)] == -1.0)
    # plane through c with normal normalize(c - o + (0.3, 0, 0))
    normal = c - o + np.array([0.3, 0, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    tp_want = np.sum((c - o) * normal, -1) / np.sum(d * normal, -1)
    front = tp_want > 0
    np.testing.assert_allclose(out["tp"].numpy()[front], tp_want[front], rtol=1e-5)
    # Snell: sin_t = eta sin_i; total internal reflection exactly when eta sin_i > 1
    sin_i = np.sqrt(1 - cos_i.astype(np.float32).astype(np.float64) ** 2)
    eta64 = eta.astype(np.float32).astype(np.float64)
    tir = eta64 * sin_i > 1
    clear = np.abs(eta64 * sin_i - 1) > 1e-5
    ok = out["ok"].numpy().astype(bool)
    assert tir.sum() > 100 and np.array_equal(ok[clear], ~tir[clear])
    t_dir = out["t_dir"].numpy()
    np.testing.assert_allclose(np.linalg.norm(t_dir[ok], axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(t_dir[ok, 0], (eta64 * sin_i)[ok], atol=2e-6)  # tangential component = sin_t
    assert np.all(t_dir[ok, 1] == 0.0) and np.all(t_dir[ok, 2] <= 0.0)
    # Fresnel: exact dielectric formula, 1 under TIR; Schlick equals it at normal incidence
    cos_t = np.sqrt(np.maximum(1 - (eta64 * sin_i) ** 2, 0))
    ci = cos_i.astype(np.float32).astype(np.float64)
    rs = (eta64 * ci - cos_t) / (eta64 * ci + cos_t)
    rp = (eta64 * cos_t - ci) / (eta64 * cos_t + ci)
    f_want = np.where(tir, 1.0, 0.5 * (rs ** 2 + rp ** 2))
    np.testing.assert_allclose(out["fe"].numpy()[clear], f_want[clear], atol=1e-5)
    assert np.all(out["fs"].numpy()[tir & clear] == 1.0)
    fs = out["fs"].numpy()
    assert np.all((fs >= 0) & (fs <= 1))


def test_mirror_sphere_reflects_the_lamp_where_geometry_says():
    """A perfect mirror sphere seen orthographically from +z shows a lamp sphere at (3, 0.5, 0) exactly
    where the mirror direction r = d - 2(d.N)N from the analytic hit meets the lamp."""
    scene = scene_dict(
        [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "mirror"},
         {"type": "sphere", "center": [3, 0.5, 0], "radius": 1, "material": "lamp"}],
        {"mirror": {"kd": [0, 0, 0], "kr": 1.0}, "lamp": {"ka": [1, 1, 1], "kd": [0, 0, 0]}},
        ambient=(1, 1, 1), camera=dict(ORTHO, width=64, height=64), render={"max_depth": 2, "shadows": False})
    image = trace(scene).image[..., 0]
    o, d = primary_rays(dict(ORTHO, width=64, height=64), 64, 64)
    t, _ = sphere_t(o, d, np.zeros(3), 1.0)
    on_mirror = np.isfinite(t) & (np.hypot(o[..., 0], o[..., 1]) < 0.97)
    p = o + np.where(np.isfinite(t), t, 0)[..., None] * d
    r = d - 2 * np.sum(d * p, -1, keepdims=True) * p
    lamp = np.array([3.0, 0.5, 0.0])
    along = np.sum((lamp - p) * r, -1)
    miss = np.linalg.norm(lamp - p - along[..., None] * r, axis=-1)  # distance of the reflected line from the lamp
    sees = (along > 0) & (miss < 1.0)
    clear = on_mirror & (np.abs(miss - 1.0) > 0.03)
    assert (clear & sees).sum() > 30 and (clear & ~sees).sum() > 300
    assert np.all(image[clear & sees] == pytest.approx(1.0)) and np.all(image[clear & ~sees] == 0.0)


def test_shadow_of_a_sphere_is_the_analytic_disk():
    """Light straight down: the shadow on y = 0 is the disk x^2 + z^2 < r^2, except one pixel at its edge."""
    camera = {"eye": [0, 2.5, 5], "target": [0, 0, 0], "fov_y": 40, "width": 64, "height": 64}
    scene = scene_dict(
        [{"type": "sphere", "center": [0, 1.5, 0], "radius": 0.6, "material": "m"},
         {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "m"}],
        {"m": {"kd": [1, 1, 1]}}, lights=[{"type": "directional", "direction": [0, -1, 0]}], camera=camera,
        render={"max_depth": 1})
    image = trace(scene).image[..., 0]
    o, d = primary_rays(camera, 64, 64)
    t_ball, _ = sphere_t(o, d, np.array([0, 1.5, 0]), 0.6)
    t_floor = -o[..., 1] / d[..., 1]
    floor = (t_floor > 0) & ~np.isfinite(t_ball)
    p = o + t_floor[..., None] * d
    shadow = np.hypot(p[..., 0], p[..., 2]) < 0.6
    check = floor & ~near_edge(floor) & ~near_edge(shadow)
    assert (check & shadow).sum() > 20 and (check & ~shadow).sum() > 1000
    assert np.all(image[check & shadow] == 0.0)
    np.testing.assert_allclose(image[check & ~shadow], 1.0, atol=1e-6)


# 2. Against the rasterizer ----------------------------------------------------------------------

MIXED = dict(
    objects=[{"type": "sphere", "center": [-0.9, 0.6, 0], "radius": 0.6, "material": "red"},
             {"type": "mesh", "builtin": "teapot", "resolution": 6, "material": "blue",
              "transform": {"translate": [0.8, 0, -0.3], "scale": 0.3, "rotate_deg": [0, 30, 0]}},
             {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
    materials={"red": {"ka": [0.1, 0, 0], "kd": [0.7, 0.1, 0.1], "ks": [0.5, 0.5, 0.5], "n": 30},
               "blue": {"ka": [0, 0, 0.1], "kd": [0.1, 0.2, 0.7], "ks": [0.4, 0.4, 0.4], "n": 20},
               "floor": {"ka": [0.1, 0.1, 0.1], "kd": [0.7, 0.7, 0.7], "checker": {"size": 0.5}}},
    camera={"eye": [0.3, 1.6, 4.0], "target": [0, 0.4, 0], "fov_y": 40, "width": 64, "height": 48, "far": 30},
    lights=[{"type": "point", "position": [3, 4, 3]}, {"type": "directional", "direction": [1, -1, -0.5],
                                                       "intensity": [0.3, 0.3, 0.3]}],
    ambient=(0.2, 0.2, 0.2))


def mixed_scene(**render_block):
    return scene_dict(MIXED["objects"], MIXED["materials"], camera=MIXED["camera"], lights=MIXED["lights"],
                      ambient=MIXED["ambient"], background=[0.1, 0.2, 0.3], render=render_block)


def test_primary_hits_and_phong_image_agree_with_the_rasterizer(compare_images):
    """Opaque Phong objects, depth 1, no shadows: the same object ids and the same image as the
    rasterizer's Phong shading, except on silhouettes (pixels next to a change of object id)."""
    scene = mixed_scene(shadows=False, max_depth=1)
    raster = render_frame(scene, method="raster", shading="phong")
    frame = render_frame(scene, method="raytrace")
    ray_ids = frame.ray_tree.object[frame.ray_tree.primary()]
    raster_ids = raster.gbuffer.object
    silhouette = np.zeros(raster_ids.shape, bool)
    for k in np.unique(raster_ids):
        silhouette |= near_edge(raster_ids == k)
    assert (~silhouette).sum() > 0.8 * silhouette.size
    assert np.array_equal(ray_ids[~silhouette], raster_ids[~silhouette])
    # Far floor cells shrink below a pixel: a sample on a checker edge may fall in either cell.
    cell_flip = frame.ray_tree.cell[frame.ray_tree.primary()] != raster.gbuffer.points.cell.reshape(raster_ids.shape)
    assert cell_flip.mean() < 0.01
    keep = ~silhouette & ~cell_flip
    # Tolerance: the rasterizer interpolates vertex normals across the tessellated sphere and teapot
    # (perspective-correct), the ray tracer uses exact sphere normals and Warp's BVH barycentrics.
    compare_images(frame.image[keep], raster.image[keep], atol=1e-3, name="phong_parity")


# 3. The ray tree ----------------------------------------------------------------------------------


def lecture_like(**render_block):
    """MIXED with mirrors (the red ball, the floor) and a glass ball; the mirrors have ior 1.5, so that
    they reflect under Fresnel weighting too (F = 0 at ior 1)."""
    materials = dict(MIXED["materials"], red={"ka": [0.05, 0, 0], "kd": [0.3, 0.05, 0.05], "ks": [0.5, 0.5, 0.5],
                                              "n": 30, "kr": 0.7, "ior": 1.5},
                     glass={"ka": [0, 0, 0], "kd": [0, 0, 0], "ks": [0.5, 0.5, 0.5], "n": 100, "kr": 0.9, "kt": 0.9,
                            "ior": 1.5, "absorption": [0.2, 0.05, 0.0]})
    materials["floor"] = dict(materials["floor"], kr=0.4, ior=1.5)
    objects = MIXED["objects"] + [{"type": "sphere", "center": [0.2, 0.35, 1.0], "radius": 0.35, "material": "glass"}]
    return scene_dict(objects, materials, camera=MIXED["camera"], lights=MIXED["lights"], ambient=MIXED["ambient"],
                      background=[0.1, 0.2, 0.3], render={"method": "raytrace", **render_block})


def test_depth_series_converges_monotonically():
    scene = Scene.from_dict(lecture_like(fresnel="schlick"))
    compiled = compile_scene(scene)
    images = [raytrace(compiled, scene.with_overrides(render={"max_depth": d}).render, 2, record_tree=False).image
              for d in range(1, 8)]
    steps = [float(np.abs(b - a).mean()) for a, b in zip(images, images[1:])]
    for a, b in zip(images, images[1:]):
        assert np.all(b >= a - 1e-6)  # every added node adds a non-negative term
    assert all(s1 < s0 for s0, s1 in zip(steps, steps[1:])), steps
    assert steps[-1] < 0.1 * steps[0]


def test_adaptive_depth_control_saves_rays_at_bounded_error():
    scene = Scene.from_dict(lecture_like(max_depth=7, fresnel="exact"))
    compiled = compile_scene(scene)
    full = raytrace(compiled, scene.render, 2, record_tree=False)
    cut = raytrace(compiled, scene.with_overrides(render={"adaptive_threshold": 0.1}).render, 2, record_tree=False)
    secondary = lambda f: f.stats["rays"]["reflection"] + f.stats["rays"]["refraction"]  # noqa: E731
    assert secondary(cut) < 0.8 * secondary(full)
    assert np.all(cut.image <= full.image + 1e-6)
    assert np.abs(cut.image - full.image).mean() < 0.01


def test_ray_tree_reevaluates_the_image_for_new_materials(compare_images):
    scene = Scene.from_dict(lecture_like(max_depth=5, fresnel="exact", spp=4))
    frame = render_frame(scene, threads=2)
    tree = frame.ray_tree
    mats = [scene.materials[n] for n in scene.material_names]
    assert tree.n_nodes == frame.stats["nodes"] > frame.stats["samples"]
    assert set(np.unique(tree.kind)) == {0, 1, 2}
    np.testing.assert_array_equal(tree.sample_offset[:-1][tree.depth[tree.sample_offset[:-1]] == 1],
                                  tree.sample_offset[:-1])
    again = np.asarray(evaluate_tree(tree, mats, scene.lights, scene.ambient, scene.background))
    compare_images(again, frame.image, atol=1e-5, name="tree_same")
    # new kd, ks, n, kr, kt, absorption (all kr / kt still > 0, no adaptive cut-off): same tree
    d = lecture_like(max_depth=5, fresnel="exact", spp=4)
    d["materials"]["glass"].update(kr=0.5, kt=0.7, absorption=[0.0, 0.6, 0.1], ks=[0.2, 0.2, 0.2])
    d["materials"]["red"].update(kd=[0.1, 0.6, 0.2], n=5, kr=0.3)
    d["materials"]["floor"].update(kr=0.8, kd=[0.4, 0.4, 0.4])
    d.update(ambient=[0.05, 0.1, 0.05], background=[0.5, 0.4, 0.1])
    changed = Scene.from_dict(d)
    want = render_frame(changed, threads=2).image
    got = np.asarray(evaluate_tree(tree, changed.materials, changed.lights, changed.ambient, changed.background))
    compare_images(got, want, atol=1e-5, name="tree_new_materials")


def test_beer_absorption_through_a_slab():
    """Two clear planes 1.5 apart, crossed at normal incidence: exp(-alpha d), times (1 - F)^2 with Fresnel."""
    alpha = np.array([0.2, 0.7, 1.5])
    slab = {"ka": [0, 0, 0], "kd": [0, 0, 0], "kt": 1.0, "ior": 1.5, "absorption": alpha.tolist()}
    scene = scene_dict([{"type": "plane", "point": [0, 0, 0.5], "normal": [0, 0, 1], "material": "slab"},
                        {"type": "plane", "point": [0, 0, -1.0], "normal": [0, 0, -1], "material": "slab"}],
                       {"slab": slab}, background=[1, 1, 1], render={"max_depth": 4})
    beer = np.exp(-alpha * 1.5)
    for mode, f in [("none", 0.0), ("schlick", 0.04), ("exact", 0.04)]:
        image = trace(scene, fresnel=mode).image
        np.testing.assert_allclose(image, np.broadcast_to(beer * (1 - f) ** 2, image.shape), rtol=2e-6)


def test_transparent_shadow_is_kt():
    pane = {"type": "mesh", "builtin": "quad", "material": "pane", "transform": {"translate": [0, 1, 0], "scale": 1.5}}
    floor = {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}
    camera = {"eye": [0, 0.5, 3], "target": [0, 0.2, 0], "fov_y": 50, "width": 32, "height": 32}
    scene = scene_dict([pane, floor], {"pane": {"kd": [0, 0, 0], "kt": 0.35}, "floor": {"kd": [1, 1, 1]}},
                       lights=[{"type": "directional", "direction": [0, -1, 0]}], camera=camera,
                       render={"max_depth": 1})
    frame = trace(scene)
    roots = frame.ray_tree.primary().ravel()
    vis = frame.ray_tree.visibility[roots, 0]
    under = (frame.ray_tree.object[roots] == 1) & (np.abs(frame.ray_tree.position[roots, 0]) < 0.7) \
        & (np.abs(frame.ray_tree.position[roots, 2]) < 0.7)
    assert under.sum() > 20
    assert np.all(vis[under] == pytest.approx(0.35))
    opaque = trace(scene, transparent_shadows=False).ray_tree
    assert np.all(opaque.visibility[roots, 0][under] == 0.0)


def test_no_shadow_acne_on_a_tessellated_sphere():
    """A convex mesh cannot shadow itself: shadow rays (offset by epsilon) must all reach the light."""
    ball = {"type": "mesh", "builtin": "sphere", "resolution": 24, "material": "m", "smooth": True,
            "transform": {"scale": 0.9}}
    scene = scene_dict([ball], {"m": {"kd": [0.8, 0.8, 0.8], "ks": [0.3, 0.3, 0.3], "n": 10}},
                       lights=[{"type": "point", "position": [2, 3, 4]}], camera=ORTHO, render={"max_depth": 1})
    assert np.array_equal(trace(scene).image, trace(scene, shadows=False).image)


# 4. Sampling, determinism, errors ---------------------------------------------------------------


def test_supersampling_patterns_are_fixed_and_renders_deterministic():
    grid = sample_points(2, 1, 2, "grid")
    np.testing.assert_array_equal(grid[:, :2], [[[0.25, 0.25], [0.75, 0.25]], [[0.25, 0.75], [0.75, 0.75]]])
    strat = sample_points(3, 3, 3, "stratified")
    cell = np.floor(strat * 3)
    np.testing.assert_array_equal(cell[..., 0], np.broadcast_to(np.arange(9), (9, 9)))
    np.testing.assert_array_equal(strat, sample_points(3, 3, 3, "stratified"))
    scene = Scene.from_dict(lecture_like(max_depth=4, spp=4, sampling="stratified", fresnel="schlick"))
    compiled = compile_scene(scene)
    a = raytrace(compiled, scene.render, 1)
    b = raytrace(compiled, scene.render, 2)
    assert np.array_equal(a.image, b.image) and a.stats["rays"] == b.stats["rays"]
    assert np.array_equal(a.ray_tree.local, b.ray_tree.local)
    assert a.stats["nonfinite_pixels"] == 0 and sum(a.stats["depth_histogram"]) == a.stats["total_rays"] - \
        a.stats["rays"]["shadow"]


def test_adaptive_supersampling_refines_edges_only():
    scene = Scene.from_dict(mixed_scene(max_depth=2))
    compiled = compile_scene(scene)
    reference = raytrace(compiled, scene.with_overrides(render={"spp": 16}).render, 2, record_tree=False)
    single = raytrace(compiled, scene.render, 2, record_tree=False)
    adaptive = raytrace_adaptive(compiled, scene.render, threshold=0.2, refine=4, threads=2)
    assert 0.02 < adaptive.stats["refined_fraction"] < 0.5
    assert adaptive.stats["rays"]["primary"] < 0.6 * reference.stats["rays"]["primary"]
    err = lambda f: float(np.abs(f.image - reference.image).mean())  # noqa: E731
    assert err(adaptive) < 0.5 * err(single)
    again = raytrace_adaptive(compiled, scene.render, threshold=0.2, refine=4, threads=1)
    assert np.array_equal(again.image, adaptive.image)
    with pytest.raises(RenderError, match="refine"):
        raytrace_adaptive(compiled, scene.render, refine=1)


def test_bad_requests_raise_clear_errors():
    scene = mixed_scene()
    with pytest.raises(SceneError, match=r"render.spp: must be a perfect square .* got 3"):
        render(scene, method="raytrace", spp=3)
    with pytest.raises(SceneError, match="render.max_depth"):
        render(scene, method="raytrace", max_depth=0)
    with pytest.raises(SceneError, match="render.fresnel"):
        render(scene, method="raytrace", fresnel="fancy")
    s = Scene.from_dict(mixed_scene(sampling="stratified"))
    with pytest.raises(RenderError, match="sampling"):
        raytrace(compile_scene(s), s.render, use_item_buffer=True)
    assert math.isfinite(render(scene, method="raytrace", width=8, height=8).sum())


def test_settings_the_chosen_renderer_does_not_use_are_errors_not_ignored():
    """shading / interpolation / culling belong to the rasterizer, max_depth / fresnel / sampling to the
    ray tracer: given to the other one (with a value other than what it does anyway) they raise."""
    scene = mixed_scene()
    for method, name, value in [("raytrace", "shading", "gouraud"), ("raytrace", "interpolation", "affine"),
                                ("raytrace", "cull_backfaces", True), ("raster", "max_depth", 3),
                                ("raster", "fresnel", "exact"), ("raster", "sampling", "stratified")]:
        with pytest.raises(RenderError, match=rf"^{name}: .* does not apply to method='{method}'"):
            render(scene, method=method, width=4, height=4, **{name: value})
    # the values that describe what the renderer does anyway are accepted
    traced = render(scene, method="raytrace", shading="phong", max_depth=1, width=8, height=8)
    assert np.array_equal(traced, render(scene, method="raytrace", max_depth=1, width=8, height=8))
    rastered = render(scene, method="raster", max_depth=1, sampling="grid", width=8, height=8)
    assert np.array_equal(rastered, render(scene, method="raster", width=8, height=8))
