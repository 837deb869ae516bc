#!/usr/bin/env python3
"""Writes a campus manifest (schemas/manifest.schema.json) of many buildings from a few models.

    python3 tools/campus_manifest.py --out DIR [--spacing-m 150] MODEL=COUNT [MODEL=COUNT ...]

Each MODEL is copied once into DIR/models/ (a manifest's paths stay inside its folder) and placed
COUNT times, the buildings named b000, b001, ... on a square grid `--spacing-m` apart, east then
north, in the order given. DIR/campus.json is the manifest. Used by `make test-browser` for the
viewer's campus (the tree and search on a real index of about 100k elements), and handy for trying
campus builds by hand.
"""

import argparse
import json
import math
import shutil
import sys
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path, help="folder of the manifest and its models")
    ap.add_argument("--spacing-m", type=float, default=150.0, help="grid step between buildings (m)")
    ap.add_argument("models", nargs="+", help="MODEL=COUNT: a model file and how many times to place it")
    args = ap.parse_args()

    placed = []
    for spec in args.models:
        path, sep, count = spec.rpartition("=")
        if not sep or not count.isdigit() or int(count) < 1:
            print(f"campus_manifest: {spec}: give MODEL=COUNT with COUNT at least 1", file=sys.stderr)
            return 2
        model = Path(path)
        if not model.is_file():
            print(f"campus_manifest: {model}: no such file", file=sys.stderr)
            return 2
        placed += [model] * int(count)

    models_dir = args.out / "models"
    models_dir.mkdir(parents=True, exist_ok=True)
    for model in dict.fromkeys(placed):
        target = models_dir / model.name
        if not target.is_file() or target.stat().st_size != model.stat().st_size:
            shutil.copyfile(model, target)

    columns = math.ceil(math.sqrt(len(placed)))
    entries = [
        {
            "name": f"b{k:03d}",
            "path": f"models/{model.name}",
            "east_m": (k % columns) * args.spacing_m,
            "north_m": (k // columns) * args.spacing_m,
        }
        for k, model in enumerate(placed)
    ]
    (args.out / "campus.json").write_text(json.dumps({"models": entries}, indent=1) + "\n")
    print(f"campus_manifest: {len(entries)} buildings in {args.out / 'campus.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
