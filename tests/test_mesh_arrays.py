"""Meshes given as arrays from Python: validated as file meshes are, round-tripped through the JSON
form, and rendered exactly as the same mesh read from a file."""

import copy
import pickle

import numpy as np
import pytest

import difflab
from conftest import POLYGONS, polygon_obj, scene_dict
from difflab.errors import SceneError

# A unit quad facing +z as two counter-clockwise triangles, with uvs.
VERTICES = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
FACES = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
UVS = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)


def quad_object(**arrays):
    return {"type": "mesh", "material": "m", "vertices": VERTICES, "faces": FACES, **arrays}


def test_arrays_are_stored_read_only_in_float64_and_int64():
    mesh = difflab.Mesh(material="m", vertices=VERTICES, faces=FACES, uvs=UVS)
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64 and mesh.normals is None
    assert not mesh.vertices.flags.writeable and not mesh.faces.flags.writeable
    assert np.array_equal(mesh.vertices, VERTICES) and np.array_equal(mesh.uvs, UVS)


@pytest.mark.parametrize("copy_of", [lambda m: pickle.loads(pickle.dumps(m)), copy.deepcopy],
                         ids=["pickle", "deepcopy"])
def test_copies_are_equal_and_stay_read_only(copy_of):
    mesh = difflab.Mesh(material="m", vertices=VERTICES, faces=FACES, normals=np.tile([0.0, 0.0, 1.0], (4, 1)))
    again = copy_of(mesh)
    assert again == mesh and hash(again) == hash(mesh)
    assert not any(getattr(again, k).flags.writeable for k in ("vertices", "faces", "normals"))


def test_equality_hash_and_json_round_trip():
    scene = difflab.Scene.from_dict(scene_dict([quad_object(uvs=UVS)], {"m": {}}))
    again = difflab.Scene.from_dict(scene.to_dict())
    assert again == scene and hash(again) == hash(scene)
    d = scene.to_dict()["objects"][0]
    assert d["vertices"] == VERTICES.tolist() and d["faces"] == FACES.tolist() and "file" not in d
    moved = VERTICES + np.array([0, 0, 1e-6], np.float32)
    assert difflab.Mesh(material="m", vertices=moved, faces=FACES) != scene.objects[0]


BAD = [
    ({"vertices": [[0, 0, 0], [1, 0, 0]], "faces": [[0, 1, 2]]},
     r"objects\[0\]: face 0 has index out of range \[0, 1, 2\] \(mesh has 2 vertices\)"),
    ({"vertices": [[0, 0, float("nan")], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]]},
     r"objects\[0\]: vertex 0 is not finite"),
    ({"vertices": [[0, 0], [1, 0], [0, 1]], "faces": [[0, 1, 2]]},
     r"objects\[0\]: vertices must have shape \(V, 3\), got \(3, 2\)"),
    ({"vertices": VERTICES, "faces": np.zeros((0, 3), int)}, r"objects\[0\]: mesh has no faces"),
    ({"vertices": VERTICES, "faces": [[0, 1, 2.5]]}, r"objects\[0\]: face indices must be integers"),
    ({"vertices": VERTICES}, r"objects\[0\]\.faces: required with 'vertices'"),
    ({"vertices": VERTICES, "faces": FACES, "uvs": UVS[:3]}, r"objects\[0\]: uvs must have shape \(4, 2\), got \(3, 2\)"),
    ({"vertices": VERTICES, "faces": FACES, "normals": np.ones((4, 3)) * np.inf},
     r"objects\[0\]: normals are not all finite"),
    ({"vertices": VERTICES, "faces": FACES, "normals": [[0, 0, 1], [0, 0, 1], [0, 0, 0], [0, 0, 1]]},
     r"objects\[0\]\.normals\[2\]: must not be zero-length \(a normal is a direction\)$"),
    ({"builtin": "quad", "uvs": UVS}, r"objects\[0\]\.uvs: only used with 'vertices'"),
]


@pytest.mark.parametrize("fields, message", BAD, ids=[m.split(": ")[1][:30] for _, m in BAD])
def test_bad_arrays_raise_scene_error_naming_the_object(fields, message):
    with pytest.raises(SceneError, match="^" + message):
        difflab.Scene.from_dict(scene_dict([{"type": "mesh", "material": "m", **fields}], {"m": {}}))


def obj_text(vertices, faces, uvs) -> str:
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [f"vt {u} {v}" for u, v in uvs]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}" for i in face) for face in faces]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("method", ["raster", "raytrace"])
def test_arrays_render_exactly_as_the_same_mesh_from_a_file(tmp_path, method):
    """A textured quad tilted toward a point light: arrays and OBJ give the same image, bit for bit."""
    texture = tmp_path / "grid.png"
    difflab.save_image(texture, np.indices((8, 8)).sum(axis=0)[..., None].repeat(3, -1).astype(np.float32) % 2)
    (tmp_path / "quad.obj").write_text(obj_text(VERTICES, FACES, UVS))
    material = {"m": {"ka": [0.1, 0.1, 0.1], "kd": [1, 1, 1], "ks": [0.3, 0.3, 0.3], "n": 20,
                      "texture": str(texture), "filter": "nearest"}}
    lights = [{"type": "point", "position": [1, 2, 4], "intensity": [1, 1, 1]}]
    transform = {"rotate_deg": [-30, 20, 0]}
    from_arrays = scene_dict([quad_object(uvs=UVS, transform=transform)], material, lights=lights,
                             ambient=(0.2, 0.2, 0.2))
    from_file = scene_dict([{"type": "mesh", "material": "m", "file": str(tmp_path / "quad.obj"),
                             "transform": transform}], material, lights=lights, ambient=(0.2, 0.2, 0.2))
    a = difflab.render(from_arrays, method=method)
    b = difflab.render(from_file, method=method)
    assert np.array_equal(a, b)
    covered = a.max(axis=-1) > 0
    assert 0.3 < covered.mean() < 0.9  # the quad covers part of the view, so the check compares something


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("name", sorted(POLYGONS))
def test_a_polygon_face_from_a_file_shows_its_texture_the_right_way_up(tmp_path, method, name):
    """A quad / pentagon OBJ face with per-corner `vt` over [-1, 1]^2, textured (nearest) with a 2 x 2
    image, red green / blue white: each quarter of the face shows its texel (its uvs once read as
    none: the whole face showed uv (0, 0)'s blue)."""
    texels = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]], np.float32)  # row 0 at the top
    difflab.save_image(tmp_path / "tex.png", texels)
    (tmp_path / "face.obj").write_text(polygon_obj(POLYGONS[name]))
    scene = scene_dict([{"type": "mesh", "material": "m", "file": str(tmp_path / "face.obj")}],
                       {"m": {"ka": [1, 1, 1], "kd": [0, 0, 0], "texture": str(tmp_path / "tex.png"),
                              "texture_target": "ka", "filter": "nearest"}}, ambient=(1, 1, 1),
                       camera={"eye": [0, 0, 3], "target": [0, 0, 0], "fov_y": 45, "width": 32, "height": 32})
    image = difflab.render(scene, method=method)
    # the face spans pixels ~3..28 (half-width 1 at distance 3: 16 / (3 tan 22.5 deg) = 12.9 pixels)
    quarters = image[[9, 9, 22, 22], [9, 22, 9, 22]]  # top-left, top-right, bottom-left, bottom-right
    np.testing.assert_allclose(quarters, texels.reshape(4, 3), atol=1e-6)


@pytest.mark.parametrize("source", ["arrays", "file", "teapot"])
def test_a_textured_material_on_a_mesh_without_uvs_is_a_scene_error(tmp_path, source):
    """A mesh with no texture coordinates under an image texture once rendered uv (0, 0)
    everywhere (one texel's colour, flat grey under bilinear filtering): now a SceneError naming
    the object, its file and the material, from either renderer."""
    texture = tmp_path / "tex.png"
    difflab.save_image(texture, np.indices((2, 2)).sum(axis=0)[..., None].repeat(3, -1).astype(np.float32) % 2)
    (tmp_path / "quad.obj").write_text("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3 4\n")
    obj = {"arrays": quad_object(), "file": {"type": "mesh", "material": "m", "file": str(tmp_path / "quad.obj")},
           "teapot": {"type": "mesh", "material": "m", "builtin": "teapot", "resolution": 2}}[source]
    label = "objects[0]" + (f" ({tmp_path / 'quad.obj'})" if source == "file" else "")
    scene = scene_dict([obj], {"m": {"kd": [1, 1, 1], "texture": str(texture)}}, ambient=(1, 1, 1))
    for method in ("raster", "raytrace"):
        with pytest.raises(SceneError) as caught:
            difflab.render(scene, method=method)
        assert str(caught.value) == (f"{label}: material 'm' has a texture ({texture}) but the mesh has no uvs "
                                     "(texture coordinates: OBJ vt lines, `uvs` with `vertices`, or a builtin "
                                     "other than the teapot)")
    assert difflab.render(scene_dict([obj], {"m": {"kd": [1, 1, 1]}}, ambient=(1, 1, 1))).shape == (32, 32, 3)
