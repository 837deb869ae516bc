"""CityJSON placement (issue 31) checked against pyproj, independently of bimtiles' code.

Each real dataset of ../shared/data/cityjson/ with a ``metadata.referenceSystem`` is converted by the
bimtiles binary (plain float tiles, no LOD, no dedup or instancing) and every output vertex is taken
to ECEF through the tiles' transforms (test_georef_crs.tileset_ecef_vertices). The independent
computation reads the file's JSON here: the vertices with ``transform`` applied (scale, translate),
pyproj from the CRS's horizontal part (a compound CRS such as EPSG:7415 = RD New + NAP) to
longitude/latitude, heights taken as ellipsoidal (as report.json says), the WGS84 formula to ECEF.
Every output vertex must be an input vertex and every input vertex of a drawn geometry (each
object's highest LoD) an output vertex, within a millimetre: across districts of a kilometre, and
the Zürich subset's ten, where placing by one linear map at the anchor would be metres off. Also:
--crs overrides the file's CRS.

Needs: pyproj, numpy (tests/python/requirements.txt) and target/release/bimtiles.
"""

import json
import os
import pathlib

import pytest

np = pytest.importorskip("numpy")
pyproj = pytest.importorskip("pyproj", reason="pyproj is not installed (pip install pyproj==3.7.2)")
from test_georef_crs import BIN, convert, ecef, nearest_distances, tileset_ecef_vertices  # noqa: E402

TOL_M = 0.001
SURFACE_TYPES = {"MultiSurface", "CompositeSurface", "Solid", "MultiSolid", "CompositeSolid"}
# (file under shared/data/cityjson, the CRS its metadata names)
DATASETS = [
    ("3dbag-5907-subset/3dbag_v210908_fd2cee53_5907_subset.json", "EPSG:7415"),
    ("denhaag-lod2/DenHaag_01.json", "EPSG:7415"),
    ("delfshaven-lod2-textured/3-20-DELFSHAVEN.city.json", "EPSG:28992"),
    ("zurich-lod2-subset/zurich_subset_lod2.json", "EPSG:2056"),
    ("seq-france-tile/tile_00000.city.jsonl", "EPSG:2154"),
    ("fzk-haus-lod2-textured/01-FZK-Haus-LoD2-Tex-no-Storey-CG30-V01_formatted.json", "EPSG:25832"),
]


def dataset(rel):
    for c in [os.environ.get("BIMTILES_SHARED", ""), str(pathlib.Path(__file__).resolve().parents[3] / "shared"),
              "/work/shared"]:
        p = pathlib.Path(c) / "data" / "cityjson" / rel
        if c and p.is_file():
            return p
    pytest.skip("shared CityJSON data not found (set BIMTILES_SHARED)")


def documents(path):
    """(header, [documents]): the file, or a CityJSONSeq's header and features."""
    if path.suffix == ".jsonl":
        lines = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        return lines[0], lines[1:]
    doc = json.loads(path.read_text())
    return doc, [doc]


def lod_value(g):
    lod = g.get("lod", 0)
    return float(lod) if not isinstance(lod, str) else float(lod)


def boundary_indices(b):
    if isinstance(b, list):
        for x in b:
            yield from boundary_indices(x)
    elif isinstance(b, int):
        yield b


def surfaces(b, depth):
    """The polygons (lists of rings) of a geometry's boundaries, `depth` levels above them."""
    return [s for x in b for s in surfaces(x, depth - 1)] if depth > 0 else b


def newell_area(ring):
    n = np.cross(ring, np.roll(ring, -1, axis=0)).sum(axis=0)
    return np.linalg.norm(n) / 2


def drawn_vertices(path):
    """Real-world (transformed) vertices of the polygons with an area (a degenerate one draws
    nothing) of each object's highest-LoD surface geometry, f64."""
    header, docs = documents(path)
    t = header.get("transform", {})
    scale = np.asarray(t.get("scale", [1, 1, 1]), dtype=np.float64)
    translate = np.asarray(t.get("translate", [0, 0, 0]), dtype=np.float64)
    out = []
    for doc in docs:
        v = np.asarray(doc["vertices"], dtype=np.float64) * scale + translate
        used = set()
        for co in doc["CityObjects"].values():
            geoms = [g for g in co.get("geometry", []) if g.get("type") in SURFACE_TYPES]
            if not geoms:
                continue
            best = max(lod_value(g) for g in geoms)
            for g in geoms:
                if lod_value(g) != best:
                    continue
                depth = {"MultiSurface": 0, "CompositeSurface": 0, "Solid": 1}.get(g["type"], 2)
                for polygon in surfaces(g["boundaries"], depth):
                    outer = v[polygon[0]]
                    if newell_area(outer - outer[0]) > 1e-6:
                        used.update(boundary_indices(polygon))
        out.append(v[sorted(used)])
    return np.concatenate(out)


def horizontal(crs):
    c = pyproj.CRS(crs)
    return c.sub_crs_list[0] if c.is_compound else c


def truth_ecef(crs, xyz):
    t = pyproj.Transformer.from_crs(horizontal(crs), "EPSG:4326", always_xy=True)
    lon, lat = t.transform(xyz[:, 0], xyz[:, 1])
    return ecef(np.asarray(lon), np.asarray(lat), xyz[:, 2]), t.get_last_used_operation().description


def unique_rows(p, step_m=1e-4):
    """One of each point (output vertices repeat per triangle corner)."""
    _, first = np.unique(np.round(p / step_m).astype(np.int64), axis=0, return_index=True)
    return p[np.sort(first)]


def worst_both_ways(ours, theirs):
    ours = unique_rows(ours)
    return nearest_distances(ours, theirs).max(), nearest_distances(theirs, ours).max()


@pytest.mark.parametrize("rel,crs", DATASETS, ids=[d[0].split("/")[0] for d in DATASETS])
def test_cityjson_vertices_land_where_pyproj_puts_them(rel, crs, tmp_path):
    if not BIN.is_file():
        pytest.skip(f"{BIN} not built")
    path = dataset(rel)
    out = tmp_path / "out"
    convert([path], out)
    report = json.loads((out / "report.json").read_text())
    geo = report["georeference"]
    assert geo["origin_source"] == "input-crs", geo
    [used] = geo["crs"]
    assert used["source"] == "cityjson-reference-system", used
    assert used["crs"] == f"EPSG:{horizontal(crs).to_epsg()}", used
    assert "ellipsoidal" in used["height_reference"]
    theirs, operation = truth_ecef(crs, drawn_vertices(path))
    worst, back = worst_both_ways(tileset_ecef_vertices(out), theirs)
    print(
        f"\n{path.name} ({crs}): {len(theirs)} input vertices, worst {worst * 1000:.3f} mm, back {back * 1000:.3f} mm; "
        f"bimtiles' PROJ operation '{used['operation']}', pyproj's '{operation}'"
    )
    assert worst < TOL_M and back < TOL_M


def test_crs_option_overrides_the_files_reference_system(tmp_path):
    if not BIN.is_file():
        pytest.skip(f"{BIN} not built")
    rel = "fzk-haus-lod2-textured/01-FZK-Haus-LoD2-Tex-no-Storey-CG30-V01_formatted.json"
    path = dataset(rel)
    out = tmp_path / "out"
    # ETRS89 / UTM 32N read as WGS 84 / UTM 32N: the same grid on another datum (same numbers here).
    convert([path, "--crs", "EPSG:32632"], out)
    geo = json.loads((out / "report.json").read_text())["georeference"]
    [used] = geo["crs"]
    assert used["crs"] == "EPSG:32632" and used["source"] == "option", used
    theirs, _ = truth_ecef("EPSG:32632", drawn_vertices(path))
    worst, back = worst_both_ways(tileset_ecef_vertices(out), theirs)
    assert worst < TOL_M and back < TOL_M, (worst, back)
