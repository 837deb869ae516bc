"""The element index (element-index.json) against the tiles' own property tables, read independently.

For every tileset directory in BIMTILES_TILESET_DIRS that names an element index in tileset.json
(``asset.extras.bimtiles.elementIndex``), this validates the file with
``schemas/element-index.schema.json``, then decodes every tile (EXT_structural_metadata tables,
EXT_mesh_features feature IDs, positions through the node transforms, glTF y-up to the tileset's
z-up) with the readers of test_metadata_reader.py and checks:

* every element drawn in the tiles is in the index once, with the same name, class, site, building,
  storey and path, and every index row is drawn, or is an exact duplicate listed in the ``aliases``
  of the row its ``drawnBy`` names;
* each element's box contains every full-detail triangle vertex of that element (simplified tiles
  may move vertices by their geometric error; GPU-instanced and Draco primitives are counted, not
  measured here);
* the index's gzip bytes (what ``bimtiles serve`` sends) are at most 5 % of the tileset's bytes,
  for tilesets of the shared models.

Run: BIMTILES_TILESET_DIRS=out/a:out/b python3 -m pytest -q tests/python/test_element_index.py
"""

import gzip
import json
import os
import pathlib

import numpy as np
import pytest

from meshopt_decode import decoded_tileset
from test_metadata_reader import decode_table, read_glb, tileset_dirs, view_bytes
from tile_content import record_base, record_bytes, record_label

jsonschema = pytest.importorskip("jsonschema", reason="pip install -r tests/python/requirements.txt")

REPO = pathlib.Path(__file__).resolve().parents[2]
SCHEMA = json.loads((REPO / "schemas" / "element-index.schema.json").read_text())
# The boxes are whole millimetres rounded outwards; vertices are f32 (or 16-bit) in a tile.
TOLERANCE_M = 2e-4
# What meshopt and Draco positions may differ from the scene's (the encoder's default bound).
COMPRESSED_POSITION_BOUND_M = 1e-3
# Share of the tileset's bytes the index may take (gzip, as served).
MAX_SHARE = 0.05
# Below this, the index's fixed part (format, frame, dictionaries) and one GlobalId per element
# outweigh a few kilobytes of tiles: such tilesets are printed, not held to the share.
MIN_ASSERTED_TILESET_BYTES = 256 * 1024

DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def accessor(doc, blob, index):
    """An accessor as a float64 array (count x components), normalized integers scaled as glTF says."""
    a = doc["accessors"][index]
    dt = np.dtype(DTYPES[a["componentType"]]).newbyteorder("<")
    n = WIDTH[a["type"]]
    view = doc["bufferViews"][a["bufferView"]]
    raw = view_bytes(doc, blob, a["bufferView"])
    stride = view.get("byteStride", n * dt.itemsize)
    start = a.get("byteOffset", 0)
    out = np.empty((a["count"], n), dtype=np.float64)
    for c in range(n):
        out[:, c] = np.ndarray((a["count"],), dt, raw, start + c * dt.itemsize, (stride,))
    if a.get("normalized"):
        out = np.maximum(out / float(np.iinfo(dt).max), -1.0)
    return out


def node_matrix(n):
    if "matrix" in n:
        return np.array(n["matrix"], dtype=np.float64).reshape(4, 4).T
    t = np.eye(4)
    t[:3, 3] = n.get("translation", [0, 0, 0])
    x, y, z, w = n.get("rotation", [0, 0, 0, 1])
    r = np.eye(4)
    r[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    s = np.diag(list(n.get("scale", [1, 1, 1])) + [1.0])
    return t @ r @ s


def float_grid(values):
    """The coarsest power-of-two grid step of the float positions (rows: vertices): lossy float
    encodings (meshopt's exponent filter, one exponent per vertex) round each vertex to a grid of
    its own, by up to half its step; the largest step of any vertex is returned."""
    step = np.zeros(len(values))
    for k in range(40, -1, -1):
        scaled = values * 2.0 ** k
        on_grid = (scaled == np.round(scaled)).all(axis=1)
        step[on_grid] = 2.0 ** -k
    return float(step.max()) if len(step) else 0.0


# glTF's y-up to the tileset's z-up (3D Tiles: x, y, z -> x, -z, y).
Y_UP_TO_Z_UP = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


def feature_vertices(doc, blob):
    """(feature ids, positions in the tileset frame, their rounding in metres) of the plain
    primitives of a GLB, and how many primitives were left out (Draco, GPU instancing). Quantized
    positions (KHR_mesh_quantization, or floats on a coarse grid) are off by up to half a step of
    their grid, a step being the node scale over the integer range (or the float grid's step)."""
    parent = {c: i for i, n in enumerate(doc.get("nodes", [])) for c in n.get("children", [])}
    ids, points, skipped = [], [], 0
    for i, n in enumerate(doc.get("nodes", [])):
        if "mesh" not in n:
            continue
        if "EXT_mesh_gpu_instancing" in n.get("extensions", {}):
            skipped += len(doc["meshes"][n["mesh"]]["primitives"])
            continue
        m, j = np.eye(4), i
        while j is not None:
            m = node_matrix(doc["nodes"][j]) @ m
            j = parent.get(j)
        m = Y_UP_TO_Z_UP @ m
        for p in doc["meshes"][n["mesh"]]["primitives"]:
            ext = p.get("extensions", {})
            if "KHR_draco_mesh_compression" in ext or "EXT_mesh_features" not in ext:
                skipped += 1
                continue
            fid = ext["EXT_mesh_features"]["featureIds"][0]
            a = doc["accessors"][p["attributes"]["POSITION"]]
            pos = accessor(doc, blob, p["attributes"]["POSITION"])
            if a["componentType"] != 5126:
                top = float(np.iinfo(DTYPES[a["componentType"]]).max)
                grid = 1.0 / top if a.get("normalized") else 1.0
            else:
                grid = float_grid(pos)
            step = np.abs(m[:3, :3]).sum(axis=1).max() * grid
            pos = pos @ m[:3, :3].T + m[:3, 3]
            ids.append(accessor(doc, blob, p["attributes"][f"_FEATURE_ID_{fid['attribute']}"])[:, 0].astype(np.int64))
            points.append((pos, step))
    return ids, points, skipped


def index_rows(ix):
    """The index as one dict per row (codes resolved, path rebuilt)."""
    d, c = ix["dictionaries"], ix["columns"]
    rows = []
    for i in range(ix["count"]):
        parent, leaf = d["pathParent"][c["pathParent"][i]], c["pathLeaf"][i]
        leaf = leaf if leaf is not None else (c["name"][i] or c["id"][i])
        path = f"{parent}/{leaf}" if parent is not None else (leaf or None)
        b = c["box_mm"][6 * i:6 * i + 6]
        rows.append({
            "id": c["id"][i], "name": c["name"][i], "site": d["site"][c["site"][i]],
            "building": d["building"][c["building"][i]], "storey": d["storey"][c["storey"][i]],
            "class": d["class"][c["class"][i]], "path": path, "drawnBy": c["drawnBy"][i],
            "min": np.array(b[:3], dtype=np.float64) / 1000.0,
            "max": (np.array(b[:3], dtype=np.float64) + np.array(b[3:], dtype=np.float64)) / 1000.0,
        })
    return rows


SHARED_DATA = pathlib.Path(os.environ.get("BIMTILES_SHARED", REPO.parent / "shared")) / "data"


BIM_SUFFIXES = {".ifc", ".glb", ".gltf"}


def inputs_are_shared_bim_models(report):
    """Whether every input of a conversion is a BIM model (IFC or glTF) of the shared data, alone
    or placed by a manifest. City models (CityJSON, CityGML) hold a few hundred bytes of tiles per
    building, so ids and boxes are a larger share there: their figure is printed, not asserted."""
    files = [pathlib.Path(f) for f in report["input"]["files"]]
    return bool(files) and all(f.resolve().is_relative_to(SHARED_DATA.resolve()) and
                               f.suffix.lower() in BIM_SUFFIXES for f in files)


def indexed_dirs():
    out = []
    for d in tileset_dirs():
        ts = json.loads((pathlib.Path(d) / "tileset.json").read_text())
        name = ts["asset"].get("extras", {}).get("bimtiles", {}).get("elementIndex")
        if name and (pathlib.Path(d) / "report.json").is_file():
            out.append((pathlib.Path(d), name))
    if not out:
        pytest.skip("no tileset with an element index among BIMTILES_TILESET_DIRS")
    return out


def test_schema_refuses_a_broken_index():
    v = jsonschema.Draft202012Validator(SCHEMA)
    good = {"format": "bimtiles-element-index/2", "frame": "f", "count": 0,
            "dictionaries": {k: [None] for k in ("site", "building", "storey", "class", "pathParent")},
            "columns": {k: [] for k in ("id", "name", "site", "building", "storey", "class", "pathParent",
                                        "pathLeaf", "box_mm", "drawnBy")}}
    assert not list(v.iter_errors(good))
    bad = json.loads(json.dumps(good))
    bad["dictionaries"]["class"] = ["IfcWall"]  # code 0 must be null
    bad["columns"]["storey"] = [-1]
    assert len(list(v.iter_errors(bad))) == 2


def test_index_matches_the_tiles():
    validator = jsonschema.Draft202012Validator(SCHEMA)
    for d, name in indexed_dirs():
        raw = (d / name).read_bytes()
        ix = json.loads(raw)
        errors = [e.message for e in validator.iter_errors(ix)]
        assert not errors, f"{d / name}: {errors[:3]}"
        for col, values in ix["columns"].items():
            assert len(values) == ix["count"] * (6 if col == "box_mm" else 1), f"{d}: column {col}"
        rows = index_rows(ix)
        by_id = {}
        for i, r in enumerate(rows):
            assert by_id.setdefault(r["id"], i) == i, f"{d}: {r['id']} twice in the index"
        report = json.loads((d / "report.json").read_text())
        plain = decoded_tileset(d)
        drawn, aliases_of = set(), {}
        measured = skipped = 0
        for tile in report["tiles"]:
            if not tile["content"]:
                continue
            where = record_label(plain, tile)
            doc, blob = read_glb(where, record_bytes(plain, tile))
            ext = doc["extensions"]["EXT_structural_metadata"]
            schema = ext["schema"] if "schema" in ext else json.loads(
                record_base(plain, tile).joinpath(ext["schemaUri"]).read_text())
            table = decode_table(doc, blob, schema)
            for t in table:
                assert t["id"] in by_id, f"{where}: element {t['id']} is not in the index"
                r = rows[by_id[t["id"]]]
                drawn.add(t["id"])
                for k in ("name", "class", "site", "building", "storey", "path"):
                    # Simplified tiles leave some out (name, path): only what a tile says is compared.
                    if t.get(k) is not None:
                        assert t[k] == r[k], f"{where}: {t['id']}: {k} {t[k]!r} in the tile, {r[k]!r} in the index"
                for a in json.loads(t.get("aliases") or "[]"):
                    aliases_of[a] = t["id"]
            if "simplified_from_triangles" in tile:
                continue
            ids, points, n_skipped = feature_vertices(doc, blob)
            skipped += n_skipped
            # Dedup draws a shape congruent within its tolerance in place of an element's own, and
            # compressed positions are written within the encoder's bound (meshopt's exponent
            # filter takes the fewest mantissa bits that keep it).
            dedup_m = (report.get("dedup") or {}).get("tolerance_m") or 0.0
            encoded_m = COMPRESSED_POSITION_BOUND_M if report["options"]["compression"] != "none" else 0.0
            for fids, (pos, step) in zip(ids, points):
                tol = TOLERANCE_M + max(step, encoded_m) + dedup_m
                for f in np.unique(fids):
                    r = rows[by_id[table[f]["id"]]]
                    p = pos[fids == f]
                    lo, hi = p.min(axis=0), p.max(axis=0)
                    assert (lo >= r["min"] - tol).all() and (hi <= r["max"] + tol).all(), \
                        f"{where}: {r['id']}: vertices span {lo}..{hi}, its box is {r['min']}..{r['max']}"
                    measured += len(p)
        for r in rows:
            if r["id"] in drawn:
                assert r["drawnBy"] == -1, f"{d}: {r['id']} is drawn but says drawnBy {r['drawnBy']}"
            else:
                assert r["drawnBy"] >= 0, f"{d}: {r['id']} is in the index but in no tile"
                assert aliases_of.get(r["id"]) == rows[r["drawnBy"]]["id"], \
                    f"{d}: {r['id']} drawn by {rows[r['drawnBy']]['id']}, the tiles say {aliases_of.get(r['id'])}"
        assert not set(aliases_of) - set(by_id), f"{d}: aliases not in the index"
        packed = len(gzip.compress(raw, 9))
        total = report["output"]["bytes"]
        assert report["output"]["element_index_bytes"] == len(raw)
        print(f"{d}: {ix['count']} elements, index {len(raw)} B ({packed} B gzip) = "
              f"{100 * len(raw) / total:.2f} % ({100 * packed / total:.2f} % gzip) of {total} B; "
              f"{measured} vertices inside their boxes, {skipped} primitives not measured")
        # The size target holds for real BIM models (the shared ones, alone or placed by a
        # manifest) of a quarter megabyte or more; the suite's synthetic scenes (thousands of
        # instances of one tiny shape), city models and tiny tilesets are only printed.
        if inputs_are_shared_bim_models(report) and total >= MIN_ASSERTED_TILESET_BYTES:
            assert packed <= MAX_SHARE * total, f"{d}: the index is {packed} B gzip, over 5 % of {total} B"
