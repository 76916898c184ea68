"""The lecture's ray-tracing speed-ups side by side: the item buffer (primary rays from the
rasterizer's z-buffer) and the light buffer (Haines and Greenberg: shadow rays test only the
candidates of their cell of a per-light direction cube), against the plain BVH ray tracer.

The example scene "lecture_teapot" (chrome teapot, mirror, ball, shiny floor, two point lights,
shadows, depth 5) with the teapot at ~10k / ~100k triangles: seconds with neither, either and both
(the light buffer's build included), medians of interleaved repeats on all cores, ratios within the
run; candidates tested per shadow ray against the scene's primitive count (what a shadow ray with no
structure would test); the image differences. Writes experiments/results/bench_speedups.json.

    python experiments/bench/speedups.py            # 640x480, 10k and 100k triangles
    python experiments/bench/speedups.py --small    # 160x120, 10k triangles
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import warp

import difflab
from difflab.io import write_json_atomic

RESULTS = Path(__file__).resolve().parents[1] / "results"
MESHES = {"10k": 13, "100k": 40}  # teapot resolution r gives ~64 r^2 triangles
VARIANTS = {"none": {"item_buffer": False}, "item": {"item_buffer": True},
            "light": {"item_buffer": False, "light_buffer": True}, "both": {"item_buffer": True, "light_buffer": True}}


def lecture_scene(resolution: int, width: int, height: int) -> difflab.Scene:
    data = difflab.example_scene("lecture_teapot", width=width, height=height).to_dict()
    data["objects"][0]["resolution"] = resolution
    data["render"].update(max_depth=5, spp=1)
    return difflab.Scene.from_dict(data)


def case(label: str, resolution: int, width: int, height: int, repeats: int) -> dict:
    compiled = difflab.compile_scene(lecture_scene(resolution, width, height))
    frames = {name: difflab.render_frame(compiled, **options) for name, options in VARIANTS.items()}  # warm-up
    seconds = {name: [] for name in VARIANTS}
    for _ in range(repeats):
        for name, options in VARIANTS.items():  # interleaved, so load changes hit every variant alike
            start = time.perf_counter()
            difflab.render_frame(compiled, **options)
            seconds[name].append(time.perf_counter() - start)
    median = {name: statistics.median(s) for name, s in seconds.items()}
    light = frames["light"].stats
    primitives = compiled.n_mesh_faces + 2  # the ball and the floor plane
    return {"mesh": label, "triangles": int(compiled.n_mesh_faces), "seconds": median,
            "item_speedup": median["none"] / median["item"], "light_speedup": median["none"] / median["light"],
            "both_speedup": median["none"] / median["both"],
            "light_buffer_build_seconds": light["light_buffer_seconds"], "light_buffer_entries": light["light_buffer_entries"],
            "shadow_rays": light["rays"]["shadow"], "tests_per_shadow_ray": light["shadow_tests"] / light["rays"]["shadow"],
            "primitives": primitives,
            "max_difference": {name: float(np.abs(f.image - frames["none"].image).max()) for name, f in frames.items()}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="tiny sizes, for a quick check")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    width, height = (160, 120) if args.small else (640, 480)
    meshes = {"10k": MESHES["10k"]} if args.small else MESHES
    print(f"lecture_teapot {width}x{height}, depth 5, median of {args.repeats}, all cores")
    print(f"{'mesh':>5} {'none':>7} {'item':>7} {'light':>7} {'both':>7} | {'item x':>6} {'light x':>7} "
          f"{'build':>6} {'tests/ray':>9} {'prims':>7}")
    rows = []
    for label, resolution in meshes.items():
        row = case(label, resolution, width, height, args.repeats)
        rows.append(row)
        s = row["seconds"]
        print(f"{label:>5} {s['none']:7.3f} {s['item']:7.3f} {s['light']:7.3f} {s['both']:7.3f} | "
              f"{row['item_speedup']:6.2f} {row['light_speedup']:7.2f} {row['light_buffer_build_seconds']:6.3f} "
              f"{row['tests_per_shadow_ray']:9.1f} {row['primitives']:>7}", flush=True)
    result = {"benchmark": "raytrace_speedups", "statistic": "median", "repeats": args.repeats, "interleaved": True,
              "width": width, "height": height, "rows": rows, "load_average": os.getloadavg(),
              "versions": {"difflab": difflab.__version__, "warp": warp.config.version,
                           "python": platform.python_version()}, "machine": platform.machine()}
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json_atomic(RESULTS / "bench_speedups.json", result)
    last = rows[-1]
    print(f"wrote {RESULTS / 'bench_speedups.json'}: {last['mesh']} mesh, item buffer x{last['item_speedup']:.2f}, "
          f"light buffer x{last['light_speedup']:.2f} ({last['tests_per_shadow_ray']:.1f} candidates per shadow ray "
          f"of {last['primitives']} primitives)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
