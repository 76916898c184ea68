"""Image files at the boundary: sRGB <-> linear, PNG/NPY load and save, atomic writes.

Images inside difflab are numpy float32 arrays (H, W, 3) of linear RGB, row 0 at the top.
sRGB encoding happens only here, when an 8-bit file is written or read.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import signal
import stat
import tempfile
import threading
from pathlib import Path
from typing import NamedTuple

import numpy as np
from PIL import Image

from . import limits
from .errors import DifflabError, OutputError, WriteError
from .limits import short_path, shorten
from .picture import read_picture, sample_depth, why

_UMASK = os.umask(0o022)  # read the process umask once (setting it is not thread-safe), then restore it
os.umask(_UMASK)


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 decoding: c/12.92 for c <= 0.04045, else ((c + 0.055)/1.055)^2.4 (c in [0, 1])."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 encoding of linear values clamped to [0, 1]."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


TMP_MARK = ".tmp"  # a temporary is .<name>.<pid>.<random><TMP_MARK><suffix>, beside its target
_LIVE: set[str] = set()  # temporaries this process is writing now
_PREVIOUS: dict = {}  # signal -> the handler before ours


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def remove_stale_temps(path: str | os.PathLike) -> int:
    """Remove the temporaries that killed writers of `path` left behind (their process is gone);
    returns how many were removed."""
    path = Path(path)
    removed = 0
    for stale in path.parent.glob(f".{glob.escape(path.name)}.*{TMP_MARK}{glob.escape(path.suffix)}"):
        pid = stale.name[len(path.name) + 2:].split(".", 1)[0]
        if not pid.isdigit() or str(stale) in _LIVE or (int(pid) != os.getpid() and _pid_alive(int(pid))):
            continue
        with contextlib.suppress(OSError):
            stale.unlink()
            removed += 1
    return removed


def _remove_live_and_die(signum, frame):
    """On SIGTERM / SIGHUP: delete this process's temporaries, then die of the signal as before."""
    for name in list(_LIVE):
        with contextlib.suppress(OSError):
            os.remove(name)
    signal.signal(signum, _PREVIOUS[signum])
    os.kill(os.getpid(), signum)


def _install_signal_cleanup() -> None:
    """Remove temporaries on SIGTERM and SIGHUP where nobody else handles them (SIGKILL cannot be
    caught: the next write of the same path removes what it leaves)."""
    if _PREVIOUS or threading.current_thread() is not threading.main_thread():
        return
    for signum in (signal.SIGTERM, signal.SIGHUP):
        previous = signal.getsignal(signum)
        _PREVIOUS[signum] = previous
        if previous == signal.SIG_DFL:
            signal.signal(signum, _remove_live_and_die)


def file_path(path, what: str = "path", error: type[DifflabError] = DifflabError) -> Path:
    """`path` (a str or os.PathLike naming a file) as a Path; `error` naming `what` otherwise."""
    if isinstance(path, os.PathLike):
        path = os.fspath(path)
    if not isinstance(path, str) or not path or "\x00" in path:
        raise error(f"{what}: expected a file path, got {shorten(path)}")
    return Path(path)


def check_output_path(path: str | os.PathLike, what: str = "output", create_parent: bool = False,
                      probe: bool = False) -> Path:
    """`path` as a file to write: not an existing folder; its parent a folder (made when
    `create_parent`, else it must exist) that takes new files, no file used as a folder on the way.
    Raises DifflabError naming `what` and the path, before any work is done. `probe`: test the
    folder by creating (and removing) a file in it, as os.access cannot: it says yes to root on a
    read-only or virtual file system (/sys)."""
    path = file_path(path, what)
    if not path.name or path.is_dir():
        raise DifflabError(f"{what}: {short_path(path)} is a folder; give a file name")
    if path.exists() and not path.is_file():  # a device, FIFO or socket is never replaced by a file
        raise DifflabError(f"{what}: {short_path(path)} exists and is not a regular file")
    parent = path.parent
    for folder in (parent, *parent.parents):
        if folder.exists() or folder.is_symlink():
            if not folder.is_dir():
                raise DifflabError(f"{what}: {short_path(folder)} is a file, not a folder")
            break
    if not parent.is_dir():
        if not create_parent:
            raise DifflabError(f"{what}: folder {short_path(parent)} does not exist")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DifflabError(f"{what}: cannot make folder {short_path(parent)} ({exc.strerror})") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise WriteError(f"{what}: folder {short_path(parent)} is not writable")
    if probe:
        try:
            fd, name = tempfile.mkstemp(prefix=".difflab-probe.", dir=parent)
        except OSError as exc:
            raise WriteError(f"{what}: cannot write in folder {short_path(parent)} ({exc.strerror or exc})") from None
        os.close(fd)
        os.remove(name)
    return path


def add_force(parser) -> None:
    """--force: the command-line flag of the one overwrite rule (`refuse_overwrite`), the same in every command."""
    parser.add_argument("--force", action="store_true", help="overwrite existing output files")


def refuse_overwrite(*paths, force: bool = False) -> None:
    """The one rule of every command: an output that exists (a file, or a folder with anything in
    it) is not overwritten unless `force`. Raises OutputError naming the first such path; call it
    before any work, so a refused command writes nothing."""
    for path in map(Path, paths):
        taken = any(path.iterdir()) if path.is_dir() else path.exists()
        if taken and not force:
            raise OutputError(f"{short_path(path)}: exists; use --force to overwrite")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, sweep: bool = True):
    """Yield a temporary path in the folder of `path` (made if missing); rename it onto `path` only
    if the block succeeds.

    A writer that fails midway leaves the old file (if any) untouched and no temporary behind; one
    killed by SIGTERM / SIGHUP removes its temporary; one killed by SIGKILL leaves it, and the next
    write of the same path removes it (`remove_stale_temps`, a listing of the folder). `sweep=False`
    skips that listing, for a writer that swept the folder itself once before writing many files into
    it (a batch's output folder: N writes, N listings of up to N files, took ~10 ms a file at 5000).
    """
    path = check_output_path(path, create_parent=True)
    if sweep:
        remove_stale_temps(path)
    _install_signal_cleanup()
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=TMP_MARK + path.suffix, dir=path.parent)
    except OSError as exc:
        raise _write_error(path, exc) from exc
    _LIVE.add(tmp)
    try:
        os.close(fd)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the file the usual permissions
        yield Path(tmp)
        os.replace(tmp, path)
    except WriteError:
        raise
    except OSError as exc:  # a full disk, a quota, an I/O error: the file is not written
        raise _write_error(path, exc) from exc
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
        _LIVE.discard(tmp)


@contextlib.contextmanager
def uninterrupted():
    """Hold Ctrl-C (SIGINT) and SIGTERM back until the block is done, so that the files it writes are
    all written (a pair of outputs: both renamed, not one) and no temporary is left half-made; the
    first signal caught is delivered after it (KeyboardInterrupt for SIGINT), also when the block
    raised. (Only the main thread receives signals; elsewhere the block runs as it is.)"""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _install_signal_cleanup()  # before the handlers are replaced: the cleanup must see the real ones
    caught = []
    previous = {number: signal.signal(number, lambda number, frame: caught.append(number))
                for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        if caught:
            signal.raise_signal(caught[0])


def write_together(writers: dict) -> None:
    """Write outputs that belong together (a fitted scene and its report, an image and its linear
    copy), all or none: `writers` maps each path to a callable writing a temporary path
    (`atomic_path`); the temporaries are renamed onto their paths once every one is written. Ctrl-C
    and SIGTERM are held meanwhile (`uninterrupted`); a writer failing midway leaves every old file
    as it was, its error naming its path. (A rename failing after another one succeeded -- two
    renames within their folders, which fail only where the folder turned read-only between the
    writes and the renames -- leaves the earlier file new.)"""
    with uninterrupted(), contextlib.ExitStack() as stack:
        for path, write in writers.items():
            write(stack.enter_context(atomic_path(path)))


def _write_error(path: Path, exc: OSError) -> WriteError:
    """WriteError naming `path` and why the OSError `exc` stopped writing it (its errno kept)."""
    error = WriteError(f"{short_path(path)}: cannot write ({exc.strerror or ' '.join(str(exc).split())}); not written")
    error.errno = exc.errno
    return error


def read_regular_file(path: str | os.PathLike, max_bytes: int, error: type[DifflabError] = DifflabError,
                      what: str = "file") -> bytes:
    """The bytes of `path`, which must be a regular file of at most `max_bytes` (devices such as
    /dev/zero, FIFOs and folders are refused at once, without blocking). Raises `error` naming it."""
    name = short_path(file_path(path, what, error))
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise error(f"{name}: {what} not found") from None
    except (OSError, ValueError) as exc:
        raise error(f"{name}: cannot open ({getattr(exc, 'strerror', None) or exc})") from None
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode) or info.st_size > max_bytes:
        os.close(fd)
        raise error(f"{name}: {what} is not a regular file" if not stat.S_ISREG(info.st_mode) else
                    f"{name}: file is {info.st_size} bytes, over the limit of {max_bytes}")
    with os.fdopen(fd, "rb") as f:
        try:
            data = f.read(max_bytes + 1)
        except OSError as exc:
            raise error(f"{name}: cannot read ({exc.strerror})") from None
    if len(data) > max_bytes:
        raise error(f"{name}: file is over the limit of {max_bytes} bytes")
    return data


def write_text_atomic(path: str | os.PathLike, text: str, *, sweep: bool = True) -> None:
    """Write a text file atomically (`atomic_path`)."""
    with atomic_path(path, sweep=sweep) as tmp:
        tmp.write_text(text)


def write_json_atomic(path: str | os.PathLike, data, *, sweep: bool = True) -> None:
    """Write `data` as indented JSON, atomically (`atomic_path`)."""
    write_text_atomic(path, json.dumps(data, indent=2) + "\n", sweep=sweep)


def _as_image(image) -> np.ndarray:
    """A float32 (H, W, 3 or 4) array from a 2-D or 3-D array of real numbers; DifflabError otherwise."""
    array = image if isinstance(image, np.ndarray) else np.asarray(image)
    if array.dtype.kind not in IMAGE_DTYPE_KINDS:
        raise DifflabError(f"image: must hold real numbers (bool, int, uint or float), got dtype {array.dtype}")
    image = array.astype(np.float32)
    if image.ndim == 2:
        image = image[..., None].repeat(3, axis=-1)
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise DifflabError(f"image: expected shape (H, W, 3), got {image.shape}")
    return image


def save_image(path: str | os.PathLike, image, srgb: bool = True) -> Path:
    """Write a linear float image (H, W, 3) atomically.

    `.npy` keeps the linear float32 values exactly. Other suffixes (PNG, ...) are written 8-bit,
    clamped to [0, 1] and sRGB-encoded when `srgb` is true (linear 8-bit otherwise).
    Non-finite pixels are not hidden: they raise, with their count.
    """
    path = file_path(path, "image")
    with atomic_path(path) as tmp:
        write_image(tmp, image, srgb, name=path)
    return path


def write_image(path: Path, image, srgb: bool = True, name=None) -> None:
    """`save_image`'s writing, into `path` as it stands (a temporary: `atomic_path`,
    `write_together`), in the format its suffix names; errors name `name` (default: `path`)."""
    name = path if name is None else name
    image = _as_image(image)
    if path.suffix.lower() == ".npy":
        with open(path, "wb") as f:  # (np.save(name) appends .npy to "x.NPY")
            np.save(f, image)
        return
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise DifflabError(f"{name}: image has {bad} non-finite values; not written")
    encoded = linear_to_srgb(image) if srgb else np.clip(image, 0.0, 1.0)
    pixels = np.round(encoded * 255.0).astype(np.uint8)
    Image.fromarray(pixels).save(path, format=Image.registered_extensions().get(path.suffix.lower(), "PNG"))


#: numpy dtype kinds an image file may hold: bool, signed and unsigned integers, real floats.
IMAGE_DTYPE_KINDS = "biuf"


def read_npy(path: Path) -> np.ndarray:
    """An image array from a .npy file, as stored: header checked (numeric real dtype, image shape, size within
    the memory budget, file long enough) before the data is read; pickles are never loaded."""
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                np.lib.format.read_array_header_2_0
            shape, _, dtype = read_header(f)
            data_start = f.tell()
    except Exception as exc:  # numpy raises ValueError, OSError, EOFError, SyntaxError on bad headers
        raise DifflabError(f"{path}: not a valid .npy file ({why(exc)})") from None
    if dtype.hasobject or dtype.kind not in IMAGE_DTYPE_KINDS or dtype.fields is not None or dtype.subdtype:
        raise DifflabError(f"{path}: image array must hold real numbers (bool, int, uint or float), got dtype {dtype}")
    if len(shape) not in (2, 3) or (len(shape) == 3 and shape[-1] not in (3, 4)) or 0 in shape:
        raise DifflabError(f"{path}: expected an image array of shape (H, W), (H, W, 3) or (H, W, 4), got {shape}")
    limits.require_image(shape[1], shape[0], str(path), limits.IMAGE_LOAD_BYTES)
    needed = data_start + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if path.stat().st_size < needed:
        raise DifflabError(f"{path}: .npy file is truncated ({path.stat().st_size} of {needed} bytes)")
    try:
        return np.load(path, allow_pickle=False)
    except Exception as exc:
        raise DifflabError(f"{path}: cannot read .npy file ({why(exc)})") from None


def refuse_code_values(dtype, name: str) -> None:
    """The one rule for integer image data (an integer .npy file, an integer array given as a fit's
    target): its values are a file's code values, not linear light, and are refused -- DifflabError
    naming `name`, saying how to decode them for their dtype. Other dtypes pass."""
    dtype = np.dtype(dtype)
    if dtype.kind not in "iu":
        return
    if dtype.itemsize == 1:
        how = "image / 255.0, then difflab.io.srgb_to_linear() of that if sRGB-encoded (ordinary 8-bit pictures are)"
    elif dtype.itemsize == 2:
        how = ("image / 65535.0: linear if the source wrote linear samples (POV-Ray File_Gamma=1.0, PNG gAMA 1.0), "
               "else difflab.io.srgb_to_linear() of that")
    else:
        how = "image / (2^bits - 1) for the bits its source wrote, then that source's transfer function"
    raise DifflabError(f"{name}: integer data ({dtype}) are code values, not linear light; give linear floats -- "
                       f"{how} -- or the PNG / TIFF, which difflab decodes")


def sample_bits(path: str | os.PathLike) -> int | None:
    """Bits per sample of an image file as `load_image` reads it: 16 for a 16-bit PNG / TIFF, 8 for other
    pictures, None for .npy (float data). Reads the header only; DifflabError naming the path."""
    path = file_path(path, "image")
    if path.suffix.lower() == ".npy":
        return None
    try:
        with Image.open(path) as im:
            return sample_depth(im)
    except Exception as exc:
        raise DifflabError(f"{short_path(path)}: cannot read image ({why(exc)})") from None


def image_file(path, what: str = "image") -> Path:
    """`path` (an image, mask or texture file to read) as a Path to a regular file, else DifflabError
    naming it and `what` it is."""
    path = file_path(path, what)
    if not path.exists():
        raise DifflabError(f"{short_path(path)}: {what} file not found")
    if path.is_dir():
        raise DifflabError(f"{short_path(path)}: a folder, not {'an' if what[0] in 'aeiou' else 'a'} {what} file")
    if not path.is_file():
        raise DifflabError(f"{short_path(path)}: not a regular file")
    return path


class LoadedImage(NamedTuple):
    """An image file as `read_image` reads it."""
    image: np.ndarray  # linear float32 (H, W, 3): `load_image`
    bits: int | None  # bits per sample: 8 or 16 (its samples' step is 1 / (2^bits - 1)); None for .npy floats
    channels: int  # colour channels the file holds: 1 (a grey PNG / TIFF or 2-D .npy, repeated into 3) or 3


def read_image(path: str | os.PathLike, srgb: bool = True, what: str = "image") -> LoadedImage:
    """`load_image`'s image, with the bits per sample and colour channels of the file, from one read
    of it (its header once). Errors name the path and `what` the file is (an "image", a "texture")."""
    path = image_file(path, what)
    if path.suffix.lower() == ".npy":
        array = read_npy(path)
        refuse_code_values(array.dtype, short_path(path))
        return LoadedImage(_as_image(array)[..., :3].copy(), None, 1 if array.ndim == 2 else 3)
    pixels, gamma, bits, channels = read_picture(path)
    if pixels.dtype == np.uint8 and (not srgb or gamma is None):
        image = (_SRGB_DECODE if srgb else _LINEAR_DECODE)[pixels]  # a 256-entry table: 15 bytes per pixel
    else:
        samples = pixels / float(np.iinfo(pixels.dtype).max)
        if srgb:
            samples = srgb_to_linear(samples) if gamma is None else samples ** (1.0 / gamma)
        image = samples.astype(np.float32)
    return LoadedImage(image, bits, channels)


def load_image(path: str | os.PathLike, srgb: bool = True) -> np.ndarray:
    """Read an image as linear float32 (H, W, 3).

    `.npy` files hold linear values (float or bool dtypes; an alpha channel is dropped; a 2-D array
    is grey, repeated into the 3 channels); an integer .npy holds code values, which are refused
    (`refuse_code_values`: how to decode them); other files are whatever Pillow reads, 8-bit, or
    16-bit PNG / TIFF (all 16 bits kept; a grey file fills the 3 channels), their samples
    s / (2^bits - 1) decoded when `srgb` is true by the file's transfer function: sRGB (IEC
    61966-2-1), unless a PNG declares a gamma g without an sRGB chunk (linear = s^(1/g); g = 1: the
    samples are linear, as POV-Ray writes with File_Gamma=1.0). With `srgb` false the samples are
    read as linear values. Every failure -- missing or not a regular file, bad header, truncated
    data, a pickled or string array, an image over the memory budget (checked from the header
    before decoding) -- raises DifflabError naming the path.
    """
    return read_image(path, srgb).image


_LINEAR_DECODE = (np.arange(256) / 255.0).astype(np.float32)
_SRGB_DECODE = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)
