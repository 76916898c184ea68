"""A compiled scene (`difflab.compile_scene`) renders many settings without rebuilding anything."""

import numpy as np
import pytest

import difflab
from conftest import scene_dict
from difflab import CompiledScene, RenderError, compile_scene, render, render_frame
from difflab.renderers import api
from difflab.renderers.soup import chunked_face_normals

CAMERA = {"eye": [0.5, 1.0, 4.0], "target": [0, 0.2, 0], "fov_y": 40, "width": 24, "height": 18}
SCENE = scene_dict(
    [{"type": "sphere", "center": [0, 0.5, 0], "radius": 0.6, "material": "red"},
     {"type": "mesh", "builtin": "box", "material": "red", "transform": {"translate": [1.0, 0.2, -0.5], "scale": 0.5}},
     {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
    {"red": {"ka": [0.2, 0, 0], "kd": [0.7, 0.1, 0.1], "ks": [0.5, 0.5, 0.5], "n": 20, "kr": 0.3},
     "floor": {"kd": [0.6, 0.6, 0.6], "checker": {"size": 0.5, "kd2": [0.1, 0.1, 0.1]}}},
    camera=CAMERA, lights=[{"type": "point", "position": [2, 4, 3]}], ambient=(0.1, 0.1, 0.1))


@pytest.fixture
def no_compiling(monkeypatch):
    """Make any rebuild of device data an error for the rest of the test."""
    def refuse(*args, **kwargs):
        raise AssertionError("compile_scene was called")

    monkeypatch.setattr(api, "compile_scene", refuse)


def test_compiled_scene_renders_every_setting_as_a_fresh_scene_does(no_compiling):
    compiled = compile_scene(SCENE)  # the public name; only render's own compiling is refused
    assert isinstance(compiled, CompiledScene) and difflab.compile_scene is compile_scene
    cases = [dict(method="raster", shading=s, specular=p) for s in ("flat", "gouraud", "phong")
             for p in ("phong", "blinn")]
    cases += [dict(method="raytrace", max_depth=d, shadows=sh) for d in (1, 3) for sh in (True, False)]
    got = [render(compiled, **case) for case in cases]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(api, "compile_scene", compile_scene)
        want = [render(SCENE, **case) for case in cases]
    for case, a, b in zip(cases, got, want):
        assert np.array_equal(a, b), case
    assert compiled.scene == difflab.Scene.from_dict(SCENE)  # rendering with overrides leaves it as it was


def test_frames_of_one_compiled_scene_keep_their_images_and_threads_do_not_share_scratch(no_compiling):
    """A compiled scene reuses its per-frame arrays (`scratch`): an earlier frame's image stays as it
    was, a different sample grid (spp) reallocates them, and threads rendering it at once each get
    their own (frames sharing the band threads, whose lit-point caches they take turns with, too)."""
    from concurrent.futures import ThreadPoolExecutor

    compiled = compile_scene(SCENE)
    cases = [dict(shading=s, spp=n) for s in ("flat", "gouraud") for n in (1, 4)]
    first = [render(compiled, threads=1, **case) for case in cases]
    kept = [image.copy() for image in first]
    again = [render(compiled, threads=1, **case) for case in reversed(cases)][::-1]
    with ThreadPoolExecutor(max_workers=4) as pool:  # frames at once, each on one thread or sharing the band pool
        threaded = list(pool.map(lambda case: render(compiled, threads=1, **case), cases * 3))
        banded = list(pool.map(lambda case: render(compiled, threads=2, **case), cases * 3))
    for k, case in enumerate(cases):
        assert np.array_equal(first[k], kept[k]) and np.array_equal(again[k], kept[k]), case
        assert all(np.array_equal(threaded[k + j * len(cases)], kept[k]) for j in range(3)), case
        assert all(np.array_equal(banded[k + j * len(cases)], kept[k]) for j in range(3)), case


def test_every_frame_starts_from_a_cleared_zbuffer_whatever_ran_before(no_compiling):
    """The z-buffer is kept between frames and reset by the kernel that reads it last (or filled
    when that did not run). A quad seen from behind, drawn and then culled: the culled frame is
    empty after a render, a G-buffer frame, the ray tracer's item buffer (which reads the keys and
    leaves them) and other thread counts (a stale key would show the quad)."""
    quad = {"type": "mesh", "vertices": [[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]],
            "faces": [[0, 2, 1], [0, 3, 2]], "material": "m"}  # clockwise from the eye: its back
    compiled = compile_scene(scene_dict([quad], {"m": {"ka": [1, 1, 1]}}, ambient=(0.5, 0.5, 0.5)))
    drawn = render(compiled, threads=1)
    assert float(drawn.max()) == pytest.approx(0.5) and float(drawn.mean()) == pytest.approx(0.125)
    for before in [lambda: render(compiled, threads=3), lambda: render_frame(compiled, threads=2),
                   lambda: render(compiled, method="raytrace", item_buffer=True, threads=1)]:
        before()
        assert not render(compiled, cull_backfaces=True, threads=1).any()
        assert np.array_equal(render(compiled, threads=2), drawn)


def test_compiled_scene_gives_the_frame_a_fresh_scene_gives(no_compiling):
    compiled = compile_scene(SCENE)
    frame = render_frame(compiled, method="raster", shading="phong")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(api, "compile_scene", compile_scene)
        fresh = render_frame(SCENE, method="raster", shading="phong")
    assert np.array_equal(frame.gbuffer.depth, fresh.gbuffer.depth)
    assert np.array_equal(frame.gbuffer.points.color, fresh.gbuffer.points.color)
    traced = render_frame(compiled, method="raytrace", max_depth=2)
    assert traced.ray_tree.n_nodes == traced.stats["nodes"] > 18 * 24


def test_compiled_scene_refuses_what_it_was_not_built_for(no_compiling):
    compiled = compile_scene(SCENE)
    with pytest.raises(RenderError, match=r"^width / height: a CompiledScene is built for its camera \(24x18\)"):
        render(compiled, width=32)
    with pytest.raises(RenderError, match="^device: "):
        render(compiled, device="cuda")
    with pytest.raises(RenderError, match="^shading: 'flat' does not apply to method='raytrace'"):
        render(compiled, method="raytrace", shading="flat")
    with pytest.raises(RenderError, match="^scene: expected a Scene, a dict or a path, got int"):
        compile_scene(3)


def test_compiled_mesh_is_one_copy_and_chunked_face_normals_equal_one_call():
    """On the CPU the device arrays alias the compiled numpy arrays (no second copy of the mesh);
    face normals computed a few faces at a time are bitwise those of one float64 call."""
    compiled = compile_scene(SCENE)
    for name in ("vertices", "normals", "uvs", "faces", "face_normal", "face_material"):
        assert compiled.arrays[name].ptr == getattr(compiled, name).ctypes.data, name
    mesh = difflab.geometry.uv_sphere(1.0, (0.2, 0.0, -0.3), 9, 14)
    vertices = mesh.vertices.astype(np.float32)
    faces = mesh.faces.astype(np.int32)
    whole = difflab.geometry.face_normals(vertices.astype(np.float64), faces).astype(np.float32)
    chunked = chunked_face_normals(vertices, faces, chunk=5)  # 5 does not divide the 224 faces
    assert faces.shape[0] % 5 and chunked.dtype == np.float32
    np.testing.assert_array_equal(chunked, whole)
    np.testing.assert_allclose(np.linalg.norm(chunked, axis=1), 1.0, atol=1e-6)
