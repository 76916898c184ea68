"""Files at the boundary: path arguments checked, regular files read within a size limit, and
outputs written atomically -- a temporary beside its target, renamed onto it once whole (one
output: `atomic_path`; outputs that belong together: `write_together`) --, under the one overwrite
rule of every command (`refuse_overwrite`). `difflab.io` re-exports the writers (its public API).
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

from .errors import DifflabError, OutputError, WriteError
from .interrupts import check
from .limits import short_path, shorten

_UMASK = os.umask(0o022)  # read the process umask once (setting it is not thread-safe), then restore it
os.umask(_UMASK)

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


#: How the overwrite refusal names its way out: the command line's option, the Python keyword.
FORCE_ADVICE = {"cli": "use --force to overwrite", "python": "pass force=True to overwrite"}


def refuse_overwrite(*paths, force: bool = False, caller: str = "cli") -> None:
    """The one rule of every command: an output that exists (a file, or a folder with anything in
    it) is not overwritten unless `force`. Raises OutputError naming the first such path and, in the
    `caller`'s words (FORCE_ADVICE), how to overwrite; call it before any work, so a refused command
    writes nothing."""
    for path in map(Path, paths):
        taken = any(path.iterdir()) if path.is_dir() else path.exists()
        if taken and not force:
            raise OutputError(f"{short_path(path)}: exists; {FORCE_ADVICE[caller]}")


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
    check()  # a command interrupted before (its KeyboardInterrupt swallowed somewhere) writes nothing
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


def write_together(writers: dict, *, sweep: bool = True) -> None:
    """Write outputs that belong together (a fitted scene and its report, an image and its linear
    copy), all or none: `writers` maps each path to a callable writing a temporary path
    (`atomic_path`); the temporaries are renamed onto their paths once every one is written. Ctrl-C
    and SIGTERM are held meanwhile (`uninterrupted`); a writer failing midway leaves every old file
    as it was, its error naming its path. (A rename failing after another one succeeded -- two
    renames within their folders, which fail only where the folder turned read-only between the
    writes and the renames -- leaves the earlier file new.) `sweep`: as `atomic_path`'s."""
    with uninterrupted(), contextlib.ExitStack() as stack:
        for path, write in writers.items():
            write(stack.enter_context(atomic_path(path, sweep=sweep)))


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


def write_json(path: Path, data) -> None:
    """Write `data` as indented JSON into `path` as it stands (a temporary: `write_together`)."""
    path.write_text(json.dumps(data, indent=2) + "\n")


def write_json_atomic(path: str | os.PathLike, data, *, sweep: bool = True) -> None:
    """Write `data` as indented JSON, atomically (`atomic_path`)."""
    with atomic_path(path, sweep=sweep) as tmp:
        write_json(tmp, data)
