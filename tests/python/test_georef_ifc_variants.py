"""Georeferencing conventions of real exporters, written into the shared IFC files and checked
vertex by vertex against IfcOpenShell and pyproj, independently of bimtiles' code.

Each variant is a shared IFC file with georeferencing entities appended as text, in the line shapes
real exporters write (shared data/georef-ifc/MANIFEST.md), one convention a file:
- Bentley OpenRoads: IfcProjectedCRS Name 'NC83', the code in MapProjection 'EPSG' + MapZone;
- a short Name PROJ does not know, the code in MapZone ('EPSG:n');
- Eastings/Northings 0 with the geometry itself in map coordinates (12d): the shared KIT road,
  its points scaled 10x (a 1.1 km road) and its site placed in ETRS89 / UTM 32N near KIT;
- IFC2X3 ePSet_MapConversion + ePSet_ProjectedCRS on IfcProject (duplex.ifc);
- a State Plane CRS in US survey feet (EPSG:2263) with the MapUnit an IfcConversionBasedUnit;
- a millimetre project under a metre map, Scale omitted;
- a project declared in metres whose geometry is in feet of the map (the unit slip read around;
  IfcOpenShell reads its twin declared in feet).

The independent side: IfcOpenShell's triangulation of the variant in world coordinates (metres),
through the map conversion written (values held here, units as the exporter meant them), pyproj to
longitude/latitude and the WGS84 formula to ECEF. bimtiles converts each variant once (plain float
tiles, no LOD, no dedup or instancing); every output vertex must lie within 5 cm of the independent
mesh. The datum step of the operation bimtiles reports must be the one pyproj chose, so that the
5 cm hold also where PROJ's accuracy for the datum shift is metres. Every independent vertex must
lie within 15 cm of an output vertex (the two kernels tessellate FZK-Haus' curved faces apart by up
to 10 cm; this check is for parts missing). The 1.1 km road's far end (the output vertices
farthest from the anchor) must lie within 5 mm.

The KIT road is written as IFC4X3_RC2, a schema IfcOpenShell 0.9 does not open; the variant's
header says IFC4X3_ADD2 (IfcOpenShell opens it; bimtiles' output of the road is the same bytes
under either header, checked here).

Needs: ifcopenshell, pyproj, numpy and target/release/bimtiles.
"""

import hashlib
import json
import math
import re

import pytest

np = pytest.importorskip("numpy")
pyproj = pytest.importorskip("pyproj")
ifcopenshell = pytest.importorskip("ifcopenshell")

from test_georef_crs import (  # noqa: E402
    BIN,
    TOL_M,
    convert,
    data_file,
    ecef,
    ifcopenshell_world_mesh,
    map_to_ecef,
    nearest_distances,
    point_triangle_distances,
    tileset_ecef_vertices,
)

FAR_END_TOL_M = 0.005
BACK_TOL_M = 0.15
US_FT_M = 1200 / 3937


def entity_id(text, entity):
    """The id of the first `entity` instance (upper-case STEP name) of a STEP text."""
    return int(re.search(rf"^#(\d+)\s*=\s*{entity}\(", text, re.M).group(1))


def append_entities(text, lines):
    """Appends `lines` to the DATA section; a line is a function of the first free id, so that
    `#{n + k}` names the k-th new entity."""
    n = max(int(i) for i in re.findall(r"^#(\d+)\s*=", text, re.M)) + 1
    body = "".join(line(n) + "\n" for line in lines)
    i = text.rindex("ENDSEC;")
    return text[:i] + body + text[i:]


def read(name):
    src = data_file(name)
    if src is None:
        pytest.skip("shared data not found (set BIMTILES_SHARED)")
    return src.read_text(encoding="latin-1")


def without_site_reference(text):
    """IfcSite RefLatitude/RefLongitude/RefElevation emptied (they name the base file's own place)."""
    def empty(m):
        return re.sub(r"\.ELEMENT\.,\s*\([^)]*\),\s*\([^)]*\),\s*[-0-9.E]+,", ".ELEMENT.,$,$,$,", m.group(0))

    return re.sub(r"^#\d+\s*=\s*IFCSITE\(.*$", empty, text, flags=re.M)


def datum_step(operation):
    """The datum transformation of a PROJ operation's name ('NAD83 to WGS 84 (1)'), lower case."""
    m = re.search(r"\+ ([^+]* to WGS 84 \(\d+\))", operation)
    return m.group(1).lower() if m else None


def theta(deg):
    return math.cos(math.radians(deg)), math.sin(math.radians(deg))


def bentley_epsg_code():
    """FZK-Haus (metres) in NC State Plane, named as OpenRoads names it (MANIFEST row 5)."""
    text = without_site_reference(read("AC20-FZK-Haus.ifc"))
    ctx = entity_id(text, "IFCGEOMETRICREPRESENTATIONCONTEXT")
    e0, n0, h0, deg = 435750.0, 168600.0, 230.0, 20.0
    a, b = theta(deg)
    text = append_entities(text, [
        lambda n: f"#{n}=IFCMAPCONVERSION(#{ctx},#{n + 1},{e0},{n0},{h0},{a!r},{b!r},$);",
        lambda n: f"#{n + 1}=IFCPROJECTEDCRS('NC83','NAD83 North Carolina State Plane, Meter','NAD83','NAVD88',"
                  f"'EPSG','32119',#{n + 2});",
        lambda n: f"#{n + 2}=IFCSIUNIT(*,.LENGTHUNIT.,$,.METRE.);",
    ])
    place = dict(crs="EPSG:32119", e=e0, n=n0, h=h0, a=a, b=b, unit=1.0, source="ifc-map-zone-code")
    return text, place


def short_name_map_zone():
    """IfcOpenHouse (millimetres) in LV95: Name 'LV95/01' (no name PROJ knows), the code in MapZone,
    Scale 0.001."""
    text = read("IfcOpenHouse_IFC4.ifc")
    ctx = entity_id(text, "IFCGEOMETRICREPRESENTATIONCONTEXT")
    e0, n0, h0, deg = 2600650.0, 1199780.0, 540.0, -35.0
    a, b = theta(deg)
    text = append_entities(text, [
        lambda n: f"#{n}=IFCPROJECTEDCRS('LV95/01','CH1903+ / LV95','CH1903+','LN02','Swiss Oblique Mercator',"
                  f"'EPSG:2056',$);",
        lambda n: f"#{n + 1}=IFCMAPCONVERSION(#{ctx},#{n},{e0},{n0},{h0},{a!r},{b!r},0.001);",
    ])
    place = dict(crs="EPSG:2056", e=e0, n=n0, h=h0, a=a, b=b, unit=1.0, source="ifc-map-zone-code")
    return text, place


# The road's site in ETRS89 / UTM 32N, near KIT Campus North (metres).
ROAD_E, ROAD_N, ROAD_H = 457300.0, 5439400.0, 110.0


def site_point_at(text, xyz):
    """The IfcSite's placement point moved to `xyz` (file units): the model into map coordinates."""
    site = entity_id(text, "IFCSITE")
    label = r"(?:'[^']*'|\$)"
    placement = int(re.search(rf"^#{site}\s*=\s*IFCSITE\('[^']*',\s*#\d+,\s*{label},\s*{label},\s*{label},\s*#(\d+)",
                              text, re.M).group(1))
    axis = int(re.search(rf"^#{placement}\s*=\s*IFCLOCALPLACEMENT\(\$,\s*#(\d+)\)", text, re.M).group(1))
    point = int(re.search(rf"^#{axis}\s*=\s*IFCAXIS2PLACEMENT3D\(#(\d+)", text, re.M).group(1))
    assert len(re.findall(rf"#{point}\b", text)) == 2, "the site's point is its own"
    x, y, z = xyz
    return re.sub(rf"^#{point}\s*=.*$", f"#{point} = IFCCARTESIANPOINT(({x!r}, {y!r}, {z!r}));", text, flags=re.M)


def road_in_map_coordinates():
    """The KIT road (millimetres), points scaled 10x, its site placed at map coordinates in
    ETRS89 / UTM 32N; IfcMapConversion with E/N 0 and Scale 0.001 (project mm to map metres), as
    12d writes a model in map coordinates (MANIFEST row 1)."""
    text = read("KIT-Simple-Road-Test-Web-IFC4x3_RC2.ifc").replace("'IFC4X3_RC2'", "'IFC4X3_ADD2'")
    text = without_site_reference(text)

    def scaled(m):
        return "IFCCARTESIANPOINT((" + ", ".join(repr(float(c) * 10) for c in m.group(1).split(",")) + "))"

    text = re.sub(r"IFCCARTESIANPOINT\(\(([^)]*)\)\)", scaled, text)
    text = site_point_at(text, (ROAD_E * 1000, ROAD_N * 1000, ROAD_H * 1000))
    ctx = entity_id(text, "IFCGEOMETRICREPRESENTATIONCONTEXT")
    text = append_entities(text, [
        lambda n: f"#{n} = IFCPROJECTEDCRS('EPSG:25832', 'ETRS89 / UTM zone 32N', 'EPSG:4258', 'EPSG:7837', "
                  f"'UTM', '32N', $);",
        lambda n: f"#{n + 1} = IFCMAPCONVERSION(#{ctx}, #{n}, 0., 0., 0., 1., 0., 0.001);",
    ])
    place = dict(crs="EPSG:25832", e=0.0, n=0.0, h=0.0, a=1.0, b=0.0, unit=1.0, source="ifc-name")
    return text, place


def ifc2x3_property_sets_on_project():
    """duplex.ifc (IFC2X3, metres) with ePSet_MapConversion + ePSet_ProjectedCRS on IfcProject, in
    the line shapes of MANIFEST row 9, in NAD83 / Illinois East at its site's own RefLatitude/
    RefLongitude (Chicago)."""
    text = read("duplex.ifc")
    project = entity_id(text, "IFCPROJECT")
    owner = int(re.search(rf"^#{project}\s*=\s*IFCPROJECT\('[^']*',\s*#(\d+)", text, re.M).group(1))
    e0, n0 = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:26971", always_xy=True).transform(
        -(87 + 38 / 60 + 21.84 / 3600), 41 + 52 / 60 + 27.84 / 3600
    )
    e0, n0, h0, deg = round(e0, 1), round(n0, 1), 181.5, 30.0
    a, b = theta(deg)
    text = append_entities(text, [
        lambda n: f"#{n}=IFCPROPERTYSET('3ko_MBwD17ZAIDG4mQnhkm',#{owner},'ePSet_MapConversion',$,"
                  f"(#{n + 2},#{n + 3},#{n + 4},#{n + 5},#{n + 6},#{n + 7}));",
        lambda n: f"#{n + 1}=IFCRELDEFINESBYPROPERTIES('1LBSCnhwD1pxxMB3SY92WM',#{owner},$,$,(#{project}),#{n});",
        lambda n: f"#{n + 2}=IFCPROPERTYSINGLEVALUE('Eastings',$,IFCLENGTHMEASURE({e0!r}),$);",
        lambda n: f"#{n + 3}=IFCPROPERTYSINGLEVALUE('Northings',$,IFCLENGTHMEASURE({n0!r}),$);",
        lambda n: f"#{n + 4}=IFCPROPERTYSINGLEVALUE('OrthogonalHeight',$,IFCLENGTHMEASURE({h0!r}),$);",
        lambda n: f"#{n + 5}=IFCPROPERTYSINGLEVALUE('XAxisAbscissa',$,IFCREAL({a!r}),$);",
        lambda n: f"#{n + 6}=IFCPROPERTYSINGLEVALUE('XAxisOrdinate',$,IFCREAL({b!r}),$);",
        lambda n: f"#{n + 7}=IFCPROPERTYSINGLEVALUE('Scale',$,IFCREAL(1.),$);",
        lambda n: f"#{n + 8}=IFCPROPERTYSET('2Dum9zWHjBZu82DLn1VYqj',#{owner},'ePSet_ProjectedCRS',$,(#{n + 10}));",
        lambda n: f"#{n + 9}=IFCRELDEFINESBYPROPERTIES('1UGeQ3uY5EPBYC0YnU7Qw8',#{owner},$,$,(#{project}),#{n + 8});",
        lambda n: f"#{n + 10}=IFCPROPERTYSINGLEVALUE('Name',$,IFCLABEL('EPSG:26971'),$);",
    ])
    place = dict(crs="EPSG:26971", e=e0, n=n0, h=h0, a=a, b=b, unit=1.0, source="epset-name")
    return text, place


def state_plane_us_feet():
    """FZK-Haus (metres) in NAD83 / New York Long Island (ftUS): E/N and height in US survey feet
    under an IfcConversionBasedUnit MapUnit (the shape Revit writes, MANIFEST row 8), Scale omitted:
    one project metre is one ground metre."""
    text = without_site_reference(read("AC20-FZK-Haus.ifc"))
    ctx = entity_id(text, "IFCGEOMETRICREPRESENTATIONCONTEXT")
    e0, n0, h0, deg = 988150.0, 211900.0, 35.0, 28.9
    a, b = theta(deg)
    text = append_entities(text, [
        lambda n: f"#{n}= IFCDIMENSIONALEXPONENTS(1,0,0,0,0,0,0);",
        lambda n: f"#{n + 1}= IFCSIUNIT(*,.LENGTHUNIT.,$,.METRE.);",
        lambda n: f"#{n + 2}= IFCMEASUREWITHUNIT(IFCRATIOMEASURE(0.304800609601219),#{n + 1});",
        lambda n: f"#{n + 3}= IFCCONVERSIONBASEDUNIT(#{n},.LENGTHUNIT.,'US SURVEY FOOT',#{n + 2});",
        lambda n: f"#{n + 4}= IFCPROJECTEDCRS('EPSG:2263','NAD83 / New York Long Island (ftUS)','NAD83',$,$,$,"
                  f"#{n + 3});",
        lambda n: f"#{n + 5}= IFCMAPCONVERSION(#{ctx},#{n + 4},{e0},{n0},{h0},{a!r},{b!r},$);",
    ])
    # Map coordinates in ftUS: project metres are converted to feet.
    place = dict(crs="EPSG:2263", e=e0, n=n0, h=h0 * US_FT_M, a=a, b=b, unit=1.0 / US_FT_M,
                 source="ifc-name")
    return text, place


def millimetre_project_metre_map():
    """IfcOpenHouse (millimetres) in ETRS89 / UTM 33N (Berlin), MapUnit metre, Scale omitted."""
    text = read("IfcOpenHouse_IFC4.ifc")
    ctx = entity_id(text, "IFCGEOMETRICREPRESENTATIONCONTEXT")
    e0, n0, h0, deg = 391800.0, 5820100.0, 34.0, 12.5
    a, b = theta(deg)
    text = append_entities(text, [
        lambda n: f"#{n}=IFCSIUNIT(*,.LENGTHUNIT.,$,.METRE.);",
        lambda n: f"#{n + 1}=IFCPROJECTEDCRS('EPSG:25833','ETRS89 / UTM zone 33N','ETRS89',$,'UTM','33N',#{n});",
        lambda n: f"#{n + 2}=IFCMAPCONVERSION(#{ctx},#{n + 1},{e0},{n0},{h0},{a!r},{b!r},$);",
    ])
    place = dict(crs="EPSG:25833", e=e0, n=n0, h=h0, a=a, b=b, unit=1.0, source="ifc-name")
    return text, place


def geometry_in_feet_declared_metres():
    """The KIT road, its points in feet (10x, as the 1.1 km road) with its site in map coordinates
    of ETRS89 / UTM 32N, its project length unit declared METRE, which its geometry contradicts;
    IfcMapConversion with E/N 0 and Scale 1. Read in metres the model lies 3.28 times farther north
    than the CRS reaches: it must be read in feet, with a warning. The independent side reads the
    file as the exporter meant it (declared in feet)."""
    text = read("KIT-Simple-Road-Test-Web-IFC4x3_RC2.ifc").replace("'IFC4X3_RC2'", "'IFC4X3_ADD2'")
    text = without_site_reference(text)

    def in_feet(m):
        return "IFCCARTESIANPOINT((" + ", ".join(repr(float(c) * 10 / 304.8) for c in m.group(1).split(",")) + "))"

    text = re.sub(r"IFCCARTESIANPOINT\(\(([^)]*)\)\)", in_feet, text)
    text = site_point_at(text, (ROAD_E / 0.3048, ROAD_N / 0.3048, ROAD_H / 0.3048))
    ctx = entity_id(text, "IFCGEOMETRICREPRESENTATIONCONTEXT")
    length_unit = r"^(#\d+)\s*=\s*IFCSIUNIT\(\*,\s*\.LENGTHUNIT\.,\s*\.MILLI\.,\s*\.METRE\.\);"
    unit_id = int(re.search(length_unit, text, re.M).group(1)[1:])
    text = append_entities(text, [
        lambda n: f"#{n} = IFCPROJECTEDCRS('EPSG:25832', 'ETRS89 / UTM zone 32N', 'EPSG:4258', $, 'UTM', '32N', $);",
        lambda n: f"#{n + 1} = IFCMAPCONVERSION(#{ctx}, #{n}, 0., 0., 0., 1., 0., 1.);",
        lambda n: f"#{n + 2} = IFCDIMENSIONALEXPONENTS(1, 0, 0, 0, 0, 0, 0);",
        lambda n: f"#{n + 3} = IFCSIUNIT(*, .LENGTHUNIT., $, .METRE.);",
        lambda n: f"#{n + 4} = IFCMEASUREWITHUNIT(IFCLENGTHMEASURE(0.3048), #{n + 3});",
        lambda n: f"#{n + 5} = IFCCONVERSIONBASEDUNIT(#{n + 2}, .LENGTHUNIT., 'FOOT', #{n + 4});",
    ])
    feet = int(re.search(r"^#(\d+) = IFCCONVERSIONBASEDUNIT\([^;]*'FOOT'", text, re.M).group(1))
    assignment = re.compile(r"^(#\d+\s*=\s*IFCUNITASSIGNMENT\(\(.*?)#%d\b" % unit_id, re.M)
    truth, n = assignment.subn(rf"\g<1>#{feet}", text, count=1)
    assert n == 1
    slip, n = re.subn(length_unit, r"\1 = IFCSIUNIT(*, .LENGTHUNIT., $, .METRE.);", text, count=1, flags=re.M)
    assert n == 1
    place = dict(crs="EPSG:25832", e=0.0, n=0.0, h=0.0, a=1.0, b=0.0, unit=1.0, source="ifc-name",
                 truth=truth, warning="read in 0.3048 m units")
    return slip, place


VARIANTS = {
    "bentley-epsg-map-zone": bentley_epsg_code,
    "short-name-code-in-map-zone": short_name_map_zone,
    "road-in-map-coordinates": road_in_map_coordinates,
    "ifc2x3-epsets-on-project": ifc2x3_property_sets_on_project,
    "state-plane-us-feet": state_plane_us_feet,
    "millimetre-project-metre-map": millimetre_project_metre_map,
    "geometry-in-feet-declared-metres": geometry_in_feet_declared_metres,
}


def independent_ecef(world, place):
    """IfcOpenShell world metres -> map (E/N, rotation, map units per metre) -> pyproj -> ECEF."""
    x, y = (world[:, :2] * place["unit"]).T
    a, b = place["a"], place["b"]
    e = place["e"] + a * x - b * y
    n = place["n"] + b * x + a * y
    h = place["h"] + world[:, 2]
    return map_to_ecef(place["crs"], e, n, h)


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    """Each variant written and converted once: name -> (path, out dir, stderr, place)."""
    if not BIN.is_file():
        pytest.skip(f"{BIN} not built (cargo build --release)")
    root = tmp_path_factory.mktemp("variants")
    done = {}

    def get(name):
        if name not in done:
            text, place = VARIANTS[name]()
            ifc = root / f"{name}.ifc"
            ifc.write_text(text, encoding="latin-1")
            if "truth" in place:
                place["truth_ifc"] = root / f"{name}-as-meant.ifc"
                place["truth_ifc"].write_text(place.pop("truth"), encoding="latin-1")
            out = root / f"{name}-tiles"
            r = convert([ifc], out)
            done[name] = (ifc, out, r.stderr, place)
        return done[name]

    return get


@pytest.mark.parametrize("name", list(VARIANTS))
def test_variant_vertices_land_where_pyproj_puts_them(name, converted):
    ifc, out, stderr, place = converted(name)
    report = json.loads((out / "report.json").read_text())
    if "warning" in place:
        assert any(place["warning"] in w for w in report["warnings"]), report["warnings"]
    else:
        assert "warning" not in stderr, stderr
    geo = report["georeference"]
    assert geo["origin_source"] == "input-crs", geo
    assert not geo.get("warnings"), geo
    [used] = geo["crs"]
    assert used["crs"].startswith(place["crs"]), used
    assert used["source"] == place["source"], used
    transformer = pyproj.Transformer.from_crs(used["crs"], "EPSG:4326", always_xy=True)
    # Where several operations apply, PROJ chooses by place: ask at the anchor's map point.
    transformer.transform(used["easting"], used["northing"])
    chosen = transformer.get_last_used_operation().description
    assert datum_step(used["operation"]) == datum_step(chosen), (used["operation"], chosen)

    world, faces = ifcopenshell_world_mesh(place.get("truth_ifc", ifc))
    theirs = independent_ecef(world, place)
    ours = tileset_ecef_vertices(out)
    d_ours = nearest_distances(ours, theirs)
    far = d_ours >= FAR_END_TOL_M
    if far.any():
        d_ours[far] = point_triangle_distances(ours[far], theirs[faces])
    d_theirs = nearest_distances(theirs, ours)
    extent = float(np.ptp(world[:, :2], axis=0).max())
    print(f"\n{name}: {len(ours)} output vertices, model {extent:.0f} m across, in {used['crs']} "
          f"(field {used['source']}), worst {d_ours.max() * 1000:.1f} mm (to IfcOpenShell+pyproj), "
          f"back {d_theirs.max() * 1000:.1f} mm; PROJ '{used['operation']}', accuracy {used['accuracy_m']} m")
    assert d_ours.max() < TOL_M and d_theirs.max() < BACK_TOL_M

    if name == "road-in-map-coordinates":
        assert extent > 1000.0, "the road is kilometre-long"
        anchor = ecef(np.asarray(geo["origin"]["longitude_deg"]), np.asarray(geo["origin"]["latitude_deg"]),
                      np.asarray(geo["origin"]["height_m"]))
        reach = np.sqrt(((ours - anchor) ** 2).sum(axis=1))
        end = reach >= np.quantile(reach, 0.98)
        print(f"far end ({end.sum()} vertices, {reach.max():.0f} m from the anchor): worst "
              f"{d_ours[end].max() * 1000:.2f} mm")
        assert d_ours[end].max() < FAR_END_TOL_M


def test_road_header_rewrite_leaves_bimtiles_output_unchanged(converted, tmp_path):
    """The ADD2 header given to IfcOpenShell changes nothing in what bimtiles reads."""
    ifc = converted("road-in-map-coordinates")[0]
    text = ifc.read_text(encoding="latin-1")
    rc2 = tmp_path / "rc2" / ifc.name
    rc2.parent.mkdir()
    rc2.write_text(text.replace("'IFC4X3_ADD2'", "'IFC4X3_RC2'"), encoding="latin-1")
    digests = []
    for i, src in enumerate((ifc, rc2)):
        out = tmp_path / f"out{i}"
        convert([src], out)
        digests.append(sorted(hashlib.sha256(p.read_bytes()).hexdigest() for p in out.rglob("*")
                              if p.is_file() and p.name != "report.json"))
    assert digests[0] == digests[1]
