"""A fractal terrain as a scene the renderers can draw: one OBJ per height band, one material each."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..geometry import TriMesh, save_mesh
from .terrain import TERRAIN_COLORS, TERRAIN_LEVELS, terrain_parts


def terrain_scene(mesh: TriMesh, folder: str | os.PathLike, levels=TERRAIN_LEVELS, *, width: int = 320,
                  height: int = 240, eye=(9.0, 6.0, 11.0), target=(0.0, -0.5, 0.0),
                  sun=(-1.0, -0.7, -0.4)) -> dict:
    """Write the terrain's bands as `folder/terrain_<band>.obj` (atomically) and return a scene dict.

    The scene (the scene-file format) has one smooth mesh object per band with its diffuse colour
    from `TERRAIN_COLORS` (water a little glossy), a low sun (directional light along `sun`) that
    casts shadows, a sky-blue ambient and background, and a camera from `eye` to `target`.
    Render it with `difflab.render(scene, method="raster" | "raytrace")`.
    """
    folder = Path(folder)
    materials, objects = {}, []
    for band, part in terrain_parts(mesh, levels).items():
        path = folder / f"terrain_{band}.obj"
        save_mesh(path, part)
        glossy = band == "water"
        materials[band] = {"ka": list(TERRAIN_COLORS[band]), "kd": list(TERRAIN_COLORS[band]),
                           "ks": [0.4] * 3 if glossy else [0.0] * 3, "n": 40 if glossy else 1}
        objects.append({"type": "mesh", "file": str(path.resolve()), "material": band, "smooth": True})
    return {
        "camera": {"eye": list(eye), "target": list(target), "fov_y": 40, "width": width, "height": height},
        "ambient": [0.25, 0.28, 0.35],
        "background": [0.45, 0.6, 0.85],
        "lights": [{"type": "directional", "direction": list(sun), "intensity": [1.0, 0.95, 0.85]}],
        "materials": materials,
        "objects": objects,
        "render": {"shading": "phong", "shadows": True},
    }
