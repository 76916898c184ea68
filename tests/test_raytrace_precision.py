"""Where the ray tracer's rays start: primary rays at the camera's float32 limits, ray offsets that
scale with the scene, and the medium a camera inside a transparent object starts in."""

import numpy as np
import pytest

from difflab import Scene, render, render_frame
from difflab.fit import evaluate_tree
from difflab.renderers.compile import compile_scene
from difflab.renderers.raytrace.medium import camera_media

EDGES = 0.05  # a reference pixel differing from a 4-neighbour by more than this sits on an edge

BASE = {
    "camera": {"eye": [0, 1, 4], "target": [0, 0.5, 0], "fov_y": 45, "width": 96, "height": 72, "near": 0.1,
               "far": 10},
    "ambient": [0.1, 0.1, 0.1], "background": [0.1, 0.1, 0.3],
    "lights": [{"type": "point", "position": [3, 4, 3], "attenuation": [1, 0.1, 0.02]},
               {"type": "directional", "direction": [1, -1, -0.5], "intensity": [0.3, 0.3, 0.3]}],
    "materials": {"r": {"kd": [0.8, 0.2, 0.2], "ks": [0.4, 0.4, 0.4], "n": 30},
                  "f": {"kd": [0.7, 0.7, 0.7], "checker": {"size": 1, "kd2": [0.2, 0.2, 0.2]}}},
    "objects": [{"type": "sphere", "center": [0, 0.7, 0], "radius": 0.7, "material": "r"},
                {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "f"}],
    "render": {"method": "raytrace", "shadows": True},
}


def transformed(d, scale=1.0, shift=(0.0, 0.0, 0.0), **camera):
    """Scene dict `d` under p -> scale p + shift (camera, lights, objects and mesh transforms, near /
    far, checker cells, attenuation and absorption per unit length): the same picture, in other
    coordinates."""
    shift = np.asarray(shift, float)

    def point(p):
        return [float(v) for v in scale * np.asarray(p, float) + shift]

    out = {**d, "camera": {**d["camera"], "eye": point(d["camera"]["eye"]),
                           "target": point(d["camera"]["target"]),
                           "near": d["camera"]["near"] * scale, "far": d["camera"]["far"] * scale, **camera}}
    out["lights"] = [{**light, **({"position": point(light["position"])} if "position" in light else {}),
                      **({"attenuation": [a / scale ** k for k, a in enumerate(light["attenuation"])]}
                         if "attenuation" in light else {})} for light in d["lights"]]
    materials = {}
    for name, m in d["materials"].items():
        m = dict(m)
        if "checker" in m:
            m["checker"] = {**m["checker"], "size": m["checker"]["size"] * scale}
        if "absorption" in m:
            m["absorption"] = [a / scale for a in m["absorption"]]
        materials[name] = m
    out["materials"] = materials
    objects = []
    for o in d["objects"]:
        o = dict(o)
        for key in ("center", "point"):
            if key in o:
                o[key] = point(o[key])
        if "radius" in o:
            o["radius"] = o["radius"] * scale
        if "transform" in o:  # the mesh's own transform, then this one
            t = o["transform"]
            o["transform"] = {**t, "translate": point(t.get("translate", [0, 0, 0])), "scale": t.get("scale", 1) * scale}
        objects.append(o)
    out["objects"] = objects
    return out


def edge_pixels(image):
    """Pixels of `image` differing from a 4-neighbour by more than EDGES (largest channel)."""
    edge = np.zeros(image.shape[:2], bool)
    for axis in (0, 1):
        step = np.abs(np.diff(image, axis=axis)).max(-1) > EDGES
        lo = [slice(None), slice(None)]
        hi = [slice(None), slice(None)]
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        edge[tuple(lo)] |= step
        edge[tuple(hi)] |= step
    return edge


def pinhole_directions(camera, samples):
    """Float64 unit directions of the pinhole rays through the centres of pixels `samples` (flat indices)."""
    eye, target = np.asarray(camera["eye"], float), np.asarray(camera["target"], float)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0, 1, 0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    w, h = camera["width"], camera["height"]
    i, j = np.divmod(samples, w)
    half = np.tan(np.radians(camera["fov_y"]) / 2)
    x = ((j + 0.5) / w * 2 - 1) * half * w / h
    y = (1 - (i + 0.5) / h * 2) * half
    d = forward + x[:, None] * right + y[:, None] * up
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("shift, near", [(0.0, 1e-5), (1e5, 0.1)])
def test_primary_ray_directions_are_the_pinholes_to_float32_rounding(shift, near):
    """The primary rays' directions (recorded as -view at their hits) against the float64 pinhole model,
    at far / near = 1e6 (the documented limit) and with the eye 1e5 from the origin. Unprojecting
    through the float32 inverse view-projection was off by 0.68 and 3.9 pixels; the camera basis is
    exact to float32 rounding (measured < 2e-5 pixel)."""
    d = transformed(BASE, shift=(shift, 0, 0), near=near)
    tree = render_frame(Scene.from_dict(d), shadows=False).ray_tree
    primary = np.flatnonzero((tree.parent == -1) & (tree.material >= 0))
    assert primary.size > 3000
    expected = pinhole_directions(d["camera"], tree.sample[primary])
    got = -tree.view[primary].astype(np.float64)
    angle = np.arccos(np.clip(np.sum(expected * got, 1) / np.linalg.norm(got, axis=1), -1, 1))
    pixel = 2 * np.arctan(np.tan(np.radians(45) / 2)) / d["camera"]["height"]
    assert angle.max() / pixel < 1e-4


def test_a_tiny_near_plane_leaves_the_image_as_it_was():
    """Nothing lies within 0.1 of the eye, so near = 1e-5 (far / near = 1e6) must give near 0.1's image:
    measured bit for bit (the ray starts at the eye and is only traced from the near plane on); the
    unprojected rays changed 92 pixels by more than 0.1 (up to 0.70)."""
    ref = render(Scene.from_dict(BASE))
    tiny = render(Scene.from_dict(transformed(BASE, near=1e-5)))
    assert np.abs(tiny - ref).max() <= 1e-6


def test_a_camera_far_from_the_origin_sees_what_it_sees_at_the_origin():
    """The whole scene moved by 1e5 along x: float32 positions there are 1/128 apart, so a hit point
    cannot be nearer than ~0.004 to the true one. Where that matters (a hit within an ulp of a checker
    line or the silhouette: pixels on an edge of the reference) a pixel may flip (measured: 8 of 1567
    edge pixels); every other pixel must keep its value within 0.02 (measured 0.006: the sphere's
    normal, from a point off by an ulp over a radius of 0.7, under an n = 30 highlight). Shadows are
    off: their rays start 8 x 2^-23 of the coordinates (`trace.ray_offset`: 0.1 here) off the
    surface, which moves shadow edges by about as much. The unprojected rays moved hits by 3.2
    units: 823 pixels changed by > 0.1."""
    ref = render(Scene.from_dict(BASE), shadows=False)
    far = render(Scene.from_dict(transformed(BASE, shift=(1e5, 0, 0))), shadows=False)
    err = np.abs(far - ref).max(-1)
    edge = edge_pixels(ref)
    assert err[~edge].max() <= 0.02
    assert (err > 0.02).sum() <= 0.02 * edge.sum()

GLASS = {**BASE, "materials": {**BASE["materials"],
                               "g": {"kd": [0, 0, 0], "ks": [0.5, 0.5, 0.5], "n": 100, "kt": 0.9, "ior": 1.5,
                                     "absorption": [0.6, 0.2, 0.0]}},
         "objects": BASE["objects"] + [{"type": "sphere", "center": [-1.1, 0.5, 0.9], "radius": 0.5, "material": "g"}],
         "render": {**BASE["render"], "max_depth": 5, "fresnel": "schlick"}}

GRAZING = {
    "camera": {"eye": [0, 1, 4], "target": [0, 0.5, 0], "width": 96, "height": 72, "near": 0.01, "far": 1000},
    "ambient": [0, 0, 0], "lights": [{"type": "directional", "direction": [-1, -0.3, -0.2]}],
    "materials": {"m": {"kd": [0.8, 0.8, 0.8]}},
    "objects": [{"type": "sphere", "center": [0, 0.7, 0], "radius": 0.7, "material": "m"},
                {"type": "mesh", "builtin": "teapot", "resolution": 4, "material": "m",
                 "transform": {"translate": [1.5, 0, 0], "scale": 0.4}},
                {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "m"}],
    "render": {"method": "raytrace", "shadows": True},
}


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_a_uniformly_scaled_scene_renders_the_same_image(scale):
    """A glass sphere (Schlick Fresnel, absorption, depth 5), a Phong sphere and a checker floor, under
    an attenuated point light: scaled by 1e-3 or 1e3 about the origin, the ray offsets scale too and
    the image stays within 1e-4 (measured 2.2e-5: float32 rounding). With offsets stuck at 1e-4 absolute,
    scale 1e-3 changed 107 pixels by > 0.1."""
    ref = render(Scene.from_dict(GLASS))
    got = render(Scene.from_dict(transformed(GLASS, scale=scale)))
    assert np.abs(got - ref).max() <= 1e-4


def test_shadows_of_a_thin_scene_stay_dark():
    """Grazing light over a sphere, a teapot and a floor: what is in shadow at scale 1 (darker than half
    its unshadowed value) stays in shadow at scale 1e-3, and the images agree within 1e-4 (measured
    4e-6). A 1e-4 offset at scale 1e-3 started shadow rays past the occluders: 37 of the 576 shadowed
    pixels came out lit (up to 0.70)."""
    ref = render(Scene.from_dict(GRAZING))
    unshadowed = render(Scene.from_dict(GRAZING), shadows=False)
    shadowed = (ref[..., 0] < 0.5 * unshadowed[..., 0]) & (unshadowed[..., 0] > 0.1)
    assert shadowed.sum() > 500 and np.all(ref[shadowed] == 0.0)
    got = render(Scene.from_dict(transformed(GRAZING, scale=1e-3)))
    assert np.all(got[shadowed] == 0.0)
    assert np.abs(got - ref).max() <= 1e-4


def test_the_rasterizers_least_offset_follows_the_objects_not_the_eye_or_far():
    """`compile.object_offset` (what a rasterized point's shadow rays start off its surface at least):
    8 x 2^-23 x the largest coordinate of the objects -- the plane's point, the sphere's |c_i| + r,
    the teapot's vertices -- at any scale, wherever the eye is and however far the far plane (it was
    1e-4 x the diagonal of a box that held the eye, and 2 ulps of the far plane's reach)."""
    compiled = compile_scene(transformed(GRAZING, far=10))
    largest = max(1.4, float(np.abs(compiled.vertices[:compiled.n_mesh_vertices]).max()))
    assert compiled.epsilon == pytest.approx(8 * 2.0 ** -23 * largest, rel=1e-6)
    for scale in (1e-3, 1e3):
        scaled = compile_scene(transformed(GRAZING, scale=scale, far=10 * scale))
        assert scaled.epsilon / scale == pytest.approx(compiled.epsilon, rel=1e-6)
    moved = transformed(GRAZING, near=0.1, far=1e5)
    moved["camera"] = {**moved["camera"], "eye": [0, 100, 4000]}
    assert compile_scene(moved).epsilon == compiled.epsilon


def test_without_planes_the_far_plane_beyond_everything_changes_nothing():
    """A glass sphere, a Phong sphere and a quad mesh (a 6 x 6 wall at z = 0), no planes: every hit lies in the box around
    the eye and the objects, so far = 10 or 1e5 gives the same image (bit for bit). An offset floor
    of |eye| + far for every scene once made 0.00097 into 0.0238 at far 1e5 and changed 18 of these
    1728 pixels by > 0.02, up to 0.127."""
    d = {**GLASS, "camera": {**GLASS["camera"], "width": 48, "height": 36}, "objects": [
        {"type": "sphere", "center": [0, 0.7, 0], "radius": 0.7, "material": "g"},
        {"type": "sphere", "center": [0.9, 0.3, 0.6], "radius": 0.3, "material": "r"},
        {"type": "mesh", "builtin": "quad", "material": "f", "transform": {"rotate_deg": [-90, 0, 0], "scale": 6}}]}
    near = compile_scene(d)
    distant = compile_scene(transformed(d, far=1e5))
    assert distant.epsilon == near.epsilon == pytest.approx(8 * 2.0 ** -23 * 3, rel=1e-6)  # the quad's corners
    np.testing.assert_array_equal(render(distant), render(near))


ABSORBING = {"kd": [0, 0, 0], "kt": 1.0, "ior": 1.0, "absorption": [1.0, 0.0, 0.0]}


def inside(objects, eye, fov_y=60):
    """A white-background scene of transparent (ior 1, kt 1) objects absorbing red at 1 per unit,
    seen from `eye` looking down -z."""
    return {"camera": {"eye": list(eye), "target": [eye[0], eye[1], eye[2] - 1], "fov_y": fov_y, "width": 16,
                       "height": 16, "near": 0.01, "far": 100},
            "ambient": [0, 0, 0], "background": [1, 1, 1], "lights": [],
            "materials": {"g": ABSORBING, "opaque": {"kd": [0.5, 0.5, 0.5]}}, "objects": objects,
            "render": {"method": "raytrace", "shadows": False, "max_depth": 4}}


def test_a_camera_inside_an_absorbing_sphere_sees_through_its_medium():
    """Eye at the centre of a unit sphere: every primary ray travels 1 inside, so the white background
    comes out exp(-1) red (it was 1: primary rays started outside any medium); the recorded ray tree
    (medium and distance from the eye) gives the same image again."""
    d = inside([{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "g"}], [0, 0, 0])
    frame = render_frame(Scene.from_dict(d))
    np.testing.assert_allclose(frame.image[..., 0], np.exp(-1.0), rtol=1e-5)
    np.testing.assert_allclose(frame.image[..., 1:], 1.0, rtol=1e-6)
    again = evaluate_tree(frame.ray_tree, *(getattr(Scene.from_dict(d), k) for k in ("materials", "lights",
                                                                                     "ambient", "background")))
    np.testing.assert_allclose(np.asarray(again), frame.image, rtol=1e-5)


def test_outside_the_sphere_only_its_chord_absorbs():
    """Eye at z = 3: each ray absorbs over its chord through the sphere, exp(-chord) red (the centre
    pixel's 0.1366 as before), 1 where it misses -- within 1e-5 relative (measured 4.8e-7; it was
    0.19 % while refracted rays started 4.9e-4 off the surface along its normal, on a line that much
    off the true one: `trace.spawn_origin` keeps them on it)."""
    d = inside([{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "g"}], [0, 0, 3], fov_y=40)
    image = render(Scene.from_dict(d))
    rays = pinhole_directions(d["camera"], np.arange(16 * 16))
    h = rays @ np.array([0.0, 0.0, -3.0])
    chord = 2 * np.sqrt(np.maximum(1.0 - (9.0 - h ** 2), 0.0))
    clear = np.abs(9.0 - h ** 2 - 1.0) > 0.05  # off the silhouette
    np.testing.assert_allclose(image[..., 0].ravel()[clear], np.exp(-chord[clear]), rtol=1e-5)
    assert image[8, 8, 0] == pytest.approx(0.1366, abs=1e-4)


def test_a_camera_inside_a_closed_mesh_or_nested_objects_starts_in_the_innermost_medium():
    """Eye at the centre of a transparent box mesh (half-size 0.5): each ray absorbs over 0.5 / max |d_i|
    to the wall it leaves by. Inside a sphere of radius 0.3 nested in that box, with an opaque ball
    in front that is not around the eye: the sphere's medium, over the 0.3 to its wall, then the
    box's (media nest: `camera_media` lists the sphere, then the box), 0.5 / max |d_i| in all."""
    box = {"type": "mesh", "builtin": "box", "resolution": 1, "material": "g"}
    image = render(Scene.from_dict(inside([box], [0, 0, 0])))
    rays = pinhole_directions(inside([box], [0, 0, 0])["camera"], np.arange(16 * 16))
    np.testing.assert_allclose(image[..., 0].ravel(), np.exp(-0.5 / np.abs(rays).max(axis=1)), rtol=1e-4)
    nested = inside([box, {"type": "sphere", "center": [0, 0, 0], "radius": 0.3, "material": "g"},
                     {"type": "sphere", "center": [0, 0, -10], "radius": 0.5, "material": "opaque"}], [0, 0, 0])
    g = Scene.from_dict(nested).material_index("g")
    assert camera_media(compile_scene(nested))[0] == ((1, g), (0, g))
    frame = render_frame(Scene.from_dict(nested))
    tree = frame.ray_tree
    primary = tree.parent == -1
    assert np.all(tree.medium[primary] == g)
    np.testing.assert_allclose(tree.distance[primary], 0.3, rtol=1e-5)
    np.testing.assert_allclose(frame.image[..., 0].ravel(), np.exp(-0.5 / np.abs(rays).max(axis=1)), rtol=1e-4)


def test_outside_every_object_primary_rays_start_in_no_medium():
    """An eye between a transparent sphere and an opaque one, and behind an open transparent quad
    seen from its front: no medium (a plane or open mesh contains the eye only from its back side)."""
    d = inside([{"type": "sphere", "center": [0, 0, -3], "radius": 1, "material": "g"},
                {"type": "sphere", "center": [0, 0, 3], "radius": 1, "material": "opaque"},
                {"type": "mesh", "builtin": "quad", "material": "g", "transform": {"translate": [0, 0, -1]}}],
               [0, 0, 0])
    tree = render_frame(Scene.from_dict(d)).ray_tree
    assert np.all(tree.medium[tree.parent == -1] == -1)


def test_the_near_plane_clips_a_bubble_around_the_eye_and_its_medium():
    """Eye at the centre of a bubble of radius 0.05 absorbing red: with the near plane inside it, every
    ray absorbs exp(-0.05) from the eye on, whatever `near` is; with the near plane beyond it, the
    bubble is clipped as the rasterizer clips it and the white background comes through (it came
    out [0, 1, 1]: the ray took the eye's medium but started outside the bubble and never left it).
    Only the second needs each ray's own look back from the near plane (`per_ray_check`)."""
    d = inside([{"type": "sphere", "center": [0, 0, 0], "radius": 0.05, "material": "g"}], [0, 0, 0], fov_y=40)
    g = Scene.from_dict(d).material_index("g")
    for near in (0.001, 0.01):
        scene = Scene.from_dict(transformed(d, near=near))
        assert camera_media(compile_scene(scene)) == (((0, g),), False)
        image = render(scene)
        np.testing.assert_allclose(image[..., 0], np.exp(-0.05), rtol=1e-5)
        np.testing.assert_array_equal(image[..., 1:], 1.0)
    clipped = Scene.from_dict(transformed(d, near=0.1))
    assert camera_media(compile_scene(clipped)) == (((0, g),), True)
    np.testing.assert_array_equal(render(clipped), 1.0)
    np.testing.assert_array_equal(render(clipped, method="raster"), 1.0)


def test_past_a_clipped_bubble_the_ray_absorbs_from_its_wall():
    """A bubble of radius 0.05 absorbing green around the eye, inside a unit sphere absorbing red, near
    plane 0.1: rays start in the sphere's medium and absorb over the 0.95 from the bubble's (clipped)
    wall to the sphere's -- exp(-0.95) red, green 1 (it was green exp(-1), red 1: the bubble's medium
    from the eye) -- and the recorded tree (medium, distance from that wall) gives the same image."""
    d = inside([{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "g"},
                {"type": "sphere", "center": [0, 0, 0], "radius": 0.05, "material": "green"}], [0, 0, 0], fov_y=40)
    d["camera"]["near"] = 0.1
    d["materials"]["green"] = {**ABSORBING, "absorption": [0.0, 1.0, 0.0]}
    scene = Scene.from_dict(d)
    frame = render_frame(scene)
    np.testing.assert_allclose(frame.image[..., 0], np.exp(-0.95), rtol=1e-5)
    np.testing.assert_array_equal(frame.image[..., 1:], 1.0)
    again = evaluate_tree(frame.ray_tree, scene.materials, scene.lights, scene.ambient, scene.background)
    np.testing.assert_allclose(np.asarray(again), frame.image, rtol=1e-5)


def test_orthographic_rays_start_in_the_medium_at_their_own_start():
    """An orthographic camera (view 3 tall) at the centre of a unit sphere absorbing red: the ray at
    offset (x, y) starts inside when x^2 + y^2 < 1 and absorbs over sqrt(1 - x^2 - y^2) to the wall,
    else starts outside, misses, and stays white (it was [0, 1, 1]: every ray took the eye's medium)."""
    d = inside([{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "g"}], [0, 0, 0])
    d["camera"].update(projection="orthographic", ortho_height=3.0, width=15, height=15)
    image = render(Scene.from_dict(d))
    x = (np.arange(15) + 0.5) / 15 * 3 - 1.5
    r2 = x[None, :] ** 2 + x[:, None] ** 2
    expected = np.where(r2 < 1, np.exp(-np.sqrt(np.maximum(1 - r2, 0))), 1.0)
    clear = np.abs(r2 - 1) > 0.05  # off the silhouette
    np.testing.assert_allclose(image[..., 0][clear], expected[clear], rtol=1e-4)
    assert np.all(image[..., 0][r2 > 1.05] == 1.0)
    np.testing.assert_array_equal(image[..., 1:], 1.0)


def test_the_camera_medium_is_found_once_per_camera(monkeypatch):
    """The medium check (`medium.per_ray_check`, a loop over the objects: 43 ms a frame with 20k
    spheres) runs once for the frames of one camera and again for another camera."""
    import difflab
    from difflab.renderers.raytrace import medium

    calls = []
    check = medium.per_ray_check
    monkeypatch.setattr(medium, "per_ray_check", lambda *args: calls.append(1) or check(*args))
    scene = difflab.example_scene("glass_sphere", width=12, height=9)
    compiled = difflab.compile_scene(scene)
    first = difflab.render(compiled, method="raytrace")
    np.testing.assert_array_equal(difflab.render(compiled, method="raytrace"), first)
    assert len(calls) == 1
    moved = scene.with_overrides(camera={**scene.camera.to_dict(), "eye": [2.5, 1.6, 3.4]})
    difflab.render(compiled.with_scene(moved), method="raytrace")
    assert len(calls) == 2
