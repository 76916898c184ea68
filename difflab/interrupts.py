"""Ctrl-C on the command line, never lost: a SIGINT ends the command with exit 130 wherever it lands.

Python's own handler raises KeyboardInterrupt wherever the main thread happens to be, and where that
is a gc callback (JAX's `_xla_gc_callback`), a `__del__` or a weakref callback, the exception is
printed as "Exception ignored in ..." and dropped: the command ran on, wrote its files and exited 0.
`install` replaces the handler while a command runs: a SIGINT marks the run interrupted and raises
KeyboardInterrupt, and until the command has caught it (`Run.done`) a helper thread makes the
handler run again every REPEAT_S seconds (`_thread.interrupt_main`): where no
KeyboardInterrupt is being handled (the first was swallowed) it raises anew, at the next bytecode
that does not swallow it, and where one is on its way out (cleanup in finally blocks) it lets that
one go on, and inside an import it waits for the import to end (`_importing`); swallowed
KeyboardInterrupts are not printed (`sys.unraisablehook`). The user's own next Ctrl-C is never let
go: it raises also while the first is on its way out, so it breaks a cleanup that blocks (closing a
Dask client whose workers hang). `check` raises for a run that is interrupted, so that no output is
written after a Ctrl-C (`files.uninterrupted`, the writers' guard). Main thread only; stdlib only.
"""

from __future__ import annotations

import _thread
import signal
import sys
import threading
import time

#: Seconds between the repeats of an interrupt the command has not caught yet.
REPEAT_S = 0.05

class Run:
    """One command's interrupt state: `interrupted` once a SIGINT arrived, `armed` once the command
    is inside the block that catches KeyboardInterrupt, `done` once it caught it or ended (each set by
    a plain attribute store, which runs no handler in between). `repeat_sent`: a repeat not handled
    yet, which tells the repeats from the user's SIGINTs (both call `on_sigint`)."""

    def __init__(self):
        self.interrupted = False
        self.armed = False  # set by the command once it can catch KeyboardInterrupt: till then noted only
        self.done = False
        self.repeater: threading.Thread | None = None
        self.repeat_sent = False
        self.owed = False  # a user's SIGINT, not yet raised (it came inside an import)

    def on_sigint(self, signum, frame):
        repeat, self.repeat_sent = self.repeat_sent, False
        if not self.armed:
            self.interrupted = True
            return
        if self.done:
            return
        self.owed = self.owed or not repeat
        if _unwinding() and not self.owed:
            return  # a repeat while the KeyboardInterrupt is on its way out (a finally, an __exit__): let it
        self.interrupted = True
        if self.repeater is None:
            self.repeater = threading.Thread(target=self._repeat, name="difflab-sigint", daemon=True)
            self.repeater.start()
        if _importing(frame):
            return  # raised by a repeat once the import is done (see `_importing`)
        self.owed = False
        raise KeyboardInterrupt

    def _repeat(self) -> None:
        """Repeat the interrupt while the command has not caught it, except while the main thread
        handles one: a repeat it does not run at once (blocked in a wait that only a signal breaks)
        would be taken with the user's next SIGINT for one repeat, and that SIGINT let go."""
        main = threading.main_thread().ident
        while not self.done:
            time.sleep(REPEAT_S)
            if not (self.done or _unwinding(main)):
                self.repeat_sent = True
                _thread.interrupt_main(signal.SIGINT)


def _unwinding(thread: int | None = None) -> bool:
    """Whether the main thread (where handlers run) is handling a KeyboardInterrupt now: in an except
    or finally block or an __exit__ it runs through, directly or as the context of a later error.
    `thread`: the main thread's id, where another thread asks (`sys._current_exceptions`)."""
    error = sys.exc_info()[1] if thread is None else sys._current_exceptions().get(thread)
    if isinstance(error, tuple):  # Python 3.11 gives exc_info triples, 3.12 the exceptions
        error = error[1]
    while error is not None:
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__context__
    return False


def _importing(frame) -> bool:
    """Whether `frame` runs inside an import (a frame of importlib's bootstrap below it). A
    KeyboardInterrupt raised there can land in an extension module's initialisation calling back into
    Python, which aborts the process: jaxlib's did (SIGABRT, SIGSEGV) in 3 of 10 runs interrupted
    0.5-0.65 s into `difflab fit`. The interrupt waits for the import to finish (a second or two)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib._bootstrap"):
            return True
        frame = frame.f_back
    return False


_RUN: Run | None = None


def install():
    """Handle SIGINT as above until the returned `restore()` is called; returns (run, restore). In a
    thread other than the main one nothing is installed (signals reach the main thread only)."""
    global _RUN
    run = Run()
    if threading.current_thread() is not threading.main_thread():
        return run, lambda: None
    previous_run, previous_handler, previous_hook = _RUN, signal.getsignal(signal.SIGINT), sys.unraisablehook

    def hook(unraisable):
        if not (run.interrupted and issubclass(unraisable.exc_type, KeyboardInterrupt)):
            previous_hook(unraisable)

    def restore():
        global _RUN
        run.done = True
        signal.signal(signal.SIGINT, previous_handler)
        sys.unraisablehook = previous_hook
        _RUN = previous_run

    _RUN = run
    sys.unraisablehook = hook
    signal.signal(signal.SIGINT, run.on_sigint)
    return run, restore


def check() -> None:
    """Raise KeyboardInterrupt if the running command was interrupted and has not caught it yet."""
    if _RUN is not None and _RUN.interrupted and not _RUN.done:
        raise KeyboardInterrupt
