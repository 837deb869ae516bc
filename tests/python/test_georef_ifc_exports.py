"""Real georeferenced IFC exports (shared data/georef-ifc/) placed by bimtiles, checked vertex by
vertex against IfcOpenShell and pyproj, independently of bimtiles' code.

For the exports IfcOpenShell opens that carry a map placement, IfcOpenShell triangulates the file in
world coordinates (metres); the file's own placement values (read here with IfcOpenShell, through
the formula each convention defines) take every vertex to map coordinates, pyproj to longitude and
latitude, the WGS84 formula to ECEF (heights ellipsoidal, as report.json says). bimtiles converts
the file with plain float tiles, no LOD, no dedup or instancing; a sample of its output vertices
(ECEF through the tiles' transforms) must each lie near an independent triangle: within 5 cm plus
the Earth's curvature across the model (bimtiles maps an IFC model by one linear map at its anchor,
so its far edge stays on the anchor's tangent plane). Datum shifts (RD New, LUREF, ETRS89) are not
allowed for: pyproj and Debian's PROJ must choose the same operation.

Conventions covered: IfcRigidOperation to a projected CRS (Civil 3D), Eastings/Northings written in
project millimetres (Revit 2020, read in project units as its MANIFEST row does), IFC2X3
ePSet_MapConversion on IfcSite with a compound CRS (Duplex), IfcMapConversion with a rotation
(Van Brienenoord bridge), IfcRigidOperation into an IfcGeographicCRS in degrees (buildingSMART).

Needs: ifcopenshell, pyproj, numpy and target/release/bimtiles.
"""

import json
import math
import os
import pathlib

import pytest

np = pytest.importorskip("numpy")
pyproj = pytest.importorskip("pyproj")
ifcopenshell = pytest.importorskip("ifcopenshell")
import ifcopenshell.util.element  # noqa: E402

from test_georef_crs import (  # noqa: E402
    convert,
    ecef,
    ifcopenshell_world_mesh,
    map_to_ecef,
    point_triangle_distances,
    tileset_ecef_vertices,
)

REPO = pathlib.Path(__file__).resolve().parents[2]
EARTH_RADIUS_M = 6371008.8
SAMPLE = 300


def export(name):
    for c in [os.environ.get("BIMTILES_SHARED", ""), str(REPO.parent / "shared"), "/work/shared"]:
        p = pathlib.Path(c) / "data" / "georef-ifc" / name
        if c and p.is_file():
            return p
    return None


def rotation(a, b):
    n = math.hypot(a, b) or 1.0
    return a / n, b / n


def mapped(v, e0, n0, h0, a, b, scale):
    """IfcMapConversion: E = E0 + s(a x - b y), N = N0 + s(b x + a y), H = H0 + s z."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return e0 + scale * (a * x - b * y), n0 + scale * (b * x + a * y), h0 + scale * z


def civil3d(f, v):
    op = f.by_type("IfcRigidOperation")[0]
    e, n, h = mapped(v, op.FirstCoordinate.wrappedValue, op.SecondCoordinate.wrappedValue, op.Height or 0.0, 1, 0, 1)
    return map_to_ecef(op.TargetCRS.Name, e, n, h)


def revit_millimetres(f, v):
    # E/N and OrthogonalHeight are in the project's millimetres (MANIFEST row 8); the geometry
    # comes from IfcOpenShell in metres, so the conversion has no further unit change.
    m = f.by_type("IfcMapConversion")[0]
    a, b = rotation(m.XAxisAbscissa, m.XAxisOrdinate)
    e, n, h = mapped(v, m.Eastings * 1e-3, m.Northings * 1e-3, m.OrthogonalHeight * 1e-3, a, b, 1.0)
    return map_to_ecef(m.TargetCRS.Name, e, n, h)


def property_sets(f, v):
    site = f.by_type("IfcSite")[0]
    psets = ifcopenshell.util.element.get_psets(site)
    mc, crs = psets["ePSet_MapConversion"], psets["ePSet_ProjectedCRS"]
    a, b = rotation(mc["XAxisAbscissa"], mc["XAxisOrdinate"])
    e, n, h = mapped(v, mc["Eastings"], mc["Northings"], mc["OrthogonalHeight"], a, b, mc.get("Scale") or 1.0)
    return map_to_ecef(crs["Name"], e, n, h)


def map_conversion(f, v):
    m = f.by_type("IfcMapConversion")[0]
    a, b = rotation(m.XAxisAbscissa, m.XAxisOrdinate)
    e, n, h = mapped(v, m.Eastings, m.Northings, m.OrthogonalHeight, a, b, m.Scale or 1.0)
    return map_to_ecef(m.TargetCRS.Name, e, n, h)


def geographic(f, v):
    """IfcRigidOperation in degrees: the project origin at (lon, lat, Height) of the target CRS,
    project x east, y north, z up there."""
    op = f.by_type("IfcRigidOperation")[0]
    lon, lat = pyproj.Transformer.from_crs(op.TargetCRS.Name, "EPSG:4326", always_xy=True).transform(
        op.FirstCoordinate.wrappedValue, op.SecondCoordinate.wrappedValue
    )
    o = ecef(np.asarray(lon), np.asarray(lat), np.asarray(op.Height or 0.0))
    la, ph = math.radians(lon), math.radians(lat)
    east = np.array([-math.sin(la), math.cos(la), 0.0])
    up = np.array([math.cos(ph) * math.cos(la), math.cos(ph) * math.sin(la), math.sin(ph)])
    north = np.cross(up, east)
    return o + v[:, :1] * east + v[:, 1:2] * north + v[:, 2:3] * up


# file, the independent placement of its convention
CASES = [
    ("Civil3D_Hoeveelheden_Verharding_NZ.ifc", civil3d),
    ("Revit2020_LaanOpZuid_OWL_20230717.ifc", revit_millimetres),
    ("Duplex_A_20110907_georeferenced.ifc", property_sets),
    ("Van_Brienenoordbrug-IFC4X3.ifc", map_conversion),
    ("bSI_geographic-referencing-rigid-operation.ifc", geographic),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0].split("_")[0] for c in CASES])
def test_export_lands_on_its_independent_triangles(case, tmp_path):
    name, place = case
    src = export(name)
    if src is None:
        pytest.skip(f"{name}: shared data/georef-ifc/ not found")
    f = ifcopenshell.open(str(src))
    verts, faces = ifcopenshell_world_mesh(src)
    theirs = place(f, verts)
    out = tmp_path / "tiles"
    convert([src], out)
    ours = tileset_ecef_vertices(out, leaves_only=True)
    rng = np.random.default_rng(7)
    sample = ours[rng.choice(len(ours), size=min(SAMPLE, len(ours)), replace=False)]
    d = point_triangle_distances(sample, theirs[faces])
    # The linear map at the anchor stays on the anchor's tangent plane: the far edge is off by
    # the curvature drop there.
    report = json.loads((out / "report.json").read_text())
    g = report["georeference"]
    anchor = ecef(np.asarray(g["origin"]["longitude_deg"]), np.asarray(g["origin"]["latitude_deg"]),
                  np.asarray(g["origin"]["height_m"]))
    reach_m = float(np.sqrt(((ours - anchor) ** 2).sum(axis=1)).max())
    allowed_m = 0.05 + 1.1 * reach_m ** 2 / (2 * EARTH_RADIUS_M)
    print(f"\n{name}: {len(sample)} output vertices, worst {d.max():.4f} m from an independent triangle "
          f"(allowed {allowed_m:.3f} m; reach {reach_m:.0f} m)")
    assert d.max() <= allowed_m, f"{name}: an output vertex lies {d.max():.3f} m from the independent mesh"
