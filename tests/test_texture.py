"""Textures: mip pyramid, filters, wrap modes, perspective-correct uv and its derivatives, shading."""

import math
import tracemalloc

import numpy as np
import pytest

from conftest import scene_dict
from difflab import DifflabError, RenderError, TextureError, load_image, render, render_frame
from difflab._warp import wp
from difflab.io import save_image
from difflab.renderers.camera import CameraW, camera_struct, projection_matrix, view_matrix
from difflab.renderers.api import as_scene
from difflab.lighting.warp_model import MaterialW, target_only, textured_material
from difflab.renderers.texture.footprint import pixel_footprint, plane_uv_derivatives
from difflab.demos.textures import checker_texture, compare_filters
from difflab.renderers.texture.store import TextureStore, load_texture, mip_pyramid, sample

FILTERS = ["nearest", "bilinear", "mipmap", "trilinear", "ewa"]
WRAPS = ["repeat", "clamp", "mirror"]


# ---- 1. storage and pyramid ------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(16, 16), (8, 32), (4, 2)])
def test_each_mip_level_is_the_exact_box_mean_of_the_one_below(shape):
    texels = np.random.default_rng(0).random(shape + (3,)).astype(np.float32)
    levels = mip_pyramid(texels)
    assert levels[-1].shape[:2] == (1, 1)
    assert len(levels) == int(math.log2(max(shape))) + 1
    below = texels.astype(np.float64)  # the chain of box means is kept in float64, each level rounded once
    for above in levels[1:]:
        h, w = below.shape[:2]
        if h == 1:
            below = np.concatenate([below, below])  # a 1-row level pairs its row with itself
        if w == 1:
            below = np.concatenate([below, below], axis=1)
        below = below.reshape(above.shape[0], 2, above.shape[1], 2, 3).mean(axis=(1, 3))
        np.testing.assert_array_equal(above, below.astype(np.float32))


def checkerboard(h, w):
    r, c = np.mgrid[:h, :w]
    return ((r + c) % 2).astype(np.float32)[..., None].repeat(3, axis=2)


@pytest.mark.parametrize("shape", [(257, 257), (5, 5), (3, 3), (1, 5), (7, 2), (6, 9)])
def test_every_level_keeps_the_mean_of_the_image_at_any_size(shape):
    texels = np.random.default_rng(2).random(shape + (3,)).astype(np.float32)
    levels = mip_pyramid(texels)
    sizes = [shape]
    while sizes[-1] != (1, 1):
        sizes.append(tuple(max(1, n // 2) for n in sizes[-1]))  # OpenGL's level sizes
    assert [lv.shape[:2] for lv in levels] == sizes
    mean = texels.astype(np.float64).mean(axis=(0, 1))
    for lv in levels:
        np.testing.assert_allclose(lv.astype(np.float64).mean(axis=(0, 1)), mean, rtol=2e-7)


@pytest.mark.parametrize("shape, mean", [((5, 5), 0.48), ((3, 3), 4 / 9), ((1, 5), 0.4)])
def test_the_last_level_of_an_odd_checker_is_its_mean(shape, mean):
    # An odd edge repeated (the old rule) gave 0.375, 0.375 and 0.25: one texel counted twice per axis.
    np.testing.assert_allclose(mip_pyramid(checkerboard(*shape))[-1], np.full((1, 1, 3), mean), rtol=1e-6)


def test_an_odd_level_splits_the_texel_on_a_footprint_edge():
    row = np.arange(5, dtype=np.float32)[None, :, None]  # footprints [0, 2.5) and [2.5, 5)
    np.testing.assert_allclose(mip_pyramid(row)[1][0, :, 0], [(0 + 1 + 0.5 * 2) / 2.5, (0.5 * 2 + 3 + 4) / 2.5])


#: Most bytes per level-0 texel `mip_pyramid` may hold at once (traced numpy allocations, the
#: input excluded): the float64 first pass and its float32 copy, an odd axis's product, the levels.
MIP_PEAK_BYTES = 40


@pytest.mark.parametrize("shape", [(1, 1 << 16), ((1 << 16) + 1, 1), (1, (1 << 16) + 1), (256, 256), (257, 255),
                                   (4095, 3)])
def test_the_pyramid_stays_within_its_memory_whatever_the_shape(shape):
    """An axis of size 1 is not averaged (the old code gathered 4 full-size float64 taps along it:
    93 B / texel for 1 x 65536, 68 for 65537 x 1, 52 for 4095 x 3; now 26, 34, 38), and the taps
    are strided views, not gathered copies (256 x 256: 32 -> 20)."""
    texels = np.random.default_rng(3).random(shape + (3,)).astype(np.float32)
    tracemalloc.start()
    try:
        levels = mip_pyramid(texels)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak <= MIP_PEAK_BYTES * texels[..., 0].size
    np.testing.assert_allclose(levels[-1][0, 0], texels.astype(np.float64).mean(axis=(0, 1)), rtol=2e-7)


def test_every_texel_of_a_257_checker_pyramid_is_grey(tmp_path):
    # Old rule: the corner texel stayed 0 or 1 at every odd level (|error| 0.5; a 16 px render's
    # top-right pixel was 0.032 where the checker's mean is 0.5).
    for lv in mip_pyramid(checkerboard(257, 257))[1:]:
        np.testing.assert_allclose(lv, 0.5, atol=1e-5)
    np.save(tmp_path / "check.npy", checkerboard(257, 257))
    image = render(scene_dict(
        camera={"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic", "ortho_height": 1,
                "width": 16, "height": 16, "near": 1, "far": 10},
        ambient=[1, 1, 1], lights=[],
        materials={"t": {"ka": 1, "kd": 0, "texture": str(tmp_path / "check.npy"), "filter": "trilinear", "texture_target": "ka"}},
        objects=[{"type": "mesh", "builtin": "quad", "material": "t", "transform": {"rotate_deg": [90, 0, 0]}}]))
    np.testing.assert_allclose(image, 0.5, atol=1e-4)


def test_many_textures_of_different_sizes_share_one_array():
    a = np.full((5, 7, 3), 0.25, np.float32)
    b = np.random.default_rng(1).random((8, 4, 3)).astype(np.float32)
    store = TextureStore.from_images([a, b])
    levels = store.warp.level.numpy()
    first = store.warp.first_level.numpy()
    assert list(first) == [0, len(store.pyramids[0])]
    assert store.warp.texels.shape[0] == sum(lv.shape[0] * lv.shape[1] for p in store.pyramids for lv in p)
    assert tuple(levels[first[1]]) == (levels[first[1] - 1][0] + 1, 4, 8)  # after a's 1x1 last level
    # texel centres of b, nearest: b itself (rows flipped: v = 0 is the image's bottom row)
    r, c = np.meshgrid(np.arange(8), np.arange(4), indexing="ij")
    uv = np.stack([(c + 0.5) / 4, (r + 0.5) / 8], -1).reshape(-1, 2)
    np.testing.assert_array_equal(sample(store, 1, uv, filter="nearest"), np.flipud(b).reshape(-1, 3))
    np.testing.assert_array_equal(sample(store, 1, uv, filter="bilinear"), np.flipud(b).reshape(-1, 3))


# ---- 2. filters and wrap modes ---------------------------------------------------------------


def edge_uvs(count=400, seed=2):
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-3, 3, (count, 2))
    special = [[1, 1], [0, 0], [1, 0], [0, 1], [-1e-7, 1 + 1e-7], [-1, -1], [1e30, -1e30], [3e9, 7.5],
               [np.nan, 0.5], [np.inf, -np.inf]]
    uv[:len(special)] = special
    duv = rng.normal(0, 0.2, (count, 2, 2))
    duv[10:20] = 0.0  # no footprint
    duv[20:30, 1] = 0.0  # a line footprint
    duv[30:40] *= 1e4  # bigger than the texture
    return uv, duv[:, 0], duv[:, 1]


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("filter", FILTERS)
def test_a_constant_texture_samples_to_the_constant(filter, wrap):
    store = TextureStore.from_images([np.full((6, 10, 3), [0.2, 0.5, 0.7], np.float32)])
    out = sample(store, 0, *edge_uvs(), filter=filter, wrap=wrap)
    # Lerps of equal values are exact; EWA divides float32 sums of up to ~2 x 35^2 weighted taps.
    rtol = 1e-5 if filter == "ewa" else 2e-7
    np.testing.assert_allclose(out, np.broadcast_to([0.2, 0.5, 0.7], out.shape), rtol=rtol, atol=0)


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("filter", FILTERS)
def test_fetches_stay_in_range_at_the_edges(filter, wrap):
    """Texels hold their own index: any fetch outside the texture would read a value out of range
    (or another level); every filter is a convex combination, so results stay in [0, max]."""
    h, w = 4, 8
    image = np.arange(h * w, dtype=np.float32).reshape(h, w)[..., None].repeat(3, -1)
    store = TextureStore.from_images([image, np.full((2, 2, 3), 1e6, np.float32)])  # a poison neighbour
    out = sample(store, 0, *edge_uvs(), filter=filter, wrap=wrap)
    assert np.all(np.isfinite(out)) and out.min() >= 0.0 and out.max() <= (h * w - 1) * (1 + 1e-6)


@pytest.mark.parametrize("wrap, want", [("repeat", [0, 7, 0, 0]), ("clamp", [7, 0, 7, 7]), ("mirror", [7, 0, 7, 0])])
def test_u_equal_one_picks_the_documented_texel(wrap, want):
    """u = 1, just below 0, just above 1, and 2.01 (mirror: [1, 2] is reflected, [2, 3] is not)."""
    image = np.tile(np.arange(8, dtype=np.float32)[None, :, None], (4, 1, 3))
    store = TextureStore.from_images([image])
    out = sample(store, 0, [[1.0, 0.5], [-0.01, 0.5], [1.01, 0.5], [2.01, 0.5]], filter="nearest", wrap=wrap)
    assert out[:, 0].tolist() == want


def test_mipmap_levels_follow_the_footprint():
    """A footprint of 2^k texels reads level k: the pyramid of a checker of 1-texel cells is 0.5 from
    level 1 on, while level 0 (magnification) keeps the texels."""
    image = checker_texture(16, 16, dark=0.0, light=1.0)
    store = TextureStore.from_images([image])
    uv = np.array([[0.51 / 16, 0.51 / 16]] * 3)
    duv = np.array([[0.5 / 16, 0], [2.0 / 16, 0], [8.0 / 16, 0]])
    for filter in ("mipmap", "trilinear", "ewa"):  # isotropic footprints, 8 texels wide: level 3
        out = sample(store, 0, uv, duv, duv[:, ::-1], filter=filter)[:, 0]
        assert abs(out[2] - 0.5) < 1e-6, filter
    out = sample(store, 0, uv, duv, np.zeros_like(duv), filter="trilinear")[:, 0]
    assert abs(out[0] - np.flipud(image)[0, 0, 0]) < 0.05 and abs(out[1] - 0.5) < 1e-6  # texel (0, 0); level 1


def test_ewa_is_anisotropic_where_trilinear_is_not():
    """Stripes along v, footprint long along v and one texel across u: EWA keeps the stripes (it
    averages along them), trilinear's isotropic level blurs them to grey."""
    image = np.tile(np.array([0.0, 0.0, 1.0, 1.0] * 8, np.float32)[None, :, None], (32, 1, 3))
    store = TextureStore.from_images([image])
    uv = np.array([[5.0 / 32, 0.5], [7.0 / 32, 0.5]])  # the middles of a dark and a light stripe
    dx = np.array([[0.5 / 32, 0.0]] * 2)
    dy = np.array([[0.0, 8.0 / 32]] * 2)
    ewa = sample(store, 0, uv, dx, dy, filter="ewa")[:, 0]
    tri = sample(store, 0, uv, dx, dy, filter="trilinear")[:, 0]
    assert ewa[1] - ewa[0] > 0.5
    assert abs(tri[1] - tri[0]) < 1e-6


@pytest.mark.parametrize("level", [0, 1])
def test_ewa_at_a_texel_per_pixel_is_pbrts_gaussian_over_five_texels(level):
    """A footprint of 2^level texels along u and v, at texel centres of level `level`: pbrt's EWA
    (and ours) adds a one-texel reconstruction filter to the footprint's quadratic form, so the
    ellipse is the disc r^2 = (ds^2 + dt^2) / 2 < 1 at that level: the texel (weight 1 - e^-2) and
    its 4 edge neighbours (r^2 = 1/2: e^-1 - e^-2); the diagonal ones lie on r^2 = 1, outside. So
    EWA blurs at 1:1 where nearest / bilinear / trilinear return the texel (docs/scene-format.md)."""
    image = np.random.default_rng(4).random((32, 32, 3)).astype(np.float32)
    store = TextureStore.from_images([image])
    texels = store.pyramids[0][level]  # texture orientation: row 0 is v = 0
    n = texels.shape[0]
    r, c = np.meshgrid(np.arange(2, n - 2), np.arange(2, n - 2), indexing="ij")
    uv = np.stack([(c.ravel() + 0.5) / n, (r.ravel() + 0.5) / n], -1)
    step = 2.0 ** level / 32
    got = sample(store, 0, uv, np.tile([step, 0.0], (len(uv), 1)), np.tile([0.0, step], (len(uv), 1)), filter="ewa")
    centre, edge = 1 - math.exp(-2), math.exp(-1) - math.exp(-2)
    r, c = r.ravel(), c.ravel()
    around = texels[r - 1, c] + texels[r + 1, c] + texels[r, c - 1] + texels[r, c + 1]
    want = (centre * texels[r, c] + edge * around) / (centre + 4 * edge)
    np.testing.assert_allclose(got, want, atol=2e-6)
    tri = sample(store, 0, uv, np.tile([step, 0.0], (len(uv), 1)), np.tile([0.0, step], (len(uv), 1)), filter="trilinear")
    np.testing.assert_allclose(tri, texels[r, c], atol=1e-6)


# ---- 3. interpolation against the analytic ray-plane intersection ------------------------------


def tilted_plane_scene(texture, filter="nearest", interpolation="perspective", size=64):
    return {"camera": {"eye": [0.3, 1.2, 2.0], "target": [0, 0, -2], "fov_y": 50, "width": size, "height": size,
                       "near": 0.1, "far": 40},
            "ambient": [1, 1, 1],
            "materials": {"m": {"ka": 1, "kd": 0, "texture": str(texture), "texture_target": "ka",
                                "filter": filter, "wrap": "repeat"}},
            "objects": [{"type": "plane", "point": [0, 0, 0], "normal": [0.15, 1.0, 0.35], "material": "m"}],
            "render": {"interpolation": interpolation, "shadows": False}}


def analytic_plane_uv(scene, xs, ys):
    """uv (`Plane.uv`) where the rays through raster points (xs, ys) meet the plane, in float64."""
    scene = as_scene(scene)
    cam, plane = scene.camera, scene.objects[0]
    inv = np.linalg.inv(projection_matrix(cam) @ view_matrix(cam))
    ndc = np.stack([2 * xs / cam.width - 1, 1 - 2 * ys / cam.height], -1)

    def unproject(z):
        p = np.concatenate([ndc, np.full(ndc.shape[:-1] + (1,), z), np.ones(ndc.shape[:-1] + (1,))], -1) @ inv.T
        return p[..., :3] / p[..., 3:]

    near, far = unproject(-1.0), unproject(1.0)
    d = far - near
    normal, point = np.asarray(plane.normal), np.asarray(plane.point)
    t = ((point - near) @ normal) / (d @ normal)
    p = near + t[..., None] * d
    return plane.uv(p.reshape(-1, 3)).reshape(p.shape[:-1] + (2,)), p


@pytest.fixture(scope="module")
def checker_file(tmp_path_factory):
    return save_image(tmp_path_factory.mktemp("tex") / "checker.png", checker_texture(64, 8, 0.1, 0.8))


def test_perspective_correct_uv_matches_the_ray_plane_uv(checker_file):
    scene = tilted_plane_scene(checker_file)
    frame = render_frame(scene)
    g = frame.gbuffer
    j, i = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5)
    uv, _ = analytic_plane_uv(scene, j, i)
    mask = g.mask
    assert mask.mean() > 0.4
    scale = np.abs(uv[mask]).max()
    shift = np.round(g.uv[mask][0] - uv[mask][0])  # a repeating texture's plane: uv up to whole periods
    np.testing.assert_allclose(g.uv[mask], uv[mask] + shift, atol=2e-6 * max(scale, 1.0))
    # The image: the nearest texel of the analytic uv, away from the checker's cell edges.
    cell = uv * 8.0  # 8 cells per unit of uv
    away = mask & (np.abs(cell - np.round(cell)).min(axis=-1) > 0.02)
    # Image row 0 is v = 1: the image's cell (row, col) = (7 - floor(8 v), floor(8 u)) is light when
    # row + col is even, i.e. when floor(8 u) + floor(8 v) is odd.
    want = np.where((np.floor(cell[..., 0]) + np.floor(cell[..., 1])) % 2 == 1, 0.8, 0.1)
    # The file is sRGB 8-bit: decode the two stored values the way the loader does.
    texels = load_texture(checker_file)
    want = np.where(want > 0.5, texels.max(), texels.min())
    assert np.abs(frame.image[..., 0][away] - want[away]).max() <= 1 / 255


def test_affine_interpolation_differs(checker_file):
    g = render_frame(tilted_plane_scene(checker_file, interpolation="affine")).gbuffer
    j, i = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5)
    uv, _ = analytic_plane_uv(tilted_plane_scene(checker_file), j, i)
    assert np.abs(g.uv[g.mask] - uv[g.mask]).max() > 0.05


@pytest.mark.parametrize("interpolation", ["perspective", "affine"])
def test_uv_derivatives_are_those_of_the_interpolation(checker_file, interpolation):
    """duv_dx, duv_dy against central differences of the perspective map (analytic ray-plane uv at
    x +- h) and, for affine, of the G-buffer uv itself inside one triangle."""
    scene = tilted_plane_scene(checker_file, interpolation=interpolation)
    g = render_frame(scene).gbuffer
    j, i = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5)
    if interpolation == "perspective":
        h = 1e-3
        dx = (analytic_plane_uv(scene, j + h, i)[0] - analytic_plane_uv(scene, j - h, i)[0]) / (2 * h)
        dy = (analytic_plane_uv(scene, j, i + h)[0] - analytic_plane_uv(scene, j, i - h)[0]) / (2 * h)
        m = g.mask
        np.testing.assert_allclose(g.duv_dx[m], dx[m], rtol=1e-3, atol=1e-4 * np.abs(dx[m]).max())
        np.testing.assert_allclose(g.duv_dy[m], dy[m], rtol=1e-3, atol=1e-4 * np.abs(dy[m]).max())
    else:
        same = g.mask[:, :-1] & g.mask[:, 1:] & (g.face[:, :-1] == g.face[:, 1:])
        fd = g.uv[:, 1:] - g.uv[:, :-1]
        np.testing.assert_allclose(g.duv_dx[:, :-1][same], fd[same], atol=1e-3)


@wp.kernel
def footprint_kernel(cam: CameraW, xs: wp.array(dtype=wp.vec2), ps: wp.array(dtype=wp.vec3), normal: wp.vec3,
                     tangent: wp.vec3, bitangent: wp.vec3, out_dx: wp.array(dtype=wp.vec2),
                     out_dy: wp.array(dtype=wp.vec2)):
    k = wp.tid()
    dpdx, dpdy = pixel_footprint(cam, xs[k][0], xs[k][1], 1.0, ps[k], normal)
    du, dv = plane_uv_derivatives(dpdx, dpdy, tangent, bitangent)
    out_dx[k] = du
    out_dy[k] = dv


def test_the_ray_tracers_footprint_rule_agrees_with_the_rasterizer(checker_file):
    """`pixel_footprint` + `plane_uv_derivatives` (what a ray hit uses) give the G-buffer's derivatives
    to the second-order error of a one-sample central difference."""
    scene = tilted_plane_scene(checker_file)
    g = render_frame(scene).gbuffer
    sc = as_scene(scene)
    j, i = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5)
    _, p = analytic_plane_uv(scene, j, i)
    m = g.mask
    normal = np.asarray(sc.objects[0].normal)
    xs = wp.array(np.stack([j[m], i[m]], -1).astype(np.float32), dtype=wp.vec2)
    ps = wp.array(p[m].astype(np.float32), dtype=wp.vec3)
    out_dx = wp.zeros(int(m.sum()), dtype=wp.vec2)
    out_dy = wp.zeros(int(m.sum()), dtype=wp.vec2)
    tangent, bitangent = (wp.vec3(*axis) for axis in sc.objects[0].uv_frame())
    wp.launch(footprint_kernel, dim=int(m.sum()), inputs=[camera_struct(sc.camera, 64, 64), xs, ps,
                                                           wp.vec3(*normal), tangent, bitangent, out_dx, out_dy])
    np.testing.assert_allclose(out_dx.numpy(), g.duv_dx[m], rtol=0.02, atol=0.01 * np.abs(g.duv_dx[m]).max())
    np.testing.assert_allclose(out_dy.numpy(), g.duv_dy[m], rtol=0.02, atol=0.01 * np.abs(g.duv_dy[m]).max())


# ---- 4. filtering quality ---------------------------------------------------------------------


def test_filter_errors_fall_in_the_order_theory_predicts(tmp_path):
    texture = save_image(tmp_path / "checker.png", checker_texture())
    _, table = compare_filters(texture, 96, 72, n_reference=12, repeats=1)
    rmse = {row["filter"]: row["rmse"] for row in table}
    assert rmse["ewa"] < 0.8 * rmse["trilinear"]
    assert rmse["trilinear"] < rmse["mipmap"]
    assert rmse["mipmap"] < 0.6 * min(rmse["bilinear"], rmse["nearest"])
    assert abs(rmse["bilinear"] - rmse["nearest"]) < 0.15 * rmse["nearest"]


# ---- 5. shading with a texture ----------------------------------------------------------------


QUAD = {"type": "mesh", "builtin": "quad", "material": "m",
        "transform": {"rotate_deg": [90, 0, 0], "scale": 1.5}}
QUADRANTS = np.array([[[0.9, 0.2, 0.1], [0.1, 0.7, 0.3]],
                      [[0.3, 0.3, 0.8], [0.6, 0.5, 0.05]]], np.float32)  # image orientation: row 0 = top


@pytest.mark.parametrize("shading", ["phong", "flat", "gouraud"])
@pytest.mark.parametrize("target", ["ka", "kd", "ks"])
def test_a_texture_modulates_its_coefficient_in_the_illumination_model(tmp_path, target, shading):
    """A facing quad, orthographic, a directional light at 30 degrees: each quadrant of the 2x2 texture
    (nearest, clamp) shades as the textbook formula with the target coefficient times that texel."""
    path = tmp_path / "quadrants.npy"
    np.save(path, QUADRANTS)
    coeffs = {"ka": 0.2, "kd": 0.5, "ks": 0.4}
    material = {k: [v] * 3 for k, v in coeffs.items()}
    material.update(n=6.0, texture=str(path), texture_target=target, filter="nearest", wrap="clamp")
    t = math.radians(30.0)
    light = {"type": "directional", "direction": [-math.sin(t), 0.0, -math.cos(t)], "intensity": [0.9] * 3}
    scene = scene_dict([QUAD], {"m": material}, lights=[light], ambient=(0.5, 0.5, 0.5))
    frame = render_frame(scene, shading=shading)
    n_dot_l = math.cos(t)
    lobe = (2 * n_dot_l * np.array([0, 0, 1.0]) - np.array([math.sin(t), 0, math.cos(t)]))[2] ** 6.0
    image = frame.image
    # The quad spans x, y in [-0.75, 0.75] of the [-1, 1] view: pixel centres per quadrant.
    centres = (np.arange(32) + 0.5) / 32 * 2 - 1
    x, y = np.meshgrid(centres, -centres)
    for r, c in np.ndindex(2, 2):
        inside = ((x - (-0.375 + 0.75 * c)) ** 2 < 0.3 ** 2) & ((y - (0.375 - 0.75 * r)) ** 2 < 0.3 ** 2)
        k = {name: np.full(3, v) for name, v in coeffs.items()}
        k[target] = coeffs[target] * QUADRANTS[r, c]
        want = k["ka"] * 0.5 + 0.9 * (k["kd"] * n_dot_l + k["ks"] * lobe)
        np.testing.assert_allclose(image[inside], np.broadcast_to(want, image[inside].shape), atol=1e-5)
        np.testing.assert_allclose(frame.gbuffer.texture[inside], np.broadcast_to(QUADRANTS[r, c], (inside.sum(), 3)))


# ---- 6. faults ---------------------------------------------------------------------------------


def test_a_missing_texture_raises_texture_error_naming_the_path(tmp_path):
    missing = tmp_path / "nowhere" / "brick.png"
    with pytest.raises(TextureError, match="brick.png"):
        load_texture(missing)
    with pytest.raises(TextureError, match="brick.png"):
        TextureStore.from_paths([missing])


def test_a_texture_file_is_checked_as_any_image_file(tmp_path):
    """One place checks a file to read (`io.image_file`): a texture's messages are an image's, naming
    it a texture. `load_texture` had its own checks before: a broken PNG was "cannot read texture
    (broken.png: cannot read image (...))" (the path twice), a folder "a folder, not a texture file"
    where `load_image` said "not a regular file"."""
    (tmp_path / "folder.png").mkdir()
    (tmp_path / "broken.png").write_bytes(b"not a png")
    for name in ("missing.png", "folder.png", "broken.png"):
        with pytest.raises(DifflabError) as image:
            load_image(tmp_path / name)
        with pytest.raises(TextureError) as texture:
            load_texture(tmp_path / name)
        assert str(texture.value) == str(image.value).replace(": image file", ": texture file").replace(
            "not an image file", "not a texture file"), name


def test_a_texture_deleted_after_loading_the_scene_raises_at_render(tmp_path):
    path = save_image(tmp_path / "gone.png", np.ones((2, 2, 3)))
    scene = as_scene(scene_dict([QUAD], {"m": {"texture": str(path)}}))
    path.unlink()
    with pytest.raises(TextureError, match="gone.png"):
        render(scene)


@pytest.mark.parametrize("bad, message", [
    ({(0, 0, 0): -1.0, (1, 1, 2): -0.25}, r"neg\.npy: texture has 2 negative texel values \(least -1\); .* >= 0"),
    ({(0, 0, 0): np.nan, (1, 0, 1): np.inf, (1, 1, 1): -np.inf}, r"neg\.npy: texture has 3 non-finite texel values"),
])
def test_a_negative_or_non_finite_texel_raises_texture_error_naming_the_file(tmp_path, bad, message):
    """A texel scales a coefficient, which must be >= 0: the old code rendered a -1 texture to a
    minimum of -96.3 (negative light) while a scene's negative kd was refused."""
    texels = np.full((2, 2, 3), 0.5, np.float32)
    for index, value in bad.items():
        texels[index] = value
    np.save(tmp_path / "neg.npy", texels)
    with pytest.raises(TextureError, match=message):
        load_texture(tmp_path / "neg.npy")
    with pytest.raises(TextureError, match=message):
        render(scene_dict([QUAD], {"m": {"texture": str(tmp_path / "neg.npy")}}))


def test_an_overflow_report_names_a_huge_texture_first(tmp_path):
    """1e30 texels times kd 1e9 overflow float32: the report named only kd (1e9) before."""
    np.save(tmp_path / "big.npy", np.full((2, 2, 3), 1e30, np.float32))
    light = {"type": "directional", "direction": [0, 0, -1], "intensity": [1, 1, 1]}
    with pytest.raises(RenderError, match=r"the largest numbers in the scene: materials\.m\.texture \(\S*big\.npy\) "
                                          r"largest texel = 1e\+30, materials\.m\.kd\[0\] = 1e\+09"):
        render(scene_dict([QUAD], {"m": {"kd": 1e9, "texture": str(tmp_path / "big.npy")}}, lights=[light]))


def test_an_unreadable_texture_raises_texture_error(tmp_path):
    path = tmp_path / "broken.png"
    path.write_bytes(b"not a png")
    with pytest.raises(TextureError, match="broken.png"):
        load_texture(path)


# ---- 7. uv projections and the model's texture helpers ------------------------------------------


def test_spherical_projection_reproduces_the_uv_sphere():
    from difflab.geometry import project_uvs, uv_sphere

    mesh = uv_sphere(2.0, (1, 2, 3), 8, 16)
    uv = project_uvs(mesh, "spherical", center=(1, 2, 3)).uvs
    ring = slice(16, 16 + 7 * 17)  # poles and the duplicated seam are the mesh's own choices
    du = np.abs(uv[ring, 0] - mesh.uvs[ring, 0])
    assert np.all(np.minimum(du, 1 - du) < 1e-12)
    np.testing.assert_allclose(uv[ring, 1], mesh.uvs[ring, 1], atol=1e-12)


def test_planar_and_cylindrical_projections():
    from difflab.geometry import cylindrical_uv, planar_uv

    p = np.array([[0.5, 0.0, 0.0], [0.0, 0.0, -0.5], [0.0, 0.3, 0.0]])
    np.testing.assert_allclose(planar_uv(p), [[1.0, 0.5], [0.5, 1.0], [0.5, 0.5]])  # t = +x, b = -z
    np.testing.assert_allclose(cylindrical_uv(p[:2], scale=2.0), [[0.0, 0.5], [0.25, 0.5]])


@wp.kernel
def textured_material_kernel(base: wp.array(dtype=MaterialW), value: wp.vec3, out: wp.array2d(dtype=wp.vec3)):
    """Row t: ka, kd, ks of textured_material(base, t, value), then of target_only(base, t)."""
    t = wp.tid()
    textured = textured_material(base[0], t, value)
    unit = target_only(base[0], t)
    out[t, 0] = textured.ka
    out[t, 1] = textured.kd
    out[t, 2] = textured.ks
    out[t, 3] = unit.ka
    out[t, 4] = unit.kd
    out[t, 5] = unit.ks


def test_textured_material_is_the_same_in_warp_and_jax():
    """Both halves of the model modulate exactly the target coefficient (k * texel) and, for the
    texel's factor, keep only it: Warp and JAX equal to the float32 product."""
    import jax.numpy as jnp

    from difflab.lighting import jax_model as jm
    from difflab.vocabulary import TEXTURE_TARGET_IDS

    k = {"ka": np.array([0.1, 0.2, 0.3]), "kd": np.array([0.4, 0.5, 0.6]), "ks": np.array([0.7, 0.8, 0.9])}
    value = np.array([0.25, 0.5, 0.75])
    base_w = MaterialW()
    base_w.ka, base_w.kd, base_w.ks = (wp.vec3(*k[name]) for name in ("ka", "kd", "ks"))
    out = wp.zeros((3, 6), dtype=wp.vec3)
    wp.launch(textured_material_kernel, dim=3, inputs=[wp.array([base_w], dtype=MaterialW), wp.vec3(*value), out])
    warp_rows = out.numpy()
    base_j = jm.MaterialJ(ka=jnp.array(k["ka"]), kd=jnp.array(k["kd"]), ks=jnp.array(k["ks"]), n=jnp.array(3.0),
                          m=jnp.array(0.3), f0=jnp.array(0.04))
    for name, target in TEXTURE_TARGET_IDS.items():
        textured = jm.textured_material(base_j, target, jnp.array(value))
        unit = jm.target_only(base_j, target)
        for col, coef in enumerate(("ka", "kd", "ks")):
            want = k[coef] * value if coef == name else k[coef]
            np.testing.assert_allclose(warp_rows[target, col], want, rtol=1e-7)
            np.testing.assert_allclose(np.asarray(getattr(textured, coef)), want, rtol=1e-7)
            want_unit = k[coef] if coef == name else 0.0
            np.testing.assert_allclose(warp_rows[target, 3 + col], want_unit, rtol=1e-7)
            np.testing.assert_allclose(np.asarray(getattr(unit, coef)), want_unit, rtol=1e-7)
