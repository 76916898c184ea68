"""Benchmark: validating a scene by difflab's hand-written checks (`Scene.from_dict`, records built
from the field specs) versus the generated JSON Schema (`jsonschema`, Draft 2020-12), and the
messages each gives for the same mistakes. This is the measurement behind keeping the hand-written
validation beside the schema (docs/scene-format.md).

    python experiments/bench/scene_validation.py            # 200 repeats
    python experiments/bench/scene_validation.py --small    # 20 repeats

Writes experiments/results/bench_scene_validation.json (atomically) and prints a table.
"""

from __future__ import annotations

import argparse
import copy
import json
from importlib import metadata
from pathlib import Path

import jsonschema

from difflab.demos import scene_path
from difflab.errors import SceneError
from difflab.io import write_json_atomic
from difflab.scene import Scene, scene_schema
from timing import median_seconds

MS = 1e3  # milliseconds a second

RESULTS = Path(__file__).resolve().parents[1] / "results" / "bench_scene_validation.json"
# (what is wrong, a change to the lecture scene)
MISTAKES = [
    ("typo in a key", lambda d: d["camera"].update(fovy=d["camera"].pop("fov_y"))),
    ("negative radius", lambda d: d["objects"][3].update(radius=-1)),
    ("misspelt shading", lambda d: d["render"].update(shading="Phong")),
    ("colour of 2 numbers", lambda d: d["materials"]["chrome"].update(kd=[0.1, 0.2])),
]


def hand_message(data) -> str:
    try:
        Scene.from_dict(data)
    except SceneError as exc:
        return str(exc)
    return "(accepted)"


def schema_message(validator, data) -> str:
    best = jsonschema.exceptions.best_match(validator.iter_errors(data))
    return "(accepted)" if best is None else f"{'.'.join(map(str, best.absolute_path))}: {best.message}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="20 repeats")
    args = parser.parse_args()
    repeats = 20 if args.small else 200
    data = json.loads(scene_path("lecture_teapot").read_text(encoding="utf-8"))
    data.pop("$schema")
    validator = jsonschema.Draft202012Validator(scene_schema())
    hand = MS * median_seconds(lambda: Scene.from_dict(data), repeats)
    schema = MS * median_seconds(lambda: list(validator.iter_errors(data)), repeats)
    rows = []
    for name, change in MISTAKES:
        bad = copy.deepcopy(data)
        change(bad)
        rows.append({"mistake": name, "difflab": hand_message(bad), "jsonschema": schema_message(validator, bad)})
    print(f"{'validator':<28}{'median ms':>10}")
    print(f"{'Scene.from_dict (by hand)':<28}{hand:>10.3f}")
    print(f"{'jsonschema (generated)':<28}{schema:>10.3f}")
    for row in rows:
        print(f"\n{row['mistake']}:\n  difflab:    {row['difflab']}\n  jsonschema: {row['jsonschema']}")
    write_json_atomic(RESULTS, {"repeats": repeats, "scene": "lecture_teapot", "from_dict_ms": hand,
                                "jsonschema_ms": schema, "ratio_jsonschema_over_from_dict": schema / hand,
                                "messages": rows, "jsonschema_version": metadata.version("jsonschema")})
    print(f"\njsonschema / from_dict time: {schema / hand:.2f}x; wrote {RESULTS}")


if __name__ == "__main__":
    main()
