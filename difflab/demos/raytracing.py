"""The ray tracer's demo figures: the lecture's "ray tree depth" series and glass with total internal
reflection. `demo_figures(out_dir)` writes them and returns (path, description) pairs.

The scenes are the example scenes "lecture_teapot" and "glass_sphere" shipped in the package
(`difflab.example_scene(name)`; the files `difflab.demos.scene_path(name)` that
`difflab render FILE --method raytrace` renders).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..renderers.compile import compile_scene
from ..renderers.raytrace.driver import raytrace
from .examples import example_scene
from .figures import image_grid


def depth_series(out: Path, width: int = 240, height: int = 180, depths=range(1, 8), spp: int = 4) -> list[tuple[Path, str]]:
    """The chrome teapot and mirror at ray-tree depths 1..7, each panel titled with its depth and
    rays traced, supersampled (`spp` on a regular grid) so the floor and the reflections do not alias."""
    scene = example_scene("lecture_teapot", width=width, height=height).with_overrides(render={"spp": spp})
    compiled = compile_scene(scene)
    images, titles, counts = [], [], []
    for depth in depths:
        frame = raytrace(compiled, scene.with_overrides(render={"max_depth": depth}).render, record_tree=False)
        images.append(frame.image)
        counts.append(frame.stats["total_rays"])
        titles.append(f"depth {depth} ({counts[-1]:,} rays)")
    images.append(np.clip(images[-1] - images[0], 0.0, None))
    titles.append(f"depth {depths[-1]} - depth {depths[0]}")
    path = image_grid(images, titles, out / "raytrace_depth_series.png", columns=4)
    change = [float(np.abs(b - a).mean()) for a, b in zip(images, images[1:-1])]
    return [(path, f"ray tree depth {depths[0]}..{depths[-1]} at {spp} spp: chrome teapot and mirror on a shiny "
                   f"checker floor, shadows, 2 point lights (depth 1: only the local shade on mirror and teapot; each "
                   f"level fills in one more reflection); mean change per extra level "
                   + ", ".join(f"{c:.4f}" for c in change))]


def glass(out: Path, width: int = 240, height: int = 180, spp: int = 4) -> list[tuple[Path, str]]:
    """A glass sphere and a glass cube: refraction, Fresnel reflection, Beer absorption, and a map of
    where total internal reflection happens, coloured by the object it happens in."""
    scene = example_scene("glass_sphere", width=width, height=height).with_overrides(render={"spp": spp})
    frame = raytrace(compile_scene(scene), scene.render)
    tree = frame.ray_tree
    kt = np.array([scene.materials[name].kt for name in scene.material_names])
    hit = tree.material >= 0
    tir_node = hit & (kt[np.maximum(tree.material, 0)] > 0) & (tree.fresnel_t == 0.0)
    n_samples = tree.sample_offset.size - 1
    side = tree.spp_side
    objects = [type(o).__name__.lower() for o in scene.objects]
    colours = {"mesh": [1.0, 0.45, 0.05], "sphere": [0.1, 0.8, 1.0]}
    overlay = 0.35 * frame.image.copy()
    shares = {}
    for kind, colour in colours.items():
        node = tir_node & np.isin(tree.object, [k for k, o in enumerate(objects) if o == kind])
        per_sample = np.bincount(tree.sample[node], minlength=n_samples).reshape(tree.grid_shape) > 0
        pixels = per_sample.reshape(height, side, width, side).any(axis=(1, 3))
        overlay[pixels] = colour
        shares[kind] = (int(node.sum()), float(pixels.mean()))
    titles = [f"glass, depth {scene.render.max_depth}, {spp} spp",
              "TIR: orange in the cube, blue in the sphere"]
    path = image_grid([frame.image, overlay], titles, out / "raytrace_glass.png", columns=2)
    return [(path, f"a glass sphere (left) and a glass cube (ior 1.5, exact Fresnel, Beer absorption); right: pixels "
                   f"whose ray tree meets total internal reflection, coloured by where it happens: in the cube "
                   f"{shares['mesh'][0]} events ({shares['mesh'][1]:.1%} of pixels, orange; inside the sphere's "
                   f"outline too, where the sphere shows the cube), in the sphere {shares['sphere'][0]} events (blue) "
                   f"-- a sphere never traps light that enters it from outside: every chord meets its surface at "
                   f"the entry angle")]


def demo_figures(out_dir, width: int = 240, height: int = 180) -> list[tuple[Path, str]]:
    """Write the ray tracer's figures to `out_dir`; returns (path, description) pairs."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return depth_series(out, width, height) + glass(out, width, height)


def ray_tracing(out: Path, size: int) -> list[tuple[Path, str]]:
    """`difflab demo` section: the figures at size x 3/4 size."""
    return demo_figures(out, size, size * 3 // 4)
