"""`FitResult`: what a fit returns -- values in scene units, their uncertainty, and how it went."""

from __future__ import annotations

import dataclasses
import glob
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import FitError
from ..io import save_image
from .hints import flag_lines, notes


def _json_number(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _json(value):
    """A number or an array (any shape: nested lists) with non-finite entries as None."""
    if isinstance(value, (list, tuple, np.ndarray)):
        value = np.asarray(value, np.float64)
        return [_json(v) for v in value] if value.ndim > 1 else [_json_number(v) for v in value]
    return _json_number(value)


def texel_summary(values) -> dict:
    """A texture's values (H_t, W_t, 3) -- texels, or their standard errors -- as a report gives them,
    not texel by texel: {"size": [W_t, H_t], "min", "max", "mean": per channel, over its finite
    entries (null where there are none), "nonfinite": how many entries are not (a stderr's inf: the
    texels the data do not determine)}."""
    values = np.asarray(values, np.float64)
    out = {"size": [values.shape[1], values.shape[0]], "min": [], "max": [], "mean": []}
    for channel in values.reshape(-1, values.shape[-1]).T:
        kept = channel[np.isfinite(channel)]
        for name, reduce in (("min", np.min), ("max", np.max), ("mean", np.mean)):
            out[name].append(_json_number(reduce(kept)) if kept.size else None)
    out["nonfinite"] = int(np.count_nonzero(~np.isfinite(values)))
    return out


def _reported(value):
    """A parameter's value in a report: `_json`, a texture (a 3-D array) by its `texel_summary`."""
    return texel_summary(value) if np.ndim(value) == 3 else _json(value)


WORD = re.compile(r"[A-Za-z0-9_-]{1,64}")  # a material name used as is in a texture file's name
TEXTURE_FILE = r"\.(?:[A-Za-z0-9_-]{1,64}\.texture|texture[0-9]+)\.npy"  # what follows the stem


def texture_file_name(stem: str, material: str, index: int) -> str:
    """The file a command writes a fitted texture to, beside its scene file `stem`.json:
    <stem>.<material>.texture.npy, or <stem>.texture<index>.npy where the material's name is not a
    plain word (letters, digits, _ and -; at most 64): never a path, and no two (stem, material)
    pairs share a name (`TEXTURE_FILE` matches what follows the stem)."""
    return f"{stem}.{material}.texture.npy" if WORD.fullmatch(material) else f"{stem}.texture{index}.npy"


def texture_files_beside(folder, stem: str) -> list[Path]:
    """The fitted-texture files of the scene file `stem`.json in `folder` that exist now (the names
    `texture_file_name` gives: `TEXTURE_FILE` after the stem), sorted; none where `folder` is not one."""
    pattern = re.compile(re.escape(stem) + TEXTURE_FILE)
    folder = Path(folder)
    found = folder.glob(f"{glob.escape(stem)}.*.npy") if folder.is_dir() else ()
    return sorted(path for path in found if pattern.fullmatch(path.name))


def drop_texture_files(folder, stem: str, keep=()) -> None:
    """Remove `texture_files_beside(folder, stem)` but the file names in `keep`: what an earlier fit of
    the scene `stem` wrote that the new one does not (another material's texture, or any texture
    where none is fitted now). `difflab fit --force` and a batch job both end with this."""
    for path in texture_files_beside(folder, stem):
        if path.name not in keep:
            path.unlink(missing_ok=True)


NO_FIT = ("empty_mask", "nonfinite_target")  # difflab's result codes of a fit that was not made
NOT_JUDGED = ("noise_unknown", "underdetermined", "mismatch_suspected")  # the flags of `FitResult.not_judged`


class ResultCode(str):
    """A result code (compared, printed and written to JSON as the plain string) with `detail`: why,
    in words (for difflab's "empty_mask" / "nonfinite_target": which targets, masks and counts)."""

    def __new__(cls, code: str, detail: str = ""):
        out = super().__new__(cls, code)
        out.detail = detail
        return out


@dataclass(frozen=True)
class FitResult:
    """The outcome of a fit (`fit_material`, `fit_scene`, `fit_batch`). Failure is a value: read
    `converged`, `result` and `model_mismatch`; `ok` is True only for a converged fit whose image
    model explains the targets.

    params: name -> fitted value in scene units (RGB lists for ka / kd / ks / light intensities,
        floats for n, m, f0, an (H_t, W_t, 3) float32 image for a texture, row 0 at the top); names
        are "kd", ..., or "<material>.kd" when several materials were fitted, and
        "lights[i].intensity".
    stderr: name -> standard error (same shapes; inf where the data do not determine it -- a texel
        no pixel sees, or seen only in a fixed combination with others; nan when no fit was made,
        and, in a matrix-free fit, for the entries of a block of J^T J too large to invert:
        `fit.stats.covariance_diagonal`). A matrix-free (texel) fit's are the dense fit's, its
        Jacobian formed sparse (`fit.sparse_jacobian`). With a texture `smoothness` prior they are
        the pixels' alone (the prior's rows left out of J^T J): they do not cover the prior's pull
        (`prior_pull`).
        They assume the image model holds (see `fit.stats`): with `model_mismatch` set they
        understate the real error.
    loss: the solvers' objective 0.5 sum r^2 at the solution, summed over the channels of the pixels
        used (for the l2 loss: half the weighted sum of squared errors; a texture prior excluded).
    psnr: 10 log10(1 / MSE) of the fit over the pixels used (dB, peak 1): those in the masks that
        show a fitted material.
    steps: solver steps. seconds: wall time of the solve (compilation included on a first call).
    converged: the solver reported success and every value is finite.
    result: the result code as a string: optimistix's ("successful", "nonlinear_max_steps_reached",
        "nonlinear_divergence", "nonfinite", ...) or difflab's ("empty_mask": no pixel of the fitted
        material lies in the masks; "nonfinite_target": NaN / inf target pixels inside the masks --
        a `ResultCode`, its `.detail` naming the targets, masks and counts: `no_fit()`).
    history: the loss at the point each solver step evaluated (rejected trial points included).
    poorly_determined: names whose value the images do not pin down (see `fit.stats`; a texture
        also when some texel is not `seen`; an entry whose stderr is nan flags nothing); every name
        when the fit rests only on noise clipped at a bound -- the pixels `fit.clipping` would leave out are all, or
        all but no more entries than unknowns, of those used: the fit is kept as solved (nothing
        censored), its values biased by the clip beyond what their standard errors cover.
    initial: the starting values (same shapes as params). solver: the solver's name.
    timings: seconds per phase ("setup": G-buffers / ray trees and arrays, of which "render": the
        Warp renders, 0 where every view was kept with a compiled scene: `fit.records`; "solve"; "stats"),
        summed over both solves when the fit was made again without clipped pixels (`fit.clipping`).
    model: the image model fitted through: "raster" (the G-buffer) or "raytrace" (the recorded ray
        tree). sigma: the pixel noise used (given, or estimated from the targets; see `fit.stats`).
    chi2: reduced chi-square sum w r^2 / (dof w_mean sigma^2) of the residuals at noise sigma (about
        1 when the model explains the targets to their noise). model_mismatch: chi2 above its
        spread for a given sigma, and above `fit.stats.MISMATCH_CHI2` too for an estimated one.
        mismatch_suspected: sigma estimated and chi2 above its spread (`fit.noise.chi2_spread`) but
        not above MISMATCH_CHI2: the residuals exceed the estimated noise, by less than an estimate
        can be off for non-white noise: the model is not judged (`ok` False; pass `sigma=` to judge it).
        sigma_range: (low, high), the noise levels the residuals allow when their noise is not white
        (`fit.whiteness`: read between neighbours 1 pixel apart -- sigma -- and 2 apart, they
        disagree beyond their spread: a pixel filter or a blur makes neighbours alike, dithering
        makes them differ), the model then judged against both: a mismatch only when chi2 is above
        its threshold even at `high`, ok only when within it even at `low`, else mismatch_suspected;
        None when the noise reads white, is given or is not estimated. `noise_not_white`: whether
        it is set.
        noise_unknown: too few used pixels have used neighbours to estimate the noise (a small,
        thin or scattered mask) and no `sigma` was given: sigma and chi2 are nan, and whether the
        image model explains the targets is not judged (`ok` is False; pass `sigma=` to judge it).
        underdetermined: `too_few_values`, or J^T J over the unknowns the data reach is singular
        (`degenerate` names the parameters; with enough values the model is still judged by chi2),
        or a parameter reaches no counted value (`unreached`); either way `ok` is False.
    too_few_values: no more counted residual entries (weight > 0, uncensored, not noise-free
        zeros) than fitted unknowns: the data neither determine the values nor say anything of the
        noise or the model -- chi2 nan, not judged, every parameter poorly determined; the standard
        errors use a given sigma, else are inf.
    prior_pull: with a texture `smoothness` prior, the most it moves a value the pixels determine
        from where they alone put it, in standard errors (`fit.stats.prior_pull`; 0 without a prior,
        nan when not formed); above `fit.stats.PRIOR_PULL_MAX` (1) the moved parameters are
        `poorly_determined` -- their values carry the prior's bias, which their stderr do not cover.
    degenerate: names of parameters the data reach that a singular direction of J^T J involves: the
        images fix only combinations of them (kd of every material and the lights' intensities:
        kd c and I / c give the same image), their values arbitrary along it, their stderr inf
        (`fit.stats.degenerate`; `identify` names the directions). Directions within a texture's
        texels alone do not count under a smoothness prior (it fills them).
    unreached: names of parameters (not texels) with an entry no counted value depends on -- a zero
        column of J^T J: kd where no used pixel of the material is lit, a light that reaches no used
        pixel --, left at their start, stderr inf (`fit.stats.unreached`).
    at_bound: names with a value (some channel) on a bound (ks = 0 for a matte target).
    censored: target pixel channels at the target's ceiling (clipped highlights), fitted as "at
        least the ceiling"; with noise, also the channels of the pixels left out because their
        model lies within 2 sigma of a bound the target is clipped at (black or the ceiling,
        `fit.clipping`). nonfinite_left_out: non-finite target values (NaN, inf: a masked EXR's
        background) outside the pixels the fit uses, which it does not read (at a pixel it uses they
        make "nonfinite_target"). residuals: per view (H, W, 3) float32 model - target on the pixels
        used (0 elsewhere). seen: parameter name of each fitted texture, as in `params` ("texture",
        or "<material>.texture" when several materials were fitted) -> (H_t, W_t) bool, the texels
        the pixels used constrain (`FitOptions.visible_threshold`).
    """

    params: dict
    stderr: dict
    loss: float
    psnr: float
    steps: int
    seconds: float
    converged: bool
    result: str
    history: list = field(default_factory=list)
    poorly_determined: list = field(default_factory=list)
    initial: dict = field(default_factory=dict)
    solver: str = "lm"
    timings: dict = field(default_factory=dict)
    model: str = "raster"
    sigma: float = float("nan")
    chi2: float = float("nan")
    model_mismatch: bool = False
    mismatch_suspected: bool = False
    noise_unknown: bool = False
    sigma_range: tuple | None = None
    underdetermined: bool = False
    too_few_values: bool = False
    degenerate: list = field(default_factory=list)
    unreached: list = field(default_factory=list)
    prior_pull: float = 0.0
    at_bound: list = field(default_factory=list)
    censored: int = 0
    nonfinite_left_out: int = 0
    residuals: list = field(default_factory=list, repr=False, compare=False)
    seen: dict = field(default_factory=dict, repr=False, compare=False)
    scene: object = field(default=None, repr=False, compare=False)
    layout: tuple = field(default=(), repr=False, compare=False)

    @property
    def ok(self) -> bool:
        """Converged, and the image model explains the targets (judged against a known noise
        level, without a mismatch flag)."""
        return self.converged and not (self.model_mismatch or self.not_judged)

    @property
    def noise_not_white(self) -> bool:
        """Whether the estimated noise is not white (`sigma_range` set)."""
        return self.sigma_range is not None

    @property
    def not_judged(self) -> bool:
        """Whether the fit is left unsettled (the CLI's exit 5; a flag of NOT_JUDGED): the noise
        unknown or a mismatch suspected against an estimated noise (the model not judged), or the
        fit underdetermined (its values not determined; the model still judged where chi2 is not
        nan: a degenerate fit can also be a model mismatch)."""
        return any(getattr(self, flag) for flag in NOT_JUDGED)

    def no_fit(self) -> str | None:
        """Why no fit was made -- "empty_mask: ..." or "nonfinite_target: ..." with what the targets
        and masks hold --, or None when one was."""
        if self.result not in NO_FIT:
            return None
        detail = getattr(self.result, "detail", "")
        return f"{self.result}: {detail}" if detail else str(self.result)

    @property
    def notes(self) -> list[str]:
        """Notes on the inputs, one line each (`fit.hints.notes`): non-finite target values left
        out, coefficients far above 1 (a target in code values?). Hints: `ok` does not read them."""
        return notes(self)

    @property
    def n_params(self) -> int:
        """The number of fitted entries (an RGB value counts 3, a texture H_t W_t 3)."""
        return int(sum(p.size for p in self.layout))

    @property
    def rmse(self) -> float:
        """Root of the mean squared weighted error over the pixels used: 10^(-psnr / 20)."""
        return 10.0 ** (-self.psnr / 20.0)

    def _texture_key(self) -> str:
        keys = [p.key for p in self.layout if p.shape is not None]
        if len(keys) != 1:
            raise FitError(f"texture: this result fitted {len(keys)} textures ({', '.join(keys) or 'none'}); read "
                           "params[name] and seen[name]")
        return keys[0]

    @property
    def texture(self) -> np.ndarray:
        """The one fitted texture, (H_t, W_t, 3) float32 linear, row 0 at the top."""
        return self.params[self._texture_key()]

    @property
    def visible(self) -> np.ndarray:
        """(H_t, W_t) bool: the texels of the one fitted texture that the views constrain."""
        return self.seen[self._texture_key()]

    def to_scene(self, folder=None, stem: str = "fitted"):
        """The scene with the fitted values written back (materials, and lights where fitted); a
        fitted texture is saved in `folder` as `texture_file_name(stem, material, index)` (linear
        float32, atomically; the commands' rule: a material name that is not a plain word, such as
        "../x", gives <stem>.texture<index>.npy, never a path outside `folder`) and the material
        points to it (FitError without a folder). `scene_dict` names the texture files without
        writing them, for a caller that writes them together with the scene."""
        scene = self._with_values()
        textures = self.fitted_textures()
        if textures and folder is None:
            raise FitError(f"to_scene: a fitted texture (material {', '.join(map(repr, textures))}); give folder= to "
                           "save its texels")
        materials = dict(scene.materials)
        for name, file in self._texture_names(stem).items():
            path = save_image(Path(folder) / file, textures[name])
            materials[name] = dataclasses.replace(materials[name], texture=str(path))
        return dataclasses.replace(scene, materials=materials)

    def scene_dict(self, stem: str) -> dict:
        """The fitted scene in the scene file format (`to_scene().to_dict()`), saved as a file named
        `stem`.json beside `texture_files(stem)`: each fitted texture's material points to its file by
        name, a relative path that resolves against the scene file's folder."""
        data = self._with_values().to_dict()
        for name, file in self._texture_names(stem).items():
            data["materials"][name]["texture"] = file
        return data

    def texture_files(self, stem: str) -> dict:
        """File name -> texels ((H_t, W_t, 3) float32 linear, for a .npy) of each fitted texture of
        the scene `scene_dict(stem)` describes: `texture_file_name(stem, material, index)`."""
        textures = self.fitted_textures()
        return {file: textures[name] for name, file in self._texture_names(stem).items()}

    def _texture_names(self, stem: str) -> dict:
        """Material name -> `texture_file_name` of each fitted texture."""
        names = self.scene.material_names
        return {name: texture_file_name(stem, name, names.index(name)) for name in self.fitted_textures()}

    def fitted_textures(self) -> dict:
        """Material name -> its fitted texture, (H_t, W_t, 3) float32 linear, row 0 at the top."""
        names = self.scene.material_names
        return {names[p.index]: self.params[p.key] for p in self.layout if p.shape is not None}

    def _with_values(self):
        """The scene with every fitted value but the textures written back."""
        if self.scene is None:
            raise FitError("to_scene: this result carries no scene")
        scene = self.scene
        names = scene.material_names
        materials = dict(scene.materials)
        lights = list(scene.lights)
        for p in self.layout:
            value = self.params[p.key]
            if p.kind == "intensity":
                lights[p.index] = dataclasses.replace(lights[p.index], intensity=tuple(value))
            elif p.shape is None:
                name = names[p.index]
                new = tuple(value) if isinstance(value, list) else float(value)
                materials[name] = dataclasses.replace(materials[name], **{p.kind: new})
        return dataclasses.replace(scene, materials=materials, lights=tuple(lights))

    def to_dict(self, stem: str | None = None, folder=None) -> dict:
        """A JSON-able summary (non-finite numbers become null). A texture -- fitted, its stderr, its
        start -- is given by its statistics (`texel_summary`), not texel by texel (a 256 x 256 one was
        ~1.5 MB of JSON): the texels are in the file `texture_files(stem)` writes, which, with `stem`,
        the fitted texture's entry names ("file": `folder` / that name, the name alone without
        `folder`), beside the share of its texels the views see ("seen")."""
        textures = {}
        if stem is not None:
            names, files = self.scene.material_names, self._texture_names(stem)
            textures = {p.key: files[names[p.index]] for p in self.layout if p.shape is not None}
        params = {k: _reported(v) for k, v in self.params.items()}
        for key, file in textures.items():
            seen = self.seen.get(key)
            params[key] = {"file": str(Path(folder) / file) if folder is not None else file, **params[key],
                           "seen": None if seen is None else float(np.mean(seen))}
        return {
            "params": params,
            "stderr": {k: _reported(v) for k, v in self.stderr.items()},
            "initial": {k: _reported(v) for k, v in self.initial.items()},
            "loss": _json_number(self.loss), "psnr": _json_number(self.psnr), "steps": self.steps,
            "seconds": self.seconds, "ok": self.ok, "converged": self.converged, "result": self.result,
            "solver": self.solver,
            "poorly_determined": list(self.poorly_determined), "history": [_json_number(x) for x in self.history],
            "timings": dict(self.timings), "model": self.model, "sigma": _json_number(self.sigma),
            "chi2": _json_number(self.chi2), "model_mismatch": self.model_mismatch,
            "mismatch_suspected": self.mismatch_suspected, "noise_unknown": self.noise_unknown,
            "noise_not_white": self.noise_not_white,
            "sigma_range": None if self.sigma_range is None else [_json_number(x) for x in self.sigma_range],
            "underdetermined": self.underdetermined, "too_few_values": self.too_few_values,
            "degenerate": list(self.degenerate), "unreached": list(self.unreached),
            "prior_pull": _json_number(self.prior_pull), "at_bound": list(self.at_bound), "censored": self.censored,
            "nonfinite_left_out": self.nonfinite_left_out, "notes": self.notes,
        }

    def table(self) -> str:
        """A plain-text table: name, value +- stderr (per channel), and a flag for poorly determined;
        the result, the noise and chi-square; the flags (`fit.hints.flag_lines`) and notes."""
        rows = [f"{'parameter':<22} {'value ± stderr':<60}"]
        for key, value in self.params.items():
            if isinstance(value, np.ndarray):  # a texture: its size and how much of it the views see
                seen = self.seen.get(key)
                share = f", {100.0 * seen.mean():.1f} % seen" if seen is not None else ""
                rows.append(f"{key:<22} {value.shape[1]}x{value.shape[0]} texels, mean {value.mean(axis=(0, 1))}"
                            f"{share}")
                continue
            err = self.stderr.get(key)
            values = value if isinstance(value, list) else [value]
            errs = err if isinstance(err, list) else [err] * len(values)
            cells = ", ".join(f"{v:.6g} ± {e:.2g}" for v, e in zip(values, errs))
            flag = "  (poorly determined)" if key in self.poorly_determined else ""
            flag += "  (at bound)" if key in self.at_bound else ""
            rows.append(f"{key:<22} {cells}{flag}")
        rows.append(f"result: {self.result}, converged: {self.converged}, steps: {self.steps}, "
                    f"loss: {self.loss:.4g}, PSNR: {self.psnr:.2f} dB, {self.seconds:.3f} s ({self.solver})")
        rows.append(f"image model: {self.model}, noise sigma: {self.sigma:.3g}, reduced chi-square: {self.chi2:.3g}")
        rows.extend(flag_lines(self) + self.notes)
        return "\n".join(rows)
