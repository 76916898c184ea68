"""Texels as fitted parameters: a material's image texture, one unknown per texel and channel.

On a Phong G-buffer every shading point is a sample with texture coordinates uv -- and in a recorded
ray tree every node that hit a textured surface has its uv (`RayTree.uv`) -- and the texture value
the renderer multiplied into the point's coefficient (`texture_target`: ka, kd or ks) is a fixed
linear combination of texels, the filter's taps at uv:

    texel(point) = sum_k w_k T[i_k]          (per channel; `texture_taps`, the Warp sampler's rules)

so the image stays affine in T (a ray tree's node weights do not depend on it) and the fit's
Jacobian is sparse (4 bilinear taps per point). The taps are built once per view
(`TexelSource.taps_at`); the texels travel in the flat parameter vector (texture orientation: row 0
= v 0, as the Warp texture store) and into `MaterialTable.texels`, where `shading.GBufferModel` and
`raytree.TreeModel` read them. Filters: "nearest" and "bilinear" (level 0; the magnification
filters, which need no footprint). An optional smoothness prior adds sqrt(smoothness) times the
differences of neighbouring texels to the residuals (`smoothness_residuals`), which also fills
texels no view sees.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DifflabError, FitError
from ..renderers.texture.store import load_texture
from ..vocabulary import TEXTURE_TARGET_IDS
from .params import KINDS, name_list

FIT_FILTERS = ("nearest", "bilinear")


def texture_taps(uv: np.ndarray, shape: tuple[int, int], filter: str, wrap: str) -> tuple[np.ndarray, np.ndarray]:
    """Texel indices and weights (N, K) of `filter` at level 0 of an (H_t, W_t) texture for uv (N, 2),
    with the Warp kernel's conventions (`renderers.texture.sampling`: texel centres at half-integers,
    wrap on the integer index); indices are row * W_t + column, row 0 at v = 0."""
    h, w = shape
    uv = np.asarray(uv, np.float32)
    if filter == "nearest":
        col = np.floor(uv[:, 0] * np.float32(w))
        row = np.floor(uv[:, 1] * np.float32(h))
        return (wrap_np(row, h, wrap) * w + wrap_np(col, w, wrap))[:, None], np.ones((uv.shape[0], 1), np.float32)
    if filter != "bilinear":
        raise FitError(f"filter: texture fitting supports {FIT_FILTERS}, got {filter!r}")
    x = uv[:, 0] * np.float32(w) - np.float32(0.5)
    y = uv[:, 1] * np.float32(h) - np.float32(0.5)
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    cols = [wrap_np(x0, w, wrap), wrap_np(x0 + 1, w, wrap)]
    rows = [wrap_np(y0, h, wrap), wrap_np(y0 + 1, h, wrap)]
    index = np.stack([rows[0] * w + cols[0], rows[0] * w + cols[1], rows[1] * w + cols[0], rows[1] * w + cols[1]], 1)
    weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return index, weight.astype(np.float32)


def wrap_np(i: np.ndarray, n: int, wrap: str) -> np.ndarray:
    """`renderers.texture.sampling.wrap_index` in numpy: integer-valued float indices -> [0, n - 1]."""
    i = np.where(np.isfinite(i), i, 0.0).astype(np.float64)
    if wrap == "clamp":
        i = np.clip(i, 0, n - 1)
    elif wrap == "mirror":
        i = np.mod(i, 2 * n)
        i = np.where(i >= n, 2 * n - 1 - i, i)
    else:
        i = np.mod(i, n)
    return np.clip(i, 0, n - 1).astype(np.int64)


def wants_texels(params) -> bool:
    """Whether `params` (the engine's argument) names a texture."""
    try:
        names = name_list(params, "params")
    except FitError:
        return False  # build_layout reports it
    return any(KINDS.get(name.rpartition(".")[2], KINDS["ka"]).texels for name in names)


def texture_starts(scene, materials, init) -> dict:
    """Material name -> its start texels (H_t, W_t, 3) float64, row 0 at the top, for the fitted
    materials with an image texture: `init["texture"]` / `init["name.texture"]` when given (an image,
    which also sets the texel grid, or a number / RGB triple filling the file's grid), else the
    texture file. Raises FitError naming the argument."""
    starts = {}
    for name in materials:
        mat = scene.materials[name]
        if mat.texture is None:
            continue
        if mat.filter not in FIT_FILTERS:
            raise FitError(f"materials[{name!r}].filter: texture fitting supports {FIT_FILTERS} (level 0), "
                           f"got {mat.filter!r}")
        key = next((k for k in (f"{name}.texture", "texture") if k in (init or {})), None)
        value = None if key is None else init[key]
        if value is not None and np.ndim(value) == 3:
            image = np.asarray(value, np.float64)
            if image.shape[2] != 3 or min(image.shape[:2]) < 1:
                raise FitError(f"init[{key!r}]: expected an (H_t, W_t, 3) texture, got shape {image.shape}")
        else:
            try:
                image = np.asarray(load_texture(mat.texture), np.float64)
            except DifflabError as exc:
                raise FitError(f"materials[{name!r}].texture: {exc}") from None
            if value is not None:
                fill = np.asarray(value, np.float64).reshape(-1)
                if fill.size not in (1, 3):
                    raise FitError(f"init[{key!r}]: expected a number, an RGB triple or an (H_t, W_t, 3) texture, "
                                   f"got shape {np.shape(value)}")
                image = np.broadcast_to(fill, image.shape).copy()
        if not np.all(np.isfinite(image)) or np.any(image < 0):
            raise FitError(f"init[{key!r}]: texels must be finite and >= 0")
        starts[name] = image
    return starts


def texel_blocks(layout) -> dict:
    """Material id -> (first row in the stacked texels, (H_t, W_t)) of each fitted texture, in
    layout order."""
    blocks, row = {}, 0
    for p in layout:
        if p.shape is not None:
            blocks[p.index] = (row, p.shape)
            row += p.shape[0] * p.shape[1]
    return blocks


@dataclass(frozen=True)
class TexelSource:
    """Where each G-buffer shading point reads its texels: material id -> (first stacked row,
    (H_t, W_t), filter, wrap), for the materials whose texture is fitted; targets: the TARGET_* ids
    their textures modulate."""

    blocks: dict
    targets: tuple

    @classmethod
    def from_layout(cls, layout, scene) -> TexelSource | None:
        mats = list(scene.materials.values())
        blocks = {i: (row, shape, mats[i].filter, mats[i].wrap) for i, (row, shape) in texel_blocks(layout).items()}
        targets = tuple(sorted({TEXTURE_TARGET_IDS[mats[i].texture_target] for i in blocks}))
        return cls(blocks, targets) if blocks else None

    def taps(self, gbuffer, point_ids) -> tuple[np.ndarray, np.ndarray]:
        """`taps_at` the points `point_ids` of a Phong G-buffer (point i = sample i)."""
        if gbuffer.shading != "phong":
            raise FitError(f"params: fitting texels needs Phong shading (a shading point per sample), the targets "
                           f"are rendered with {gbuffer.shading!r}; or fit through the ray tree (method='raytrace')")
        point_ids = np.asarray(point_ids, np.int64)
        material = gbuffer.points.material[point_ids] if point_ids.size else np.zeros(0, np.int32)
        uv = gbuffer.uv.reshape(-1, 2)[point_ids] if point_ids.size else np.zeros((0, 2), np.float32)
        return self.taps_at(material, uv)

    def taps_at(self, material, uv) -> tuple[np.ndarray, np.ndarray]:
        """(rows (R, K) int32 into the stacked texels, -1 where the point reads no fitted texture;
        weights (R, K)) for R points with material ids `material` (R,) that read their textures at
        `uv` (R, 2): G-buffer samples or ray-tree nodes."""
        rows = np.full((material.size, 4), -1, np.int32)
        weights = np.zeros((material.size, 4), np.float32)
        for mat_id, (first, shape, filter, wrap) in self.blocks.items():
            on = material == mat_id
            index, weight = texture_taps(uv[on], shape, filter, wrap)
            rows[on, :index.shape[1]] = first + index
            weights[on, :weight.shape[1]] = weight
        return rows, weights


def stacked_texels(layout, values):
    """(T, 3) the fitted textures' texels in layout order -- static slices of the flat values (no
    gather) -- or None without a texture."""
    parts, offset = [], 0
    for p in layout:
        if p.shape is not None:
            parts.append(values[offset:offset + p.size].reshape(-1, 3))
        offset += p.size
    return jnp.concatenate(parts) if parts else None


def point_texels(texels, rows, weights, other=1.0):
    """(R, 3) texel value of each point: its taps' weighted sum of the stacked `texels` (T, 3);
    `other` ((R, 3) or a number) where it reads none (1: its coefficient unmodulated)."""
    value = jnp.sum(weights[..., None] * texels[jnp.maximum(rows, 0)], axis=1)
    return jnp.where(jnp.any(rows >= 0, axis=1)[:, None], value, other)


def pixel_texels(pixel, point, taps) -> tuple[np.ndarray, np.ndarray]:
    """(pixel, texel) int64 pairs: for each (pixel, point) pair -- a point the pixel's colour sums --
    the stacked fitted texels the point's taps (R, K) read (rows -1: none); a model's `texel_reads`."""
    if taps is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    rows = np.asarray(taps, np.int64)[np.asarray(point, np.int64)]  # (M, K)
    keep = rows >= 0
    return np.repeat(np.asarray(pixel, np.int64), rows.shape[1])[keep.reshape(-1)], rows[keep]


def smoothness_residuals(layout, values, smoothness: float):
    """sqrt(smoothness) times the horizontal and vertical neighbour differences of every fitted
    texture (flat; empty when smoothness is 0): 0.5 |.|^2 is the first-difference prior."""
    parts, offset = [], 0
    for p in layout:
        if p.shape is not None and smoothness > 0.0:
            grid = values[offset:offset + p.size].reshape(p.shape + (3,))
            scale = jnp.sqrt(jnp.asarray(smoothness, values.dtype))
            parts += [scale * (grid[:, 1:] - grid[:, :-1]).reshape(-1), scale * (grid[1:] - grid[:-1]).reshape(-1)]
        offset += p.size
    return jnp.concatenate(parts) if parts else jnp.zeros(0, values.dtype)


def texel_linearisation(x, problem):
    """r, J v, J^T u and the other entries' columns (E, N) of a `Problem`'s residuals at solver
    coordinates x (`matfree.linearisation`'s), in the image's affine form in the texels.

    The texels reach the residuals only through each view's point texture values P (the filter's
    taps, `texels.point_texels`) and the smoothness prior S, so with E the other entries (ks, n, ...)

        J v = dr/dP (taps v_T) + S v_T + J_E v_E.

    dr/dP comes from one linearisation in P (x fixed; the shading's partials stored once per step);
    when every view is `direct` (pixel i is point i) it is diagonal -- a point's channel is affine
    in its own texel value -- and is kept as one gain per residual, dr/dP(1), so a product is the
    texture lookups times a gain (and their transpose, a scatter-add of the taps). J_E's few columns
    are formed once per step. Same J as jax.linearize's, without running the shading per product
    (`affine_residuals` makes it the derivative of `Problem.residuals`)."""
    layout = problem.layout
    texel = np.concatenate([np.full(p.size, p.shape is not None) for p in layout])
    tex, exact = np.flatnonzero(texel), np.flatnonzero(~texel)
    points = problem.point_texels(layout.values(x))

    def texel_terms(xt):
        values = layout.values(x.at[tex].set(xt))
        return problem.point_texels(values), smoothness_residuals(layout, values, problem.smoothness)

    (_, smooth), taps = jax.linearize(texel_terms, x[tex])
    taps_t = jax.linear_transpose(taps, x[tex])
    if all(getattr(getattr(view.model, "formation", None), "direct", False) and view.target.size == t.size
           for view, t in zip(problem.views, points)):  # (a view with no used pixel keeps one dummy point)
        r, gain = jax.jvp(lambda t: problem.residuals(x, t), (points,), (tuple(jnp.ones_like(t) for t in points),))
        gain = gain[:gain.shape[0] - smooth.shape[0]]  # the prior's entries: 0
        ends = np.cumsum([t.size for t in points])[:-1]

        def data_jvp(dp):
            return gain * jnp.concatenate([t.reshape(-1) for t in dp])

        def data_vjp(u):
            return tuple(part.reshape(t.shape) for part, t in zip(jnp.split(gain * u, ends), points))
    else:
        r, through = jax.linearize(lambda t: problem.residuals(x, t), points)
        through_t = jax.linear_transpose(through, points)

        def data_jvp(dp):
            return through(dp)[:n_data]

        def data_vjp(u):
            return through_t(jnp.concatenate([u, jnp.zeros_like(smooth)]))[0]

    n_data = r.shape[0] - smooth.shape[0]
    columns = None
    if exact.size:
        _, direct = jax.linearize(lambda xe: problem.residuals(x.at[exact].set(xe), points), x[exact])
        columns = jax.vmap(direct)(jnp.eye(exact.size, dtype=x.dtype))

    def jvp(v):
        dp, ds = taps(v[tex])
        out = jnp.concatenate([data_jvp(dp), ds])
        return out if columns is None else out + columns.T @ v[exact]

    def vjp(u):
        out = jnp.zeros_like(x).at[tex].set(taps_t((data_vjp(u[:n_data]), u[n_data:]))[0])
        return out if columns is None else out.at[exact].set(columns @ u)

    return r, jvp, vjp, columns


@eqx.filter_custom_jvp
def affine_residuals(x, *, problem):
    """`Problem.residuals` of a texel fit at solver coordinates x, with its derivative in the image's
    affine form (`texel_linearisation`): jax.linearize, jvp, grad and jacfwd of it -- every solver's
    J v and J^T u -- apply the taps times the gains instead of running the shading model."""
    return problem.residuals(x, problem.point_texels(problem.layout.values(x)))


@affine_residuals.def_jvp
def _affine_residuals_jvp(primals, tangents, *, problem):
    r, jvp, _, _ = texel_linearisation(primals[0], problem)
    return r, jvp(tangents[0])


@eqx.filter_jit
def _column_sums(problem, x, used):
    plain = dataclasses.replace(problem, loss="l2", smoothness=0.0)  # its residuals: `Problem.weighted`
    return texel_linearisation(x, plain)[2](used)


def texel_coverage(problem, values, used) -> dict:
    """Texture key -> (H_t, W_t) float64, image orientation: the column sums of the Jacobian of the
    weighted residuals over the residual entries `used` (N,) bool, averaged over the channels -- how
    much the pixels used change per unit texel, summed (0: no pixel sees the texel)."""
    layout = problem.layout
    if not any(p.shape is not None for p in layout):
        return {}
    x = jnp.asarray(layout.x_of(np.asarray(values, np.float64)), values.dtype)  # texels: x = values
    ones = jnp.asarray(np.asarray(used, np.float64), values.dtype)
    sums = np.asarray(_column_sums(problem, x, ones), np.float64)
    out, offset = {}, 0
    for p in layout:
        if p.shape is not None:
            grid = sums[offset:offset + p.size].reshape(p.shape + (3,)).mean(axis=-1)
            out[p.key] = np.flipud(grid)
        offset += p.size
    return out
