"""CityJSON tilesets checked against an independent CityJSON reader, cjio (PyPI).

For every tileset directory in BIMTILES_TILESET_DIRS converted from one CityJSON or CityJSONSeq
file (tests/cityjson.rs writes them from ../shared/data/cityjson/), cjio reads the input and this
checks, with the property tables decoded by test_metadata_reader's independent decoder:

* the elements are exactly the CityObjects that have geometry (ids and count);
* each element's class is its CityObject type;
* the CityObject attributes are in the property table (strings as written, numbers as numbers).

Every tile is read, the root too when it is inlined in tileset.json as a data URI (tile_content.py).
"""

import json
import math
import pathlib

import json.encoder

import pytest

# cjio replaces the json module's float encoding for the whole process when imported (it sets
# json.encoder.c_make_encoder and json.encoder.float): put them back, so the other tests' JSON
# keeps full precision.
_SAVED_ENCODER = {k: json.encoder.__dict__[k] for k in ("c_make_encoder", "float") if k in json.encoder.__dict__}
cityjson = pytest.importorskip("cjio.cityjson")
for _k in ("c_make_encoder", "float"):
    if _k in _SAVED_ENCODER:
        setattr(json.encoder, _k, _SAVED_ENCODER[_k])
    else:
        json.encoder.__dict__.pop(_k, None)

from test_metadata_reader import decode_table, read_glb, tileset_dirs  # noqa: E402
from tile_content import record_base, record_bytes, record_label  # noqa: E402

SURFACE_TYPES = {"MultiSurface", "CompositeSurface", "Solid", "MultiSolid", "CompositeSolid"}


def cjio_objects(path, lod=None):
    """{id: (type, attributes)} of the CityObjects with surface geometry (at LoD `lod`, when
    given: --cityjson-lod), as cjio reads them."""
    path = pathlib.Path(path)
    if path.suffix == ".jsonl":
        lines = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        cm = cityjson.CityJSON(j=lines[0])
        for feature in lines[1:]:
            cm.add_cityjsonfeature(feature)
    else:
        with open(path) as f:
            cm = cityjson.reader(f)
    out = {}
    for oid, co in cm.j["CityObjects"].items():
        if any(
            g.get("type") in SURFACE_TYPES and (lod is None or float(g.get("lod", 0)) == float(lod))
            for g in co.get("geometry", [])
        ):
            out[oid] = (co["type"], co.get("attributes", {}))
    return out


def test_cityjson_elements_and_attributes_match_cjio():
    checked = 0
    for d in tileset_dirs():
        d = pathlib.Path(d)
        report_path = d / "report.json"
        if not report_path.is_file():
            continue
        report = json.loads(report_path.read_text())
        inputs = [f for f in report["input"]["files"] if f.endswith((".json", ".jsonl")) and pathlib.Path(f).is_file()]
        if len(inputs) != 1:
            continue
        expected = cjio_objects(inputs[0], report["options"].get("cityjson_lod"))
        rows = {}
        # Properties by id over every tile's schema (an inline schema holds only its tile's).
        properties = {}
        tiles_read = inlined = 0
        for tile in report["tiles"]:
            if not tile["content"]:
                continue
            doc, blob = read_glb(record_label(d, tile), record_bytes(d, tile))
            tiles_read += 1
            inlined += bool(tile.get("inlined_in_tileset"))
            ext = doc["extensions"]["EXT_structural_metadata"]
            if "schema" in ext:
                schema = ext["schema"]
            else:
                schema = json.loads(record_base(d, tile).joinpath(ext["schemaUri"]).read_text())
            properties.update(schema["classes"]["element"]["properties"])
            for r in decode_table(doc, blob, schema):
                rows.setdefault(r["id"], {}).update({k: v for k, v in r.items() if v is not None})
        assert set(rows) == set(expected), (
            f"{d}: {len(rows)} elements vs {len(expected)} CityObjects with geometry; "
            f"missing {sorted(set(expected) - set(rows))[:3]}, extra {sorted(set(rows) - set(expected))[:3]}"
        )
        names = {p["name"]: pid for pid, p in properties.items() if "name" in p}
        attributes_checked = 0
        for oid, (cotype, attributes) in expected.items():
            row = rows[oid]
            assert row.get("class") == cotype, f"{oid}: class {row.get('class')!r} != {cotype!r}"
            for key, value in attributes.items():
                if value is None or isinstance(value, (dict, list)):
                    continue
                pid = names.get(f"attributes.{key}") or names.get(key)
                if pid is None:
                    # No tile stores a value of it (an empty string is no value), so no inline
                    # schema names it.
                    assert value == "", f"{d}: attribute {key} has no column"
                    attributes_checked += 1
                    continue
                got = row.get(pid)
                if isinstance(value, bool):
                    assert got in (value, float(value), str(value).lower()), f"{oid}.{key}: {got!r} != {value!r}"
                elif isinstance(value, (int, float)):
                    assert got is not None and math.isclose(float(got), float(value), rel_tol=1e-9), \
                        f"{oid}.{key}: {got!r} != {value!r}"
                else:
                    # An empty string is the table's noData (no value).
                    assert got == value or (value == "" and got is None), f"{oid}.{key}: {got!r} != {value!r}"
                attributes_checked += 1
        checked += 1
        print(f"{d}: {len(expected)} CityObjects with geometry, {attributes_checked} attribute values match cjio "
              f"({tiles_read} tiles, {inlined} inlined in tileset.json)")
    if checked == 0:
        pytest.skip("no tileset converted from a CityJSON input among BIMTILES_TILESET_DIRS")
