"""JAX's set-up for difflab's fits, done at import of `params` (which every fit module imports), before
any JAX array is made: its persistent compilation cache, so that a new process reuses the compiled
solves, and its CPU threads (`limit_xla_threads`).

The cache lives in the user's cache directory -- $DIFFLAB_CACHE_DIR if set, else
$XDG_CACHE_HOME/difflab/jax, else ~/.cache/difflab/jax -- and is switched off by
DIFFLAB_CACHE_DIR=off. Every compilation is cached (no minimum compile time), since each fit's
first step otherwise pays seconds of compilation.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
from jax._src import xla_bridge

from ..errors import DifflabError
from ..limits import shorten

ENV = "DIFFLAB_CACHE_DIR"
THREADS_ENV = "DIFFLAB_JAX_THREADS"


def cache_dir() -> Path | None:
    """Where compiled programs are kept (None: caching off)."""
    value = os.environ.get(ENV, "").strip()
    if value.lower() == "off":
        return None
    if value:
        return Path(value).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or str(Path.home() / ".cache")
    return Path(base) / "difflab" / "jax"


def enable_compilation_cache() -> Path | None:
    """Point JAX's persistent compilation cache at `cache_dir()` (once per process); the path, or
    None when off or when the directory cannot be made (fits still run, compiling each time)."""
    path = cache_dir()
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


def limit_xla_threads() -> int | None:
    """Give XLA's CPU client $DIFFLAB_JAX_THREADS threads (a count; unset, `all` or 0: XLA's own
    default, one per core) by creating JAX's backends now with NPROC set to that count -- XLA sizes
    its intra-op (Eigen) pool and its client's pool from it -- and NPROC put back at once. The count
    set, or None where nothing is done: XLA's default, or JAX's backends made already (left as they
    are). NPROC, not a narrowed CPU affinity, so that no thread is left pinned.

    Why one thread can pay: a small solve's operations (~25k pixels at 256^2, the moments' steps)
    gain nothing from a second thread, and each one handed to the pool wakes a sleeping thread (~22
    wake-ups a solve on 2 cores, 1 with one thread), tens of microseconds each on a shared virtual
    machine: the Mitsuba sphere's kd, ks, n fit, 53 pairs of processes alternating 1 / all (2 cores,
    load 2.4-3.9), solve 3.66 -> 2.75 ms in a first fit of the view, whole fit 11.04 -> 10.33 ms.
    Why it is not the default: fits that take their Jacobian by forward mode lose 1.5-1.8x (256^2,
    alternating processes at load ~0.7: with the lights' intensities fitted 51-56 -> 81-83 ms, at
    4 samples a pixel 123 -> 225 ms; a plain JAX step 10.5 -> 18 ms; docs/api.md).
    """
    value = os.environ.get(THREADS_ENV, "").strip().lower() or "all"
    if value != "all" and not value.isdecimal():
        raise DifflabError(f"{THREADS_ENV}: expected a positive integer, 0 or 'all', got {shorten(value)}")
    if value == "all" or int(value) == 0 or xla_bridge.backends_are_initialized():
        return None
    nproc = os.environ.get("NPROC")
    os.environ["NPROC"] = str(int(value))
    try:
        jax.devices()
    finally:
        if nproc is None:
            del os.environ["NPROC"]
        else:
            os.environ["NPROC"] = nproc
    return int(value)
