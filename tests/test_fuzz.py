"""Our own fuzzing: hostile scene documents and mesh files either render to finite pixels or raise a
DifflabError whose message names the field (or the file) -- never another exception, a warning, a
NaN pixel, or a render that runs unbounded (the budgets are set low here, so every accepted render is
small: at most 64 MiB and 10^6 rays).

The CI profile is derandomized with a fixed number of examples. For a longer local run:

    DIFFLAB_FUZZ=long pytest tests/test_fuzz.py      # 2,000 random examples per property (300 fits)
"""

import copy
import json
import math
import os
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from difflab import DifflabError, Scene, fit_material, render

PROFILES = {
    "ci": dict(derandomize=True, max_examples=60, deadline=None, database=None),
    "long": dict(derandomize=False, max_examples=2000, deadline=None),
}
PROFILE = os.environ.get("DIFFLAB_FUZZ", "ci")
FUZZ = settings(**PROFILES[PROFILE], suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
FIT_FUZZ = settings(FUZZ, max_examples={"ci": 12, "long": 300}[PROFILE])  # each fit compiles: ~1 s

BASE = {
    "camera": {"eye": [0, 1, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40, "width": 8, "height": 6,
               "near": 0.1, "far": 50, "projection": "perspective", "ortho_height": 2},
    "ambient": [0.1, 0.1, 0.1],
    "background": [0, 0, 0.1],
    "lights": [{"type": "point", "position": [3, 4, 5], "intensity": [1, 1, 1], "attenuation": [1, 0.1, 0]},
               {"type": "spot", "position": [0, 4, 0], "direction": [0, -1, 0], "cutoff_deg": 30, "exponent": 4}],
    "materials": {"red": {"ka": [0.1, 0, 0], "kd": [0.7, 0.1, 0.1], "ks": 0.5, "n": 32},
                  "glass": {"kd": 0, "ks": 0.5, "n": 100, "kr": 0.2, "kt": 0.8, "ior": 1.5,
                            "absorption": [0.1, 0, 0]},
                  "floor": {"kd": 0.8, "checker": {"size": 1.0, "ka2": 0, "kd2": 0.1}}},
    "objects": [{"type": "sphere", "center": [0, 0.5, 0], "radius": 0.5, "material": "glass"},
                {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"},
                {"type": "mesh", "builtin": "teapot", "resolution": 2, "material": "red",
                 "transform": {"translate": [1, 0, 0], "rotate_deg": [0, 30, 0], "scale": 0.3}}],
    "fog": {"mode": "linear", "color": 0.5, "start": 5, "end": 20},
    "render": {"method": "raster", "shading": "phong", "max_depth": 3, "spp": 1},
}

#: Values a hostile user puts anywhere: extremes of float32 and float64, wrong types, huge integers.
EXTREMES = [0, -1, 1, 2, 1e-300, 1e-30, 1e-7, 1e6, 1e12, 1e13, 1e30, 3e38, -3e38, 1e39, 1e308, 10 ** 400,
            math.nan, math.inf, -math.inf, True, None, "", "x" * 300, [], {}, [1, 2], [0, 0, 0], [1e30] * 3,
            [3e38, 0, 0], {"a": 1}, 64, 65, 4096, 2 ** 31, "teapot", "raytrace", "schlick"]
VALUES = st.one_of(st.sampled_from(EXTREMES), st.floats(-10, 10, allow_nan=False), st.integers(-3, 70))

KEYWORDS = ["method", "shading", "specular", "shadows", "max_depth", "spp", "fresnel", "transparent_shadows",
            "clamp_vertex_colors", "interpolation", "cull_backfaces", "adaptive_threshold", "sampling", "width",
            "height", "threads", "device", "colour"]
#: Where a message may start: a field of the scene, a render option, or a file path.
FIELD = re.compile(r"^(scene|camera|ambient|background|lights|materials|objects|fog|render|record_tree|"
                   r"textures|DIFFLAB_\w+|/|(" + "|".join(KEYWORDS) + r")\b)")


def paths(doc, prefix=()):
    """Every (container, key) path in a JSON document."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        yield prefix + (key,)
        yield from paths(value, prefix + (key,))


def mutate(doc, data) -> dict:
    """Up to three random edits: a value replaced, a key deleted, or an unknown key added."""
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 3), label="edits")):
        where = data.draw(st.sampled_from(list(paths(doc))), label="path")
        parent = doc
        for key in where[:-1]:
            parent = parent[key]
        action = data.draw(st.sampled_from(["replace", "replace", "replace", "delete", "add"]), label="action")
        if action == "replace":
            parent[where[-1]] = data.draw(VALUES, label="value")
        elif action == "delete" and isinstance(parent, dict):
            del parent[where[-1]]
        elif isinstance(parent, dict):
            parent[data.draw(st.sampled_from(["k" * 500, "colour", "type", "radius"]), label="key")] = 1
    return doc


@pytest.fixture
def small_budgets(monkeypatch):
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "64M")
    monkeypatch.setenv("DIFFLAB_MAX_RAYS", str(10 ** 6))


def check(doc, what=FIELD, **keywords):
    """Render `doc`: finite pixels, or a DifflabError whose message starts with a field or file."""
    try:
        image = render(doc, **keywords)
    except DifflabError as exc:
        message = str(exc)
        event(f"{type(exc).__name__}: {message.split(':')[0][:30]}")
        assert what.match(message), message
        assert len(message) <= DifflabError.MAX_MESSAGE and "\n" not in message.split(" [...] ")[0][:80], message
        return "error"
    assert image.dtype == np.float32 and image.shape[2] == 3
    assert np.isfinite(image).all()
    event("image")
    return "image"


@FUZZ
@given(data=st.data(), method=st.sampled_from(["raster", "raytrace"]))
def test_mutated_scene_documents_render_or_name_the_field(small_budgets, data, method):
    doc = copy.deepcopy(BASE)
    doc["render"]["method"] = method
    check(mutate(doc, data))


def test_the_unmutated_fuzz_scene_renders(small_budgets):
    for method in ("raster", "raytrace"):
        image = render({**BASE, "render": {**BASE["render"], "method": method}})
        assert image.shape == (6, 8, 3) and np.isfinite(image).all() and image.max() > 0.05


COORD = st.floats(-2, 2, allow_nan=False).map(lambda x: f"{x:.3g}")
@FUZZ
@given(keywords=st.dictionaries(st.sampled_from(KEYWORDS), VALUES, max_size=3),
       method=st.sampled_from(["raster", "raytrace"]))
def test_hostile_keyword_arguments_render_or_name_the_argument(small_budgets, keywords, method):
    doc = copy.deepcopy(BASE)
    doc["render"]["method"] = method
    check(doc, **{"method": method, **keywords})


OBJ_LINES = st.one_of(
    st.builds(lambda *xyz: "v " + " ".join(xyz), COORD, COORD, COORD),
    st.builds(lambda *ijk: "f " + " ".join(ijk), *[st.sampled_from(["1", "2", "3", "4", "-1", "-2"])] * 3),
    st.builds(lambda xs: "v " + " ".join(xs), st.lists(st.sampled_from(
        ["0", "1", "-1", "0.5", "1e39", "1e13", "-3e38", "nan", "inf", "x", "1e-45", "2"]), min_size=0, max_size=4)),
    st.builds(lambda ix: "f " + " ".join(ix), st.lists(st.sampled_from(
        ["1", "2", "3", "4", "-1", "0", "99", "1/1", "2//2", "3/3/3", "a"]), min_size=0, max_size=5)),
    st.sampled_from(["# comment", "", "vn 0 1 0", "vt 0.5 0.5", "o part", "g group", "usemtl x", "s off", "junk"]),
)
GOOD_OBJ = ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0", "f 1 2 3", "f 2 4 3"]


@FUZZ
@given(lines=st.lists(OBJ_LINES, max_size=12), keep=st.booleans(), method=st.sampled_from(["raster", "raytrace"]))
def test_hostile_obj_files_render_or_name_the_file(small_budgets, tmp_path, lines, keep, method):
    path = tmp_path / "fuzz.obj"
    path.write_text("\n".join((GOOD_OBJ if keep else []) + lines) + "\n")
    doc = copy.deepcopy(BASE)
    doc["render"]["method"] = method
    doc["objects"][2] = {"type": "mesh", "file": str(path), "material": "red", "smooth": True}
    check(doc, re.compile(r"^(objects\[2\] \(.*fuzz\.obj\): .*fuzz\.obj|objects\[2\]\.transform: )"))


FIT_KEYWORDS = ["params", "material", "init", "solver", "max_steps", "loss", "loss_scale", "per_channel", "bounded",
                "masks", "weights", "x64", "sigma", "colour"]
FIT_VALUES = st.one_of(VALUES, st.sampled_from([("kd",), ["kd", 3], {"kd": "abc"}, {"kd": math.nan}, {"zz": 1},
                                                "kd,ks", ("n",), [np.zeros((6, 8))], [np.ones((6, 8)) * -1]]))
FIT_TARGETS = st.sampled_from(["same", "huge", "nan", "complex", "small", "negative"])


@FIT_FUZZ
@given(keywords=st.dictionaries(st.sampled_from(FIT_KEYWORDS), FIT_VALUES, max_size=2), target=FIT_TARGETS)
def test_hostile_fit_arguments_fit_or_name_the_argument(small_budgets, keywords, target):
    """A fit returns finite numbers (whatever its result code), or raises a DifflabError naming the argument."""
    doc = {**BASE, "objects": BASE["objects"][:2], "fog": None}
    image = render(doc)
    targets = {"same": image, "huge": image * 1e30, "nan": image * np.nan, "complex": image.astype(complex),
               "small": image[:2, :2], "negative": -image}[target]
    try:
        result = fit_material(doc, [targets], **{"material": "floor", "params": ("kd",), "max_steps": 3, **keywords})
    except DifflabError as exc:
        assert re.match(r"^(targets|" + "|".join(FIT_KEYWORDS) + r"|fit|scene|no fit|unknown argument)", str(exc)), \
            str(exc)
        event(f"{type(exc).__name__}: {str(exc).split(':')[0][:30]}")
        return
    event(f"result {result.result}")
    values = np.concatenate([np.ravel(v) for v in result.params.values()])
    assert np.isfinite(values).all() or result.result != "successful"


PNG_HEAD = b"\x89PNG\r\n\x1a\n"
NPY_HEAD = b"\x93NUMPY\x01\x00"


@FUZZ
@given(head=st.sampled_from([b"", PNG_HEAD, NPY_HEAD]), body=st.binary(max_size=200),
       suffix=st.sampled_from([".png", ".npy", ".jpg"]), method=st.sampled_from(["raster", "raytrace"]))
def test_hostile_texture_files_render_or_name_the_file(small_budgets, tmp_path, head, body, suffix, method):
    path = tmp_path / f"fuzz{suffix}"
    path.write_bytes(head + body)
    doc = copy.deepcopy(BASE)
    doc["render"]["method"] = method
    doc["materials"]["red"]["texture"] = str(path)
    check(doc, re.compile(r"^.*fuzz\.(png|npy|jpg)"))


def test_scene_documents_round_trip_their_json_form():
    """The base document is valid: from_dict -> to_dict -> from_dict gives the same scene."""
    scene = Scene.from_dict(json.loads(json.dumps(BASE)))
    assert Scene.from_dict(scene.to_dict()) == scene
