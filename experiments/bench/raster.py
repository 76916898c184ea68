"""Rasterizer throughput: frames and triangles per second, one thread versus all cores.

Phong shading of the Utah teapot tessellated to ~100k and ~1M triangles, at 640x480 and 1920x1080,
one point light with shadows. Reports medians over repeats (after a warm-up render that compiles the
kernels), the all-cores / one-thread speed-up measured in the same run, and the peak resident memory
of a process that renders one 1080p frame. Writes experiments/results/bench_raster.json.

    python experiments/bench/raster.py            # full
    python experiments/bench/raster.py --small    # quick check
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import warp

import difflab
from difflab.io import write_json_atomic
from difflab.renderers.compile import compile_scene
from difflab.renderers.launch import cpu_threads
from difflab.renderers.raster.driver import rasterize

RESULTS = Path(__file__).resolve().parents[1] / "results"


def teapot_scene(resolution: int, width: int, height: int) -> difflab.Scene:
    return difflab.Scene.from_dict({
        "camera": {"eye": [0, 3, 9], "target": [0, 1.2, 0], "fov_y": 35, "width": width, "height": height},
        "ambient": [0.1, 0.1, 0.1],
        "lights": [{"type": "point", "position": [5, 8, 6]}],
        "materials": {"red": {"ka": [0.2, 0, 0], "kd": [0.7, 0.1, 0.1], "ks": [0.5] * 3, "n": 32}},
        "objects": [{"type": "mesh", "builtin": "teapot", "resolution": resolution, "material": "red"}],
        "render": {"shading": "phong", "shadows": True},
    })


def time_render(compiled, threads: int, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        rasterize(compiled, compiled.scene.render, threads)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def peak_memory_mib(resolution: int, width: int, height: int) -> float:
    """Peak RSS of a fresh process that compiles the scene and renders one frame."""
    code = (f"import resource, sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import raster as b; "
            f"from difflab.renderers.compile import compile_scene; from difflab.renderers.raster.driver import rasterize; "
            f"c = compile_scene(b.teapot_scene({resolution}, {width}, {height})); rasterize(c, c.scene.render); "
            f"print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(out.stdout.strip().splitlines()[-1]) / 1024.0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="tiny sizes, for a quick check")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    meshes = {"100k": 40, "1M": 125} if not args.small else {"10k": 12}
    sizes = [(640, 480), (1920, 1080)] if not args.small else [(160, 120)]
    all_threads = cpu_threads()
    rows = []
    for label, resolution in meshes.items():
        for width, height in sizes:
            compiled = compile_scene(teapot_scene(resolution, width, height))
            triangles = compiled.faces.shape[0]
            rasterize(compiled, compiled.scene.render)  # warm-up: compile kernels
            one = time_render(compiled, 1, args.repeats)
            many = time_render(compiled, all_threads, args.repeats)
            rows.append({"mesh": label, "triangles": triangles, "width": width, "height": height,
                         "seconds_1_thread": one, f"seconds_{all_threads}_threads": many,
                         "fps_all_threads": 1.0 / many, "triangles_per_second": triangles / many,
                         "speedup": one / many})
            print(f"{label:>5} {triangles:>8} tris {width}x{height}: 1 thread {one * 1e3:8.1f} ms, "
                  f"{all_threads} threads {many * 1e3:8.1f} ms, {1 / many:6.2f} fps, "
                  f"{triangles / many / 1e6:6.2f} Mtri/s, speed-up {one / many:4.2f}x", flush=True)
    big = max(meshes.values())
    width, height = sizes[-1]
    peak = peak_memory_mib(big, width, height)
    print(f"peak RSS rendering one {width}x{height} frame of the largest mesh: {peak:.0f} MiB")
    result = {"benchmark": "raster", "threads": all_threads, "repeats": args.repeats, "statistic": "median",
              "rows": rows, "peak_rss_mib": peak, "versions": {"difflab": difflab.__version__,
              "warp": warp.config.version, "python": platform.python_version()}, "machine": platform.machine()}
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json_atomic(RESULTS / "bench_raster.json", result)
    print(f"wrote {RESULTS / 'bench_raster.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
