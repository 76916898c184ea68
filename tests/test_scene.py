"""difflab.scene: the JSON scene format, defaults, validation messages, round trips, overrides."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
import pickle
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from difflab import render
from difflab.errors import SceneError
from difflab.scene import (Camera, Checker, Fog, Light, Material, Mesh, Plane, RenderSettings, Scene,
                           Sphere, Transform, load_scene, save_scene)

# The example of DESIGN.md, verbatim.
DESIGN_EXAMPLE = r"""
{
  "camera":  {"eye": [0, 1, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40,
              "width": 320, "height": 240, "projection": "perspective", "near": 0.1, "far": 100},
  "ambient": [0.1, 0.1, 0.1],
  "background": [0, 0, 0],
  "lights": [
    {"type": "point", "position": [5, 5, 5], "intensity": [1, 1, 1], "attenuation": [1, 0, 0]},
    {"type": "directional", "direction": [-1, -1, -1], "intensity": [0.5, 0.5, 0.5]},
    {"type": "spot", "position": [0, 4, 0], "direction": [0, -1, 0], "cutoff_deg": 30,
     "exponent": 8, "intensity": [1, 1, 1], "attenuation": [1, 0, 0]}
  ],
  "materials": {
    "red":    {"ka": [0.1, 0, 0], "kd": [0.7, 0.1, 0.1], "ks": [0.5, 0.5, 0.5], "n": 32},
    "mirror": {"ka": [0, 0, 0], "kd": [0.05, 0.05, 0.05], "ks": [0.8, 0.8, 0.8], "n": 200, "kr": 0.9},
    "glass":  {"kd": [0, 0, 0], "ks": [0.5, 0.5, 0.5], "n": 200, "kt": 0.9, "ior": 1.5,
               "absorption": [0.1, 0.0, 0.0]},
    "floor":  {"kd": [0.8, 0.8, 0.8], "checker": {"size": 1.0, "ka2": [0, 0, 0], "kd2": [0.1, 0.1, 0.1]}},
    "brick":  {"kd": [1, 1, 1], "texture": "brick.png", "filter": "trilinear"}
  },
  "objects": [
    {"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"},
    {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"},
    {"type": "mesh", "file": "teapot.obj", "material": "mirror", "smooth": true,
     "transform": {"translate": [2, 0, 0], "rotate_deg": [0, 30, 0], "scale": 0.5}},
    {"type": "mesh", "builtin": "teapot", "material": "red"}
  ],
  "fog": {"mode": "linear", "color": [0.5, 0.5, 0.5], "start": 5, "end": 20},
  "render": {"method": "raster", "shading": "phong", "specular": "phong", "shadows": true,
             "max_depth": 5, "spp": 1, "fresnel": "none", "transparent_shadows": true,
             "clamp_vertex_colors": false}
}
"""


def _make_assets(folder) -> None:
    (folder / "teapot.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (folder / "brick.png").write_bytes(b"\x89PNG\r\n\x1a\n")  # existence is all the scene checks


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene_assets")
    _make_assets(folder)
    return folder


@pytest.fixture
def example(assets):
    """The DESIGN.md example as a dict, and the folder its relative paths resolve against."""
    return json.loads(DESIGN_EXAMPLE), assets


def minimal(**extra):
    d = {"camera": {"eye": [0, 0, 5], "target": [0, 0, 0]},
         "materials": {"m": {}},
         "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]}
    d.update(extra)
    return d


# -- the example, round trips, defaults ----------------------------------------------------------


def test_design_example_loads(tmp_path):
    _make_assets(tmp_path)
    (tmp_path / "scene.json").write_text(DESIGN_EXAMPLE)
    s = load_scene(tmp_path / "scene.json")
    assert s.camera == Camera(eye=(0, 1, 5), target=(0, 0, 0))
    assert s.ambient == (0.1, 0.1, 0.1)
    assert [light.type for light in s.lights] == ["point", "directional", "spot"]
    d = -1 / math.sqrt(3)
    assert s.lights[1].direction == pytest.approx((d, d, d), abs=1e-15)
    assert s.lights[2].cutoff_deg == 30.0 and s.lights[2].exponent == 8.0
    assert s.material_names == ("red", "mirror", "glass", "floor", "brick")
    assert s.material_index("floor") == 3
    assert s.materials["floor"].checker == Checker()
    assert s.materials["glass"].ior == 1.5 and s.materials["glass"].kt == 0.9
    assert s.materials["brick"].texture == str(tmp_path / "brick.png")
    assert s.materials["brick"].filter == "trilinear"
    sphere, plane, mesh, teapot = s.objects
    assert isinstance(sphere, Sphere) and sphere.radius == 1.0 and isinstance(sphere.radius, float)
    assert isinstance(plane, Plane) and plane.normal == (0.0, 1.0, 0.0)
    assert mesh.file == str(tmp_path / "teapot.obj") and mesh.builtin is None
    assert mesh.transform == Transform(translate=(2, 0, 0), rotate_deg=(0, 30, 0), scale=(0.5, 0.5, 0.5))
    assert teapot.builtin == "teapot" and teapot.file is None and teapot.resolution == 8
    assert s.fog == Fog(mode="linear", start=5, end=20)
    assert s.render == RenderSettings()
    assert s.base_dir == str(tmp_path)


def test_round_trip_exact(example, tmp_path):
    d, folder = example
    s = Scene.from_dict(d, base_dir=folder)
    out = s.to_dict()
    assert Scene.from_dict(out) == s
    assert Scene.from_dict(json.loads(json.dumps(out))) == s
    assert Scene.from_dict(out).to_dict() == out  # to_dict is a normal form
    # explicit, JSON-native: lists (never tuples), every field, absolute paths
    text = json.dumps(out, allow_nan=False)
    assert "(" not in text
    assert set(out) == {"camera", "ambient", "background", "lights", "materials", "objects", "fog", "render"}
    assert set(out["render"]) == {f.name for f in dataclasses.fields(RenderSettings)}
    assert out["objects"][2]["transform"]["scale"] == [0.5, 0.5, 0.5]
    assert out["objects"][0]["type"] == "sphere" and out["objects"][3]["type"] == "mesh"
    assert os.path.isabs(out["objects"][2]["file"]) and os.path.isabs(out["materials"]["brick"]["texture"])
    # save/load through a file in another folder keeps the scene
    save_scene(s, tmp_path / "sub" / "saved.json")
    assert load_scene(tmp_path / "sub" / "saved.json") == s
    # records are immutable, picklable and hashable
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.camera.width = 3
    with pytest.raises(TypeError):
        s.materials["x"] = Material()
    assert pickle.loads(pickle.dumps(s)) == s and copy.deepcopy(s) == s
    assert hash(s) == hash(Scene.from_dict(out))


def test_direction_normalisation_is_idempotent():
    for v in [(-1, -1, -1), (1e-300, 2e-300, 0), (3, 4, 12), (0.1, 0.7, -0.2)]:
        light = Light("directional", direction=v)
        assert math.isclose(math.hypot(*light.direction), 1.0, rel_tol=1e-15)
        assert Light(**{f.name: getattr(light, f.name) for f in dataclasses.fields(light)}) == light


def test_defaults():
    s = Scene.from_dict(minimal())
    assert s.camera == Camera(eye=(0, 0, 5), target=(0, 0, 0), up=(0, 1, 0), fov_y=40.0, width=320,
                              height=240, projection="perspective", near=0.1, far=100.0, ortho_height=2.0)
    assert s.ambient == (0, 0, 0) and s.background == (0, 0, 0) and s.lights == () and s.fog is None
    assert s.materials["m"] == Material(ka=(0, 0, 0), kd=(0.8, 0.8, 0.8), ks=(0, 0, 0), n=1.0, kr=0.0,
                                        kt=0.0, ior=1.0, absorption=(0, 0, 0), m=0.3, f0=0.04)
    m = s.materials["m"]
    assert (m.checker, m.texture, m.filter, m.wrap, m.texture_target) == (None, None, "bilinear", "repeat", "kd")
    r = s.render
    assert (r.method, r.shading, r.specular, r.shadows, r.max_depth, r.spp, r.fresnel) == (
        "raster", "phong", "phong", True, 5, 1, "none")
    assert (r.transparent_shadows, r.clamp_vertex_colors, r.interpolation, r.cull_backfaces,
            r.adaptive_threshold, r.sampling) == (True, False, "perspective", False, 0.0, "grid")
    light = Light("point", position=(1, 2, 3))
    assert (light.intensity, light.attenuation, light.cutoff_deg, light.exponent, light.direction) == (
        (1, 1, 1), (1, 0, 0), 180.0, 0.0, None)
    assert Fog("exp") == Fog(mode="exp", color=(0.5, 0.5, 0.5), start=0.0, end=1.0, density=1.0)
    mesh = Mesh("m", builtin="box")
    assert (mesh.resolution, mesh.smooth, mesh.transform) == (8, True, Transform())
    assert Transform() == Transform((0, 0, 0), (0, 0, 0), (1, 1, 1), None)
    assert Checker() == Checker(1.0, (0, 0, 0), (0.1, 0.1, 0.1))
    assert Scene.from_dict(minimal(objects=[])).objects == ()


def test_grey_shorthand_and_matrix_forms():
    d = minimal(ambient=0.2, materials={"m": {"ka": 0.1, "kd": 0.5, "ks": 1, "absorption": 0}})
    s = Scene.from_dict(d)
    assert s.ambient == (0.2, 0.2, 0.2)
    assert s.materials["m"].ks == (1.0, 1.0, 1.0) and s.to_dict()["materials"]["m"]["kd"] == [0.5, 0.5, 0.5]
    flat = [1, 0, 0, 1, 0, 1, 0, 2, 0, 0, 1, 3, 0, 0, 0, 1]
    nested = [flat[0:4], flat[4:8], flat[8:12], flat[12:16]]
    assert Transform(matrix=nested) == Transform(matrix=flat)
    assert Transform(matrix=flat).to_dict()["matrix"] == [float(x) for x in flat]


def test_direct_construction_is_validated():
    with pytest.raises(SceneError, match=r"^camera\.width: must be > 0, got 0"):
        Camera((0, 0, 1), (0, 0, 0), width=0)
    with pytest.raises(SceneError, match=r"^sphere\.radius: must be > 0"):
        Sphere((0, 0, 0), -1.0, "m")
    with pytest.raises(SceneError, match=r"^objects\[0\]\.material: undefined material 'x' \(defined: none\)"):
        Scene(camera=Camera((0, 0, 1), (0, 0, 0)), objects=[Sphere((0, 0, 0), 1, "x")])
    with pytest.raises(SceneError, match=r"^lights\[0\]: expected a Light"):
        Scene(camera=Camera((0, 0, 1), (0, 0, 0)), lights=[{"type": "point"}])
    s = Scene(camera=Camera((0, 0, 1), (0, 0, 0)), lights=[Light("point", (0, 1, 0))],
              materials={"m": Material()}, objects=[Plane((0, 0, 0), (0, 2, 0), "m")])
    assert isinstance(s.lights, tuple) and isinstance(s.objects, tuple) and s.objects[0].normal == (0, 1, 0)


# -- bad input ------------------------------------------------------------------------------------

def _set(d, path, value):
    """Set d[path] where path is a tuple of keys / indices; value DELETE removes the key."""
    *head, last = path
    for key in head:
        d = d[key]
    if value is DELETE:
        del d[last]
    else:
        d[last] = value


DELETE = object()
BAD = [
    # (path in the example dict, new value, expected message start)
    (("objects", 0, "radius"), -1, r"objects\[0\]\.radius: must be > 0, got -1"),
    (("objects", 0, "radius"), 0, r"objects\[0\]\.radius: must be > 0, got 0"),
    (("objects", 0, "radius"), True, r"objects\[0\]\.radius: expected a number, got True"),
    (("objects", 0, "radius"), "1", r"objects\[0\]\.radius: expected a number, got '1'"),
    (("objects", 0, "radius"), float("nan"), r"objects\[0\]\.radius: must be finite, got nan"),
    (("objects", 0, "radius"), float("inf"), r"objects\[0\]\.radius: must be finite, got inf"),
    (("objects", 0, "radius"), 10**400, r"objects\[0\]\.radius: must be finite"),
    (("objects", 0, "radius"), 1e39, r"objects\[0\]\.radius: must be within the float32 range"),
    (("objects", 0, "radius"), DELETE, r"objects\[0\]\.radius: required"),
    (("objects", 0, "radiuss"), 1, r"objects\[0\]: unknown key 'radiuss' \(did you mean 'radius'\?\)"),
    (("objects", 0, "type"), "cube", r"objects\[0\]\.type: must be one of 'sphere', 'plane', 'mesh'"),
    (("objects", 0, "type"), DELETE, r"objects\[0\]\.type: required"),
    (("objects", 1, "material"), "foo",
     r"objects\[1\]\.material: undefined material 'foo' \(defined: red, mirror, glass, floor, brick\)"),
    (("objects", 1, "normal"), [0, 0, 0], r"objects\[1\]\.normal: must not be zero-length"),
    (("objects", 0, "center"), [0, float("nan"), 0], r"objects\[0\]\.center\[1\]: must be finite"),
    (("objects", 0, "center"), [0, 0], r"objects\[0\]\.center: expected 3 numbers, got \[0, 0\]"),
    (("objects", 2, "file"), "missing.obj", r"objects\[2\]\.file: file not found: .*missing\.obj"),
    (("objects", 2, "builtin"), "teapot", r"objects\[2\]\.builtin: give one of 'file', 'builtin' or 'vertices', "
                                          r"not 'file' and 'builtin'"),
    (("objects", 3, "builtin"), DELETE, r"objects\[3\]: needs one of 'file', 'builtin' or 'vertices' \(with 'faces'\)"),
    (("objects", 3, "vertices"), [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
     r"objects\[3\]\.vertices: give one of 'file', 'builtin' or 'vertices', not 'builtin' and 'vertices'"),
    (("objects", 3, "faces"), [[0, 1, 2]], r"objects\[3\]\.faces: only used with 'vertices'"),
    (("objects", 3, "builtin"), "teapott", r"objects\[3\]\.builtin: must be one of .*did you mean 'teapot'"),
    (("objects", 3, "resolution"), 0, r"objects\[3\]\.resolution: must be >= 1"),
    (("objects", 3, "resolution"), 2.5, r"objects\[3\]\.resolution: expected an integer"),
    (("objects", 3, "smooth"), 1, r"objects\[3\]\.smooth: expected true or false, got 1"),
    (("objects", 2, "transform", "scale"), 0, r"objects\[2\]\.transform\.scale\[0\]: must not be zero"),
    (("objects", 2, "transform", "rotate"), [0, 1, 0],
     r"objects\[2\]\.transform: unknown key 'rotate' \(did you mean 'rotate_deg'\?\)"),
    (("objects", 2, "transform", "matrix"), [1, 2, 3], r"objects\[2\]\.transform\.matrix: expected 16 numbers"),
    (("objects", 2, "transform", "matrix"), [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 1, 1],
     r"objects\[2\]\.transform\.matrix: must be affine"),
    (("objects", 2, "transform"), None, r"objects\[2\]\.transform: expected an object, got None"),
    (("objects", 0), [1], r"objects\[0\]: expected an object"),
    (("materials", "red", "kd"), "abc", r"materials\.red\.kd: expected 3 numbers, got 'abc'"),
    (("materials", "red", "kd"), [0.1, -0.1, 0], r"materials\.red\.kd\[1\]: must be >= 0, got -0\.1"),
    (("materials", "red", "n"), -1, r"materials\.red\.n: must be >= 0, got -1"),
    (("materials", "red", "kr"), 1.5, r"materials\.red\.kr: must be <= 1, got 1\.5"),
    (("materials", "red", "kt"), -0.5, r"materials\.red\.kt: must be >= 0"),
    (("materials", "red", "ior"), 0, r"materials\.red\.ior: must be >= 0\.001, got 0"),
    (("materials", "red", "ior"), 1e-30, r"materials\.red\.ior: must be >= 0\.001, got 1e-30"),
    (("materials", "red", "ior"), 1e30, r"materials\.red\.ior: must be <= 1000, got 1e\+30"),
    (("materials", "red", "ior"), 1000.5, r"materials\.red\.ior: must be <= 1000, got 1000\.5"),
    (("materials", "red", "m"), 0, r"materials\.red\.m: must be > 0"),
    (("materials", "red", "f0"), 2, r"materials\.red\.f0: must be <= 1"),
    (("materials", "red", "filter"), "cubic", r"materials\.red\.filter: must be one of 'nearest'"),
    (("materials", "red", "wrap"), "border", r"materials\.red\.wrap: must be one of"),
    (("materials", "red", "texture_target"), "kr", r"materials\.red\.texture_target: must be one of"),
    (("materials", "brick", "texture"), "nope.png", r"materials\.brick\.texture: file not found: .*nope\.png"),
    (("materials", "floor", "checker", "size"), 0, r"materials\.floor\.checker\.size: must be > 0"),
    (("materials", "floor", "checker"), 3, r"materials\.floor\.checker: expected an object, got 3"),
    (("materials", "red", "kdd"), 1, r"materials\.red: unknown key 'kdd' \(did you mean 'kd'\?\)"),
    (("materials", "red"), "red", r"materials\.red: expected an object"),
    (("materials",), [], r"materials: expected an object"),
    (("lights", 0, "position"), DELETE, r"lights\[0\]\.position: required for a point light"),
    (("lights", 0, "direction"), [0, -1, 0], r"lights\[0\]\.direction: not used by a point light"),
    (("lights", 1, "direction"), [0, 0, 0], r"lights\[1\]\.direction: must not be zero-length"),
    (("lights", 1, "direction"), DELETE, r"lights\[1\]\.direction: required for a directional light"),
    (("lights", 1, "position"), [0, 1, 0], r"lights\[1\]\.position: not used by a directional light"),
    (("lights", 1, "cutoff_deg"), 30, r"lights\[1\]\.cutoff_deg: only spot lights have a cone"),
    (("lights", 2, "cutoff_deg"), 91, r"lights\[2\]\.cutoff_deg: must be <= 90, got 91$"),
    (("lights", 2, "cutoff_deg"), 0, r"lights\[2\]\.cutoff_deg: must be > 0, got 0"),
    (("lights", 2, "cutoff_deg"), DELETE, r"lights\[2\]\.cutoff_deg: a spot light needs 0 < cutoff_deg <= 90"),
    (("lights", 2, "exponent"), -1, r"lights\[2\]\.exponent: must be >= 0"),
    (("lights", 2, "direction"), DELETE, r"lights\[2\]\.direction: required for a spot light"),
    (("lights", 0, "intensity"), [1, -1, 1], r"lights\[0\]\.intensity\[1\]: must be >= 0"),
    (("lights", 0, "attenuation"), [0, 0, 0], r"lights\[0\]\.attenuation: must not be all zero"),
    (("lights", 0, "attenuation"), [1, -1, 0], r"lights\[0\]\.attenuation\[1\]: must be >= 0"),
    (("lights", 0, "type"), "area", r"lights\[0\]\.type: must be one of 'point', 'directional', 'spot'"),
    (("lights", 0, "type"), DELETE, r"lights\[0\]\.type: required"),
    (("lights",), {}, r"lights: expected a list"),
    (("camera", "width"), 0, r"camera\.width: must be > 0, got 0"),
    (("camera", "height"), -5, r"camera\.height: must be > 0, got -5"),
    (("camera", "width"), 300000, r"camera\.width: 300000 x 240 = 72000000 pixels is over the limit of 64 megapixels \(67108864 pixels; "
     r"below it the memory budget applies\)$"),  # a fixed cap, not the memory budget
    (("camera", "width"), 320.5, r"camera\.width: expected an integer, got 320\.5"),
    (("camera", "eye"), [0, 0, 0], r"camera\.target: must differ from eye"),
    (("camera", "up"), [0, 2, 10], r"camera\.up: must not be parallel to the view direction"),
    (("camera", "up"), [0, 0, 0], r"camera\.up: must not be zero-length"),
    (("camera", "fov_y"), 180, r"camera\.fov_y: must be < 180, got 180"),
    (("camera", "fov_y"), 0, r"camera\.fov_y: must be >= 1e-06, got 0"),
    (("camera", "near"), 0, r"camera\.near: must be > 0, got 0"),
    (("camera", "far"), 0.05, r"camera\.far: must be > near \(0\.1\), got 0\.05"),
    (("camera", "projection"), "fisheye", r"camera\.projection: must be one of 'perspective', 'orthographic'"),
    (("camera", "ortho_height"), -2, r"camera\.ortho_height: must be >= 1e-09"),
    (("camera", "fovy"), 40, r"camera: unknown key 'fovy' \(did you mean 'fov_y'\?\)"),
    (("camera", "eye"), DELETE, r"camera\.eye: required"),
    (("camera",), DELETE, r"camera: required"),
    (("objects",), DELETE, r"objects: required"),
    (("objects",), {}, r"objects: expected a list"),
    (("ambient",), [0.1, -1, 0], r"ambient\[1\]: must be >= 0"),
    (("background",), "black", r"background: expected 3 numbers, got 'black'"),
    (("fog", "end"), 1, r"fog\.end: must be > start \(5\.0\) for linear fog, got 1"),
    (("fog", "mode"), "exp3", r"fog\.mode: must be one of 'linear', 'exp', 'exp2', got 'exp3'"),
    (("fog", "density"), -1, r"fog\.density: must be >= 0"),
    (("render", "method"), "raycast", r"render\.method: must be one of 'raster', 'raytrace'"),
    (("render", "shading"), "Phong", r"render\.shading: must be one of .*\(did you mean 'phong'\?\)"),
    (("render", "specular"), "cook", r"render\.specular: must be one of 'phong', 'blinn', 'torrance'"),
    (("render", "max_depth"), 0, r"render\.max_depth: must be >= 1, got 0"),
    (("render", "spp"), 0, r"render\.spp: must be >= 1, got 0"),
    (("render", "spp"), 8, r"render\.spp: must be a perfect square \(1, 4, 9, 16, \.\.\.\).*got 8"),
    (("render", "spp"), 5000, r"render\.spp: must be <= 4096, got 5000"),
    (("$schema",), 5, r"\$schema: expected a string, got 5"),
    (("render", "shadows"), "yes", r"render\.shadows: expected true or false, got 'yes'"),
    (("render", "fresnel"), "full", r"render\.fresnel: must be one of 'none', 'schlick', 'exact'"),
    (("render", "adaptive_threshold"), -0.1, r"render\.adaptive_threshold: must be >= 0"),
    (("render", "sampling"), "random", r"render\.sampling: must be one of 'grid', 'stratified'"),
    (("render", "interpolation"), "linear", r"render\.interpolation: must be one of 'perspective', 'affine'"),
    (("render", "spp "), 1, r"render: unknown key 'spp ' \(did you mean 'spp'\?\)"),
    (("lightz",), [], r"scene: unknown key 'lightz' \(did you mean 'lights'\?\)"),
]


@pytest.mark.parametrize("path, value, message", BAD, ids=[f"{'.'.join(map(str, p))}={v!r:.20}" for p, v, _ in BAD])
def test_bad_input_names_the_field(example, path, value, message):
    d, folder = example
    _set(d, path, value)
    with pytest.raises(SceneError, match="^" + message):
        Scene.from_dict(d, base_dir=folder)


def test_schema_key_is_accepted_and_not_kept(example):
    d, folder = example
    scene = Scene.from_dict({"$schema": "scene.schema.json", **d}, base_dir=folder)
    assert scene == Scene.from_dict(d, base_dir=folder) and "$schema" not in scene.to_dict()


def test_supersampled_grid_is_held_to_the_pixel_budget():
    camera = {"eye": [0, 0, 5], "target": [0, 0, 0], "width": 4096, "height": 2048}
    assert Scene.from_dict(minimal(camera=camera, render={"spp": 4})).render.spp_side == 2  # 32 M samples
    with pytest.raises(SceneError, match=r"^render\.spp: 4096 x 2048 pixels at spp 9 is 75497472 samples, over"):
        Scene.from_dict(minimal(camera=camera, render={"spp": 9}))
    small = Scene.from_dict(minimal(render={"spp": 16}))
    with pytest.raises(SceneError, match=r"^render\.spp: 10000 x 1000 pixels at spp 16"):
        small.with_overrides(camera={"eye": [0, 0, 5], "target": [0, 0, 0], "width": 10000, "height": 1000})


@pytest.mark.parametrize("fresnel", ["schlick", "exact"])
def test_a_fresnel_mirror_of_ior_1_loads_and_reflects_nothing(fresnel):
    """With Fresnel weighting a surface reflects kr F (DESIGN.md's formula), and F = 0 at ior 1 (the
    default: no interface): such a mirror loads and renders as if kr were 0, as POV-Ray's does
    (the scene was refused for a while: the DESIGN example's mirror, kr 0.9 without an ior, then
    could not be rendered with Fresnel on at all). With an ior it reflects."""
    mirror = minimal(materials={"m": {"kd": 0.8}, "mirror": {"kd": 0.3, "kr": 0.5}},
                     objects=[{"type": "plane", "point": [0, -1, 0], "normal": [0, 1, 0], "material": "mirror"},
                              {"type": "sphere", "center": [0, 0, 0], "radius": 0.5, "material": "m"}],
                     lights=[{"type": "point", "position": [2, 4, 3]}], background=[0.2, 0.4, 0.9])
    mirror["camera"].update(eye=[0, 2, 4], width=16, height=16)
    plain = Scene.from_dict({**mirror, "render": {"method": "raytrace", "fresnel": fresnel}})
    dark = copy.deepcopy(mirror)
    dark["materials"]["mirror"]["kr"] = 0.0
    image = render(plain)
    assert image.mean() > 0.05  # (lit floor, sphere and sky: not a black image)
    assert np.array_equal(image, render(Scene.from_dict({**dark, "render": plain.render.to_dict()})))
    glassy = copy.deepcopy(mirror)
    glassy["materials"]["mirror"]["ior"] = 1.5
    assert np.abs(render(Scene.from_dict({**glassy, "render": plain.render.to_dict()})) - render(plain)).max() > 1e-3


def test_not_an_object():
    with pytest.raises(SceneError, match=r"^scene: expected an object, got \[\]"):
        Scene.from_dict([])


def test_load_scene_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"camera": {"eye": [0, 0, 5],\n  "target": [0, 0, 0]\n  "objects": []}')
    with pytest.raises(SceneError, match=r"bad\.json: invalid JSON at line 3, column 3"):
        load_scene(bad)
    with pytest.raises(SceneError, match=r"missing\.json: scene file not found"):
        load_scene(tmp_path / "missing.json")
    dup = tmp_path / "dup.json"
    dup.write_text('{"camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "eye": [0, 0, 1]}, "objects": []}')
    with pytest.raises(SceneError) as refused:
        load_scene(dup)
    assert str(refused.value) == f"{dup}: duplicate key 'eye' in a JSON object"  # the file named once
    nan = tmp_path / "nan.json"
    nan.write_text(json.dumps(minimal()).replace('"radius": 1', '"radius": NaN'))
    with pytest.raises(SceneError, match=r"^objects\[0\]\.radius: must be finite, got nan \(in .*nan\.json\)$"):
        load_scene(nan)


def test_relative_paths_resolve_against_the_scene_file(tmp_path, monkeypatch):
    (tmp_path / "assets").mkdir()
    _make_assets(tmp_path / "assets")
    d = json.loads(DESIGN_EXAMPLE)
    d["objects"][2]["file"] = "assets/teapot.obj"
    d["materials"]["brick"]["texture"] = "assets/../assets/brick.png"
    (tmp_path / "scene.json").write_text(json.dumps(d))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    s = load_scene(tmp_path / "scene.json")
    assert s.objects[2].file == str(tmp_path / "assets" / "teapot.obj")
    assert s.materials["brick"].texture == str(tmp_path / "assets" / "brick.png")
    # from_dict without base_dir resolves against the current folder, and says so when missing
    with pytest.raises(SceneError, match=r"^materials\.brick\.texture: file not found: " + str(elsewhere)):
        Scene.from_dict(d)
    monkeypatch.chdir(tmp_path)
    assert Scene.from_dict(d) == s
    # absolute paths are kept
    d["objects"][2]["file"] = str(tmp_path / "assets" / "teapot.obj")
    d["materials"]["brick"]["texture"] = "../assets/brick.png"
    t = Scene.from_dict(d, base_dir=elsewhere)
    assert t.objects[2].file == d["objects"][2]["file"] and t == s


def test_with_overrides(example):
    d, folder = example
    s = Scene.from_dict(d, base_dir=folder)
    cam = {"eye": [3, 0, 0], "target": [0, 0, 0], "width": 64, "height": 48}
    t = s.with_overrides(camera=cam)
    assert t.camera == Camera(eye=(3, 0, 0), target=(0, 0, 0), width=64, height=48)  # whole block: defaults
    assert (t.lights, t.materials, t.objects, t.render, t.base_dir) == (s.lights, s.materials, s.objects,
                                                                        s.render, s.base_dir)
    u = s.with_overrides(lights=[{"type": "directional", "direction": [0, 0, -2]}])
    assert u.lights == (Light("directional", direction=(0, 0, -1)),) and u.camera == s.camera
    v = s.with_overrides(render={"method": "raytrace", "max_depth": 3})
    assert (v.render.method, v.render.max_depth, v.render.shading) == ("raytrace", 3, "phong")
    w = v.with_overrides(render={"spp": 4})
    assert (w.render.method, w.render.spp) == ("raytrace", 4)
    assert s.with_overrides() == s and s.render.method == "raster"  # s itself is unchanged
    assert s.with_overrides(camera=t.camera, lights=list(u.lights)) == dataclasses.replace(
        s, camera=t.camera, lights=u.lights)
    with pytest.raises(SceneError, match=r"^camera\.width: must be > 0"):
        s.with_overrides(camera={**cam, "width": 0})
    with pytest.raises(SceneError, match=r"^lights\[0\]\.direction: must not be zero-length"):
        s.with_overrides(lights=[{"type": "directional", "direction": [0, 0, 0]}])
    with pytest.raises(SceneError, match=r"^render: unknown key 'metod' \(did you mean 'method'\?\)"):
        s.with_overrides(render={"metod": "raytrace"})
    with pytest.raises(SceneError, match=r"^material: undefined material 'nope'"):
        s.material_index("nope")


# -- property: random mutations load or raise SceneError ------------------------------------------

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=8,
)


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from _paths(value, (*prefix, i))


@st.composite
def mutated_scenes(draw):
    """(scene dict, the paths it changed): 1 to 3 keys or items deleted, set or added."""
    d = json.loads(DESIGN_EXAMPLE)
    changed = []
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_paths(d))
        path = draw(st.sampled_from(paths))
        op = draw(st.sampled_from(["delete", "set", "add"]))
        if op == "set" and path:
            _set(d, path, draw(json_values))
        elif op == "delete" and path:
            _set(d, path, DELETE)
        else:
            parent = d
            for key in path:
                parent = parent[key]
            if isinstance(parent, dict):
                key = draw(st.text(min_size=1, max_size=8))
                parent[key] = draw(json_values)
                path = (*path, key)
            elif isinstance(parent, list):
                parent.append(draw(json_values))
                path = (*path, len(parent) - 1)
        changed.append(path)
    return d, changed


def field_name(path) -> str:
    """A dict path as the scene's messages write it: ("objects", 2, "radius") -> objects[2].radius."""
    out = ""
    for key in path:
        out += f"[{key}]" if isinstance(key, int) else (f".{key}" if out else str(key))
    return out


def names_a_changed_field(message: str, changed) -> bool:
    """The message starts with (or, for unknown keys at the top level, quotes) a field at, above or
    beside one that was changed; a changed material may also be named by the objects that use it
    (`objects[i].material`), a changed camera by the fields it constrains."""
    for path in changed:
        name = field_name(path)
        parent = field_name(path[:-1])
        if name and (message.startswith(name) or message.startswith(f"{parent}.") or message.startswith(f"{parent}[")):
            return True
        if parent and message.startswith(f"{parent}:"):
            return True
        if path and isinstance(path[-1], str) and repr(path[-1]) in message:
            return True
        if path[:1] == ("materials",) and re.match(r"objects\[\d+\]\.material: ", message):
            return True
    return False


@settings(derandomize=True, max_examples=200, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(mutation=mutated_scenes())
def test_mutated_scenes_load_or_raise_scene_error_naming_the_field(assets, mutation):
    d, changed = mutation
    try:
        s = Scene.from_dict(d, base_dir=assets)
    except SceneError as exc:
        assert names_a_changed_field(str(exc), changed), (str(exc), changed)
        return
    out = s.to_dict()
    json.dumps(out, allow_nan=False)
    assert Scene.from_dict(out) == s
