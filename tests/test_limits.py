"""Budgets and numeric edges: requests are priced before allocating, and valid-but-extreme numbers
(a tiny field of view, an eye at 1e30, a vertex at 1e39) are refused with the field that causes them."""

import json
import math
import re
import subprocess
import sys
import textwrap

import pytest

from conftest import scene_dict
from difflab import DifflabError, MeshError, Scene, SceneError, limits
from difflab.geometry import box, load_mesh, teapot, uv_sphere


def test_parse_bytes_reads_binary_suffixes_and_names_bad_values():
    assert limits.parse_bytes("512M", "X") == 512 * 2 ** 20
    assert limits.parse_bytes("8G", "X") == 8 * 2 ** 30
    assert limits.parse_bytes("1.5GiB", "X") == 3 * 2 ** 29
    assert limits.parse_bytes("4096", "X") == 4096
    for bad in ("abc", "-1G", "0", "nanG", ""):
        with pytest.raises(DifflabError, match=r"^X: expected a positive size in bytes such as 8G or 512M, got "):
            limits.parse_bytes(bad, "X")


def test_budget_comes_from_the_environment_or_half_the_available_memory(monkeypatch):
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "3G")
    assert limits.memory_budget() == 3 * 2 ** 30
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "lots")
    with pytest.raises(DifflabError, match=r"^DIFFLAB_MEMORY_BUDGET: expected a positive size"):
        limits.memory_budget()
    monkeypatch.delenv("DIFFLAB_MEMORY_BUDGET")
    monkeypatch.setattr(limits, "available_bytes", lambda: 10 * 2 ** 30)
    assert limits.memory_budget() == 5 * 2 ** 30


def test_an_address_space_limit_lowers_the_available_memory():
    """Under `ulimit -v`, what the process may still map is the limit less what it has mapped."""
    code = textwrap.dedent("""
        import resource
        from difflab import limits
        mapped = limits._vm_size()
        resource.setrlimit(resource.RLIMIT_AS, (mapped + 2 ** 30, resource.RLIM_INFINITY))
        print(limits.available_bytes() / 2 ** 30)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert 0.9 < float(out.stdout) <= 1.0


def test_available_memory_is_read_again_only_after_its_max_age(monkeypatch):
    readings, clock = iter([5 * 2 ** 30, 3 * 2 ** 30]), [100.0]
    monkeypatch.setattr(limits, "_read_available", lambda: next(readings))
    monkeypatch.setattr(limits, "monotonic", lambda: clock[0])
    monkeypatch.setattr(limits, "_available", (-math.inf, 0))
    assert limits.available_bytes() == 5 * 2 ** 30
    clock[0] += limits.AVAILABLE_MAX_AGE  # not older than the max age yet: the same reading
    assert limits.available_bytes() == 5 * 2 ** 30
    clock[0] += 0.01
    assert limits.available_bytes() == 3 * 2 ** 30


def test_a_small_request_is_checked_against_the_last_reading_a_large_one_against_a_new_one(monkeypatch):
    readings, clock = iter([64 * 2 ** 30, 2 * 2 ** 30]), [100.0]
    monkeypatch.delenv("DIFFLAB_MEMORY_BUDGET", raising=False)
    monkeypatch.setattr(limits, "_read_available", lambda: next(readings))
    monkeypatch.setattr(limits, "monotonic", lambda: clock[0])
    monkeypatch.setattr(limits, "_available", (-math.inf, 0))
    limits.require_memory(2 ** 20, "first")  # read: 64 GiB
    clock[0] += limits.SMALL_MAX_AGE
    limits.require_memory(2 ** 30, "small")  # 1 GiB = 1 / 64 of the last reading: not read again
    assert limits._available == (100.0, 64 * 2 ** 30)
    with pytest.raises(DifflabError, match=r"^large: needs about 1\.50 GiB, over the memory budget of 1\.00 GiB"):
        limits.require_memory(1.5 * 2 ** 30, "large")  # read again: 2 GiB, a budget of 1 GiB


def test_require_memory_names_the_request_and_the_setting(monkeypatch):
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "1G")
    limits.require_memory(2 ** 30, "frame")  # exactly the budget is allowed
    with pytest.raises(SceneError, match=r"^frame: needs about 2\.00 GiB, over the memory budget of 1\.00 GiB "
                                         r"\(DIFFLAB_MEMORY_BUDGET; set DIFFLAB_MEMORY_BUDGET to raise it\); try less$"):
        limits.require_memory(2 * 2 ** 30, "frame", SceneError, "try less")


@pytest.mark.parametrize("budget, nbytes, need, have", [
    ("1M", 2 ** 20 + 1000, "1.001 MiB", "1.000 MiB"),  # was "needs about 1.0 MiB, over the memory budget of 1.0 MiB"
    ("1M", 2 ** 20 + 1, "1.000001 MiB", "1.000000 MiB"),
    ("1G", 2 ** 30 + 1, "1073741825 bytes", "1073741824 bytes"),  # no 6 digits tell them apart: the bytes
    ("1G", 2 ** 30 + 2 ** 21, "1.002 GiB", "1.000 GiB"),
    ("1M", 3 * 2 ** 20, "3.0 MiB", "1.0 MiB"),  # apart at the usual digits: as before
])
def test_a_refusal_prints_its_need_and_budget_apart(monkeypatch, budget, nbytes, need, have):
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", budget)
    with pytest.raises(SceneError, match=f"^frame: needs about {re.escape(need)}, over the memory budget of "
                                         f"{re.escape(have)} "):
        limits.require_memory(nbytes, "frame", SceneError)


@pytest.mark.parametrize("depth, branching, weight, threshold, nodes", [
    (5, 0, 1.0, 0.0, 1),          # opaque, no reflection: the primary ray only
    (5, 1, 1.0, 0.0, 5),          # a mirror chain: one node per level
    (5, 2, 1.0, 0.0, 31),         # glass: 1 + 2 + 4 + 8 + 16
    (64, 2, 1.0, 0.0, 2 ** 62),   # capped
    # Hall's cut: 0.5^(k-1) >= 0.01 for k <= 7, so levels 1..8 can exist; their weights sum to <= (2 x 0.5)^(k-1)
    # = 1, so each holds <= 1 / 0.01 = 100 rays: 1 + 2 + ... + 64 + 100 (it was 2^8 - 1 = 255 before that count)
    (64, 2, 0.5, 0.01, 127 + 100),
    (64, 2, 0.0, 0.01, 1),        # nothing is spawned with weight 0
])
def test_ray_tree_bound(depth, branching, weight, threshold, nodes):
    assert limits.ray_tree_nodes(depth, branching, weight, threshold) == nodes


@pytest.mark.parametrize("depth, weight, spread, threshold, nodes", [
    (64, 1.0, 1.0, 0.01, 127 + 57 * 100),  # Fresnel glass kr = kt = 1: every level's weights sum to <= 1
    (20, 1.0, 1.0, 0.01, 127 + 13 * 100),  # the reviewer's glass_sphere at max_depth 20 (was 2^20 - 1)
    (10, 2.0, 2.0, 0.01, 2 ** 10 - 1),     # kr = kt = 1 without Fresnel: the weights double, no bound
    (64, 1.0, 0.9, 0.1, 1 + 2 + 4 + 7 + 6 + 5 + 5 + 4 + 4 + 3 + 3 + 3 + 2 + 2 + 2 + 2 + 1 + 1 + 1 + 1 + 1 + 1),
    (64, 0.9, 1.8, 0.0, 2 ** 62),          # no threshold: no count by weight
])
def test_ray_tree_bound_counts_each_level_by_its_total_weight(depth, weight, spread, threshold, nodes):
    """Level k + 1 holds at most min(2 x level k's rays, spread^k / threshold): with 0.9^k / 0.1 the
    levels hold 1, 2, 4, floor(7.29), 6.56, 5.9, ... and none once 0.9^k < 0.1 (k = 22)."""
    assert limits.ray_tree_nodes(depth, 2, weight, threshold, spread) == nodes


def test_ray_budget_refuses_an_exponential_tree(monkeypatch):
    with pytest.raises(DifflabError, match=r"^render: up to 2\.83e\+22 rays \(768 samples x 1\.84e\+19 ray-tree nodes "
                                           r"x 2 rays per node\) is over the budget of 1\.07e\+09 rays"):
        limits.check_rays(32 * 24, 2 ** 64 - 1, 1, "render")
    monkeypatch.setenv("DIFFLAB_MAX_RAYS", "12")
    limits.check_rays(2, 3, 1, "render")
    with pytest.raises(DifflabError, match=r"over the budget of 12 rays"):
        limits.check_rays(2, 3, 2, "render")
    monkeypatch.setenv("DIFFLAB_MAX_RAYS", "many")
    with pytest.raises(DifflabError, match=r"^DIFFLAB_MAX_RAYS: expected a positive integer, got 'many'$"):
        limits.ray_budget()


def test_tessellations_are_priced_before_they_are_built(monkeypatch):
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "1G")
    with pytest.raises(MeshError, match=r"^teapot at resolution 1024 \(67108864 triangles\): needs about 33\.75 GiB, "
                                        r"over the memory budget of 1\.00 GiB"):
        teapot(1024)
    with pytest.raises(MeshError, match=r"^uv_sphere of 4000 x 8000 \(63984000 triangles\): needs about"):
        uv_sphere(1.0, n_lat=4000, n_lon=8000)
    with pytest.raises(MeshError, match=r"^box of 3000 x 3000 divisions \(108000000 triangles\)"):
        box(divisions=3000)
    assert teapot(2).n_faces <= 64 * 2 * 2  # small ones are built as before


@pytest.mark.parametrize("value, message", [
    ("1e39", r"vertex 2 is beyond \+-1e\+12 \(float32 rendering overflows\)"),
    ("-2e12", r"vertex 2 is beyond \+-1e\+12"),
    ("inf", r"vertex 2 is not finite"),
])
def test_obj_vertices_beyond_float32_rendering_name_file_and_line(tmp_path, value, message):
    path = tmp_path / "big.obj"
    path.write_text(f"v 0 0 0\nv {value} 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match=rf"big\.obj:2: {message}"):
        load_mesh(path)


def test_ply_vertices_beyond_the_range_are_refused(tmp_path):
    path = tmp_path / "big.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n3e30 0 0\n0 1 0\n3 0 1 2\n")
    with pytest.raises(MeshError, match=r"big\.ply: vertex coordinates reach 3e\+30, beyond \+-1e\+12"):
        load_mesh(path)


CAMERA = {"eye": [0, 0, 5], "target": [0, 0, 0], "width": 8, "height": 8}


@pytest.mark.parametrize("change, message", [
    ({"fov_y": 1e-300}, r"camera\.fov_y: must be >= 1e-06, got 1e-300"),
    ({"projection": "orthographic", "ortho_height": 1e-30}, r"camera\.ortho_height: must be >= 1e-09"),
    ({"near": 1e-20}, r"camera\.far / camera\.near: 1e\+22 is over 1e\+06 .*; raise near or lower far$"),
    ({"far": 1e7}, r"camera\.far / camera\.near: 1e\+08 is over 1e\+06"),  # was reported as camera.near's
    ({"width": 8192, "height": 8193}, r"camera\.width: 8192 x 8193 = 67117056 pixels is over the limit of 64 "
                                      r"megapixels \(67108864 pixels; below it the memory budget applies\)$"),
    ({"eye": [0, 0, 1e30], "target": [0, 0, 1e29]}, r"camera\.eye\[2\]: must be within \+-1e12 scene units"),
    ({"target": [1e13, 0, 0]}, r"camera\.target\[0\]: must be within \+-1e12 scene units"),
    ({"up": [0, 1e-259, 0]}, r"camera\.up: is 1e-259 long, too short to give a direction \(must be >= 1e-09\)"),
    ({"eye": [1e6, 0, 0], "target": [1e6, 0, 1e-5]}, r"camera\.target: is 1e-05 from eye, too close to give a view"),
])
def test_extreme_cameras_name_their_field(change, message):
    with pytest.raises(SceneError, match="^" + message):
        Scene.from_dict(scene_dict([], {}, camera={**CAMERA, **change}))


def test_the_sample_cap_is_not_called_the_memory_budget():
    """width * height * spp <= 64 M is a fixed cap (docs/limits.md), the memory budget applying below it."""
    with pytest.raises(SceneError, match=r"^render\.spp: 4096 x 4096 pixels at spp 16 is 268435456 samples, over the "
                                         r"limit of 64 M samples \(67108864; below it the memory budget applies\)$"):
        Scene.from_dict(scene_dict([], {}, camera={**CAMERA, "width": 4096, "height": 4096}, render={"spp": 16}))


@pytest.mark.parametrize("obj, message", [
    ({"type": "sphere", "center": [0, 0, 0], "radius": 1e30, "material": "m"}, r"objects\[0\]\.radius: must be within"),
    ({"type": "plane", "point": [0, 3e38, 0], "normal": [0, 1, 0], "material": "m"}, r"objects\[0\]\.point\[1\]: must"),
    ({"type": "mesh", "builtin": "box", "material": "m", "transform": {"scale": 1e30}},
     r"objects\[0\]\.transform\.scale\[0\]: must be within"),
    ({"type": "mesh", "builtin": "box", "material": "m", "transform": {"translate": [0, 0, -1e13]}},
     r"objects\[0\]\.transform\.translate\[2\]: must be within"),
])
def test_extreme_geometry_names_its_field(obj, message):
    with pytest.raises(SceneError, match="^" + message):
        Scene.from_dict(scene_dict([obj], {"m": {}}))


def test_scene_file_errors_carry_the_file(tmp_path):
    d = scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": 1e30, "material": "m"}], {"m": {}})
    (tmp_path / "s.json").write_text(json.dumps(d))
    from difflab import load_scene

    with pytest.raises(SceneError, match=r"^objects\[0\]\.radius: must be within .* \(in .*s\.json\)$"):
        load_scene(tmp_path / "s.json")


def test_fractal_images_are_priced_before_they_are_drawn(monkeypatch, tmp_path):
    from difflab import RenderError
    from difflab.demos.fractals import draw_curve
    from difflab.fractals import mandelbrot

    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "1G")
    with pytest.raises(RenderError, match=r"^width x height \(8000 x 8000 pixels\): needs about 7\.15 GiB, over the "
                                          r"memory budget of 1\.00 GiB"):
        mandelbrot(8000, 8000)
    with pytest.raises(RenderError, match=r"^koch: a figure of \(20000 x 20000 pixels\): needs about 2\.98 GiB"):
        draw_curve("koch", 2, tmp_path / "k.png", 20000, 20000)
    assert not (tmp_path / "k.png").exists()


def test_raster_overdraw_is_priced_by_bounding_boxes_and_refused_over_the_budget(monkeypatch):
    """Two triangles of a quad larger than the 32x32 frame: each box spans every sample, so the
    coverage stage makes 2 x 32 x 32 = 2048 tests; one fewer allowed is a RenderError before drawing."""
    from difflab import RenderError, render

    quad = {"type": "mesh", "vertices": [[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]],
            "faces": [[0, 1, 2], [0, 2, 3]], "material": "m"}
    scene = Scene.from_dict(scene_dict([quad], {"m": {"ka": [1, 1, 1]}}, ambient=(0.5, 0.5, 0.5)))
    monkeypatch.setenv("DIFFLAB_MAX_RASTER_TESTS", "2048")
    image = render(scene, method="raster")
    assert image.shape == (32, 32, 3) and float(image.min()) == pytest.approx(0.5)
    monkeypatch.setenv("DIFFLAB_MAX_RASTER_TESTS", "2047")
    with pytest.raises(RenderError, match=r"^render: rasterizing 2 triangles means 2\.05e\+03 sample tests .* "
                                          r"over the budget of 2\.05e\+03 \(set DIFFLAB_MAX_RASTER_TESTS"):
        render(scene, method="raster")


@pytest.mark.parametrize("threads", [1, 3])
def test_overdraw_count_adds_up_over_the_launch_parts(monkeypatch, threads):
    """Assembling sums each launch part's box samples apart (1 part on one thread, 12 on three) and
    the driver adds the parts: 300 copies of the frame-covering quad make exactly 600 x 32 x 32 tests."""
    from difflab import RenderError, render

    copies = 300
    faces = [[4 * k, 4 * k + 1, 4 * k + 2] for k in range(copies)] + [[4 * k, 4 * k + 2, 4 * k + 3]
                                                                       for k in range(copies)]
    quads = {"type": "mesh", "vertices": [[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]] * copies, "faces": faces,
             "material": "m"}
    scene = Scene.from_dict(scene_dict([quads], {"m": {"ka": [1, 1, 1]}}, ambient=(0.5, 0.5, 0.5)))
    monkeypatch.setenv("DIFFLAB_MAX_RASTER_TESTS", str(2 * copies * 32 * 32))
    assert float(render(scene, method="raster", threads=threads).min()) == pytest.approx(0.5)
    monkeypatch.setenv("DIFFLAB_MAX_RASTER_TESTS", str(2 * copies * 32 * 32 - 1))
    with pytest.raises(RenderError, match=r"^render: rasterizing 600 triangles means 6\.14e\+05 sample tests"):
        render(scene, method="raster", threads=threads)
