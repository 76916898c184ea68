"""The Jacobian of a fit's plain weighted residuals at a point as a sparse matrix, by column
compression (Curtis, Powell and Reid 1974): the standard errors of matrix-free fits (`stats.py`).

A residual entry (used pixel u, channel) depends on the scalar entries (ka, kd, ks, n, ...) and on
the fitted texels its points' filter taps read -- nearest 1, bilinear 4 per lookup; through the ray
tree the taps of every node of the pixel's samples (`GBufferModel.texel_reads`,
`TreeModel.texel_reads`) -- in any channel, for all J's columns assume. Texels no pixel reads
together share a colour (greedy distance-2 colouring of the pixel-texel graph), per channel: one
Jacobian-vector product with the sum of their unit vectors gives all their columns, row (u, ch)
being the column of the one texel of that colour that pixel u reads. Each scalar entry has a colour
of its own. C texel colours and E scalars cost 3 C + E products (one batch, `jax.vmap`) of the
linearisation every solver steps on (`texels.affine_residuals`), never N x p dense work; each
product is exact -- the seed's other unit vectors meet zero Jacobian entries in that row -- so J
holds the numbers a dense Jacobian would (`stats.normal_matrix`'s), to the bit:

    J[:, j] = d r / d value_j = (d r / d x_j) / value_j for an entry fitted in log coordinates

with r = `Problem.weighted` (no robust loss, no smoothness prior rows) over every residual entry.
A texel no pixel reads has an empty column.

Blocks too large for standard errors are left out before any product (`stats_blocks`): J^T J's
connected blocks are predicted from the reads alone -- with an RGB scalar (ks) beside the texels,
per channel one block of every texel a pixel reads and the channel's scalars, with a scalar of every
channel (n) one block of all; without scalars, per channel the connected components of the texel
graph (texels read by a common pixel) -- and the texels of a block over
`stats.SPARSE_STATS_MAX` entries (and the scalars with them) get no colour and no column: their
standard errors are nan (`stats.covariance_diagonal`'s `skip`). The prediction is an upper bound,
never smaller than a real block, and can be larger: a texel whose reads all have zero derivative,
reads of pixels at weight 0 (a refit without clipped pixels keeps them) and a scalar of another
material (its real block is its own) are counted in -- so near the limit, or beside a large texture,
some entries report nan where the dense path would give numbers; where a model mixed channels the
real blocks would be larger, and `stats.covariance_diagonal` still sizes them.
When nothing is left no Jacobian is formed at all (a 128^2 texture with ks at 512^2 pixels: the
stats phase 3.0 -> 0.52 s, peak RSS 996 -> 714 MiB, medians of 3 interleaved, load 2.8).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from . import stats


def texel_columns(layout) -> np.ndarray:
    """(T, 3) the flat-vector entry of each stacked texel's channels (`texels.stacked_texels` order)."""
    parts, offset = [], 0
    for p in layout:
        if p.shape is not None:
            parts.append(offset + np.arange(p.size).reshape(-1, 3))
        offset += p.size
    return np.concatenate(parts) if parts else np.zeros((0, 3), np.int64)


def texel_reads(problem) -> tuple[np.ndarray, np.ndarray]:
    """(pixel, texel) int64 pairs over every view: pixel numbered across the views in residual
    order (residual entry i belongs to pixel i // 3), texel a stacked texel row."""
    pixels, texels, offset = [], [], 0
    for view in problem.views:
        pixel, texel = view.model.texel_reads()
        pixels.append(pixel + offset)
        texels.append(texel)
        offset += view.target.shape[0]
    return np.concatenate(pixels), np.concatenate(texels)


def read_graph(pixel, texel, n_texels: int) -> sp.csr_matrix:
    """(T, T) sparse: nonzero where two texels (or a texel and itself) are read by a common pixel."""
    n_pixels = int(pixel.max(initial=-1)) + 1
    reads = sp.csr_matrix((np.ones(pixel.size, np.float32), (pixel, texel)), shape=(n_pixels, n_texels))
    return (reads.T @ reads).tocsr()


def colour_texels(together: sp.csr_matrix) -> np.ndarray:
    """(T,) a colour per texel, greedily (the smallest one none of its neighbours in the `read_graph`
    has), such that no pixel reads two texels of one colour; texels no pixel reads get colour 0."""
    colour = np.full(together.shape[0], -1, np.int64)
    colour[np.diff(together.indptr) == 0] = 0  # unread (or skipped): no neighbour, no loop
    for t in np.flatnonzero(colour < 0):
        taken = colour[together.indices[together.indptr[t]:together.indptr[t + 1]]]
        free = np.ones(taken.size + 1, bool)
        free[taken[(taken >= 0) & (taken <= taken.size)]] = False
        colour[t] = np.argmax(free)
    return colour


def scalar_channels(layout) -> np.ndarray:
    """(E,) the colour channel of each scalar (not texel) entry in flat order: c for entry c of an
    RGB (3-entry) parameter, -1 (every channel) for one of another size (n, a grey ks)."""
    parts = [np.arange(3) if p.size == 3 else np.full(p.size, -1) for p in layout if p.shape is None]
    return np.concatenate(parts) if parts else np.zeros(0, np.int64)


def stats_blocks(together: sp.csr_matrix, channels: np.ndarray, limit: int) -> tuple[np.ndarray, bool]:
    """(keep (T,) bool, scalars kept): the texels, and whether the scalar entries of `channels`
    (`scalar_channels`), lie in a predicted block of J^T J of at most `limit` entries; a texel no
    pixel reads is a block alone. A texel's channel reaches its pixels' channel alone, so with R
    texels read: scalars of one channel each -- s_c in channel c -- join that channel's read texels,
    R + max s_c entries; one of every channel joins them all, 3 R + E; without scalars the blocks are
    a channel's connected components of the `read_graph`."""
    read = together.diagonal() > 0
    if channels.size:
        n_read = int(np.count_nonzero(read))
        size = 3 * n_read + channels.size if (channels < 0).any() else \
            n_read + int(np.bincount(channels, minlength=3).max())
        return ~read | (size <= limit), size <= limit
    _, label = connected_components(together, directed=False)
    return np.bincount(label)[label] <= limit, False


@eqx.filter_jit
def _products(problem, x, seeds):
    plain = dataclasses.replace(problem, loss="l2", smoothness=0.0)  # its residuals: `Problem.weighted`
    r, jvp = jax.linearize(plain.residuals, x)
    return r, jax.vmap(jvp)(seeds)


@eqx.filter_jit
def _weighted(problem, values):
    return problem.weighted(values)


def sparse_jacobian(problem, values, limit: int | None = None) -> tuple[sp.csc_matrix, np.ndarray, np.ndarray]:
    """(J (N, p) float64 CSC, r (N,) float64, skipped (p,) bool): the plain weighted residuals r at
    flat `values` (scene units) and their Jacobian with respect to the values, by column compression
    (module docstring), without the columns of the entries in predicted blocks of J^T J over `limit`
    entries (`skipped`; None: no limit). With every seen entry skipped no product is made."""
    layout = problem.layout
    values = np.asarray(values)
    columns = texel_columns(layout)
    scalar = np.setdiff1d(np.arange(layout.size), columns.reshape(-1))
    pixel, texel = texel_reads(problem)
    together = read_graph(pixel, texel, columns.shape[0])
    keep, keep_scalars = (np.ones(columns.shape[0], bool), True) if limit is None else \
        stats_blocks(together, scalar_channels(layout), limit)
    skipped = np.zeros(layout.size, bool)
    skipped[columns[~keep].reshape(-1)] = True
    skipped[scalar] = not keep_scalars
    if not keep[texel].any() and not (keep_scalars and scalar.size):  # nothing seen left: no Jacobian
        r = np.asarray(_weighted(problem, jnp.asarray(values)), np.float64)
        return sp.csc_matrix((r.size, layout.size)), r, skipped
    if not keep.all():
        pixel, texel = pixel[keep[texel]], texel[keep[texel]]
        together = read_graph(pixel, texel, columns.shape[0])
    scalar = scalar[:scalar.size if keep_scalars else 0]
    colour = colour_texels(together)
    n_colours = int(colour.max(initial=-1)) + 1
    seeds = np.zeros((3 * n_colours + scalar.size, layout.size), values.dtype)
    for c in range(3):
        seeds[3 * colour[keep] + c, columns[keep, c]] = 1.0
    seeds[3 * n_colours + np.arange(scalar.size), scalar] = 1.0
    x = jnp.asarray(layout.x_of(values), values.dtype)
    r, products = _products(problem, x, jnp.asarray(seeds))
    r, products = np.asarray(r, np.float64), np.asarray(products, np.float64)
    n = r.size
    owner = np.full((n_colours, n // 3), -1, np.int64)  # per colour and pixel: the texel of that colour it reads
    owner[colour[texel], pixel] = texel
    by_colour = products[:3 * n_colours].reshape(n_colours, 3, n)
    read = owner[:, np.arange(n) // 3]  # (C, N)
    k, c, i = np.nonzero((read[:, None, :] >= 0) & (by_colour != 0.0))
    s_rows, s_seed = np.nonzero(products[3 * n_colours:].T)
    rows = np.concatenate([i, s_rows])
    cols = np.concatenate([columns[read[k, i], c], scalar[s_seed]])
    data = np.concatenate([by_colour[k, c, i], products[3 * n_colours + s_seed, s_rows]])
    scale = np.where(layout.entries("log") > 0, np.asarray(values, np.float64), 1.0)  # d value / d x
    return sp.csc_matrix((data / scale[cols], (rows, cols)), shape=(n, layout.size)), r, skipped


def sparse_normal_matrix(problem, values) -> tuple[sp.csc_matrix, tuple, np.ndarray]:
    """(J^T J (p, p) float64 sparse, r per view (3, U), skipped (p,) bool): `stats.normal_matrix`'s
    pair from the sparse J, without the entries of predicted blocks over `stats.SPARSE_STATS_MAX`
    (skipped)."""
    jac, r, skipped = sparse_jacobian(problem, values, stats.SPARSE_STATS_MAX)
    return (jac.T @ jac).tocsc(), problem.view_residuals(r), skipped
