"""Validate tileset.json files against the official 3D Tiles JSON schemas (draft 2020-12).

The schemas are read from <BIMTILES_SHARED>/specs/3d-tiles/specification/schema (BIMTILES_SHARED defaults to
the `shared` folder beside the repository). Every schema file is registered under its file:// URI (its
relative `$id` is replaced by that URI) in a `referencing` registry, so the relative `$ref`s between the
files (`../common/rootProperty.schema.json`, `./Schema/schema.schema.json`, ...) resolve.

    BIMTILES_TILESET_DIRS=out/a:out/b python3 -m pytest tests/python/test_tileset_schema.py
"""

import copy
import json
import os
import pathlib

import pytest

jsonschema = pytest.importorskip("jsonschema", reason="pip install -r tests/python/requirements.txt")
referencing = pytest.importorskip("referencing", reason="pip install -r tests/python/requirements.txt")
from referencing import Registry, Resource  # noqa: E402
from referencing.jsonschema import DRAFT202012  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[2]
SHARED = pathlib.Path(os.environ.get("BIMTILES_SHARED", REPO.parent / "shared"))
SCHEMA_DIR = SHARED / "specs" / "3d-tiles" / "specification" / "schema"


def _retrieve(uri):
    if not uri.startswith("file://"):
        raise referencing.exceptions.NoSuchResource(ref=uri)
    path = pathlib.Path(uri[len("file://"):])
    contents = json.loads(path.read_text(encoding="utf-8"))
    contents["$id"] = uri
    return Resource.from_contents(contents, default_specification=DRAFT202012)


def tileset_validator():
    root = SCHEMA_DIR / "tileset.schema.json"
    if not root.is_file():
        pytest.skip(f"3D Tiles schemas not found at {SCHEMA_DIR} (set BIMTILES_SHARED to the shared folder)")
    uri = root.resolve().as_uri()
    resource = _retrieve(uri)
    registry = Registry(retrieve=_retrieve).with_resource(uri, resource)
    cls = jsonschema.validators.validator_for(resource.contents, default=jsonschema.Draft202012Validator)
    return cls(resource.contents, registry=registry)


def schema_errors(tileset):
    """List of 'path: message' strings (empty when valid)."""
    v = tileset_validator()
    errs = sorted(v.iter_errors(tileset), key=lambda e: list(e.absolute_path))
    return [f"/{'/'.join(str(p) for p in e.absolute_path)}: {e.message}" for e in errs]


def _env_dirs():
    return [d for d in os.environ.get("BIMTILES_TILESET_DIRS", "").split(":") if d]


@pytest.mark.parametrize("directory", _env_dirs() or [None])
def test_tileset_json_matches_schema(directory):
    if directory is None:
        pytest.skip("BIMTILES_TILESET_DIRS is not set: set it to a colon-separated list of bimtiles output "
                    "directories to validate their tileset.json against the 3D Tiles schemas")
    with open(os.path.join(directory, "tileset.json"), encoding="utf-8") as fh:
        ts = json.load(fh)
    errs = schema_errors(ts)
    assert not errs, "\n".join(errs[:20])


MINIMAL = {
    "asset": {"version": "1.1"},
    "geometricError": 50.0,
    "schema": {"id": "bim", "classes": {"element": {"properties": {"ifc_class": {"type": "STRING"}}}}},
    "root": {
        "transform": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 4000000.0, 1000000.0, 4800000.0, 1],
        "boundingVolume": {"box": [0, 0, 5, 15, 0, 0, 0, 7.5, 0, 0, 0, 6]},
        "geometricError": 10.0,
        "refine": "REPLACE",
        "content": {"uri": "tiles/0.glb"},
        "children": [{"boundingVolume": {"box": [0, 0, 5, 7, 0, 0, 0, 7, 0, 0, 0, 6]},
                      "geometricError": 0.0, "contents": [{"uri": "tiles/0_0.glb"}]}],
    },
    "extensionsUsed": ["EXT_structural_metadata"],
}


def test_minimal_tileset_is_valid():
    assert schema_errors(MINIMAL) == []


def test_tileset_without_asset_fails():
    bad = copy.deepcopy(MINIMAL)
    del bad["asset"]
    errs = schema_errors(bad)
    assert any("'asset' is a required property" in e for e in errs), errs


def test_bad_nested_values_fail():
    # exercises $refs into other files: tile.schema.json, boundingVolume.schema.json, Schema/*.schema.json
    bad = copy.deepcopy(MINIMAL)
    bad["root"]["children"][0]["boundingVolume"]["box"] = [0, 0, 0]          # needs 12 numbers
    bad["root"]["refine"] = 1                  # enums are open ("anyOf ... or any string") but must be strings
    bad["root"]["geometricError"] = -1.0       # minimum 0
    bad["schema"]["classes"]["element"]["properties"]["ifc_class"]["type"] = 42
    errs = "\n".join(schema_errors(bad))
    assert "/root/children/0/boundingVolume/box" in errs, errs
    assert "/root/refine" in errs, errs
    assert "/root/geometricError" in errs, errs
    assert "/schema/classes/element/properties/ifc_class/type" in errs, errs
