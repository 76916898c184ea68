"""Shared pieces of the fit_* experiments: the test scene, random materials, versions, output."""

from __future__ import annotations

import platform
import sys
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
SEED = 0


def scene_dict(size: int, red: dict | None = None, lights=None, shading="phong", specular="phong") -> dict:
    """A red sphere on a checker floor under one point light (the issue's reference scene)."""
    return {
        "camera": {"eye": [0, 1.2, 4], "target": [0, 0.6, 0], "up": [0, 1, 0], "fov_y": 40, "width": size,
                   "height": size},
        "ambient": [0.2, 0.2, 0.2],
        "lights": lights or [{"type": "point", "position": [3, 4, 3], "intensity": [1, 1, 1]}],
        "materials": {
            "red": {"ka": [0.1, 0.05, 0.02], "kd": [0.7, 0.2, 0.1], "ks": [0.5, 0.4, 0.3], "n": 24.0, **(red or {})},
            "floor": {"kd": [0.8, 0.8, 0.8], "checker": {"size": 1.0, "ka2": [0, 0, 0], "kd2": [0.1, 0.1, 0.1]}},
        },
        "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"},
                    {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
        "render": {"shading": shading, "specular": specular, "shadows": True},
    }


def random_material(rng) -> dict:
    """A plausible plastic: ka, kd, ks per channel and n, within the ranges the experiments sample."""
    return {"ka": rng.uniform(0.02, 0.2, 3).tolist(), "kd": rng.uniform(0.1, 0.9, 3).tolist(),
            "ks": rng.uniform(0.1, 0.8, 3).tolist(), "n": float(np.exp(rng.uniform(np.log(5), np.log(200))))}


def perturb(material: dict, rng, factor=0.3) -> dict:
    """Each value scaled by 1 +- factor (random sign), the recovery start."""
    out = {}
    for key, value in material.items():
        value = np.asarray(value, float)
        out[key] = (value * (1 + factor * rng.choice([-1.0, 1.0], size=value.shape))).tolist()
    return out


def rel_error(params: dict, truth: dict) -> dict:
    """Max relative error per parameter."""
    return {k: float(np.max(np.abs(np.asarray(params[k]) - np.asarray(v)) / np.abs(np.asarray(v))))
            for k, v in truth.items()}


def versions() -> dict:
    import jax
    import optimistix
    import warp

    import difflab

    return {"python": sys.version.split()[0], "platform": platform.platform(), "difflab": difflab.__version__,
            "jax": jax.__version__, "optimistix": optimistix.__version__, "warp": warp.__version__,
            "numpy": np.__version__, "cpu_count": __import__("os").cpu_count()}


def write_csv(path: Path, rows: list[dict]) -> None:
    import csv
    import io

    from difflab.io import write_text_atomic

    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, buffer.getvalue())
