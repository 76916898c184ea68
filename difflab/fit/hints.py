"""The lines `FitResult.table()` prints after its numbers: the flags of the verdict (`flag_lines`),
with what the numbers suggest beyond it -- a likely local minimum beside a mismatch --, and notes on
the inputs (a scale that suggests code values, non-finite target values left out). The hints and
notes are not verdicts: none of them changes `FitResult.ok` or the exit code."""

from __future__ import annotations

import math

import numpy as np

from .whiteness import not_white_line

SCALE_HINT = 10.0
"""A fitted reflectance coefficient (ka, kd, ks, kr, kt, texels) above this is far above 1, a
reflectance's physical limit. Light intensities scale the image (kd I), so a scene whose light is a
few times too dim -- a pi or 4 pi between renderers' units -- legitimately gives kd up to a few; it
rarely reaches 10. A target in code values instead of linear floats multiplies every coefficient by
255 or 65535 (and the sRGB curve): even a dark 0.04 reflectance read as 8-bit codes is 10.2. So 10
separates the two; it is a hint, not an error."""

COEFFICIENTS = ("ka", "kd", "ks", "kr", "kt", "texture")
LOBES = ("n", "m")  # the specular lobe's width: Phong / Blinn exponent, Torrance roughness


def scale_note(params: dict, layout) -> str | None:
    """"kd = 45874: coefficients far above 1 -- ..." when a fitted coefficient exceeds SCALE_HINT
    (its largest entry named per parameter), else None."""
    high = [(p.key, float(np.max(params[p.key]))) for p in layout if p.kind in COEFFICIENTS]
    high = [f"{key} = {value:.5g}" for key, value in high if value > SCALE_HINT]
    if not high:
        return None
    return (f"{', '.join(high)}: coefficients far above 1 -- is the target in code values (0-255 / 0-65535) rather "
            "than linear floats in [0, 1]?")


def local_minimum(result) -> list[str]:
    """Names of parameters pushed to a degenerate value: a lobe width (n, m) that the images do not
    determine (degenerate, unreached, or an infinite stderr) or that sits on its bound, with its
    material's ks when fitted -- the highlight gone from the model (ks -> 0, n -> 1e5 +- inf from a
    start far off). Beside a mismatch, the fit may sit in a local minimum rather than the image
    model be wrong; or the target is matte (ks truly 0), and the mismatch has another cause."""
    names = []
    for p in result.layout:
        if p.kind not in LOBES:
            continue
        undetermined = p.key in result.degenerate or p.key in result.unreached or \
            math.isinf(float(np.max(result.stderr.get(p.key, np.nan))))  # (nan: no stderr formed)
        if undetermined or p.key in result.at_bound:
            names += [q.key for q in result.layout if q.kind == "ks" and q.index == p.index] + [p.key]
    return names


def minimum_hint(result) -> str:
    """The clause a mismatch line gains when `local_minimum` names parameters, else ""."""
    names = local_minimum(result)
    if not names:
        return ""
    return (f" -- or the fit may sit in a local minimum ({', '.join(names)} at a degenerate value: the highlight "
            "gone, its width undetermined or at its bound): retry from another start (init= / --init)")


def notes(result) -> list[str]:
    """Notes on a fit's inputs: `scale_note`, and how many non-finite target values were left out."""
    out = []
    if result.nonfinite_left_out:
        out.append(f"non-finite target values left out: {result.nonfinite_left_out} (none at a pixel the fit uses)")
    scale = scale_note(result.params, result.layout)
    if scale:
        out.append(scale)
    return out


def flag_lines(result) -> list[str]:
    """One line per flag the result carries (MODEL MISMATCH, MISMATCH SUSPECTED -- with `minimum_hint` --,
    NOISE NOT WHITE, NOISE UNKNOWN, UNDERDETERMINED, PRIOR PULL, at bound, censored), in that order."""
    from .stats import PRIOR_PULL_MAX  # (JAX: imported with the fit that made this result)

    hint = minimum_hint(result) if result.model_mismatch or result.mismatch_suspected else ""
    flags = [name for name, on in (("MODEL MISMATCH: the image model does not explain the targets; the standard "
                                     "errors assume it does" + hint, result.model_mismatch),
                                    ("MISMATCH SUSPECTED: the residuals exceed the estimated noise beyond its "
                                     "spread; the image model is not judged (give sigma to judge it)" + hint,
                                     result.mismatch_suspected),
                                    (not_white_line(result.sigma, result.chi2, result.sigma_range)
                                     if result.noise_not_white else "", result.noise_not_white),
                                    ("NOISE UNKNOWN: too few used pixels with used neighbours to estimate it; "
                                     "the image model is not judged (give sigma)", result.noise_unknown),
                                    ("UNDERDETERMINED: no more counted target values than unknowns the data "
                                     "reach; the model is not judged", result.too_few_values),
                                    ("UNDERDETERMINED: the images fix only combinations of "
                                     f"{', '.join(result.degenerate)} (J^T J singular; `difflab.identify` names "
                                     "them); their values are undetermined"
                                     + ("" if math.isnan(result.chi2) else " (the model is still judged)"),
                                     bool(result.degenerate)),
                                    (f"UNDERDETERMINED: {', '.join(result.unreached)} "
                                     f"reach{'es' if len(result.unreached) == 1 else ''} no value the fit counts "
                                     "(left at their start)", bool(result.unreached)),
                                    (f"PRIOR PULL: the smoothness prior moves values the pixels determine by up "
                                     f"to {result.prior_pull:.3g} standard errors; their stderr (the pixels' "
                                     "alone) do not cover that bias", result.prior_pull > PRIOR_PULL_MAX),
                                    (f"at bound: {', '.join(result.at_bound)}", bool(result.at_bound)),
                                    (f"censored (clipped) target values: {result.censored}",
                                     result.censored > 0)) if on]
    return flags
