"""Georeferencing in projected CRSs (issue 29), checked independently of bimtiles' code.

IFC files are made here from the shared IfcOpenHouse_IFC4.ifc (millimetres) with IfcOpenShell: the
site's RefLatitude/RefLongitude removed, an IfcProjectedCRS and an IfcMapConversion with a rotated x
axis added, in seven national grids (RD New, LV95, British National Grid, Lambert-93, Gauss-Krüger,
NC State Plane, ETRS-TM35FIN), one named only through MapProjection/MapZone/GeodeticDatum (UTM), one
with a Scale that is not the unit conversion. Each is converted by the bimtiles binary with plain
float tiles, no LOD, no dedup or instancing, and every output vertex is taken to ECEF through the
tiles' node transforms and the tileset's root transform. The independent computation: IfcOpenShell's
triangulation in world coordinates, through the IfcMapConversion formula (Scale, rotation, offsets),
pyproj to longitude/latitude and the WGS84 formula to ECEF (heights ellipsoidal, as report.json says).
Every output vertex must lie within 5 cm of an independent vertex (datum-shifting CRSs: within the
accuracy PROJ reports for the operation, which both sides choose alike), and every independent vertex
within the same of an output vertex.

Also: a GLB in RD New coordinates with --crs EPSG:28992; a manifest with an RD New and a UTM 31N
entry; an unknown CRS warns once and falls back to the default placement, and with --strict-georef
fails with nothing written.

Needs: ifcopenshell, pyproj, numpy (tests/python/requirements.txt) and target/release/bimtiles.
"""

import json
import math
import os
import pathlib
import struct
import subprocess

import pytest

from tile_content import content_bytes

np = pytest.importorskip("numpy")
pyproj = pytest.importorskip("pyproj", reason="pyproj is not installed (pip install pyproj==3.7.2)")
ifcopenshell = pytest.importorskip("ifcopenshell")
import ifcopenshell.geom  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = pathlib.Path(os.environ.get("BIMTILES_BIN", REPO / "target/release/bimtiles"))
TOL_M = 0.05
from ifc_classes import EXCLUDED  # noqa: E402
WGS84_A = 6378137.0
WGS84_F = 1 / 298.257223563


def data_file(name):
    for c in [os.environ.get("BIMTILES_SHARED", ""), str(REPO.parent / "shared"), "/work/shared"]:
        p = pathlib.Path(c) / "data" / name
        if c and p.is_file():
            return p
    return None


def ecef(lon_deg, lat_deg, h):
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    e2 = WGS84_F * (2 - WGS84_F)
    n = WGS84_A / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.stack(
        [(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1 - e2) + h) * np.sin(lat)],
        axis=-1,
    )


def map_to_ecef(crs, e, n, h):
    t = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = t.transform(e, n)
    return ecef(np.asarray(lon), np.asarray(lat), np.asarray(h))


def ifcopenshell_world_mesh(path):
    """The triangles of the products bimtiles draws, IFC world frame, metres: (vertices, faces)."""
    f = ifcopenshell.open(str(path))
    s = ifcopenshell.geom.settings()
    s.set("use-world-coords", True)
    it = ifcopenshell.geom.iterator(s, f, 1, exclude=EXCLUDED)
    verts, faces, n = [], [], 0
    if it.initialize():
        while True:
            g = it.get().geometry
            if len(g.faces) >= 3:
                v = np.asarray(g.verts, dtype=np.float64).reshape(-1, 3)
                verts.append(v)
                faces.append(np.asarray(g.faces, dtype=np.int64).reshape(-1, 3) + n)
                n += len(v)
            if not it.next():
                break
    return np.concatenate(verts), np.concatenate(faces)


def point_triangle_distances(points, tri):
    """Distance from each point to the nearest of the triangles `tri` (n, 3, 3) (Ericson's
    closest-point-on-triangle, vectorized over triangles)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    out = np.empty(len(points))
    for i, p in enumerate(points):
        ab, ac, ap = b - a, c - a, p - a
        n = np.cross(ab, ac)
        nn = (n * n).sum(axis=1)
        ok = nn > 1e-18
        # Barycentric coordinates of the projection; inside -> plane distance, else edges.
        v0, v1, v2 = ab, ac, ap
        d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
        d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
        den = np.where(ok, d00 * d11 - d01 * d01, 1.0)
        v = (d11 * d20 - d01 * d21) / den
        w = (d00 * d21 - d01 * d20) / den
        inside = ok & (v >= 0) & (w >= 0) & (v + w <= 1)
        plane = np.abs((ap * n).sum(1)) / np.sqrt(np.where(ok, nn, 1.0))
        best = np.where(inside, plane, np.inf)

        def seg(q0, q1):
            d = q1 - q0
            t = np.clip(((p - q0) * d).sum(1) / np.maximum((d * d).sum(1), 1e-30), 0, 1)
            x = q0 + d * t[:, None] - p
            return np.sqrt((x * x).sum(1))

        best = np.minimum(best, np.minimum(seg(a, b), np.minimum(seg(b, c), seg(c, a))))
        out[i] = best.min()
    return out


def node_matrix(node):
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    t = node.get("translation", [0, 0, 0])
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    sc = node.get("scale", [1, 1, 1])
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m[:3, :3] = r * np.asarray(sc)
    m[:3, 3] = t
    return m


def glb_positions(glb):
    """Float POSITIONs of a GLB's drawn nodes (a path, or the GLB's bytes), in the glTF scene frame (y-up)."""
    data = glb if isinstance(glb, (bytes, bytearray)) else pathlib.Path(glb).read_bytes()
    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + jlen])
    bin_chunk = data[20 + jlen + 8 :]
    out = []

    def walk(i, parent):
        node = doc["nodes"][i]
        m = parent @ node_matrix(node)
        if "mesh" in node:
            assert "extensions" not in node, "instancing must be off for this check"
            for prim in doc["meshes"][node["mesh"]]["primitives"]:
                acc = doc["accessors"][prim["attributes"]["POSITION"]]
                ext = prim.get("extensions", {})
                assert acc["componentType"] == 5126 and "KHR_draco_mesh_compression" not in ext, "plain float tiles"
                bv = doc["bufferViews"][acc["bufferView"]]
                stride = bv.get("byteStride", 12)
                start = bv.get("byteOffset", 0) + acc.get("byteOffset", 0)
                raw = np.frombuffer(bin_chunk, dtype=np.uint8, count=stride * acc["count"], offset=start)
                p = np.ndarray((acc["count"], 3), dtype="<f4", buffer=raw.tobytes(), strides=(stride, 4))
                p = np.c_[p.astype(np.float64), np.ones(len(p))]
                out.append((p @ m.T)[:, :3])
        for c in node.get("children", []):
            walk(c, m)

    for root in doc["scenes"][doc.get("scene", 0)]["nodes"]:
        walk(root, np.eye(4))
    return np.concatenate(out) if out else np.zeros((0, 3))


Y_UP_TO_Z_UP = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


def tileset_ecef_vertices(out_dir, leaves_only=False):
    """Every vertex of every tile (`leaves_only`: of the tiles without children, full detail), in
    ECEF (tile transforms, glTF y-up to z-up); a content inlined in tileset.json as a data URI (the
    root, by default) is read from there."""
    ts = json.loads((out_dir / "tileset.json").read_text())
    pts = []

    def walk(tile, parent):
        m = parent
        if "transform" in tile:
            m = parent @ np.asarray(tile["transform"], dtype=np.float64).reshape(4, 4).T
        uri = tile.get("content", {}).get("uri")
        if uri and not (leaves_only and tile.get("children")):
            p = glb_positions(content_bytes(out_dir, uri))
            p = np.c_[p, np.ones(len(p))] @ (m @ Y_UP_TO_Z_UP).T
            pts.append(p[:, :3])
        for c in tile.get("children", []):
            walk(c, m)

    walk(ts["root"], np.eye(4))
    return np.concatenate(pts)


def nearest_distances(a, b, chunk=512):
    """For each point of `a`, the distance to the nearest point of `b` (brute force, chunked)."""
    centre = b.mean(axis=0)
    a, b = a - centre, b - centre
    bb = (b * b).sum(axis=1)
    out = np.empty(len(a))
    for i in range(0, len(a), chunk):
        x = a[i : i + chunk]
        d2 = (x * x).sum(axis=1)[:, None] + bb[None, :] - 2 * x @ b.T
        out[i : i + chunk] = np.sqrt(np.maximum(d2.min(axis=1), 0))
    return out


def run(args, check=True):
    r = subprocess.run([str(BIN), *map(str, args)], capture_output=True, text=True)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def convert(inputs, out, extra=()):
    return run(
        ["convert", *inputs, "--out", out, "--force", "--quiet", "--compression", "none", "--lod", "none",
         "--no-dedup", "--no-instancing", *extra]
    )


def with_map_conversion(src, dst, crs, e, n, h, theta_deg, scale, projection=None, zone=None, datum=None):
    f = ifcopenshell.open(str(src))
    for s in f.by_type("IfcSite"):
        s.RefLatitude = None
        s.RefLongitude = None
    ctx = [c for c in f.by_type("IfcGeometricRepresentationContext") if not c.is_a("IfcGeometricRepresentationSubContext")][0]
    p = f.create_entity("IfcProjectedCRS", Name=crs, GeodeticDatum=datum, MapProjection=projection, MapZone=zone)
    f.create_entity(
        "IfcMapConversion", SourceCRS=ctx, TargetCRS=p, Eastings=e, Northings=n, OrthogonalHeight=h,
        XAxisAbscissa=math.cos(math.radians(theta_deg)), XAxisOrdinate=math.sin(math.radians(theta_deg)), Scale=scale,
    )
    f.write(str(dst))


_MESHES = {}


def shared_model(name):
    """(path, IfcOpenShell mesh) of a shared IFC file, triangulated once per session."""
    src = data_file(name)
    if src is None:
        pytest.skip("shared data not found (set BIMTILES_SHARED)")
    if not BIN.is_file():
        pytest.skip(f"{BIN} not built (cargo build --release)")
    if name not in _MESHES:
        _MESHES[name] = ifcopenshell_world_mesh(src)
    return src, _MESHES[name]


@pytest.fixture(scope="module")
def house():
    return shared_model("IfcOpenHouse_IFC4.ifc")


# (CRS name, E, N, OrthogonalHeight m, x-axis angle °, Scale, MapProjection, MapZone, GeodeticDatum, expected CRS)
# IfcOpenHouse is in millimetres: Scale 0.001 converts to the map's metres (IFC4: Scale converts
# project length units to map units). The last case is AC20-FZK-Haus (metres).
CASES = [
    ("EPSG:28992", 155000.0, 463000.0, 5.0, 30.0, 0.001, None, None, None, "EPSG:28992"),
    ("EPSG:2056", 2600000.0, 1200000.0, 540.0, -20.0, 0.001, None, None, None, "EPSG:2056"),
    ("EPSG:27700", 530000.0, 180000.0, 20.0, 45.0, 0.001, None, None, None, "EPSG:27700"),
    ("EPSG:2154", 652000.0, 6862000.0, 35.0, 10.0, 0.001, None, None, None, "EPSG:2154"),
    ("EPSG:31467", 3458000.0, 5438000.0, 115.0, 60.0, 0.001, None, None, None, "EPSG:31467"),
    ("EPSG:32119", 600000.0, 200000.0, 90.0, -75.0, 0.001, None, None, None, "EPSG:32119"),
    ("3067", 385000.0, 6672000.0, 12.0, 15.0, 0.001, None, None, None, "EPSG:3067"),
    # Named only through MapProjection + MapZone + GeodeticDatum (the Name is no CRS PROJ knows).
    ("Site grid", 458000.0, 5438000.0, 110.0, -40.0, 0.001, "UTM", "32N", "ETRS89", "EPSG:25832"),
    # Scale 0.0015: 1.5 map metres per project metre (a scaled engineering grid).
    ("EPSG:28992", 156000.0, 462000.0, 3.0, 120.0, 0.0015, None, None, None, "EPSG:28992"),
    ("EPSG:2056", 2683000.0, 1248000.0, 410.0, 25.0, 1.0, None, None, None, "EPSG:2056"),
]
FZK_CASE = len(CASES) - 1


@pytest.mark.parametrize("index", range(len(CASES)), ids=[f"{c[9]}-{c[5]}-{c[6] or 'name'}" for c in CASES])
def test_ifc_map_conversion_vertices_land_where_pyproj_puts_them(index, tmp_path):
    case = CASES[index]
    fzk = index == FZK_CASE
    src, (world, faces) = shared_model("AC20-FZK-Haus.ifc" if fzk else "IfcOpenHouse_IFC4.ifc")
    name, e0, n0, h0, theta, scale, projection, zone, datum, expected = case
    ifc = tmp_path / "georef.ifc"
    with_map_conversion(src, ifc, name, e0, n0, h0, theta, scale, projection, zone, datum)
    out = tmp_path / "out"
    r = convert([ifc], out)
    assert "warning" not in r.stderr, r.stderr
    report = json.loads((out / "report.json").read_text())
    geo = report["georeference"]
    assert geo["origin_source"] == "input-crs", geo
    [used] = geo["crs"]
    assert used["crs"] == expected, used
    assert used["source"] == ("ifc-map-projection" if projection else "ifc-name"), used
    assert "ellipsoidal" in used["height_reference"]
    accuracy = used["accuracy_m"] or 0.0
    tol = max(TOL_M, accuracy)

    # Independent: IfcOpenShell world metres -> project units -> map (IfcMapConversion) -> pyproj.
    unit_m = 1.0 if fzk else 0.001
    a, b = math.cos(math.radians(theta)), math.sin(math.radians(theta))
    x, y, z = (world / unit_m).T
    e = e0 + scale * (a * x - b * y)
    n = n0 + scale * (b * x + a * y)
    h = h0 + scale * z
    theirs = map_to_ecef(expected, e, n, h)
    ours = tileset_ecef_vertices(out)
    d_ours = nearest_distances(ours, theirs)
    # An output vertex that is no IfcOpenShell vertex (the two kernels tessellate a few curved
    # faces differently) must lie on IfcOpenShell's surface.
    far = d_ours >= TOL_M
    if far.any():
        d_ours[far] = point_triangle_distances(ours[far], theirs[faces])
    d_theirs = nearest_distances(theirs, ours)
    print(
        f"\n{src.name} in {expected} ({name}, scale {scale}, x axis {theta}°): {len(ours)} output vertices, "
        f"worst {d_ours.max() * 1000:.1f} mm (to IfcOpenShell+pyproj; {far.sum()} off its vertices), "
        f"back {d_theirs.max() * 1000:.1f} mm; "
        f"PROJ operation '{used['operation']}', accuracy {used['accuracy_m']} m, tolerance {tol} m"
    )
    assert d_ours.max() < tol and d_theirs.max() < tol


def write_glb(path, positions, indices, translation):
    """A one-mesh GLB: float positions (local, small) under a node at `translation` (f64 in JSON)."""
    pos = np.asarray(positions, dtype="<f4")
    idx = np.asarray(indices, dtype="<u4")
    blob = pos.tobytes() + idx.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "building", "mesh": 0, "translation": list(map(float, translation))}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
             "min": pos.min(axis=0).tolist(), "max": pos.max(axis=0).tolist()},
            {"bufferView": 1, "componentType": 5125, "count": len(idx), "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
            {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": idx.nbytes},
        ],
        "buffers": [{"byteLength": len(blob)}],
    }
    j = json.dumps(doc).encode()
    j += b" " * (-len(j) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(blob), 0x004E4942) + blob
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)


def block(size=(40.0, 12.0, 25.0)):
    """A box of `size` (x east, y up, z south: glTF) as 12 triangles, corner at the origin."""
    sx, sy, sz = size
    p = [(x, y, z) for x in (0, sx) for y in (0, sy) for z in (0, -sz)]
    f = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4),
         (1, 5, 7), (1, 7, 3)]
    return np.asarray(p, dtype=np.float64), [i for t in f for i in t]


def glb_truth(crs, positions, translation):
    """glTF +x = easting, -z = northing, +y = height, through pyproj."""
    p = np.asarray(positions) + np.asarray(translation)
    return map_to_ecef(crs, p[:, 0], -p[:, 2], p[:, 1])


def test_glb_in_rd_new_with_crs_option(tmp_path):
    if not BIN.is_file():
        pytest.skip(f"{BIN} not built")
    pos, idx = block()
    t = (155000.0, 4.0, -463000.0)
    glb = tmp_path / "rd.glb"
    write_glb(glb, pos, idx, t)
    out = tmp_path / "out"
    r = convert([glb, "--crs", "EPSG:28992"], out)
    assert "warning" not in r.stderr, r.stderr
    geo = json.loads((out / "report.json").read_text())["georeference"]
    assert geo["origin_source"] == "input-crs" and geo["crs"][0]["source"] == "option", geo
    ours = tileset_ecef_vertices(out)
    theirs = glb_truth("EPSG:28992", pos, t)
    tol = max(TOL_M, geo["crs"][0]["accuracy_m"] or 0)
    worst = max(nearest_distances(ours, theirs).max(), nearest_distances(theirs, ours).max())
    print(f"\nGLB in RD New: worst {worst * 1000:.1f} mm (tolerance {tol} m)")
    assert worst < tol


def test_manifest_mixing_two_crs(tmp_path):
    if not BIN.is_file():
        pytest.skip(f"{BIN} not built")
    pos, idx = block()
    t_rd = (155000.0, 4.0, -463000.0)
    # The same kind of block 800 m east, written in UTM 31N coordinates.
    to_utm = pyproj.Transformer.from_crs("EPSG:28992", "EPSG:32631", always_xy=True)
    e, n = to_utm.transform(155800.0, 463000.0)
    t_utm = (round(e, 3), 2.0, -round(n, 3))
    write_glb(tmp_path / "rd.glb", pos, idx, t_rd)
    write_glb(tmp_path / "utm.glb", pos, idx, t_utm)
    manifest = {
        "origin": {"longitude_deg": 5.39, "latitude_deg": 52.155, "height_m": 0},
        "models": [{"path": "rd.glb", "crs": "EPSG:28992"}, {"path": "utm.glb", "crs": "EPSG:32631"}],
    }
    (tmp_path / "campus.json").write_text(json.dumps(manifest))
    out = tmp_path / "out"
    r = convert(["--manifest", tmp_path / "campus.json"], out)
    assert "warning" not in r.stderr, r.stderr
    geo = json.loads((out / "report.json").read_text())["georeference"]
    assert [c["crs"] for c in geo["crs"]] == ["EPSG:28992", "EPSG:32631"], geo
    assert all(c["source"] == "manifest" for c in geo["crs"])
    theirs = np.concatenate([glb_truth("EPSG:28992", pos, t_rd), glb_truth("EPSG:32631", pos, t_utm)])
    ours = tileset_ecef_vertices(out)
    tol = max([TOL_M] + [c["accuracy_m"] or 0 for c in geo["crs"]])
    worst = max(nearest_distances(ours, theirs).max(), nearest_distances(theirs, ours).max())
    print(f"\nmanifest RD New + UTM 31N: worst {worst * 1000:.1f} mm (tolerance {tol} m)")
    assert worst < tol


def test_unknown_crs_warns_and_falls_back_or_fails_when_strict(house, tmp_path):
    src = house[0]
    ifc = tmp_path / "unknown.ifc"
    with_map_conversion(src, ifc, "EPSG:99999", 155000.0, 463000.0, 5.0, 30.0, 0.001)
    out = tmp_path / "out"
    # --quiet prints nothing on success: the warning is in report.json.
    r = convert([ifc], out)
    assert r.stderr == "", r.stderr
    r = run(["convert", ifc, "--out", tmp_path / "loud", "--compression", "none"])
    warnings = [l for l in r.stderr.splitlines() if l.startswith("warning:")]
    assert len(warnings) == 1 and "EPSG:99999" in warnings[0], r.stderr
    geo = json.loads((out / "report.json").read_text())["georeference"]
    assert geo["origin_source"] == "default" and geo["crs"] == [], geo
    assert len(geo["warnings"]) == 1 and "EPSG:99999" in geo["warnings"][0], geo

    strict = tmp_path / "strict"
    r = run(["convert", ifc, "--out", strict, "--quiet", "--strict-georef"], check=False)
    assert r.returncode != 0
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "EPSG:99999" in err[0] and "unknown.ifc" in err[0], r.stderr
    assert not strict.exists(), "nothing is written"
    assert not any(p.name.startswith(".strict") for p in tmp_path.iterdir())

    # --crs with a CRS whose unit is not a length (geographic degrees): the same warning path.
    pos, idx = block()
    glb = tmp_path / "deg.glb"
    write_glb(glb, pos, idx, (155000.0, 4.0, -463000.0))
    convert([glb, "--crs", "EPSG:4326"], tmp_path / "deg")
    warnings = json.loads((tmp_path / "deg" / "report.json").read_text())["warnings"]
    assert len(warnings) == 1 and "not a length" in warnings[0], warnings
