"""The illumination model measured the way the lecture draws it: one flat patch, one light, one
viewer, each at a stated angle -- rendered, so every number comes from the renderer's model.

Angles lie in one plane (x, y) through the patch's normal (+y): the light `incidence_deg` from the
normal on the +x side, L = (sin t, cos t, 0); the viewer `view_deg` from the normal on the -x side,
V = (-sin v, cos v, 0), so view_deg = incidence_deg puts the eye on the mirror direction R.
"""

from __future__ import annotations

import math

import numpy as np

from ..renderers.api import render

# The lecture's material table. "shininess" s in [0, 1] maps to the Phong exponent n = 128 s, the
# range of OpenGL's GL_SHININESS ([0, 128]).
SHININESS_TO_N = 128.0
LECTURE_MATERIALS = {
    "lecture 1": {"ambient": 0.52, "diffuse": 0.00, "specular": 0.82, "shininess": 0.10},
    "lecture 2": {"ambient": 0.39, "diffuse": 0.46, "specular": 0.82, "shininess": 0.75},
}


def lecture_material(name: str) -> dict:
    """The lecture's material `name` in the scene format (grey ka, kd, ks; n = 128 * shininess)."""
    m = LECTURE_MATERIALS[name]
    return {"ka": [m["ambient"]] * 3, "kd": [m["diffuse"]] * 3, "ks": [m["specular"]] * 3,
            "n": SHININESS_TO_N * m["shininess"]}


def unit(degrees: float, side: float) -> list[float]:
    t = math.radians(degrees)
    return [side * math.sin(t), math.cos(t), 0.0]


def lit_patch(material: dict, incidence_deg: float, view_deg: float = 0.0, *, ambient: float = 1.0,
              intensity: float = 1.0, specular: str = "phong", distance: float | None = None,
              attenuation=(1.0, 0.0, 0.0)) -> np.ndarray:
    """The linear RGB (3,) that `difflab.render` gives a flat patch of `material` (scene format),
    under ambient light `ambient` (grey) and one light of grey `intensity`: directional, or with
    `distance` a point light that far away along L with `attenuation` (kc, kl, kq) -- the lecture's
    I / (d + K) is (K, 1, 0). The viewer is orthographic (V the same at every point)."""
    light = ({"type": "directional", "direction": [-c for c in unit(incidence_deg, 1.0)]} if distance is None else
             {"type": "point", "position": [distance * c for c in unit(incidence_deg, 1.0)],
              "attenuation": list(attenuation)})
    scene = {
        "camera": {"eye": [4.0 * c for c in unit(view_deg, -1.0)], "target": [0, 0, 0], "up": [0, 0, -1],
                   "projection": "orthographic", "ortho_height": 0.02, "width": 3, "height": 3, "near": 0.1, "far": 10},
        "ambient": [ambient] * 3,
        "lights": [{**light, "intensity": [intensity] * 3}],
        "materials": {"m": material},
        "objects": [{"type": "mesh", "builtin": "quad", "resolution": 1, "material": "m"}],
        "render": {"method": "raster", "shading": "phong", "specular": specular, "shadows": False},
    }
    return render(scene)[1, 1]


def lecture_phong_table(ambient: float = 1.0, intensity: float = 1.0, view_deg: float = 10.0) -> list[dict]:
    """The lecture's table: each material lit at incidence 60, 25 and 0 degrees, split into ambient,
    diffuse, specular and total -- each term rendered alone (the others' coefficients set to 0).
    The default viewer is 10 degrees off the normal towards the mirror side (alpha = incidence - 10
    degrees), Ia = Ip = 1."""
    rows = []
    for name in LECTURE_MATERIALS:
        full = lecture_material(name)
        n = full["n"]
        for incidence in (60.0, 25.0, 0.0):
            terms = {}
            for term, keep in (("ambient", "ka"), ("diffuse", "kd"), ("specular", "ks"), ("total", None)):
                material = {k: (v if k in (keep, "n") or keep is None else [0.0] * 3) for k, v in full.items()}
                terms[term] = float(lit_patch(material, incidence, view_deg, ambient=ambient, intensity=intensity)[0])
            rows.append({"material": name, "n": n, "incidence_deg": incidence, **terms})
    return rows


#: The geometry under which the lecture's two quoted intensities come out of the model. The lecture
#: states neither Ia, Ip nor the angles. With Ia = 0.5, Ip = 1 and the light at 45 degrees of
#: incidence, material 2 gives 0.39 * 0.5 + 0.46 cos 45 = 0.520 for any viewer its narrow highlight
#: (n = 96) does not reach; material 1 (kd = 0) then needs 0.52 * 0.5 + 0.82 cos^12.8(alpha) = 0.31,
#: i.e. the viewer alpha = acos((0.05 / 0.82)^(1 / 12.8)) = 36.5 degrees from the mirror direction.
LECTURE_GEOMETRY = {"ambient": 0.5, "intensity": 1.0, "incidence_deg": 45.0,
                    "view_deg": 45.0 - math.degrees(math.acos((0.05 / 0.82) ** (1.0 / 12.8)))}


def lecture_intensities() -> dict[str, float]:
    """Each lecture material's rendered intensity under `LECTURE_GEOMETRY` (the lecture quotes 0.31
    and 0.52)."""
    g = LECTURE_GEOMETRY
    return {name: float(lit_patch(lecture_material(name), g["incidence_deg"], g["view_deg"], ambient=g["ambient"],
                                  intensity=g["intensity"])[0]) for name in LECTURE_MATERIALS}
