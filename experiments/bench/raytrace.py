"""Ray-tracer throughput on the lecture's test scene: rays per second, item buffer, threads.

the example scene "lecture_teapot" (difflab/demos/scenes/lecture_teapot.json: chrome teapot, mirror, shiny checker floor, shadows, two
point lights) at 640x480, max depth 5, with the teapot tessellated to ~10k, ~100k and ~1M
triangles. For each mesh: the full ray tracer and the item-buffer variant (primary visibility from
the rasterizer's z-buffer), each on one thread and on all cores; medians over repeats after a
warm-up render that compiles the kernels. Ratios (item buffer / full, all cores / one thread) are
measured in the same run. The ray tree is not recorded in the timed renders; its cost (the second
pass) is measured once on the smallest mesh. POV-Ray's time on the equivalent scene is not measured
(no exporter yet; reported as absent). Writes experiments/results/bench_raytrace.json.

    python experiments/bench/raytrace.py            # full
    python experiments/bench/raytrace.py --small    # quick check (160x120, 10k triangles)
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import sys
import time
from pathlib import Path

import warp

import difflab
from difflab.demos import scene_path
from difflab.io import write_json_atomic
from difflab.renderers.compile import compile_scene
from difflab.renderers.launch import cpu_threads
from difflab.renderers.raytrace.driver import raytrace

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
SCENE = scene_path("lecture_teapot")
MESHES = {"10k": 13, "100k": 40, "1M": 125}  # teapot resolution r gives ~64 r^2 triangles


def lecture_scene(resolution: int, width: int, height: int, depth: int) -> difflab.Scene:
    data = json.loads(SCENE.read_text())
    data["camera"].update(width=width, height=height)
    data["objects"][0]["resolution"] = resolution
    data["render"].update(max_depth=depth, spp=1)
    return difflab.Scene.from_dict(data)


def time_render(compiled, threads: int, repeats: int, item: bool, record: bool = False):
    times, frame = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        frame = raytrace(compiled, compiled.scene.render, threads, record_tree=record, use_item_buffer=item)
        times.append(time.perf_counter() - start)
    return statistics.median(times), frame


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="tiny sizes, for a quick check")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--depth", type=int, default=5)
    args = parser.parse_args(argv)
    meshes = {"10k": MESHES["10k"]} if args.small else MESHES
    width, height = (160, 120) if args.small else (640, 480)
    repeats = 1 if args.small else args.repeats
    all_threads = cpu_threads()
    rows = []
    print(f"lecture scene {width}x{height}, depth {args.depth}, {all_threads} cores, median of {repeats}")
    print(f"{'mesh':>5} {'tris':>8} {'primary':>8} {'shadow':>8} {'second.':>8} | {'full 1t':>8} {'full Nt':>8} "
          f"{'item 1t':>8} {'item Nt':>8} | {'Mray/s':>6} {'thr x':>5} {'item x':>6}")
    for label, resolution in meshes.items():
        compiled = compile_scene(lecture_scene(resolution, width, height, args.depth))
        triangles = compiled.n_mesh_faces
        raytrace(compiled, compiled.scene.render, record_tree=False)  # warm-up: compile kernels
        raytrace(compiled, compiled.scene.render, record_tree=False, use_item_buffer=True)
        t = {}
        for item in (False, True):
            for threads in (1, all_threads):
                t[item, threads], frame = time_render(compiled, threads, repeats, item)
                if not item:
                    rays = frame.stats["rays"]
        total = sum(rays.values())
        row = {"mesh": label, "triangles": triangles, "width": width, "height": height, "max_depth": args.depth,
               "rays": rays, "total_rays": total,
               "seconds": {f"{'item' if item else 'full'}_{threads}_threads": s for (item, threads), s in t.items()},
               "rays_per_second_all_cores": total / t[False, all_threads],
               "rays_per_second_1_thread": total / t[False, 1],
               "thread_speedup": t[False, 1] / t[False, all_threads],
               "item_buffer_speedup": t[False, all_threads] / t[True, all_threads],
               "item_buffer_speedup_1_thread": t[False, 1] / t[True, 1]}
        rows.append(row)
        print(f"{label:>5} {triangles:>8} {rays['primary']:>8} {rays['shadow']:>8} "
              f"{rays['reflection'] + rays['refraction']:>8} | {t[False, 1]:8.3f} {t[False, all_threads]:8.3f} "
              f"{t[True, 1]:8.3f} {t[True, all_threads]:8.3f} | {row['rays_per_second_all_cores'] / 1e6:6.2f} "
              f"{row['thread_speedup']:5.2f} {row['item_buffer_speedup']:6.2f}", flush=True)
    compiled = compile_scene(lecture_scene(meshes[next(iter(meshes))], width, height, args.depth))
    plain, _ = time_render(compiled, all_threads, repeats, False)
    recorded, frame = time_render(compiled, all_threads, repeats, False, record=True)
    tree = {"seconds_without": plain, "seconds_with": recorded, "ratio": recorded / plain,
            "nodes": frame.stats["nodes"]}
    print(f"recording the ray tree ({tree['nodes']} nodes): {recorded:.3f} s vs {plain:.3f} s ({tree['ratio']:.2f}x)")
    povray = shutil.which("povray")
    print("POV-Ray: " + ("installed, but no scene exporter yet: not timed" if povray else "not installed: not timed"))
    result = {"benchmark": "raytrace", "scene": SCENE.name, "threads": all_threads, "repeats": repeats,
              "statistic": "median", "rows": rows, "tree_recording": tree, "povray": None,
              "versions": {"difflab": difflab.__version__, "warp": warp.config.version,
                           "python": platform.python_version()}, "machine": platform.machine()}
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json_atomic(RESULTS / "bench_raytrace.json", result)
    summary = rows[-1]
    print(f"wrote {RESULTS / 'bench_raytrace.json'}: {summary['mesh']} mesh "
          f"{summary['rays_per_second_all_cores'] / 1e6:.2f} Mrays/s on {all_threads} cores, threads x{summary['thread_speedup']:.2f}, "
          f"item buffer x{summary['item_buffer_speedup']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
