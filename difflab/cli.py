"""The `difflab` command line. Exit codes: 0 success, 1 internal error, 2 invalid input, 3 a fit
that did not converge (results still written)."""

from __future__ import annotations

import argparse
import sys
import traceback

from .errors import DifflabError

EXIT_OK, EXIT_INTERNAL, EXIT_INVALID, EXIT_NOT_CONVERGED = 0, 1, 2, 3


def build_parser() -> argparse.ArgumentParser:
    from . import commands

    parser = argparse.ArgumentParser(prog="difflab", description="A differentiable shading lab.")
    parser.add_argument("--version", action="version", version="difflab 0.1.0")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_parser in commands.PARSERS:
        add_parser(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or EXIT_OK)
    except DifflabError as exc:
        print(f"difflab: error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    except KeyboardInterrupt:
        print("difflab: interrupted", file=sys.stderr)
        return EXIT_INTERNAL
    except Exception:  # an internal error: show where, so it can be reported
        traceback.print_exc()
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
