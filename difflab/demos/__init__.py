"""difflab.demos: the figures of `difflab demo` and the example scenes shipped with the package.

The engine (scene, geometry, lighting, renderers, fit, fractals) never imports this package; it imports
them. Sections (each `section(out, size) -> [(path, what it shows), ...]`):

- `lighting`: flat / Gouraud / Phong, the model term by term, the lecture's material table
- `textures`: texture filters on a receding checkerboard against a supersampled truth
- `raytracing`: the ray-tree depth series and glass with total internal reflection
- `fractals`: one figure per fractal kind (also `difflab fractal KIND`)

Figure helpers: `save_figure`, `image_grid` (in `figures`). Lecture helpers the notebooks
use: `incremental_span`, `polygon_scanline_shade`, `triangle_shade`, `tiled_surface`, `edge_kinks` (Gouraud's
scan line and its defects, in `gouraud`), `wireframe` (a scene's edges in raster coordinates, in
`pipeline`), `lit_patch`, `lecture_phong_table`, `lecture_intensities`, `lecture_material`,
`LECTURE_GEOMETRY` (the illumination model measured on one patch at stated angles, in
`illumination`), `texture_to_object`, `texture_to_screen`, `apply_projective`, `mip_pyramid` (the
texture -> screen chain as one 3x3 projective map, in `texture_maps`), and the texture-filter
comparison `checker_texture`, `receding_plane_scene`, `compare_filters`, `FILTER_ORDER`,
`FILTER_TITLES` (in `textures`), `forward_trace`, `forward_scene`, `light_buffer_counts` (forward
against backward tracing, and the light buffer's candidate lists, in `tracing`). Example scenes:
`example_scene(name, *, width=None, height=None)`, `scene_path(name)`, `example_names()`.
"""

from __future__ import annotations

import time
from pathlib import Path

from .examples import example_names as example_names
from .examples import example_scene as example_scene
from .examples import scene_path as scene_path
from .figures import image_grid as image_grid
from .gouraud import edge_kinks as edge_kinks
from .gouraud import incremental_span as incremental_span
from .gouraud import polygon_scanline_shade as polygon_scanline_shade
from .gouraud import tiled_surface as tiled_surface
from .gouraud import triangle_shade as triangle_shade
from .illumination import LECTURE_GEOMETRY as LECTURE_GEOMETRY
from .illumination import lecture_intensities as lecture_intensities
from .illumination import lecture_material as lecture_material
from .illumination import lecture_phong_table as lecture_phong_table
from .illumination import lit_patch as lit_patch
from .pipeline import wireframe as wireframe
from .texture_maps import apply_projective as apply_projective
from .texture_maps import mip_pyramid as mip_pyramid
from .texture_maps import texture_to_object as texture_to_object
from .texture_maps import texture_to_screen as texture_to_screen
from .textures import FILTER_ORDER as FILTER_ORDER
from .tracing import forward_scene as forward_scene
from .tracing import forward_trace as forward_trace
from .tracing import light_buffer_counts as light_buffer_counts
from .textures import FILTER_TITLES as FILTER_TITLES
from .textures import checker_texture as checker_texture
from .textures import compare_filters as compare_filters
from .textures import receding_plane_scene as receding_plane_scene
from .figures import save_figure as save_figure

#: Image size (pixels) of the demo's panels: full, and with `--quick`.
DEMO_SIZE, QUICK_SIZE = 256, 96


def sections() -> list:
    """The demo's sections in the order they run."""
    from .fractals import gallery
    from .lighting import decomposition, materials_table, shading_models
    from .raytracing import ray_tracing
    from .textures import texture_figures

    return [shading_models, decomposition, materials_table, texture_figures, ray_tracing, gallery]


#: The demo's index in its folder: INDEX_HEADER, then `name: what it shows` a line. It marks the folder
#: as the demo's own, which `difflab demo` writes again without --force (`is_demo_folder`).
INDEX_NAME = "difflab-demo.txt"
INDEX_HEADER = "Figures written by `difflab demo` (docs/cli.md); what each shows:"


def is_demo_folder(folder) -> bool:
    """Whether `folder` holds the demo's index (a run of the demo wrote it, finished or not)."""
    index = Path(folder) / INDEX_NAME
    try:
        return index.is_file() and index.read_text(encoding="utf-8").startswith(INDEX_HEADER)
    except (OSError, UnicodeDecodeError):
        return False


def run_demo(out, quick: bool = False) -> list[tuple[Path, str]]:
    """Write every section's figures to the folder `out` (created if needed) and print where they
    are and what each shows; `quick` uses QUICK_SIZE panels. The index (INDEX_NAME) is written
    first, with its header alone, and at the end with every figure. Returns (path, description) pairs."""
    from ..files import write_text_atomic

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / INDEX_NAME, INDEX_HEADER + "\n")
    size = QUICK_SIZE if quick else DEMO_SIZE
    written = []
    for section in sections():
        start = time.perf_counter()
        written += section(out, size)
        print(f"[{section.__module__.rsplit('.', 1)[-1]}.{section.__name__}] {time.perf_counter() - start:.1f} s",
              flush=True)
    write_text_atomic(out / INDEX_NAME, "".join(f"{line}\n" for line in
                                                 [INDEX_HEADER, *(f"{path.name}: {what}" for path, what in written)]))
    print(f"difflab demo: {len(written)} files in {out.resolve()} (listed in {INDEX_NAME})")
    for path, description in written:
        print(f"  {path.name}: {description}")
    return written


__all__ = ["DEMO_SIZE", "INDEX_NAME", "is_demo_folder", "forward_scene", "forward_trace", "light_buffer_counts", "FILTER_ORDER", "FILTER_TITLES", "apply_projective", "checker_texture", "compare_filters",
           "mip_pyramid", "receding_plane_scene", "texture_to_object", "texture_to_screen", "LECTURE_GEOMETRY", "lecture_intensities", "lecture_material", "lecture_phong_table",
           "lit_patch", "QUICK_SIZE", "edge_kinks", "example_names", "example_scene", "image_grid", "incremental_span",
           "polygon_scanline_shade", "run_demo", "save_figure", "scene_path", "sections", "tiled_surface",
           "triangle_shade", "wireframe"]
