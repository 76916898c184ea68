"""The ray tracer's peers for `raytrace.py`: Mitsuba 3's `scene.ray_intersect` on the same rays, and
POV-Ray 3.7 on the same Whitted scene (spheres, a checkered plane, point lights, mirror and glass).

    trace, variant = mitsuba_tracer(obj_path, origins, directions)  # (None, None) when Mitsuba is missing
    wall, cpu = trace()                                             # one timed ray_intersect of all rays
    povray_seconds(scene, repeats)                                   # None when povray is missing
"""

from __future__ import annotations

import os
import resource
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np


def mitsuba_variant() -> str | None:
    """llvm_ad_rgb when Mitsuba and its LLVM backend (libllvm) load, else scalar_rgb, else None."""
    try:
        import mitsuba as mi
    except ImportError:
        return None
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        try:
            mi.set_variant(variant)
            return variant
        except Exception:  # noqa: BLE001 - a variant whose backend is missing
            continue
    return None


def mitsuba_tracer(obj_path: Path, origins: np.ndarray, directions: np.ndarray):
    """A function timing one `scene.ray_intersect` (closest hit, t and primitive index evaluated) of
    the given (N, 3) rays, returning (wall, CPU) seconds (CPU: all of the process's threads), already
    called once (the first call JIT-compiles the kernel); and the variant used. (None, None) without
    Mitsuba."""
    variant = mitsuba_variant()
    if variant is None:
        return None, None
    import drjit as dr
    import mitsuba as mi

    scene = mi.load_dict({"type": "scene", "mesh": {"type": "obj", "filename": str(obj_path)}})
    rays = mi.Ray3f(o=mi.Point3f(*[origins[:, k].astype(np.float32) for k in range(3)]),
                    d=mi.Vector3f(*[directions[:, k].astype(np.float32) for k in range(3)]))
    dr.eval(rays)

    def trace() -> tuple[float, float]:
        start, start_cpu = time.perf_counter(), time.process_time()
        hit = scene.ray_intersect(rays)
        dr.eval(hit.t, hit.prim_index)
        dr.sync_thread()
        return time.perf_counter() - start, time.process_time() - start_cpu

    trace()
    return trace, variant


def pov_vec(v) -> str:
    return f"<{v[0]:.6g}, {v[1]:.6g}, {-v[2]:.6g}>"  # POV-Ray is left-handed: flip z


def pov_colour(c) -> str:
    return f"rgb <{c[0]:.6g}, {c[1]:.6g}, {c[2]:.6g}>"


def pov_finish(m) -> str:
    """The difflab material as a POV-Ray finish (Phong highlight, plain kr reflection, no Fresnel)."""
    return (f"finish {{ ambient {pov_colour(m.ka)} diffuse 1 phong {max(m.ks):.6g} phong_size {m.n:.6g} "
            f"reflection {{ {m.kr:.6g} }} }}")


def pov_pigment(m) -> str:
    filt = f" transmit {m.kt:.6g}" if m.kt > 0 else ""
    if m.checker is not None:
        return (f"pigment {{ checker {pov_colour(m.kd)}{filt} {pov_colour(m.checker.kd2)}{filt} "
                f"scale {m.checker.size:.6g} }}")
    return f"pigment {{ {pov_colour(m.kd)}{filt} }}"


def to_pov(scene) -> str:
    """A POV-Ray 3.7 scene for a difflab scene of spheres, planes and point lights."""
    from difflab.scene import Plane, Sphere

    cam = scene.camera
    aspect = cam.width / cam.height
    lines = ["#version 3.7;", f"global_settings {{ max_trace_level {scene.render.max_depth} ambient_light rgb 1 }}",
             f"background {{ {pov_colour(scene.background)} }}",
             f"camera {{ perspective location {pov_vec(cam.eye)} look_at {pov_vec(cam.target)} "
             f"sky {pov_vec(cam.up)} right x*{aspect:.6g} "
             f"angle {2 * np.degrees(np.arctan(np.tan(np.radians(cam.fov_y) / 2) * aspect)):.6g} }}"]
    for light in scene.lights:
        lines.append(f"light_source {{ {pov_vec(light.position)} color {pov_colour(light.intensity)} }}")
    for obj in scene.objects:
        m = scene.materials[obj.material]
        interior = f" interior {{ ior {m.ior:.6g} }}" if m.kt > 0 else ""
        body = f"texture {{ {pov_pigment(m)} {pov_finish(m)} }}{interior}"
        if isinstance(obj, Sphere):
            lines.append(f"sphere {{ {pov_vec(obj.center)}, {obj.radius:.6g} {body} }}")
        elif isinstance(obj, Plane):
            normal = np.asarray(obj.normal, float)
            lines.append(f"plane {{ {pov_vec(normal)}, {float(np.dot(normal, obj.point)):.6g} {body} }}")
        else:
            raise ValueError(f"the POV-Ray export takes spheres and planes, not {type(obj).__name__}")
    return "\n".join(lines) + "\n"


def povray_seconds(scene, repeats: int, threads: int) -> tuple[float, float] | None:
    """Median wall time and CPU time (user + system of the child) of `povray` rendering the scene
    (parse + trace, no anti-aliasing, no display, `threads` render threads); None without povray."""
    povray = shutil.which("povray")
    if povray is None:
        return None
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "scene.pov"
        path.write_text(to_pov(scene))
        command = [povray, f"+I{path}", f"+O{Path(folder) / 'out.png'}", f"+W{scene.camera.width}",
                   f"+H{scene.camera.height}", "-D", "-A", "+Q9", f"+WT{threads}", "-V", "-GA"]
        times, cpu = [], []
        for _ in range(repeats):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.perf_counter()
            subprocess.run(command, capture_output=True, check=True, cwd=folder, env={**os.environ, "HOME": folder})
            times.append(time.perf_counter() - start)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return statistics.median(times), statistics.median(cpu)
