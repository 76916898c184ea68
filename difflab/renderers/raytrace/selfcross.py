"""Whether a solid's surface passes through itself: the item buffer leaves back faces out of its
z-buffer only when no piece of the mesh does (`itembuffer.culls_back_faces`; the pieces and their
welded vertices from `geometry.solid_pieces`). A fold that passes through its own piece can wrap a
region inside out (winding number -1), where a primary ray's first hit is a back face; pieces
crossing each other are fine (each is a solid: windings add up, never below 0).

A piece strictly star-shaped from its centroid is proven not to pass through itself at once
(`star_shaped`: convex solids, the benchmark's sphere; ~0.05 us a face, 2 cores -- the 81,920-face
icosphere's ~4 ms against its BVH build's ~25 ms). In the others (~0.8 us a face on one core, of
which Warp's CPU `mesh_query_aabb` takes ~0.55 us), two triangles of one piece are tested when
their bounding boxes overlap (the BVH's candidates, each pair once), by how many welded vertices
they share:

- none: they meet exactly when an edge of one meets the other triangle (`segment_meets`, six
  tests: two triangles in different planes meet in a segment whose ends lie on edges; in one plane,
  an edge crosses the other triangle or one triangle holds the other);
- one, P: (P, A, B) and (P, C, D) meet anywhere but P exactly when AB meets (P, C, D) or CD meets
  (P, A, B) (their intersection is convex and holds P; its far side lies on AB or CD);
- two, an edge: not tested. Such neighbours meet only along their edge, unless folded flat onto
  each other -- coincident surfaces, which the item buffer leaves to rounding as the BVH does.

Touching counts as meeting, within a tolerance: a segment within TOUCH x the pair's longest edge of
a triangle (off its plane, or past its edges when in it) meets it. The numbers are float64 from
the float32 vertices the BVH holds (exact), so rounding (~1e-16 relative) never hides a crossing;
a near-touch reported wrongly only turns culling off. A zero-area triangle meets every triangle
whose bounding box overlaps its own (its plane is undefined).
"""

from __future__ import annotations

import numpy as np

from ..._warp import wp
from ..launch import launch_chunks, load_kernels

wp.set_module_options({"enable_backward": False})

TOUCH = wp.constant(wp.float64(1.0e-6))  # pairs closer than this x their longest edge meet (see module doc)
ZERO = wp.constant(wp.float64(0.0))
ONE = wp.constant(wp.float64(1.0))
STAR_MARGIN = wp.constant(wp.float64(1.0e-12))  # `cover_kernel`: the least sine of a decided turn (rounding: ~1e-16)
PROBE = wp.constant(wp.vec3d(wp.float64(0.5379), wp.float64(0.6934), wp.float64(0.4795)))  # `star_shaped`'s ray (unit)


@wp.func
def turn(x: wp.vec3d, u: wp.vec3d, v: wp.vec3d, normal: wp.vec3d):
    """|u v| times the signed distance of x from the line u -> v in the plane of `normal`: positive
    to the left (inside a triangle counter-clockwise about `normal`)."""
    return wp.dot(wp.cross(v - u, x - u), normal)


@wp.func
def within(x: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, normal: wp.vec3d, eps: wp.float64):
    """Whether x, seen along the unit `normal`, lies in triangle abc with each edge moved out by eps."""
    return (turn(x, a, b, normal) >= -eps * wp.length(b - a) and turn(x, b, c, normal) >= -eps * wp.length(c - b)
            and turn(x, c, a, normal) >= -eps * wp.length(a - c))


@wp.func
def near_segment(x: wp.vec3d, p: wp.vec3d, q: wp.vec3d, eps: wp.float64):
    """Whether x lies within eps of segment pq."""
    d = q - p
    t = wp.clamp(wp.dot(x - p, d) / wp.dot(d, d), ZERO, ONE)
    return wp.length(x - (p + t * d)) <= eps


@wp.func
def edges_cross(p: wp.vec3d, q: wp.vec3d, u: wp.vec3d, v: wp.vec3d, normal: wp.vec3d):
    """Whether segments pq and uv in the plane of `normal` cross: each one's ends strictly on both
    sides of the other's line."""
    return (turn(u, p, q, normal) * turn(v, p, q, normal) < ZERO
            and turn(p, u, v, normal) * turn(q, u, v, normal) < ZERO)


@wp.func
def segment_meets(p: wp.vec3d, q: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, eps: wp.float64):
    """Whether segment pq meets triangle abc, touching within eps: both ends clearly on one side of
    its plane -- no; both within eps of the plane -- the flat test (an end in the triangle, a corner
    near the segment, or the segment crossing an edge); else where pq crosses the plane (or its end
    nearer the plane) in the triangle grown by eps."""
    normal = wp.normalize(wp.cross(b - a, c - a))
    dp = wp.dot(p - a, normal)
    dq = wp.dot(q - a, normal)
    if (dp > eps and dq > eps) or (dp < -eps and dq < -eps):
        return False
    if wp.abs(dp) <= eps and wp.abs(dq) <= eps:
        return (within(p, a, b, c, normal, eps) or within(q, a, b, c, normal, eps) or near_segment(a, p, q, eps)
                or near_segment(b, p, q, eps) or near_segment(c, p, q, eps) or edges_cross(p, q, a, b, normal)
                or edges_cross(p, q, b, c, normal) or edges_cross(p, q, c, a, normal))
    t = wp.clamp(dp / (dp - dq), ZERO, ONE)  # |dp - dq| > eps here: well conditioned
    return within(p + t * (q - p), a, b, c, normal, eps)


@wp.func
def triangles_meet(a0: wp.vec3d, a1: wp.vec3d, a2: wp.vec3d, b0: wp.vec3d, b1: wp.vec3d, b2: wp.vec3d,
                   eps: wp.float64):
    """Whether two triangles meet (within eps): an edge of one meets the other."""
    return (segment_meets(a0, a1, b0, b1, b2, eps) or segment_meets(a1, a2, b0, b1, b2, eps)
            or segment_meets(a2, a0, b0, b1, b2, eps) or segment_meets(b0, b1, a0, a1, a2, eps)
            or segment_meets(b1, b2, a0, a1, a2, eps) or segment_meets(b2, b0, a0, a1, a2, eps))


@wp.func
def corner(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), face: int, k: int):
    p = points[indices[3 * face + k]]
    return wp.vec3d(wp.float64(p[0]), wp.float64(p[1]), wp.float64(p[2]))


@wp.func
def longest_edge(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
    return wp.max(wp.max(wp.length(b - a), wp.length(c - b)), wp.length(a - c))


@wp.func
def pair_meets(face: int, other: int, points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32),
               corners: wp.array2d(dtype=wp.int32)):
    """Whether faces `face` and `other` of one piece meet where they share no vertex (module doc)."""
    shared = int(0)
    k_face = int(0)  # the shared vertex's place in each face, when one is shared
    k_other = int(0)
    for i in range(3):
        for j in range(3):
            if corners[face, i] == corners[other, j]:
                shared += 1
                k_face = i
                k_other = j
    if shared > 1:
        return False
    a0 = corner(points, indices, face, k_face)
    a1 = corner(points, indices, face, (k_face + 1) % 3)
    a2 = corner(points, indices, face, (k_face + 2) % 3)
    b0 = corner(points, indices, other, k_other)
    b1 = corner(points, indices, other, (k_other + 1) % 3)
    b2 = corner(points, indices, other, (k_other + 2) % 3)
    eps = TOUCH * wp.max(longest_edge(a0, a1, a2), longest_edge(b0, b1, b2))
    if shared == 1:  # a0 is b0
        return segment_meets(a1, a2, b0, b1, b2, eps) or segment_meets(b1, b2, a0, a1, a2, eps)
    return triangles_meet(a0, a1, a2, b0, b1, b2, eps)


@wp.func
def meets_later_face(face: int, bvh: wp.uint64, points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32),
                     corners: wp.array2d(dtype=wp.int32), piece: wp.array(dtype=wp.int32)):
    """Whether face `face` meets a face of its piece numbered after it (`pair_meets`), among those
    whose bounding box overlaps its own grown by TOUCH x its longest edge."""
    a = points[indices[3 * face]]
    b = points[indices[3 * face + 1]]
    c = points[indices[3 * face + 2]]
    pad = float(TOUCH) * wp.max(wp.max(wp.length(b - a), wp.length(c - b)), wp.length(a - c))
    query = wp.mesh_query_aabb(bvh, wp.min(wp.min(a, b), c) - wp.vec3(pad), wp.max(wp.max(a, b), c) + wp.vec3(pad))
    other = int(0)
    while wp.mesh_query_next(query, other):
        if other > face and piece[other] == piece[face]:
            if pair_meets(face, other, points, indices, corners):
                return True
    return False


@wp.kernel
def cover_kernel(begin: int, end: int, chunk: int, points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32),
                 piece: wp.array(dtype=wp.int32), centre: wp.array(dtype=wp.vec3d), cover: wp.array(dtype=wp.int8)):
    """Faces begin + tid * chunk ... (up to chunk, below end) seen from their piece's centre c:
    `cover` -1 unless face (a, b, x) turns counter-clockwise, det(a - c, b - c, x - c) >
    STAR_MARGIN |a - c| |b - c| |x - c|; else 1 where the ray from c along PROBE crosses it strictly
    inside (it is on the left of all three planes through c and an edge), 0 where it clearly misses
    (on the right of one by the margin), -1 where it may pass through an edge (undecided)."""
    first = begin + wp.tid() * chunk
    for face in range(first, wp.min(first + chunk, end)):
        c = centre[piece[face]]
        a = corner(points, indices, face, 0) - c
        b = corner(points, indices, face, 1) - c
        x = corner(points, indices, face, 2) - c
        det = wp.dot(a, wp.cross(b, x))
        la = wp.length(a)
        lb = wp.length(b)
        lx = wp.length(x)
        side = wp.vec3d(wp.dot(PROBE, wp.cross(a, b)) / (la * lb), wp.dot(PROBE, wp.cross(b, x)) / (lb * lx),
                        wp.dot(PROBE, wp.cross(x, a)) / (lx * la))  # sines: PROBE against each edge's plane
        cover[face] = wp.int8(-1)
        if det > STAR_MARGIN * la * lb * lx:
            if wp.min(side) > STAR_MARGIN:
                cover[face] = wp.int8(1)
            elif wp.min(side) < -STAR_MARGIN:
                cover[face] = wp.int8(0)


@wp.kernel
def meets_kernel(begin: int, end: int, chunk: int, tested: wp.array(dtype=wp.int32), bvh: wp.uint64,
                 points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32),
                 corners: wp.array2d(dtype=wp.int32), piece: wp.array(dtype=wp.int32), meets: wp.array(dtype=wp.uint8)):
    """Items begin + tid * chunk ... (up to chunk, below end): `meets[k]` 1 where face tested[k]
    `meets_later_face`."""
    first = begin + wp.tid() * chunk
    for k in range(first, wp.min(first + chunk, end)):
        meets[k] = wp.uint8(0)
        if meets_later_face(tested[k], bvh, points, indices, corners, piece):
            meets[k] = wp.uint8(1)


def passes_through_itself(bvh: wp.Mesh, corners, piece, centre, threads: int | None = None) -> bool:
    """Whether a piece of a closed, consistently wound surface (the BVH's) passes through itself:
    not those `star_shaped` proves embedded; of the others, whether a face meets another of its
    piece (`crossing_faces`, the BVH's candidates). `corners`, `piece`, `centre`: each face's welded
    corners and piece, and each piece's centre, as `geometry.solid_pieces` gives them."""
    tested = np.flatnonzero(~star_shaped(bvh, piece, centre, threads))
    return bool(tested.size) and bool(crossing_faces(bvh, corners, piece, tested, threads).any())


def star_shaped(bvh: wp.Mesh, piece, centre, threads: int | None = None) -> np.ndarray:
    """Per face of a closed, consistently wound surface (the BVH's), whether its piece is strictly
    star-shaped from its centre c (row piece of `centre`; `solid_pieces` gives the centroid): every
    face turns counter-clockwise seen from c, so that the central projection onto a sphere around c
    is a branched covering, covering each direction equally often -- and the ray from c along PROBE
    crosses exactly one face, strictly inside (`cover_kernel`): it covers the sphere once, so no
    two points of the piece lie in one direction from c, and the piece does not pass through itself.
    False says nothing. (F,) bool."""
    device = str(bvh.device)
    piece = np.asarray(piece, np.int64)
    cover = wp.empty(len(piece), dtype=wp.int8, device=device)
    load_kernels(device, cover_kernel)
    launch_chunks(cover_kernel, len(piece), [bvh.points, bvh.indices, wp.array(piece.astype(np.int32), dtype=wp.int32,
                                                                               device=device),
                                             wp.array(np.ascontiguousarray(centre, np.float64), dtype=wp.vec3d,
                                                      device=device), cover], device, threads)
    cover = cover.numpy()
    star = (np.bincount(piece, cover < 0, len(centre)) == 0) & (np.bincount(piece, cover == 1, len(centre)) == 1)
    return star[piece]


def crossing_faces(bvh: wp.Mesh, corners, piece, tested=None, threads: int | None = None) -> np.ndarray:
    """Per face of `tested` (default: all), whether it meets a face of its own piece numbered after
    it with which it shares at most one vertex (module doc). (len(tested),) bool; `tested` must hold
    whole pieces for every pair of them to be tested.

    Arguments:
        bvh: the `wp.Mesh` over the faces (its points and flat indices; the item buffer's is the
            compiled scene's BVH).
        corners: (F, 3) each face's corners as welded vertex numbers (equal for bitwise-equal
            positions), as `geometry.solid_pieces` gives them.
        piece: (F,) each face's connected piece; only faces of one piece are paired.
        tested: face numbers to test; threads: CPU threads (default all cores)."""
    device = str(bvh.device)
    tested = np.arange(len(piece)) if tested is None else np.asarray(tested)
    meets = wp.empty(len(tested), dtype=wp.uint8, device=device)

    def int32(values):
        return wp.array(np.ascontiguousarray(values, np.int32), dtype=wp.int32, device=device)

    load_kernels(device, meets_kernel)
    launch_chunks(meets_kernel, len(tested), [int32(tested), bvh.id, bvh.points, bvh.indices, int32(corners),
                                              int32(piece), meets], device, threads)
    return meets.numpy().astype(bool)
