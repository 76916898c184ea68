"""The `difflab` console command's entry point (pyproject's [project.scripts]).

It lives outside the `difflab` package so that it runs before the package is imported (~0.3 s of
numpy, the scene code and the batch API): a Ctrl-C during those imports is noted, not raised (a
KeyboardInterrupt inside an extension module's initialisation can abort the process), and
`difflab.cli.main` then stops at once with the one line `difflab: interrupted` and exit 130
(docs/cli.md, exit codes)."""

import signal
import sys


def main(argv=None) -> int:
    caught = []
    signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    from difflab.cli import main as run

    return run(argv, interrupted=caught)  # (read after difflab.cli's handler is in place)


if __name__ == "__main__":
    sys.exit(main())
