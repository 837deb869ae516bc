"""Independent check of our Draco output with another decoder (DracoPy, PyPI).

Our encoder is Debian's libdraco through shim/draco_shim.cc; DracoPy bundles its own
build of Draco, so a stream that our Rust code wrote and DracoPy reads back with the
expected counts, bounds and values is decodable by a third party, not only by us.

Two sources of streams:

1. Fixtures (always run): the Rust test
   ``draco::tests::write_independent_check_fixtures`` writes ``*.drc`` files and
   ``manifest.json`` (expected counts, per-attribute min/max, source positions/indices,
   tolerance) into ``$BIMTILES_DRACO_FIXTURE_DIR``.  This file runs that test itself
   through cargo into a temporary folder, unless ``BIMTILES_DRACO_FIXTURE_DIR`` already
   holds a ``manifest.json`` (then it only reads it).  ``BIMTILES_CARGO_MANIFEST`` picks
   the Cargo.toml (default: the repository's); ``CARGO_TARGET_DIR`` is honoured.

2. Tiles (run when ``BIMTILES_TILE_DIR`` is set): every ``*.glb`` in a ``tiles/`` folder of a
   tileset (one with a ``tileset.json`` beside it) below that folder, and every content inlined in
   such a ``tileset.json`` as a data URI (bimtiles' default for the root: tile_content.py);
   each primitive with ``KHR_draco_mesh_compression`` is decoded and its accessors are
   checked against the decoded data (counts, POSITION min/max, attribute ids, integer
   feature ids), as the extension requires.

Run:  python3 -m pytest -q tests/python/test_draco_independent.py
Needs: pip install DracoPy numpy pytest
"""

import json
import os
import pathlib
import struct
import subprocess

import pytest

from tile_content import inlined_contents, record_bytes, record_label

np = pytest.importorskip("numpy")
DracoPy = pytest.importorskip("DracoPy")

REPO = pathlib.Path(__file__).resolve().parents[2]
FIXTURE_TEST = "draco::fixtures::write_independent_check_fixtures"


# --------------------------------------------------------------------------- helpers


def decode(data: bytes):
    mesh = DracoPy.decode(data)
    assert isinstance(mesh, DracoPy.DracoMesh), "stream decoded as a point cloud, not a mesh"
    return mesh


def attribute_by_uid(mesh, uid):
    for att in mesh.attributes:
        if att["unique_id"] == uid:
            data = np.asarray(att["data"])
            return att, data.reshape(len(data), -1)
    raise AssertionError(f"no attribute with unique id {uid}")


def max_deviation_within(a, b, tol):
    """Largest distance (max-norm) from a point of ``a`` to its nearest point of ``b``,
    looking only within ``tol``; returns inf if some point of ``a`` has no point of
    ``b`` within ``tol``.  Uses a hash grid of cell ``tol`` (no scipy here)."""
    cell = max(float(tol), 1e-12)
    keys_b = np.floor(b / cell).astype(np.int64)
    grid = {}
    for i, k in enumerate(map(tuple, keys_b)):
        grid.setdefault(k, []).append(i)
    keys_a = np.floor(a / cell).astype(np.int64)
    offsets = [(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)]
    worst = 0.0
    for i, (kx, ky, kz) in enumerate(map(tuple, keys_a)):
        cand = []
        for dx, dy, dz in offsets:
            cand.extend(grid.get((kx + dx, ky + dy, kz + dz), ()))
        if not cand:
            return float("inf")
        d = np.abs(b[cand] - a[i]).max(axis=1).min()
        if d > tol:
            return float("inf")
        worst = max(worst, float(d))
    return worst


def total_area(pos, tris):
    p = pos[tris]
    return float(np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum() / 2)


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def fixture_dir(tmp_path_factory):
    given = os.environ.get("BIMTILES_DRACO_FIXTURE_DIR")
    if given and (pathlib.Path(given) / "manifest.json").exists():
        return pathlib.Path(given)
    out = pathlib.Path(given) if given else tmp_path_factory.mktemp("draco_fixtures")
    manifest = os.environ.get("BIMTILES_CARGO_MANIFEST", str(REPO / "Cargo.toml"))
    env = dict(os.environ, BIMTILES_DRACO_FIXTURE_DIR=str(out))
    cmd = ["cargo", "test", "--manifest-path", manifest, "--lib", FIXTURE_TEST, "--", "--exact"]
    run = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert run.returncode == 0, f"{' '.join(cmd)} failed:\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    assert (out / "manifest.json").exists(), f"the Rust test wrote no manifest:\n{run.stderr[-3000:]}"
    return out


def load_cases(d):
    manifest = json.loads((d / "manifest.json").read_text())
    assert manifest["version"] == 1
    assert manifest["cases"], "manifest lists no case"
    return manifest["cases"]


def test_fixtures_decode_with_dracopy(fixture_dir):
    cases = load_cases(fixture_dir)
    for case in cases:
        name = case["name"]
        mesh = decode((fixture_dir / case["drc"]).read_bytes())
        faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
        points = np.asarray(mesh.points, dtype=np.float64).reshape(-1, 3)
        # Counts the glTF accessors will carry.
        assert len(faces) == case["face_count"], name
        assert len(points) == case["point_count"], name
        assert faces.min() >= 0 and faces.max() < len(points), name

        # Every attribute is there, under the unique id our encoder reported, with the
        # same component count and the min/max we would write into the accessors.
        for att in case["attributes"]:
            info, data = attribute_by_uid(mesh, att["unique_id"])
            assert data.shape == (case["point_count"], att["components"]), (name, att["kind"])
            lo = data.min(axis=0).astype(np.float64)
            hi = data.max(axis=0).astype(np.float64)
            scale = np.maximum(1.0, np.abs(np.asarray(att["max"], dtype=np.float64)))
            assert np.all(np.abs(lo - att["min"]) <= 1e-6 * scale), (name, att["kind"], lo, att["min"])
            assert np.all(np.abs(hi - att["max"]) <= 1e-6 * scale), (name, att["kind"], hi, att["max"])
            if att["kind"] == "POSITION":
                assert np.allclose(data, points), name

        # Against the source mesh: every decoded vertex is near a source vertex and every
        # referenced source vertex near a decoded one (vertex Hausdorff distance), within
        # half a quantization step; the surface area is the same.
        src = case["source"]
        spos = np.fromfile(fixture_dir / src["positions"], dtype="<f4").astype(np.float64).reshape(-1, 3)
        sidx = np.fromfile(fixture_dir / src["indices"], dtype="<u4").astype(np.int64).reshape(-1, 3)
        assert len(spos) == src["vertex_count"] and len(sidx) == src["face_count"]
        used = spos[np.unique(sidx)]
        tol = case["position_tolerance"]
        fwd = max_deviation_within(points, used, tol)
        back = max_deviation_within(used, points, tol)
        assert fwd <= tol and back <= tol, (name, fwd, back, tol)
        a_src, a_dec = total_area(spos, sidx), total_area(points, faces)
        assert abs(a_src - a_dec) <= 1e-3 * a_src, (name, a_src, a_dec)
        if case["method"] == "Sequential":
            assert len(points) == len(spos)
            assert np.abs(points - spos).max() <= tol, name
            assert np.array_equal(faces, sidx), name

        # Feature ids: exact integers, the same set as the source.
        for uid in case["feature_id_unique_ids"]:
            _, ids = attribute_by_uid(mesh, uid)
            ids = ids.reshape(-1).astype(np.float64)
            assert np.array_equal(ids, np.round(ids)), (name, "feature ids not integers")
            assert sorted(set(ids.astype(np.int64).tolist())) == src["feature_ids"], name
        print(f"{name}: {len(faces)} faces, {len(points)} points, max deviation {max(fwd, back):.2e} (tol {tol:.2e})")


# --------------------------------------------------------------------------- tiles


def read_glb(path, data=None):
    """(JSON, BIN chunk) of the GLB at `path`, or of its bytes `data` (then `path` only names it)."""
    if data is None:
        data = pathlib.Path(path).read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2, f"{path}: not a GLB 2.0"
    off, doc, blob = 12, None, None
    while off + 8 <= min(length, len(data)):
        clen, ctype = struct.unpack_from("<II", data, off)
        chunk = data[off + 8 : off + 8 + clen]
        if ctype == 0x4E4F534A:
            doc = json.loads(chunk)
        elif ctype == 0x004E4942:
            blob = chunk
        off += 8 + clen
    assert doc is not None, f"{path}: no JSON chunk"
    return doc, blob


COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def check_glb(path, data=None):
    """Checks every Draco primitive of one GLB (the file `path`, or its bytes `data` named by `path`);
    returns the number checked."""
    doc, blob = read_glb(path, data)
    checked = 0
    for mi, mesh_def in enumerate(doc.get("meshes", [])):
        for pi, prim in enumerate(mesh_def.get("primitives", [])):
            ext = prim.get("extensions", {}).get("KHR_draco_mesh_compression")
            if ext is None:
                continue
            where = f"{pathlib.Path(path).name} mesh {mi} primitive {pi}"
            assert "KHR_draco_mesh_compression" in doc.get("extensionsUsed", []), where
            assert prim.get("mode", 4) in (4, 5), where
            bv = doc["bufferViews"][ext["bufferView"]]
            assert "uri" not in doc["buffers"][bv["buffer"]], f"{where}: external buffers not handled"
            start = bv.get("byteOffset", 0)
            mesh = decode(bytes(blob[start : start + bv["byteLength"]]))
            faces = np.asarray(mesh.faces).reshape(-1, 3)
            n_points = len(np.asarray(mesh.points).reshape(-1, 3))
            if "indices" in prim:
                assert doc["accessors"][prim["indices"]]["count"] == 3 * len(faces), f"{where}: indices count"
            # Our tiler puts every attribute inside Draco.
            assert set(prim["attributes"]) == set(ext["attributes"]), f"{where}: attributes outside Draco"
            for semantic, uid in ext["attributes"].items():
                acc = doc["accessors"][prim["attributes"][semantic]]
                info, data = attribute_by_uid(mesh, uid)
                assert acc["count"] == n_points == len(data), f"{where}: {semantic} count"
                assert COMPONENTS[acc["type"]] == data.shape[1], f"{where}: {semantic} type"
                if semantic == "POSITION":
                    assert "min" in acc and "max" in acc, f"{where}: POSITION needs min/max"
                    lo, hi = data.min(axis=0), data.max(axis=0)
                    tol = 1e-6 * max(1.0, float(np.abs(data).max()))
                    assert np.all(np.abs(lo - acc["min"]) <= tol), f"{where}: POSITION min {acc['min']} vs {lo}"
                    assert np.all(np.abs(hi - acc["max"]) <= tol), f"{where}: POSITION max {acc['max']} vs {hi}"
                if semantic.startswith("_FEATURE_ID_") or semantic == "_BATCHID":
                    v = data.reshape(-1).astype(np.float64)
                    assert np.array_equal(v, np.round(v)), f"{where}: {semantic} not integers"
            checked += 1
    return checked


def tile_files():
    d = os.environ.get("BIMTILES_TILE_DIR")
    if not d:
        return []
    # Only tile content: a test folder may also hold deliberately broken input files.
    return sorted(p for p in pathlib.Path(d).rglob("*.glb")
                  if p.parent.name == "tiles" and (p.parent.parent / "tileset.json").is_file())


def inlined_tiles():
    """(label, bytes) of the contents inlined as data URIs in the tileset.json files below
    BIMTILES_TILE_DIR."""
    d = os.environ.get("BIMTILES_TILE_DIR")
    if not d:
        return []
    return [c for t in sorted(pathlib.Path(d).rglob("tileset.json")) for c in inlined_contents(t.parent)]


@pytest.mark.skipif(not os.environ.get("BIMTILES_TILE_DIR"), reason="BIMTILES_TILE_DIR not set")
def test_tiles_decode_with_dracopy():
    files, inlined = tile_files(), inlined_tiles()
    assert files or inlined, "no .glb under BIMTILES_TILE_DIR"
    total = sum(check_glb(f) for f in files)
    total_inlined = sum(check_glb(label, data) for label, data in inlined)
    print(f"checked {total + total_inlined} Draco primitives in {len(files)} GLB files and {len(inlined)} "
          f"GLBs inlined in tileset.json ({total_inlined} of the primitives)")


def shading_deviation_deg(path, data=None):
    """Per Draco primitive with normals (of the GLB file `path`, or its bytes `data` named by
    `path`): the median angle (degrees) between each decoded vertex normal and the area-weighted
    normal of the decoded faces that use the vertex (its copies included)."""
    doc, blob = read_glb(path, data)
    out = []
    for mesh_def in doc.get("meshes", []):
        for prim in mesh_def.get("primitives", []):
            ext = prim.get("extensions", {}).get("KHR_draco_mesh_compression")
            if ext is None or "NORMAL" not in ext["attributes"]:
                continue
            bv = doc["bufferViews"][ext["bufferView"]]
            start = bv.get("byteOffset", 0)
            mesh = decode(bytes(blob[start : start + bv["byteLength"]]))
            faces = np.asarray(mesh.faces).reshape(-1, 3)
            _, pos = attribute_by_uid(mesh, ext["attributes"]["POSITION"])
            _, nrm = attribute_by_uid(mesh, ext["attributes"]["NORMAL"])
            pos = pos.astype(np.float64)
            cross = np.cross(pos[faces[:, 1]] - pos[faces[:, 0]], pos[faces[:, 2]] - pos[faces[:, 0]])
            # Draco splits vertices at non-manifold spots; a copy keeps position and normal, so
            # the copies are joined again to sum all the faces of the vertex we wrote.
            _, vertex = np.unique(np.hstack([pos, nrm]), axis=0, return_inverse=True)
            vertex = vertex.reshape(-1)
            group_sum = np.zeros((vertex.max() + 1, 3))
            for k in range(3):
                np.add.at(group_sum, vertex[faces[:, k]], cross)
            face_sum = group_sum[vertex]
            weight = np.linalg.norm(face_sum, axis=1)
            used = weight > 0
            if not used.any():
                continue
            g = face_sum[used] / weight[used, None]
            n = nrm[used].astype(np.float64)
            n /= np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
            angle = np.degrees(np.arccos(np.clip((g * n).sum(axis=1), -1.0, 1.0)))
            out.append(float(np.median(angle)))
    return out


def simplified_tile_files():
    """Tiles that report.json lists as simplified (HLOD and LOD-chain content): (label, bytes),
    the root's read from tileset.json when it is inlined there."""
    d = os.environ.get("BIMTILES_TILE_DIR")
    out = []
    for report in sorted(pathlib.Path(d).rglob("report.json")) if d else []:
        tiles = json.loads(report.read_text()).get("tiles", [])
        for t in tiles:
            if not (t.get("simplified_from_triangles") and t.get("content") and t["content"].endswith(".glb")):
                continue
            if t.get("inlined_in_tileset"):
                out.append((record_label(report.parent, t), record_bytes(report.parent, t)))
            elif (report.parent / t["content"]).is_file():
                out.append((str(report.parent / t["content"]), None))
    return out


@pytest.mark.skipif(not os.environ.get("BIMTILES_TILE_DIR"), reason="BIMTILES_TILE_DIR not set")
def test_simplified_tiles_shade_the_faces_they_draw():
    """Simplified tiles take their normals from the faces Draco decodes (full-detail tiles keep
    the input's). Normals that disagree with the faces shade a tile wrongly and change shade when
    it refines: interpolated along collapsed edges, they were a median 20 degrees off on
    Mini_Project's HLOD root (14 on its children). Octahedral 8-bit normals are within about a
    degree."""
    files = simplified_tile_files()
    if not files:
        pytest.skip("no simplified tiles under BIMTILES_TILE_DIR")
    worst = sorted(((d, label) for label, data in files for d in shading_deviation_deg(label, data)), reverse=True)
    assert worst, "no Draco primitive with normals in the simplified tiles"
    inlined = sum(1 for _, data in files if data is not None)
    print(f"{len(files)} simplified tiles ({inlined} inlined in tileset.json); median normal-to-face angle "
          f"per primitive, worst: {worst[:3]}")
    assert worst[0][0] < 2.0, f"normals off their faces: {worst[:5]}"
