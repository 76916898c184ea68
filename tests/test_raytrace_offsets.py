"""Where rays leaving a surface start (`trace.hit_point`, `trace.ray_offset`, `trace.spawn_origin`): a
few float32 ulps of the hit's own coordinates off it, along the ray -- not a share of a box that holds
the eye -- so that images do not depend on where the eye is, thin objects are crossed, refracted rays
keep their paths, and no surface shadows or blocks itself."""

import numpy as np
import pytest

from difflab import Scene, render, render_frame
from difflab.renderers.raytrace.tree import REFRACTED

from test_raytrace_precision import transformed


def far_eye_glass(distance, backdrop=None):
    """A unit glass sphere (kt 0.8, ior 1.5, absorption 0.5, no Fresnel) before an ambient-only ball
    (or `backdrop`), seen by an orthographic camera `distance` away along +z: the image does not
    depend on it."""
    return {"camera": {"eye": [0, 0, distance], "target": [0, 0, 0], "projection": "orthographic",
                       "ortho_height": 2.2, "width": 32, "height": 32, "far": distance + 10},
            "background": [0, 0, 0], "ambient": [1, 1, 1], "lights": [],
            "materials": {"g": {"kd": 0, "kt": 0.8, "ior": 1.5, "absorption": 0.5}, "f": {"kd": 0, "ka": 1}},
            "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "g"},
                        backdrop or {"type": "sphere", "center": [0, 0, -6], "radius": 4, "material": "f"}],
            "render": {"method": "raytrace", "fresnel": "none", "max_depth": 5}}


def test_an_orthographic_image_does_not_depend_on_the_eye_distance():
    """Eye 5, 1000 or 5000 away: the same image within 1e-4 (measured: bit for bit). The offset was
    1e-4 x the box around the eye and the objects (0.1 at 1000, 0.5 at 5000): the image changed by up
    to 0.29 and the dark rim of the refracted ball vanished."""
    ref = render(Scene.from_dict(far_eye_glass(5)))
    b2 = 2 * (1.1 / 32) ** 2  # the centre pixel's ray: at (1.1 / 32, -1.1 / 32); its chord is 2 cos(asin(b / 1.5))
    assert ref[16, 16, 0] == pytest.approx(0.64 * np.exp(-0.5 * 2 * np.sqrt(1 - b2 / 2.25)), abs=1e-5)
    for distance in (1000, 5000):
        assert np.abs(render(Scene.from_dict(far_eye_glass(distance))) - ref).max() <= 1e-4


def test_images_and_shadows_do_not_depend_on_the_eye_distance():
    """An opaque sphere and a box mesh on a floor under a point light, seen obliquely by an
    orthographic camera 6 or 5000 away: every shadow ray gives the same visibility and the images
    agree within 1e-5 (measured: bit for bit). The offset of 0.5 at 5000 changed 63 of the 2304
    pixels by > 0.05; with the offset fixed, hits found from the ray's origin on the eye's plane,
    rounded to ulp(5000) / 2 = 2.4e-4, still moved the shading by up to 5e-4 (`camera.line_point`)."""
    def scene(distance):
        view = np.array([0, 0.35, 1]) / np.linalg.norm([0, 0.35, 1])
        return Scene.from_dict({
            "camera": {"eye": [float(v) for v in np.array([0, 0.6, 0]) + distance * view], "target": [0, 0.6, 0],
                       "projection": "orthographic", "ortho_height": 3, "width": 48, "height": 48,
                       "far": distance + 20},
            "ambient": [0.05, 0.05, 0.05], "lights": [{"type": "point", "position": [2, 4, 1]}],
            "materials": {"s": {"kd": 0.8, "ka": 1, "ks": 0.5, "n": 40}},
            "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "s"},
                        {"type": "mesh", "builtin": "box", "resolution": 1, "smooth": False, "material": "s",
                         "transform": {"translate": [1.3, 0.3, 0.8], "rotate_deg": [0, 30, 0], "scale": 0.3}},
                        {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "s"}],
            "render": {"method": "raytrace", "max_depth": 1}})
    near, far = render_frame(scene(6)), render_frame(scene(5000))
    assert 200 < (near.ray_tree.visibility == 0).sum() < 1000 and np.any(near.ray_tree.object == 1)
    np.testing.assert_array_equal(far.ray_tree.visibility, near.ray_tree.visibility)
    assert np.abs(far.image - near.image).max() <= 1e-5


def pane(thickness, absorption):
    """A glass pane (box mesh, kt 0.9, ior 1.5, no Fresnel) 6 x 6 x `thickness` before an ambient-only
    ball, in a scene 30 units deep: each pixel sees the ball through it, 0.81 exp(-absorption thickness)."""
    return {"camera": {"eye": [0, 0, 10], "target": [0, 0, 0], "fov_y": 10, "width": 8, "height": 8, "far": 30},
            "background": [0, 0, 0], "ambient": [1, 1, 1], "lights": [],
            "materials": {"g": {"kd": 0, "kt": 0.9, "ior": 1.5, "absorption": absorption}, "b": {"kd": 0, "ka": 1}},
            "objects": [{"type": "mesh", "builtin": "box", "material": "g", "smooth": False,
                         "transform": {"scale": [3, 3, thickness]}},
                        {"type": "sphere", "center": [0, 0, -8], "radius": 6, "material": "b"}],
            "render": {"method": "raytrace", "max_depth": 6, "fresnel": "none"}}


@pytest.mark.parametrize("absorption", [0.0, 0.5])
@pytest.mark.parametrize("thickness", [1e-3, 1e-5])
def test_a_pane_thinner_than_a_millimetre_is_entered_and_left(thickness, absorption):
    """Panes 1e-3 and 1e-5 thick: every pixel 0.81 exp(-absorption x thickness / cos) within 1e-5
    (measured 3e-7). Rays started 2.9e-3 (1e-4 x the scene's box) off the front face skipped the back
    face of the 1 mm pane: 0.33 with absorption (absorbed all the way to the ball), 0.90 without."""
    image = render(Scene.from_dict(pane(thickness, absorption)))
    np.testing.assert_allclose(image[..., 0], 0.81 * np.exp(-absorption * thickness), atol=1e-5)


def refracted_exits(scene):
    """Per primary hit on the unit sphere at the origin (material 0) of an orthographic view down -z:
    its distance b from the axis, and the recorded exit point and direction of its twice-refracted ray."""
    tree = render_frame(Scene.from_dict(scene)).ray_tree
    b, points, directions = [], [], []
    for k in np.flatnonzero((tree.parent == -1) & (tree.material == 0)):
        inside = np.flatnonzero((tree.parent == k) & (tree.kind == REFRACTED))
        out = np.flatnonzero(np.isin(tree.parent, inside) & (tree.kind == REFRACTED))
        if inside.size == 1 and out.size == 1:
            b.append(np.hypot(*tree.position[k, :2].astype(float)))
            points.append(tree.position[inside[0]].astype(float))
            directions.append(-tree.view[out[0]].astype(float))
    return np.array(b), np.array(points), np.array(directions)


def test_refracted_rays_keep_their_path():
    """A ray at distance b from the axis of a unit glass sphere (ior 1.5) refracts in at angle r =
    asin(b / 1.5), leaves at the point 2 r - asin(b) around from its entry and is deviated by
    2 (asin b - r) (Snell's law, closed form): exit points within 1e-5 (measured 2e-6) and deviations
    within 5e-5 rad for every b up to 0.998 (measured 6e-6). Rays started 6.6e-4 off the surface along
    its normal ran parallel to their path: exit points off by 5.8e-4, deviations by 8.7e-3 rad."""
    wall = {"type": "plane", "point": [0, 0, -3], "normal": [0, 0, 1], "material": "f"}  # meets every exit ray
    b, points, directions = refracted_exits(far_eye_glass(5, wall))
    assert b.size > 400 and b.max() > 0.99
    r = np.arcsin(b / 1.5)
    turn = np.pi - 2 * r  # the exit point's angle from the entry, seen from the centre
    entry = np.arcsin(b)  # the entry point's angle from +z
    np.testing.assert_allclose(np.hypot(points[:, 0], points[:, 1]), np.abs(np.sin(entry + turn)), atol=1e-5)
    np.testing.assert_allclose(points[:, 2], np.cos(entry + turn), atol=1e-5)
    deviation = np.arccos(np.clip(-directions[:, 2] / np.linalg.norm(directions, axis=1), -1, 1))
    np.testing.assert_allclose(deviation, 2 * (np.arcsin(b) - r), atol=5e-5)


FACETED = {
    "camera": {"eye": [0, 0.5, 3], "target": [0, 0, 0], "fov_y": 40, "width": 48, "height": 48, "near": 0.1, "far": 10},
    "ambient": [0, 0, 0], "lights": [{"type": "directional", "direction": [1, -0.4, -0.3]}],
    "materials": {"m": {"kd": [0.8, 0.8, 0.8]},
                  "g": {"kd": [0, 0, 0], "kt": 1.0, "ior": 1.5}},
    "objects": [{"type": "mesh", "builtin": "sphere", "resolution": 8, "smooth": False, "material": "m",
                 "transform": {"translate": [-0.6, 0, 0], "scale": 0.5}},
                {"type": "mesh", "builtin": "box", "resolution": 1, "smooth": False, "material": "g",
                 "transform": {"translate": [0.6, 0, 0], "rotate_deg": [20, 30, 0], "scale": 0.4}}],
    "render": {"method": "raytrace", "shadows": True, "max_depth": 2, "fresnel": "none"},
}


@pytest.mark.parametrize("light_buffer", [False, True])
@pytest.mark.parametrize("scale, shift", [(1.0, 0.0), (1e-3, 0.0), (1.0, 1e4), (1e3, -3e5)])
def test_no_surface_shadows_or_blocks_itself(scale, shift, light_buffer):
    """A faceted sphere (convex) and a glass box, at scale 1e-3 and 1e3 and 1e4 / 3e5 from the origin:
    every hit on the sphere whose face looks at the light is lit (visibility 1: nothing but its own
    facets could block it), and no ray refracted into the box meets the side it entered by again --
    through the BVH and through the light buffer. (Offsets of 1 x 2^-23 of the coordinates, not 8,
    left 9 of the 908 lit facets dark 1e4 from the origin.) Near the origin every such ray leaves
    through another side; far from it, where the box is 0.8 across and the offset 8 x 2^-23 x 1e4 =
    0.01, a ray that enters within the offset of an edge may start past the side next to it and
    leave the box unseen (measured 2 of 130)."""
    d = transformed(FACETED, scale=scale, shift=(shift, shift, shift))
    tree = render_frame(Scene.from_dict(d), light_buffer=light_buffer).ray_tree
    to_light = -np.array(d["lights"][0]["direction"], float) / np.linalg.norm(d["lights"][0]["direction"])
    sphere = np.flatnonzero((tree.parent == -1) & (tree.object == 0))
    facing = sphere[tree.normal[sphere] @ to_light > 1e-3]
    assert facing.size > 200
    np.testing.assert_array_equal(tree.visibility[facing, 0], 1.0)
    box = np.flatnonzero((tree.parent == -1) & (tree.object == 1))
    inside = np.flatnonzero(np.isin(tree.parent, box) & (tree.kind == REFRACTED))
    met = inside[tree.object[inside] == 1]
    assert inside.size > 100 and met.size >= (inside.size if shift == 0 else 0.95 * inside.size)
    entry_normal = tree.normal[tree.parent[met]]  # normals face the ray: the side it entered by, seen
    assert np.sum(tree.normal[met] * entry_normal, axis=1).min() > -0.99  # from inside, would face back


@pytest.mark.parametrize("shift", [0.0, 1e4])
def test_rays_inside_a_glass_sphere_cross_it(shift):
    """A glass sphere (kr 0.1, kt 0.9, Schlick, depth 4) at the origin and 1e4 from it: every ray
    inside it -- refracted in, or reflected off its inner wall -- meets its wall again across a
    chord of at least 2 cos(asin(1 / 1.5)) = 1.49 (the steepest a refracted ray enters at; internal
    reflections keep that angle). A reflected direction several bounces deep is unit only to a few
    ulps, and the hit point c - f + s d carried that off the sphere (|p| = 1 + 8e-7 against an
    offset of 9.5e-7): 3 of 4872 such rays met the wall they had just left, 1e-6 on."""
    d = {"camera": {"eye": [shift, shift, shift + 4], "target": [shift, shift, shift], "fov_y": 40, "width": 64,
                    "height": 64, "near": 0.1, "far": 20},
         "ambient": [1, 1, 1], "background": [1, 1, 1], "lights": [{"type": "directional", "direction": [-1, -1, -1]}],
         "materials": {"g": {"kd": 0, "kt": 0.9, "kr": 0.1, "ior": 1.5, "absorption": 0.3}},
         "objects": [{"type": "sphere", "center": [shift, shift, shift], "radius": 1, "material": "g"}],
         "render": {"method": "raytrace", "max_depth": 4, "fresnel": "schlick"}}
    tree = render_frame(Scene.from_dict(d)).ray_tree
    inside = np.flatnonzero(tree.medium == 0)
    assert inside.size > 4000 and np.all(tree.material[inside] == 0)
    assert tree.distance[inside].min() > 2 * np.sqrt(1 - 1 / 1.5 ** 2) - 0.02


def test_a_light_on_a_wall_lights_what_faces_it():
    """A point light set exactly on a wall (the plane z = 0) and a sphere in front of it: the shadow
    rays end the offset short of the light, so the wall it sits on does not shadow the sphere, and
    the image equals the unshadowed render exactly. (Rays that stepped off along themselves,
    offset / cos, then ran to the offset short of the light ran past it into the wall: 53 of the
    576 pixels dark.)"""
    d = {"camera": {"eye": [5, 0.5, 1.0], "target": [0, 0, 1.6], "fov_y": 30, "width": 24, "height": 24},
         "ambient": [0, 0, 0], "lights": [{"type": "point", "position": [0.3, 0.2, 0.0]}],
         "materials": {"m": {"kd": [0.8, 0.8, 0.8]}},
         "objects": [{"type": "sphere", "center": [0, 0, 2], "radius": 0.8, "material": "m"},
                     {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "material": "m"}],
         "render": {"method": "raytrace", "max_depth": 1}}
    shadowed, free = render(Scene.from_dict(d), shadows=True), render(Scene.from_dict(d), shadows=False)
    sphere = free[..., 0] > 0
    assert sphere.sum() > 50
    np.testing.assert_array_equal(shadowed, free)
