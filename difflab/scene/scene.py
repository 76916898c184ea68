"""The Scene record, its JSON form, and scene files (load_scene / save_scene)."""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from ..errors import SceneError
from ._check import Vec3, check_keys, fail, join, mapping, sequence, show, string, vec3
from ._record import FrozenDict, Record, plain
from .material import Material
from ._spec import Spec, colour, spec_field
from .objects import OBJECT_TYPES, Mesh, Plane, SceneObject, Sphere, parse_object
from .view import MAX_PIXELS, Camera, Fog, Light, RenderSettings


def list_of(record) -> dict:
    """The JSON Schema of a list of `record` objects."""
    return {"description": f"list of {record.__name__}", "type": "array", "items": {"$ref": f"#/$defs/{record.__name__}"}}


#: The optional top-level key naming the file's JSON Schema (for editors); checked to be a string, not kept.
SCHEMA_KEY = "$schema"


def _lights(value, path: str) -> tuple[Light, ...]:
    items = sequence(value, path)
    return tuple(x if isinstance(x, Light) else Light.parse(x, f"{path}[{i}]") for i, x in enumerate(items))


@dataclass(frozen=True)
class Scene(Record):
    """A whole scene: camera, lights, named materials, objects, fog and render settings. Every
    object names a defined material. In Python, `lights` and `objects` are tuples and `materials` a
    read-only mapping; `base_dir` is the folder relative paths were resolved against (informational:
    not compared, not written; file paths are stored absolute)."""

    camera: Camera = spec_field(Spec("record", "the view", record=Camera))
    ambient: Vec3 = spec_field(colour("ambient light Ia"), (0.0, 0.0, 0.0))
    background: Vec3 = spec_field(colour("colour of rays that hit nothing"), (0.0, 0.0, 0.0))
    lights: tuple[Light, ...] = spec_field(Spec("custom", "the lights", json=list_of(Light)), ())
    materials: Mapping[str, Material] = spec_field(
        Spec("custom", "named materials; an object's material id is its name's position here",
             json={"description": "object: name -> Material", "type": "object",
                   "additionalProperties": {"$ref": "#/$defs/Material"}}), FrozenDict())
    objects: tuple[SceneObject, ...] = spec_field(
        Spec("custom", "the objects",
             json={"description": "list of Sphere | Plane | Mesh (by \"type\")", "type": "array",
                   "items": {"oneOf": [{"$ref": f"#/$defs/{t.__name__}"} for t in OBJECT_TYPES.values()]}}), ())
    fog: Fog | None = spec_field(Spec("record", "depth cueing / fog", record=Fog, nullable=True), None)
    render: RenderSettings = spec_field(Spec("record", "render settings", record=RenderSettings), RenderSettings())
    base_dir: str | None = field(default=None, compare=False)

    _PATH: ClassVar[str] = ""
    #: Keys a scene file must give (the others have defaults).
    FILE_REQUIRED: ClassVar[tuple[str, ...]] = ("camera", "objects")

    @classmethod
    def _check(cls, v: dict, path: str = "") -> dict:
        if not isinstance(v["camera"], Camera):
            fail("camera", f"expected a Camera, got {v['camera']!r:.60}")
        lights = tuple(sequence(v["lights"], "lights"))
        for i, light in enumerate(lights):
            if not isinstance(light, Light):
                fail(f"lights[{i}]", f"expected a Light, got {light!r:.60}")
        materials = mapping(v["materials"], "materials")
        for name, material in materials.items():
            string(name, "materials")
            if not isinstance(material, Material):
                fail(join("materials", name), f"expected a Material, got {material!r:.60}")
        objects = tuple(sequence(v["objects"], "objects"))
        for i, obj in enumerate(objects):
            if not isinstance(obj, (Sphere, Plane, Mesh)):
                fail(f"objects[{i}]", f"expected a Sphere, Plane or Mesh, got {obj!r:.60}")
            if obj.material not in materials:
                defined = ", ".join(materials) or "none"
                fail(f"objects[{i}].material", f"undefined material {obj.material!r} (defined: {defined})")
        if v["fog"] is not None and not isinstance(v["fog"], Fog):
            fail("fog", f"expected a Fog or None, got {v['fog']!r:.60}")
        if not isinstance(v["render"], RenderSettings):
            fail("render", f"expected RenderSettings, got {v['render']!r:.60}")
        camera, spp = v["camera"], v["render"].spp
        if camera.width * camera.height * spp > MAX_PIXELS:
            fail("render.spp", f"{camera.width} x {camera.height} pixels at spp {spp} is "
                 f"{camera.width * camera.height * spp} samples, over the limit of 64 M samples ({MAX_PIXELS}; below "
                 "it the memory budget applies)")
        base_dir = v["base_dir"]
        if base_dir is not None:
            base_dir = os.path.abspath(os.fspath(base_dir))
        return dict(
            camera=v["camera"],
            ambient=vec3(v["ambient"], "ambient", grey=True, ge=0),
            background=vec3(v["background"], "background", grey=True, ge=0),
            lights=lights, materials=FrozenDict(materials), objects=objects,
            fog=v["fog"], render=v["render"], base_dir=base_dir,
        )

    # -- JSON form ------------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, d, base_dir: str | os.PathLike | None = None) -> Scene:
        """Validate a scene in its JSON form (see DESIGN.md); relative paths resolve against `base_dir`
        (default: the current folder). Raises SceneError naming the field."""
        if base_dir is not None:
            base_dir = os.path.abspath(os.fspath(base_dir))
        d = mapping(d, "scene")
        check_keys(d, "", (SCHEMA_KEY, *(f.name for f in cls.spec_fields())), required=cls.FILE_REQUIRED)
        if SCHEMA_KEY in d:
            string(d[SCHEMA_KEY], SCHEMA_KEY)
        materials = mapping(d.get("materials", {}), "materials")
        fog = d.get("fog")
        return cls(
            camera=Camera.parse(d["camera"], "camera"),
            ambient=vec3(d.get("ambient", 0.0), "ambient", grey=True, ge=0),
            background=vec3(d.get("background", 0.0), "background", grey=True, ge=0),
            lights=_lights(d.get("lights", []), "lights"),
            materials={string(name, "materials"): Material.parse(m, join("materials", name), base_dir)
                       for name, m in materials.items()},
            objects=tuple(parse_object(o, f"objects[{i}]", base_dir)
                          for i, o in enumerate(sequence(d["objects"], "objects"))),
            fog=None if fog is None else Fog.parse(fog, "fog"),
            render=RenderSettings.parse(d.get("render", {}), "render"),
            base_dir=base_dir,
        )

    def to_dict(self) -> dict:
        """The scene as a plain JSON-able dict: every field explicit, lists not tuples, absolute paths.
        `Scene.from_dict(s.to_dict()) == s`."""
        return {f.name: plain(getattr(self, f.name)) for f in self.spec_fields()}

    # -- queries and variants -------------------------------------------------------------------

    @property
    def material_names(self) -> tuple[str, ...]:
        """Material names in file order; an object's material id is the index of its name here."""
        return tuple(self.materials)

    def material_index(self, name: str) -> int:
        """The index of material `name` in `material_names`; SceneError if undefined."""
        names = self.material_names
        if name not in names:
            raise SceneError(f"material: undefined material {name!r} (defined: {', '.join(names) or 'none'})")
        return names.index(name)

    def with_overrides(self, camera=None, lights=None, render=None) -> Scene:
        """A new validated scene with a whole camera block and/or a whole lights list replaced (in the
        scene file's format, or as Camera / Light objects) and/or some render settings overridden
        (a partial dict of the "render" block, or a RenderSettings)."""
        changes = {}
        if camera is not None:
            changes["camera"] = camera if isinstance(camera, Camera) else Camera.parse(camera, "camera")
        if lights is not None:
            changes["lights"] = _lights(lights, "lights")
        if render is not None:
            if not isinstance(render, RenderSettings):
                render = RenderSettings.parse({**self.render.to_dict(), **mapping(render, "render")}, "render")
            changes["render"] = render
        return dataclasses.replace(self, **changes)


def _no_duplicates(pairs):
    """json's object_pairs_hook: a dict, or SceneError for a key given twice (`load_scene` names the file)."""
    out = {}
    for key, value in pairs:
        if key in out:
            raise SceneError(f"duplicate key {show(key)} in a JSON object")
        out[key] = value
    return out


#: Largest scene file read (bytes): scene files are small; anything bigger is not one.
MAX_SCENE_BYTES = 64 * 1024 * 1024
#: Integer literals longer than this many digits are read as floats (so that a 5,000-digit number
#: becomes inf and its field reports "must be finite" instead of Python's int-conversion limit).
MAX_INT_DIGITS = 40


def _parse_int(text: str):
    return int(text) if len(text) <= MAX_INT_DIGITS else float(text)


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a scene file (JSON). Relative paths inside resolve against the file's folder.

    Only a regular file of at most MAX_SCENE_BYTES is read (a device, FIFO or folder is refused at
    once). Raises SceneError: for bad JSON with the file, line and column; for invalid content with
    the field path first and the file appended.
    """
    from ..files import file_path, read_regular_file
    from ..limits import short_path

    path = file_path(path, "scene", SceneError)
    data = read_regular_file(path, MAX_SCENE_BYTES, SceneError, "scene file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(f"{short_path(path)}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        data = json.loads(text, object_pairs_hook=_no_duplicates, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise SceneError(f"{path}: invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except SceneError as exc:  # (a ValueError: before the clause below, which would name the file twice)
        raise SceneError(f"{path}: {exc}") from None
    except (RecursionError, ValueError) as exc:
        raise SceneError(f"{path}: invalid JSON: {'nested too deeply' if isinstance(exc, RecursionError) else exc}") from None
    try:
        return Scene.from_dict(data, base_dir=path.parent.absolute())
    except SceneError as exc:
        raise SceneError(f"{exc} (in {path})") from None


def save_scene(scene: Scene, path: str | os.PathLike) -> Path:
    """Write `scene.to_dict()` as indented JSON, atomically (paths inside are absolute)."""
    from ..files import write_json_atomic

    if not isinstance(scene, Scene):
        raise SceneError(f"scene: expected a Scene, got {type(scene).__name__}")
    write_json_atomic(path, scene.to_dict())
    return Path(path)
