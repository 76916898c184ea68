"""Rasterizer stage 3: binning, coverage and the z-buffer.

`bin_kernel` lists the slots meeting each band of rows (stage 2 counted them), so that each band's
coverage launch reads only its own triangles.
For every sample centre inside a screen triangle (exact integer edge functions with a top-left-style
fill rule: a shared edge's samples go to exactly one triangle) the kernel writes min(depth, slot) into
a 64-bit visibility key: the z-buffer test and a deterministic tie-break in one atomic.
"""

from __future__ import annotations

from ..._warp import wp

from .clip import SAMPLE_CENTRE, SUBPIXEL, drawn_rows, edge, owns_edge, snapped

wp.set_module_options({"enable_backward": False})

DEPTH_SCALE = wp.constant(wp.float64(0.5 * 2147483647.0))  # key depth (z_ndc + 1) x this: [-1, 1] -> [0, 2^31 - 1]
NO_HIT = wp.constant(wp.int64(9223372036854775807))
NARROW_BOX = wp.constant(4)  # sample columns below which `raster_slot` takes no branch on coverage


@wp.func
def edge_values(s0: wp.vec4d, s1: wp.vec4d, s2: wp.vec4d, i: int, j: int):
    """The three edge functions (float64, unsnapped) of triangle s0 s1 s2 at sample centre
    (j + 0.5, i + 0.5): e_k is twice the signed area of the sub-triangle opposite corner k, so
    e / (e0 + e1 + e2) are the screen-space barycentrics."""
    cx = wp.float64(j) + wp.float64(0.5)
    cy = wp.float64(i) + wp.float64(0.5)
    e0 = (s2[0] - s1[0]) * (cy - s1[1]) - (s2[1] - s1[1]) * (cx - s1[0])
    e1 = (s0[0] - s2[0]) * (cy - s2[1]) - (s0[1] - s2[1]) * (cx - s2[0])
    e2 = (s1[0] - s0[0]) * (cy - s0[1]) - (s1[1] - s0[1]) * (cx - s0[0])
    return wp.vec3d(e0, e1, e2)


@wp.func
def edge_weights(s0: wp.vec4d, s1: wp.vec4d, s2: wp.vec4d, i: int, j: int):
    """`edge_values` at sample centre (j + 0.5, i + 0.5) and their sum (twice the signed area):
    the screen-space barycentrics times that sum; (1, 0, 0) for a sliver (sum 0: a triangle only the
    snapped vertices give an area). Coverage is decided on the snapped integers; the weights come
    from the unsnapped float64 vertices, so interpolation carries no snapping error."""
    e = edge_values(s0, s1, s2, i, j)
    area = e[0] + e[1] + e[2]
    if area == wp.float64(0.0):
        return wp.vec3d(wp.float64(1.0), wp.float64(0.0), wp.float64(0.0)), area
    return e, area


@wp.func
def float_barycentrics(s0: wp.vec4d, s1: wp.vec4d, s2: wp.vec4d, i: int, j: int):
    """Screen-space barycentrics (float64) of sample centre (j + 0.5, i + 0.5) in triangle s0 s1 s2,
    and the edge values' sum (`edge_weights`; (1, 0, 0) for a sliver)."""
    e, area = edge_weights(s0, s1, s2, i, j)
    if area == wp.float64(0.0):
        return e, area
    return e / area, area


@wp.func
def depth_gradient(s0: wp.vec4d, s1: wp.vec4d, s2: wp.vec4d):
    """(dz/dx, dz/dy) of z_ndc over raster space in triangle s0 s1 s2 (float64, unsnapped): the
    barycentric blend of the corners' z_ndc is affine, z = z0 + dz/dx (x - x0) + dz/dy (y - y0),
    with dz/dx = -sum_k z_k (y_{k+2} - y_{k+1}) / A and dz/dy = sum_k z_k (x_{k+2} - x_{k+1}) / A
    (A: twice the signed area, as `edge_values` sums). Zero for a sliver (A = 0: z = z0)."""
    area = (s1[0] - s0[0]) * (s2[1] - s0[1]) - (s1[1] - s0[1]) * (s2[0] - s0[0])
    if area == wp.float64(0.0):
        return wp.float64(0.0), wp.float64(0.0)
    inv_area = wp.float64(1.0) / area  # one division per triangle
    dz_dx = -(s0[2] * (s2[1] - s1[1]) + s1[2] * (s0[1] - s2[1]) + s2[2] * (s1[1] - s0[1])) * inv_area
    dz_dy = (s0[2] * (s2[0] - s1[0]) + s1[2] * (s0[0] - s2[0]) + s2[2] * (s1[0] - s0[0])) * inv_area
    return dz_dx, dz_dy


@wp.func
def edge_threshold(owned: bool):
    """The least edge value b covering a sample: on the inner side (b > 0), or exactly on an edge
    the triangle owns (b = 0)."""
    if owned:
        return wp.int64(0)
    return wp.int64(1)


@wp.func(inline=True)
def drawn_at(b0: wp.int64, b1: wp.int64, b2: wp.int64, z_ndc: wp.float64):
    """Whether a sample with edge values b_k less their thresholds and depth z_ndc is drawn: all three
    cover (no sign bit) and z in [-1, 1] (in float64: z = 1 keys 2^31 - 1)."""
    return (b0 | b1 | b2) >= wp.int64(0) and z_ndc >= wp.float64(-1.0) and z_ndc <= wp.float64(1.0)


@wp.func(inline=True)
def sample_key(z_ndc: wp.float64, slot: int):
    """The visibility key of a sample at depth z_ndc in [-1, 1] drawn by `slot`: depth << 32 | slot."""
    return wp.int64((z_ndc + wp.float64(1.0)) * DEPTH_SCALE) * wp.int64(4294967296) + wp.int64(slot)


@wp.func
def raster_slot(slot: int, row_begin: int, row_end: int, rows: wp.array2d(dtype=wp.int32),
                screen: wp.array2d(dtype=wp.vec4d), width: int, key: wp.array(dtype=wp.int64)):
    """Z-test the samples of rows [row_begin, row_end) that screen triangle `slot` covers. (A perf
    profile of the 256^2 bench sphere's first fits: ~26 % of this loop's time waits on the key's
    load, a cache miss where the fit's other work pushed the z-buffer out: see `driver.zbuffer`.)"""
    s0 = screen[slot, 0]
    s1 = screen[slot, 1]
    s2 = screen[slot, 2]
    x0, y0, x1, y1, x2, y2 = snapped(s0, s1, s2)
    j_lo = wp.max(rows[slot, 2], 0)  # the candidates: samples in the snapped triangle's box (`clip.emit`)
    j_hi = wp.min(rows[slot, 3], width - 1)
    i_lo = wp.max(rows[slot, 0], row_begin)
    i_hi = wp.min(rows[slot, 1], row_end - 1)
    if j_lo > j_hi or i_lo > i_hi:
        return
    t0 = edge_threshold(owns_edge(x1, y1, x2, y2))  # covered: every b_k >= t_k
    t1 = edge_threshold(owns_edge(x2, y2, x0, y0))
    t2 = edge_threshold(owns_edge(x0, y0, x1, y1))
    dz_dx, dz_dy = depth_gradient(s0, s1, s2)  # z_ndc is affine in screen space: its plane
    step = wp.int64(SUBPIXEL)
    centre = wp.int64(SAMPLE_CENTRE)
    px = wp.int64(j_lo) * step + centre
    # A narrow box takes no branch on coverage, mispredicted for small triangles (the 256^2 bench
    # sphere's boxes: 156k samples for ~52k covered; raster 0.45 -> 0.40 ms a half); a wide one
    # skips its uncovered samples (taking every sample's min cost 7% at 512^2).
    narrow = j_hi - j_lo < NARROW_BOX
    for i in range(i_lo, i_hi + 1):
        py = wp.int64(i) * step + centre
        b0 = edge(x1, y1, x2, y2, px, py) - t0  # exact integer edge functions less their thresholds, stepped
        b1 = edge(x2, y2, x0, y0, px, py) - t1  # along the row
        b2 = edge(x0, y0, x1, y1, px, py) - t2
        z_row = s0[2] + dz_dy * (wp.float64(i) + wp.float64(0.5) - s0[1])
        if narrow:  # every box sample takes min(key, the triangle's key or NO_HIT): no branch on coverage
            for j in range(j_lo, j_hi + 1):
                z_ndc = z_row + dz_dx * (wp.float64(j) + wp.float64(0.5) - s0[0])
                drawn = drawn_at(b0, b1, b2, z_ndc)
                wp.atomic_min(key, i * width + j, wp.where(drawn, sample_key(wp.where(drawn, z_ndc, wp.float64(-1.0)),
                                                                              slot), NO_HIT))
                b0 = b0 - (y2 - y1) * step
                b1 = b1 - (y0 - y2) * step
                b2 = b2 - (y1 - y0) * step
        else:
            for j in range(j_lo, j_hi + 1):
                z_ndc = z_row + dz_dx * (wp.float64(j) + wp.float64(0.5) - s0[0])
                if drawn_at(b0, b1, b2, z_ndc):
                    wp.atomic_min(key, i * width + j, sample_key(z_ndc, slot))
                b0 = b0 - (y2 - y1) * step
                b1 = b1 - (y0 - y2) * step
                b2 = b2 - (y1 - y0) * step


@wp.kernel
def raster_kernel(first: int, step: int, row_begin: int, row_end: int, slots: wp.array(dtype=wp.int32), n_all: int,
                  rows: wp.array2d(dtype=wp.int32), screen: wp.array2d(dtype=wp.vec4d), width: int, height: int,
                  key: wp.array(dtype=wp.int64)):
    """The triangles binned to rows [row_begin, row_end), or with `slots` empty (a single band:
    nothing binned) the slots of [0, n_all) whose box holds samples: thread tid takes the items
    first + tid, first + tid + step, ... (on the CPU one thread takes a band's list, or every
    step-th slot for one of `step` partial z-buffers; on CUDA, a thread an item)."""
    binned = slots.shape[0] > 0
    n = n_all
    if binned:
        n = slots.shape[0]
    for k in range(first + wp.tid(), n, step):
        if binned:
            raster_slot(slots[k], row_begin, row_end, rows, screen, width, key)
        else:
            top, bottom, unused = drawn_rows(k, rows, width, height)
            if top <= bottom:
                raster_slot(k, row_begin, row_end, rows, screen, width, key)


@wp.func
def bin_slot(slot: int, rows: wp.array2d(dtype=wp.int32), width: int, height: int,
             band_of_row: wp.array(dtype=wp.int32), part: int, cursor: wp.array2d(dtype=wp.int32),
             binned: wp.array(dtype=wp.int32)):
    """Write `slot` into the list of every row band its box meets, at cursor[part, band] (then advanced)."""
    first, last, unused = drawn_rows(slot, rows, width, height)
    if first <= last:
        for band in range(band_of_row[first], band_of_row[last] + 1):
            binned[wp.atomic_add(cursor, part, band, 1)] = slot


@wp.kernel
def bin_kernel(part: int, begin: int, end: int, chunk: int, extra_slot: wp.array(dtype=wp.int32),
               rows: wp.array2d(dtype=wp.int32), width: int, height: int, band_of_row: wp.array(dtype=wp.int32),
               cursor: wp.array2d(dtype=wp.int32), binned: wp.array(dtype=wp.int32)):
    """The slots of faces [begin, end) (launch part `part`, as `assemble_kernel` counted them), `chunk`
    faces per thread, into their bands' lists; cursor[part, band] starts where that part's slots of
    that band go. `extra_slot` is empty when no face is clipped to a quad."""
    first = begin + wp.tid() * chunk
    for f in range(first, wp.min(first + chunk, end)):
        bin_slot(f, rows, width, height, band_of_row, part, cursor, binned)
        if extra_slot.shape[0] > 0:
            if extra_slot[f] >= 0:
                bin_slot(extra_slot[f], rows, width, height, band_of_row, part, cursor, binned)
