"""Mutation testing of difflab's formula modules: mutmut's operators, one mutant at a time, each run
against the tests that guard its module. Not part of CI (it takes about an hour on 2 cores).

Why not plain `mutmut run`: mutmut 3 switches between mutants at run time through trampolines, and
it skips decorated functions -- every Warp `@wp.func` is one, and Warp compiles a function from its
source, so a trampoline could not run inside a kernel anyway. This script keeps mutmut's mutation
operators (`mutmut.mutation.file_mutation.create_mutations`, with decorated functions allowed) but
writes each mutant into a scratch copy of the repository and runs pytest there: a mutant is *killed*
when the chosen tests fail (or error, or time out), *survived* when they pass.

What is mutated and which tests run is configured in pyproject.toml, one table per module:

    [tool.difflab.mutation."difflab/io.py"]
    functions = ["srgb_to_linear", "linear_to_srgb"]   # top-level functions to mutate
    tests = ["tests/test_cli_io.py"]                    # pytest arguments

Usage (from the repository root, in the project's environment):

    python tools/mutate.py                  # every configured module
    python tools/mutate.py difflab/io.py    # some modules
    python tools/mutate.py --list           # count the mutants, run nothing
    python tools/mutate.py --survivors      # run again only the last run's survivors (after adding tests)

Prints each survivor as a diff line and the score; writes results/mutation/<module>.json (git
ignores results/). docs/testing.md records the last score and why each survivor is equivalent.
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import libcst as cst
from mutmut.mutation.file_mutation import MutationVisitor, create_mutations, deep_replace

ROOT = Path(__file__).resolve().parent.parent
COPIED = ("difflab", "tests", "pyproject.toml", "README.md")


class DecoratedToo(MutationVisitor):
    """mutmut's visitor, but entering decorated functions (the decorator itself stays untouched)."""

    def _skip_node_and_children(self, node):
        if isinstance(node, cst.FunctionDef) and node.decorators:
            return False
        return super()._skip_node_and_children(node)


def mutants(path: Path, functions) -> list[dict]:
    """Every mutant of the chosen top-level functions of one module: id, line, diff, source."""
    import mutmut.mutation.file_mutation as fm

    code = path.read_text()
    saved, fm.MutationVisitor = fm.MutationVisitor, DecoratedToo
    try:
        module, mutations, _, _ = create_mutations(str(path), code)
    finally:
        fm.MutationVisitor = saved
    out = []
    for k, m in enumerate(mutations):
        owner = m.contained_by_top_level_function
        name = owner.name.value if owner is not None else None
        if name is None or (functions and name not in functions):
            continue
        source = deep_replace(module, m.original_node, m.mutated_node).code
        changed = [line for line in difflib.unified_diff(code.splitlines(), source.splitlines(), lineterm="", n=0)
                   if line[:1] in "+-" and not line.startswith(("+++", "---"))]
        if not changed:
            continue
        line = next(i for i, (a, b) in enumerate(zip(code.splitlines(), source.splitlines()), 1) if a != b)
        out.append({"id": f"{path}:{name}:{k}", "function": name, "line": line, "diff": changed, "source": source})
    return out


def run_tests(scratch: Path, tests, timeout: float) -> tuple[str, float]:
    """('passed' | 'failed' | 'error' | 'timeout', seconds) of pytest on `tests` in the scratch copy."""
    env = dict(os.environ, PYTHONPATH=str(scratch), MPLBACKEND="Agg", WARP_CACHE_PATH=str(scratch / ".warp-cache"))
    start = time.perf_counter()
    try:
        rc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests],
                            cwd=scratch, env=env, capture_output=True, timeout=timeout).returncode
    except subprocess.TimeoutExpired:
        return "timeout", time.perf_counter() - start
    return {0: "passed", 1: "failed"}.get(rc, "error"), time.perf_counter() - start


def prune_cache(cache: Path, keep: set) -> None:
    """Remove the Warp modules compiled for a mutant (the cache would grow by one module per mutant)."""
    for entry in cache.glob("*") if cache.is_dir() else []:
        if entry.name not in keep:
            shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)


def record_path(module: str) -> Path:
    return ROOT / "results" / "mutation" / (module.replace("/", "_") + ".json")


def mutate_module(scratch: Path, module: str, config: dict, survivors_only: bool = False) -> dict:
    """Run every mutant of one module (or only the survivors of its last record); returns its record
    (also written to results/mutation/)."""
    target = scratch / module
    original = target.read_text()
    tests = config["tests"]
    todo = mutants(ROOT / module, set(config.get("functions", ())))
    previous = {}
    if survivors_only:
        previous = {r["id"]: r for r in json.loads(record_path(module).read_text())["results"]}
        todo = [m for m in todo if previous.get(m["id"], {}).get("outcome") == "passed"]
    status, baseline = run_tests(scratch, tests, timeout=3600)
    if status != "passed":
        raise SystemExit(f"{module}: the unmutated tests do not pass ({status}): {' '.join(tests)}")
    cache = scratch / ".warp-cache"
    keep = {p.name for p in cache.glob("*")} if cache.is_dir() else set()
    timeout = max(120.0, 10 * baseline)
    print(f"{module}: {len(todo)} mutants, tests {baseline:.0f} s unmutated", flush=True)
    results = []
    try:
        for k, m in enumerate(todo, 1):
            target.write_text(m["source"])
            outcome, seconds = run_tests(scratch, tests, timeout)
            target.write_text(original)
            prune_cache(cache, keep)
            results.append({key: m[key] for key in ("id", "function", "line", "diff")} | {"outcome": outcome,
                                                                                         "seconds": round(seconds, 1)})
            write_record(module, config, list((previous | {r["id"]: r for r in results}).values()))
            mark = "SURVIVED" if outcome == "passed" else outcome
            print(f"  [{k}/{len(todo)}] {mark:8s} line {m['line']}: {' | '.join(m['diff'])[:150]}", flush=True)
    finally:
        target.write_text(original)
    return write_record(module, config, list((previous | {r["id"]: r for r in results}).values()))


def write_record(module: str, config: dict, results: list) -> dict:
    """results/mutation/<module>.json, rewritten after every mutant so that a stopped run keeps what it did."""
    killed = sum(r["outcome"] != "passed" for r in results)
    record = {"module": module, "tests": config["tests"], "functions": config.get("functions"),
              "mutants": len(results), "killed": killed, "score": killed / max(len(results), 1), "results": results}
    out = record_path(module)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=1) + "\n")
    return record


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("modules", nargs="*", help="modules to mutate (default: every configured one)")
    parser.add_argument("--list", action="store_true", help="count the mutants per module and function, run nothing")
    parser.add_argument("--survivors", action="store_true", help="run only the survivors of each module's last record")
    args = parser.parse_args(argv)
    table = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["difflab"]["mutation"]
    unknown = set(args.modules) - set(table)
    if unknown:
        parser.error(f"not configured in pyproject.toml [tool.difflab.mutation]: {sorted(unknown)}")
    chosen = args.modules or list(table)
    if args.list:
        for module in chosen:
            found = mutants(ROOT / module, set(table[module].get("functions", ())))
            by_function = {}
            for m in found:
                by_function[m["function"]] = by_function.get(m["function"], 0) + 1
            print(f"{module}: {len(found)} {by_function}")
        return 0
    summary = []
    with tempfile.TemporaryDirectory(prefix="difflab-mutation-") as tmp:
        scratch = Path(tmp)
        for name in COPIED:
            source = ROOT / name
            if source.is_dir():
                shutil.copytree(source, scratch / name, ignore=shutil.ignore_patterns("__pycache__"))
            else:
                shutil.copy2(source, scratch / name)
        for module in chosen:
            record = mutate_module(scratch, module, table[module], survivors_only=args.survivors)
            summary.append(record)
            survivors = [r for r in record["results"] if r["outcome"] == "passed"]
            print(f"{module}: {record['killed']}/{record['mutants']} killed ({100 * record['score']:.1f} %)")
            for r in survivors:
                print(f"  survived line {r['line']} ({r['function']}): {' | '.join(r['diff'])}")
    total = sum(r["mutants"] for r in summary)
    killed = sum(r["killed"] for r in summary)
    print(f"total: {killed}/{total} killed ({100 * killed / max(total, 1):.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
