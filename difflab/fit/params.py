"""What is fitted: one table from parameter kind to its size, bounds and solver coordinate, and the
layout of the fitted values in one flat vector.

    kind        size     bounds (scene units)      solver coordinate x
    ka, kd, ks  RGB      [0, inf)  ([0, 1] bounded) the value
    intensity   RGB      [0, inf)                   the value        (a light's Ip)
    kr, kt      1        [0, 1]                     the value        (ray tree only)
    absorption  RGB      [0, inf)                   the value        (ray tree only)
    f0          1        [0, 1]                     the value        (torrance specular only)
    n, m        1        [e^-12, e^12]              log(value)       (n: phong / blinn only; m: torrance only)
    texture     H_t W_t 3 [0, inf)                  the value        (texels of a material's image
                                                                      texture; G-buffer (Phong) or ray tree)

The box-constrained Levenberg-Marquardt solver (`lm.py`) works on x inside its bounds, so a
coefficient whose best value is 0 lands on 0. The unconstrained solvers (optimistix's and Adam) see
z, mapped into the box smoothly: x = softplus(z) - softplus(Z_FLOOR) on [0, inf), sigmoid(z) on
[0, 1], clip(z) on a finite log range.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DifflabError, FitError
from .cache import enable_compilation_cache, limit_xla_threads, register_serial_cpu

enable_compilation_cache()  # here, as every fit module imports this one before any makes a JAX array
limit_xla_threads()
register_serial_cpu()

INF = math.inf
LOG_RANGE = (-12.0, 12.0)


@dataclass(frozen=True)
class Kind:
    """A parameter kind: rgb (an RGB triple, or one grey value); lower / upper bounds in scene units;
    log: the solver coordinate is log(value); tree: needs the ray-tree image model; linear: the
    image is affine in it (variable projection solves it exactly); texels: one entry per texel and
    channel of the material's texture (`texels.py`); models: the specular models that read it
    (None: all), under any other the image does not depend on it and it is not fitted."""

    rgb: bool
    lower: float
    upper: float
    log: bool = False
    tree: bool = False
    linear: bool = False
    texels: bool = False
    models: tuple[str, ...] | None = None


KINDS = {
    "ka": Kind(True, 0.0, INF, linear=True), "kd": Kind(True, 0.0, INF, linear=True),
    "ks": Kind(True, 0.0, INF, linear=True),
    "n": Kind(False, math.exp(LOG_RANGE[0]), math.exp(LOG_RANGE[1]), log=True, models=("phong", "blinn")),
    "m": Kind(False, math.exp(LOG_RANGE[0]), math.exp(LOG_RANGE[1]), log=True, models=("torrance",)),
    "f0": Kind(False, 0.0, 1.0, models=("torrance",)),
    "kr": Kind(False, 0.0, 1.0, tree=True), "kt": Kind(False, 0.0, 1.0, tree=True),
    "absorption": Kind(True, 0.0, INF, tree=True), "intensity": Kind(True, 0.0, INF),
    "texture": Kind(True, 0.0, INF, linear=True, texels=True),
}
MATERIAL_KINDS = tuple(k for k in KINDS if k != "intensity")
COLOR_PARAMS = ("ka", "kd", "ks")


class Defaults(tuple):
    """A default parameter list, whose "n" stands for the lobe width of the scene's specular model:
    n (phong, blinn), or the roughness m (torrance), which does not read n (`for_model`). The
    defaults with more names added (`DEFAULT_PARAMS + ("intensity",)`, either side of the +) are
    still the defaults, "n" read alike; a list the caller writes or builds otherwise (a list, a
    comprehension) is taken as written, and "n" in it under torrance is refused. `optional`: the
    default's ray-tree kinds (SCENE_PARAMS' kr, kt, absorption), fitted only for the materials whose
    start traces them (`_traced`); a name added, like any name the caller writes, is fitted for every
    material it names or refused."""

    def __new__(cls, names, optional=()):
        out = super().__new__(cls, names)
        out.optional = frozenset(optional)
        return out

    def __add__(self, other) -> Defaults:
        return Defaults(tuple(self) + tuple(other), self.optional) if isinstance(other, (tuple, list)) else NotImplemented

    def __radd__(self, other) -> Defaults:
        return Defaults(tuple(other) + tuple(self), self.optional) if isinstance(other, (tuple, list)) else NotImplemented

    def for_model(self, specular: str) -> tuple[str, ...]:
        return tuple("m" if kind == "n" and specular == "torrance" else kind for kind in self)


DEFAULT_PARAMS = Defaults(("ka", "kd", "ks", "n"))
SCENE_PARAMS = Defaults(("ka", "kd", "ks", "n", "kr", "kt", "absorption"), optional=("kr", "kt", "absorption"))
LIGHT_PARAM = re.compile(r"^lights\[(\d+)\]\.intensity$")
Z_FLOOR, Z_CEIL, LOGIT_RANGE = -20.0, 30.0, 20.0
START_FLOOR = 1e-2  # an unconstrained solver starting at a bound 0 starts here (no gradient at the floor)


@dataclass(frozen=True)
class Param:
    """One fitted quantity. key: its name in `FitResult.params` ("kd", "red.kd" when several
    materials are fitted, "lights[0].intensity"); kind: a key of `KINDS`; index: material id or
    light index; size: 3 (RGB) or 1, H_t W_t 3 for a texture; lower / upper: bounds in scene units;
    shape: (H_t, W_t) of a texture (entries in texture orientation, row 0 = v 0), else None."""

    key: str
    kind: str
    index: int
    size: int
    lower: float
    upper: float
    shape: tuple | None = None

    @property
    def rgb(self) -> bool:
        return KINDS[self.kind].rgb

    @property
    def log(self) -> bool:
        return KINDS[self.kind].log


@dataclass(frozen=True)
class Layout:
    """The fitted parameters in the order of the flat vector (hashable: a static field of the
    problem)."""

    params: tuple

    def __hash__(self):  # (kept: a jitted call hashes its problem's static fields; `build_layout` interns layouts)
        found = self.__dict__.get("hash")
        if found is None:
            found = self.__dict__["hash"] = hash(self.params)
        return found

    def __reduce__(self):  # (a pickled layout is interned where it is loaded; its hash is that process's)
        return _interned, (tuple(dataclasses.astuple(p) for p in self.params),)

    def __iter__(self):
        return iter(self.params)

    def __len__(self):
        return len(self.params)

    @property
    def size(self) -> int:
        return sum(p.size for p in self.params)

    def entries(self, attribute: str) -> np.ndarray:
        """Per entry of the flat vector: the parameter's `attribute` (a read-only float array, formed
        once per layout)."""
        return _entries(self, attribute)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) of the solver coordinate x per entry, new arrays each call: copies of
        `_box`'s (the cached read-only ones themselves, used by a float32 fit's compiled solve and then
        handed to a float64 one, reached it as float32 buffers:
        test_fit_engine.test_a_float64_fit_after_a_float32_fit_of_the_same_layout)."""
        lo, hi = _box(self)
        return lo.copy(), hi.copy()

    def values(self, x):
        """Solver coordinates x -> values in scene units (numpy for a numpy x, else JAX)."""
        xp = np if isinstance(x, np.ndarray) else jnp
        log = self.entries("log") > 0  # exp of the log entries only: a large linear one (ks = 800) overflows it
        return xp.where(log, xp.exp(xp.where(log, x, 0.0)), x)

    def x_of(self, values) -> np.ndarray:
        """Values (flat, scene units) -> x inside the bounds (numpy)."""
        lo, hi = _box(self)
        values = np.asarray(values, np.float64)
        x = np.where(self.entries("log") > 0, np.log(np.maximum(values, 1e-300)), values)
        return np.minimum(np.maximum(x, lo), hi)  # (np.clip, the same bits: ~3x the time on a few entries)

    def x_from_free(self, z):
        """Unconstrained z -> x in the box (JAX, differentiable; see the module docstring)."""
        lo, hi = self.bounds()
        half_open = np.isinf(hi)
        soft = jax.nn.softplus(jnp.clip(z, Z_FLOOR, Z_CEIL)) - jax.nn.softplus(Z_FLOOR) + lo
        unit = lo + (np.where(half_open, 1.0, hi) - lo) * jax.nn.sigmoid(jnp.clip(z, -LOGIT_RANGE, LOGIT_RANGE))
        clipped = jnp.clip(z, lo, hi)
        return jnp.where(half_open, soft, jnp.where(self.entries("log") > 0, clipped, unit))

    def free_from_x(self, x) -> np.ndarray:
        """x -> z (numpy), starts on a bound moved inside where the map has no gradient."""
        lo, hi = self.bounds()
        x = np.asarray(x, np.float64)
        log = self.entries("log") > 0
        half_open = np.isinf(hi)
        shift = np.maximum(x - lo, START_FLOOR)
        soft = shift + np.log(-np.expm1(-(shift + math.log1p(math.exp(Z_FLOOR))))) + math.log1p(math.exp(Z_FLOOR))
        width = np.where(half_open, 1.0, hi - lo)
        t = np.clip((x - lo) / width, START_FLOOR, 1.0 - 1e-6)
        return np.where(half_open, soft, np.where(log, x, np.log(t) - np.log1p(-t)))

    def flatten(self, values: dict) -> np.ndarray:
        """key -> value (scalar, grey or RGB) as one vector in layout order."""
        out = []
        for p in self.params:
            value = np.asarray(values[p.key], np.float64).reshape(-1)
            out.append(value if value.size == p.size else np.broadcast_to(value, (p.size,)))  # (a grey value)
        return np.concatenate(out)

    def unflatten(self, vector) -> dict:
        """One vector back to key -> (size,) float64 arrays."""
        vector = np.asarray(vector, np.float64)
        out, offset = {}, 0
        for p in self.params:
            out[p.key] = vector[offset:offset + p.size]
            offset += p.size
        return out


@functools.lru_cache(maxsize=64)
def _entries(layout: Layout, attribute: str) -> np.ndarray:
    out = np.concatenate([np.full(p.size, float(getattr(p, attribute))) for p in layout.params])
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=64)
def _box(layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """`Layout.bounds`, formed once per layout: read-only arrays."""
    log = layout.entries("log") > 0
    lo, hi = layout.entries("lower"), layout.entries("upper")
    box = np.where(log, np.log(np.where(log, lo, 1.0)), lo), np.where(log, np.log(np.where(log, hi, 1.0)), hi)
    for array in box:
        array.setflags(write=False)
    return box


def name_list(value, argument: str) -> tuple[str, ...]:
    """A name, a comma-separated string or a sequence of names, as a tuple (FitError otherwise; also
    for an empty name among them, "ka,,kd" or "kd,": a name given is used or refused, never dropped)."""
    if isinstance(value, str):
        names = tuple(part.strip() for part in value.split(","))
        if value.strip() and not all(names):
            raise FitError(f"{argument}: an empty name in {value!r}; separate names by single commas")
        return tuple(name for name in names if name)
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
        if not all(v.strip() for v in value):
            raise FitError(f"{argument}: an empty name in {list(value)!r}")
        return tuple(value)
    raise FitError(f"{argument}: expected a name, a comma-separated string or a list of names, got {value!r}")


def fitted_materials(scene, materials) -> tuple[str, ...]:
    """The materials to fit: the names given (checked), or every material an object uses."""
    names = scene.material_names
    if materials is None:
        used = {obj.material for obj in scene.objects}
        return tuple(name for name in names if name in used)
    chosen = name_list(materials, "material")
    if not chosen or len(set(chosen)) != len(chosen):
        raise FitError(f"material: expected one or more distinct names, got {list(chosen)}")
    for name in chosen:
        if name not in names:
            raise FitError(f"material: undefined material {name!r} (defined: {', '.join(names) or 'none'})")
    return chosen


def _traced(mat, kind: str) -> bool:
    """Whether the recorded tree can see this kind move: kr needs kr > 0, kt and absorption kt > 0."""
    if kind == "kr":
        return mat.kr > 0
    if kind in ("kt", "absorption"):
        return mat.kt > 0
    return True


def _untraced(scene, p: str, kind: str, names, materials) -> FitError:
    """The refusal of a named kr / kt / absorption (`p`) of the materials `names`, whose start weight
    is 0: the ray tree records only the rays that exist, so there is nothing to fit it through."""
    weight = "kr" if kind == "kr" else "kt"
    keys = [f"{name}.{weight}" for name in names]
    one = len(keys) == 1
    others = [f"{name}.{kind}" for name in materials if _traced(scene.materials[name], kind)]
    rest = f"name the others alone ({', '.join(others)})" if others else "leave it out"
    return FitError(f"params: {p!r}: {', '.join(keys)} {'is' if one else 'are'} 0 at the start, so the recorded ray "
                    f"tree has no {'reflected' if weight == 'kr' else 'refracted'} rays from {'it' if one else 'them'}: "
                    f"start {'it' if one else 'them'} above 0 (e.g. 0.05: the scene's materials.{keys[0]}, or init "
                    f"{{'{keys[0]}': 0.05}}), or {rest}")


def build_layout(scene, materials, params, *, tree: bool, per_channel=True, bounded=False,
                 texture_shapes=None) -> Layout:
    """The fitted parameters of `materials` (names): "kd" means every fitted material's, "red.kd" one material's;
    "intensity" every light's, "lights[i].intensity" one light's; "texture" the texels of each fitted
    material's texture, `texture_shapes` name -> (H_t, W_t). `tree`: the image model is the ray
    tree (kr, kt, absorption allowed). Raises FitError naming the offending parameter: a kr (kt,
    absorption) the recorded tree cannot see move -- the start's kr (kt) 0 -- is refused where the
    caller names it for that material ("red.kr") or where no fitted material traces it; a generic
    one over several materials is fitted for those that do (as the defaults' `optional` kinds)."""
    model = scene.render.specular
    optional = params.optional if isinstance(params, Defaults) else frozenset()
    params = params.for_model(model) if isinstance(params, Defaults) else name_list(params, "params")
    if not params:
        raise FitError(f"params: nothing to fit (give some of {', '.join(KINDS)})")
    if len(set(params)) != len(params):
        raise FitError(f"params: duplicate names in {list(params)}")
    wanted, lights = set(), []
    for p in params:
        head, _, kind = p.rpartition(".")
        if p == "intensity":
            lights.extend(range(len(scene.lights)))
            continue
        if (match := LIGHT_PARAM.match(p)) is not None:
            i = int(match.group(1))
            if i >= len(scene.lights):
                raise FitError(f"params: {p!r}: the scene has {len(scene.lights)} light(s)")
            lights.append(i)
            continue
        if kind not in MATERIAL_KINDS or (head and head not in materials):
            where = f"{head!r} is not among the fitted materials ({', '.join(materials)})" if kind in KINDS else \
                f"known: {', '.join(KINDS)}, lights[i].intensity, or 'material.kind'"
            raise FitError(f"params: unknown parameter {p!r}; {where}")
        if KINDS[kind].tree and not tree:
            raise FitError(f"params: {p!r} needs the ray-traced image model (method='raytrace')")
        if KINDS[kind].models is not None and model not in KINDS[kind].models:
            models = KINDS[kind].models
            raise FitError(f"params: {p!r} applies only to the {' and '.join(models)} specular model"
                           f"{'s' if len(models) > 1 else ''}; the scene's is {model!r} (its render.specular), "
                           "which does not read it: the image does not depend on it")
        names = [name for name in ((head,) if head else materials) if _traced(scene.materials[name], kind)]
        untraced = [name for name in ((head,) if head else materials) if name not in names]
        if untraced and p not in optional and (head or not names):  # (generic over several: where traced)
            raise _untraced(scene, p, kind, untraced, materials)
        wanted.update((name, kind) for name in names)
    qualify = len(materials) > 1
    layout = []
    for name in materials:
        for kind in MATERIAL_KINDS:
            if (name, kind) in wanted:
                spec = KINDS[kind]
                upper = 1.0 if bounded and kind in COLOR_PARAMS else spec.upper
                if spec.texels and name not in (texture_shapes or {}):
                    raise FitError(f"params: {kind!r}: material {name!r} has no image texture; give it one in "
                                   "the scene (its file sets the texel grid and the start values)")
                shape = tuple(texture_shapes[name]) if spec.texels else None
                size = 3 * shape[0] * shape[1] if spec.texels else 3 if spec.rgb and per_channel else 1
                layout.append((f"{name}.{kind}" if qualify else kind, kind, scene.material_names.index(name),
                               size, spec.lower, upper, shape))
    for i in sorted(set(lights)):
        layout.append((f"lights[{i}].intensity", "intensity", i, 3 if per_channel else 1, 0.0, INF, None))
    if not layout:
        raise FitError(f"params: nothing to fit in {list(params)} for materials {list(materials)} and "
                       f"{len(scene.lights)} light(s)")
    return _interned(tuple(layout))


@functools.lru_cache(maxsize=64)
def _interned(params: tuple) -> Layout:
    """One `Layout` per parameter list, given as tuples of each `Param`'s fields: a fit's layout is
    then the one its earlier fits used, found equal by identity where the problem's static fields
    are compared (each jitted call's dispatch; `_box`, `_entries`) rather than by comparing its
    `Param`s (16 such hashes and compares in a first fit: ~100 us); the list is hashed and compared
    here as plain tuples, its Params made only for a new one (a dataclass's hash and == are Python)."""
    return Layout(tuple(Param(*p) for p in params))


def scene_value(scene, param: Param, textures=None) -> np.ndarray:
    """The parameter's value in the scene (grey: the mean of the RGB triple), shape (size,); a
    texture's from `textures` (material name -> (H_t, W_t, 3) image, row 0 at the top)."""
    if param.shape is not None:
        image = np.asarray(textures[scene.material_names[param.index]], np.float64)
        return np.flipud(image).reshape(-1)
    if param.kind == "intensity":
        raw = scene.lights[param.index].intensity
    else:
        raw = getattr(list(scene.materials.values())[param.index], param.kind)
    raw = np.asarray(raw, np.float64).reshape(-1)
    return raw if param.size == raw.size else np.full(param.size, raw.mean())


def public_value(param: Param, value) -> float | list | np.ndarray:
    """A value as the scene file writes it: an RGB list for RGB kinds, a float for scalars, and an
    (H_t, W_t, 3) float32 image (row 0 at the top, as `load_texture`) for a texture."""
    value = np.asarray(value, np.float64).reshape(-1)
    if param.shape is not None:
        return np.flipud(value.reshape(param.shape + (3,))).astype(np.float32)
    if param.rgb:
        return (value if value.size == 3 else np.repeat(value, 3)).tolist()  # (python floats)
    return float(value[0])


def apply_init(scene, materials, init):
    """The scene with the starting values `init` written in: keys "kind" (one fitted material),
    "material.kind" or "lights[i].intensity"; values a number or an RGB triple."""
    if init is None:
        return scene
    if not isinstance(init, dict):
        raise FitError(f"init: expected a dict of name -> value, got {type(init).__name__}")
    mats, lights = dict(scene.materials), list(scene.lights)
    for key, value in init.items():
        where = f"init[{key!r}]"
        if not isinstance(key, str):
            raise FitError(f"{where}: names are strings")
        if KINDS.get(key.rpartition(".")[2], KINDS["ka"]).texels:
            continue  # a texture's start: `texels.texture_starts`
        try:
            array = np.asarray(value, np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise FitError(f"{where}: expected a number or an RGB triple, got {value!r}") from None
        if array.size not in (1, 3) or not np.all(np.isfinite(array)):
            raise FitError(f"{where}: expected a finite number or RGB triple, got {array.tolist()}")
        rgb = tuple(np.broadcast_to(array, (3,)).tolist())
        try:
            if (match := LIGHT_PARAM.match(key)) is not None:
                i = int(match.group(1))
                if i >= len(lights):
                    raise FitError(f"{where}: the scene has {len(lights)} light(s)")
                lights[i] = dataclasses.replace(lights[i], intensity=rgb)
                continue
            head, _, kind = key.rpartition(".")
            name = head or (materials[0] if len(materials) == 1 else None)
            if kind not in KINDS or kind == "intensity" or name not in materials:
                raise FitError(f"{where}: expected 'kind' (one fitted material), 'material.kind' or "
                               f"'lights[i].intensity'; fitted materials: {', '.join(materials)}")
            if not KINDS[kind].rgb and array.size != 1:
                raise FitError(f"{where}: {kind} is one number, got {array.tolist()}")
            mats[name] = dataclasses.replace(mats[name], **{kind: rgb if KINDS[kind].rgb else float(array[0])})
        except FitError:
            raise
        except DifflabError as exc:  # the scene's own validation names the field
            raise FitError(f"{where}: {exc}") from None
    return dataclasses.replace(scene, materials=mats, lights=tuple(lights))
