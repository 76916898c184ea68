"""Ray tracer against its peers, side by side in one run: Mitsuba 3 and POV-Ray 3.7.

1. Primary rays: an 81,920-triangle icosphere filling a 1024x1024 view, depth 1, no shadows. difflab:
   the whole `difflab.render` of a compiled scene (its default: primary mesh hits from the item
   buffer, the BVH's bit for bit, its z-buffer without the closed sphere's back faces; shading; the
   image; no ray tree), with the item buffer kept from
   the last render of the view (as the BVH is kept) and made anew (a new view's first frame), and
   with every primary ray through the BVH (item_buffer=False); beside them what the compiled scene
   builds once: the BVH and the culling test. Mitsuba: `scene.ray_intersect` alone on the same rays
   (closest hit only, no shading; llvm_ad_rgb when Mitsuba's LLVM backend loads, else scalar_rgb,
   named in the output). Rays per second, medians, interleaved repeats.
2. Whitted scenes: spheres (mirror, glass, diffuse) over a checkered plane, two point lights with
   shadows, depth 5, against POV-Ray rendering the same scene exported to SDL (no anti-aliasing,
   same thread count; its wall time includes parsing, as difflab's includes compiling the scene).

The machine may be shared: every ratio is measured within one run, repeats interleaved, both on wall
time and on CPU time (all threads of the process, or of the povray child), the latter less
sensitive to other work; the load average before and after is written with the results to
experiments/results/bench_raytrace.json.

    python experiments/bench/raytrace.py            # full
    python experiments/bench/raytrace.py --small    # quick check (256^2 rays, 160x120 Whitted)
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
import warp

import difflab
from difflab.io import write_json_atomic
from difflab.renderers.camera import camera_frame
from difflab.renderers.bandpool import cpu_threads
from difflab.geometry import solid_pieces
from difflab.renderers.raytrace.itembuffer import forget_item_buffer
from difflab.renderers.raytrace.selfcross import passes_through_itself

sys.path.insert(0, str(Path(__file__).parent))
import peers  # noqa: E402

RESULTS = Path(__file__).resolve().parents[1] / "results"
CAMERA = {"eye": [0.0, 0.0, 3.0], "target": [0.0, 0.0, 0.0], "fov_y": 45}


def icosphere_scene(obj_path: Path, size: int) -> difflab.Scene:
    return difflab.Scene.from_dict({
        "camera": {**CAMERA, "width": size, "height": size},
        "ambient": [0.1, 0.1, 0.1], "lights": [{"type": "point", "position": [3, 4, 5]}],
        "materials": {"m": {"kd": [0.7, 0.3, 0.2], "ks": [0.5, 0.5, 0.5], "n": 30}},
        "objects": [{"type": "mesh", "file": str(obj_path), "material": "m"}],
        "render": {"method": "raytrace", "max_depth": 1, "shadows": False},
    })


def whitted_scene(width: int, height: int, glass: bool) -> difflab.Scene:
    second = ({"ka": [0, 0, 0], "kd": [0.02, 0.02, 0.02], "ks": [0.6, 0.6, 0.6], "n": 200, "kt": 0.9, "ior": 1.5}
              if glass else {"ka": [0, 0, 0], "kd": [0.05, 0.05, 0.05], "ks": [0.8, 0.8, 0.8], "n": 200, "kr": 0.9})
    return difflab.Scene.from_dict({
        "camera": {"eye": [0, 1.6, 6], "target": [0, 0.8, 0], "fov_y": 40, "width": width, "height": height},
        "ambient": [0.1, 0.1, 0.1], "background": [0.3, 0.4, 0.6],
        "lights": [{"type": "point", "position": [5, 8, 6]}, {"type": "point", "position": [-6, 5, 3],
                                                             "intensity": [0.5, 0.5, 0.5]}],
        "materials": {"red": {"ka": [0.1, 0, 0], "kd": [0.7, 0.1, 0.1], "ks": [0.4, 0.4, 0.4], "n": 30, "kr": 0.2},
                      "second": second,
                      "floor": {"ka": [0.1, 0.1, 0.1], "kd": [0.8, 0.8, 0.8], "kr": 0.3,
                                "checker": {"size": 1.0, "ka2": [0, 0, 0], "kd2": [0.1, 0.1, 0.1]}}},
        "objects": [{"type": "sphere", "center": [-1.2, 1, 0], "radius": 1, "material": "red"},
                    {"type": "sphere", "center": [1.2, 1, 0.5], "radius": 1, "material": "second"},
                    {"type": "sphere", "center": [0, 0.5, -2], "radius": 0.5, "material": "red"},
                    {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
        "render": {"method": "raytrace", "max_depth": 5, "shadows": True, "transparent_shadows": False},
    })


def primary_rays(camera, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The pinhole rays through the pixel centres of a size x size image (difflab's camera)."""
    right, up, forward = camera_frame(camera)
    half = np.tan(np.radians(camera.fov_y) / 2)
    centres = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(centres * half, -centres * half)
    directions = x[..., None] * right + y[..., None] * up + forward
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    directions = directions.reshape(-1, 3)
    return np.broadcast_to(np.asarray(camera.eye, float), directions.shape).copy(), directions


def timed_render(scene, threads: int, **options) -> tuple[float, float]:
    """Wall seconds and CPU seconds (all threads of this process) of one `difflab.render`."""
    start, start_cpu = time.perf_counter(), time.process_time()
    difflab.render(scene, threads=threads, **options)
    return time.perf_counter() - start, time.process_time() - start_cpu


def one_time_costs(compiled) -> tuple[float, float, float]:
    """Wall seconds of what a compiled scene builds once for its meshes: the BVH (`wp.Mesh`), and
    the item buffer's culling test -- closed solids facing out (`solid_pieces`), then none passing
    through itself (`passes_through_itself`)."""
    vertices = compiled.arrays["vertices"]
    faces = compiled.faces[:compiled.n_mesh_faces]
    start = time.perf_counter()
    bvh = warp.Mesh(points=vertices, indices=warp.array(np.ascontiguousarray(faces).ravel(), dtype=warp.int32))
    built = time.perf_counter()
    pieces = solid_pieces(vertices.numpy()[:compiled.n_mesh_vertices], faces)
    solids = time.perf_counter()
    passes_through_itself(bvh, *pieces)
    return built - start, solids - built, time.perf_counter() - solids


def medians(pairs) -> tuple[float, float]:
    return statistics.median(p[0] for p in pairs), statistics.median(p[1] for p in pairs)


def primary_case(size: int, repeats: int, threads: int) -> dict:
    """difflab's whole `render` of the frame (the item buffer -- the default --, shading, the image),
    with the item buffer kept from the previous render of this view (as the BVH is) and made anew
    (a new view), and with every primary ray through the BVH (item_buffer=False), against Mitsuba's
    `ray_intersect` alone (no shading, no image), repeats interleaved."""
    with tempfile.TemporaryDirectory() as folder:
        obj_path = Path(folder) / "icosphere.obj"
        trimesh.creation.icosphere(subdivisions=6, radius=1.0).export(obj_path)
        scene = icosphere_scene(obj_path, size)
        compiled = difflab.compile_scene(scene)
        frame = difflab.render_frame(compiled, threads=threads)  # warm-up: kernels compiled and loaded, BVH built
        difflab.render(compiled, threads=threads, item_buffer=False)
        origins, directions = primary_rays(scene.camera, size)
        mitsuba, variant = peers.mitsuba_tracer(obj_path, origins, directions)
        ours, new_view, bvh, single, theirs = [], [], [], [], []
        once = [one_time_costs(compiled)]  # the first loads the kernels
        for _ in range(repeats):
            once.append(one_time_costs(compiled))
            ours.append(timed_render(compiled, threads))
            forget_item_buffer(compiled)
            new_view.append(timed_render(compiled, threads))
            bvh.append(timed_render(compiled, threads, item_buffer=False))
            single.append(timed_render(compiled, 1))
            if mitsuba is not None:
                theirs.append(mitsuba())
    rays = size * size
    wall, cpu = medians(ours)
    row = {"case": "icosphere primary rays", "triangles": int(compiled.n_mesh_faces), "size": size, "rays": rays,
           "compared": "difflab: the whole difflab.render of the frame (item buffer, shading, image) of a compiled "
                       "scene (BVH and the view's item buffer kept from the previous render; new_view: item buffer "
                       "made anew); Mitsuba: scene.ray_intersect alone (closest hit, no shading)",
           "difflab_rays_per_second": rays / wall, "difflab_rays_per_cpu_second": rays / cpu,
           "difflab_1_thread_rays_per_second": rays / medians(single)[0],
           "difflab_new_view_rays_per_second": rays / medians(new_view)[0],
           "difflab_new_view_rays_per_cpu_second": rays / medians(new_view)[1],
           "difflab_bvh_rays_per_second": rays / medians(bvh)[0],
           "difflab_bvh_rays_per_cpu_second": rays / medians(bvh)[1],
           "item_buffer_asked_bvh": frame.stats["item_buffer_asked_bvh"],
           "item_buffer_culled": frame.stats["item_buffer_culled"],
           **{f"{name}_ms": 1e3 * statistics.median(times) for name, times in
              zip(("bvh_build", "solid_pieces", "passes_through_itself"), zip(*once[1:]))},
           "mitsuba_variant": variant, "mitsuba_rays_per_second": None, "mitsuba_rays_per_cpu_second": None}
    if theirs:
        row["mitsuba_rays_per_second"], row["mitsuba_rays_per_cpu_second"] = (rays / m for m in medians(theirs))
        row["difflab_over_mitsuba"] = row["difflab_rays_per_second"] / row["mitsuba_rays_per_second"]
        row["difflab_over_mitsuba_cpu"] = row["difflab_rays_per_cpu_second"] / row["mitsuba_rays_per_cpu_second"]
        row["difflab_new_view_over_mitsuba"] = row["difflab_new_view_rays_per_second"] / row["mitsuba_rays_per_second"]
        row["difflab_new_view_over_mitsuba_cpu"] = (row["difflab_new_view_rays_per_cpu_second"]
                                                    / row["mitsuba_rays_per_cpu_second"])
    return row


def whitted_case(width: int, height: int, glass: bool, repeats: int, threads: int) -> dict:
    scene = whitted_scene(width, height, glass)
    difflab.render(scene, threads=threads)  # warm-up
    ours, theirs = [], []
    for _ in range(repeats):
        ours.append(timed_render(scene, threads))  # compiling the scene included, as POV-Ray's parsing is
        pov = peers.povray_seconds(scene, 1, threads)
        if pov is not None:
            theirs.append(pov)
    row = {"case": "whitted " + ("glass" if glass else "mirror"), "width": width, "height": height,
           "max_depth": scene.render.max_depth}
    row["difflab_seconds"], row["difflab_cpu_seconds"] = medians(ours)
    if theirs:
        row["povray_seconds"], row["povray_cpu_seconds"] = medians(theirs)
        row["difflab_over_povray"] = row["difflab_seconds"] / row["povray_seconds"]
        row["difflab_over_povray_cpu"] = row["difflab_cpu_seconds"] / row["povray_cpu_seconds"]
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="tiny sizes, for a quick check")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    threads = cpu_threads()
    size = 256 if args.small else 1024
    width, height = (160, 120) if args.small else (640, 480)
    load_before = os.getloadavg()
    primary = primary_case(size, args.repeats, threads)
    print(f"icosphere ({primary['triangles']} tris) {size}^2 primary rays, difflab's whole render (item buffer, "
          f"shading, image) vs Mitsuba's ray_intersect alone: difflab {primary['difflab_rays_per_second'] / 1e6:.2f} "
          f"Mrays/s ({threads} threads; {primary['difflab_1_thread_rays_per_second'] / 1e6:.2f} on 1; "
          f"{primary['difflab_rays_per_cpu_second'] / 1e6:.2f} per CPU-s; new view (item buffer made anew) "
          f"{primary['difflab_new_view_rays_per_second'] / 1e6:.2f}, "
          f"{primary['difflab_new_view_rays_per_cpu_second'] / 1e6:.2f} per CPU-s; BVH only {primary['difflab_bvh_rays_per_second'] / 1e6:.2f}; "
          f"{primary['item_buffer_asked_bvh']} samples asked the BVH; back faces culled: "
          f"{primary['item_buffer_culled']}; once per compiled scene: BVH {primary['bvh_build_ms']:.1f} ms, "
          f"culling test {primary['solid_pieces_ms']:.1f} ms solids + {primary['passes_through_itself_ms']:.1f} ms "
          f"self-crossing), Mitsuba "
          + (f"{primary['mitsuba_rays_per_second'] / 1e6:.2f} Mrays/s ({primary['mitsuba_variant']}; "
             f"{primary['mitsuba_rays_per_cpu_second'] / 1e6:.2f} per CPU-s): difflab / Mitsuba "
             f"{primary['difflab_over_mitsuba']:.2f} (wall), {primary['difflab_over_mitsuba_cpu']:.2f} (CPU); "
             f"new view {primary['difflab_new_view_over_mitsuba']:.2f} (wall), "
             f"{primary['difflab_new_view_over_mitsuba_cpu']:.2f} (CPU)"
             if primary["mitsuba_rays_per_second"] else "not installed"), flush=True)
    whitted = [whitted_case(width, height, glass, args.repeats, threads) for glass in (False, True)]
    for row in whitted:
        print(f"{row['case']} {width}x{height} depth {row['max_depth']}: difflab {row['difflab_seconds']:.3f} s, "
              + (f"POV-Ray {row['povray_seconds']:.3f} s: difflab / POV-Ray {row['difflab_over_povray']:.2f} (wall), "
                 f"{row['difflab_over_povray_cpu']:.2f} (CPU)"
                 if "povray_seconds" in row else "POV-Ray not installed"), flush=True)
    result = {"benchmark": "raytrace_vs_peers", "statistic": "median", "repeats": args.repeats, "interleaved": True,
              "threads": threads, "primary": primary, "whitted": whitted,
              "load_average_before": load_before, "load_average_after": os.getloadavg(),
              "versions": {"difflab": difflab.__version__, "warp": warp.config.version,
                           "python": platform.python_version()}, "machine": platform.machine(), "cpus": os.cpu_count()}
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json_atomic(RESULTS / "bench_raytrace.json", result)
    print(f"wrote {RESULTS / 'bench_raytrace.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
