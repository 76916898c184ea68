"""Memory per unit of work, measured: the costs `difflab/limits.py` budgets with.

Each case runs in a fresh process: warm up (compile kernels at a tiny size), note the resident set,
reset the kernel's peak counter (/proc/self/clear_refs), run the case at size N, and report the peak
resident memory above the warmed-up baseline. Two sizes per case give the slope (bytes per sample,
triangle, texel, ray-tree node); it is printed beside the estimate `difflab.limits` makes for the
larger size, so a renderer change that grows its buffers shows as an estimate below the measurement.
Writes experiments/results/bench_memory.json.

    python experiments/bench/memory.py            # all cases
    python experiments/bench/memory.py --small    # smaller sizes (slopes are noisier)
    python experiments/bench/memory.py --case raster --size 512   # one case, one process (JSON line)
"""

from __future__ import annotations

import argparse
import gc
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / "results"


def rss_kib(field: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    raise RuntimeError(field)


def scene(size: int, objects, materials, lights=1, **render):
    import difflab

    return difflab.Scene.from_dict({
        "camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "fov_y": 40, "width": size, "height": size},
        "ambient": 0.1,
        "lights": [{"type": "point", "position": [3 + i, 4, 5]} for i in range(lights)],
        "materials": materials, "objects": objects, "render": render})


WALL = {"type": "plane", "point": [0, 0, -1], "normal": [0, 0, 1], "material": "m"}  # covers every sample
DEEP = 8
MATTE = {"m": {"kd": 0.7, "ks": 0.3, "n": 20}}


def run(case: str, size: int) -> dict:
    """Build the case at `size`, return {units, peak_bytes, estimate_bytes} (units: the count the cost is per)."""
    import difflab
    from difflab import limits

    def raster(n, lights):
        return difflab.render_frame(scene(n, [WALL], MATTE, lights, method="raster", shading="phong"))

    def raytrace(n):
        return difflab.render_frame(scene(n, [WALL], MATTE, 1, method="raytrace", max_depth=1))

    def raytrace_deep(n):  # two facing mirrors: every sample's tree is a chain of DEEP nodes
        mirrors = [WALL, {"type": "plane", "point": [0, 0, 6], "normal": [0, 0, -1], "material": "m"}]
        return difflab.render_frame(scene(n, mirrors, {"m": {"kd": 0.5, "kr": 0.5}}, 1, method="raytrace",
                                          max_depth=DEEP))

    def teapot(r, n=32):
        return difflab.render_frame(scene(n, [{"type": "mesh", "builtin": "teapot", "resolution": r, "material": "m"}],
                                          MATTE, 1, method="raster"))

    texture_dir = Path(tempfile.mkdtemp())

    def texture(n):  # n x n texels; "texture_strip": the same texels in one row (mip levels 1 x ...)
        shape = (1, n * n) if case == "texture_strip" else (n, n)
        path = texture_dir / f"tex{shape[0]}x{shape[1]}.png"
        if not path.exists():
            difflab.save_image(path, np.random.default_rng(0).random(shape + (3,)).astype(np.float32))
        materials = {"m": {"kd": 1.0, "texture": str(path), "filter": "trilinear"}}
        return path, lambda: difflab.render_frame(scene(8, [WALL], materials, 1, method="raster"))

    def load(n):
        path = texture_dir / f"img{n}.png"
        difflab.save_image(path, np.random.default_rng(0).random((n, n, 3)).astype(np.float32))
        return lambda: difflab.load_image(path)

    def obj(n):  # an OBJ file of a uv sphere with n bands, 4 n^2 triangles
        from difflab.geometry import load_mesh, uv_sphere

        path = texture_dir / f"sphere{n}.obj"
        mesh = uv_sphere(1.0, n_lat=n, n_lon=2 * n)
        path.write_text("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in mesh.vertices)
                        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces))
        return path, lambda: load_mesh(path)

    def fit(n):  # fit ka, kd, ks, n (10 numbers) of a sphere to an n x n target of itself
        sphere = scene(n, [{"type": "sphere", "center": [0, 0, 0], "radius": 1.5, "material": "m"}],
                       {"m": {"ka": 0.1, "kd": [0.6, 0.3, 0.2], "ks": 0.4, "n": 20}}, 1, method="raster")
        target = difflab.render(sphere)
        return lambda: difflab.fit_material(sphere, [target], "m", max_steps=5)

    lights = 5 if case == "raster_lights" else 1
    warm = {"raster": lambda: raster(8, lights), "raster_lights": lambda: raster(8, lights),
            "raytrace": lambda: raytrace(8), "raytrace_deep": lambda: raytrace_deep(8), "teapot": lambda: teapot(2), "texture": texture(8)[1],
            "texture_strip": texture(8)[1],
            "load": load(8), "obj": obj(4)[1], "fit": fit(8)}[case]
    warm()
    if case in ("texture", "texture_strip"):
        _, work = texture(size)
    elif case == "load":
        work = load(size)
    elif case == "obj":
        obj_path, work = obj(size)
    elif case == "fit":
        work = fit(size)
    else:
        work = {"raster": lambda: raster(size, lights), "raster_lights": lambda: raster(size, lights),
                "raytrace": lambda: raytrace(size), "raytrace_deep": lambda: raytrace_deep(size),
                "teapot": lambda: teapot(size)}[case]
    gc.collect()
    base = rss_kib("VmRSS")
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # reset VmHWM to the current resident set
    result = work()
    peak = (rss_kib("VmHWM") - base) * 1024
    if case in ("raster", "raster_lights"):
        units = size * size
        estimate = limits.raster_frame_bytes(units, units, lights, result.stats["triangles"])
    elif case in ("raytrace", "raytrace_deep"):
        units = result.stats["nodes"]
        estimate = limits.raytrace_bytes(size * size, units, 1, True)
    elif case == "teapot":
        units = result.stats["triangles"]
        estimate = limits.raster_frame_bytes(32 * 32, 32 * 32, 1, units)
    elif case == "fit":
        units = size * size * 3 * 10  # residuals x fitted numbers
        estimate = limits.fit_bytes(size * size * 3, 10)
    elif case == "obj":
        units = obj_path.stat().st_size
        estimate = units * limits.MESH_FILE_BYTES
    else:
        units = size * size
        estimate = units * (limits.IMAGE_LOAD_BYTES if case == "load" else limits.TEXEL_BYTES)
    return {"case": case, "size": size, "units": units, "peak_bytes": peak, "estimate_bytes": int(estimate)}


CASES = {  # case: (small sizes, full sizes, unit)
    "raster": ((256, 512), (512, 1024), "sample"),
    "raster_lights": ((256, 512), (512, 1024), "sample (5 lights)"),
    "raytrace": ((256, 512), (512, 1024), "node (1 per sample)"),
    "raytrace_deep": ((128, 256), (256, 512), f"node ({DEEP} per sample)"),
    "teapot": ((32, 64), (64, 128), "triangle"),
    "texture": ((512, 1024), (1024, 2048), "texel"),
    "texture_strip": ((512, 1024), (1024, 2048), "texel (one row)"),
    "load": ((512, 1024), (1024, 2048), "pixel"),
    "obj": ((100, 200), (200, 400), "byte of an OBJ file"),
    "fit": ((64, 128), (128, 256), "residual x parameter (fit_material, lm)"),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true")
    parser.add_argument("--case", choices=sorted(CASES))
    parser.add_argument("--size", type=int)
    args = parser.parse_args()
    if args.case and args.size:
        print(json.dumps(run(args.case, args.size)))
        return
    rows = []
    print(f"{'case':15} {'size':>6} {'units':>10} {'peak MiB':>9} {'est. MiB':>9} {'bytes/unit (slope)':>19}")
    for case, (small, full, unit) in CASES.items():
        if args.case and case != args.case:
            continue
        points = []
        for size in small if args.small else full:
            out = subprocess.run([sys.executable, __file__, "--case", case, "--size", str(size)], check=True,
                                 capture_output=True, text=True)
            points.append(json.loads(out.stdout.strip().splitlines()[-1]))
        (a, b) = points
        slope = (b["peak_bytes"] - a["peak_bytes"]) / max(1, b["units"] - a["units"])
        for p in points:
            print(f"{case:15} {p['size']:>6} {p['units']:>10} {p['peak_bytes'] / 2**20:>9.1f} "
                  f"{p['estimate_bytes'] / 2**20:>9.1f} {slope:>19.1f}")
        rows.append({"case": case, "unit": unit, "points": points, "bytes_per_unit": slope})
    RESULTS.mkdir(parents=True, exist_ok=True)
    import difflab
    from difflab.io import write_json_atomic

    write_json_atomic(RESULTS / "bench_memory.json", {
        "what": "peak resident bytes above a warmed-up baseline; slope between two sizes",
        "python": platform.python_version(), "difflab": difflab.__version__, "rows": rows})
    print(f"wrote {RESULTS / 'bench_memory.json'}")


if __name__ == "__main__":
    main()
