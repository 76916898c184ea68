"""Memory and work budgets: estimate what a request will cost before allocating it, refuse it if too big.

Every large allocation in difflab grows with a count we know up front: image samples, triangles of a
tessellation, texels of a texture pyramid, nodes of a ray tree, residuals x parameters of a fit. The
per-unit costs below were MEASURED (peak resident memory above a warmed-up baseline, the slope
between two sizes) by `python experiments/bench/memory.py`, which prints them again with the
estimate beside each measurement; rerun it after a change to a renderer's buffers.

The budget is `DIFFLAB_MEMORY_BUDGET` (bytes, or with a K/M/G/T suffix: "8G") when set, else
BUDGET_FRACTION of the memory this process can still get: the least of the system's available memory
(MemAvailable), the cgroup limit (v2 `memory.max` or v1 `memory.limit_in_bytes`) less its usage, and
the RLIMIT_AS / RLIMIT_DATA address-space limits less what the process has mapped already.

Work (rays traced) has its own budget, MAX_RAYS, raised by `DIFFLAB_MAX_RAYS`: a ray tree that
doubles at every bounce can need more rays than any machine traces, in bounded memory; it is refused
up front instead of running for hours. This module imports no Warp and no JAX.
"""

from __future__ import annotations

import math
import os
import resource
from time import monotonic

from .errors import DifflabError

#: Fraction of the memory still available that one request may take (the rest is for the caller,
#: the interpreter and the estimate's error).
BUDGET_FRACTION = 0.5
#: Largest number of rays one render may trace (worst case, before any adaptive cut-off): 2^30 rays take
#: about 4 minutes at the 4-5 M rays/s of two cores.
MAX_RAYS = 2 ** 30
#: Sample tests the rasterizer's coverage stage may make in one frame (the sum over triangles of
#: their screen bounding boxes, in samples: overdraw); $DIFFLAB_MAX_RASTER_TESTS raises it. Measured
#: on 2 cores: 2,000 full-screen triangles at 512^2 (5.2e8 tests) in 2.9 s, so 2^32 is ~25 s of
#: coverage work, while a 1M-triangle 1080p frame needs ~1e7 tests.
MAX_RASTER_TESTS = 2 ** 32
#: Largest magnitude of a world-space coordinate or size (scene units). The renderers compute in
#: float32: squared distances (ray-sphere tests, attenuation) must stay far below 3.4e38, and the
#: camera's matrices stop being invertible in float64 beyond ~1e16 (measured: an eye at 1e17 gives
#: a singular view-projection matrix).
MAX_COORD = 1e12
#: Largest count of anything one kernel indexes (Warp indexes with 32-bit ints).
MAX_INDEX = 2 ** 31 - 1

# -- measured costs (bytes; experiments/bench/memory.py, slopes between two sizes, 2026-11-29) --------
# Each is the measured slope rounded up by about 10%; the measurement is in the comment.
#: Rasterizer, per sample of the sample grid (G-buffer, shading points, colour, the numpy copies in
#: the Frame; measured 200 with Phong shading) plus per light and shading point (measured 20).
RASTER_SAMPLE_BYTES = 220
RASTER_LIGHT_POINT_BYTES = 24
#: Ray tracer, per sample (colour, fog, counts, sample points; measured ~76) and per recorded
#: ray-tree node (device arrays and numpy copies; measured ~132 with one light, of which ~40 per light;
#: ~140 since `tir_share` added a float32 on the device and its copy: still under 110 + 40).
RAYTRACE_SAMPLE_BYTES = 90
TREE_NODE_BYTES = 110
TREE_NODE_LIGHT_BYTES = 40
#: Per recorded node when a material has an image texture: its texel (vec3) and uv (vec2) float32,
#: on the device and copied (from the dtypes, not measured).
TREE_NODE_TEXTURE_BYTES = 40
#: Per node, light and material when shadow rays count their crossings of transparent surfaces
#: (int32 on the device, its numpy copy, the uint8 result: from the dtypes, not measured).
TREE_CROSSING_BYTES = 9
#: One triangle of a tessellated mesh through compile and a raster frame (float64 mesh arrays,
#: float32 device arrays, normals, uvs, BVH, per-face clip buffers; measured 488 on the teapot).
TRIANGLE_BYTES = 540
#: One byte of a mesh file being loaded (text scan, trimesh, the TriMesh; measured 12.6 on OBJ
#: spheres of 5.6 and 23.8 MB, about 480 bytes per triangle).
MESH_FILE_BYTES = 14
#: One texel of a texture through load, mip pyramid and packing (measured 66 at 1024^2 -> 2048^2, 74 for
#: a one-row texture of as many texels: experiments/bench/memory.py --case texture / texture_strip).
TEXEL_BYTES = 80
#: One pixel of an 8-bit image file being read (decode, table lookup to float32; measured 26.5).
IMAGE_LOAD_BYTES = 30
#: One pixel of an escape-time fractal or the Mandelbulb (measured 108 with `difflab fractal mandelbrot`
#: at 1000^2 and 2000^2), and of a matplotlib curve figure (measured 6 with `difflab fractal koch`).
FRACTAL_PIXEL_BYTES = 120
CURVE_PIXEL_BYTES = 8
#: A fit (fit_material, Levenberg-Marquardt, float64): per residual x fitted number (the Jacobian and
#: the solver's copies; measured 24.4), plus JAX's compilation for a new problem size (measured ~180 MiB).
FIT_ELEMENT_BYTES = 28
FIT_OVERHEAD_BYTES = 256 * 2 ** 20

_SUFFIX = {"": 1, "K": 2 ** 10, "M": 2 ** 20, "G": 2 ** 30, "T": 2 ** 40}


def parse_bytes(text: str, name: str) -> int:
    """'123', '512M', '8G', '1.5T' -> bytes (binary multiples). DifflabError naming `name` if not."""
    raw = str(text).strip().upper().removesuffix("B").removesuffix("I")
    unit = raw[-1:] if raw[-1:] in _SUFFIX and raw[-1:] else ""
    try:
        value = float(raw[: len(raw) - len(unit)]) * _SUFFIX[unit]
    except ValueError:
        value = float("nan")
    if not math.isfinite(value) or value <= 0:
        raise DifflabError(f"{name}: expected a positive size in bytes such as 8G or 512M, got {shorten(text)}")
    return int(value)


def shorten(value, limit: int = 60) -> str:
    """repr(value), cut to `limit` characters: user strings in messages stay short."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def short_path(path, limit: int = 200) -> str:
    """A path for messages: whole if short, else '...' and its last `limit` characters (the file name)."""
    text = os.fspath(path) if isinstance(path, (str, os.PathLike)) else str(path)
    return text if len(text) <= limit else "..." + text[-limit:]


def _read_int(path: str) -> int | None:
    try:
        with open(path) as f:
            text = f.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _meminfo(key: str) -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _vm_size() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


#: Seconds `available_bytes` reuses its last reading: reading /proc and /sys costs ~0.15-0.45 ms, a
#: sizeable part of a small frame rendered again and again (a fit's views), while what a frame
#: may use changes little in that time.
AVAILABLE_MAX_AGE = 0.5
#: A request of at most SMALL_SHARE of the memory available at the last reading is checked against
#: that reading while it is at most SMALL_MAX_AGE seconds old (`require_memory`): such a request fits
#: unless the available memory has since fallen BUDGET_FRACTION / SMALL_SHARE = 32-fold, while
#: re-reading it cost a fit's first frame after a pause (> AVAILABLE_MAX_AGE: one fit at a time)
#: ~0.15-0.45 ms for a 256 x 256 frame of ~15 MiB (1 / 1200 of this VM's 18 GiB available).
SMALL_SHARE = 1 / 64
SMALL_MAX_AGE = 300.0
_available = (-math.inf, 0)  # (monotonic() of the reading, bytes)


def available_bytes() -> int:
    """Memory this process can still allocate (bytes): see the module doc, as read at most
    AVAILABLE_MAX_AGE seconds ago. Unknown limits are ignored."""
    global _available
    now = monotonic()
    if now - _available[0] > AVAILABLE_MAX_AGE:
        _available = (now, _read_available())
    return _available[1]


def _read_available() -> int:
    candidates = [_meminfo("MemAvailable")]
    for limit_path, usage_path in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        limit = _read_int(limit_path)
        if limit is not None and limit < 2 ** 60:
            candidates.append(limit - (_read_int(usage_path) or 0))
    for which in (resource.RLIMIT_AS, resource.RLIMIT_DATA):
        soft = resource.getrlimit(which)[0]
        if soft != resource.RLIM_INFINITY:
            candidates.append(soft - _vm_size())
    known = [c for c in candidates if c is not None]
    return max(0, min(known)) if known else 2 ** 40


def memory_budget() -> int:
    """Bytes one request may use: $DIFFLAB_MEMORY_BUDGET, else BUDGET_FRACTION x `available_bytes()`."""
    value = os.environ.get("DIFFLAB_MEMORY_BUDGET")
    if value:
        return parse_bytes(value, "DIFFLAB_MEMORY_BUDGET")
    return int(BUDGET_FRACTION * available_bytes())


def env_count(name: str, default: int) -> int:
    """The positive integer in environment variable `name`, or `default` when it is unset or empty;
    DifflabError naming the variable otherwise."""
    value = os.environ.get(name, "").strip()
    if not value:
        return default
    if not value.isdigit() or int(value) < 1:
        raise DifflabError(f"{name}: expected a positive integer, got {shorten(value)}")
    return int(value)


def ray_budget() -> int:
    """Rays one render may trace: $DIFFLAB_MAX_RAYS, else MAX_RAYS."""
    return env_count("DIFFLAB_MAX_RAYS", MAX_RAYS)


def gib(nbytes: float, digits: int | None = None) -> str:
    """Bytes as '1.23 GiB' (or '1.2 MiB' below 1 GiB); `digits` after the point if given."""
    if nbytes >= 2 ** 30:
        return f"{nbytes / 2 ** 30:.{2 if digits is None else digits}f} GiB"
    return f"{nbytes / 2 ** 20:.{1 if digits is None else digits}f} MiB"


def sizes_apart(a: float, b: float) -> tuple[str, str]:
    """`a` and `b` bytes as `gib` writes them, with as many more digits (up to 6) as tell two unequal
    sizes apart, else as exact bytes: never 'needs 1.0 MiB, over the budget of 1.0 MiB'."""
    for digits in (None, 2, 3, 4, 5, 6):
        pair = gib(a, digits), gib(b, digits)
        if pair[0] != pair[1] or a == b:
            return pair
    return f"{int(a)} bytes", f"{int(b)} bytes"


def require_memory(nbytes: float, what: str, error: type[DifflabError] = DifflabError, hint: str = "") -> None:
    """Raise `error("what: needs about X, over the memory budget of Y ...")` if `nbytes` > the budget
    (a small request against the last reading of the available memory: `SMALL_SHARE`)."""
    read_at, available = _available
    if nbytes <= SMALL_SHARE * available and monotonic() - read_at <= SMALL_MAX_AGE and \
            not os.environ.get("DIFFLAB_MEMORY_BUDGET"):
        return
    budget = memory_budget()
    if nbytes > budget:
        need, have = sizes_apart(nbytes, budget)
        raise error(f"{what}: needs about {need}, over the memory budget of {have} "
                    f"({'DIFFLAB_MEMORY_BUDGET' if os.environ.get('DIFFLAB_MEMORY_BUDGET') else 'half the available memory'}"
                    f"; set DIFFLAB_MEMORY_BUDGET to raise it){'; ' + hint if hint else ''}")


def require_count(count: int, what: str, error: type[DifflabError] = DifflabError, limit: int = MAX_INDEX) -> None:
    """Raise `error` if `count` exceeds what a kernel can index (`limit`)."""
    if count > limit:
        raise error(f"{what}: {count} is over the limit of {limit} (32-bit indices)")


# -- estimates ----------------------------------------------------------------------------------------------

def raster_frame_bytes(samples: int, n_points: int, n_lights: int, n_faces: int) -> int:
    """Peak bytes of one rasterized frame: samples x RASTER_SAMPLE_BYTES + shading points x lights x
    RASTER_LIGHT_POINT_BYTES + faces x TRIANGLE_BYTES."""
    return samples * RASTER_SAMPLE_BYTES + n_points * n_lights * RASTER_LIGHT_POINT_BYTES + n_faces * TRIANGLE_BYTES


def ray_tree_nodes(max_depth: int, branching: int, weight: float = 1.0, threshold: float = 0.0,
                   spread: float | None = None) -> int:
    """Upper bound on the nodes of one sample's ray tree: 1 + b + b^2 + ... over the levels a ray can
    reach. b = rays a hit can spawn (0, 1: reflection or refraction, 2: both). With Hall's adaptive
    control (threshold t > 0) a ray is traced only while its weight is >= t:
    - every spawned ray's weight is at most `weight` w times its parent's, so a ray at level k weighs
      <= w^(k-1) and (w < 1) levels stop at 1 + log(t) / log(w);
    - the weights of one hit's children sum to at most `spread` s times its own (default b w), so a
      level's weights sum to <= s^(k-1) and level k holds at most s^(k-1) / t rays (and b^(k-1))."""
    levels = int(max_depth)
    if threshold > 0.0 and 0.0 <= weight < 1.0:
        cut = 1 if weight == 0.0 else 1 + math.floor(math.log(threshold) / math.log(weight)) + 1
        levels = max(1, min(levels, cut))
    if branching <= 1:
        return levels if branching == 1 else 1
    if threshold <= 0.0:
        return min(2 ** 62, branching ** levels - 1)
    s = branching * weight if spread is None else spread
    nodes = count = 1  # the primary ray
    for k in range(1, levels):  # level k + 1 holds <= min(b x level k's, s^k / t) rays
        count = min(branching * count, math.floor(s ** k / threshold * (1.0 + 1e-9)))  # (rounding drops no ray)
        nodes += count
        if count == 0 or nodes >= 2 ** 62:
            break
    return min(nodes, 2 ** 62)


def raytrace_bytes(samples: int, nodes: int, n_lights: int, record: bool, textured: bool = False) -> int:
    """Peak bytes of a ray-traced frame: samples x RAYTRACE_SAMPLE_BYTES, plus the recorded tree
    (`textured`: its nodes record texels and uv too)."""
    per_node = TREE_NODE_BYTES + n_lights * TREE_NODE_LIGHT_BYTES + (TREE_NODE_TEXTURE_BYTES if textured else 0)
    tree = nodes * per_node if record else 0
    return samples * RAYTRACE_SAMPLE_BYTES + tree


def check_rays(samples: int, nodes_per_sample: int, n_lights: int, what: str,
               error: type[DifflabError] = DifflabError, hint: str = "lower max_depth, kr / kt, spp or the image size"
               ) -> None:
    """Refuse a render whose worst-case ray count (samples x nodes x (1 + lights)) is over the ray
    budget; the message ends with `hint` (what can bring the count down)."""
    rays = samples * nodes_per_sample * (1 + n_lights)
    budget = ray_budget()
    if rays > budget:
        raise error(f"{what}: up to {rays:.3g} rays ({samples} samples x {nodes_per_sample:.3g} ray-tree nodes x "
                    f"{1 + n_lights} rays per node) is over the budget of {budget:.3g} rays (set DIFFLAB_MAX_RAYS to "
                    f"raise it); {hint}")


def check_raster_work(tests: int, n_triangles: int, what: str, error: type[DifflabError] = DifflabError) -> None:
    """Refuse a raster frame whose coverage stage would make more sample tests than the budget."""
    budget = env_count("DIFFLAB_MAX_RASTER_TESTS", MAX_RASTER_TESTS)
    if tests > budget:
        raise error(f"{what}: rasterizing {n_triangles} triangles means {tests:.3g} sample tests (their screen "
                    f"bounding boxes, overlapping), over the budget of {budget:.3g} (set DIFFLAB_MAX_RASTER_TESTS "
                    "to raise it); lower the image size or spp, or draw fewer overlapping triangles")


def require_triangles(n_triangles: int, what: str, error: type[DifflabError] = DifflabError) -> None:
    """Refuse a tessellation of `n_triangles` over the memory budget (TRIANGLE_BYTES each) or int32 range."""
    require_count(n_triangles, what, error)
    require_memory(n_triangles * TRIANGLE_BYTES, f"{what} ({n_triangles} triangles)", error)


def require_image(width: int, height: int, what: str, per_pixel: int = IMAGE_LOAD_BYTES,
                  error: type[DifflabError] = DifflabError) -> None:
    """Refuse reading or building a width x height image over the memory budget."""
    require_memory(width * height * per_pixel, f"{what} ({width} x {height} pixels)", error)


def fit_bytes(n_residuals: int, n_params: int) -> int:
    """Peak bytes of a least-squares fit: FIT_OVERHEAD_BYTES + residuals x parameters x FIT_ELEMENT_BYTES."""
    return FIT_OVERHEAD_BYTES + n_residuals * max(1, n_params) * FIT_ELEMENT_BYTES
