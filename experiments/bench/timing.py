"""The benchmarks' one timer: the median wall time of repeated calls."""

from __future__ import annotations

import statistics
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
