"""The benchmarks' timing: the median wall time of repeated calls, and a worker in a fresh process."""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time


def median_seconds(fn, repeats: int) -> float:
    """Median wall-clock seconds of `repeats` calls of `fn()` (one call per sample: the median
    resists a shared machine's spikes, as a mean does not)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def worker_in(tree, script, *args) -> dict:
    """Run `script --worker ARGS` in a fresh process with `tree` (a checkout) first on the path and
    no compilation cache -- how a benchmark times another version of difflab beside this one --
    and return the JSON its last printed line holds."""
    env = {**os.environ, "PYTHONPATH": str(tree), "DIFFLAB_CACHE_DIR": "off", "MPLBACKEND": "Agg"}
    out = subprocess.run([sys.executable, str(script), "--worker", *map(str, args)], env=env, capture_output=True,
                         text=True, check=True, cwd=tree).stdout
    return json.loads(out.strip().splitlines()[-1])
