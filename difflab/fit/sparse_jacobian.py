"""The Jacobian of a fit's plain weighted residuals at a point as a sparse matrix, by column
compression (Curtis, Powell and Reid 1974): the standard errors of matrix-free fits (`stats.py`).

A residual entry (used pixel u, channel) depends on the scalar entries (ka, kd, ks, n, ...) and on
the fitted texels its points' filter taps read -- nearest 1, bilinear 4 per lookup; through the ray
tree the taps of every node of the pixel's samples (`GBufferModel.texel_reads`,
`TreeModel.texel_reads`) -- in any channel, for all this module assumes. Texels no pixel reads
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
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp


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


def colour_texels(pixel, texel, n_texels: int) -> np.ndarray:
    """(T,) a colour per texel, greedily (the smallest one none of its neighbours has), such that no
    pixel reads two texels of one colour; texels no pixel reads get colour 0."""
    n_pixels = int(pixel.max(initial=-1)) + 1
    reads = sp.csr_matrix((np.ones(pixel.size, np.float32), (pixel, texel)), shape=(n_pixels, n_texels))
    together = (reads.T @ reads).tocsr()  # texels read by a common pixel
    colour = np.full(n_texels, -1, np.int64)
    for t in range(n_texels):
        taken = colour[together.indices[together.indptr[t]:together.indptr[t + 1]]]
        free = np.ones(taken.size + 1, bool)
        free[taken[(taken >= 0) & (taken <= taken.size)]] = False
        colour[t] = np.argmax(free)
    return colour


@eqx.filter_jit
def _products(problem, x, seeds):
    plain = dataclasses.replace(problem, loss="l2", smoothness=0.0)  # its residuals: `Problem.weighted`
    r, jvp = jax.linearize(plain.residuals, x)
    return r, jax.vmap(jvp)(seeds)


def sparse_jacobian(problem, values) -> tuple[sp.csc_matrix, np.ndarray]:
    """(J (N, p) float64 CSC, r (N,) float64): the plain weighted residuals r at flat `values` (scene
    units) and their Jacobian with respect to the values, by column compression (module docstring)."""
    layout = problem.layout
    values = np.asarray(values)
    columns = texel_columns(layout)
    scalar = np.setdiff1d(np.arange(layout.size), columns.reshape(-1))
    pixel, texel = texel_reads(problem)
    colour = colour_texels(pixel, texel, columns.shape[0])
    n_colours = int(colour.max(initial=-1)) + 1
    seeds = np.zeros((3 * n_colours + scalar.size, layout.size), values.dtype)
    for c in range(3):
        seeds[3 * colour + c, columns[:, c]] = 1.0
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
    return sp.csc_matrix((data / scale[cols], (rows, cols)), shape=(n, layout.size)), r


def sparse_normal_matrix(problem, values) -> tuple[sp.csc_matrix, np.ndarray]:
    """(J^T J (p, p) float64 sparse, r (N,)): `stats.normal_matrix`'s pair from the sparse J."""
    jac, r = sparse_jacobian(problem, values)
    return (jac.T @ jac).tocsc(), r
