"""What the whiteness test (`fit.whiteness`) adds to a fit's statistics phase: `whiteness` against
the noise estimate it follows (`fit.noise._estimate`), on the same views' picks and residual planes,
timed interleaved (medians of --repeats calls, --rounds alternations), for a sphere of the
fitting tests' scene at each --size with Gaussian noise 0.01 (the residuals of a correct fit).

    python experiments/bench/noise_white.py [--sizes 96 256] [--rounds 5] [--repeats 200]

Prints per size: the used pixels, the lattice's points, both medians (ms) and their ratio, and the
load average (the machine is shared: quote the ratio)."""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from difflab import Scene, render_frame
from difflab.fit.noise import _estimate, _view_picks
from difflab.fit.whiteness import _view_log_ratios, whiteness


def sphere(size: int) -> Scene:
    return Scene.from_dict({
        "camera": {"eye": [0, 1.2, 4], "target": [0, 0.6, 0], "up": [0, 1, 0], "fov_y": 40, "width": size,
                   "height": size},
        "ambient": [0.2, 0.2, 0.2], "background": [0, 0, 0],
        "lights": [{"type": "point", "position": [3, 4, 3], "intensity": [1, 1, 1]}],
        "materials": {"red": {"ka": [0.1, 0.05, 0.02], "kd": [0.7, 0.2, 0.1], "ks": [0.5, 0.4, 0.3], "n": 24.0}},
        "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"}]})


def median_ms(call, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[96, 256])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args(argv)
    for size in args.sizes:
        frame = render_frame(sphere(size))
        used = frame.gbuffer.mask
        rng = np.random.default_rng(0)
        residual = rng.normal(0.0, 0.01, frame.image.shape).astype(np.float32) * used[..., None]
        views = [_view_picks(used, None, frame.image, True)]
        planes = [np.ascontiguousarray(np.moveaxis(residual, -1, 0))]
        points = _view_log_ratios(views[0], planes[0])[1]
        estimate, white = [], []
        for _ in range(args.rounds):
            estimate.append(median_ms(lambda: _estimate(views, planes), args.repeats))
            white.append(median_ms(lambda: whiteness(views, planes), args.repeats))
        e, w = float(np.median(estimate)), float(np.median(white))
        print(f"{size} x {size}: {int(used.sum())} used pixels, {points} lattice points; noise estimate "
              f"{e:.3f} ms, whiteness {w:.3f} ms (+{100 * w / e:.0f} %); load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
