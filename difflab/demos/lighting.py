"""The lighting and shading sections of `difflab demo`: flat / Gouraud / Phong, the illumination
model term by term, and the lecture's material table.

Each section writes its files and returns (file, what it shows) pairs.
"""

from __future__ import annotations

import csv
import io as _io
from pathlib import Path

from ..files import write_text_atomic
from ..renderers.api import render
from .figures import image_grid
from .illumination import (LECTURE_GEOMETRY, LECTURE_MATERIALS, lecture_intensities, lecture_material,
                           lecture_phong_table)


def base_scene(objects, materials, width, height, eye=(0.0, 0.6, 4.0), target=(0.0, 0.0, 0.0), lights=None):
    return {
        "camera": {"eye": list(eye), "target": list(target), "fov_y": 35, "width": width, "height": height},
        "ambient": [0.2, 0.2, 0.2],
        "background": [0.02, 0.02, 0.03],
        "lights": lights or [{"type": "point", "position": [4.0, 5.0, 6.0], "intensity": [1.0, 1.0, 1.0]},
                             {"type": "directional", "direction": [1.0, -0.3, -0.5], "intensity": [0.25, 0.25, 0.3]}],
        "materials": materials,
        "objects": objects,
        "render": {"shadows": False},
    }


PLASTIC = {"ka": [0.3, 0.08, 0.05], "kd": [0.75, 0.2, 0.12], "ks": [0.6, 0.6, 0.6], "n": 40}


def shading_models(out: Path, size: int) -> list[tuple[Path, str]]:
    """The same coarse sphere and low-polygon teapot, flat vs Gouraud vs Phong."""
    sphere = base_scene([{"type": "mesh", "builtin": "sphere", "resolution": 8, "material": "plastic"}],
                        {"plastic": PLASTIC}, size, size, eye=(0.0, 0.5, 3.6))
    teapot = base_scene([{"type": "mesh", "builtin": "teapot", "resolution": 3, "material": "plastic",
                          "transform": {"translate": [-0.1, -0.75, 0.0], "scale": 0.45}}],
                        {"plastic": PLASTIC}, size, size, eye=(0.0, 1.4, 4.6), target=(0.0, 0.0, 0.0))
    images, titles = [], []
    for name, scene in [("sphere (8 bands)", sphere), ("teapot (res. 3)", teapot)]:
        for shading in ("flat", "gouraud", "phong"):
            images.append(render(scene, shading=shading))
            titles.append(f"{name}: {shading}")
    path = image_grid(images, titles, out / "shading_models.png", columns=3)
    return [(path, "flat vs Gouraud vs Phong shading of one coarse sphere and one low-polygon teapot: "
                   "facets, Mach bands and the highlight Gouraud smears or loses")]


def decomposition(out: Path, size: int) -> list[tuple[Path, str]]:
    """Ambient, diffuse and specular terms of one sphere, and their sum."""
    obj = [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]
    parts = {"ambient": {"ka": PLASTIC["ka"], "kd": [0, 0, 0]},
             "diffuse": {"kd": PLASTIC["kd"]},
             "specular": {"kd": [0, 0, 0], "ks": PLASTIC["ks"], "n": PLASTIC["n"]},
             "total": PLASTIC}
    images = [render(base_scene(obj, {"m": material}, size, size)) for material in parts.values()]
    clipped = [int((image > 1.0).any(axis=-1).sum()) for image in images]
    titles = [k if not c else f"{k} ({c} px > 1, shown as 1)" for k, c in zip(parts, clipped)]
    path = image_grid(images, titles, out / "decomposition.png", columns=4)
    return [(path, "the illumination model term by term: ka Ia, kd Il cos(theta), ks Il cos^n(alpha), and the total "
                   f"(linear values above 1 are displayed as 1: {clipped[-1]} pixels of the total, at the highlight)")]


def materials_table(out: Path, size: int) -> list[tuple[Path, str]]:
    """The lecture's two materials (and the table of their terms at three incidences)."""
    images, titles = [], []
    obj = [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]
    quoted = lecture_intensities()
    for name, m in LECTURE_MATERIALS.items():
        material = lecture_material(name)
        scene = base_scene(obj, {"m": material}, size, size,
                           lights=[{"type": "point", "position": [4.0, 5.0, 6.0], "intensity": [0.6, 0.6, 0.6]}])
        scene["ambient"] = [0.5, 0.5, 0.5]
        images.append(render(scene))
        titles.append(f"{name}: ka {m['ambient']}, kd {m['diffuse']}, ks {m['specular']},\n"
                      f"shininess {m['shininess']} (n = {material['n']:.1f}); patch: {quoted[name]:.2f}")
    figure = image_grid(images, titles, out / "materials.png", columns=2)
    buffer = _io.StringIO()
    rows = lecture_phong_table()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()} for row in rows)
    table = out / "materials.csv"
    write_text_atomic(table, buffer.getvalue())
    g = LECTURE_GEOMETRY
    return [(figure, "the lecture's two materials (shininess s mapped to n = 128 s, OpenGL's GL_SHININESS range); "
                     f"'patch' is the rendered intensity of a flat patch with Ia {g['ambient']}, Ip {g['intensity']}, "
                     f"light {g['incidence_deg']:.0f} deg, viewer {g['view_deg']:.1f} deg from the normal "
                     "(the lecture quotes 0.31 and 0.52)"),
            (table, "their ambient / diffuse / specular / total at incidence 60, 25 and 0 degrees")]
