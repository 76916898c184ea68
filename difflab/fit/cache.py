"""JAX's set-up for difflab's fits, done at import of `params` (which every fit module imports), before
any JAX array is made: its persistent compilation cache, so that a new process reuses the compiled
solves, its CPU threads (`limit_xla_threads`), and a second CPU client of one thread for the fits that
step in closed form (`register_serial_cpu`, `serial_cpu_device`).

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
SERIAL_BACKEND = "difflab_serial_cpu"


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
    made_with_nproc(int(value), jax.devices)
    return int(value)


def made_with_nproc(count: int, make):
    """`make()` with NPROC set to `count` -- XLA sizes a CPU client's pools from it when the client is
    made --, NPROC put back after."""
    nproc = os.environ.get("NPROC")
    os.environ["NPROC"] = str(count)
    try:
        return make()
    finally:
        if nproc is None:
            del os.environ["NPROC"]
        else:
            os.environ["NPROC"] = nproc


_serial = {"registered": False}


def register_serial_cpu() -> bool:
    """Register a second JAX CPU backend, SERIAL_BACKEND, whose client XLA makes with one thread (NPROC
    1 while it is made, as `limit_xla_threads` does), beside the default one -- before JAX makes its
    backends, so that it is made with them. Whether it was registered: not where the user set
    $DIFFLAB_JAX_THREADS to a count (their client serves every fit), on one core, or once JAX's
    backends exist. (JAX's backend registry is private API: where it is missing or fails, fits keep
    the one client.)"""
    value = os.environ.get(THREADS_ENV, "").strip().lower() or "all"
    if value not in ("all", "0") or (os.cpu_count() or 1) < 2 or xla_bridge.backends_are_initialized():
        return False

    try:
        xla_bridge.register_backend_factory(SERIAL_BACKEND, lambda: made_with_nproc(1, xla_bridge.make_cpu_client),
                                            priority=-100)
    except Exception:  # noqa: BLE001 (a JAX without this private hook: the default client only)
        return False
    _serial["registered"] = True
    return True


def serial_cpu_device():
    """The one-thread CPU client's device (`register_serial_cpu`), or None: not registered, JAX's
    default backend not the CPU, or a default device the user set (`jax.default_device`).

    Why a fit steps there when its normal equations are formed in closed form (`Setup.jax_device`):
    such a solve's operations on ~25k pixels are too small to gain from a second thread, and each one
    XLA hands to its pool wakes a sleeping thread -- tens of microseconds each on a shared virtual
    machine -- while fits that take their Jacobian by forward mode need every core (1.5-1.8x slower on
    one thread: `limit_xla_threads`). The bench's Mitsuba sphere (kd, ks, n, 256^2) against the
    default client, processes alternating in ABBA order (three runs of 10-12 rounds, medians of 25
    fits, load 0.3-0.9): the solve 1.77-1.84 -> 1.58-1.68 ms; first fit of the view paired -0.35,
    -0.03 and -0.24 ms (faster in 7 of 10, 6 of 10, 8 of 12), fitted again -0.18, 0.00, -0.13, in a
    row -0.11, +0.11, -0.02 (the report, whose JAX work runs there too, is no faster)."""
    if not _serial["registered"]:
        return None
    if "device" not in _serial:
        try:
            _serial["device"] = jax.devices(SERIAL_BACKEND)[0] if jax.default_backend() == "cpu" else None
        except Exception:  # noqa: BLE001 (the backend failed to start: the default client only)
            _serial["device"] = None
    device, chosen = _serial["device"], jax.config.jax_default_device
    return device if chosen is None or chosen is device else None
