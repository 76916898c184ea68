"""The `difflab` command line. Exit codes: 0 success, 1 internal error, 2 invalid input, 3 a fit
that did not converge, 4 a fit flagged model_mismatch, 5 a converged fit whose model was not judged
(its noise unknown, or underdetermined; results still written for 3, 4 and 5), 130 interrupted
(Ctrl-C)."""

from __future__ import annotations

import argparse
import os
import sys
import traceback

from . import interrupts
from .errors import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_INVALID, EXIT_OK, DifflabError
from .limits import short_path


#: Arguments naming files a command writes; checked before any work (a folder, a missing folder, a
#: file used as a folder are invalid input). A command whose `output_is_folder` is set writes a folder.
OUTPUT_ARGUMENTS = {"output": "-o/--output", "report": "--report"}


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: `difflab: error: ...` and exit code 2 (no usage block), and
    --help showing every option's default (`(default: X)`) unless its help states it."""

    def add_argument(self, *args, **kwargs):
        action = super().add_argument(*args, **kwargs)
        if action.option_strings and action.default is not None and action.default is not False and \
                action.default != argparse.SUPPRESS and "default" not in (action.help or ""):
            action.help = f"{action.help} (default: %(default)s)" if action.help else "default: %(default)s"
        return action

    def error(self, message):
        command = self.prog.removeprefix("difflab").strip()
        self.exit(EXIT_INVALID, f"difflab: error: {command + ': ' if command else ''}{message}\n")


def check_outputs(args) -> None:
    """Raise DifflabError for an output path that cannot be written (see OUTPUT_ARGUMENTS)."""
    from .files import check_output_path

    for name, flag in OUTPUT_ARGUMENTS.items():
        value = getattr(args, name, None)
        if value is None:
            continue
        if getattr(args, "output_is_folder", False):
            if os.path.exists(value) and not os.path.isdir(value):
                raise DifflabError(f"{flag}: {short_path(value)} is a file, not a folder")
            check_output_path(os.path.join(value, "x"), flag, create_parent=True, probe=True)
        else:
            check_output_path(value, flag, probe=True)


def build_parser() -> argparse.ArgumentParser:
    from . import commands
    from .batch.command import add_parser as add_fit_batch
    from .fit.command import add_parser as add_fit

    parser = Parser(prog="difflab", description="A differentiable shading lab.")
    parser.add_argument("--version", action="version", version="difflab 0.1.0")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_parser in (commands.add_render, commands.add_demo, add_fit, add_fit_batch, commands.add_fractal):
        add_parser(sub)
    return parser


def main(argv=None, *, interrupted=()) -> int:
    """Run the command line; returns its exit code. Ctrl-C is handled by `interrupts.install` for the
    whole run (parsing included): never lost, exit 130. `interrupted`: the SIGINTs that arrived
    before, read once the handler is in place (the console entry point, `difflab_cli`, passes the
    list its own handler fills during the imports, so that none falls between the two)."""
    run, restore = interrupts.install()
    try:
        run.armed = True  # (an attribute store: no handler runs before the try is entered)
        run.interrupted = run.interrupted or bool(interrupted)
        interrupts.check()
        code = run_command(argv)
        interrupts.check()  # a Ctrl-C swallowed at the very end is still an interrupt
        return code
    except KeyboardInterrupt:  # outputs are written atomically: an interrupted write leaves nothing
        run.done = True  # first, by an attribute store: no repeat of the interrupt can be raised after it
        print("difflab: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        run.done = True
        restore()


def run_command(argv) -> int:
    """Parse `argv` and run its command: its exit code, or the one-line error's (EXIT_INVALID), or
    EXIT_INTERNAL with the traceback. KeyboardInterrupt goes to `main`, also from these handlers, and
    so does an error after a Ctrl-C (a library that caught the KeyboardInterrupt raised its own)."""
    try:
        args = build_parser().parse_args(argv)
        check_outputs(args)
        return int(args.func(args) or EXIT_OK)
    except Exception as exc:
        interrupts.check()  # interrupted: exit 130 in `main`, whatever error the interrupt became
        return report_error(exc)


def report_error(exc: Exception) -> int:
    """Print a command's error on stderr and return its exit code: a DifflabError or MemoryError in
    one line (EXIT_INVALID), anything else, an internal error, with its traceback (EXIT_INTERNAL)."""
    if isinstance(exc, DifflabError):
        print(f"difflab: error: {' '.join(str(exc).split())}", file=sys.stderr)  # one line
        return EXIT_INVALID
    if isinstance(exc, MemoryError):  # the budgets (docs/limits.md) should refuse such a request before it starts
        print("difflab: error: out of memory: the request is too big for this machine; lower the image size, "
              "spp or mesh resolution, or DIFFLAB_MEMORY_BUDGET", file=sys.stderr)
        return EXIT_INVALID
    traceback.print_exception(exc)  # an internal error: show where, so it can be reported
    return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
