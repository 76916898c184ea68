"""Rasterizer stages 1-2: world -> clip space, and primitive assembly (near-plane clipping, the
perspective divide, raster space, fixed-point snapping, degenerate and back-face rejection).

A face becomes at most two screen triangles, stored in *slots*: face f's first triangle in slot f, the
second (only a face with one vertex behind the near plane is clipped to a quad) in an extra slot
after the F faces' (`extra_slots` numbers them, `split_kernel` finds them). Every slot carries its
three corners (x_raster, y_raster, z_ndc, 1/w) in float64, their weights over the original face's
vertices (a clipped corner lies on an edge), its facing, and the rows of sample centres it may cover.
"""

from __future__ import annotations

from ..._warp import wp

wp.set_module_options({"enable_backward": False})

SUBPIXEL_BITS = 8
SUBPIXEL = 1 << SUBPIXEL_BITS  # fixed-point steps per sample
SAMPLE_CENTRE = SUBPIXEL // 2  # a sample centre, in fixed-point steps from its sample's corner
GUARD = 4194304.0  # |raster coordinate| clamp (samples) keeping int64 edge products exact


@wp.func
def near_crossing(ia: int, ib: int, ca: wp.vec4, cb: wp.vec4, wa: wp.vec3, wb: wp.vec3):
    """Where edge a-b meets z = -w, computed from the lower vertex index so both triangles sharing
    the edge get bitwise the same point. Returns (clip position, original barycentric weights)."""
    if ia > ib:
        tmp_c = ca
        ca = cb
        cb = tmp_c
        tmp_w = wa
        wa = wb
        wb = tmp_w
    da = ca[2] + ca[3]
    db = cb[2] + cb[3]
    t = da / (da - db)
    return ca + t * (cb - ca), wa + t * (wb - wa)


@wp.func
def to_screen(c: wp.vec4, width: int, height: int):
    """Clip -> (x_raster, y_raster, z_ndc, 1/w) in float64, x and y clamped to the guard band."""
    one = wp.float64(1.0)
    guard = wp.float64(GUARD)
    inv_w = one / wp.float64(c[3])
    x = wp.clamp((wp.float64(c[0]) * inv_w + one) * wp.float64(0.5 * float(width)), -guard, guard)
    y = wp.clamp((one - wp.float64(c[1]) * inv_w) * wp.float64(0.5 * float(height)), -guard, guard)
    return wp.vec4d(x, y, wp.float64(c[2]) * inv_w, inv_w)


@wp.func
def snap(x: wp.float64):
    return wp.int64(wp.rint(x * wp.float64(SUBPIXEL)))  # to nearest, ties to even: one instruction


@wp.func
def snapped(s0: wp.vec4d, s1: wp.vec4d, s2: wp.vec4d):
    """The screen triangle's corners on the fixed-point grid: x0, y0, x1, y1, x2, y2 (int64)."""
    return snap(s0[0]), snap(s0[1]), snap(s1[0]), snap(s1[1]), snap(s2[0]), snap(s2[1])


@wp.func
def edge(ax: wp.int64, ay: wp.int64, bx: wp.int64, by: wp.int64, px: wp.int64, py: wp.int64):
    """Twice the signed area of (a, b, p), exact in 64-bit integers."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@wp.func
def first_centre(lo: wp.int64):
    """The first sample index whose centre (index * SUBPIXEL + SAMPLE_CENTRE, fixed point) is >= lo:
    ceil((lo - SAMPLE_CENTRE) / SUBPIXEL), as -floor of the negation (an arithmetic shift floors)."""
    return int(-((wp.int64(SAMPLE_CENTRE) - lo) >> wp.int64(SUBPIXEL_BITS)))


@wp.func
def last_centre(hi: wp.int64):
    """The last sample index whose centre is <= hi (fixed point): floor((hi - SAMPLE_CENTRE) / SUBPIXEL)."""
    return int((hi - wp.int64(SAMPLE_CENTRE)) >> wp.int64(SUBPIXEL_BITS))


@wp.func
def sample_box(x0: wp.int64, y0: wp.int64, x1: wp.int64, y1: wp.int64, x2: wp.int64, y2: wp.int64):
    """(first row, last row, first column, last column) of the sample centres in the bounding box of
    the snapped triangle, the one the edge functions test (a box from the unsnapped corners can miss
    a row or column that an edge snapped onto a sample centre covers: a crack between triangles)."""
    return wp.vec4i(first_centre(wp.min(y0, wp.min(y1, y2))), last_centre(wp.max(y0, wp.max(y1, y2))),
                    first_centre(wp.min(x0, wp.min(x1, x2))), last_centre(wp.max(x0, wp.max(x1, x2))))


@wp.func
def owns_edge(ax: wp.int64, ay: wp.int64, bx: wp.int64, by: wp.int64):
    """Fill rule for samples exactly on edge a->b: the edge's direction lies in a fixed half-plane,
    so of two triangles sharing the edge (traversing it in opposite directions) exactly one owns it."""
    return (by > ay) or (by == ay and bx < ax)


@wp.func
def emit(slot: int, s0: wp.vec4d, s1: wp.vec4d, s2: wp.vec4d, w0: wp.vec3, w1: wp.vec3, w2: wp.vec3, cull: int,
         screen: wp.array2d(dtype=wp.vec4d), weight: wp.array2d(dtype=wp.vec3), facing: wp.array(dtype=wp.int32),
         rows: wp.array2d(dtype=wp.int32)):
    """Store one screen triangle, wound so its integer area is positive; facing +1 front, -1 back,
    0 not drawn (degenerate, or culled); and the rows of sample centres it may cover, for binning."""
    x0, y0, x1, y1, x2, y2 = snapped(s0, s1, s2)
    area = edge(x0, y0, x1, y1, x2, y2)
    facing[slot] = 0
    if area == wp.int64(0):
        return
    side = 1  # counter-clockwise in NDC (y up) is clockwise in raster space (y down): area < 0
    if area > wp.int64(0):
        side = -1
    if cull == 1 and side < 0:
        return
    facing[slot] = side
    box = sample_box(x0, y0, x1, y1, x2, y2)
    rows[slot, 0] = box[0]
    rows[slot, 1] = box[1]
    rows[slot, 2] = box[2]  # its box's sample columns
    rows[slot, 3] = box[3]
    screen[slot, 0] = s0
    weight[slot, 0] = w0
    if side > 0:
        screen[slot, 1] = s2
        screen[slot, 2] = s1
        weight[slot, 1] = w2
        weight[slot, 2] = w1
    else:
        screen[slot, 1] = s1
        screen[slot, 2] = s2
        weight[slot, 1] = w1
        weight[slot, 2] = w2


@wp.func
def inside_near(c: wp.vec4):
    return c[2] + c[3] >= 0.0  # z_clip >= -w_clip


@wp.kernel
def clip_vertices_kernel(begin: int, end: int, chunk: int, vertices: wp.array(dtype=wp.vec3), view_proj: wp.mat44,
                         width: int, height: int, clip: wp.array(dtype=wp.vec4), screen: wp.array(dtype=wp.vec4d),
                         behind: wp.array(dtype=wp.int32)):
    """Vertices [begin, end), `chunk` per thread: clip space and (in front of the near plane) the
    screen position `to_screen` gives, shared by the faces around the vertex; behind[0] = 1 when
    a vertex is behind the near plane (every write is a 1: threads may write it in any order)."""
    first = begin + wp.tid() * chunk
    for k in range(first, wp.min(first + chunk, end)):
        p = vertices[k]
        c = view_proj * wp.vec4(p[0], p[1], p[2], 1.0)
        clip[k] = c
        if inside_near(c):
            screen[k] = to_screen(c, width, height)
        else:
            behind[0] = 1


@wp.kernel
def split_kernel(begin: int, end: int, chunk: int, faces: wp.array2d(dtype=wp.int32), clip: wp.array(dtype=wp.vec4),
                 split: wp.array(dtype=wp.int32)):
    """split[f] = 1 for a face with exactly one vertex behind the near plane (clipped to a quad);
    faces [begin, end), `chunk` per thread."""
    first = begin + wp.tid() * chunk
    for f in range(first, wp.min(first + chunk, end)):
        count = int(inside_near(clip[faces[f, 0]])) + int(inside_near(clip[faces[f, 1]])) \
            + int(inside_near(clip[faces[f, 2]]))
        split[f] = int(count == 2)


@wp.func
def clear_slot(slot: int, facing: wp.array(dtype=wp.int32), rows: wp.array2d(dtype=wp.int32)):
    facing[slot] = 0
    rows[slot, 0] = 1  # empty row range [1, 0]: binned nowhere
    rows[slot, 1] = 0
    rows[slot, 2] = 1
    rows[slot, 3] = 0


@wp.func
def assemble_face(f: int, faces: wp.array2d(dtype=wp.int32), clip: wp.array(dtype=wp.vec4),
                  vertex_screen: wp.array(dtype=wp.vec4d), cull: int,
                  width: int, height: int, extra: int, screen: wp.array2d(dtype=wp.vec4d),
                  weight: wp.array2d(dtype=wp.vec3), facing: wp.array(dtype=wp.int32),
                  rows: wp.array2d(dtype=wp.int32)):
    """Clip face f and store its slot(s): slot f, and `extra` (-1: none) when it is clipped to a quad.
    `clip` empty: every vertex is in front of the near plane (`driver.zbuffer` knows it from
    `clip_vertices_kernel`), so the face is its slot's triangle, unclipped (nothing of `clip` to
    read: the 256^2 bench sphere's assembly ~300 -> ~285 us)."""
    clear_slot(f, facing, rows)
    if extra >= 0:
        clear_slot(extra, facing, rows)
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    e0 = wp.vec3(1.0, 0.0, 0.0)
    e1 = wp.vec3(0.0, 1.0, 0.0)
    e2 = wp.vec3(0.0, 0.0, 1.0)
    if clip.shape[0] == 0:
        emit(f, vertex_screen[i0], vertex_screen[i1], vertex_screen[i2], e0, e1, e2, cull, screen, weight, facing,
             rows)
        return
    c0 = clip[i0]
    c1 = clip[i1]
    c2 = clip[i2]
    in0 = inside_near(c0)
    in1 = inside_near(c1)
    in2 = inside_near(c2)
    count = int(in0) + int(in1) + int(in2)
    if count == 0:
        return
    if count == 3:
        emit(f, vertex_screen[i0], vertex_screen[i1], vertex_screen[i2], e0, e1, e2, cull, screen, weight, facing,
             rows)
        return
    # Rotate (keeping the winding) so that vertex a is the odd one out: the only vertex inside
    # (count 1) or the only one outside (count 2).
    ia = i0
    ib = i1
    ic = i2
    ca = c0
    cb = c1
    cc = c2
    wa = e0
    wb = e1
    wc = e2
    odd1 = in1
    odd2 = in2
    if count == 2:
        odd1 = not in1
        odd2 = not in2
    if odd1:
        ia = i1
        ib = i2
        ic = i0
        ca = c1
        cb = c2
        cc = c0
        wa = e1
        wb = e2
        wc = e0
    elif odd2:
        ia = i2
        ib = i0
        ic = i1
        ca = c2
        cb = c0
        cc = c1
        wa = e2
        wb = e0
        wc = e1
    cab, wab = near_crossing(ia, ib, ca, cb, wa, wb)
    cac, wac = near_crossing(ia, ic, ca, cc, wa, wc)
    sab = to_screen(cab, width, height)
    sac = to_screen(cac, width, height)
    if count == 1:  # a inside: triangle (a, ab, ac)
        emit(f, vertex_screen[ia], sab, sac, wa, wab, wac, cull, screen, weight, facing, rows)
    else:  # a outside: quad (ab, b, c, ac)
        sb = vertex_screen[ib]
        sc = vertex_screen[ic]
        emit(f, sab, sb, sc, wab, wb, wc, cull, screen, weight, facing, rows)
        emit(extra, sab, sc, sac, wab, wc, wac, cull, screen, weight, facing, rows)


@wp.func
def drawn_rows(slot: int, rows: wp.array2d(dtype=wp.int32), width: int, height: int):
    """The sample rows [first, last] of `slot`'s box on screen, and its sample tests (box samples on
    screen); (1, 0, 0) for a slot that draws nothing there (not drawn, or its box off screen)."""
    first = wp.max(rows[slot, 0], 0)
    last = wp.min(rows[slot, 1], height - 1)
    columns = wp.min(rows[slot, 3], width - 1) - wp.max(rows[slot, 2], 0) + 1
    if first > last or columns <= 0:
        return 1, 0, wp.int64(0)
    return first, last, wp.int64(last - first + 1) * wp.int64(columns)


@wp.func
def count_slot(slot: int, rows: wp.array2d(dtype=wp.int32), width: int, height: int,
               band_of_row: wp.array(dtype=wp.int32), part: int, counts: wp.array2d(dtype=wp.int32),
               tests: wp.array(dtype=wp.int64)):
    """Count `slot` in every row band its box meets (counts[part, band]; `counts` empty: a single
    band, nothing to bin, none counted -- the 256^2 bench sphere's assembly ~292 -> ~274 us) and add
    its sample tests."""
    first, last, n_tests = drawn_rows(slot, rows, width, height)
    if first <= last:
        wp.atomic_add(tests, part, n_tests)
        if counts.shape[0] > 0:
            for band in range(band_of_row[first], band_of_row[last] + 1):
                wp.atomic_add(counts, part, band, 1)


@wp.kernel
def assemble_kernel(part: int, begin: int, end: int, chunk: int, faces: wp.array2d(dtype=wp.int32),
                    clip: wp.array(dtype=wp.vec4), vertex_screen: wp.array(dtype=wp.vec4d), cull: int, width: int,
                    height: int, extra_slot: wp.array(dtype=wp.int32), screen: wp.array2d(dtype=wp.vec4d),
                    weight: wp.array2d(dtype=wp.vec3), facing: wp.array(dtype=wp.int32),
                    rows: wp.array2d(dtype=wp.int32), slot_face: wp.array(dtype=wp.int32),
                    band_of_row: wp.array(dtype=wp.int32), counts: wp.array2d(dtype=wp.int32),
                    tests: wp.array(dtype=wp.int64)):
    """Faces [begin, end) of launch part `part`, `chunk` per thread: their slots, each slot's face,
    and per row band the slots meeting it (counts[part, band]) and their sample tests (tests[part]).
    `extra_slot` is empty when no face is clipped to a quad."""
    first = begin + wp.tid() * chunk
    for f in range(first, wp.min(first + chunk, end)):
        extra = int(-1)
        if extra_slot.shape[0] > 0:
            extra = extra_slot[f]
        assemble_face(f, faces, clip, vertex_screen, cull, width, height, extra, screen, weight, facing, rows)
        slot_face[f] = f
        count_slot(f, rows, width, height, band_of_row, part, counts, tests)
        if extra >= 0:
            slot_face[extra] = f
            count_slot(extra, rows, width, height, band_of_row, part, counts, tests)
