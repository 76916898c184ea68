"""Standard errors under unequal noise: the sandwich (heteroscedasticity-consistent) covariance

    cov = (J^T J)^-1 (J^T diag(v) J) (J^T J)^-1

of linearised least squares whose residual entries have variances v_i (J: the Jacobian of the
weighted residuals, `stats.normal_matrix`). With one noise level, v_i = s^2, it is the pooled
s^2 (J^T J)^-1; where the noise differs by channel (a camera's gains) or grows with the signal
(shot noise, a Monte Carlo render's), the pooled form misstates each parameter's error by the ratio
of the noise its pixels carry to the mean: 2-3x on a POV-Ray target with blue noise 4x red's.

v_i = r_i^2 N / (N - p), White's estimator with its small-sample factor (HC1): r the weighted
residuals at the solution, N the counted entries (neither censored nor silent), p the unknowns --
the pooled s^2 = sum r^2 / (N - p) redistributed over the entries as their squares are. Measured
against the alternative, v from the noise estimate's own levels by channel and intensity
(`noise._levels`) read at each entry's target value: as good under per-channel noise, but under
noise of 5 % of each value (its variance rising 2000-fold over a 48 x 48 sphere) the rms z-score
over 80 seeds was 1.14-1.24 per channel (a binned mean of r^2 by intensity: 1.11-1.18), HC1's
0.99-1.12. Its price is spread: a parameter resting on K entries has its variance from K squared
residuals, relative spread ~ sqrt(2 / K) (the highlight's ks, a few dozen pixels: +-25 %, where the
levels' binned means kept +-10-18 %), and leverage makes it ~1 / K low (HC3's correction, not applied:
negligible from ~20 entries up).

It is formed only where the noise levels that the estimate of sigma read (per view, channel and
half of the intensity range: the targets' noise, so `weights=` are taken to be inverse variances --
other weights leave the weighted residuals' noise unequal under the pooled form) differ beyond their
spread (`unequal`): one more linearisation at the solution (`_scaled_gram`: the problem's
sqrt(weights) times r; ~0.25 ms of XLA's after its dispatch on the 74k entries of a 256 x 256
sphere, dispatched before the rest of the noise estimate to run beside it, `noise_middle`). What it
adds to a first fit's report (the bench's Mitsuba sphere, fits with and without it alternating in
one process, medians of 60): 0.30 ms at load 0.4-0.9 -- `unequal` 0.05, the cold dispatch 0.15-0.17
(0.04 hot), the sums beside XLA's run 0.035 slower, the middle done when asked -- and 0.70 ms at
load 1.8 (the dispatch 0.43: XLA's threads take the caller's core); waited for at once, 0.25 ms
more at load 0.5. Elsewhere s^2 (J^T J)^-1 is within ~15 % of it (`unequal`). Not with sigma given
(one number: the noise is declared equal), nor where it is unknown, nor for a texture fit, dense or
matrix-free (the sparse path of `stats.covariance_diagonal` keeps the pooled form, and so does a
dense one to stay its equal; a texel resting on a few pixels would have a sandwich variance of
spread sqrt(2 / K) from them).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import numpy as np

from .stats import _normal_matrix

LEVEL_SPREAD = 3.2  # a level's relative standard error times sqrt(n) (white noise, 64 x 64, 20 seeds: 3.15)
UNEQUAL_SPREADS = 3.0  # levels further apart than this many standard errors (plus the share) differ
UNEQUAL_SHARE = 0.1  # and than this share of the mean: noise within it is one level


def unequal(levels) -> bool:
    """Whether the noise levels (`noise.views_noise`'s: per view, channel and intensity bin the
    level l and the count n of values it is the median of) differ beyond their spread: the levels
    of each channel's lower and upper halves of intensity, each group's mean against their mean
    over every group (weighted by count), differ by more than UNEQUAL_SPREADS of the group's
    relative standard error LEVEL_SPREAD / sqrt(n group) plus UNEQUAL_SHARE (views and channels
    without levels aside). Otherwise one level serves: groups within ~30 % of their mean (at the
    noise sample's cap, 4096 values a channel; more on small images) leave s^2 (J^T J)^-1 within
    ~15 % of the sandwich's value."""
    groups = [(float(half.sum()) / half.size, n * half.size)  # (np.mean: the same, slower)
              for per_channel in filter(None, levels)
              for _, level, n in filter(None, per_channel)
              for half in (level[:(level.size + 1) // 2], level[(level.size + 1) // 2:]) if half.size]
    if not groups:
        return False
    level, count = np.array(groups).T
    mean = float(np.dot(level, count)) / sum(n for _, n in groups)  # (a few groups: Python's floats, the same
    # IEEE operations as numpy's on arrays of them: 15 -> 10 us)
    return mean > 0 and any(abs(v / mean - 1.0) > UNEQUAL_SPREADS * LEVEL_SPREAD / math.sqrt(n) + UNEQUAL_SHARE
                            for v, n in groups)


@jax.jit
def _scaled_gram(problem, values, scales):
    """J^T diag(s^2) J for the views' scales s (3, U), channel-major as the residuals: the normal
    matrix of the residuals with each view's sqrt(weight) times s (`stats._normal_matrix`, fast).
    (A plain jit, as `lm.solve_box`'s: its dispatch costs less than eqx.filter_jit's.)"""
    views = tuple(eqx.tree_at(lambda v: v.sqrt_weight, view, view.sqrt_weight * s.T)
                  for view, s in zip(problem.views, scales))
    return _normal_matrix(eqx.tree_at(lambda p: p.views, problem, views), values, True)[0]


def noise_middle(setup, at, r: tuple, levels, counted: int, total: float | None = None):
    """M = J^T diag(r^2) J N / sum r^2 (p, p) float64 (module docstring) for a fit's `Setup` at the
    flat values `at` with weighted residuals r there (per view (3, U): `Problem.view_residuals`),
    from the noise `levels` of `noise.views_noise` (None: given or unknown) and N = `counted`
    entries (neither censored nor silent); `total`: sum r^2 when the caller has it (`engine.report`'s
    sum of squares: with unit weights and C-order parts the same bits, a pass over r less). None where
    one level serves (`unequal`) -- s^2 (J^T J)^-1 holds -- and for a texture fit (`texels`: the
    pooled form, dense or matrix-free alike). Else returns a function that gives it: JAX computes
    J^T diag(r^2) J from the call on, beside what the caller does until it asks (`engine.report`:
    the rest of the noise estimate)."""
    if levels is None or any(p.shape is not None for p in setup.layout) or not unequal(levels):
        return None
    scales = [part.astype(view.target.dtype, copy=False)  # (r itself: its rows enter J^T diag(r^2) J squared)
              for view, part in zip(setup.problem.views, r)]
    if total is None:
        total = sum(float(np.einsum("ij,ij->", part, part)) for part in r)
    if not total > 0:
        return None
    with jax.enable_x64(setup.x64):
        middle = _scaled_gram(setup.problem, at, scales)  # (dispatched: it runs while the caller goes on)
    return lambda: np.asarray(middle, np.float64) * (counted / total)
