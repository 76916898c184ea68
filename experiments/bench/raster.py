"""Rasterizer against Mesa's llvmpipe (OSMesa, fixed function), side by side in one run.

The four rows of issue 14: a UV sphere of ~100k and ~1M triangles at 640x480 and 1920x1080, Gouraud
shading, Blinn specular, one point light, no shadows, warm (kernels compiled, scene compiled once:
`difflab.render(compiled)` forms only the image). Each repeat renders difflab on all cores, Mesa,
and difflab on one thread, interleaved, so a machine shared with other work loads all three alike;
the table gives medians, difflab / Mesa per row on wall time and on CPU time (all threads of the
process: less sensitive to other work on the machine), the 1 -> all-cores speed-up, compile time, the
PSNR of difflab's 8-bit image against Mesa's (the same picture), the peak resident memory of a
fresh process that loads, compiles and renders the 1080p 1M-triangle frame, and the load + compile
time of the largest sphere written as an OBJ file with `vn` normals (`f a//n` corners) and without
(bare `v` / `f a b c`: vertex normals computed). Writes experiments/results/bench_raster.json with
the machine's load average before and after.

    python experiments/bench/raster.py            # full
    python experiments/bench/raster.py --small    # quick check (10k triangles, 160x120)
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp

import difflab
from difflab.geometry import TriMesh, save_mesh
from difflab.io import write_json_atomic
from difflab.renderers.compile import object_mesh
from difflab.renderers.bandpool import cpu_threads

sys.path.insert(0, str(Path(__file__).parent))
import mesa  # noqa: E402

RESULTS = Path(__file__).resolve().parents[1] / "results"
MESHES = {"100k": 158, "1M": 500}  # a UV sphere of resolution r has 4 r (r - 1) triangles
SIZES = [(640, 480), (1920, 1080)]


def sphere_scene(resolution: int, width: int, height: int) -> difflab.Scene:
    return difflab.Scene.from_dict({
        "camera": {"eye": [0.4, 0.8, 3.2], "target": [0, 0, 0], "fov_y": 45, "width": width, "height": height,
                   "near": 0.5, "far": 20},
        "ambient": [0.15, 0.12, 0.1],
        "lights": [{"type": "point", "position": [2.0, 3.0, 2.5], "intensity": [0.9, 0.85, 0.8],
                    "attenuation": [0.6, 0.15, 0.03]}],
        "materials": {"m": {"ka": [0.3, 0.2, 0.2], "kd": [0.7, 0.35, 0.2], "ks": [0.6, 0.6, 0.6], "n": 24}},
        "objects": [{"type": "mesh", "builtin": "sphere", "resolution": resolution, "material": "m"}],
        "render": {"method": "raster", "shading": "gouraud", "specular": "blinn", "shadows": False,
                   "clamp_vertex_colors": True},
    })


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / max(float(np.mean((a - b) ** 2)), 1e-12)))


def timed(fn) -> tuple[float, float, object]:
    """Wall seconds, CPU seconds (all threads of this process) and result of fn()."""
    start, start_cpu = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - start, time.process_time() - start_cpu, out


def peak_memory_mib(resolution: int, width: int, height: int) -> float:
    """Peak RSS of a fresh process that builds, compiles and renders one frame, with Warp's kernel
    cache warm (run twice: the first may compile a kernel, which takes memory of its own). Read as
    VmHWM of /proc/self/status, which belongs to the new process image: getrusage's ru_maxrss
    survives fork + exec on Linux and reported this (large) benchmark process's RSS instead."""
    code = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import raster as b, difflab; "
            f"difflab.render(b.sphere_scene({resolution}, {width}, {height})); "
            "print(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM:')))")
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(out.stdout.strip().splitlines()[-1]) / 1024.0


def obj_load_seconds(resolution: int, repeats: int) -> dict:
    """Median seconds of `compile_scene` for the sphere of `resolution` read from an OBJ file, with
    `vn` normals and bare (process CPU seconds beside: less sensitive to other work)."""
    mesh = object_mesh(sphere_scene(resolution, 64, 48).objects[0])
    out = {}
    with tempfile.TemporaryDirectory() as folder:
        for label, written in [("obj_with_vn", mesh), ("obj_bare", TriMesh(mesh.vertices, mesh.faces))]:
            path = save_mesh(Path(folder) / f"{label}.obj", written)
            scene = sphere_scene(resolution, 640, 480).to_dict()
            scene["objects"] = [{"type": "mesh", "file": str(path), "material": "m"}]
            scene = difflab.Scene.from_dict(scene)
            times = [timed(lambda: difflab.compile_scene(scene))[:2] for _ in range(repeats)]
            out[label] = {"seconds": statistics.median(t for t, _ in times),
                          "cpu_seconds": statistics.median(c for _, c in times), "bytes": path.stat().st_size}
    return out


def bench_row(label: str, resolution: int, width: int, height: int, repeats: int, threads: int) -> dict:
    scene = sphere_scene(resolution, width, height)
    compile_seconds, _, compiled = timed(lambda: difflab.compile_scene(scene))
    difflab.render(compiled, threads=threads)  # warm-up: kernels compiled and loaded
    peer = mesa.MesaRenderer(scene, object_mesh(scene.objects[0])) if mesa.available() is None else None
    ours, theirs, single, image, reference = [], [], [], None, None
    for _ in range(repeats):
        seconds, cpu, image = timed(lambda: difflab.render(compiled, threads=threads))
        ours.append((seconds, cpu))
        if peer is not None:
            seconds, cpu, (_, reference) = timed(peer.draw)
            theirs.append((seconds, cpu))
        single.append(timed(lambda: difflab.render(compiled, threads=1))[0])
    if peer is not None:
        peer.close()
    row = {"mesh": label, "triangles": int(compiled.faces.shape[0]), "width": width, "height": height,
           "compile_seconds": compile_seconds, "difflab_seconds": statistics.median(t for t, _ in ours),
           "difflab_cpu_seconds": statistics.median(c for _, c in ours),
           "difflab_1_thread_seconds": statistics.median(single), "threads": threads}
    row["speedup_1_to_all"] = row["difflab_1_thread_seconds"] / row["difflab_seconds"]
    if peer is not None:
        row["mesa_seconds"] = statistics.median(t for t, _ in theirs)
        row["mesa_cpu_seconds"] = statistics.median(c for _, c in theirs)
        row["difflab_over_mesa"] = row["difflab_seconds"] / row["mesa_seconds"]
        row["difflab_over_mesa_cpu"] = row["difflab_cpu_seconds"] / row["mesa_cpu_seconds"]
        row["psnr_vs_mesa_db"] = psnr(np.round(np.clip(image, 0, 1) * 255) / 255, reference)
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="tiny sizes, for a quick check")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    meshes = {"10k": 50} if args.small else MESHES
    sizes = [(160, 120)] if args.small else SIZES
    threads = cpu_threads()
    why_not = mesa.available()
    load_before = os.getloadavg()
    rows = []
    print(f"{'mesh':>5} {'tris':>8} {'size':>10} {'difflab ms':>10} {'Mesa ms':>8} {'ratio':>6} {'CPU ratio':>9} "
          f"{'1->' + str(threads):>6} {'compile s':>9} {'PSNR dB':>7}")
    for label, resolution in meshes.items():
        for width, height in sizes:
            row = bench_row(label, resolution, width, height, args.repeats, threads)
            rows.append(row)
            print(f"{label:>5} {row['triangles']:>8} {width:>4}x{height:<5} {row['difflab_seconds'] * 1e3:>10.1f} "
                  f"{row.get('mesa_seconds', float('nan')) * 1e3:>8.1f} {row.get('difflab_over_mesa', float('nan')):>6.2f} "
                  f"{row.get('difflab_over_mesa_cpu', float('nan')):>9.2f} "
                  f"{row['speedup_1_to_all']:>6.2f} {row['compile_seconds']:>9.2f} "
                  f"{row.get('psnr_vs_mesa_db', float('nan')):>7.1f}", flush=True)
    width, height = sizes[-1]
    peak = peak_memory_mib(max(meshes.values()), width, height)
    print(f"peak RSS of a fresh process rendering the {width}x{height} {list(meshes)[-1]} frame: {peak:.0f} MiB")
    obj = obj_load_seconds(max(meshes.values()), min(args.repeats, 3))
    for label, row in obj.items():
        print(f"load + compile of the {list(meshes)[-1]}-triangle sphere as {label} ({row['bytes'] / 2 ** 20:.0f} MiB): "
              f"{row['seconds']:.2f} s (CPU {row['cpu_seconds']:.2f} s)")
    if why_not:
        print(f"Mesa not measured: {why_not}")
    result = {"benchmark": "raster_vs_mesa", "statistic": "median", "repeats": args.repeats, "interleaved": True,
              "threads": threads, "rows": rows, "peak_rss_mib": peak, "obj_load": obj,
              "mesa": why_not or "OSMesa llvmpipe",
              "load_average_before": load_before, "load_average_after": os.getloadavg(),
              "versions": {"difflab": difflab.__version__, "warp": warp.config.version,
                           "python": platform.python_version()},
              "machine": platform.machine(), "cpus": os.cpu_count(),
              "max_rss_this_process_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json_atomic(RESULTS / "bench_raster.json", result)
    print(f"wrote {RESULTS / 'bench_raster.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
