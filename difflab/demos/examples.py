"""The example scenes shipped inside the package (`difflab/demos/scenes/*.json`), found through the
package so that they work from a wheel install in any folder."""

from __future__ import annotations

from pathlib import Path

from ..errors import SceneError
from ..scene import Scene, load_scene
from ..scene._check import suggestion

SCENE_FOLDER = Path(__file__).resolve().parent / "scenes"


def example_names() -> tuple[str, ...]:
    """The names of the shipped example scenes (file stems), sorted."""
    return tuple(sorted(p.stem for p in SCENE_FOLDER.glob("*.json")))


def scene_path(name: str) -> Path:
    """The path of the shipped example scene `name` (e.g. "lecture_teapot"); SceneError if unknown."""
    names = example_names()
    if not isinstance(name, str) or name not in names:
        raise SceneError(f"example scene: unknown name {name!r}{suggestion(name, names)}; "
                         f"known: {', '.join(names)}")
    return SCENE_FOLDER / f"{name}.json"


def example_scene(name: str, *, width: int | None = None, height: int | None = None) -> Scene:
    """The shipped example scene `name` as a validated Scene, optionally at width x height pixels."""
    scene = load_scene(scene_path(name))
    size = {k: v for k, v in (("width", width), ("height", height)) if v is not None}
    return scene.with_overrides(camera={**scene.camera.to_dict(), **size}) if size else scene
