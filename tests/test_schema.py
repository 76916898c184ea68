"""The JSON Schema of scene files: generated from the field specs (the committed file and the
reference page are what the generator writes), valid, satisfied by every example scene, and
rejecting what `load_scene` rejects wherever a schema can say it."""

import json
import re
from pathlib import Path

import jsonschema
import pytest

import difflab
from difflab import Scene, SceneError
from difflab.demos import example_names, scene_path
from difflab.scene import SCHEMA_FILE, scene_schema
from difflab.scene.reference import docs_text, schema_text
from test_scene import BAD, DESIGN_EXAMPLE, _set

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "scene-format.md"
VALIDATOR = jsonschema.Draft202012Validator(scene_schema())


def test_committed_schema_and_reference_are_generated():
    """`python -m difflab.scene` has been run after the last change to a field spec."""
    assert SCHEMA_FILE.read_text(encoding="utf-8") == schema_text()
    current = DOCS.read_text(encoding="utf-8")
    assert docs_text(current) == current


def test_schema_is_valid_draft_2020_12():
    jsonschema.Draft202012Validator.check_schema(scene_schema())


@pytest.mark.parametrize("name", example_names())
def test_example_scenes_name_and_satisfy_the_schema(name):
    path = scene_path(name)
    data = json.loads(path.read_text(encoding="utf-8"))
    assert (path.parent / data["$schema"]).resolve() == SCHEMA_FILE
    assert list(VALIDATOR.iter_errors(data)) == []
    difflab.load_scene(path)


def doc_examples() -> list[dict]:
    blocks = re.findall(r"```json\n(.*?)```", DOCS.read_text(encoding="utf-8"), flags=re.S)
    return [json.loads(block) for block in blocks]


def test_the_reference_page_examples_satisfy_the_schema_and_load(tmp_path):
    examples = doc_examples()
    assert len(examples) == 2
    for data in examples:
        assert list(VALIDATOR.iter_errors(data)) == []
        difflab.Scene.from_dict(data, base_dir=tmp_path)


# Bad documents of tests/test_scene.py that load_scene rejects and a JSON Schema cannot: the reason.
SCHEMA_CANNOT = {
    (("objects", 0, "radius"), "nan"): "NaN is not JSON (Python's json module reads it)",
    (("objects", 0, "center"), "[0, nan, 0]"): "NaN is not JSON",
    (("objects", 1, "material"), "'foo'"): "a reference to another key's names",
    (("objects", 2, "file"), "'missing.obj'"): "a file on disk",
    (("materials", "brick", "texture"), "'nope.png'"): "a file on disk",
    (("objects", 2, "transform", "scale"), "0"): "a zero inside a grey-or-triple value",
    (("objects", 2, "transform", "matrix"), repr([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 1, 1])):
        "affine: the last row's values",
    (("camera", "width"), "300000"): "the product width * height",
    (("camera", "eye"), "[0, 0, 0]"): "eye != target: two fields compared",
    (("camera", "up"), "[0, 2, 10]"): "up not parallel to target - eye: geometry",
    (("camera", "far"), "0.05"): "far > near: two fields compared",
    (("fog", "end"), "1"): "end > start: two fields compared",
}


def cannot(path, value) -> bool:
    return (tuple(path), repr(value)) in SCHEMA_CANNOT


@pytest.mark.parametrize("path, value, message", BAD, ids=[f"{'.'.join(map(str, p))}={v!r:.20}" for p, v, _ in BAD])
def test_schema_rejects_what_load_scene_rejects(path, value, message):
    """Each bad document is rejected by the schema, except the listed rules a schema cannot state;
    those must still be accepted by it (so the list stays exact)."""
    d = json.loads(DESIGN_EXAMPLE)
    _set(d, path, value)
    errors = list(VALIDATOR.iter_errors(d))
    assert (not errors) == cannot(path, value), [e.message for e in errors]


def test_every_exception_is_a_case():
    assert set(SCHEMA_CANNOT) <= {(tuple(p), repr(v)) for p, v, _ in BAD}


@pytest.mark.parametrize("field, value", [("fov_y", 1e-7), ("ortho_height", 1e-10)])
def test_schema_holds_the_cameras_float32_floors(field, value):
    """fov_y >= 1e-6 and ortho_height >= 1e-9 (the camera's float32 matrices degenerate below) are
    ranges of their fields: the schema refuses what load_scene refuses (it once said only > 0)."""
    d = json.loads(DESIGN_EXAMPLE)
    d["camera"][field] = value
    assert any(field in e.json_path for e in VALIDATOR.iter_errors(d))
    with pytest.raises(SceneError, match=rf"camera\.{field}: must be >= "):
        Scene.from_dict(d)
