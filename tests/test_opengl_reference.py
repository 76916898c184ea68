"""Optional: the rasterizer against OpenGL's fixed-function pipeline (Mesa's OSMesa, software GL).

With Blinn specular, per-vertex lighting, a local viewer, no light ambient and (kc, kl, kq)
attenuation, difflab's Gouraud shading is the GL 2.x lighting equation, so a 256x256 sphere must
match Mesa's render to PSNR >= 40 dB (8-bit output). Flat shading given one normal per face must
reach 30 dB: OpenGL lights a flat face at its last (provoking) vertex, difflab at its centroid.
Runs when PyOpenGL and libOSMesa are installed (`apt-get install libosmesa6; pip install PyOpenGL`);
skipped, with that reason, on a machine without them -- unless DIFFLAB_REQUIRE_OSMESA=1 (CI sets it
once it has installed libOSMesa), where their absence fails the run instead of skipping it.
"""

import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "experiments" / "bench"))
import mesa  # noqa: E402 - the benchmarks' OSMesa peer, one GL setup for both

MISSING = mesa.available()
if MISSING is not None:  # pragma: no cover - depends on the machine
    if os.environ.get("DIFFLAB_REQUIRE_OSMESA") == "1":
        pytest.fail(f"DIFFLAB_REQUIRE_OSMESA=1, but {MISSING}", pytrace=False)
    pytest.skip(MISSING, allow_module_level=True)

from difflab import Scene, render
from difflab.renderers.compile import object_mesh

SIZE = 256
SCENE = {
    "camera": {"eye": [0.4, 0.8, 3.2], "target": [0, 0, 0], "fov_y": 45, "width": SIZE, "height": SIZE,
               "near": 0.5, "far": 20},
    "ambient": [0.15, 0.12, 0.1],
    "lights": [
        {"type": "point", "position": [2.0, 3.0, 2.5], "intensity": [0.9, 0.85, 0.8], "attenuation": [0.6, 0.15, 0.03]},
        {"type": "directional", "direction": [-1.0, 0.2, -0.6], "intensity": [0.3, 0.35, 0.5]},
    ],
    "materials": {"m": {"ka": [0.3, 0.2, 0.2], "kd": [0.7, 0.35, 0.2], "ks": [0.6, 0.6, 0.6], "n": 24}},
    "objects": [{"type": "mesh", "builtin": "sphere", "resolution": 16, "material": "m"}],
    "render": {"shadows": False, "specular": "blinn"},
}


def psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((a - b) ** 2))


@pytest.mark.parametrize("shading, smooth, threshold", [("gouraud", True, 40.0), ("flat", False, 30.0)])
def test_matches_mesa_fixed_function(shading, smooth, threshold):
    d = {**SCENE, "objects": [{**SCENE["objects"][0], "smooth": smooth}]}
    scene = Scene.from_dict(d)
    mesh = object_mesh(scene.objects[0])
    peer = mesa.MesaRenderer(scene, mesh, flat=not smooth)
    reference = peer.draw()[1].astype(np.float64)
    peer.close()
    ours = render(scene, shading=shading, clamp_vertex_colors=True)
    ours8 = np.round(np.clip(ours, 0, 1) * 255) / 255
    assert reference.max() > 0.5  # not a black image
    value = psnr(ours8, reference)
    print(f"{shading}: PSNR {value:.1f} dB against Mesa")
    assert value >= threshold
