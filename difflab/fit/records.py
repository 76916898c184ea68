"""A fit's views (`View`: one target and what it was seen with), and what a fit keeps of each view
with its compiled scene, so that fitting the same view again renders nothing and cuts nothing again.

A fit renders each view once -- its G-buffer or its ray tree (`setup.Setup._record`) -- and cuts
the image model's arrays out of it for the pixels it uses. Neither depends on the start values nor
on the target:

- the record depends on the compiled scene, the device and the view: its camera, render settings,
  objects, ambient, background and fog, each light but its intensity, and each material but the
  coefficients the image model evaluates afresh (ka, kd, ks, n, m, f0; kr, kt and absorption stay
  in the key: they shape the ray tree and transparent shadows) -- `view_key`;
- the model arrays, in addition, on the pixels used (masks, weights, the fitted materials), the
  precision and the fitted textures (a texel fit cuts its model afresh).

So a fit of a `CompiledScene` keeps, in `CompiledScene.built` (shared by its `with_scene` copies),
the records of its latest KEPT_VIEWS views, with the influence maps found on them and the image
models of their latest KEPT_MODELS pixel sets; a fit of a plain scene keeps no view. The device
copies of a problem's small arrays (lights, material table, indices) are kept process-wide by the
values they are made of (`DEVICE_COPIES`, `setup.Setup._problem`): they depend on no view, and any
fit with the same values uses them -- the first fit of another view or scene too.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, fields
from functools import cache, cached_property

import numpy as np

from .problem import carved, take_rows, to_device
from .targets import in_channels

KEPT_VIEWS = 4
KEPT_MODELS = 2  # per view
KEPT_ARRAYS = 8  # sets of device copies of small arrays (a fit's: its lights' and its problem's others)
EVALUATED = frozenset(("ka", "kd", "ks", "n", "m", "f0"))  # what the image models evaluate afresh
UNPLACED = frozenset(("intensity",))  # a light's fields that the record does not depend on
STORE = "fit views"  # the key in CompiledScene.built


def view_key(view_scene, device: str) -> tuple:
    """What a view's record depends on, as a tuple compared with == (see the module docstring)."""
    materials = tuple((name, tuple(getattr(mat, f) for f in _names(type(mat), EVALUATED)))
                      for name, mat in view_scene.materials.items())
    lights = tuple(tuple(getattr(light, f) for f in _names(type(light), UNPLACED)) for light in view_scene.lights)
    return (device, view_scene.camera, view_scene.render, tuple(view_scene.objects), view_scene.ambient,
            view_scene.background, view_scene.fog, materials, lights)


@cache
def _names(record: type, left_out: frozenset) -> tuple:
    """The names of a dataclass's fields but `left_out`, in order (`dataclasses.fields`: ~1 us a call)."""
    return tuple(f.name for f in fields(record) if f.name not in left_out)


class KeptView:
    """One view's record (a `GBuffer` or `RayTree`, never written to), the pixels its parameters
    influence (by what is fitted) and the image models cut from it (by pixels used and precision)."""

    def __init__(self, record):
        self.record = record
        self._lock = threading.Lock()
        self._touched: dict = {}
        self._pixels = None  # (used, its flat indices) of the pixel set found last, read-only
        self._models: list = []  # [(key, used, model)], the latest first

    def touched(self, key, find) -> np.ndarray:
        """The influence map for `key` (what is fitted), found by `find()` on first use."""
        with self._lock:
            found = self._touched.get(key)
        if found is None:
            found = find()
            with self._lock:
                self._touched[key] = found
        return found

    def pixels(self, used: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(used, np.flatnonzero(used)) for the pixels `used` (H, W) bool: the kept pair, read-only,
        when the pixel set found last is the same (a fit of the view again with its mask: a compare,
        ~1/4 of flatnonzero's time, and `model` then finds its model by identity)."""
        with self._lock:
            kept = self._pixels
        if kept is not None and np.array_equal(kept[0], used):
            return kept
        found = (used, np.flatnonzero(used))
        for array in found:
            array.setflags(write=False)
        with self._lock:
            self._pixels = found
        return found

    def model(self, key, used: np.ndarray, build):
        """The image model for the pixels `used` (H, W) bool and `key` (method, precision, device), cut
        by `build()` on first use."""
        with self._lock:
            for kept_key, kept_used, model in self._models:
                if kept_key == key and (kept_used is used or np.array_equal(kept_used, used)):
                    return model
        model = build()
        with self._lock:
            self._models.insert(0, (key, used, model))
            del self._models[KEPT_MODELS:]
        return model


@dataclass(frozen=True)
class View:
    """One target and what it was seen with. image (H, W, 3): the target as given (a private copy,
    in its own float precision; `target`: float64, 0 outside the mask and where not finite); mask
    (H, W) bool; weighting (H, W, 3) >= 0, 0 outside the mask, or None: 1 inside the mask (`weight`:
    either as an image); ceiling: where its values clip (inf: nowhere); step: its samples' step (1 /
    255 from an 8-bit file, 1 / 65535 from a 16-bit one, 0 for float data) and gamma (the file's
    transfer, None for sRGB: `io.code_step` gives a value's quantisation, `noise.quantisation`); nonfinite: non-finite target values at the pixels used (`left_out`: those elsewhere, which the fit does not read); record: its G-buffer or ray tree;
    scene: the scene of this view; used (H, W) bool: the pixels the fit reads (`pixels`: their flat
    indices, in order; `values` and `weights`: the target's and the weight's (U, 3) float64 rows
    there, `zeros`: values == 0, `black` (U,): 0 in every channel, `floor`: the zeros that weigh in --
    each computed once, on first use, or handed over by `Setup._ceiling`,
    which took them already); kept: the `KeptView` of the record when it is kept with the compiled
    scene, else None; touched (H, W) bool: the pixels the fitted parameters influence. The
    whole-image `target` and `weight` are formed only when asked for: a fit reads the used pixels'
    rows."""

    image: np.ndarray
    mask: np.ndarray
    weighting: np.ndarray | None
    ceiling: float
    step: float
    gamma: float | None
    nonfinite: int
    record: object
    scene: object
    used: np.ndarray
    kept: KeptView | None = None
    touched: np.ndarray | None = None
    left_out: int = 0

    def replaced(self, **changes) -> View:
        """`dataclasses.replace(self, **changes)` without its checks and `__init__` (~15 us of a first
        fit's setup); the cached properties stay behind."""
        out = object.__new__(View)
        out.__dict__.update({name: self.__dict__[name] for name in VIEW_FIELDS}, **changes)
        return out

    @cached_property
    def target(self) -> np.ndarray:
        inside = np.isfinite(self.image) & self.mask[..., None]
        return np.where(inside, self.image, np.float64(0.0))

    @cached_property
    def weight(self) -> np.ndarray:
        if self.weighting is not None:
            return self.weighting
        return in_channels(self.mask).astype(np.float64)

    @cached_property
    def pixels(self) -> np.ndarray:
        return np.flatnonzero(self.used)

    @cached_property
    def values(self) -> np.ndarray:
        return target_values(self.image, self.used, self.nonfinite)

    @cached_property
    def zeros(self) -> np.ndarray:
        return self.values == 0.0

    @cached_property
    def black(self) -> np.ndarray:
        zeros = self.zeros
        return zeros[:, 0] & zeros[:, 1] & zeros[:, 2]

    @cached_property
    def floor(self) -> np.ndarray:
        """The used entries whose target value is 0 and weight > 0, as flat indices into the
        channel-major planes (3, H, W) of the residual images (where `clipping.clipped_band` reads
        the model); none when a used value lies below 0 (the target is not clipped at 0)."""
        zero = self.zeros if self.weighting is None else self.zeros & (self.weights > 0)
        if self.values.min(initial=0.0) < 0.0:
            return np.zeros(0, np.intp)
        return np.concatenate([self.pixels[zero[:, c]] + c * self.used.size for c in range(3)])  # (np.nonzero: 2.5x)

    @cached_property
    def weights(self) -> np.ndarray:
        if self.weighting is None:
            return np.ones((self.pixels.size, 3))
        return used_rows(self.weighting, self.used)

    @cached_property
    def entries(self) -> np.ndarray:
        """(U, 3) bool: the residual entries of the used pixels that weigh in (weight > 0)."""
        if self.weighting is None:
            return np.ones((self.pixels.size, 3), bool)
        return self.weights > 0

    @cached_property
    def counted(self) -> np.ndarray:
        """(U, 3) bool: the entries a fit counts -- weight > 0 and the target below its ceiling (an
        entry at the ceiling is censored: the model need only reach it)."""
        return self.entries & (self.values < self.ceiling) if np.isfinite(self.ceiling) else self.entries


VIEW_FIELDS = tuple(f.name for f in fields(View))


def target_values(image, used, nonfinite: int) -> np.ndarray:
    """`View.values`: the (U, 3) float64 rows of a target `image` at the pixels `used` (H, W), its
    `nonfinite` values there (a count) set to 0."""
    values = used_rows(image, used, np.float64)
    if nonfinite:
        values[~np.isfinite(values)] = 0.0
    return values


def used_rows(image, used, dtype=None) -> np.ndarray:
    """`take_pixels` at the pixels `used` (H, W) bool (`View.pixels`): a boolean selection of the
    image's pixels as whole items (3 values each), which copies each run of used pixels at once,
    then moved into a buffer on a 64-byte boundary in `dtype` (default: the image's) -- 0.03 ms less
    than the take of a first fit's target (24.7k of 65.5k pixels, float32 -> float64: 0.125 ->
    0.096 ms, medians of 40 first fits)."""
    image = np.ascontiguousarray(image)
    rows = image.reshape(-1).view(np.dtype((np.void, 3 * image.itemsize)))[used.reshape(-1)]
    out = carved([(rows.size, 3)], [image.dtype if dtype is None else dtype])[0]
    out[...] = rows.view(image.dtype).reshape(-1, 3)
    return out


def take_pixels(image, pixels, dtype=None) -> np.ndarray:
    """(U, 3) rows of an (H, W, 3) image at flat pixel indices, in `dtype` (default: the image's;
    `problem.take_rows`: moved to the device without a copy)."""
    return take_rows(image.reshape(-1, 3), pixels, dtype)


class ViewStore:
    """The latest KEPT_VIEWS `KeptView`s of one compiled scene by `view_key`."""

    def __init__(self):
        self._lock = threading.Lock()
        self._views: list = []  # [(key, KeptView)], the latest first

    def get(self, key) -> KeptView | None:
        with self._lock:
            for i, (kept_key, view) in enumerate(self._views):
                if kept_key == key:
                    self._views.insert(0, self._views.pop(i))
                    return view
        return None

    def put(self, key, view: KeptView) -> KeptView:
        with self._lock:
            self._views = [(key, view)] + [(k, v) for k, v in self._views if k != key][:KEPT_VIEWS - 1]
        return view

    def __len__(self):
        return len(self._views)


class DeviceCopies:
    """The device copies of the KEPT_ARRAYS sets of small arrays used last, by what they are made of."""

    def __init__(self):
        self._lock = threading.Lock()
        self._arrays: list = []  # [(key, device arrays)], the latest used first

    def kept(self, key, host):
        """The device copies (`to_device`, one dispatch) of the pytree of numpy arrays `host()` for
        `key`, a value compared with == that determines them (device arrays are immutable): the
        copies kept for an equal key among the KEPT_ARRAYS used last, else `host()` formed and moved
        now (one jitted dispatch costs some 8 us a leaf)."""
        with self._lock:  # (each kept key compared once)
            found = next((i for i, (kept_key, _) in enumerate(self._arrays) if kept_key == key), None)
            if found is not None:  # used now: the last to be let go
                self._arrays.insert(0, self._arrays.pop(found))
                return self._arrays[0][1]
        kept = to_device(host())
        with self._lock:
            self._arrays = [(key, kept)] + self._arrays[:KEPT_ARRAYS - 1]
        return kept


DEVICE_COPIES = DeviceCopies()  # one for the process (device arrays are immutable)


def view_store(compiled) -> ViewStore | None:
    """The compiled scene's store of kept views (None without a compiled scene)."""
    if compiled is None:
        return None
    store = compiled.built.get(STORE)  # (an empty store is falsy: it has a length)
    return compiled.built.setdefault(STORE, ViewStore()) if store is None else store
