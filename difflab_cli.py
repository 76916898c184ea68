"""The `difflab` console command's entry point (pyproject's [project.scripts]).

It lives outside the `difflab` package so that it runs before the package is imported (~0.3 s of
numpy, the scene code and the batch API): a Ctrl-C during those imports also ends with the one line
`difflab: interrupted` and exit 130, not a traceback; one that an import's gc callback swallowed is
passed on to `difflab.cli.main`, which then stops at once (docs/cli.md, exit codes)."""

import signal
import sys


def main(argv=None) -> int:
    caught = []

    def on_sigint(signum, frame):
        caught.append(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)
    try:
        from difflab.cli import main as run

        return run(argv, interrupted=bool(caught))
    except KeyboardInterrupt:  # before difflab.cli took over: during the imports
        print("difflab: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
