"""The small integration scenes whose 64x64 renders are kept as golden images in tests/golden/.

Regenerate them (after a deliberate change to what the renderer draws) with:

    python tests/golden_scenes.py
"""

from pathlib import Path

import numpy as np

GOLDEN = Path(__file__).resolve().parent / "golden"

SCENES = {
    "phong_checker_shadows": {
        "camera": {"eye": [0, 1.6, 4.5], "target": [0, 0.6, 0], "fov_y": 40, "width": 64, "height": 64},
        "ambient": [0.1, 0.1, 0.12],
        "background": [0.05, 0.05, 0.1],
        "lights": [{"type": "point", "position": [3, 5, 4], "intensity": [1, 1, 1], "attenuation": [1, 0.02, 0.0]},
                   {"type": "spot", "position": [-2, 4, 1], "direction": [0.4, -1, -0.2], "cutoff_deg": 25,
                    "exponent": 6, "intensity": [0.5, 0.4, 0.3]}],
        "materials": {"red": {"ka": [0.2, 0, 0], "kd": [0.7, 0.15, 0.1], "ks": [0.5, 0.5, 0.5], "n": 32},
                      "floor": {"kd": [0.8, 0.8, 0.8], "checker": {"size": 0.5, "kd2": [0.15, 0.15, 0.2]}}},
        "objects": [{"type": "sphere", "center": [0, 0.7, 0], "radius": 0.7, "material": "red"},
                    {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
        "render": {"shading": "phong", "specular": "phong", "shadows": True},
    },
    "gouraud_teapot_blinn_fog": {
        "camera": {"eye": [1.5, 2.5, 5], "target": [0, 0.6, 0], "fov_y": 35, "width": 64, "height": 64},
        "ambient": [0.2, 0.2, 0.2],
        "lights": [{"type": "directional", "direction": [-1, -1.5, -0.5], "intensity": [0.9, 0.9, 0.8]}],
        "materials": {"teal": {"ka": [0.05, 0.2, 0.2], "kd": [0.1, 0.5, 0.5], "ks": [0.6, 0.6, 0.6], "n": 40}},
        "objects": [{"type": "mesh", "builtin": "teapot", "resolution": 4, "material": "teal",
                     "transform": {"scale": 0.5, "rotate_deg": [0, 30, 0]}}],
        "fog": {"mode": "exp2", "color": [0.6, 0.6, 0.7], "density": 0.12},
        "render": {"shading": "gouraud", "specular": "blinn", "shadows": False, "spp": 4},
    },
}


def render_golden(name: str) -> np.ndarray:
    from difflab import render

    return render(SCENES[name])


if __name__ == "__main__":
    from difflab import save_image

    GOLDEN.mkdir(exist_ok=True)
    for name in SCENES:
        image = render_golden(name)
        np.save(GOLDEN / f"{name}.npy", image)
        save_image(GOLDEN / f"{name}.png", image)  # for people to look at
        print(f"wrote {GOLDEN / name}.npy")
