"""An image texture on an analytic plane: a right-handed orthonormal uv frame seen from the normal's
side (`Plane.uv_frame`), the same in the ray tracer and the rasterizer, and the checker's own rule."""

import numpy as np
import pytest

from conftest import scene_dict
from difflab import Scene, render

#: (normal, (t, b)) by hand: u to the right and v up as seen from the normal's side.
FRAMES = [
    ((0, 0, 1), ((1, 0, 0), (0, 1, 0))),  # a wall facing +z: the builtin quad turned upright
    ((0, 0, -1), ((-1, 0, 0), (0, 1, 0))),
    ((1, 0, 0), ((0, 0, -1), (0, 1, 0))),
    ((-1, 0, 0), ((0, 0, 1), (0, 1, 0))),
    ((0, 1, 0), ((1, 0, 0), (0, 0, -1))),  # a floor: upright for a camera at +z looking toward -z
    ((0, -1, 0), ((1, 0, 0), (0, 0, 1))),
    ((0, 1, 1e-9), ((1, 0, 0), (0, 0, -1))),  # nearly a floor: the floor's frame
    ((1, 1, 0), ((0, 0, -1), (-0.5 ** 0.5, 0.5 ** 0.5, 0))),  # b: world up along the plane
]


def plane(normal, point=(0, 0, 0)):
    scene = Scene.from_dict(scene_dict([{"type": "plane", "point": list(point), "normal": list(normal),
                                         "material": "m"}], {"m": {}}))
    return scene.objects[0]


@pytest.mark.parametrize("normal, frame", FRAMES)
def test_the_uv_frame_is_right_handed_orthonormal_and_upright(normal, frame):
    p = plane(normal)
    t, b = p.uv_frame()
    np.testing.assert_allclose(t, frame[0], atol=1e-8)  # 1e-9 off for the nearly vertical normal
    np.testing.assert_allclose(b, frame[1], atol=1e-8)
    np.testing.assert_allclose(np.cross(t, b), p.normal, atol=1e-12)  # t x b = n: seen from n, unmirrored


#: Normals well inside each region of `Plane.uv_frame`'s rule: floors, ceilings, walls, slopes.
REGION_NORMALS = [(0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0), (0, 0, 1), (0, 0, -1), (0.3, 1, -0.2),
                  (1, 0.4, 0.1), (-0.2, -0.5, 1)]


@pytest.mark.parametrize("normal", REGION_NORMALS)
@pytest.mark.parametrize("tilt", [2e-6, 1e-3])
def test_a_small_tilt_turns_the_frame_by_at_most_the_tilt(normal, tilt):
    """Within a region the frame is smooth in the normal: tilting it by `tilt` radians (any way)
    moves t and b by O(tilt). The old rule (b = -z only within 1e-6 of vertical) turned a floor's
    frame 90 degrees at a 2e-6 tilt toward x and 180 degrees at 1e-3 toward -z."""
    base = np.asarray(normal, float) / np.linalg.norm(normal)
    t0, b0 = plane(normal).uv_frame()
    for axis in np.random.default_rng(0).normal(size=(8, 3)):
        axis -= np.dot(axis, base) * base
        tilted = np.cos(tilt) * base + np.sin(tilt) * axis / np.linalg.norm(axis)
        t, b = plane(tilted).uv_frame()
        assert np.abs(t - t0).max() <= 2 * tilt and np.abs(b - b0).max() <= 2 * tilt


def test_every_frame_is_right_handed_and_orthonormal():
    normals = np.random.default_rng(1).normal(size=(200, 3))
    normals = np.concatenate([normals, [[1, 1, 0], [0, 1, 1], [1, 1, 1], [0, -1, 1], [1, -1, 0]]])
    for normal in normals:
        p = plane(normal)
        t, b = p.uv_frame()
        np.testing.assert_allclose([t @ t, b @ b, t @ b], [1, 1, 0], atol=1e-12)
        np.testing.assert_allclose(np.cross(t, b), p.normal, atol=1e-12)


def test_uv_is_measured_from_the_point_in_scene_units():
    p = plane((0, 0, 1), point=(2, 3, 5))
    np.testing.assert_allclose(p.uv([[2, 3, 5], [2.5, 3, 5], [2, 4.25, 5]]), [[0, 0], [0.5, 0], [0, 1.25]])


MARKER = np.zeros((64, 64, 3), np.float32)
MARKER[:32, :32] = 1.0  # the image's top-left quarter white (row 0 is the top)


def front_view(tmp_path, normal, point, obj=None):
    """One texture tile (uv in [0, 1]^2 from `point`) filling an 8x8 orthographic view from the normal's
    side, screen up along b; the marker texture, unlit and nearest."""
    np.save(tmp_path / "marker.npy", MARKER)
    t, b = plane(normal, point).uv_frame()
    centre = np.asarray(point, float) + 0.5 * t + 0.5 * b
    facing = np.cross(t, b)  # the unit normal
    camera = {"eye": list(centre + 3 * facing), "target": list(centre), "up": list(b), "projection": "orthographic",
              "ortho_height": 1, "width": 8, "height": 8, "near": 1, "far": 10}
    material = {"ka": 1, "kd": 0, "texture": str(tmp_path / "marker.npy"), "texture_target": "ka",
                "filter": "nearest"}
    obj = obj or {"type": "plane", "point": list(point), "normal": list(normal), "material": "m"}
    return scene_dict([obj], {"m": material}, camera=camera, ambient=(1, 1, 1))


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("normal", [n for n, _ in FRAMES])
def test_a_plane_shows_its_texture_upright_and_unmirrored_from_the_front(tmp_path, method, normal):
    """The old rule (uv = the two world axes other than the normal's dominant one) showed a floor's
    white quarter at the bottom left (mirrored), a -z wall's at the top right, a +x wall's turned
    90 degrees, and stretched the (1, 1, 0) plane's tile by sqrt(2)."""
    image = render(front_view(tmp_path, normal, (0.25, -0.5, 0.75)), method=method)[..., 0]
    want = np.zeros((8, 8))
    want[:4, :4] = 1.0
    np.testing.assert_array_equal(image, want)


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("normal", [(2e-6, 1, 0), (0, 1, -1e-3), (1e-3, 1, 1e-3)])
def test_a_slightly_tilted_floor_shows_the_floors_picture(tmp_path, method, normal):
    """A ramp of 0.06 degrees or less shows what the flat floor shows (seen by the floor's camera);
    the old rule turned (2e-6, 1, 0)'s picture 90 degrees and (0, 1, -1e-3)'s 180 degrees."""
    point = (0.25, -0.5, 0.75)
    floor = render(front_view(tmp_path, (0, 1, 0), point), method=method)
    ramp = {"type": "plane", "point": list(point), "normal": list(normal), "material": "m"}
    np.testing.assert_array_equal(render(front_view(tmp_path, (0, 1, 0), point, ramp), method=method), floor)


@pytest.mark.parametrize("method", ["raster", "raytrace"])
def test_a_floor_plane_matches_the_builtin_quad(tmp_path, method):
    """The builtin quad (normal +y, uv (x + 0.5, 0.5 - z)) and a floor plane through its corner
    (-0.5, 0, 0.5) show the same picture."""
    floor = render(front_view(tmp_path, (0, 1, 0), (-0.5, 0, 0.5)), method=method)
    quad = {"type": "mesh", "builtin": "quad", "material": "m"}
    np.testing.assert_array_equal(floor, render(front_view(tmp_path, (0, 1, 0), (-0.5, 0, 0.5), quad), method=method))


@pytest.mark.parametrize("method", ["raster", "raytrace"])
def test_the_checker_keeps_world_cells_wherever_the_point_is(method):
    """A checker is a solid texture of world coordinates (as POV-Ray's), not of the plane's uv:
    moving `point` within the plane, or flipping the normal, leaves its cells in place."""
    def image(point, normal):
        return render(scene_dict(
            [{"type": "plane", "point": point, "normal": normal, "material": "c"}],
            {"c": {"ka": 1, "kd": 0, "checker": {"size": 0.5, "ka2": [0.2, 0.2, 0.2]}}},
            camera={"eye": [0.1, 5, 0.2], "target": [0.1, 0, 0.2], "up": [0, 0, -1], "projection": "orthographic",
                    "ortho_height": 2, "width": 16, "height": 16, "near": 1, "far": 10},
            ambient=(1, 1, 1)), method=method)[..., 0]
    base = image([0, 0, 0], [0, 1, 0])
    x = 0.1 + (np.arange(16) + 0.5) / 8 - 1  # pixel centres: x right, z down the screen
    z = 0.2 + (np.arange(16) + 0.5) / 8 - 1
    cell = (np.floor(x[None, :] / 0.5) + np.floor(z[:, None] / 0.5)) % 2
    np.testing.assert_allclose(base, np.where(cell == 0, 1.0, 0.2), atol=1e-6)
    np.testing.assert_array_equal(image([0.3, 0, -0.7], [0, 1, 0]), base)
    np.testing.assert_array_equal(image([0, 0, 0], [0, -1, 0]), base)


def floor_texture_scene(tmp_path, point, wrap, eye=(0.3, 2.0, 0.4)):
    """A floor plane through `point` seen straight down by a fixed 16 x 16 orthographic camera, a random
    64 x 64 texture, unlit and nearest."""
    np.save(tmp_path / "noise.npy", np.random.default_rng(1).random((64, 64, 3)).astype(np.float32))
    camera = {"eye": list(eye), "target": [eye[0], 0, eye[2]], "up": [0, 0, -1], "projection": "orthographic",
              "ortho_height": 1, "width": 16, "height": 16, "near": 0.5, "far": 10}
    material = {"ka": 1, "kd": 0, "texture": str(tmp_path / "noise.npy"), "texture_target": "ka",
                "filter": "nearest", "wrap": wrap}
    return scene_dict([{"type": "plane", "point": list(point), "normal": [0, 1, 0], "material": "m"}],
                      {"m": material}, camera=camera, ambient=(1, 1, 1))


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("wrap", ["repeat", "mirror"])
def test_a_repeating_texture_does_not_see_point_moved_by_whole_periods(tmp_path, method, wrap):
    """Moving `point` by (far, 0, -far) shifts uv by whole periods (1 repeat, 2 mirror): the same image.
    The old uv, measured from `point` in float32, changed 88 of 256 pixels (by up to 0.94) in the
    rasterizer at far = 1e5 and all 256 in both renderers at 1e6."""
    near = render(floor_texture_scene(tmp_path, (0, 0, 0), wrap), method=method)
    for far in (1e5, 1e6):
        np.testing.assert_array_equal(render(floor_texture_scene(tmp_path, (far, 0, -far), wrap), method=method), near)


def test_the_rasterizer_keeps_its_precision_with_the_eye_and_point_far_away(tmp_path):
    """A scene moved 1e5 along the floor (eye and point together) rasterizes the same image: uv is
    measured from the eye's foot, not from the world origin."""
    near = render(floor_texture_scene(tmp_path, (0.25, 0, 0.75), "repeat"), method="raster")
    far = floor_texture_scene(tmp_path, (1e5 + 0.25, 0, 0.75), "repeat", eye=(1e5 + 0.3, 2.0, 0.4))
    np.testing.assert_array_equal(render(far, method="raster"), near)


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("point", [(0.25, -0.5, 0.75), (1000.25, -0.5, -2999.5)])
def test_a_clamped_texture_keeps_its_place_at_point(tmp_path, method, point):
    """With wrap "clamp" the image lies on uv [0, 1]^2 from `point`, its edge texels beyond: seen 4
    units wide around uv (1, 0.5), the white top-left quarter fills u < 0.5, v > 0.5 -- not shifted by
    the whole units a repeating texture may be."""
    scene = front_view(tmp_path, (0, 1, 0), point)
    t, b = plane((0, 1, 0), point).uv_frame()
    centre = np.asarray(point, float) + 1.0 * t + 0.5 * b
    scene["camera"].update(eye=list(centre + 3 * np.cross(t, b)), target=list(centre), ortho_height=4, width=16,
                           height=16)
    scene["materials"]["m"]["wrap"] = "clamp"
    u = 1.0 + ((np.arange(16) + 0.5) / 16 - 0.5) * 4  # pixel centres' uv
    v = 0.5 + (0.5 - (np.arange(16) + 0.5) / 16) * 4  # row 0 at the top
    want = ((u[None, :] < 0.5) & (v[:, None] > 0.5)).astype(float)
    np.testing.assert_array_equal(render(scene, method=method)[..., 0], want)


#: An asymmetric 4 x 4 picture (row 0 at the top): an "F", read upright and unmirrored.
LETTER_F = np.array([[1, 1, 1, 0], [1, 0, 0, 0], [1, 1, 0, 0], [1, 0, 0, 0]], np.float32)


RANDOM_NORMALS = [tuple(n) for n in np.random.default_rng(2).normal(size=(6, 3))]


@pytest.mark.parametrize("normal", [n for n, _ in FRAMES] + RANDOM_NORMALS)
def test_planar_uv_is_the_planes_uv(normal):
    """`planar_uv` about an axis is a plane's uv (`Plane.uv_frame`) with that normal, centred (+ 0.5)
    and divided by `scale`: one frame for both. Before, its frame was (axis x z, axis x t) (x for
    axes near z): a wall facing +z got u = +y, v = -x, its picture turned 90 degrees."""
    from difflab.geometry import planar_uv

    point = np.array([0.25, -0.5, 0.75])
    p = plane(normal, point)
    points = np.random.default_rng(3).normal(size=(20, 3))
    np.testing.assert_allclose(planar_uv(points, normal, point, 2.0), p.uv(points) / 2.0 + 0.5, atol=1e-12)
    np.testing.assert_allclose(planar_uv(points, 3 * np.asarray(normal), point), p.uv(points) + 0.5, atol=1e-12)


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("normal", [n for n, _ in FRAMES])
def test_a_mesh_with_planar_uvs_shows_its_texture_upright_from_the_front(tmp_path, method, normal):
    """A square mesh, its uvs by `planar_uv` about its normal, seen from the front (screen up along
    the plane's b: world +y for a wall) shows the "F" upright: texel (row r, column c) in the view's
    2 x 2 pixel block (r, c) -- the top-left texel at the top left, the bar at the top."""
    from difflab.geometry import planar_uv

    point = np.array([0.25, -0.5, 0.75])
    t, b = plane(normal, point).uv_frame()
    corners = np.array([point + i * t + j * b for i, j in ((0, 0), (1, 0), (1, 1), (0, 1))])
    uvs = planar_uv(corners, normal, point + 0.5 * t + 0.5 * b)
    np.testing.assert_allclose(uvs, [[0, 0], [1, 0], [1, 1], [0, 1]], atol=1e-12)  # the tile: (0, 0) bottom left
    square = {"type": "mesh", "vertices": corners.tolist(), "faces": [[0, 1, 2], [0, 2, 3]], "uvs": uvs.tolist(),
              "material": "m"}
    scene = front_view(tmp_path, normal, point, square)
    np.save(tmp_path / "f.npy", np.repeat(LETTER_F[..., None], 3, axis=2))
    scene["materials"]["m"].update(texture=str(tmp_path / "f.npy"), wrap="clamp")
    np.testing.assert_array_equal(render(scene, method=method)[..., 0], np.kron(LETTER_F, np.ones((2, 2))))
