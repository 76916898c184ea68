"""The docs cannot drift from the code silently: every public name is in the API page, every
command and option in the CLI page, every link points at a file of the repository."""

import contextlib
import io
import re
from pathlib import Path

import pytest

import difflab
from difflab.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]


def test_every_public_name_is_documented():
    api = (DOCS / "api.md").read_text(encoding="utf-8")
    missing = [name for name in difflab.__all__ if f"`{name}" not in api]
    assert not missing


def help_text(*argv) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        build_parser().parse_args([*argv, "--help"])
    return out.getvalue()


def test_every_command_and_option_is_documented():
    cli = (DOCS / "cli.md").read_text(encoding="utf-8")
    commands = re.findall(r"^    ([a-z-]+)\s{2,}", help_text(), flags=re.M)  # the COMMAND list of --help
    assert {"render", "demo", "fit", "fit-batch", "fractal"} <= set(commands)
    for command in commands:
        assert f"## `difflab {command} " in cli, command
        flags = set(re.findall(r"(?<![\w-])(--?[a-z][a-z0-9-]*)", help_text(command))) - {"-h", "--help"}
        missing = [flag for flag in flags if f"`{flag}`" not in cli]
        assert not missing, f"{command}: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_links_point_inside_the_repository(page):
    text = page.read_text(encoding="utf-8")
    assert "../shared" not in text
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
        if target.startswith(("http://", "https://")):
            continue
        path = (page.parent / target).resolve()
        assert path.is_file() and ROOT in path.parents, f"{page.name}: {target}"
