"""Benchmark: the Mandelbrot set at 1920x1080 on one CPU thread versus all cores.

Warp runs one CPU launch on one thread; difflab splits a launch into row bands on a thread pool
(difflab.renderers.launch). This measures what that buys on this machine: the median wall time of
`difflab.fractals.mandelbrot` (escape-time kernel + colouring kernel + copy to numpy) over repeats,
with threads=1 and with every core, and their ratio. Kernels are compiled (and warmed) first.

    python experiments/bench/fractals.py            # 1920x1080, 5 repeats
    python experiments/bench/fractals.py --small    # 480x270, 3 repeats: a quick check

Writes experiments/results/bench_fractals.json (atomically) and prints a table and a summary line.
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
import warp as wp

from difflab.fractals import mandelbrot
from difflab.io import write_json_atomic
from difflab.renderers.bandpool import cpu_threads

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench_fractals.json"


def time_call(fn, repeats: int) -> list[float]:
    """Wall times (seconds) of `repeats` calls of fn()."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return times


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="480x270 and 3 repeats, for a quick run")
    parser.add_argument("--repeats", type=int, default=None, help="repeats per configuration (default 5)")
    parser.add_argument("--max-iter", type=int, default=256, help="escape iterations (default 256)")
    parser.add_argument("-o", "--output", type=Path, default=RESULTS, help=f"JSON output (default {RESULTS})")
    args = parser.parse_args(argv)

    width, height = (480, 270) if args.small else (1920, 1080)
    repeats = args.repeats or (3 if args.small else 5)
    all_threads = cpu_threads()
    view = dict(center=(-0.5, 0.0), scale=3.0, max_iter=args.max_iter, device="cpu")

    reference = mandelbrot(width, height, threads=1, **view)  # compiles and warms the kernels
    rows = []
    for label, threads in (("1 thread", 1), (f"{all_threads} threads", all_threads)):
        image = mandelbrot(width, height, threads=threads, **view)
        identical = bool(np.array_equal(image, reference))  # banding must not change a pixel
        times = time_call(lambda: mandelbrot(width, height, threads=threads, **view), repeats)
        rows.append({"config": label, "threads": threads, "median_s": statistics.median(times),
                     "times_s": times, "identical_to_one_thread": identical})
    speedup = rows[0]["median_s"] / rows[1]["median_s"]

    result = {
        "benchmark": "mandelbrot escape time + colouring, CPU, one thread vs all cores",
        "width": width, "height": height, "max_iter": args.max_iter, "center": view["center"],
        "scale": view["scale"], "repeats": repeats, "cpu_count": os.cpu_count(),
        "rows": rows, "speedup_all_vs_one": speedup,
        "megapixels_per_s_all": width * height / rows[1]["median_s"] / 1e6,
        "versions": {"python": platform.python_version(), "numpy": np.__version__, "warp": wp.config.version},
        "platform": platform.platform(), "seed": None,
    }
    write_json_atomic(args.output, result)

    print(f"{'config':<14}{'median (s)':>12}{'Mpx/s':>10}{'identical':>11}")
    for row in rows:
        print(f"{row['config']:<14}{row['median_s']:>12.4f}{width * height / row['median_s'] / 1e6:>10.2f}"
              f"{str(row['identical_to_one_thread']):>11}")
    print(f"mandelbrot {width}x{height}, max_iter {args.max_iter}: {all_threads} threads are "
          f"{speedup:.2f}x faster than 1 (median of {repeats}); wrote {args.output}")
    return 0 if all(row["identical_to_one_thread"] for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
