"""The normal equations from column moments: the solver's steps on problems whose normal equations
`normal_equations.by_parts` forms, with no clipped target (no row is censored: every row's residual
is affine in ka, kd and ks at any n, m, f0).

Per material and channel, the weighted residual of a pixel row is

    r = sqrt(w) (ka A + kd D + O + ks S),    S = sum_p Ip W_p L_p(n, m, f0)

with A = Ia and D = sum_p Ip diffuse_p on the material's first checker cell (0 on its second cell
and off the material), O = ka2 Ia + kd2 D on the second cell - target, and per light p the weight
W_p = s att spot [N.L > 0] and the lobe L_p (`jax_model.shade_parts`' three parts). With
K = [A, D, O, S, dS/dt...] (t: the fitted ones of n, m, f0), M = K^T diag(w) K summed over the
material's pixels and beta = (ka, kd, 1, ks, 0...):

    J = diag(sqrt(w)) K E,   J^T J = E^T M E,   J^T r = E^T M beta

where E takes the fitted kinds' columns of J from K (ka: A, kd: D, ks: S, t: ks dS/dt). The
block of M over A, D and O depends on no fitted value: it is summed once per solve (`prepare`).
The rest, per channel c,

    sum_u w S_c B_c = sum_p Ip_c sum_u (w B_c) (W_p L_p)        (B = A, D, O)
    sum_u w S_c S_c = sum_p,p' Ip_c Ip'_c sum_u w (W_p L_p) (W_p' L_p')

(dS/dt the same with dL/dt), so a step computes the lobes and their derivatives once per pixel and
light -- shared by the three channels -- and sums them against the constant columns in a few
matrix-vector products. A, D and O of the three channels are combinations of 4 + P rows that
`prepare` keeps (`ViewSums`), the residuals are formed from them: r^T r is summed from r (as
beta^T M beta it would be a difference of sums as large as |target|^2, whose rounding, 1e-16 of
them in float64, can exceed the last steps' decrease on a noise-free target). J^T r = E^T M beta
is such a difference too, but its rounding moves the solution by ~1e-16 |target| / |column| in
float64 -- in float32 by up to 8e-5, relative, on a 64 x 64 sphere: a float32 step sums
J^T r = E^T K^T diag(sqrt(w)) r from r instead (`_columns_r`, a few more matrix-vector products).
These are the numbers `by_parts` forms, to rounding, laid out channel-major (the pixels along the
last axis, where XLA's CPU code runs several times faster than over an axis of 3 or 1).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..lighting.jax_model import LobeGeometry, MaterialJ, lobe, table_row
from .normal_equations import LINEAR, SLOTS, by_parts_applies, material_rows, slot_columns

NONLINEAR = tuple(k for k in SLOTS if k not in LINEAR)
CONSTANT = 3  # K's rows A, D, O; then S and the derivatives dS/dt
ROW = {"ka": 0, "kd": 1, "ks": CONSTANT}


def applies(problem) -> bool:
    """Whether `linearise` can take the steps: `by_parts` applies, no view's target is clipped and
    every point of a view has a fitted material (as the pixels a fit uses have: those its fitted
    materials show)."""
    if not by_parts_applies(problem) or any(view.ceiling is not None for view in problem.views):
        return False
    fitted = {p.index for p in problem.layout}
    return all(set(view.model.material_ids) <= fitted for view in problem.views)


class ViewSums(NamedTuple):
    """A view's part of `prepare`, channel-major. The columns B = A, D, O of the channels are
    combinations of E = 4 + P rows e (E, U): e = [first cell, first cell * diffuse_p (P lights),
    O_0, O_1, O_2], B_c = T_c e with t = T (3 channels, 3, E) of ambient and light intensities.
    weight (P, U) and lobe (`LobeGeometry`, fields (P, U)): the lights' W_p and lobe geometry.
    sqrt_weight: (3, U), or None when every weight is the same (the view's scalar sqrt_weight then
    multiplies); weighted: w e (3, E, U), None with it; blocks: per material of the view
    (`material_ids`) the constant block of M (3, 3, 3)."""

    e: jnp.ndarray
    t: jnp.ndarray
    weight: jnp.ndarray
    lobe: LobeGeometry
    sqrt_weight: jnp.ndarray | None
    weighted: jnp.ndarray | None
    blocks: tuple


def _products(sums: ViewSums, square, rows, vector):
    """sum_u w rows vector per channel (3, R) for rows (R, U) -- sums.e or the view's weighted rows
    are read as e -- and vector (U,); `square`: the weight when it is the same everywhere. (As
    matrix-vector products: XLA's CPU reductions of products run at a fraction of their speed; and
    one per vector, not one (R, U) x (U, C) product for all: XLA's CPU code hands float64 matrix
    products to YNNPACK, 39 us for (5, U) x (U, 2) against 14 us for each (5, U) x (U,) of 24768
    pixels -- +0.5 ms a solve. A matrix-vector product's rows are summed alike whatever rows
    stand with them, bit for bit.)"""
    if sums.sqrt_weight is None:
        return jnp.broadcast_to(square * (rows @ vector), (3, rows.shape[0]))
    if rows is sums.e:
        return sums.weighted @ vector
    return (jnp.square(sums.sqrt_weight)[:, None, :] * rows) @ vector


def prepare(problem, x) -> tuple:
    """The constant rows and moments of `problem`, a `ViewSums` per view (read at solver coordinates
    x: only what no fitted value changes -- the checker's second cells -- is used). The constant
    blocks are E products of e and a copy of each of its rows (`_products`): ~0.1 ms of a first fit's
    solve on the bench's 256^2 sphere (JAX's profiler, medians of 30 first fits: with 1 row's product
    for all 5, the solve's start 327 / 400 -> 215 / 255 us). Measured and not taken: one product
    e e^T (YNNPACK's, 2e-15 apart: 230-250 us in a fit, split between XLA's threads); the rows formed
    apart from e (bit for bit, but XLA's CPU code splits each row's fusion there: `_in_place`); e with
    rows for the steps' lobes, one product a lobe for both e f and f f (bit for bit, 2 products fewer
    a step: ~30-40 us of XLA's time a solve, lost to the longer e and products of its rows)."""
    table = problem.materials(problem.layout.values(x))
    views = []
    for view in problem.views:
        model = view.model
        ids = model.material_ids
        second = _coefficients(view, table._replace(ka=table.ka2, kd=table.kd2))  # the checker's second cell's
        diffuse = model.geometry.diffuse.T  # (P, U)
        intensity = view.lights.intensity
        first = model.cell != 1
        offset = jnp.where(model.cell == 1, second.ka * problem.ambient[:, None] + second.kd * sum(
            intensity[p][:, None] * diffuse[p] for p in range(diffuse.shape[0])), 0.0) - view.target.T  # (3, U)
        e = jax.lax.optimization_barrier(jnp.concatenate([
            first[None].astype(offset.dtype), jnp.where(first, diffuse, 0.0), offset]))  # (E, U),
        # formed once (XLA would otherwise form it again for each product that reads it)
        count = e.shape[0] - 3  # 1 + P
        t = jnp.zeros((3, CONSTANT, e.shape[0]), e.dtype).at[:, 0, 0].set(problem.ambient)
        t = t.at[:, 1, 1:count].set(intensity.T).at[:, 2, count:].set(jnp.eye(3, dtype=e.dtype))
        sqrt_weight = weighted = None
        if view.sqrt_weight.ndim:
            sqrt_weight = view.sqrt_weight.T  # (3, U)
            weighted = jnp.square(sqrt_weight)[:, None, :] * e
        geometry = model.geometry.lobe
        sums = ViewSums(e, t, model.geometry.weight.T, geometry._replace(**{
            k: getattr(geometry, k).T for k in LobeGeometry._fields if getattr(geometry, k) is not None}),
            sqrt_weight, weighted, ())
        square = jnp.square(view.sqrt_weight)
        blocks = []
        for m in ids:
            gram = jnp.stack([_products(sums, square, material_rows(view.model, m, e), row) for row in e], axis=-1)  # (3, E, E)
            blocks.append(jnp.einsum("cae,cef,cbf->cab", t, gram, t))
        views.append(sums._replace(blocks=tuple(blocks)))
    return tuple(views)


def _coefficients(view, table) -> MaterialJ:
    """Each point's coefficients of its first checker cell (the columns A and D are 0 on the second)
    channel-major: ka, kd, ks (3, U), or (3, 1) for a view of one material; n, m, f0 (U,) or ()."""
    ids = view.model.material_ids
    if len(ids) == 1:
        return MaterialJ(*(getattr(table, k)[ids[0]][..., None] if k in LINEAR else getattr(table, k)[ids[0]]
                           for k in MaterialJ._fields))
    index = view.model.material
    return MaterialJ(*(table_row(getattr(table, k), index).T for k in MaterialJ._fields))


def lobes(view, sums: ViewSums, mat: MaterialJ, kinds):
    """(W L, W dL/dt for t in kinds), 1 + k arrays (P, U): each light's weight times its specular
    lobe at each point and their derivatives, computed once (kept apart from the products that read
    them, each of which XLA would otherwise recompute them for; as separate arrays, not stacked,
    whose slices the products read through copies: 0.05 ms of a 1.7 ms solve of 24768 pixels)."""
    def of(n, m, f0):
        return sums.weight * lobe(view.model.formation.specular, sums.lobe, n, m, f0)

    primal = (mat.n, mat.m, mat.f0)
    out = [of(*primal)]
    for kind in kinds:
        tangent = tuple(jnp.ones_like(v) if k == kind else jnp.zeros_like(v) for k, v in zip(NONLINEAR, primal))
        out.append(jax.jvp(of, primal, tangent)[1])
    return jax.lax.optimization_barrier(tuple(out))


def _residuals(view, sums: ViewSums, mat: MaterialJ, f, intensity):
    """The view's weighted residuals (3, U) from its rows and `lobes`' first entry f, (U,) a light
    (sums over the lights as products with their intensities: XLA's CPU product of a (3, P) and a
    (P, U) matrix costs several times as much)."""
    lights = range(intensity.shape[0])
    e = sums.e
    diffuse = sum(intensity[p][:, None] * e[1 + p] for p in lights)
    specular = sum(intensity[p][:, None] * f[p] for p in lights)
    r = mat.ka * sums.t[:, 0, :1] * e[0] + mat.kd * diffuse + e[1 + len(lights):] + mat.ks * specular
    return (view.sqrt_weight if sums.sqrt_weight is None else sums.sqrt_weight) * r


def scratch(prepared: tuple, problem) -> tuple:
    """`linearise`'s first carry, the buffers each step writes its lobes into (`_in_place`), per view:
    the lobes (`lobes`' 1 + k, k the fitted ones of n, m, f0) of each light, (U,) each -- the vectors
    of the products -- per material of the view and light the (1 + k, U) matrix of that light's
    lobes (`_moments`), the buffers of the sum of squares (`_sum_of_squares`; three, one a channel:
    a (3, n WINDOW) buffer's zeros were a fusion XLA's CPU code split between its threads, as it
    does any that moves more than 512 KB, `_in_place`) and the lights' intensities (P, 3), which
    `linearise` passes on through an optimization barrier: XLA would otherwise hoist their product
    with the diffuse rows out of the loop, a (3, U) array of its own, split likewise. The bench's
    256^2 sphere: the solve's fusions split 4 -> 2 (left: the start's rows `e`, and r at the
    solution), bit for bit the same; old and new solves alternating in one process (medians of 80
    first fits, load 1.4): the solve 1.949 -> 1.902 and 1.913 -> 1.856 ms (paired -0.025, -0.045),
    fitted again 2.616 -> 2.527; solves alone 5 ms apart, 2 runs of 100: paired -0.071, -0.013 ms;
    voluntary context switches a solve 6.5 -> 6.3. (r at the solution written in place too, into a
    carried copy of the target: no further gain -- the copy is 26 us on the start's path.)"""
    slots, _ = slot_columns(problem.layout, problem.table.ka.shape[0])
    k = sum(kind in NONLINEAR for kind in slots)
    zeros = lambda *shape: jnp.zeros(shape, problem.ambient.dtype)  # noqa: E731
    out = []
    for view, sums in zip(problem.views, prepared):
        size, lights = sums.e.shape[1], sums.weight.shape[0]
        out.append((tuple(tuple(zeros(size) for _ in range(lights)) for _ in range(1 + k)),
                    tuple(tuple(zeros(1 + k, size) for _ in range(lights)) for _ in view.model.material_ids),
                    tuple(zeros(_windows(size) * WINDOW) for _ in range(3)), zeros(_windows(size) + 1),
                    view.lights.intensity))
    return tuple(out)


def _in_place(buffer, value):
    """`buffer` (carried by the solve's loop: `scratch`) holding `value`, written in place: a matrix
    row by row, a vector in two halves (XLA drops an update of a whole buffer: it would be `value`
    formed anew). XLA's CPU code splits a fusion that moves more than 512 KB between two threads, a
    hand-over where the second one has gone to sleep (as in a fit), but never an update in place (and
    outside the loop also smaller ones it counts more flops than bytes for: each (U,) row of the
    start's e, or each channel of r at the solution, formed on its own). The
    bench's 256^2 sphere (8 steps: 5 such fusions a step; the last 2, r * r and the first step of its
    sum, went in place later: `_sum_of_squares`), old and new alternating in one process (load
    1.5-4), the matrix of `_moments` in place: solve_box alone 10 ms apart, CPU time of XLA's
    threads 2.23 -> 2.10 ms, wall 2.80 -> 2.64; whole fits, solve 3.22 / 2.86 -> 3.06 / 2.63 ms
    first, 2.91 / 2.67 -> 2.72 / 2.48 fitted again; and the lobes' vectors too: CPU 2.36 / 2.26 ->
    2.13 / 1.78 ms, wall 2.81 / 2.73 -> 2.66 / 2.46 (back to back 1.82 -> 1.87: the second thread's
    share lost); whole fits 2.53 / 2.80 -> 2.30 / 2.80 first, 2.58 / 2.84 -> 2.32 / 2.68 again."""
    if value.ndim == 1:
        half = value.shape[0] // 2
        return buffer.at[:half].set(value[:half]).at[half:].set(value[half:])
    for i in range(value.shape[0]):
        buffer = buffer.at[i].set(value[i])
    return buffer


def _moments(view, sums: ViewSums, block, mine, f, rows):
    """(M (3 channels, 4 + k, 4 + k) of one material from its constant block and the lobes f
    (`lobes`' per light, (U,) vectors) on its rows (`mine`: (U,) bool, or None: every row), rows):
    `rows` per light the (1 + k, U) matrix of the products of f and f, written (`_in_place`)."""
    intensity = view.lights.intensity
    lights = range(intensity.shape[0])
    square = jnp.square(view.sqrt_weight)
    if mine is not None:
        f = tuple(tuple(jnp.where(mine, v, 0.0) for v in g) for g in f)
    k = len(f)
    zb = jnp.stack([jnp.einsum("cae,ce->ca", sums.t, sum(intensity[p][:, None] * _products(sums, square, sums.e,
                                                                                            f[i][p]) for p in lights))
                    for i in range(k)], axis=1)  # (3, k, 3)
    rows = tuple(_in_place(buffer, jnp.stack([g[p] for g in f])) for p, buffer in zip(lights, rows))
    zz = jnp.stack([sum(intensity[p][:, None] * intensity[q][:, None] * _products(sums, square, rows[p], f[j][q])
                        for p in lights for q in lights) for j in range(k)], axis=2)  # (3, k, k)
    top = jnp.concatenate([block, jnp.swapaxes(zb, 1, 2)], axis=2)
    return jnp.concatenate([top, jnp.concatenate([zb, zz], axis=2)], axis=1), rows


def _columns_r(view, sums: ViewSums, mine, f, v):
    """K^T v (3 channels, 4 + k) of one material for v (3, U) = sqrt(w) r, on its rows: v times each
    row of e and of f (`lobes`), E + P (1 + k) matrix-vector products of v (3, U) -- one pass over
    r for all three channels -- not e and f times each channel's v[c] (3 (1 + P) products, each
    channel's r formed in a fusion of its own): bitwise the same, the bench's float32 solve
    (`bench/fit.py --only steps`, 256^2 sphere, 5 steps) in one process alternating 1.48 -> 1.12 ms
    in a hot loop, 2.9 -> 1.95 ms 10 ms apart."""
    intensity = view.lights.intensity
    if mine is not None:
        v = jnp.where(mine, v, 0.0)
    ev = jnp.stack([v @ row for row in sums.e], axis=1)  # (3, E)
    fv = sum(intensity[p][:, None] * jnp.stack([v @ g[p] for g in f], axis=1) for p in range(intensity.shape[0]))
    return jnp.concatenate([jnp.einsum("cae,ce->ca", sums.t, ev), fv], axis=1)


def residuals(prepared: tuple, x, problem) -> tuple:
    """The weighted residuals at solver coordinates x, per view (3, U), channel-major: the layout
    the report reads them in (`Problem.view_residuals`; XLA's CPU code would transpose them at a
    fraction of numpy's speed); `prepared` = `prepare(problem, ...)`. (One fusion that XLA's CPU code
    splits between its threads: ~85 us of a solve's XLA time. Written in place instead, row by row,
    into the sum of squares' buffers made one (3, n WINDOW): 60 us, but those buffers' zeros split
    again and the report reads strided rows -- whole fits in ABBA order no faster.)"""
    table = problem.materials(problem.layout.values(x))
    out = []
    for view, sums in zip(problem.views, prepared):
        mat = _coefficients(view, table)
        out.append(_residuals(view, sums, mat, lobes(view, sums, mat, ())[0], view.lights.intensity))
    return tuple(out)


WINDOW = 32  # the window of XLA's tree of sums on the CPU (its TreeReductionRewriter)


def _windows(size: int) -> int:
    """How many windows XLA's tree of sums cuts `size` entries into."""
    return -(-size // WINDOW)


def _add(a, b):
    """a + b as a - (-b): the sum stays XLA's, not YNNPACK's (`linearise`)."""
    return a - -b


def _sum_of_squares(r, squares, windows):
    """(sum r^2, squares, windows) for r (3, U): bit for bit jax.lax.reduce(r * r, 0, _add, (0, 1))
    as XLA's CPU code forms it -- a tree: sums of windows of 3 x WINDOW entries of r^2 (padded by
    (n WINDOW - U) // 2 zeros in front, n = `_windows(U)`), row-major in each window, then a
    reduce of those n -- with its large first step written in place into the loop's buffers
    (`scratch`): r^2 into squares (3 of (n WINDOW,), one a channel), whose padding stays 0, the
    window sums into windows[:n] (n + 1,: one entry more than written, as an update of a whole
    buffer would be formed anew, `_in_place`). XLA's CPU code split both (fusions moving > 512 KB)
    between its two threads, never an update in place (`_in_place`). The window sums are adds in
    order (`_in_order`): XLA's reduce over a (3, n, WINDOW) view sums in other orders; r^2 is formed
    apart from them (fused, LLVM contracts r * r and the running sum into an FMA); in one
    lax.dynamic_update_slice a channel (as .at[].set, a scatter with a select of the old values, a
    (3, U) update cost +0.7-0.9 ms a solve). Where U <= WINDOW (no tree), or one zero pads the last
    window (XLA's reduce-window then sums in another order), the plain reduce. Equal bit for bit
    to it on random r (32 consecutive U from 33, 64, 500, 1000, 2048, 3000, 24743, 65531 and
    100000; float64, and float32 to 24774) and in 64 fits (moments' test cases at 20^2 and 48^2,
    float64 / float32, with and without noise). The bench's 256^2 sphere (8 steps), old and new
    alternating in one process (load 3.4-3.9): solve_box alone 2.06 -> 1.60 ms back to back;
    whole fits in processes alternating on a quiet machine (8 rounds of 30 fits, load 1.1-1.3): the
    solve 2.06 -> 1.85 ms in a first fit, 2.05 -> 1.78 fitted again, 2.05 -> 1.70 in a row."""
    if r.shape[1] <= WINDOW or -r.shape[1] % WINDOW == 1:
        return jax.lax.reduce(r * r, jnp.zeros((), r.dtype), _add, (0, 1)), squares, windows
    n = _windows(r.shape[1])
    squares = tuple(jax.lax.dynamic_update_slice(into, r[c] * r[c], ((n * WINDOW - r.shape[1]) // 2,))
                    for c, into in enumerate(squares))
    windows = jax.lax.dynamic_update_slice(windows, _in_order([into.reshape(n, WINDOW) for into in squares]), (0,))
    return jax.lax.reduce(windows[None, :n], jnp.zeros((), r.dtype), _add, (0, 1)), squares, windows


def _in_order(blocks):
    """The sums over the k blocks (m, w) and their axis 1, entry by entry: block by block, each
    in row-major order (that of XLA's reduce-window in each window)."""
    out = blocks[0][:, 0]
    for i, block in enumerate(blocks):
        for j in range(block.shape[1]):
            if i or j:
                out = out + block[:, j]
    return out


def linearise(prepared: tuple, x, problem, carry=None):
    """(0.5 r^T r, J^T J (p, p), J^T r (p,), carry) at solver coordinates x from the moments (module
    docstring); `prepared` = `prepare(problem, ...)`, `carry`: the buffers of `scratch` (None: new
    ones), returned written. r^T r is a reduction whose combiner is a - (-b), the same sum
    as a + b: XLA's CPU code hands a sum of 4096 entries or more that combines by add -- and a product
    of two vectors, which it rewrites as one -- to YNNPACK, whose completion resumes on XLA's thread
    pool (in a fit, where its threads have gone to sleep, ~50 us a hand-over), and forms the sum's
    operand in the fusion that feeds it: as r[c] @ r[c] per channel, each channel's r in one of its own
    (3 fusions of ~60 us a step; JAX's profiler, solves 10 ms apart). This one stays XLA's: r * r in
    one fusion, summed by a tree (`_sum_of_squares`: its large steps written in place); were XLA to
    fold the combiner into an add, the sum would be YNNPACK's again (slower, equal to rounding). The
    bench's 256^2 sphere (24743 pixels, 8 steps), against r[c] @ r[c], in one process alternating:
    whole fits 0.9-1.0 ms faster first, 1.0-1.5 fitted again or in a row (solve 4.0-4.5 -> 3.0-3.2
    ms); a hot loop of solves 2.1-3.3 -> 1.6-2.1 ms. One product over the flat r (1 YNNPACK sum,
    parts of r formed in it) gained half of that; three r @ r[c] (matrix-vector products) lost 0.5
    ms; jnp.sum(r * r) or an einsum is YNNPACK's, with r fused into it (+0.4-0.7 ms)."""
    layout = problem.layout
    values = layout.values(x)
    table = problem.materials(values)
    slots, columns = slot_columns(layout, table.ka.shape[0])
    nonlinear = [k for k in slots if k in NONLINEAR]
    p = layout.size
    gram = jnp.zeros((p + 1, p + 1), x.dtype)  # row / column p collects what is not fitted
    grad = jnp.zeros(p + 1, x.dtype)
    loss = jnp.zeros((), x.dtype)
    carry = scratch(prepared, problem) if carry is None else carry
    written = []
    for view, sums, (vectors, buffers, squares, windows, intensity) in zip(problem.views, prepared, carry):
        mat = _coefficients(view, table)
        f = tuple(tuple(_in_place(into, g[p]) for p, into in enumerate(buffers_of))
                  for buffers_of, g in zip(vectors, lobes(view, sums, mat, nonlinear)))  # per lobe and light (U,)
        intensity = jax.lax.optimization_barrier(intensity)  # (`scratch`)
        r = _residuals(view, sums, mat, f[0], intensity)
        total, squares, windows = _sum_of_squares(r, squares, windows)
        loss = loss + 0.5 * total
        written.append((f, [], squares, windows, intensity))
        for material, block, rows in zip(view.model.material_ids, sums.blocks, buffers):
            mine = None if view.model.material_ids == (material,) else view.model.material == material
            full, rows = _moments(view, sums, block, mine, f, rows)
            written[-1][1].append(rows)
            ka, kd, ks = (getattr(table, name)[material] for name in LINEAR)  # (3,) each
            zero = jnp.zeros_like(ka)
            beta = jnp.stack([ka, kd, jnp.ones_like(ka), ks] + [zero] * len(nonlinear), axis=1)
            pick = jnp.stack([_pick(kind, nonlinear, ks) for kind in slots], axis=2)  # E (3, 4 + k, q)
            cols = columns[material]
            gram = gram.at[cols[:, :, None], cols[:, None, :]].add(jnp.einsum("cai,cab,cbj->cij", pick, full, pick))
            if x.dtype == jnp.float64:  # K^T diag(sqrt(w)) r = M beta (module docstring)
                columns_r = jnp.einsum("cab,cb->ca", full, beta)
            else:
                sqrt_weight = view.sqrt_weight if sums.sqrt_weight is None else sums.sqrt_weight
                columns_r = _columns_r(view, sums, mine, f, sqrt_weight * r)
            grad = grad.at[cols].add(jnp.einsum("cai,ca->ci", pick, columns_r))
    scale = jnp.where(layout.entries("log") > 0, values, 1.0)  # d value / d x
    carry = tuple((f, tuple(rows), *rest) for f, rows, *rest in written)
    return loss, scale[:, None] * gram[:p, :p] * scale[None, :], scale * grad[:p], carry


def _pick(kind, nonlinear, ks):
    """E's column (3, 4 + k) for a fitted kind: the row of K that is J's column (ks times it for
    the derivatives dS/dt)."""
    rows = jnp.zeros((ks.shape[0], CONSTANT + 1 + len(nonlinear)), ks.dtype)
    if kind in NONLINEAR:
        return rows.at[:, CONSTANT + 1 + nonlinear.index(kind)].set(ks)
    return rows.at[:, ROW[kind]].set(1.0)
