"""CityGML input checked independently of bimtiles' reader, on every file of ../shared/data/citygml/.

Each file is converted once by the bimtiles binary (plain float tiles, no LOD, no dedup or
instancing). Read here with the standard library's ElementTree (a whole-tree parse, unlike the
reader's stream): the city objects with surface geometry at their highest LoD (polygons reached
inline or through ``xlink:href``, each counted once), and the area of those polygons, holes
subtracted. For files with a real CRS the polygon points are placed by pyproj (horizontal CRS to
longitude/latitude, the srsName's axis order as pyproj states it, heights ellipsoidal) and the
WGS84 formula, then compared with the tiles in ECEF: every output vertex within 5 cm of an input
vertex, and the area of the output triangles within 0.1 % of the polygons'. Files in local
coordinates (no srsName, or a national CRS over local coordinates) compare areas in their own
units.

Needs: pyproj, numpy (tests/python/requirements.txt) and target/release/bimtiles.
"""

import json
import os
import pathlib
import re
import struct
import xml.etree.ElementTree as ET

import pytest

np = pytest.importorskip("numpy")
pyproj = pytest.importorskip("pyproj", reason="pyproj is not installed (pip install pyproj==3.7.2)")
from test_georef_crs import Y_UP_TO_Z_UP, convert, ecef, nearest_distances, node_matrix  # noqa: E402
from tile_content import content_bytes  # noqa: E402

TOL_M = 0.05
AREA_TOL = 1e-3
XLINK = "{http://www.w3.org/1999/xlink}href"
GML_ID = ("{http://www.opengis.net/gml}id", "{http://www.opengis.net/gml/3.2}id")
CLASSES = {
    "Building", "BuildingPart", "BuildingInstallation", "IntBuildingInstallation", "BuildingFurniture",
    "BuildingConstructiveElement", "BuildingRoom", "Room", "Bridge", "BridgePart", "BridgeInstallation",
    "IntBridgeInstallation", "BridgeConstructionElement", "BridgeConstructiveElement", "BridgeFurniture",
    "BridgeRoom", "Tunnel", "TunnelPart", "TunnelInstallation", "IntTunnelInstallation",
    "TunnelConstructiveElement", "TunnelFurniture", "HollowSpace", "Road", "Railway", "Track", "Square",
    "Waterway", "Section", "Intersection", "TrafficArea", "AuxiliaryTrafficArea", "TrafficSpace",
    "AuxiliaryTrafficSpace", "ReliefFeature", "TINRelief", "MassPointRelief", "BreaklineRelief", "WaterBody",
    "SolitaryVegetationObject", "PlantCover", "CityFurniture", "GenericCityObject", "GenericOccupiedSpace",
    "GenericUnoccupiedSpace", "GenericLogicalSpace", "LandUse", "OtherConstruction",
    # Openings are city objects too (CityGML 2.0 _Opening, 3.0 filling elements).
    "Window", "Door",
}
SURFACES = {"Polygon", "PolygonPatch", "Triangle"}


def shared_citygml():
    for c in [os.environ.get("BIMTILES_SHARED", ""), str(pathlib.Path(__file__).resolve().parents[3] / "shared"),
              "/work/shared"]:
        p = pathlib.Path(c) / "data" / "citygml"
        if c and p.is_dir():
            return p
    return None


def files():
    root = shared_citygml()
    return sorted(root.rglob("*.gml")) if root else []


def local(tag):
    return tag.rsplit("}", 1)[-1]


def ogc(tag):
    return tag.startswith("{http://www.opengis.net/") and "/gml" not in tag.split("}")[0]


def ade(tag):
    """An Application Domain Extension's name: a namespace outside OGC, W3C and OASIS xAL."""
    ns = tag[1:].split("}")[0] if tag.startswith("{") else ""
    return bool(ns) and not ns.startswith(("http://www.opengis.net/", "http://www.w3.org/", "urn:oasis:"))


# An ADE's geometry property: lodN followed by a geometry word (not an attribute like lod1HeightType).
ADE_GEOMETRY = re.compile(r"lod\d\w*(Solid|Surface|Geometry|FootPrint|RoofEdge|Curve)$")


def gml_id(el):
    for k in GML_ID:
        if k in el.attrib:
            return el.attrib[k]
    return None


def ring_points(ring, dim):
    vals = []
    for el in ring.iter():
        name = local(el.tag)
        if name in ("posList", "pos") and el.text:
            d = int(el.get("srsDimension") or (len(el.text.split()) if name == "pos" else dim))
            v = [float(x) for x in el.text.split()]
            vals += [v[i : i + d] + [0.0] * (3 - d) for i in range(0, len(v), d)]
        elif name == "coordinates" and el.text:
            vals += [[float(x) for x in t.split(",")] for t in el.text.split()]
    if len(vals) > 1 and vals[0] == vals[-1]:
        vals.pop()
    return vals


class Model:
    """A CityGML file read with ElementTree: objects' polygons at their highest LoD."""

    def __init__(self, path):
        self.tree = ET.parse(path)
        root = self.tree.getroot()
        self.ids = {gml_id(e): e for e in root.iter() if gml_id(e)}
        self.parent = {c: p for p in root.iter() for c in p}
        srs = [e.get("srsName") for e in root.iter() if e.get("srsName")]
        self.srs = srs[0] if srs else None
        dims = [e.get("srsDimension") for e in root.iter() if e.get("srsDimension")]
        self.dim = int(dims[0]) if dims else 3
        self.objects = [e for e in root.iter() if self.is_object(e)]

    def is_object(self, el):
        """A city object: a CityGML class, or an ADE's feature (a capitalised name with a gml:id)
        that is not a boundary surface (inside a boundedBy)."""
        if ogc(el.tag):
            return local(el.tag) in CLASSES
        parent = self.parent.get(el)
        return (ade(el.tag) and local(el.tag)[:1].isupper() and gml_id(el) is not None
                and parent is not None and local(parent.tag) != "boundedBy")

    def owner(self, el):
        """The nearest city object enclosing an element."""
        p = self.parent.get(el)
        while p is not None and not self.is_object(p):
            p = self.parent.get(p)
        return p

    def in_implicit(self, el):
        p = self.parent.get(el)
        while p is not None:
            if local(p.tag) == "ImplicitGeometry":
                return True
            p = self.parent.get(p)
        return False

    def polygons_of(self, prop, out, depth=0):
        """Polygons under a geometry property or geometry, following xlinks."""
        stack = [prop]
        while stack:
            el = stack.pop()
            href = el.get(XLINK)
            if href and depth < 16:
                target = self.ids.get(href.lstrip("#"))
                if target is not None:
                    self.polygons_of(target, out, depth + 1)
            if local(el.tag) in SURFACES and "opengis.net/gml" in el.tag:
                out.setdefault(id(el), el)
                continue
            stack.extend(el)

    def highest_lod_polygons(self, obj):
        per_lod = {}
        for el in obj.iter():
            name = local(el.tag)
            m = re.match(r"lod(\d)\w+", name)
            lod = None
            if m and (ogc(el.tag) or (ade(el.tag) and ADE_GEOMETRY.match(name))):
                lod = int(m.group(1))
            elif name == "tin" and ogc(el.tag):
                lods = [c.text for c in self.parent[el] if local(c.tag) == "lod"]
                lod = int(lods[0]) if lods else 0
            if lod is None or self.owner(el) is not obj or self.in_implicit(el):
                continue
            self.polygons_of(el, per_lod.setdefault(lod, {}))
        per_lod = {k: v for k, v in per_lod.items() if v}
        return per_lod[max(per_lod)] if per_lod else {}

    def rings(self, polygon):
        return [ring_points(r, self.dim) for r in polygon.iter() if local(r.tag) == "LinearRing"]


def newell(ring):
    r = np.asarray(ring)
    return np.cross(r, np.roll(r, -1, axis=0)).sum(axis=0) / 2.0


def polygon_area(rings):
    rings = [np.asarray(r, dtype=np.float64) for r in rings if len(r) >= 3]
    if not rings:
        return 0.0
    o = rings[0][0]
    outer = newell(rings[0] - o)
    n = outer / (np.linalg.norm(outer) or 1.0)
    return np.linalg.norm(outer) - sum(abs(newell(r - o) @ n) for r in rings[1:])


def placer(srs):
    """A function from the file's coordinates to ECEF, or None for local coordinates."""
    if not srs:
        return None
    text = srs
    m = re.match(r"urn:ogc:def:crs,crs:EPSG:[\d.]*:(\d+),", srs)
    if m:
        text = f"EPSG:{m.group(1)}"
    else:
        m = re.search(r"EPSG(?:/0/|:[\d.]*:|:)(\d+)$", srs)
        text = f"EPSG:{m.group(1)}"
    crs = pyproj.CRS.from_user_input(text)
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    to_ll = pyproj.Transformer.from_crs(horizontal, "EPSG:4326")
    lat_first = horizontal.axis_info[0].direction.lower() == "north"

    def place(pts):
        pts = np.asarray(pts, dtype=np.float64)
        if horizontal.is_geographic:
            a, b = pts[:, 0], pts[:, 1]
            lat, lon = (a, b) if lat_first else (b, a)
            lat, lon = to_ll.transform(lat, lon)
        else:
            lat, lon = to_ll.transform(pts[:, 0], pts[:, 1])
        return np.array([ecef(x, y, h) for x, y, h in zip(lon, lat, pts[:, 2])])

    return place, horizontal.is_projected


def glb_triangles(data):
    """Triangles (n, 3, 3) of a GLB's drawn nodes, in the glTF scene frame (y-up)."""
    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + jlen])
    blob = data[20 + jlen + 8 :]
    out = []

    def accessor(i, dtype, width):
        acc = doc["accessors"][i]
        bv = doc["bufferViews"][acc["bufferView"]]
        start = bv.get("byteOffset", 0) + acc.get("byteOffset", 0)
        size = np.dtype(dtype).itemsize * width
        stride = bv.get("byteStride", size)
        raw = np.frombuffer(blob, dtype=np.uint8, count=stride * (acc["count"] - 1) + size, offset=start)
        return np.ndarray((acc["count"], width), dtype=dtype, buffer=raw.tobytes(), strides=(stride, np.dtype(dtype).itemsize))

    def walk(i, parent):
        node = doc["nodes"][i]
        m = parent @ node_matrix(node)
        if "mesh" in node:
            for prim in doc["meshes"][node["mesh"]]["primitives"]:
                p = accessor(prim["attributes"]["POSITION"], "<f4", 3).astype(np.float64)
                p = (np.c_[p, np.ones(len(p))] @ m.T)[:, :3]
                ct = doc["accessors"][prim["indices"]]["componentType"]
                idx = accessor(prim["indices"], {5121: "<u1", 5123: "<u2", 5125: "<u4"}[ct], 1).ravel()
                out.append(p[idx.reshape(-1, 3)])
        for c in node.get("children", []):
            walk(c, m)

    for root in doc["scenes"][doc.get("scene", 0)]["nodes"]:
        walk(root, np.eye(4))
    return np.concatenate(out) if out else np.zeros((0, 3, 3))


def tileset_triangles(out_dir):
    """Every triangle of every tile, in ECEF (tile transforms, glTF y-up to z-up)."""
    ts = json.loads((out_dir / "tileset.json").read_text())
    tris = []

    def walk(tile, parent):
        m = parent
        if "transform" in tile:
            m = parent @ np.asarray(tile["transform"], dtype=np.float64).reshape(4, 4).T
        uri = tile.get("content", {}).get("uri")
        if uri:
            t = glb_triangles(content_bytes(out_dir, uri)).reshape(-1, 3)
            t = np.c_[t, np.ones(len(t))] @ (m @ Y_UP_TO_Z_UP).T
            tris.append(t[:, :3].reshape(-1, 3, 3))
        for c in tile.get("children", []):
            walk(c, m)

    walk(ts["root"], np.eye(4))
    return np.concatenate(tris)


@pytest.mark.parametrize("path", files(), ids=lambda p: p.name)
def test_citygml_counts_areas_and_placement(path, tmp_path):
    model = Model(path)
    drawn = {}
    for i, obj in enumerate(model.objects):
        polygons = model.highest_lod_polygons(obj)
        rings = [model.rings(p) for p in polygons.values()]
        if sum(polygon_area(r) for r in rings) > 0:
            # Not every object has a gml:id (PLATEAU's bridge parts and traffic areas).
            drawn[i] = rings
    out = tmp_path / "tiles"
    convert([path], out)
    report = json.loads((out / "report.json").read_text())
    assert report["input"]["components"] == len(drawn), "one element per city object with surface geometry"

    place = placer(model.srs)
    points = np.array([p for polys in drawn.values() for poly in polys for r in poly for p in r], dtype=np.float64)
    local_coords = place is None or (place[1] and np.linalg.norm(points.mean(axis=0)) < 10_000)
    tris = tileset_triangles(out)
    area_out = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1).sum() / 2
    if local_coords:
        area_in = sum(polygon_area(poly) for polys in drawn.values() for poly in polys)
    else:
        fn = place[0]
        area_in = 0.0
        for polys in drawn.values():
            for poly in polys:
                area_in += polygon_area([fn(ring) for ring in poly if len(ring) >= 3])
        placed = fn(points)
        out_vertices = tris.reshape(-1, 3)
        d = nearest_distances(out_vertices, placed)
        assert d.max() < TOL_M, f"{path.name}: an output vertex {d.max():.4f} m from every input vertex"
        d = nearest_distances(placed, out_vertices)
        assert d.max() < TOL_M, f"{path.name}: an input vertex {d.max():.4f} m from every output vertex"
    rel = abs(area_out - area_in) / area_in
    print(f"{path.name}: {len(drawn)} objects, area {area_out:.2f} vs polygons {area_in:.2f} ({rel * 100:.4f} %)")
    assert rel < AREA_TOL, f"{path.name}: triangles cover the polygons ({rel})"
