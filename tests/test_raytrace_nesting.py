"""Nested media in the ray tracer (`renderers.raytrace.nesting`): a glass sphere inside a water sphere
refracts at each surface by n_outside / n_inside and absorbs by the medium each segment is in."""

import numpy as np
import pytest

from difflab import Scene, render, render_frame
from difflab.fit import evaluate_tree
from difflab.renderers.compile import compile_scene
from difflab.renderers.raytrace.medium import camera_media
from difflab.renderers.raytrace.nesting import MEDIA_DEPTH

N_WATER, N_GLASS = 1.333, 1.5
A_WATER, A_GLASS = 0.5, 0.8  # water absorbs red, glass green (per unit length)
SIDE, VIEW = 25, 2.5  # orthographic pixels and view height: pixel centres at multiples of 0.1


def nested(fresnel="none", water=A_WATER, glass=A_GLASS, **camera):
    """Glass (radius 0.5) inside water (radius 1), concentric at the origin, kt 1, kr 0, seen by an
    orthographic camera down -z against an emissive white backdrop at z = -3."""
    cam = {"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic", "ortho_height": VIEW,
           "width": SIDE, "height": SIDE, "far": 20, **camera}
    return Scene.from_dict({
        "camera": cam, "ambient": [1, 1, 1], "background": [0, 0, 0], "lights": [],
        "materials": {"water": {"kd": 0, "kt": 1, "ior": N_WATER, "absorption": [water, 0, 0]},
                      "glass": {"kd": 0, "kt": 1, "ior": N_GLASS, "absorption": [0, glass, 0]},
                      "back": {"kd": 0, "ka": 1}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "water"},
                    {"type": "sphere", "center": [0, 0, 0], "radius": 0.5, "material": "glass"},
                    {"type": "plane", "point": [0, 0, -3], "normal": [0, 0, 1], "material": "back"}],
        "render": {"method": "raytrace", "fresnel": fresnel, "max_depth": 6, "shadows": False}})


def closed_form(b):
    """For a ray parallel to the axis at distance b < 0.5 N_WATER from it: its deviation through
    water -> glass -> water -> air (Bouguer: n r sin(angle to the radius) = b along the whole path,
    each surface turning it by incidence - refraction angle, four surfaces symmetric in pairs) and
    its path lengths in water and glass (chords of the lines at distance b / n from the centre)."""
    i1, t1 = np.arcsin(b), np.arcsin(b / N_WATER)
    i2, t2 = np.arcsin(b / (0.5 * N_WATER)), np.arcsin(b / (0.5 * N_GLASS))
    p_w, p_g = b / N_WATER, b / N_GLASS
    water = 2 * (np.sqrt(1 - p_w ** 2) - np.sqrt(0.25 - p_w ** 2))
    glass = 2 * np.sqrt(0.25 - p_g ** 2)
    return 2 * (i1 - t1 + i2 - t2), water, glass


def pixel_offsets():
    x = (np.arange(SIDE) + 0.5) * VIEW / SIDE - VIEW / 2
    return x[None, :], -x[:, None]  # row 0 at the top: +y


def test_a_ray_through_glass_in_water_exits_as_snell_gives_and_absorbs_in_both():
    """Every ray through the glass (b < 0.6: 109 of 625 pixels): its exit direction is the closed
    form's within 1e-6 (measured 1.9e-7; it came out as for glass in air: x -0.233 where -0.131 at
    b 0.155), and its colour exp(-a_w d_w) red, exp(-a_g d_g) green within 1e-6 relative -- the
    water's absorption continuing after the glass (the centre gave exp(-0.25) where exp(-0.5)). The
    recorded tree says so too: medium none, water, glass, water, none on the path's five segments."""
    scene = nested()
    frame = render_frame(scene)
    tree = frame.ray_tree
    x, y = pixel_offsets()
    b = np.hypot(x, y) * np.ones((SIDE, SIDE))
    through = b < 0.6
    assert through.sum() == 109
    deviation, water, glass = closed_form(b[through])
    np.testing.assert_allclose(frame.image[through, 0], np.exp(-A_WATER * water), rtol=1e-6)
    np.testing.assert_allclose(frame.image[through, 1], np.exp(-A_GLASS * glass), rtol=1e-6)
    np.testing.assert_array_equal(frame.image[..., 2][through], 1.0)
    assert frame.image[SIDE // 2, SIDE // 2, 0] == pytest.approx(np.exp(-A_WATER), rel=1e-5)

    back = scene.material_index("back")
    last = np.array([tree.sample_offset[s] + np.flatnonzero(
        tree.material[tree.sample_offset[s]:tree.sample_offset[s + 1]] == back)[0]
        for s in np.flatnonzero(through.ravel())])
    exit_dir = -tree.view[last]
    radial = np.stack([x * np.ones_like(b), y * np.ones_like(b)], -1)[through] / np.maximum(b[through], 1e-9)[:, None]
    expected = np.column_stack([-np.sin(deviation)[:, None] * radial, -np.cos(deviation)])
    np.testing.assert_allclose(exit_dir, expected, atol=1e-6)
    w, g = scene.material_index("water"), scene.material_index("glass")
    assert [tree.medium[k - d] for k in last[:1] for d in range(4, -1, -1)] == [-1, w, g, w, -1]


def test_fresnel_takes_the_same_ratio():
    """Exact Fresnel, head-on through the centre (kr 0: only the transmitted shares go on): the
    backdrop comes out (1 - F_aw)^2 (1 - F_wg)^2, F = ((n1 - n2) / (n1 + n2))^2 at the air-water and
    water-glass surfaces, times the absorption (as glass in air it would take (1 - F_ag)^2)."""
    image = render(nested(fresnel="exact"))
    f_aw = ((1 - N_WATER) / (1 + N_WATER)) ** 2
    f_wg = ((N_WATER - N_GLASS) / (N_WATER + N_GLASS)) ** 2
    centre = image[SIDE // 2, SIDE // 2]
    transmitted = (1 - f_aw) ** 2 * (1 - f_wg) ** 2
    np.testing.assert_allclose(centre, transmitted * np.array([np.exp(-A_WATER), np.exp(-A_GLASS * 1.0), 1.0]),
                               rtol=1e-5)


def test_the_recorded_tree_re_evaluates_the_nested_render():
    """The tree's per-node medium and distance carry the nesting: evaluated at the rendered values it
    gives the image, and at other absorptions (which do not move a ray) the image rendered with them."""
    scene = nested(fresnel="schlick")
    frame = render_frame(scene)
    again = evaluate_tree(frame.ray_tree, scene.materials, scene.lights, scene.ambient, scene.background)
    np.testing.assert_allclose(np.asarray(again), frame.image, rtol=1e-5, atol=1e-7)
    other = nested(fresnel="schlick", water=1.7, glass=0.3)
    moved = evaluate_tree(frame.ray_tree, other.materials, other.lights, other.ambient, other.background)
    np.testing.assert_allclose(np.asarray(moved), render(other), rtol=1e-5, atol=1e-7)


def test_an_eye_in_glass_in_water_starts_in_both():
    """A perspective eye at the common centre: it starts in the glass, with the water around it
    (`camera_media`, innermost first); every ray is radial (no bending) and absorbs 0.5 in each."""
    scene = nested(projection="perspective", eye=[0, 0, 0], target=[0, 0, -1], fov_y=60, width=12, height=12,
                   near=0.01)
    scene = Scene.from_dict({**scene.to_dict(), "objects": scene.to_dict()["objects"][:2], "background": [1, 1, 1]})
    w, g = scene.material_index("water"), scene.material_index("glass")
    assert camera_media(compile_scene(scene)) == (((1, g), (0, w)), False)
    image = render(scene)
    np.testing.assert_allclose(image[..., 0], np.exp(-0.5 * A_WATER), rtol=1e-5)
    np.testing.assert_allclose(image[..., 1], np.exp(-0.5 * A_GLASS), rtol=1e-5)


def test_past_the_nesting_limit_the_outermost_object_is_forgotten():
    """Five concentric clear (ior 1) spheres of radii 1, 0.8 .. 0.2, the outermost absorbing red and the
    innermost green, seen head-on: entering the fifth, the ray forgets the first (MEDIA_DEPTH = 4),
    so it absorbs red over the first 0.2 of the outer shell only, exp(-0.2) (exp(-0.4) were it
    remembered), and green across the innermost, exp(-0.4) -- the documented limit."""
    assert MEDIA_DEPTH == 4
    clear = {"kd": 0, "kt": 1}
    d = {"camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic", "ortho_height": 0.1,
                    "width": 1, "height": 1, "far": 20},
         "ambient": [0, 0, 0], "background": [1, 1, 1], "lights": [],
         "materials": {"clear": clear, "red": {**clear, "absorption": [1, 0, 0]},
                       "green": {**clear, "absorption": [0, 1, 0]}},
         "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": r, "material": m}
                     for r, m in ((1, "red"), (0.8, "clear"), (0.6, "clear"), (0.4, "clear"), (0.2, "green"))],
         "render": {"method": "raytrace", "max_depth": 12, "shadows": False}}
    np.testing.assert_allclose(render(Scene.from_dict(d))[0, 0], [np.exp(-0.2), np.exp(-0.4), 1.0], rtol=1e-5)


@pytest.mark.parametrize("water_kind", ["plane", "box"])
@pytest.mark.parametrize("glass_first", [True, False])
def test_touching_transparent_objects_cross_as_one_interface(water_kind, glass_first):
    """A glass box (1 thick, absorbing green) resting exactly on water (a plane, or a box 1 deep,
    absorbing red), seen along one ray from the air: the shared face is one interface, whichever
    of the two the tracer meets first (the order of the objects, the BVH's pick), so the ray goes
    air -> glass -> water (-> air) with Snell's sines sin_air / n, leaves the water box along its
    first direction, and absorbs exp(-a / cos) in each layer. (Meeting the glass's face first, it
    left into air and never saw the water; meeting the water's, the water box's bottom let it out
    into the glass's medium.)"""
    eye, target = np.array([0.0, 3.0, 2.2]), np.array([0.0, 0.5, 0.0])
    d0 = (target - eye) / np.linalg.norm(target - eye)
    glass = {"type": "mesh", "builtin": "box", "material": "glass", "smooth": False,
             "transform": {"translate": [0, 0.5, 0], "scale": [4, 1, 4]}}
    water = {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "water"} if water_kind == "plane" \
        else {"type": "mesh", "builtin": "box", "material": "water", "smooth": False,
              "transform": {"translate": [0, -0.5, 0], "scale": [4, 1, 4]}}
    back = {"type": "plane", "point": [0, -1.5 if water_kind == "box" else -1.0, 0], "normal": [0, 1, 0],
            "material": "back"}
    scene = Scene.from_dict({
        "camera": {"eye": eye.tolist(), "target": target.tolist(), "fov_y": 20, "width": 1, "height": 1, "far": 20},
        "ambient": [1, 1, 1], "lights": [],
        "materials": {"glass": {"kd": 0, "kt": 1, "ior": N_GLASS, "absorption": [0, A_GLASS, 0]},
                      "water": {"kd": 0, "kt": 1, "ior": N_WATER, "absorption": [A_WATER, 0, 0]},
                      "back": {"kd": 0, "ka": 1}},
        "objects": [glass, water, back] if glass_first else [water, glass, back],
        "render": {"method": "raytrace", "fresnel": "none", "max_depth": 6, "shadows": False}})
    frame = render_frame(scene)
    tree = frame.ray_tree
    sin_air = np.hypot(d0[0], d0[2])
    cos_g, cos_w = np.sqrt(1 - (sin_air / N_GLASS) ** 2), np.sqrt(1 - (sin_air / N_WATER) ** 2)
    np.testing.assert_allclose(frame.image[0, 0], [np.exp(-A_WATER / cos_w), np.exp(-A_GLASS / cos_g), 1.0],
                               rtol=1e-5)
    w, back_id = scene.material_index("water"), scene.material_index("back")
    in_water = np.flatnonzero(tree.medium == w)
    assert len(in_water) == 1
    np.testing.assert_allclose(-tree.view[in_water[0], 1], -cos_w, rtol=1e-6)
    last = np.flatnonzero(tree.material == back_id)
    assert len(last) == 1
    expected = d0 if water_kind == "box" else -tree.view[in_water[0]]
    np.testing.assert_allclose(-tree.view[last[0]], expected, atol=1e-6)
