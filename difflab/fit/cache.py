"""JAX's persistent compilation cache, so that a new process reuses the compiled solves.

The cache lives in the user's cache directory -- $DIFFLAB_CACHE_DIR if set, else
$XDG_CACHE_HOME/difflab/jax, else ~/.cache/difflab/jax -- and is switched off by
DIFFLAB_CACHE_DIR=off. Every compilation is cached (no minimum compile time), since each fit's
first step otherwise pays seconds of compilation.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

ENV = "DIFFLAB_CACHE_DIR"


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
