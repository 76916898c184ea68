"""Diagnostics at the solution: the noise level, reduced chi-square, the model-mismatch flag,
standard errors, poorly determined parameters and PSNR.

Noise: `sigma` when given, else estimated from the residual images at the solution (`fit.noise`) by Immerkaer's
Laplacian operator (L = R * [1 -2 1; -2 4 -2; 1 -2 1] has variance 36 sigma^2 for white noise) as the
mean noise variance, sigma^2 = sum w L^2 / (36 sum w) with sharp outliers counted at the noise level
of the values of their intensity in the targets (`estimate_sigma`), over the pixels
whose 3 x 3 neighbourhood is all used and uncensored --
per channel where weights of 0 leave some channels of used pixels out. sigma is in the targets'
units whatever the weights. The Laplacian removes what a wrong model leaves smoothly (an offset, a
gradual shading error), so the estimate sees the noise, not the mismatch. With fewer than
MIN_NOISE_PIXELS such pixels (a small, thin or scattered mask) the noise is unknown -- the residuals
alone cannot tell noise from a model's error -- unless given: the fit then reports sigma and chi2 as
nan and `noise_unknown`, and makes no claim about the model. (A refit without clipped pixels takes
the first fit's estimate.) It is floored at the targets' quantisation (`Setup.sigma_floor`): for targets from 8- or 16-bit
files the rms rounding error of the used values, each value's own code step in linear units /
sqrt(12) (`noise.quantisation`: an sRGB file's step is 1 / 12.92 of the sample step in the darks,
2.275 times it at white), FLOAT_SIGMA for float data (float32 rounding of a render is ~1e-7).

    chi2_red = sum_i w_i r_i^2 / (w_mean sigma^2 (N - p))

over the N uncensored residual entries (weights w_i, mean w_mean) and p fitted entries.

Silent pixels: a used pixel whose target and fitted model are both exactly 0 in every channel (the
unlit side of an object without ambient light) carries no noise -- a renderer's noise scales with
its signal, so there is none where there is no light -- and says nothing about sigma: such pixels
are left out of the noise estimate (so are their neighbours, whose Laplacian they would damp), else
a large unlit region pulls sigma down and flags a correct fit as a mismatch.
Their entries add exactly 0 to the sum of squares and are left out of N too: the chi-square counts
only the entries that can carry noise, so a correct fit still has chi2_red ~ 1 (and s^2 below
estimates the lit pixels' noise). A pixel zero in only some channels stays in both. Where the noise
level varies over the lit pixels (noise proportional to the signal) sigma^2 is their mean variance,
what chi2_red's mean compares with.

The verdict (`fit_statistics`): with sigma given, `model_mismatch` when chi2_red is above
1 + 5 sqrt(2 / (N - p)), its statistical spread; with sigma estimated, above its spread with the
estimate's (`chi2_spread`) `mismatch_suspected` (not judged), and above MISMATCH_CHI2 too
`model_mismatch`: the residuals sit far above the noise, so the image model does not explain the
target (wrong image model, wrong specular model, missing light...) and the fitted values answer a
different question. With N <= p the fit is `underdetermined`: nothing is left to judge the model or
the noise by; so is one whose J^T J is singular over the unknowns the data reach, however many
values it has (`degenerate`: the images fix only combinations of those parameters).

Standard errors are those of linearised least squares, in scene units, and assume the model holds:

    cov = s^2 (J^T J)^-1,   s^2 = sum_i r_i^2 / (N - p)

with J the Jacobian of the plain weighted residuals with respect to the values (J^T J from the
solver, or `normal_equations.linearise`) -- for noise of one level. Where the estimate's levels by
channel and intensity differ (gains, noise growing with the signal: the pooled form 2-3x off per
channel), a fit's are the sandwich's, (J^T J)^-1 J^T diag(v) J (J^T J)^-1 with White's
v_i = r_i^2 N / (N - p) (`fit.sandwich`); with sigma given, the noise unknown or texels: pooled.
Directions of J^T J that are numerically singular (after scaling its columns to unit norm: below
1e-12 of the largest eigenvalue formed in float64, 512 float32 eps in float32, `singular_rcond`)
give an infinite standard error to every parameter they involve. A texture's smoothness prior is not in J^T J (its
rows are not residuals of the images), nor in chi2: the standard errors are what the pixels alone
determine, linearised at the regularised solution -- a texel only the prior fills is inf. They are
not the posterior's (J^T J plus the prior's curvature): those are smaller, and the prior's pull is a
bias neither covers. Its size is reported instead: `prior_pull`, the move from the data-only
solution in standard errors; above PRIOR_PULL_MAX the texture is poorly determined and
`FitResult.prior_pull` says by how much (a reviewer's 8x8 POV-Ray texture at noise 0.01, smoothness
1: seen texels up to 31 standard errors off, reported ok).

A matrix-free fit (more than `FitOptions` DENSE_MAX entries: texels) forms J sparse by column
compression (`sparse_jacobian`) and `covariance_diagonal` inverts J^T J per connected block
(`inverse_diagonal`: banded with the scalars by Schur complement, else sparse LU), dense eigh where
a block is singular; the same numbers as the dense path's, to rounding. Nan where too costly: a
block of more than SPARSE_STATS_MAX entries (or more than `inverse_diagonal.LU_MAX` whose band is
too wide), a singular one of more than DENSE_STATS_MAX. Measured (`experiments/bench/fit_stderr.py`,
2 shared cores, load 2-4): a bilinear texture channel's block takes 0.45 s at 4096 entries, 0.84 s
at 8100 (the limit: a 90 x 90 texture's channel), 1.5 s at 16384 (by SuperLU: 0.1 s at 1024, 1.75
s at 4096, 7 s at 8100); eigh 0.07-0.7 s at 768, 0.5-7 s at 1536 (the limit), 1.5-9.6 s at 2048,
14-25 s at 3072. A fit's statistics phase: 0.03-0.16 s for a 16 x 16 texture, 0.12-0.18 s for a
32 x 32 one (texture alone or with ks), against 0.002-0.009 s without standard errors.

A parameter is *poorly determined* when, even at a noise floor of one 8-bit quantisation step, its
standard error exceeds `rel_tol` |value| + `abs_tol` in some channel. A specular exponent (n, or
roughness m) and the ks of the same material are only read from a highlight together, so when one
of them is poorly determined, so is the other.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import ArpackError, eigsh, spsolve

from .inverse_diagonal import inverse_diagonal
from .noise import chi2_spread
from .normal_equations import dense, linearise

QUANTISATION_SIGMA = 1.0 / (255.0 * math.sqrt(12.0))
FLOAT_SIGMA = 1e-5
MISMATCH_CHI2 = 2.0  # an estimated noise off by sqrt(2): beyond any correct model measured (1.30)
SINGULAR_RCOND = 1e-12  # a J^T J formed in float64 (`singular_rcond`)
SINGULAR_RCOND_F32 = 512 * float(np.finfo(np.float32).eps)  # 6.1e-5: one formed in float32 (`singular_rcond`)
PACKED_MAX = 256  # blocks of J^T J inverted dense (eigh) together, up to this many entries
SPARSE_STATS_MAX = 8192  # the most entries of one block of J^T J inverted sparse (measured below)
DENSE_STATS_MAX = 1536  # the most entries of a singular block inverted dense (eigh; measured below)
PRIOR_PULL_MAX = 1.0  # standard errors: a prior that moves a value further biases it beyond what they cover


@eqx.filter_jit
def _normal_matrix(problem, values, fast: bool = False):
    """(J^T J, r) of the plain weighted residuals with respect to the values (`fast`: by parts,
    J^T J from float32 columns, `normal_equations`)."""
    if problem.loss == "l2" and not problem.smoothness:  # residuals(x) = weighted(values(x)): by parts if it applies
        x = jnp.where(problem.layout.entries("log") > 0, jnp.log(values), values)
        r, gram, _ = linearise(x, problem, fast)
        scale = jnp.where(problem.layout.entries("log") > 0, values, 1.0)
        return gram / (scale[:, None] * scale[None, :]), r
    r, gram, _ = dense(lambda v, p: p.weighted(v), values, problem)
    return gram, r


def normal_matrix(problem, values, solved=None) -> tuple[np.ndarray, tuple]:
    """(J^T J (p, p) float64, r) of the plain weighted residuals r -- float64, per view (3, U)
    (`Problem.view_residuals`) --, J their Jacobian with respect to the flat values, over all
    residual entries: from `solved` = (r, J^T J with respect to the solver coordinates x) when the
    solver returned them for the l2 loss without a texture prior (d value / d x = value for log
    coordinates), else computed (one compiled call)."""
    if solved is not None and problem.loss == "l2" and not problem.smoothness:  # no prior rows in the solver's
        r, gram_x = solved
        log = problem.layout.entries("log") > 0
        scale = np.where(log, np.asarray(values, np.float64), 1.0)
        return np.asarray(gram_x, np.float64) / (scale[:, None] * scale), tuple(  # (np.outer: the same, slower)
            np.asarray(part, np.float64) for part in r)
    gram, r = _normal_matrix(problem, values)
    return np.asarray(gram, np.float64), problem.view_residuals(np.asarray(r, np.float64))


def singular_rcond(x64: bool) -> float:
    """How small an eigenvalue of the unit-diagonal J^T J, relative to the largest, is numerically 0
    when J^T J was formed in float64 (`x64`) or float32. Each entry of a J^T J formed in precision
    eps is a dot product over the N residual entries, off by up to c eps in the unit scale (c from
    eps for pairwise sums to N eps for sequential ones), so an exactly null direction comes out at
    +- p c eps, and J's own roundings move it only at second order (J v = 0 for a null v). Measured
    in float32 (ka and kd of a plane under a directional light, n.l constant: exactly collinear):
    -2.9, -26, -68, -68 eps at 32, 64, 128, 256 pixels square; the kd, ks, intensity trade-off
    (kd c, ks c, I / c) +-1e-7 -- far above float64's 1e-12. So float32: SINGULAR_RCOND_F32 = 512
    eps (6.1e-5), 7.5x the largest measured; a direction just above it has its eigenvalue at most
    ~13 % off (its standard error ~7 %), and one below it the float32 J^T J cannot resolve (a plane
    under a point light 100 units away: x64 3.2e-6, float32 2.9e-7). float64: SINGULAR_RCOND = 1e-12
    (its exact degeneracies at 1e-16 to 1e-14; the G-buffer's float32 inputs make a degeneracy of
    the true scene, such as n.l constant, one of ~(1e-7)^2)."""
    return SINGULAR_RCOND if x64 else SINGULAR_RCOND_F32


def unit_spectrum(gram: np.ndarray, top: float | None = None, rcond: float = SINGULAR_RCOND):
    """The spectrum of J^T J (p, p) with its columns scaled to unit norm (so units do not count):
    (eigval ascending, eigvec, scale (p,) 1 / column norm (1 for a zero column), zero (p,) the zero
    columns, singular (p,) the eigenvalues at most `rcond` (`singular_rcond`) times the largest -- or
    `top` when `gram` is a diagonal block of a larger J^T J whose largest that is). The rank of the data
    is the count of the others; a singular direction's eigenvector names the parameters that trade
    off exactly (`covariance_unscaled`, `identifiability`)."""
    norms = np.sqrt(np.maximum(np.diagonal(gram), 0.0))
    zero = norms == 0
    scale = 1.0 / np.where(zero, 1.0, norms)  # (1 for a zero column)
    eigval, eigvec = np.linalg.eigh(gram * (scale[:, None] * scale))
    top = max(float(eigval.max(initial=0.0)) if top is None else top, 1e-300)
    return eigval, eigvec, scale, zero, eigval <= rcond * top


def covariance_unscaled(gram: np.ndarray, top: float | None = None, rcond: float = SINGULAR_RCOND) -> np.ndarray:
    """(J^T J)^-1 from J^T J (p, p), with singular directions (`unit_spectrum`) given infinite
    variance. Returns (p, p); the diagonal is inf for parameters that a singular direction involves
    and for zero columns."""
    eigval, eigvec, scale, zero, singular = unit_spectrum(gram, top, rcond)
    outer = scale[:, None] * scale
    inv = np.where(singular, 0.0, 1.0 / np.where(singular, 1.0, eigval))
    cov = (eigvec * inv) @ eigvec.T * outer
    infinite = zero | (np.abs(eigvec[:, singular]) > 1e-6).any(axis=1) if singular.any() else zero
    if infinite.any():
        cov[infinite, :] = np.inf
        cov[:, infinite] = np.inf
    return cov


def degenerate(layout, diag: np.ndarray, gram, prior: bool) -> list[str]:
    """Keys of the parameters the data reach (a non-zero column of J^T J, dense or sparse) that a
    singular direction involves (inf in `diag`, diag (J^T J)^-1 from `covariance_diagonal`): the
    data fix only combinations of them (kd and a light's intensity: kd c and I / c give the same
    image), whatever their count. With a texture `prior` (smoothness > 0) directions within the
    texels alone are the prior's to fill and do not count; one that involves another parameter
    does (a texture's scale against a light's intensity)."""
    bad = np.isinf(diag) & (gram.diagonal() > 0)
    if not bad.any():  # (as a rule)
        return []
    if prior:  # (the texel mask only then)
        texel = np.concatenate([np.full(p.size, p.shape is not None) for p in layout]) if len(layout) else bad
        if not (bad & ~texel).any():
            return []
    flat, offset = [], 0
    for p in layout:
        if bad[offset:offset + p.size].any():
            flat.append(p.key)
        offset += p.size
    return flat


#: The coefficient whose value 0 switches a kind off: the lobe's shape does nothing without ks,
#: the absorption nothing without kt (a matte fit's n at ks = 0 is no lack of data).
SWITCHED_BY = {"n": "ks", "m": "ks", "f0": "ks", "absorption": "kt"}


def unreached(layout, gram, coefficient) -> list[str]:
    """Keys of the parameters other than texels with an entry (a channel) that no residual the fit
    counts depends on: a zero column of J^T J (dense or sparse) -- a kd on a material no used pixel
    shows lit, a light that reaches no used pixel. Their values are the start's, undetermined
    (a texel no pixel reads is the smoothness prior's to fill, or unseen: `seen`). Not those that
    their material's SWITCHED_BY coefficient, 0 in every channel at the solution, switches off:
    `coefficient(material index, kind)` gives its value (ks = 0 at its bound: n's column is 0)."""
    zero = np.asarray(gram.diagonal()) <= 0
    if not zero.any():  # (as a rule)
        return []
    flat, offset = [], 0
    for p in layout:
        switch = SWITCHED_BY.get(p.kind)
        off = switch is not None and not np.any(np.asarray(coefficient(p.index, switch)) != 0)
        if p.shape is None and not off and zero[offset:offset + p.size].any():
            flat.append(p.key)
        offset += p.size
    return flat


def covariance_diagonal(gram, skip=None, rcond: float = SINGULAR_RCOND) -> np.ndarray:
    """diag (J^T J)^-1 (p,) as `covariance_unscaled` gives it (singular below `rcond` times the
    largest eigenvalue), from J^T J (p, p): a numpy array, or a scipy.sparse matrix (a matrix-free
    fit's, `sparse_jacobian`); nan at the entries `skip` (p,) bool -- whole blocks left out
    (`sparse_jacobian.stats_blocks`) -- the rest from the others alone.

    A sparse one of up to PACKED_MAX entries is made dense. A larger one is split into its connected
    blocks (entries no residual couples: a texture's channels, texels far apart without a scalar
    beside them, a texel no pixel sees), each judged singular against the largest eigenvalue of the
    whole unit-diagonal J^T J: blocks of up to PACKED_MAX entries by `covariance_unscaled`, packed
    together; larger ones, up to SPARSE_STATS_MAX entries, by `inverse_diagonal` (banded or sparse
    LU) -- or, where that finds a singular direction, by `covariance_unscaled`
    when the block has at most DENSE_STATS_MAX entries. Nan (no standard errors: too costly) on a
    block above SPARSE_STATS_MAX entries, and on a singular one above DENSE_STATS_MAX (which entries
    its singular directions involve takes the block's eigenvectors).

    The largest eigenvalue comes from ARPACK; where that fails (no convergence), from Gershgorin's
    bound (the largest absolute row sum), which is at least the eigenvalue: a block judged regular
    against it is regular against the eigenvalue too."""
    if skip is not None and skip.any():  # (an empty column: inf, as `covariance_unscaled` has it)
        diag = np.where(skip, np.nan, np.inf)
        kept = np.flatnonzero(~skip & (gram.diagonal() > 0))
        if kept.size:
            diag[kept] = covariance_diagonal(gram[kept][:, kept], rcond=rcond)
        return diag
    if not sp.issparse(gram):
        return np.diag(covariance_unscaled(gram, rcond=rcond))
    if gram.shape[0] <= PACKED_MAX:
        return np.diag(covariance_unscaled(gram.toarray(), rcond=rcond))
    gram = gram.tocsr()
    norms = np.sqrt(np.maximum(gram.diagonal(), 0.0))
    scale = 1.0 / np.where(norms == 0, 1.0, norms)
    unit = sp.diags(scale) @ gram @ sp.diags(scale)
    try:
        top = float(eigsh(unit, k=1, which="LA", return_eigenvectors=False)[0])
    except ArpackError:  # no convergence; a J^T J of empty columns (every texel unseen)
        top = float(abs(unit).sum(axis=1).max())
    _, label = connected_components(unit, directed=False)
    blocks = np.split(np.argsort(label, kind="stable"), np.cumsum(np.bincount(label))[:-1])
    diag, packed, packed_size = np.full(gram.shape[0], np.nan), [], 0
    for block in blocks + [np.zeros(0, np.int64)]:  # (an empty block ends the last pack)
        if packed and (not block.size or packed_size + block.size > PACKED_MAX):
            index = np.concatenate(packed)
            diag[index] = np.diag(covariance_unscaled(gram[index][:, index].toarray(), top, rcond))
            packed, packed_size = [], 0
        if 0 < block.size <= PACKED_MAX:
            packed.append(block)
            packed_size += block.size
        elif PACKED_MAX < block.size <= SPARSE_STATS_MAX:
            diag[block] = inverse_diagonal(unit[block][:, block], top, rcond) * scale[block] ** 2
            if np.isnan(diag[block[0]]) and block.size <= DENSE_STATS_MAX:  # singular
                diag[block] = np.diag(covariance_unscaled(gram[block][:, block].toarray(), top, rcond))
    return diag


def sandwich_diagonal(gram: np.ndarray, middle: np.ndarray, rcond: float = SINGULAR_RCOND) -> np.ndarray:
    """diag (J^T J)^-1 M (J^T J)^-1 (p,) for dense J^T J and M = `middle` (p, p) (`fit.sandwich`):
    inf where `covariance_unscaled` has inf (a singular direction, an empty column)."""
    inverse = covariance_unscaled(gram, rcond=rcond)
    finite = np.isfinite(np.diagonal(inverse))
    if finite.all():  # (as a rule: no np.ix_ copies)
        return np.einsum("ij,jk,ki->i", inverse, middle, inverse)
    part = inverse[np.ix_(finite, finite)]
    out = np.full(gram.shape[0], np.inf)
    out[finite] = np.einsum("ij,jk,ki->i", part, middle[np.ix_(finite, finite)], part)
    return out


def finite_gram(gram) -> bool:
    """Whether every entry of J^T J (dense or sparse) is finite."""
    return bool(np.all(np.isfinite(gram.data if sp.issparse(gram) else gram)))


def standard_errors(diag: np.ndarray, sigma2: float) -> np.ndarray:
    """sqrt(diag (J^T J)^-1 * sigma2), inf where the diagonal is (and everywhere for sigma2 inf: an
    underdetermined fit's unknown noise); nan where the diagonal is nan (not formed)."""
    if math.isinf(sigma2):
        return np.where(np.isnan(diag), np.nan, np.inf)
    finite = np.isfinite(diag)
    return np.where(finite, np.sqrt(np.where(finite, np.maximum(diag, 0.0), 0.0) * sigma2), diag)


def fit_statistics(gram, sse: float, entries: int, censored: int, sigma: float, size: int, silent: int = 0,
                   sigma_given: bool = False, skip=None, noise_values: int = 0, noise_share: float = 1.0,
                   mean_weight: float = 1.0, rcond: float = SINGULAR_RCOND, sigma_range: tuple | None = None,
                   middle=None) -> dict:
    """s2 = sse / dof (sse: the sum of squares of the `entries` weighted residuals sqrt(w) r; dof =
    N - p, N entries neither censored nor `silent` (noise-free zeros), p = `size` fitted entries the
    data reach -- a texel no pixel reads is not one), chi2 = s2 / (w sigma^2) (reduced, w the
    `mean_weight` of the counted entries: sigma is the targets' noise in their own units, and a
    weighted residual's variance is w sigma^2; nan when sigma is: the noise unknown, the model is
    not judged), the verdict on the model, and diag (J^T J)^-1 (p,) from gram = J^T J (p, p), dense
    or sparse (`covariance_diagonal`; nan at `skip`; singular below `rcond`: `singular_rcond`).

    With t = 1 + 5 `chi2_spread(dof, noise_values, noise_share)` (five standard deviations of chi2
    for a correct model; `noise_values` Laplacians gave an estimated sigma, 0: given; `noise_share`:
    the share of them that unequal weights and noise levels leave, `estimate_sigma`):
    - a given sigma is the truth: `mismatch` when chi2 > t (POV-Ray's brilliance 1.2, outside the
      model, fitted with its true sigma 0.01: chi2 1.83 over ~3600 entries, flagged);
    - an estimated one: `mismatch` when chi2 > max(t, MISMATCH_CHI2); `suspected` when t < chi2 <=
      MISMATCH_CHI2: the residuals exceed the estimated noise by more than the estimate's spread,
      but an estimate can be off for a correct model where the noise is not white -- correlated
      (a pixel filter), a renderer's pixel integration against difflab's centre
      sample (Mitsuba's diffuse sphere at 64 spp: chi2 1.12-1.25, kd 3e-5 off, z up to 8) -- so
      the model is not judged: give sigma to judge it. Measured wrong models in that band: POV-Ray
      glass without its shadow absorption and TIR rim (chi2 1.13-1.55, kt 43-73 stderr off),
      Mitsuba's indirect light (1.18, floor kd 21-46 stderr off), an area light's soft shadows at
      2 % noise (1.68).
    - an estimated one whose noise is not white (`sigma_range` = (low, high), the levels its two
      scales allow: `fit.whiteness`): `mismatch` only when chi2 at `high` is above max(t,
      MISMATCH_CHI2), and ok only when chi2 at `low` is within t; else `suspected`. (Mitsuba's
      gaussian pixel filter, a correct model: chi2 5.2 at the 1-apart level, 1.4 at the 2-apart one,
      suspected, not a mismatch; an ordered-dithered 8-bit file of a wrong model: chi2 1.1 at the
      1-apart level, 6.8 at the quantisation floor, suspected, not ok.) chi2 is reported at sigma.
    With dof <= 0 (no more counted entries than unknowns: `underdetermined`) the residuals say
    nothing about the noise or the model: chi2 nan, no flag, s2 = w sigma^2 where sigma is known,
    else inf."""
    p = size
    dof = entries - censored - silent - p
    if dof <= 0:
        known = math.isfinite(sigma) and sigma > 0
        return {"s2": mean_weight * sigma * sigma if known else math.inf, "chi2": math.nan, "mismatch": False,
                "suspected": False, "diag": covariance_diagonal(gram, skip, rcond), "underdetermined": True}
    s2 = sse / dof
    chi2 = math.nan if math.isnan(sigma) else s2 / (mean_weight * sigma * sigma) if sigma > 0 else math.inf
    threshold = 1.0 + 5.0 * chi2_spread(dof, 0 if sigma_given else noise_values, noise_share)
    most, least = (chi2, chi2) if sigma_range is None else (s2 / (mean_weight * level * level) for level in sigma_range)
    mismatch = bool(least > (threshold if sigma_given else max(MISMATCH_CHI2, threshold)))  # (chi2 at the highest level)
    suspected = bool(not sigma_given and not mismatch and most > threshold)
    diag = covariance_diagonal(gram, skip, rcond) if middle is None else sandwich_diagonal(gram, middle, rcond)
    return {"s2": s2, "chi2": chi2, "mismatch": mismatch, "suspected": suspected, "diag": diag,
            "underdetermined": False}


def prior_pull(gram, diag: np.ndarray, s2: float, gradient: np.ndarray) -> np.ndarray:
    """(p,) how far a prior moves each value from where the data alone put it, in the data's
    standard errors: delta / sqrt(diag s2), delta = (J^T J)^-1 g over the entries of finite, positive
    diag (J^T J)^-1 (0 elsewhere; J^T J (p, p) dense or sparse), g (p,) the prior's gradient at the
    solution: there the data's gradient J^T r is -g, so delta is the Gauss-Newton step from the
    regularised solution to the data-only one (exactly it where the image is linear in the values,
    as in the texels)."""
    out = np.zeros(diag.shape)
    index = np.flatnonzero(np.isfinite(diag) & (diag > 0))
    if not index.size or not math.isfinite(s2) or s2 <= 0:
        return out
    if sp.issparse(gram):
        delta = spsolve(gram.tocsr()[index][:, index].tocsc(), gradient[index])
    else:
        delta = np.linalg.lstsq(gram[np.ix_(index, index)], gradient[index], rcond=None)[0]
    out[index] = delta / np.sqrt(diag[index] * s2)
    return out


def poorly_determined(layout, value: np.ndarray, err: np.ndarray, rel_tol=0.1, abs_tol=1e-3, also=()) -> list[str]:
    """Keys of parameters whose noise-floor standard error (`err`, flat in layout order as the values
    `value`) exceeds rel_tol |value| + abs_tol (inf: undetermined; nan, not formed, flags nothing),
    with ks and n (or m) of one material flagged together, and the keys `also` (the textures with
    texels no pixel sees)."""
    over = np.isinf(err) | (err > rel_tol * np.abs(value) + abs_tol)
    flagged, offset = set(also), 0
    for p in layout:
        if over[offset:offset + p.size].any():
            flagged.add(p.key)
        offset += p.size
    for p in layout:  # the specular pair of a material
        if p.kind in ("ks", "n", "m") and p.key in flagged:
            for q in layout:
                if q.index == p.index and q.kind in ("ks", "n", "m"):
                    flagged.add(q.key)
    return [p.key for p in layout if p.key in flagged]


def psnr(sse: float, weight_total: float) -> float:
    """10 log10(1 / MSE), MSE = sse / weight_total, sse the sum of squares of the weighted residuals
    (peak 1): inf for a perfect fit, -inf when the error overflows, nan without weight."""
    if weight_total <= 0:
        return float("nan")
    mse = sse / weight_total
    if not math.isfinite(mse):
        return float("-inf")
    return float("inf") if mse == 0 else 10.0 * math.log10(1.0 / mse)
