"""Independent reader of the BIM metadata in bimtiles output (shares no code with the writer).

For every tileset directory in BIMTILES_TILESET_DIRS whose report.json names glTF inputs, this
decodes each tile's EXT_structural_metadata property table (schema inline or from ``schemaUri``; STRING,
SCALAR FLOAT64 and ENUM columns as the extension defines them) and EXT_mesh_features feature IDs,
then checks against the *input* file, read here from its JSON chunk:

* every input node with a mesh appears as a feature (by its id: GlobalId extras/name, else path),
* with its name, IFC class and storey (from the node's ``extras``),
* and every feature ID stored on the vertices names a row of the tile's table.

Tiles with EXT_meshopt_compression are read from a copy decoded by meshoptimizer's reference
decoder (meshopt_decode.py). A tile inlined in tileset.json as a data URI (report.json's
``inlined_in_tileset``) is read from there (tile_content.py), with the same checks.

Run: BIMTILES_TILESET_DIRS=out/a:out/b python3 -m pytest -q tests/python/test_metadata_reader.py
"""

import json
import os
import pathlib
import re
import struct

import pytest

from meshopt_decode import decoded_tileset
from tile_content import record_base, record_bytes, record_label

GUID = re.compile(r"^[0-3][0-9A-Za-z_$]{21}$")


def read_glb(path, data=None):
    """(JSON, BIN chunk) of the GLB at `path`, or of its bytes `data` (then `path` only names it)."""
    if data is None:
        data = pathlib.Path(path).read_bytes()
    assert data[:4] == b"glTF", f"{path}: not a GLB"
    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + jlen])
    bin_chunk = b""
    off = 20 + jlen
    if off + 8 <= len(data):
        blen = struct.unpack_from("<I", data, off)[0]
        bin_chunk = data[off + 8:off + 8 + blen]
    return doc, bin_chunk


def view_bytes(doc, blob, index):
    v = doc["bufferViews"][index]
    start = v.get("byteOffset", 0)
    return blob[start:start + v["byteLength"]]


# struct codes of the metadata spec's unsigned integer types (string offsets, enum values).
UINT_CODES = {"UINT8": "B", "UINT16": "H", "UINT32": "I", "UINT64": "Q"}


def decode_table(doc, blob, schema):
    """Rows of property table 0 as a list of dicts {property id: python value or None}."""
    ext = doc["extensions"]["EXT_structural_metadata"]
    table = ext["propertyTables"][0]
    cls = schema["classes"][table["class"]]["properties"]
    enums = schema.get("enums", {})
    n = table["count"]
    rows = [dict() for _ in range(n)]
    for pid, prop in table["properties"].items():
        d = cls[pid]
        values = view_bytes(doc, blob, prop["values"])
        if d["type"] == "STRING":
            code = UINT_CODES[prop.get("stringOffsetType", "UINT32")]
            offs = struct.unpack_from(f"<{n + 1}{code}", view_bytes(doc, blob, prop["stringOffsets"]))
            col = [values[offs[i]:offs[i + 1]].decode("utf-8") for i in range(n)]
            col = [None if v == d.get("noData") else v for v in col]
        elif d["type"] == "SCALAR" and d["componentType"] == "FLOAT64":
            col = list(struct.unpack_from(f"<{n}d", values))
            col = [None if v == d.get("noData") else v for v in col]
        elif d["type"] == "ENUM":
            e = enums[d["enumType"]]
            code = UINT_CODES[e.get("valueType", "UINT16")]
            names = {v["value"]: v["name"] for v in e["values"]}
            col = [names[c] for c in struct.unpack_from(f"<{n}{code}", values)]
            col = [None if v == d.get("noData") else v for v in col]
        else:
            pytest.fail(f"unexpected property type {d}")
        for i, v in enumerate(col):
            rows[i][pid] = v
    return rows


def read_scalars(doc, blob, index):
    acc = doc["accessors"][index]
    raw = view_bytes(doc, blob, acc["bufferView"])[acc.get("byteOffset", 0):]
    fmt = {5126: "f", 5123: "H", 5121: "B"}[acc["componentType"]]
    return list(struct.unpack_from(f"<{acc['count']}{fmt}", raw))


def feature_ids(doc, blob):
    """Feature IDs of uncompressed primitives (Draco-compressed ones are checked by the Draco test)
    and of GPU instances (EXT_instance_features through an EXT_mesh_gpu_instancing attribute)."""
    out = []
    instanced_meshes = set()
    for n in doc.get("nodes", []):
        ext = n.get("extensions", {})
        if "EXT_mesh_gpu_instancing" in ext:
            instanced_meshes.add(n["mesh"])
            fid = ext["EXT_instance_features"]["featureIds"][0]
            out.extend(read_scalars(doc, blob, ext["EXT_mesh_gpu_instancing"]["attributes"][f"_FEATURE_ID_{fid['attribute']}"]))
    for mi, mesh in enumerate(doc.get("meshes", [])):
        for p in mesh["primitives"]:
            if "KHR_draco_mesh_compression" in p.get("extensions", {}):
                continue
            if mi in instanced_meshes:
                # Identity is per instance: the shape's vertices carry none.
                assert "EXT_mesh_features" not in p.get("extensions", {})
                continue
            out.extend(read_scalars(doc, blob, p["attributes"]["_FEATURE_ID_0"]))
    return out


def input_elements(path):
    """Nodes with a mesh of a glTF/GLB input: {id: (name, class, storey)}, ids by the README's
    "Element ids" rule: sibling repeats numbered `name#n`, a GlobalId when unique in the file,
    and any id still taken by an earlier element (depth-first order) numbered `#k`."""
    doc, _ = read_glb(path) if str(path).endswith(".glb") else (json.loads(pathlib.Path(path).read_text()), b"")
    nodes = doc.get("nodes", [])
    parent = {}
    for i, n in enumerate(nodes):
        for c in n.get("children", []):
            parent[c] = i
    scenes = doc.get("scenes", [])
    if scenes:
        roots = scenes[doc.get("scene", 0)].get("nodes", [])
    else:
        roots = [i for i in range(len(nodes)) if i not in parent]
    segment = {i: n.get("name", f"node{i}") for i, n in enumerate(nodes)}
    for group in [roots] + [n.get("children", []) for n in nodes]:
        seen = {}
        for i in group:
            if "name" not in nodes[i]:
                continue
            k = seen.get(nodes[i]["name"], 0)
            if k:
                segment[i] = f"{nodes[i]['name']}#{k}"
            seen[nodes[i]["name"]] = k + 1

    def node_path(i):
        parts = []
        while i is not None:
            parts.append(segment[i])
            i = parent.get(i)
        return "/".join(reversed(parts))

    def guid_of(n):
        extras = n.get("extras") or {}
        for k in ("guid", "GlobalId", "globalId", "ifc_guid"):
            if isinstance(extras.get(k), str):
                return extras[k]
        return n["name"] if GUID.match(n.get("name", "")) else None

    def owner(i):
        # An unnamed mesh node that only carries a dequantization transform (gltfpack) is its
        # named parent's element (README, glTF input).
        n, p = nodes[i], parent.get(i)
        if (p is not None and "name" not in n and "extras" not in n and not n.get("children")
                and "mesh" not in nodes[p] and len(nodes[p].get("children", [])) == 1):
            return p
        return i

    order, stack = [], list(reversed(roots))
    while stack:
        i = stack.pop()
        if "mesh" in nodes[i]:
            order.append(owner(i))
        stack.extend(reversed(nodes[i].get("children", [])))
    uses = {}
    for i in order:
        g = guid_of(nodes[i])
        if g:
            uses[g] = uses.get(g, 0) + 1
    first = [g if (g := guid_of(nodes[i])) and uses[g] == 1 else node_path(i) for i in order]
    taken, held, out = set(first), set(), {}
    for i, key in zip(order, first):
        if key in held:
            k = 1
            while f"{key}#{k}" in taken:
                k += 1
            key = f"{key}#{k}"
            taken.add(key)
        held.add(key)
        n = nodes[i]
        extras = n.get("extras") or {}
        out[key] = (n.get("name"), extras.get("ifc_class"), extras.get("storey"))
    return out


def tileset_dirs():
    dirs = [d for d in os.environ.get("BIMTILES_TILESET_DIRS", "").split(":") if d]
    if not dirs:
        pytest.skip("BIMTILES_TILESET_DIRS is not set: set it to bimtiles output folders")
    return dirs


def test_metadata_names_every_input_element():
    checked = 0
    for d in tileset_dirs():
        d = decoded_tileset(d)
        report_path = d / "report.json"
        if not report_path.is_file():
            continue
        report = json.loads(report_path.read_text())
        inputs = [f for f in report["input"]["files"] if pathlib.Path(f).is_file() and f.endswith((".glb", ".gltf"))]
        if len(inputs) != 1 or "(embedded)" in inputs[0]:
            continue
        expected = input_elements(inputs[0])
        seen = {}
        aliases = {}
        for tile in report["tiles"]:
            if not tile["content"]:
                continue
            where = record_label(d, tile)
            doc, blob = read_glb(where, record_bytes(d, tile))
            ext = doc.get("extensions", {}).get("EXT_structural_metadata")
            assert ext, f"{where}: no EXT_structural_metadata"
            assert "EXT_structural_metadata" in doc["extensionsUsed"]
            if "schema" in ext:
                schema = ext["schema"]
            else:
                schema = json.loads(record_base(d, tile).joinpath(ext["schemaUri"]).read_text())
            assert schema["id"] == "bimtiles"
            rows = decode_table(doc, blob, schema)
            assert len(rows) == tile["features"]
            for fid in feature_ids(doc, blob):
                assert fid == int(fid) and 0 <= fid < len(rows), f"feature id {fid} names no row"
            for r in rows:
                # Simplified tiles name an element with fewer properties (no path, no name where
                # the id is the node path ending with it): what any tile says is merged.
                merged = seen.setdefault(r["id"], {})
                for k, v in r.items():
                    if v is not None:
                        assert merged.setdefault(k, v) == v, f"{r['id']}: {k} {merged[k]!r} vs {v!r}"
                if r.get("name") is None and expected.get(r["id"], (None,))[0] is not None:
                    assert r["id"].endswith("/" + expected[r["id"]][0]) or r["id"] == expected[r["id"]][0], \
                        f"{r['id']}: name left out of {where} but the id does not end with it"
                # Exact duplicates that were not drawn are listed by the element drawn for them.
                for alias in json.loads(r.get("aliases") or "[]"):
                    assert aliases.setdefault(alias, r["id"]) == r["id"], f"{alias}: alias of two elements"
        missing = set(expected) - set(seen) - set(aliases)
        assert not missing, f"{d}: {len(missing)} input elements have no feature, e.g. {sorted(missing)[:3]}"
        assert not set(seen) & set(aliases), f"{d}: elements both drawn and aliased"
        for key, (name, cls, storey) in expected.items():
            if key in aliases:
                continue
            r = seen[key]
            assert r.get("name") == name, f"{key}: name {r.get('name')!r} != {name!r}"
            assert r.get("class") == cls, f"{key}: class {r.get('class')!r} != {cls!r}"
            assert r.get("storey") == storey, f"{key}: storey {r.get('storey')!r} != {storey!r}"
        checked += len(expected)
        inlined = sum(1 for t in report["tiles"] if t["content"] and t.get("inlined_in_tileset"))
        print(f"{d}: {len(expected)} elements named correctly in "
              f"{sum(1 for t in report['tiles'] if t['content'])} tiles ({inlined} inlined in tileset.json)")
    if checked == 0:
        pytest.skip("no tileset converted from a single glTF input among BIMTILES_TILESET_DIRS")


def test_feature_count_is_the_number_of_distinct_feature_ids():
    """EXT_mesh_features / EXT_instance_features: `featureCount` is the number of unique features
    the IDs name (the extensions' definition), not the property table's row count."""
    checked = 0
    for d in tileset_dirs():
        d = decoded_tileset(d)
        report_path = d / "report.json"
        if not report_path.is_file():
            continue
        for tile in json.loads(report_path.read_text())["tiles"]:
            if not tile["content"]:
                continue
            where = record_label(d, tile)
            doc, blob = read_glb(where, record_bytes(d, tile))
            for n in doc.get("nodes", []):
                ext = n.get("extensions", {})
                if "EXT_instance_features" in ext:
                    fid = ext["EXT_instance_features"]["featureIds"][0]
                    ids = read_scalars(doc, blob, ext["EXT_mesh_gpu_instancing"]["attributes"][f"_FEATURE_ID_{fid['attribute']}"])
                    assert fid["featureCount"] == len(set(ids)), f"{where}: instances {fid} name {len(set(ids))} features"
                    checked += 1
            for mesh in doc.get("meshes", []):
                for p in mesh["primitives"]:
                    ext = p.get("extensions", {})
                    if "EXT_mesh_features" not in ext or "KHR_draco_mesh_compression" in ext:
                        continue
                    fid = ext["EXT_mesh_features"]["featureIds"][0]
                    ids = read_scalars(doc, blob, p["attributes"][f"_FEATURE_ID_{fid['attribute']}"])
                    assert fid["featureCount"] == len(set(ids)), f"{where}: a primitive {fid} names {len(set(ids))} features"
                    checked += 1
    assert checked, "no feature ID sets found"
    print(f"featureCount checked on {checked} feature ID sets")
