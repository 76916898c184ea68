"""A fit prepared: the scene at its start values, the image model chosen, one Warp render per view,
the parameter layout and the device problem. Every front end (`fit_material`, `fit_scene`,
`fit_batch`, `identify`) builds one `Setup`; only the solve differs.

The image model is chosen, and the arguments checked, in `arguments.py`.
"""

from __future__ import annotations

import contextlib
import copy
import mmap
import time
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DifflabError, FitError
from ..lighting.jax_model import light_records, lights_to_jax
from ..renderers.api import as_scene, fit_frame
from ..renderers.compile import CompiledScene
from ..renderers.launch import resolve_device
from ..scene import RenderSettings
from .arguments import check_ceiling, check_number, check_smoothness, choose_method
from .cache import serial_cpu_device
from .ceiling import float_ceiling, primary_objects, refuse_values_above
from .materials import MaterialTable, material_records
from .noise import quantisation, scatter
from .normal_equations import by_parts_terms
from .params import DEFAULT_PARAMS, SCENE_PARAMS, Layout, apply_init, build_layout, fitted_materials, scene_value
from .problem import LOSSES, Problem, ViewJ, assembled, device_index, on_boundary, to_device, value_index
from .raytree import TreeModel, tree_influence
from .records import DEVICE_COPIES, KeptView, View, take_pixels, target_values, view_key, view_store
from .shading import GBufferModel, influence, points_may_be_pixels
from .stats import FLOAT_SIGMA
from .result import ResultCode
from .targets import empty_detail, nonfinite_count, nonfinite_detail, prepared_targets
from .texels import TexelSource, texture_starts, wants_texels

PRIVATE_MAP = {"flags": mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS} if hasattr(mmap, "MAP_ANONYMOUS") else {}  # (an
# anonymous map of the process's own, not shared memory: its pages written 0.25 ms for 786 kB, shared 0.39)
MAPPED_PLANES = 1 << 17  # bytes: smaller residual planes come from the heap (a map is a page or more, and a
# process may hold ~65k maps: results of many small fits kept would exhaust them; glibc maps from 128 kB too)


class TargetStatistics(NamedTuple):
    """What the report reads of a fit's targets: censored (used entries at the ceiling that weigh
    in), quantisation (`noise.quantisation`), sigma_floor (the noise floor: at least FLOAT_SIGMA),
    weighted_entries (the residual entries that count, (3 U,) bool over the views' (U, 3) rows),
    weight_total (the sum of their weights) and unit_weights (every used weight is 1: the weighted
    residuals are the plain ones)."""

    censored: int
    quantisation: float
    sigma_floor: float
    weighted_entries: np.ndarray
    weight_total: float
    unit_weights: bool


class Setup:
    """A fit prepared (see the module docstring). Attributes: scene (start values written in),
    materials, method, layout, initial (key -> value), x0 (solver coordinates), views, used_pixels,
    nonfinite (target values at the pixels used), nonfinite_left_out (elsewhere), sigma_given,
    sigma_fallback (the noise when too few pixels allow an estimate, None: unknown;
    `engine.without_clipped`), x64, dtype, problem, jax_device (the JAX device its arrays and programs
    are on, `on_device`; None: JAX's default), render_seconds (the Warp renders' wall time),
    base_scene (before `init`), ceiling_given, loss, loss_scale, threads (CPU threads for the render,
    as given); and what only the report reads (`statistics`, formed on first use): censored,
    quantisation (the rms rounding error of the targets' used values, `noise.quantisation`: 0 for
    float data), sigma_floor, weighted_entries, weight_total, unit_weights."""

    def __init__(self, scene, targets, materials=None, params=DEFAULT_PARAMS, *, method=None,
                 per_channel=True, bounded=False, loss="l2", loss_scale=0.05, masks=None, weights=None, init=None,
                 sigma=None, ceiling=None, smoothness=0.0, x64=True, max_depth=None, spp=None, device="cpu",
                 threads=None):
        if loss not in LOSSES:
            raise FitError(f"loss: unknown loss {loss!r}; known: {', '.join(LOSSES)}")
        loss_scale = check_number(loss_scale, "loss_scale")
        self.sigma_given = check_number(sigma, "sigma", allow_none=True)
        self.sigma_fallback = None
        ceiling = check_ceiling(ceiling)
        for name, flag in (("per_channel", per_channel), ("bounded", bounded), ("x64", x64)):
            if not isinstance(flag, bool):
                raise FitError(f"{name}: must be True or False, got {flag!r}")
        self.compiled = scene if isinstance(scene, CompiledScene) else None
        try:
            scene = scene.scene if self.compiled is not None else as_scene(scene)
        except DifflabError as exc:
            raise FitError(f"scene: {exc}") from None
        self.materials = fitted_materials(scene, materials)
        texels = wants_texels(params)
        self.method = choose_method(scene, self.materials, method, texels)
        self.base_scene, self.ceiling_given = scene, ceiling
        self.scene = scene = apply_init(scene, self.materials, init)  # a tree is recorded at the start values
        self.textures = texture_starts(scene, self.materials, init) if texels else {}
        self.layout: Layout = build_layout(scene, self.materials, params, tree=self.method == "raytrace",
                                           per_channel=per_channel, bounded=bounded,
                                           texture_shapes={k: v.shape[:2] for k, v in self.textures.items()})
        self._check_init_keys(init)
        self.smoothness = check_smoothness(smoothness, self.textures)
        self.texel_source = TexelSource.from_layout(self.layout, scene)
        if self.method == "raster":
            fitted = {scene.material_names[p.index] for p in self.layout if p.shape is not None}
            textured = [m for m in self.materials if scene.materials[m].texture is not None and m not in fitted]
            if textured:
                raise FitError(f"material: {', '.join(textured)} has an image texture, which the G-buffer image "
                               "model carries only when its texels are fitted; fit with method='raytrace', or add "
                               "'texture' to params")
        self.initial = {p.key: scene_value(scene, p, self.textures) for p in self.layout}
        self.x0 = self.layout.x_of(self.layout.flatten(self.initial))
        self.threads = threads  # (the render's; `engine.noise_ahead` takes a worker only where it may)
        self.x64 = x64
        self.dtype = jnp.float64 if x64 else jnp.float32
        self.loss, self.loss_scale = loss, loss_scale
        self.views = self._record(targets, masks, weights, max_depth, spp, device, threads)  # (their pixels)
        self.jax_device = self._closed_form_device()
        with jax.enable_x64(x64), self.on_device():
            # the image models first: each device program (`shading._device_model`, ~0.3 ms of XLA's
            # thread for the bench's 24.7k points, which the solve waits for) then runs while the targets'
            # rows are taken and their ceilings found (`_ceiling`, ~0.1 ms of the bench's first fit)
            lights = [self._lights(v) for v in self.views]
            models = [self._view_model(v, v.pixels, view_lights) for v, view_lights in zip(self.views, lights)]
            self.views = [self._ceiling(v) for v in self.views]
            if self.ceiling_given:  # (a number; False: none)
                for view, (target, _) in zip(self.views, self.labels):
                    refuse_values_above(self.ceiling_given, view.values, view.entries, target)
            self.used_pixels = sum(v.pixels.size for v in self.views)
            self._targets_seen()
            self.problem = self._problem(loss, loss_scale, (lights, models))

    def _closed_form_device(self):
        """`cache.serial_cpu_device()` -- the CPU client of one thread -- for a fit whose normal
        equations are formed in closed form (`normal_equations.by_parts_applies`, asked before the
        problem is made: `by_parts_terms`, and the G-buffer model with each pixel its own Phong
        point), else None (JAX's default device: forward-mode Jacobians use every core)."""
        if self.method != "raster" or not by_parts_terms(self.loss, self.smoothness, self.layout):
            return None
        if not all(view.record.shading == "phong" and points_may_be_pixels(view.record) for view in self.views):
            return None
        return serial_cpu_device()

    def on_device(self):
        """A context in which the fit's arrays are made and its programs run: on `jax_device`, the
        device `_closed_form_device` chose (nothing to set where it is None). Arrays of the fit met
        outside it are moved where the context's computation runs (correct, a copy slower)."""
        return contextlib.nullcontext() if self.jax_device is None else jax.default_device(self.jax_device)

    def reweighted(self, weights, init) -> Setup:
        """The fit with other `weights` -- per view (H, W, 3) >= 0, 0 outside its mask -- and `init`,
        without preparing the targets again: the same pixels (a pixel whose weight became 0 stays,
        its residual 0), so the problem keeps its shapes and its compiled solve serves every such
        refit of the view, and the ceilings are those found for the fit it reweights (a `Setup`
        built afresh with these weights finds a float target's ceiling again, among the values left:
        with that ceiling, its solution, statistics and residual images are the refit's). A pixel
        at weight 0 still counts in `used_pixels`: `engine.without_clipped` refits only when
        entries with weight > 0 remain."""
        out = copy.copy(self)
        out.scene = apply_init(self.base_scene, self.materials, init)
        out.textures = texture_starts(out.scene, self.materials, init) if self.textures else {}
        out.initial = {p.key: scene_value(out.scene, p, out.textures) for p in self.layout}
        out.x0 = self.layout.x_of(self.layout.flatten(out.initial))
        out.render_seconds = 0.0
        out.views = [self._weighted(view, weight) for view, weight in zip(self.views, weights)]
        out.used_pixels = sum(v.pixels.size for v in out.views)
        out._targets_seen()
        with jax.enable_x64(self.x64), self.on_device():
            out.problem = out._problem(self.loss, self.loss_scale)
        return out

    def _targets_seen(self):
        """The targets' non-finite values (the precheck's); their statistics formed afresh on first use."""
        self.nonfinite = int(sum(v.nonfinite for v in self.views))
        self.nonfinite_left_out = int(sum(v.left_out for v in self.views))
        self._statistics = None

    @property
    def statistics(self) -> TargetStatistics:
        """What only the report reads of the targets (`TargetStatistics`), formed on first use: beside
        the solve (`engine.noise_ahead`, where the calling thread waits for XLA), else by the report.
        Formed in the setup, before the solve's dispatch, it cost a first fit of the bench's float
        target ~0.02 ms, of the same target as an 8-bit PNG ~0.3 ms (`noise.quantisation`).
        (Formed on a worker beside another solver while the report asks for it, it is formed twice,
        the same.)"""
        if self._statistics is None:
            entries, total, unit_weights = [], 0.0, True  # unit weights: the weighted residuals are the plain ones
            for v in self.views:
                entries.append(v.entries.reshape(-1))
                if v.weighting is None:  # 1 at every pixel used
                    total += 3 * v.pixels.size
                else:
                    total += np.sum(v.weights)
                    unit_weights &= bool(np.all(v.weights == 1.0))
            censored = int(sum(np.count_nonzero(v.entries) - np.count_nonzero(v.counted)
                               for v in self.views if np.isfinite(v.ceiling)))  # over the used pixels
            rounding = quantisation(self.views)  # 0 for float data
            self._statistics = TargetStatistics(censored, rounding, max(FLOAT_SIGMA, rounding), np.concatenate(entries),
                                                float(total), unit_weights)
        return self._statistics

    censored = property(lambda self: self.statistics.censored)
    quantisation = property(lambda self: self.statistics.quantisation)
    sigma_floor = property(lambda self: self.statistics.sigma_floor)
    weighted_entries = property(lambda self: self.statistics.weighted_entries)
    weight_total = property(lambda self: self.statistics.weight_total)
    unit_weights = property(lambda self: self.statistics.unit_weights)

    def retarget(self, images, init=None) -> Setup:
        """The same fit (views, image models, compiled solve) for other target images, one (H, W, 3)
        linear float array per view, kept, not copied (as `targets.load_target` returns them: a private
        copy), and optionally other start values `init`."""
        out = copy.copy(self)
        views = []
        for view, image in zip(self.views, images):
            total = nonfinite_count(image)
            inside = nonfinite_count(image, view.pixels) if total else 0
            views.append(view.replaced(image=image, nonfinite=inside, left_out=total - inside))
            views[-1].__dict__.update(pixels=view.pixels, weights=view.weights)  # cached properties: the same
        out.views = views
        out.labels = [(f"targets[{i}]", mask) for i, (_, mask) in enumerate(self.labels)]  # another image
        out._targets_seen()
        if init is not None:
            scene = apply_init(self.scene, self.materials, init)
            textures = texture_starts(scene, self.materials, init) if self.textures else {}
            for name, image in textures.items():
                if image.shape != self.textures[name].shape:
                    raise FitError(f"init: the {name!r} texture's start is {image.shape}, the fit's texels "
                                   f"{self.textures[name].shape}")
            out.initial = {p.key: scene_value(scene, p, textures) for p in self.layout}
            out.x0 = self.layout.x_of(self.layout.flatten(out.initial))
        with jax.enable_x64(self.x64), self.on_device():
            out.problem = self.problem.with_targets(
                [jnp.asarray(v.values, self.dtype) for v in views])
        return out

    def _check_init_keys(self, init):
        keys = {p.key for p in self.layout}
        single = self.materials[0] + "." if len(self.materials) == 1 else None
        for key in init or {}:
            plain = key[len(single):] if single and key.startswith(single) else key
            if plain not in keys:
                raise FitError(f"init[{key!r}]: not fitted (fitted: {sorted(keys)})")

    def _record(self, targets, masks, weights, max_depth, spp, device, threads) -> list[View]:
        """One Warp render per target: its G-buffer, or its ray tree (adaptive_threshold 0, so that
        no child is cut by weight)."""
        render = {"method": self.method} if spp is None else {"method": self.method, "spp": spp}
        if self.method == "raytrace":
            render["adaptive_threshold"] = 0.0
            if max_depth is not None:
                render["max_depth"] = max_depth
        elif max_depth is not None:
            raise FitError(f"max_depth: {max_depth!r} does not apply to method='raster' (the G-buffer has no "
                           "secondary rays; use method='raytrace')")
        if spp is not None or max_depth is not None:  # (the scene's own block and a METHODS name are valid)
            try:  # checked as the scene's render block is, named by keyword (spp=True is no 1)
                RenderSettings.parse({**self.scene.render.to_dict(), **render}, "")
            except DifflabError as exc:
                raise FitError(str(exc)) from None
        ids = sorted({p.index for p in self.layout if p.kind != "intensity"})
        all_surfaces = any(p.kind == "intensity" for p in self.layout)
        crossing = sorted({p.index for p in self.layout if p.kind == "kt"})
        views, self.render_seconds = [], 0.0
        store = view_store(self.compiled)  # the views kept with the compiled scene (`records.py`)
        tree_ids = tuple(range(len(self.scene.materials))) if all_surfaces else tuple(ids)
        self.labels = []  # per view (target, mask or None), as messages name them
        for view_scene, image, step, gamma, mask, weight, nonfinite, labels in prepared_targets(self.scene, targets, masks,
                                                                                         weights, render):
            self.labels.append(labels)
            key = view_key(view_scene, resolve_device(device)) if store is not None else None
            kept = store.get(key) if store is not None else None
            if kept is None:
                start = time.perf_counter()
                frame = fit_frame(self._compiled_for(view_scene, device) or view_scene, device=device,
                                  threads=threads)
                self.render_seconds += time.perf_counter() - start
                kept = KeptView(frame.ray_tree if self.method == "raytrace" else frame.gbuffer)
                if store is not None:
                    store.put(key, kept)
            record = kept.record
            if self.method == "raytrace":
                touched = kept.touched((tree_ids, tuple(crossing)), lambda: tree_influence(record, tree_ids, crossing))
            else:
                touched = kept.touched((tuple(ids), all_surfaces), lambda: influence(record, ids, all_surfaces))
            views.append(self._used(View(image=image, mask=mask, weighting=weight, ceiling=np.inf, step=step or 0.0,
                                         gamma=gamma, nonfinite=nonfinite, record=record, scene=view_scene, used=touched,
                                         kept=kept if store is not None else None, touched=touched), weight))
        return views

    @staticmethod
    def _weighted(view: View, weight) -> View:
        """The view with `weight` (None: 1 inside the mask), its own pixels, rows and ceiling
        (`reweighted`)."""
        out = view.replaced(weighting=weight)
        out.__dict__.update(pixels=view.pixels, values=view.values, zeros=view.zeros)
        return out

    def _used(self, view: View, weight) -> View:
        """The view with `weight` (None: 1 inside the mask) and the pixels it uses (in the mask,
        weight > 0, influenced by the fitted parameters); its ceiling found later (`_ceiling`)."""
        used = view.mask & view.touched
        if weight is not None:
            positive = weight > 0
            used &= positive[..., 0] | positive[..., 1] | positive[..., 2]
        used, pixels = view.kept.pixels(used) if view.kept is not None else (used, np.flatnonzero(used))
        total = view.nonfinite + view.left_out  # (`_record`'s view: all its non-finite values)
        inside = nonfinite_count(view.image, pixels) if total else 0
        out = view.replaced(weighting=weight, used=used, nonfinite=inside, left_out=total - inside)
        out.__dict__.update(pixels=pixels)  # (View's cached property, taken already)
        return out

    def _ceiling(self, view: View) -> View:
        """The view (`_used`'s) with its target's rows at its pixels (`View.values`) and its ceiling
        (given; 1 for image files, which saturate there; for float data, ties at the maximum of the
        used values: `ceiling.py`)."""
        values = target_values(view.image, view.used, view.nonfinite)
        top = self.ceiling_given if self.ceiling_given is not None else (1.0 if view.step else None)
        if top is None:  # float data (`ceiling.py`)
            top = float_ceiling(values, lambda: primary_objects(view.record).reshape(-1)[view.pixels])
        out = view.replaced(ceiling=np.inf if top is False else float(top))
        out.__dict__.update(pixels=view.pixels, values=values)  # View's cached properties, taken already
        return out

    def _compiled_for(self, view_scene, device):
        """The compiled scene given, under the view's scene, when it holds the view's geometry (same
        camera, light positions and device: the G-buffer does not depend on the coefficients), else
        None (the view is compiled when rendered)."""
        compiled = self.compiled
        if compiled is None or compiled.device != resolve_device(device):
            return None
        if view_scene is compiled.scene:  # (a view without overrides: its scene is the compiled one)
            return compiled
        placed = lambda lights: [(l.type, l.position, l.direction) for l in lights]  # noqa: E731, E741
        if view_scene.camera != compiled.scene.camera or placed(view_scene.lights) != placed(compiled.scene.lights):
            return None
        return compiled.with_scene(view_scene)

    def _model(self, view: View, pixels, lights):
        if self.method == "raytrace":
            return TreeModel.build(view.record, pixels, view.scene.background, self.dtype, self.texel_source)
        return GBufferModel.build(view.record, pixels, lights, self.dtype, self.texel_source,
                                  covered=pixels is view.pixels)  # (in the mask: `influence` saw a material)

    def _view_arrays(self, view: View, pixels, index) -> tuple:
        """A view's arrays for `pixels`, numpy: (lights, target, sqrt(weight), ceiling (None: the
        target is not clipped), intensity_index) (see `ViewJ`)."""
        return (lights_to_jax(view.scene.lights, self.dtype, host=True), *self._view_rows(view, pixels),
                *self._view_small(view, index))

    def _view_small(self, view: View, index) -> tuple:
        """`_view_arrays`' (ceiling, intensity_index), numpy: small, and of no pixel."""
        count = len(view.scene.lights)
        intensity_index = index  # (the scene's lights: `value_index`'s own, read-only)
        if count != index.shape[0]:
            intensity_index = np.full((count, 3), -1, np.int32)
            shared = min(count, index.shape[0])
            intensity_index[:shared] = index[:shared]
        ceiling = np.asarray(view.ceiling, np.dtype(self.dtype)) if np.isfinite(view.ceiling) else None
        return ceiling, intensity_index

    def _lights(self, view: View):
        """A view's lights (`LightsJ`) on the device: `records.DEVICE_COPIES`' by their
        `light_records` (see `_problem`)."""
        records = light_records(view.scene.lights)
        return DEVICE_COPIES.kept(
            ("lights", np.dtype(self.dtype), jax.config.jax_enable_x64, jax.config.jax_default_device, records),
            lambda: lights_to_jax(view.scene.lights, self.dtype, host=True, records=records))

    def _view_rows(self, view: View, pixels) -> tuple:
        """`_view_arrays`' (target, sqrt(weight)) of the `pixels`: rows (U, 3), sqrt(weight) a scalar 1
        where every weight is (the pixels used without weights)."""
        real = np.dtype(self.dtype)
        used = pixels is view.pixels  # its rows are taken once (`View.values`, `View.weights`)
        if used and view.weighting is None:
            sqrt_weight = np.ones((), real)  # (`ViewJ`: 1, broadcast)
        else:
            sqrt_weight = np.sqrt(view.weights if used else take_pixels(view.weight, pixels)).astype(real, copy=False)
        return (view.values if used else take_pixels(view.target, pixels)).astype(real, copy=False), sqrt_weight

    def _view_model(self, view: View, pixels, lights):
        """The image model of a view's `pixels` (kept with the record when they are the pixels used),
        for its `lights` (numpy or on the device)."""
        if view.kept is not None and pixels is view.pixels and self.texel_source is None:
            key = (self.method, np.dtype(self.dtype), self.jax_device)  # (the device its arrays are on)
            return view.kept.model(key, view.used, lambda: self._model(view, pixels, lights))
        return self._model(view, pixels, lights)

    @staticmethod
    def _view(arrays, model) -> ViewJ:
        """A view from its `_view_arrays` on the device and its image model."""
        lights, target, sqrt_weight, ceiling, intensity_index = arrays
        return assembled(ViewJ, model=model, lights=lights, target=target, sqrt_weight=sqrt_weight, ceiling=ceiling,
                         intensity_index=intensity_index)

    def _problem(self, loss, loss_scale, built=None) -> Problem:
        """The device problem, of the views' (lights, image models) `built` already (`__init__`: the
        models before the targets' rows are taken; else built here). Its small arrays (lights: `_lights`; each view's ceiling and
        intensity index, the material table, ambient, loss scale and a unit weight) are
        `records.DEVICE_COPIES`' by the values they are made of, as the scene holds them
        (`light_records`, `material_records`) -- compared as Python values (0.0 and -0.0 as one),
        numpy arrays formed and moved only for values met first: keyed by the arrays' bytes, formed
        each fit, they held the bench's first fit's setup ~0.1 ms longer from the render's end to
        the solve's dispatch (medians of 100 first fits, processes alternating, load 1.2-1.6) --;
        the targets' and weights' rows are numpy, on a 64-byte boundary (`problem.on_boundary`),
        never written to: each jitted call takes them in place (~1 us), where moving them cost a
        copy (`to_device`'s dispatch of a 24768 x 3 target ~0.1 ms in a first fit; the bench's first
        fit -0.14 ms, wall 6.43 -> 6.28 and 6.29 -> 6.15 ms, medians of 80, load 0.9)."""
        counts = (self.layout, len(self.scene.materials), len(self.scene.lights))
        real = np.dtype(self.dtype)
        intensity = value_index(*counts)["intensity"]
        if built is None:
            lights = [self._lights(v) for v in self.views]
            built = lights, [self._view_model(v, v.pixels, view_lights) for v, view_lights in zip(self.views, lights)]
        lights, models = built
        materials = material_records(self.scene.materials.values())
        key = (real, jax.config.jax_enable_x64, jax.config.jax_default_device, counts, materials, self.scene.ambient,
               float(loss_scale), [(v.ceiling, len(v.scene.lights)) for v in self.views])
        small, table, ambient, loss_scale, one = DEVICE_COPIES.kept(key, lambda: (
            [self._view_small(v, intensity) for v in self.views],
            MaterialTable.from_scene(self.scene.materials.values(), self.dtype, host=True, records=materials),
            np.asarray(self.scene.ambient, real), np.asarray(loss_scale, real), np.ones((), real)))
        views = []
        for view, view_lights, model, (ceiling, intensity_index) in zip(self.views, lights, models, small):
            target, sqrt_weight = self._view_rows(view, view.pixels)
            views.append(self._view((view_lights, on_boundary(target), one if view.weighting is None else
                                     on_boundary(sqrt_weight), ceiling, intensity_index), model))
        index = device_index(*counts, jax.config.jax_default_device)
        return assembled(Problem, views=tuple(views), table=table, ambient=ambient, index=index, loss_scale=loss_scale,
                         layout=self.layout, loss=loss, smoothness=self.smoothness)

    def precheck(self) -> ResultCode | None:
        """A result code when the fit cannot be made (non-finite target values at the pixels used, or
        no pixel that the fitted parameters affect), its `detail` naming the targets, masks and
        counts; else None."""
        plural = "s" if len(self.materials) > 1 else ""
        materials = f"material{plural} {', '.join(self.materials)}"
        if self.nonfinite:
            objects = [i for i, o in enumerate(self.scene.objects) if o.material in self.materials]
            showing = [np.isin(primary_objects(view.record), objects) for view in self.views]
            return ResultCode("nonfinite_target", nonfinite_detail(self.labels, self.views, materials, showing))
        if self.used_pixels == 0:
            lit = any(p.kind == "intensity" for p in self.layout)
            return ResultCode("empty_mask", empty_detail(self.labels, self.views, "a surface" if lit else materials))
        return None

    def zero_planes(self) -> list[np.ndarray]:
        """Per view (3, H W) float32 zeros, the memory `residual_planes` fills, each of MAPPED_PLANES
        bytes or more in an anonymous memory map of its own (zero-filled by the system). A fit's result keeps its planes (its
        residual images), so they are new memory in every fit; from the heap they took the memory
        the next first fit's G-buffer rows would reuse, and those faulted in anew. The bench's fits
        with their results kept (tools/mfirst.py's loop, as bench/fit.py keeps them; a page fault
        ~1.5-2 us on this 2-core VM): in a first fit `shading.pixel_arrays` 291 page faults and 0.55
        ms, here 1 and 0.14; `residual_planes` 111 and 0.26 ms, in a row 137 and 0.27, here 0 and
        0.06 -- `engine.noise_ahead` writes their pages beside the solve, where the calling thread
        waits for XLA (~195 faults, 0.25 ms of its time: at load ~1.5 the solve no slower; at ~2 and
        more it competes with XLA's thread). With the results dropped at once the heap's planes were
        reused without a fault, the maps' pages are faulted in anew each fit."""
        return [np.frombuffer(mmap.mmap(-1, 12 * view.used.size, **PRIVATE_MAP), np.float32).reshape(3, -1)
                if 12 * view.used.size >= MAPPED_PLANES else np.zeros((3, view.used.size), np.float32)
                for view in self.views]

    def residual_planes(self, r, zeros=None) -> list[np.ndarray]:
        """Per view (3, H, W) float32 plain residuals min(model, ceiling) - target, channel-major,
        from the weighted residuals r, per view (3, U) (`Problem.view_residuals`; 0 outside the
        pixels used and where the weight is 0), written into `zeros` (default: `zero_planes()`)."""
        zeros = self.zero_planes() if zeros is None else zeros
        out = []
        for view, part, planes in zip(self.views, r, zeros):
            if not self.unit_weights:
                sqrt_w = np.sqrt(view.weights).T
                part = np.where(sqrt_w > 0, part / np.where(sqrt_w > 0, sqrt_w, 1.0), 0.0)
            scatter(planes, view.used, view.pixels, part)
            out.append(planes.reshape(3, *view.used.shape))
        return out

    def values(self, x) -> dict:
        """Solver coordinates -> key -> (size,) values in scene units."""
        return self.layout.unflatten(self.layout.values(np.asarray(x, np.float64)))

    def render(self, values: dict | None = None) -> list[np.ndarray]:
        """Each view's whole image (H, W, 3) float32 from its image model at `values` (key -> value in
        scene units; default: the start), pixels outside the masks included."""
        flat = self.layout.flatten(self.initial if values is None else values)
        out = []
        with jax.enable_x64(self.x64), self.on_device():
            index = value_index(self.layout, len(self.scene.materials), len(self.scene.lights))
            for view in self.views:
                every = np.arange(view.used.size)
                arrays = to_device(self._view_arrays(view, every, index["intensity"]))
                model = self._view_model(view, every, arrays[0])
                full = eqx.tree_at(lambda p: p.views, self.problem, (self._view(arrays, model),))
                image = images_jit(full, jnp.asarray(flat, self.dtype))[0]
                out.append(np.asarray(image, np.float32).reshape(view.image.shape))
        return out


@eqx.filter_jit
def images_jit(problem, values):
    """Every view's (U, 3) image at the flat `values` (scene units), compiled once per problem structure."""
    return problem.images(values)


class SceneSetup(Setup):
    """A `Setup` with `fit_scene`'s defaults: the ray-tree image model and SCENE_PARAMS."""

    def __init__(self, scene, targets, materials=None, params=SCENE_PARAMS, *, method="raytrace", **kwargs):
        super().__init__(scene, targets, materials, params, method=method, **kwargs)
