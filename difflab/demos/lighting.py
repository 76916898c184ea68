"""The lighting and shading sections of `difflab demo`: flat / Gouraud / Phong, the illumination
model term by term, and the lecture's material table.

Each section writes its files and returns (file, what it shows) pairs.
"""

from __future__ import annotations

import csv
import io as _io
import math
from pathlib import Path

import numpy as np

from ..io import write_text_atomic
from ..renderers.api import render
from .figures import image_grid

# The lecture's material table. "shininess" s in [0, 1] maps to the Phong exponent n = 128 s, the
# range of OpenGL's GL_SHININESS ([0, 128]).
SHININESS_TO_N = 128.0
LECTURE_MATERIALS = {
    "lecture 1": {"ambient": 0.52, "diffuse": 0.00, "specular": 0.82, "shininess": 0.10},
    "lecture 2": {"ambient": 0.39, "diffuse": 0.46, "specular": 0.82, "shininess": 0.75},
}


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
    path = image_grid(images, [f"{k}" for k in parts], out / "decomposition.png", columns=4)
    return [(path, "the illumination model term by term: ka Ia, kd Il cos(theta), ks Il cos^n(alpha), and the total")]


def lecture_phong_table() -> list[dict]:
    """The lecture's table: each material lit at incidence 60, 25 and 0 degrees (viewer along the
    mirror direction's neighbour, 10 degrees off the normal), split into its terms, with Ia = Il = 1."""
    rows = []
    for name, m in LECTURE_MATERIALS.items():
        n = SHININESS_TO_N * m["shininess"]
        for incidence in (60.0, 25.0, 0.0):
            theta = math.radians(incidence)
            view = math.radians(-10.0)
            l = np.array([math.sin(theta), 0.0, math.cos(theta)])
            v = np.array([math.sin(view), 0.0, math.cos(view)])
            r = 2.0 * l[2] * np.array([0.0, 0.0, 1.0]) - l
            ambient, diffuse = m["ambient"], m["diffuse"] * math.cos(theta)
            specular = m["specular"] * max(float(r @ v), 0.0) ** n
            rows.append({"material": name, "n": n, "incidence_deg": incidence, "ambient": ambient,
                         "diffuse": diffuse, "specular": specular, "total": ambient + diffuse + specular})
    return rows


def materials_table(out: Path, size: int) -> list[tuple[Path, str]]:
    """The lecture's two materials (and the table of their terms at three incidences)."""
    images, titles = [], []
    obj = [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]
    for name, m in LECTURE_MATERIALS.items():
        grey = lambda x: [x, x, x]  # noqa: E731
        material = {"ka": grey(m["ambient"]), "kd": grey(m["diffuse"]), "ks": grey(m["specular"]),
                    "n": SHININESS_TO_N * m["shininess"]}
        scene = base_scene(obj, {"m": material}, size, size,
                           lights=[{"type": "point", "position": [4.0, 5.0, 6.0], "intensity": [0.6, 0.6, 0.6]}])
        scene["ambient"] = [0.5, 0.5, 0.5]
        images.append(render(scene))
        titles.append(f"{name}: ka {m['ambient']}, kd {m['diffuse']},\nks {m['specular']}, "
                      f"shininess {m['shininess']} (n = {material['n']:.1f})")
    figure = image_grid(images, titles, out / "materials.png", columns=2)
    buffer = _io.StringIO()
    rows = lecture_phong_table()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()} for row in rows)
    table = out / "materials.csv"
    write_text_atomic(table, buffer.getvalue())
    return [(figure, "the lecture's two materials (shininess s mapped to n = 128 s, OpenGL's GL_SHININESS range)"),
            (table, "their ambient / diffuse / specular / total at incidence 60, 25 and 0 degrees")]
