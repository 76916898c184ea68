"""Whether triangles bound solids from outside: `closed_outward` / `solid_pieces` (the item buffer's
back-face culling asks it, `renderers/raytrace/itembuffer.py`)."""

from __future__ import annotations

import numpy as np

MIN_VOLUME = 1.0e-8  # a piece's volume must pass this times the bounding-box diagonal cubed (rounding: ~1e-16 per face)


def closed_outward(vertices, faces) -> bool:
    """Whether the triangles are the closed, outward-facing surfaces of solids (`solid_pieces`)."""
    return solid_pieces(vertices, faces) is not None


def solid_pieces(vertices, faces) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The solids the triangles bound, facing out: each face's corners as welded vertex numbers
    (F, 3) and its connected piece (F,), a label (int64 both), and each piece's centroid (centre of
    volume: the sum over its faces of v0 . (v1 x v2) (v0 + v1 + v2) / 24, over its volume) as row
    `label` of a (largest label + 1, 3) float64 array; None unless they are closed and face out.

    Vertices at bitwise-equal positions are one (a seam's duplicates, whose edges the BVH's watertight
    triangle test shares too). Then every edge a -> b of a face must be met by exactly one other face,
    which runs it b -> a (closed, consistently wound, no face repeated or folded flat onto a neighbour
    with the same winding), no face may repeat a vertex, and every connected piece must enclose a
    signed volume V = sum over its faces of v0 . (v1 x v2) / 6 above MIN_VOLUME d^3 (d: the bounding
    box diagonal of all the vertices; a sheet shown on both sides has V ~ 0): its counter-clockwise
    (front) faces look out. A ray from outside every piece then enters a solid at its first hit,
    through a front face -- provided no piece passes through itself: a self-intersection can wrap a
    region inside out (winding number -1), seen first through a back face. That is not tested here
    (pieces crossing each other are fine: windings add up); the item buffer asks it of the pieces
    returned (`renderers/raytrace/selfcross.py`). Empty: None."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    if not len(faces):
        return None
    n, weld = welded(vertices)
    corners = weld[faces]
    start, end = corners.reshape(-1), np.roll(corners, -1, axis=1).reshape(-1)  # edge k of face f: k -> k + 1
    if np.any(start == end):
        return None
    edges = np.sort(start * n + end)
    if np.any(edges[1:] == edges[:-1]):  # an edge run twice the same way
        return None
    reverse = end * n + start
    found = np.minimum(np.searchsorted(edges, reverse), len(edges) - 1)
    if np.any(edges[found] != reverse):  # an edge run one way only: a border
        return None
    v = vertices[faces]
    piece = pieces(n, start, end)[corners[:, 0]]  # each face's piece
    six_volume = np.einsum("fi,fi->f", v[:, 0], np.cross(v[:, 1], v[:, 2]))  # 6 x each face's cone from the origin
    volume = np.bincount(piece, six_volume) / 6.0  # by piece label (0 for numbers that label no piece)
    labels = np.bincount(piece) > 0
    diagonal = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    if not np.all(volume[labels] > MIN_VOLUME * diagonal ** 3):
        return None
    corner_sum = v[:, 0] + v[:, 1] + v[:, 2]  # a cone's centroid is corner_sum / 4 (numpy's sum(axis=1): ~10x slower)
    centroid = np.stack([np.bincount(piece, six_volume * corner_sum[:, k]) for k in range(3)], axis=1)
    return corners, piece, centroid / np.where(labels, 24.0 * volume, 1.0)[:, None]

def welded(vertices: np.ndarray) -> tuple[int, np.ndarray]:
    """How many distinct positions the (V, 3) vertices have, and each vertex's position number."""
    order = np.lexsort(vertices.T[::-1])
    ordered = vertices[order]
    new = np.r_[True, np.any(ordered[1:] != ordered[:-1], axis=1)]
    number = np.empty(len(vertices), np.int64)
    number[order] = np.cumsum(new) - 1
    return int(new.sum()), number


def pieces(n: int, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """The connected piece of each of n vertices joined by edges start[k] - end[k]: a label (the least
    vertex of its piece). Union-find in whole-array steps: every label is a vertex of its own piece
    no larger than the vertex (label[v] <= v, so no cycles); each round hooks, for every edge whose
    ends' roots differ, the larger root under the smaller (one root fewer at least), then points
    every vertex at its root."""
    label = np.arange(n)
    while True:
        a, b = label[start], label[end]
        apart = a != b
        if not apart.any():
            return label
        np.minimum.at(label, np.maximum(a[apart], b[apart]), np.minimum(a[apart], b[apart]))
        while True:
            root = label[label]
            if np.array_equal(root, label):
                break
            label = root

