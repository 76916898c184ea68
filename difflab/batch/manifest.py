"""The batch manifest: JSON Lines, one fit per line, validated as a whole before any fit runs.

    {"name": "sphere-07", "scene": "scenes/sphere.json", "targets": ["shots/07.png"],
     "material": "red", "params": "kd,ks,n", "solver": {"solver": "lm", "max_steps": 100}}

Keys of a line (docs/batch.md is the reference):
    name      the output name: letters, digits, ".", "_", "-" (starts with a letter or digit), unique.
    scene     scene file (JSON).
    targets   an image file, or a list of image files and/or views {"image": FILE, "mask": FILE,
              "camera": {...}, "lights": [...]}, camera / lights replacing the scene's for that view.
    material  a material name or a list of names (default: every material an object uses).
    params    "ka,kd,ks,n" or a list of names (default: `difflab.fit.fit`'s, ka, kd, ks, n; m for n under
              torrance).
    method    "raster" (G-buffer) or "raytrace" (ray tree); default: chosen from the scene.
    init      parameter name -> starting value (a number or an RGB list).
    solver    options of the fit: see `OPTIONS` (max_depth: not with method "raster").
    edge_margin  pixels: count only those at least this far from every edge (`difflab.interior_mask`,
              as `difflab fit --edge-margin`); default: `fit_many`'s edge_margin, else 0 (every pixel
              of the masks).
Relative file paths resolve against the manifest's folder. Blank lines are skipped; line numbers
count every line of the file from 1.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import ManifestError
from ..vocabulary import METHODS

NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
KEYS = ("name", "scene", "targets", "material", "params", "method", "init", "solver", "edge_margin")
REQUIRED = ("name", "scene", "targets")
VIEW_KEYS = ("image", "mask", "camera", "lights")
NUMBER = (int, float)
# option -> accepted JSON types; the values are `difflab.fit.fit`'s keywords (and FitOptions fields),
# whose ranges the fit checks (a bad value fails that job, naming it)
OPTIONS = {
    "solver": str, "max_steps": int, "rtol": NUMBER, "atol": NUMBER, "learning_rate": NUMBER, "x64": bool,
    "rel_tol": NUMBER, "abs_tol": NUMBER, "per_channel": bool, "bounded": bool, "loss": str, "loss_scale": NUMBER,
    "sigma": NUMBER, "ceiling": (int, float, bool), "max_depth": int, "spp": int, "device": str,
}
RAYTRACE_ONLY = ("max_depth",)  # options the G-buffer image model does not read: refused with method "raster"


@dataclass(frozen=True)
class Job:
    """One valid manifest line: `spec` is the line with defaults filled in and paths made absolute
    (plain JSON data; a report records it, and a rerun redoes a job whose spec changed)."""

    line: int
    name: str
    spec: dict


@dataclass(frozen=True)
class Invalid:
    """One bad manifest line: its number, its name when it has a usable one, and what is wrong."""

    line: int
    name: str | None
    error: str


def _typed(value, types) -> bool:
    """isinstance that does not take a bool for a number (JSON true is not 1)."""
    return bool in _tuple(types) if isinstance(value, bool) else isinstance(value, types)


def _tuple(types) -> tuple:
    return types if isinstance(types, tuple) else (types,)


def _path(value, base: Path, where: str) -> str:
    if not (isinstance(value, str) and value):
        raise ManifestError(f"{where}: expected a file path, got {value!r}")
    return str((base / value).resolve()) if not os.path.isabs(value) else value


def _view(item, base: Path, where: str) -> dict:
    if isinstance(item, str):
        return {"image": _path(item, base, where)}
    if not isinstance(item, dict):
        raise ManifestError(f"{where}: expected an image path or a view object, got {type(item).__name__}")
    unknown = sorted(set(item) - set(VIEW_KEYS))
    if unknown:
        raise ManifestError(f"{where}: unknown key(s) {unknown}; known: {', '.join(VIEW_KEYS)}")
    view = {"image": _path(item.get("image"), base, f"{where}.image")}
    if "mask" in item:
        view["mask"] = _path(item["mask"], base, f"{where}.mask")
    if "camera" in item:
        if not isinstance(item["camera"], dict):
            raise ManifestError(f"{where}.camera: expected an object (a scene file's camera block)")
        view["camera"] = item["camera"]
    if "lights" in item:
        if not (isinstance(item["lights"], list) and all(isinstance(x, dict) for x in item["lights"])):
            raise ManifestError(f"{where}.lights: expected a list of light objects (a scene file's lights)")
        view["lights"] = item["lights"]
    return view


def _names(value, where: str) -> list[str]:
    """A comma-separated string or a list of distinct non-empty strings, as a list."""
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",")]
    if not (isinstance(value, list) and value and all(isinstance(v, str) and v for v in value)):
        raise ManifestError(f"{where}: expected a name or a non-empty list of names, got {value!r}")
    if len(set(value)) != len(value):
        raise ManifestError(f"{where}: names repeat: {value}")
    return value


def _solver(value) -> dict:
    if not isinstance(value, dict):
        raise ManifestError(f"solver: expected an object of options, got {type(value).__name__}")
    for key, option in value.items():
        if key not in OPTIONS:
            raise ManifestError(f"solver.{key}: unknown option; known: {', '.join(OPTIONS)}")
        if not _typed(option, OPTIONS[key]):
            names = " or ".join(t.__name__ for t in _tuple(OPTIONS[key]))
            raise ManifestError(f"solver.{key}: expected {names}, got {option!r}")
    return dict(value)


def _init(value) -> dict:
    if not isinstance(value, dict):
        raise ManifestError(f"init: expected an object name -> value, got {type(value).__name__}")
    for key, start in value.items():
        flat = start if isinstance(start, list) else [start]
        if not (flat and all(_typed(x, NUMBER) for x in flat)):
            raise ManifestError(f"init.{key}: expected a number or a list of numbers, got {start!r}")
    return dict(value)


def parse_line(data, base: Path) -> dict:
    """The spec of one manifest line (a parsed JSON value); raises ManifestError naming the key."""
    if not isinstance(data, dict):
        raise ManifestError(f"expected a JSON object, got {type(data).__name__}")
    unknown = sorted(set(data) - set(KEYS))
    if unknown:
        raise ManifestError(f"unknown key(s) {unknown}; known: {', '.join(KEYS)}")
    for key in REQUIRED:
        if key not in data:
            raise ManifestError(f"{key}: missing (required: {', '.join(REQUIRED)})")
    name = data["name"]
    if not (isinstance(name, str) and NAME.fullmatch(name)):
        raise ManifestError(f"name: expected letters, digits, '.', '_', '-' (at most 100, starting with a letter "
                            f"or digit), got {name!r}")
    if data.get("method", METHODS[0]) not in METHODS:
        raise ManifestError(f"method: expected one of {', '.join(METHODS)}, got {data['method']!r}")
    targets = data["targets"]
    targets = targets if isinstance(targets, list) else [targets]
    if not targets:
        raise ManifestError("targets: empty list")
    spec = {"name": name, "scene": _path(data["scene"], base, "scene"),
            "targets": [_view(t, base, f"targets[{i}]") for i, t in enumerate(targets)]}
    if "method" in data:
        spec["method"] = data["method"]
    if "material" in data:
        spec["material"] = _names(data["material"], "material")
    if "params" in data:
        spec["params"] = _names(data["params"], "params")
    spec["init"] = _init(data.get("init", {}))
    if "edge_margin" in data:  # (0 too: a line's own margin is kept over fit_many's edge_margin)
        margin = data["edge_margin"]
        if not (_typed(margin, int) and margin >= 0):
            raise ManifestError(f"edge_margin: expected an integer number of pixels >= 0, got {margin!r}")
        spec["edge_margin"] = margin
    spec["solver"] = _solver(data.get("solver", {}))
    for key in RAYTRACE_ONLY:
        if key in spec["solver"] and spec.get("method") == "raster":
            raise ManifestError(f"solver.{key}: does not apply to method 'raster' (the G-buffer has no secondary "
                                "rays; use method 'raytrace')")
    return spec


def _line_name(data) -> str | None:
    name = data.get("name") if isinstance(data, dict) else None
    return name if isinstance(name, str) and NAME.fullmatch(name) else None


def parse_manifest(lines, base: Path) -> tuple[list[Job], list[Invalid]]:
    """(valid jobs, invalid lines) of manifest lines (JSON text, or parsed objects), numbered from 1;
    a name already used by an earlier valid line makes the later line invalid."""
    jobs, invalid, seen = [], [], {}
    for number, text in enumerate(lines, start=1):
        if isinstance(text, str) and not text.strip():
            continue
        data = None
        try:
            data = json.loads(text) if isinstance(text, str) else text
            spec = parse_line(data, base)
            if spec["name"] in seen:
                raise ManifestError(f"name: {spec['name']!r} is already used on line {seen[spec['name']]}")
        except json.JSONDecodeError as exc:
            invalid.append(Invalid(number, None, f"not JSON: {exc}"))
            continue
        except ManifestError as exc:
            invalid.append(Invalid(number, _line_name(data), str(exc)))
            continue
        seen[spec["name"]] = number
        jobs.append(Job(number, spec["name"], spec))
    return jobs, invalid


def load_manifest(manifest) -> tuple[list[Job], list[Invalid]]:
    """Read a manifest: a JSON Lines file path, or a list of line objects (dicts; paths relative to the
    working directory). Returns (valid jobs, invalid lines).

    Raises ManifestError: the file cannot be read, or holds no line at all.
    """
    if isinstance(manifest, (str, os.PathLike)):
        path = Path(manifest)
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except FileNotFoundError:
            raise ManifestError(f"{path}: manifest not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ManifestError(f"{path}: cannot read manifest ({exc})") from None
        base = path.resolve().parent
    else:
        try:
            lines = list(manifest)
        except TypeError:
            raise ManifestError(f"manifest: expected a file path or a list of line objects, "
                                f"got {type(manifest).__name__}") from None
        base = Path.cwd()
    jobs, invalid = parse_manifest(lines, base)
    if not jobs and not invalid:
        raise ManifestError(f"{manifest if isinstance(manifest, (str, os.PathLike)) else 'manifest'}: no fits listed")
    return jobs, invalid
