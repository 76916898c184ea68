"""Benchmark: compiling a ray-traced scene of many spheres (a row-major grid of radius-0.3 spheres
and a box, 64 x 64 camera): median milliseconds of `compile_scene` on a parsed `Scene` and on the
scene's dict (parsing included). What docs/api.md's "compiles in milliseconds" rests on.

    python experiments/bench/compile_spheres.py            # 1000 and 8000 spheres, 5 repeats
    python experiments/bench/compile_spheres.py --small    # 1000 spheres, 3 repeats
"""

from __future__ import annotations

import argparse

import difflab
from difflab.scene import Scene
from timing import median_seconds

MS = 1e3  # milliseconds a second


def spheres_scene(n: int) -> dict:
    """n spheres in rows of 50 receding from the camera, and a box."""
    spheres = [{"type": "sphere", "center": [float(i % 50) - 25, 0.0, -float(i // 50)], "radius": 0.3,
                "material": "red"} for i in range(n)]
    return {"camera": {"eye": [0, 5, 30], "target": [0, 0, 0], "fov_y": 45, "width": 64, "height": 64},
            "materials": {"red": {"kd": [0.7, 0.1, 0.1]}},
            "lights": [{"type": "directional", "direction": [0, -1, -1]}],
            "objects": spheres + [{"type": "mesh", "builtin": "box", "material": "red"}]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="1000 spheres, 3 repeats")
    args = parser.parse_args(argv)
    sizes, repeats = ((1000,), 3) if args.small else ((1000, 8000), 5)
    difflab.compile_scene(spheres_scene(10))  # warm up (Warp kernels)
    print(f"{'spheres':>8} {'compile Scene ms':>17} {'compile dict ms':>16}")
    for n in sizes:
        data = spheres_scene(n)
        scene = Scene.from_dict(data)
        print(f"{n:8d} {MS * median_seconds(lambda: difflab.compile_scene(scene), repeats):17.1f} "
              f"{MS * median_seconds(lambda: difflab.compile_scene(data), repeats):16.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
