"""The rasterizer against closed forms: analytic shading, coverage, clipping, interpolation, shadows."""

import math

import numpy as np
import pytest

from conftest import scene_dict
from difflab import RenderError, SceneError, render, render_frame
from difflab.geometry import rotation_matrix

SHADINGS = ["flat", "gouraud", "phong"]


def facing_quad(material="m", size=1.5, z=0.0):
    return {"type": "mesh", "builtin": "quad", "material": material,
            "transform": {"rotate_deg": [90, 0, 0], "scale": size, "translate": [0, 0, z]}}


def directional(theta_deg, intensity=0.9):
    t = math.radians(theta_deg)
    return {"type": "directional", "direction": [-math.sin(t), 0.0, -math.cos(t)], "intensity": [intensity] * 3}


def textbook(ka, kd, ks, n, ia, il, theta_deg, specular="phong"):
    """ka Ia + kd Il cos(theta) + ks Il S for a quad facing +z, viewer along +z (orthographic)."""
    t = math.radians(theta_deg)
    normal, l, v = np.array([0, 0, 1.0]), np.array([math.sin(t), 0, math.cos(t)]), np.array([0, 0, 1.0])
    if normal @ l <= 0:
        return ka * ia
    if specular == "phong":
        lobe = max((2 * normal * (normal @ l) - l) @ v, 0.0) ** n
    else:
        h = (l + v) / np.linalg.norm(l + v)
        lobe = max(normal @ h, 0.0) ** n
    return ka * ia + il * (kd * (normal @ l) + ks * lobe)


@pytest.mark.parametrize("shading", SHADINGS)
@pytest.mark.parametrize("specular", ["phong", "blinn"])
@pytest.mark.parametrize("theta, ka, kd, ks", [(30, 0.1, 0.6, 0.4), (0, 0.1, 0.6, 0.4), (50, 0.1, 0.6, 0.0),
                                               (40, 0.3, 0.0, 0.0), (120, 0.2, 0.6, 0.4)])
def test_facing_quad_matches_the_textbook_value(shading, specular, theta, ka, kd, ks):
    n = 8.0
    material = {"ka": [ka] * 3, "kd": [kd] * 3, "ks": [ks] * 3, "n": n}
    scene = scene_dict([facing_quad()], {"m": material}, lights=[directional(theta)], ambient=(0.5, 0.5, 0.5))
    frame = render_frame(scene, shading=shading, specular=specular)
    mask = frame.gbuffer.mask
    assert mask.sum() > 0.5 * mask.size
    want = textbook(ka, kd, ks, n, 0.5, 0.9, theta, specular)
    np.testing.assert_allclose(frame.image[mask], want, atol=1e-5)
    assert np.all(frame.image[~mask] == 0.0)


def test_lambert_sphere_lit_head_on_has_cosine_falloff():
    """Orthographic view and light along -z: a unit sphere shows kd cos(theta) = kd sqrt(1 - x^2 - y^2)."""
    scene = scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}],
                       {"m": {"kd": [0.8, 0.8, 0.8]}}, lights=[directional(0, intensity=1.0)],
                       camera={"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic",
                               "ortho_height": 2.5, "width": 64, "height": 64})
    frame = render_frame(scene, shading="phong")
    centres = (np.arange(64) + 0.5) / 64 * 2.5 - 1.25
    x, y = np.meshgrid(centres, -centres)
    r2 = x ** 2 + y ** 2
    inner = r2 < 0.9 ** 2
    want = 0.8 * np.sqrt(1 - r2[inner])
    # The sphere is tessellated to half-pixel silhouette accuracy with analytic vertex normals.
    np.testing.assert_allclose(frame.image[inner][:, 0], want, atol=2e-3)
    assert frame.gbuffer.mask[r2 > 1.05 ** 2].sum() == 0


def two_triangle_scene(faces, vertices, width=16):
    return vertices, faces


def coverage(tmp_path, vertices, faces, size=16):
    """Render a mesh of the given triangles, one at a time and together: per-triangle coverage masks."""
    masks = []
    for k in range(len(faces)):
        path = tmp_path / f"tri{k}.obj"
        lines = [f"v {x} {y} {z}" for x, y, z in vertices] + ["f " + " ".join(str(i + 1) for i in faces[k])]
        path.write_text("\n".join(lines) + "\n")
        scene = scene_dict([{"type": "mesh", "file": str(path), "material": "m", "smooth": False}],
                           {"m": {"ka": [1, 1, 1], "kd": [0, 0, 0]}}, ambient=(1, 1, 1),
                           camera={"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic",
                                   "ortho_height": 2.0, "width": size, "height": size})
        masks.append(render_frame(scene).gbuffer.mask)
    return np.array(masks)


def test_triangles_sharing_edges_cover_each_pixel_exactly_once(tmp_path):
    """A fan of 8 triangles around a vertex at a pixel centre, with edges through pixel centres."""
    c = 1.0 / 16  # half a pixel: (c, c) is the centre of pixel (7, 8)
    ring = [(c + 0.9 * math.cos(a), c + 0.9 * math.sin(a), 0.0) for a in np.arange(8) * math.pi / 4]
    vertices = [(c, c, 0.0)] + ring
    faces = [(0, 1 + k, 1 + (k + 1) % 8) for k in range(8)]
    masks = coverage(tmp_path, vertices, faces)
    counts = masks.sum(axis=0)
    assert counts.max() == 1
    # the union is the octagon: every sample centre strictly inside it is covered once
    centres = (np.arange(16) + 0.5) / 16 * 2 - 1
    x, y = np.meshgrid(centres, -centres)
    inside = np.hypot(x - c, y - c) < 0.9 * math.cos(math.pi / 8) - 1e-3
    assert np.all(counts[inside] == 1)


def test_back_faces_are_culled_only_on_request():
    quad = facing_quad()
    quad["transform"]["rotate_deg"] = [-90, 0, 0]  # now faces -z, away from the camera
    scene = scene_dict([quad], {"m": {"ka": [1, 1, 1]}}, ambient=(1, 1, 1))
    assert render_frame(scene).gbuffer.mask.sum() > 0
    assert render_frame(scene, cull_backfaces=True).gbuffer.mask.sum() == 0


def floor_scene(width=48, height=32, **render):
    return scene_dict([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
                      {"floor": {"kd": [0.8, 0.8, 0.8], "checker": {"size": 1.0}}},
                      camera={"eye": [0.3, 1.0, 2.0], "target": [0, 0.2, -3], "fov_y": 60, "width": width,
                              "height": height, "near": 0.1, "far": 50},
                      lights=[directional(30)], render=render)


def ray_plane_hits(scene_camera, width, height):
    """World points where each pixel-centre ray meets y = 0 (NaN where it does not)."""
    from difflab.renderers.camera import camera_frame

    class Cam:  # the scene's camera as a plain object
        pass

    right, up, forward = camera_frame(scene_camera)
    tan = math.tan(math.radians(scene_camera.fov_y) / 2)
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    ndc_x, ndc_y = 2 * j / width - 1, 1 - 2 * i / height
    d = forward + ndc_x[..., None] * tan * width / height * right + ndc_y[..., None] * tan * up
    eye = np.asarray(scene_camera.eye)
    t = -eye[1] / d[..., 1]
    return np.where((t > 0)[..., None], eye + t[..., None] * d, np.nan)


@pytest.mark.parametrize("interpolation", ["perspective", "affine"])
def test_receding_plane_positions_are_perspective_correct(interpolation):
    """The floor crosses the near plane (clipped, not dropped): its G-buffer positions and uvs equal
    the ray-plane intersections with perspective-correct interpolation, and differ with affine."""
    frame = render_frame(floor_scene(interpolation=interpolation))
    from difflab import Scene

    scene = Scene.from_dict(floor_scene())
    camera = scene.camera
    hits = ray_plane_hits(camera, 48, 32)
    below = ~np.isnan(hits[..., 0]) & (np.linalg.norm(hits - np.array(camera.eye), axis=-1) < 40)
    g = frame.gbuffer
    assert np.all(g.mask[below])
    err = np.linalg.norm(g.position[below] - hits[below], axis=-1) / np.linalg.norm(hits[below] - camera.eye, axis=-1)
    uv_err = np.abs(g.uv[below] - scene.objects[0].uv(hits[below])).max()  # (x, -z) on this floor
    if interpolation == "perspective":
        assert err.max() < 1e-4
        assert uv_err < 1e-3
    else:
        assert err.max() > 1e-2


def test_a_triangle_crossing_the_near_plane_is_clipped_not_dropped():
    scene = floor_scene()
    frame = render_frame(scene)
    # the bottom rows look at floor points nearer than `near` would allow unclipped: still covered
    assert frame.gbuffer.mask[-1].all()
    assert np.all(frame.gbuffer.depth[frame.gbuffer.mask] >= 0.1 - 1e-6)


def test_shadow_of_a_sphere_is_the_analytic_disk():
    """Light straight down: the shadow on y = 0 is the disk x^2 + z^2 < r^2 (except one pixel at the edge)."""
    scene = scene_dict(
        [{"type": "sphere", "center": [0, 1.5, 0], "radius": 0.6, "material": "m"},
         {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "m"}],
        {"m": {"kd": [1, 1, 1]}}, lights=[{"type": "directional", "direction": [0, -1, 0]}],
        camera={"eye": [0, 2.5, 5], "target": [0, 0, 0], "fov_y": 40, "width": 64, "height": 64})
    g = render_frame(scene, shading="phong").gbuffer
    on_floor = g.object == 1
    radius = np.hypot(g.position[..., 0], g.position[..., 2])
    vis = g.visibility[..., 0]
    pixel = 2 * 6.0 * math.tan(math.radians(20)) / 64  # a pixel's footprint at the disk, generously
    inside, outside = on_floor & (radius < 0.6 - pixel), on_floor & (radius > 0.6 + pixel)
    assert inside.sum() > 20 and outside.sum() > 1000
    assert np.all(vis[inside] == 0.0)
    assert np.all(vis[outside] == 1.0)
    render_no = render_frame(scene, shading="phong", shadows=False).gbuffer
    assert np.all(render_no.visibility == 1.0)


def test_rigid_motion_of_camera_and_scene_leaves_the_image_unchanged():
    def scene(rotation):
        m = np.eye(4)
        m[:3, :3] = rotation
        mesh = {"type": "mesh", "builtin": "teapot", "resolution": 3, "material": "m",
                "transform": {"scale": 0.4, "matrix": m.ravel().tolist()}}
        eye, light = rotation @ np.array([0.5, 1.5, 4.0]), rotation @ np.array([3.0, 4.0, 2.0])
        up = rotation @ np.array([0, 1.0, 0])
        return scene_dict([mesh], {"m": {"ka": [0.1] * 3, "kd": [0.6] * 3, "ks": [0.4] * 3, "n": 20}},
                          camera={"eye": eye.tolist(), "target": (rotation @ np.array([0, 0.5, 0])).tolist(),
                                  "up": up.tolist(), "fov_y": 40, "width": 48, "height": 48},
                          lights=[{"type": "point", "position": light.tolist()}], ambient=(0.3, 0.3, 0.3))

    base = render(scene(np.eye(3)))
    moved = render(scene(rotation_matrix((1, 2, 3), 37.0)[:3, :3]))
    differ = np.abs(base - moved).max(axis=-1) > 1e-3
    assert differ.mean() < 0.01  # only a few edge samples may flip
    np.testing.assert_allclose(base[~differ], moved[~differ], atol=1e-3)


def test_renders_are_deterministic_and_independent_of_threads():
    scene = floor_scene()
    a = render(scene, threads=1)
    b = render(scene, threads=2)
    c = render(scene, threads=2)
    assert np.array_equal(a, b) and np.array_equal(b, c)


@pytest.mark.parametrize("mode", ["linear", "exp", "exp2"])
def test_fog_blends_by_eye_depth(mode):
    fog = {"mode": mode, "color": [0.2, 0.4, 0.6], "start": 1.0, "end": 9.0, "density": 0.15}
    scene = scene_dict([facing_quad(z=-2.0)], {"m": {"ka": [1, 1, 1], "kd": [0, 0, 0]}}, ambient=(1, 1, 1), fog=fog)
    frame = render_frame(scene)
    z = 7.0  # eye at z = 5, quad at z = -2
    f = {"linear": (9 - z) / 8, "exp": math.exp(-0.15 * z), "exp2": math.exp(-(0.15 * z) ** 2)}[mode]
    want = f * 1.0 + (1 - f) * np.array([0.2, 0.4, 0.6])
    np.testing.assert_allclose(frame.image[frame.gbuffer.mask], np.broadcast_to(want, (frame.gbuffer.mask.sum(), 3)),
                               atol=1e-5)


def test_supersampling_averages_a_regular_grid():
    """A half-plane edge through a pixel column: with spp = 16 the edge pixels hold fractional coverage."""
    quad = {"type": "mesh", "builtin": "quad", "material": "m",
            "transform": {"rotate_deg": [90, 0, 0], "scale": 4.0, "translate": [2.0 + 0.3 / 16, 0, 0]}}
    scene = scene_dict([quad], {"m": {"ka": [1, 1, 1], "kd": [0, 0, 0]}}, ambient=(1, 1, 1),
                       camera={"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic",
                               "ortho_height": 2.0, "width": 16, "height": 16})
    image = render(scene, spp=16)[..., 0]
    # the quad covers x > 0.3/16 world units = 0.15 pixel right of the centre line (column 8 starts at x = 0)
    np.testing.assert_allclose(image[:, 8], 1.0 - 0.15 * 16 / 16 * 1, atol=0.126)  # 4x4 grid: steps of 1/4
    assert np.all(image[:, 9:] == 1.0) and np.all(image[:, :8] == 0.0)


def test_gouraud_clamps_vertex_colours_only_on_request():
    material = {"ka": [0, 0, 0], "kd": [3.0, 3.0, 3.0]}
    scene = scene_dict([facing_quad()], {"m": material}, lights=[directional(0, 1.0)])
    plain = render_frame(scene, shading="gouraud").image
    clamped = render_frame(scene, shading="gouraud", clamp_vertex_colors=True).image
    assert plain.max() == pytest.approx(3.0) and clamped.max() == pytest.approx(1.0)


def test_bad_requests_raise_clear_errors():
    scene = scene_dict([facing_quad()], {"m": {}})
    with pytest.raises(SceneError, match=r"render.spp: must be a perfect square .* got 3"):
        render(scene, spp=3)
    with pytest.raises(RenderError, match="device"):
        render(scene, device="cuda:7")
    with pytest.raises(SceneError, match="camera.width"):
        render(scene, width=0)
    with pytest.raises(RenderError, match="unknown option"):
        render(scene, shinyness=3)
    with pytest.raises(SceneError, match="render.shading"):
        render(scene, shading="toon")


@pytest.mark.parametrize("shading", ["flat", "gouraud", "phong"])
def test_render_forms_the_image_render_frame_composes_from_its_gbuffer(tmp_path, shading):
    """`render` fuses resolve, lighting and compose per sample and stores no G-buffer; its image is
    the one `render_frame` composes from the G-buffer (textures, checker, fog, shadows, spp 4,
    clamped vertex colours, a plane clipped by the near plane), to float32 rounding."""
    from difflab.io import save_image

    texels = np.zeros((8, 8, 3), np.float32)
    texels[::2, ::2] = texels[1::2, 1::2] = 1.0
    save_image(tmp_path / "checker.png", texels)
    scene = scene_dict(
        [{"type": "sphere", "center": [0, 0.6, 0], "radius": 0.6, "material": "textured"},
         {"type": "mesh", "builtin": "teapot", "resolution": 3, "material": "shiny",
          "transform": {"translate": [1.1, 0.3, 0.2], "scale": 0.3}},
         {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
        {"textured": {"kd": [1, 1, 1], "ks": [0.3, 0.3, 0.3], "n": 20, "texture": str(tmp_path / "checker.png"),
                      "filter": "trilinear"},
         "shiny": {"ka": [0.1, 0, 0], "kd": [0.6, 0.2, 0.1], "ks": [0.8, 0.8, 0.8], "n": 60},
         "floor": {"kd": [0.7, 0.7, 0.7], "checker": {"size": 0.5, "kd2": [0.1, 0.1, 0.2]}}},
        camera={"eye": [0.3, 1.2, 3.5], "target": [0.2, 0.4, 0], "fov_y": 45, "width": 24, "height": 20},
        lights=[{"type": "point", "position": [2, 4, 3]}, {"type": "directional", "direction": [1, -1, -1]}],
        ambient=(0.1, 0.1, 0.1), fog={"mode": "linear", "color": [0.5, 0.5, 0.6], "start": 2, "end": 9},
        render={"shading": shading, "shadows": True, "spp": 4, "clamp_vertex_colors": shading == "gouraud"})
    frame = render_frame(scene)
    np.testing.assert_allclose(render(scene), frame.image, rtol=0, atol=1e-6)
    assert frame.gbuffer.mask.any() and not frame.gbuffer.mask.all()


@pytest.mark.parametrize("shading", ["flat", "gouraud"])
def test_the_image_path_lights_only_the_points_visible_samples_read(shading):
    """`render` lights only the shading points visible samples read (Gouraud: the vertex copies on
    the side each face shows); the image is bitwise the one `render_frame` composes from every lit point. The
    near plane cuts the sphere open: front faces, back faces seen inside, and faces clipped to quads."""
    scene = scene_dict([{"type": "mesh", "builtin": "sphere", "resolution": 16, "material": "m"}],
                       {"m": {"ka": [0.2, 0.1, 0.1], "kd": [0.6, 0.5, 0.3], "ks": [0.5] * 3, "n": 20}},
                       lights=[{"type": "point", "position": [0.5, 0.3, 0.2]}], ambient=(0.2, 0.2, 0.2),
                       camera={"eye": [0, 0, 1.3], "target": [0, 0, 0], "near": 0.35, "fov_y": 100, "width": 40,
                               "height": 30})
    frame = render_frame(scene, shading=shading)
    gouraud = render_frame(scene, shading="gouraud").gbuffer
    copies = gouraud.point_index[gouraud.mask] >= len(gouraud.points.position) // 2  # back copies after the V fronts
    assert copies.any() and not copies.all()  # both sides of the surface are seen
    assert np.array_equal(render(scene, shading=shading), frame.image)


@pytest.mark.parametrize("threads", [1, 3])
def test_a_scene_without_objects_renders_its_background(threads):
    """No triangles: the image pass still runs on every band (and the G-buffer is empty)."""
    scene = scene_dict([], {}, background=[0.2, 0.3, 0.4])
    image = render(scene, threads=threads)
    assert image.shape == (32, 32, 3) and np.array_equal(image, np.broadcast_to(np.float32([0.2, 0.3, 0.4]), image.shape))
    frame = render_frame(scene, threads=threads)
    assert np.array_equal(frame.image, image) and not frame.gbuffer.mask.any()
    assert np.array_equal(render(scene, method="raytrace", threads=threads), image)


def test_a_surface_on_the_far_plane_is_drawn_behind_nearer_ones():
    """z_ndc = 1 (the far plane, included) keys the deepest depth, 2^31 - 1: it once rounded up to
    2^31 in float32, overflowed the 64-bit key and hid everything nearer."""
    def quad(z, half, material):
        return {"type": "mesh", "vertices": [[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]],
                "faces": [[0, 1, 2], [0, 2, 3]], "material": material}

    scene = scene_dict([quad(0.0, 0.5, "near"), quad(-15.0, 3.0, "far")],  # the camera's far plane: z = 5 - 20
                       {"near": {"ka": [1, 0, 0], "kd": 0}, "far": {"ka": [0, 0, 1], "kd": 0}}, ambient=(1, 1, 1))
    image = render(scene)
    assert image[16, 16].tolist() == [1, 0, 0] and image[0, 0].tolist() == [0, 0, 1]


def test_no_cracks_where_a_shared_edge_snaps_onto_sample_centres():
    """A closed icosphere (subdivisions 4, 256^2) has no pixel where the far side shows through: a
    triangle's candidate rows come from its snapped corners, the ones its edge functions test (from
    the unsnapped corners, rows whose centres an edge snapped onto were skipped: 30 pixels here
    showed a back face, black). Every pixel's face is the ray tracer's or a neighbour of it (a tie on
    a shared edge), and the Phong images agree."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    scene = {"camera": {"eye": [0, 0, 3], "target": [0, 0, 0], "fov_y": 45, "width": 256, "height": 256},
             "ambient": [0.1, 0.1, 0.1], "lights": [{"type": "point", "position": [3, 4, 5]}],
             "materials": {"m": {"kd": [0.7, 0.3, 0.2], "ks": [0.5, 0.5, 0.5], "n": 30}},
             "objects": [{"type": "mesh", "vertices": mesh.vertices.tolist(), "faces": mesh.faces.tolist(),
                          "material": "m"}],
             "render": {"shading": "phong", "shadows": False, "max_depth": 1}}
    raster = render_frame(scene, method="raster")
    traced = render_frame(scene, method="raytrace", item_buffer=False)
    ours, theirs = raster.gbuffer.face, traced.ray_tree.face[traced.ray_tree.primary()]
    differ = np.argwhere(ours != theirs)
    assert all(set(mesh.faces[ours[i, j]]) & set(mesh.faces[theirs[i, j]]) for i, j in differ)
    assert np.abs(raster.image - traced.image).max() < 1e-4  # 7.8e-6 measured


def test_a_snapped_boxs_first_and_last_sample_centres_are_exact_at_every_step():
    """`clip.first_centre` / `last_centre` (integer shifts) give the first sample index whose centre
    k * SUBPIXEL + SAMPLE_CENTRE is >= lo and the last whose centre is <= hi, for fixed-point values
    on both sides of 0 and on, next to, and between centres."""
    from difflab._warp import wp
    from difflab.renderers.raster import clip

    @wp.kernel
    def centres_kernel(values: wp.array(dtype=wp.int64), first: wp.array(dtype=wp.int32),
                       last: wp.array(dtype=wp.int32)):
        k = wp.tid()
        first[k] = clip.first_centre(values[k])
        last[k] = clip.last_centre(values[k])

    values = np.arange(-5 * clip.SUBPIXEL - 3, 5 * clip.SUBPIXEL + 4, dtype=np.int64)
    first = wp.empty(values.size, dtype=wp.int32, device="cpu")
    last = wp.empty(values.size, dtype=wp.int32, device="cpu")
    wp.launch(centres_kernel, dim=values.size, inputs=[wp.array(values, dtype=wp.int64, device="cpu"), first, last],
              device="cpu")
    centre = lambda k: k * clip.SUBPIXEL + clip.SAMPLE_CENTRE  # noqa: E731
    want_first = [min(k for k in range(-8, 8) if centre(k) >= v) for v in values]
    want_last = [max(k for k in range(-8, 8) if centre(k) <= v) for v in values]
    assert first.numpy().tolist() == want_first and last.numpy().tolist() == want_last


@pytest.mark.parametrize("shading", SHADINGS)
def test_a_sphere_seen_from_inside_is_shadowed_by_its_own_wall(shading):
    """Eye inside a closed analytic sphere, the one light outside: every shadow ray from the inner
    wall meets the far wall (the ray tracer's `leaving_skip` skips a sphere only for rays leaving
    it outwards), so all three -- rasterizer, ray tracer, the same sphere as a mesh -- show ka Ia
    only. Without shadows the light does reach it (the test is not vacuous)."""
    sphere = {"type": "sphere", "center": [0, 0.7, 0], "radius": 0.7, "material": "m"}
    mesh = {"type": "mesh", "builtin": "sphere", "resolution": 16, "material": "m",
            "transform": {"translate": [0, 0.7, 0], "scale": 0.7}}
    camera = {"eye": [0, 0.7, 0.2], "target": [0, 0.7, -1], "fov_y": 45, "width": 32, "height": 24}
    materials = {"m": {"ka": [0.5] * 3, "kd": [0.8, 0.2, 0.2], "ks": [0.4] * 3, "n": 30}}

    def scene(obj, shadows):
        return scene_dict([obj], materials, camera=camera, lights=[{"type": "point", "position": [3, 4, 3]}],
                          ambient=(0.1, 0.1, 0.1), render={"shading": shading, "shadows": shadows})

    ambient_only = np.full((24, 32, 3), 0.05, np.float32)
    # the mesh: where a facet's geometric normal turns from the light, no shadow ray is cast (both
    # renderers), but its interpolated normal may still see it at grazing N.L < 0.01 (one pixel here)
    for obj, atol in ((sphere, 1e-6), (mesh, 0.01)):
        for method in ("raster", "raytrace"):
            np.testing.assert_allclose(render(scene(obj, True), method=method), ambient_only, atol=atol,
                                       err_msg=f"{obj['type']} {method}")
    gbuffer = render_frame(scene(sphere, True)).gbuffer
    used = np.unique(gbuffer.point_index[gbuffer.mask])  # the shading points the image is made of
    points = gbuffer.points
    lit_side = np.einsum("kc,kc->k", points.normal[used], points.light_dir[used, 0]) > 0
    assert lit_side.mean() > 0.3 and np.all(points.visibility[used, 0][lit_side] == 0.0)
    assert render(scene(sphere, False)).max() > 0.5


@pytest.mark.parametrize("shading", SHADINGS)
def test_a_sphere_seen_from_outside_does_not_shadow_itself(shading):
    """The same sphere and light from outside: no shadow ray may meet the sphere it leaves, so with
    shadows on, the image is the one without them, and agrees with the ray tracer's."""
    d = scene_dict([{"type": "sphere", "center": [0, 0.7, 0], "radius": 0.7, "material": "m"}],
                   {"m": {"ka": [0.5] * 3, "kd": [0.8, 0.2, 0.2], "ks": [0.4] * 3, "n": 30}},
                   camera={"eye": [0, 1, 4], "target": [0, 0.7, 0], "fov_y": 30, "width": 32, "height": 24},
                   lights=[{"type": "point", "position": [3, 4, 3]}], ambient=(0.1, 0.1, 0.1),
                   render={"shading": shading, "shadows": True})
    shadowed = render(d)
    assert shadowed.max() > 0.5
    np.testing.assert_array_equal(shadowed, render(d, shadows=False))
    if shading == "phong":
        assert np.abs(shadowed - render(d, method="raytrace")).mean() < 2e-3
