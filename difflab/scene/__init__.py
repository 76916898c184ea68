"""Plain, validated scene data and its JSON form (no Warp, no JAX).

Every record is a frozen dataclass validated on construction; `Scene.from_dict` / `load_scene` raise
`difflab.errors.SceneError` with a message that starts with the field path, e.g.
`objects[2].radius: must be > 0, got -1`. Unknown keys, wrong types, bools as numbers, NaN/inf,
negative coefficients, zero-length directions, missing files and undefined materials are errors.
Colours may be one number meaning (x, x, x); `to_dict` always writes triples, lists and absolute
paths.

Every key, its type, default and unit: docs/scene-format.md, generated (with the JSON Schema
`SCHEMA_FILE`, `scene_schema()`) from the field specs that validate (`python -m difflab.scene`).
"""

from .material import TEXTURE_FILTERS, TEXTURE_TARGETS, TEXTURE_WRAPS, Checker, Material
from .objects import BUILTIN_MESHES, Mesh, Plane, SceneObject, Sphere, Transform
from .reference import SCHEMA_FILE, scene_schema
from .scene import Scene, load_scene, save_scene
from .view import MAX_PIXELS, Camera, Fog, Light, RenderSettings

__all__ = [
    "BUILTIN_MESHES", "MAX_PIXELS", "SCHEMA_FILE", "scene_schema", "TEXTURE_FILTERS", "TEXTURE_TARGETS", "TEXTURE_WRAPS",
    "Camera", "Checker", "Fog", "Light", "Material", "Mesh", "Plane", "RenderSettings", "Scene",
    "SceneObject", "Sphere", "Transform", "load_scene", "save_scene",
]
