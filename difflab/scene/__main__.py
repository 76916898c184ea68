"""`python -m difflab.scene [ROOT]`: regenerate difflab/scene/scene.schema.json and
ROOT/docs/scene-format.md (ROOT: the repository, default the current folder) from the field specs."""

import sys
from pathlib import Path

from .reference import main

main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path.cwd())
