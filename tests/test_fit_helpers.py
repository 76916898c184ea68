"""Shared scenes for the fitting tests (no tests here)."""

import numpy as np

from difflab.renderers.api import render_frame
from difflab.scene import Scene

TRUTH = {"ka": [0.1, 0.05, 0.02], "kd": [0.7, 0.2, 0.1], "ks": [0.5, 0.4, 0.3], "n": 24.0}


def scene_dict(size=32, shading="phong", specular="phong", lights=None, fog=None, spp=1, clamp=False, red=None):
    d = {
        "camera": {"eye": [0, 1.2, 4], "target": [0, 0.6, 0], "up": [0, 1, 0], "fov_y": 40, "width": size,
                   "height": size},
        "ambient": [0.2, 0.2, 0.2],
        "background": [0.05, 0.05, 0.1],
        "lights": lights if lights is not None else [
            {"type": "point", "position": [3, 4, 3], "intensity": [1, 1, 1], "attenuation": [1, 0, 0]}],
        "materials": {
            "red": {**TRUTH, **(red or {})},
            "floor": {"kd": [0.8, 0.8, 0.8], "checker": {"size": 1.0, "ka2": [0, 0, 0], "kd2": [0.1, 0.1, 0.1]}},
        },
        "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"},
                    {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
        "render": {"shading": shading, "specular": specular, "shadows": True, "spp": spp,
                   "clamp_vertex_colors": clamp},
    }
    if fog is not None:
        d["fog"] = fog
    return d


def make_scene(**kw) -> Scene:
    return Scene.from_dict(scene_dict(**kw))


def mirror_scene(size: int) -> Scene:
    """The issue's trap: a ray-traced scene whose red sphere reflects (kr = 0.1), with shadows."""
    d = scene_dict(size=size, red={"kr": 0.1})
    d["render"]["method"] = "raytrace"
    return Scene.from_dict(d)


def target_of(scene) -> np.ndarray:
    return render_frame(scene).image


def perturbed(truth: dict, factor=0.3, seed=0) -> dict:
    """Every value moved by +-factor (alternating signs per entry), as the recovery criterion asks."""
    rng = np.random.default_rng(seed)
    out = {}
    for key, value in truth.items():
        value = np.asarray(value, float)
        sign = rng.choice([-1.0, 1.0], size=value.shape)
        out[key] = (value * (1.0 + factor * sign)).tolist()
    return out
