"""Independent cross-check of bimtiles output with Pixar USD (PyPI `usd-core`).

Shares no code with the Rust crate. For every output directory in the environment variable
BIMTILES_TILESET_DIRS (colon-separated; skipped when unset) it

1. reads tileset.json and walks the tile tree (external tileset .json contents are followed), composing each
   tile's `transform` (column-major 4x4, 3D Tiles 1.1) with its ancestors'. The ROOT tile's own transform
   (usually local -> ECEF) is ignored: everything is compared in the root's local frame;
2. reads each tile's GLB content with the small pure-Python reader below (JSON + BIN chunks, accessors with
   byteOffset/byteStride, FLOAT/normalized-int positions, UNSIGNED_BYTE/SHORT/INT indices, the node
   hierarchy with translation/rotation/scale/matrix, EXT_mesh_gpu_instancing on nodes); a GLB inlined in
   the tileset JSON as a data URI (bimtiles' default for the root) is decoded (tile_content.py) and read
   the same way;
3. builds an in-memory USD stage: one UsdGeom.Xform per tile with the composed transform, a child Xform with
   the glTF y-up -> 3D Tiles z-up rotation ((x, y, z) -> (x, -z, y), +90 deg about X), children Xforms per
   glTF node, one UsdGeom.Mesh per primitive;
4. checks with UsdGeom.BBoxCache that each tile's content lies inside its boundingVolume (box or sphere;
   tolerance 1 mm + 1e-6 relative), prints how tight the box is (content box volume / tile box volume), and
   that every child's box lies inside its parent's box (corner test).

Primitives with KHR_draco_mesh_compression are decoded with DracoPy when it is installed, else skipped with a
printed note. Run:

    pip install -r tests/python/requirements.txt
    BIMTILES_TILESET_DIRS=out/a:out/b python3 -m pytest -s tests/python/test_usd_crosscheck.py
"""

import base64
import json
import math
import os
import struct

import pytest
from meshopt_decode import decoded_tileset
from tile_content import GLB_MEDIA_TYPE, data_uri_bytes, data_uri_label, data_uri_media_type, is_data_uri

pxr = pytest.importorskip("pxr", reason="usd-core is not installed (pip install -r tests/python/requirements.txt)")
from pxr import Gf, Usd, UsdGeom, Vt  # noqa: E402

try:  # optional
    import DracoPy  # type: ignore
except Exception:  # pragma: no cover - depends on the machine
    DracoPy = None

ABS_TOL = 1e-3
REL_TOL = 1e-6

# ----------------------------------------------------------------------------------------------------------
# 4x4 matrices, column-vector convention (p' = M p), stored as row lists M[r][c]
# ----------------------------------------------------------------------------------------------------------
IDENTITY = [[1.0 if r == c else 0.0 for c in range(4)] for r in range(4)]
# glTF y-up -> 3D Tiles z-up: (x, y, z) -> (x, -z, y)
Y_UP_TO_Z_UP = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


def mat_from_column_major(a):
    assert len(a) == 16, "a transform needs 16 numbers"
    return [[float(a[c * 4 + r]) for c in range(4)] for r in range(4)]


def mat_mul(a, b):
    return [[sum(a[r][k] * b[k][c] for k in range(4)) for c in range(4)] for r in range(4)]


def mat_point(m, p):
    return tuple(m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3] for r in range(3))


def mat_vec(m, v):
    return tuple(m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2] for r in range(3))


def trs_matrix(t=(0, 0, 0), q=(0, 0, 0, 1), s=(1, 1, 1)):
    x, y, z, w = q
    r = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    return [[r[0][0] * s[0], r[0][1] * s[1], r[0][2] * s[2], t[0]],
            [r[1][0] * s[0], r[1][1] * s[1], r[1][2] * s[2], t[1]],
            [r[2][0] * s[0], r[2][1] * s[1], r[2][2] * s[2], t[2]],
            [0.0, 0.0, 0.0, 1.0]]


def node_matrix(node):
    if "matrix" in node:
        return mat_from_column_major(node["matrix"])
    return trs_matrix(node.get("translation", (0, 0, 0)), node.get("rotation", (0, 0, 0, 1)),
                      node.get("scale", (1, 1, 1)))


def to_gf(m):
    """Column-vector matrix -> Gf.Matrix4d (row-vector convention: the transpose)."""
    return Gf.Matrix4d(*[m[c][r] for r in range(4) for c in range(4)])


def det3(a, b, c):
    return (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))


# ----------------------------------------------------------------------------------------------------------
# Minimal GLB reader
# ----------------------------------------------------------------------------------------------------------
COMPONENT = {5120: ("b", 1, 127.0), 5121: ("B", 1, 255.0), 5122: ("h", 2, 32767.0), 5123: ("H", 2, 65535.0),
             5125: ("I", 4, None), 5126: ("f", 4, None)}
NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


class Glb:
    def __init__(self, path, data=None, base=None):
        """The GLB file `path`, or its bytes `data` (then `path` only names it, and `base` is the folder its
        relative buffer uris resolve against)."""
        self.path = path
        self.base = base or os.path.dirname(os.path.abspath(path))
        if data is None:
            with open(path, "rb") as fh:
                data = fh.read()
        magic, version, length = struct.unpack_from("<4sII", data, 0)
        if magic != b"glTF" or version != 2:
            raise ValueError(f"{path}: not a glTF 2.0 binary")
        if length > len(data):
            raise ValueError(f"{path}: truncated ({len(data)} of {length} bytes)")
        off, self.json, self.bin = 12, None, None
        while off + 8 <= length:
            clen, ctype = struct.unpack_from("<II", data, off)
            chunk = data[off + 8: off + 8 + clen]
            if ctype == 0x4E4F534A:
                self.json = json.loads(chunk.decode("utf-8"))
            elif ctype == 0x004E4942 and self.bin is None:
                self.bin = chunk
            off += 8 + clen + ((4 - clen % 4) % 4 if clen % 4 else 0)
        if self.json is None:
            raise ValueError(f"{path}: no JSON chunk")
        self._buffers = {}

    def buffer(self, i):
        if i not in self._buffers:
            b = self.json["buffers"][i]
            uri = b.get("uri")
            if uri is None:
                if i != 0 or self.bin is None:
                    raise ValueError(f"{self.path}: buffer {i} has no data")
                self._buffers[i] = self.bin
            elif uri.startswith("data:"):
                self._buffers[i] = base64.b64decode(uri.split(",", 1)[1])
            else:
                base = os.path.abspath(self.base)
                full = os.path.abspath(os.path.join(base, uri))
                if not full.startswith(base + os.sep):
                    raise ValueError(f"{self.path}: buffer uri escapes its folder: {uri}")
                with open(full, "rb") as fh:
                    self._buffers[i] = fh.read()
        return self._buffers[i]

    def buffer_view_bytes(self, i):
        bv = self.json["bufferViews"][i]
        buf = self.buffer(bv["buffer"])
        o = bv.get("byteOffset", 0)
        return buf[o: o + bv["byteLength"]]

    def accessor(self, i):
        """List of tuples (one per element); normalized integers are mapped to floats."""
        a = self.json["accessors"][i]
        fmt, size, norm = COMPONENT[a["componentType"]]
        n = NCOMP[a["type"]]
        count = a["count"]
        if "bufferView" not in a:
            if "sparse" in a:
                raise NotImplementedError("sparse accessors are not supported by this checker")
            return [tuple([0] * n)] * count
        bv = self.json["bufferViews"][a["bufferView"]]
        buf = self.buffer(bv["buffer"])
        stride = bv.get("byteStride") or n * size
        base = bv.get("byteOffset", 0) + a.get("byteOffset", 0)
        need = base + stride * (count - 1) + n * size if count else base
        if need > bv.get("byteOffset", 0) + bv["byteLength"] or need > len(buf):
            raise ValueError(f"{self.path}: accessor {i} runs past its bufferView")
        st = struct.Struct("<" + fmt * n)
        out = [st.unpack_from(buf, base + k * stride) for k in range(count)]
        if a.get("normalized") and norm:
            out = [tuple(max(v / norm, -1.0) for v in e) for e in out]
        return out


def primitive_triangles(glb, prim, notes):
    """(points, faceVertexCounts, faceVertexIndices) or None when the primitive is skipped."""
    ext = prim.get("extensions", {})
    if "KHR_draco_mesh_compression" in ext:
        if DracoPy is None:
            notes.append(f"{os.path.basename(glb.path)}: Draco primitive skipped (DracoPy not installed)")
            return None
        mesh = DracoPy.decode(glb.buffer_view_bytes(ext["KHR_draco_mesh_compression"]["bufferView"]))
        pts = [tuple(float(c) for c in p) for p in mesh.points]
        idx = [int(v) for f in mesh.faces for v in f]
        return pts, [3] * (len(idx) // 3), idx
    mode = prim.get("mode", 4)
    if mode not in (4, 5, 6):
        notes.append(f"{os.path.basename(glb.path)}: primitive mode {mode} (points/lines) skipped")
        return None
    pts = [tuple(float(c) for c in p) for p in glb.accessor(prim["attributes"]["POSITION"])]
    if "indices" in prim:
        idx = [e[0] for e in glb.accessor(prim["indices"])]
    else:
        idx = list(range(len(pts)))
    if mode == 5:
        tri = []
        for k in range(len(idx) - 2):
            tri += [idx[k], idx[k + 1], idx[k + 2]] if k % 2 == 0 else [idx[k + 1], idx[k], idx[k + 2]]
        idx = tri
    elif mode == 6:
        idx = [v for k in range(1, len(idx) - 1) for v in (idx[0], idx[k], idx[k + 1])]
    if len(idx) % 3:
        raise ValueError(f"{glb.path}: index count {len(idx)} is not a multiple of 3")
    if idx and max(idx) >= len(pts):
        raise ValueError(f"{glb.path}: index {max(idx)} out of range ({len(pts)} vertices)")
    return pts, [3] * (len(idx) // 3), idx


def gpu_instances(glb, node):
    """Per-instance matrices of EXT_mesh_gpu_instancing, or None."""
    ext = node.get("extensions", {}).get("EXT_mesh_gpu_instancing")
    if not ext:
        return None
    attrs = ext.get("attributes", {})
    cols = {k: glb.accessor(v) for k, v in attrs.items() if k in ("TRANSLATION", "ROTATION", "SCALE")}
    count = max((len(v) for v in cols.values()), default=0)
    out = []
    for i in range(count):
        out.append(trs_matrix(cols["TRANSLATION"][i] if "TRANSLATION" in cols else (0, 0, 0),
                              cols["ROTATION"][i] if "ROTATION" in cols else (0, 0, 0, 1),
                              cols["SCALE"][i] if "SCALE" in cols else (1, 1, 1)))
    return out


# ----------------------------------------------------------------------------------------------------------
# USD stage
# ----------------------------------------------------------------------------------------------------------
def add_glb_to_stage(stage, parent_path, glb, notes):
    """Adds the default scene of `glb` under parent_path; returns the number of triangles added."""
    g = glb.json
    scene = g.get("scenes", [{}])[g.get("scene", 0)] if g.get("scenes") else {"nodes": []}
    tris = 0

    def add_mesh(path, mesh_index, bake=None):
        """`bake`: an instance matrix applied to the points here (a transformed extent box would
        over-state the bounds of rotated instances)."""
        nonlocal tris
        for pi, prim in enumerate(g["meshes"][mesh_index]["primitives"]):
            res = primitive_triangles(glb, prim, notes)
            if res is None:
                continue
            pts, counts, idx = res
            if bake is not None:
                pts = [mat_point(bake, p) for p in pts]
            if not counts:
                continue
            m = UsdGeom.Mesh.Define(stage, f"{path}/p{pi}")
            m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
            m.CreateFaceVertexCountsAttr(Vt.IntArray(counts))
            m.CreateFaceVertexIndicesAttr(Vt.IntArray(idx))
            m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            m.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(m.GetPointsAttr().Get()))
            tris += len(counts)

    def add_node(path_parent, ni, depth):
        if depth > 64:
            raise ValueError(f"{glb.path}: node hierarchy too deep (cycle?)")
        node = g["nodes"][ni]
        xf = UsdGeom.Xform.Define(stage, f"{path_parent}/n{ni}")
        xf.AddTransformOp().Set(to_gf(node_matrix(node)))
        path = str(xf.GetPath())
        if "mesh" in node:
            inst = gpu_instances(glb, node)
            if inst is None:
                add_mesh(path, node["mesh"])
            else:
                for k, im in enumerate(inst):
                    ix = UsdGeom.Xform.Define(stage, f"{path}/i{k}")
                    add_mesh(str(ix.GetPath()), node["mesh"], bake=im)
        for c in node.get("children", []):
            add_node(path, c, depth + 1)

    for ni in scene.get("nodes", []):
        add_node(parent_path, ni, 0)
    return tris


# ----------------------------------------------------------------------------------------------------------
# Bounding volumes
# ----------------------------------------------------------------------------------------------------------
def box_in_frame(box, m):
    """Tile box (12 numbers) transformed by m: (centre, [3 half-axis vectors])."""
    c = mat_point(m, box[0:3])
    return c, [mat_vec(m, box[3 + 3 * i: 6 + 3 * i]) for i in range(3)]


def box_corners(c, axes):
    return [tuple(c[k] + sx * axes[0][k] + sy * axes[1][k] + sz * axes[2][k] for k in range(3))
            for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]


def box_volume(axes):
    return 8.0 * abs(det3(*axes))


def point_outside_box(p, c, axes, tol):
    """Distance (>0) by which p lies outside the oriented box, 0 if inside (axes may be degenerate)."""
    d = [p[k] - c[k] for k in range(3)]
    worst = 0.0
    for a in axes:
        la = math.sqrt(sum(x * x for x in a))
        if la == 0.0:
            continue
        t = sum(d[k] * a[k] for k in range(3)) / la      # projection on the axis direction
        worst = max(worst, abs(t) - la)
    # component orthogonal to all non-degenerate axes (flat boxes)
    nz = [a for a in axes if any(a)]
    if len(nz) < 3:
        # Gram-Schmidt on the non-degenerate axes, residual = part of d outside their span
        basis = []
        for a in nz:
            v = list(a)
            for b in basis:
                s = sum(v[k] * b[k] for k in range(3))
                v = [v[k] - s * b[k] for k in range(3)]
            n = math.sqrt(sum(x * x for x in v))
            if n > 0:
                basis.append([x / n for x in v])
        r = list(d)
        for b in basis:
            s = sum(r[k] * b[k] for k in range(3))
            r = [r[k] - s * b[k] for k in range(3)]
        worst = max(worst, math.sqrt(sum(x * x for x in r)))
    return worst if worst > tol else 0.0


def tolerance(axes):
    size = max(math.sqrt(sum(x * x for x in a)) for a in axes)
    return ABS_TOL + REL_TOL * size


class TileCheck:
    """One tile: composed matrix (root-local frame), bounding volume, content prim path."""

    def __init__(self, label, matrix, bv, parent):
        self.label, self.matrix, self.bv, self.parent = label, matrix, bv, parent
        self.prim_path = None
        self.triangles = 0
        self.content_files = []


def walk_tileset(tileset_path, stage, notes):
    """Walk the tile tree (following external tilesets); returns a list of TileCheck."""
    tiles = []
    root_dir = os.path.dirname(os.path.abspath(tileset_path))
    UsdGeom.Xform.Define(stage, "/Tileset")

    def content_uris(tile, ptr):
        """(JSON pointer, uri) of the tile's contents."""
        out = []
        if "content" in tile:
            key = "uri" if "uri" in tile["content"] else "url"
            out.append((f"{ptr}/content/{key}", tile["content"][key]))
        out += [(f"{ptr}/contents/{i}/uri", c["uri"]) for i, c in enumerate(tile.get("contents", []))]
        return out

    def visit(tile, json_path, ptr, parent_matrix, parent_check, label, is_root, depth):
        base_dir = os.path.dirname(json_path)
        if depth > 256:
            raise ValueError("tile tree too deep")
        local = IDENTITY if ("transform" not in tile or is_root) else mat_from_column_major(tile["transform"])
        m = mat_mul(parent_matrix, local)
        check = TileCheck(label, m, tile["boundingVolume"], parent_check)
        tiles.append(check)
        if "implicitTiling" in tile:
            notes.append(f"{label}: implicit tiling is not followed by this checker")
        glbs, externals = [], []
        for uri_ptr, uri in content_uris(tile, ptr):
            if is_data_uri(uri):
                # Inlined content: decoded here, read like a file; its own relative uris resolve against
                # the tileset JSON's folder.
                where = data_uri_label(json_path, uri_ptr)
                if data_uri_media_type(uri) == GLB_MEDIA_TYPE:
                    glbs.append((where, data_uri_bytes(uri, where), base_dir))
                else:
                    notes.append(f"{label}: content {where} ({data_uri_media_type(uri)}, not GLB) skipped")
                continue
            full = os.path.normpath(os.path.join(base_dir, uri.split("?")[0]))
            if not os.path.abspath(full).startswith(root_dir + os.sep):
                raise ValueError(f"{label}: content uri escapes the tileset folder: {uri}")
            low = full.lower()
            if low.endswith(".glb"):
                glbs.append((full, None, None))
            elif low.endswith(".json"):
                externals.append(full)
            else:
                notes.append(f"{label}: content {uri} (not GLB) skipped")
        if glbs:
            xf = UsdGeom.Xform.Define(stage, f"/Tileset/{label}")
            xf.AddTransformOp().Set(to_gf(m))
            up = UsdGeom.Xform.Define(stage, f"/Tileset/{label}/yup")
            up.AddTransformOp().Set(to_gf(Y_UP_TO_Z_UP))
            for ci, (full, data, base) in enumerate(glbs):
                cx = UsdGeom.Xform.Define(stage, f"/Tileset/{label}/yup/c{ci}")
                check.triangles += add_glb_to_stage(stage, str(cx.GetPath()), Glb(full, data, base), notes)
                check.content_files.append(os.path.relpath(full, root_dir))
            check.prim_path = f"/Tileset/{label}"
        for ext in externals:
            with open(ext) as fh:
                sub = json.load(fh)
            # the external tileset's root is a child of this tile (its transform applies)
            visit(sub["root"], ext, "/root", m, check, f"{label}_x", False, depth + 1)
        for i, child in enumerate(tile.get("children", [])):
            visit(child, json_path, f"{ptr}/children/{i}", m, check, f"{label}_{i}", False, depth + 1)

    with open(tileset_path) as fh:
        ts = json.load(fh)
    if "transform" in ts["root"]:
        notes.append("root transform ignored: bounds compared in the root tile's local frame")
    visit(ts["root"], os.path.abspath(tileset_path), "/root", IDENTITY, None, "t0", True, 0)
    return ts, tiles


def check_tileset(directory, verbose=True):
    """Cross-check one tileset directory. Returns a report dict; report['problems'] is empty when all is fine."""
    tileset_path = os.path.join(directory, "tileset.json")
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    notes, problems = [], []
    ts, tiles = walk_tileset(tileset_path, stage, notes)
    cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_])
    rows = []
    for t in tiles:
        bv = t.bv
        row = {"tile": t.label, "content": t.content_files, "triangles": t.triangles}
        if "box" in bv:
            c, axes = box_in_frame(bv["box"], t.matrix)
            tol = tolerance(axes)
        elif "sphere" in bv:
            c = mat_point(t.matrix, bv["sphere"][0:3])
            scale = max(math.sqrt(sum(t.matrix[r][k] ** 2 for r in range(3))) for k in range(3))
            radius = bv["sphere"][3] * scale
            axes, tol = None, ABS_TOL + REL_TOL * radius
        else:
            notes.append(f"{t.label}: boundingVolume {list(bv)} not checked (region needs geodesy)")
            rows.append(row)
            continue
        if t.prim_path is not None and t.triangles > 0:
            bbox = cache.ComputeWorldBound(stage.GetPrimAtPath(t.prim_path))
            rng = bbox.GetRange()
            mtx = bbox.GetMatrix()
            lo, hi = rng.GetMin(), rng.GetMax()
            corners = [tuple(mtx.Transform(Gf.Vec3d(x, y, z))) for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                       for z in (lo[2], hi[2])]
            aligned = bbox.ComputeAlignedRange()
            row["content_min"] = list(aligned.GetMin())
            row["content_max"] = list(aligned.GetMax())
            if axes is not None:
                out = max(point_outside_box(p, c, axes, tol) for p in corners)
                vol = box_volume(axes)
                cvol = bbox.GetVolume()
                row["tightness"] = (cvol / vol) if vol > 0 else None
            else:
                out = max(max(0.0, math.dist(p, c) - radius - tol) for p in corners)
                row["tightness"] = None
            if out > 0:
                problems.append(f"{t.label}: content bounds {row['content_min']}..{row['content_max']} lie "
                                f"{out:.6g} outside its boundingVolume")
        if t.parent is not None and "box" in bv and "box" in t.parent.bv:
            pc, paxes = box_in_frame(t.parent.bv["box"], t.parent.matrix)
            ptol = tolerance(paxes)
            out = max(point_outside_box(p, pc, paxes, ptol) for p in box_corners(c, axes))
            if out > 0:
                problems.append(f"{t.label}: box lies {out:.6g} outside its parent {t.parent.label}'s box")
        rows.append(row)
    report = {"dir": directory, "tiles": len(tiles), "triangles": sum(t.triangles for t in tiles),
              "rows": rows, "notes": notes, "problems": problems}
    if verbose:
        print(f"\n[usd-crosscheck] {directory}: {len(tiles)} tiles, {report['triangles']} triangles")
        for r in rows:
            tight = r.get("tightness")
            print(f"  {r['tile']}: {r['triangles']} tris, content/box volume "
                  f"{'n/a' if tight is None else f'{tight:.3f}'} {r['content']}")
        for n in notes:
            print(f"  note: {n}")
        for p in problems:
            print(f"  PROBLEM: {p}")
    return report


# ----------------------------------------------------------------------------------------------------------
# Tests on real output (BIMTILES_TILESET_DIRS)
# ----------------------------------------------------------------------------------------------------------
def _env_dirs():
    v = os.environ.get("BIMTILES_TILESET_DIRS", "")
    return [d for d in v.split(":") if d]


@pytest.mark.parametrize("directory", _env_dirs() or [None])
def test_tileset_dirs_crosscheck(directory):
    if directory is None:
        pytest.skip("BIMTILES_TILESET_DIRS is not set: set it to a colon-separated list of bimtiles output "
                    "directories (each with a tileset.json) to cross-check them with USD")
    assert os.path.isfile(os.path.join(directory, "tileset.json")), f"no tileset.json in {directory}"
    # Meshopt tiles: read from a copy decoded by meshoptimizer's reference decoder.
    report = check_tileset(str(decoded_tileset(directory)))
    assert report["tiles"] > 0
    assert not report["problems"], "\n".join(report["problems"])


# ----------------------------------------------------------------------------------------------------------
# Self-tests on a hand-built tileset
# ----------------------------------------------------------------------------------------------------------
def box_mesh(hx, hy, hz):
    """Closed box centred at the origin: 8 points, 12 triangles."""
    pts = [(sx * hx, sy * hy, sz * hz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    idx = [i for a, b, c, d in quads for i in (a, b, c, a, c, d)]
    return pts, idx


def write_glb(path, nodes, scene_nodes, index_type=5123, interleave=True):
    """A GLB whose single mesh is a 2 x 1 x 0.5 box (half extents 1, 0.5, 0.25) centred at the origin."""
    pts, idx = box_mesh(1.0, 0.5, 0.25)
    bin_ = bytearray()
    views, accessors = [], []
    normals = [(0.0, 0.0, 1.0)] * len(pts)
    if interleave:   # POSITION + a dummy attribute, byteStride 24, position at byteOffset 12
        data = b"".join(struct.pack("<3f3f", *n, *p) for p, n in zip(pts, normals))
        views.append({"buffer": 0, "byteOffset": 0, "byteLength": len(data), "byteStride": 24, "target": 34962})
        pos_off = 12
    else:
        data = b"".join(struct.pack("<3f", *p) for p in pts)
        views.append({"buffer": 0, "byteOffset": 0, "byteLength": len(data), "target": 34962})
        pos_off = 0
    bin_ += data
    accessors.append({"bufferView": 0, "byteOffset": pos_off, "componentType": 5126, "count": len(pts),
                      "type": "VEC3", "min": [-1, -0.5, -0.25], "max": [1, 0.5, 0.25]})
    fmt = {5121: "B", 5123: "H", 5125: "I"}[index_type]
    while len(bin_) % 4:
        bin_.append(0)
    ib = struct.pack(f"<{len(idx)}{fmt}", *idx)
    views.append({"buffer": 0, "byteOffset": len(bin_), "byteLength": len(ib), "target": 34963})
    bin_ += ib
    accessors.append({"bufferView": 1, "componentType": index_type, "count": len(idx), "type": "SCALAR"})
    while len(bin_) % 4:
        bin_.append(0)
    g = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": scene_nodes}], "nodes": nodes,
         "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
         "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(bin_)}]}
    js = json.dumps(g).encode()
    js += b" " * ((4 - len(js) % 4) % 4)
    with open(path, "wb") as fh:
        fh.write(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(js) + 8 + len(bin_)))
        fh.write(struct.pack("<I4s", len(js), b"JSON") + js)
        fh.write(struct.pack("<I4s", len(bin_), b"BIN\x00") + bytes(bin_))


def column_major(m):
    return [m[r][c] for c in range(4) for r in range(4)]


def make_tileset(d, root_box=None, child_box=None, inline_root=False):
    """Root tile (ECEF-like root transform, content root.glb) with one child (own transform: 90 deg about Z
    plus translation (3, 0, 0); content child/child.glb). With inline_root, root.glb is inlined in
    tileset.json as a base64 data URI instead (as bimtiles writes the root by default) and not kept as a file.

    root.glb: node 0 translation (0, 5, 0) with child node 1 rotated 90 deg about +Y holding the box ->
      glTF half extents (0.25, 0.5, 1) at (0, 5, 0) -> z-up: x [-0.25, 0.25], y [-1, 1], z [4.5, 5.5].
    child.glb: node translation (0, 1, 0), box -> z-up in the child frame: centre (0, 0, 1), half (1, 0.25, 0.5)
      -> root frame (after the child transform (x, y) -> (3 - y, x)): x [2.75, 3.25], y [-1, 1], z [0.5, 1.5].
    """
    os.makedirs(os.path.join(d, "child"), exist_ok=True)
    s = math.sqrt(0.5)
    write_glb(os.path.join(d, "root.glb"),
              [{"translation": [0, 5, 0], "children": [1]}, {"rotation": [0, s, 0, s], "mesh": 0}], [0],
              index_type=5121, interleave=True)
    write_glb(os.path.join(d, "child", "child.glb"), [{"translation": [0, 1, 0], "mesh": 0}], [0],
              index_type=5125, interleave=False)
    lat, lon = math.radians(49.0), math.radians(8.4)
    east = (-math.sin(lon), math.cos(lon), 0.0)
    north = (-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat))
    up = (math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat))
    origin = tuple(6378137.0 * u for u in up)
    root_tf = [*east, 0, *north, 0, *up, 0, *origin, 1]
    child_tf = column_major([[0, -1, 0, 3], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    ts = {
        "asset": {"version": "1.1"},
        "geometricError": 100,
        "root": {
            "transform": root_tf,
            "boundingVolume": {"box": root_box or [1.5, 0, 3, 3, 0, 0, 0, 1.5, 0, 0, 0, 3.5]},
            "geometricError": 10, "refine": "ADD",
            "content": {"uri": "root.glb"},
            "children": [{
                "transform": child_tf,
                "boundingVolume": {"box": child_box or [0, 0, 1, 1.01, 0, 0, 0, 0.26, 0, 0, 0, 0.51]},
                "geometricError": 0,
                "content": {"uri": "child/child.glb"},
            }],
        },
    }
    if inline_root:
        with open(os.path.join(d, "root.glb"), "rb") as fh:
            ts["root"]["content"]["uri"] = f"data:{GLB_MEDIA_TYPE};base64," + base64.b64encode(fh.read()).decode()
        os.remove(os.path.join(d, "root.glb"))
    with open(os.path.join(d, "tileset.json"), "w") as fh:
        json.dump(ts, fh, indent=1)
    return d


def _row(report, tile):
    return next(r for r in report["rows"] if r["tile"] == tile)


def test_handbuilt_tileset_passes(tmp_path):
    rep = check_tileset(make_tileset(str(tmp_path)))
    assert rep["problems"] == []
    assert rep["tiles"] == 2 and rep["triangles"] == 24
    root, child = _row(rep, "t0"), _row(rep, "t0_0")
    for got, want in zip(root["content_min"] + root["content_max"], [-0.25, -1, 4.5, 0.25, 1, 5.5]):
        assert got == pytest.approx(want, abs=1e-6)
    for got, want in zip(child["content_min"] + child["content_max"], [2.75, -1, 0.5, 3.25, 1, 1.5]):
        assert got == pytest.approx(want, abs=1e-6)
    # content box 0.5 x 2 x 1 = 1 m^3 in a 6 x 3 x 7 = 126 m^3 box
    assert root["tightness"] == pytest.approx(1 / 126, rel=1e-6)
    assert any("root transform ignored" in n for n in rep["notes"])


def test_inlined_root_is_read(tmp_path):
    # The root's GLB as a data URI in tileset.json: read as the file was (same bounds, same triangles).
    rep = check_tileset(make_tileset(str(tmp_path), inline_root=True))
    assert rep["problems"] == []
    assert rep["tiles"] == 2 and rep["triangles"] == 24
    root = _row(rep, "t0")
    assert root["content"] == ["tileset.json#/root/content/uri"]
    for got, want in zip(root["content_min"] + root["content_max"], [-0.25, -1, 4.5, 0.25, 1, 5.5]):
        assert got == pytest.approx(want, abs=1e-6)
    # ... and checked as the file was: a box that does not hold it fails.
    bad = check_tileset(make_tileset(str(tmp_path / "bad"), root_box=[1.5, 0, 3, 3, 0, 0, 0, 0.9, 0, 0, 0, 3.5],
                                     inline_root=True), verbose=False)
    assert any(p.startswith("t0: content") for p in bad["problems"]), bad["problems"]


def test_inlined_root_not_base64_fails(tmp_path):
    d = make_tileset(str(tmp_path), inline_root=True)
    with open(os.path.join(d, "tileset.json")) as fh:
        ts = json.load(fh)
    ts["root"]["content"]["uri"] = ts["root"]["content"]["uri"].replace(";base64,", ",", 1)
    with open(os.path.join(d, "tileset.json"), "w") as fh:
        json.dump(ts, fh)
    with pytest.raises(AssertionError, match="not base64"):
        check_tileset(d, verbose=False)


def test_box_not_containing_content_fails(tmp_path):
    # root box too thin in y (content spans y -1..1)
    rep = check_tileset(make_tileset(str(tmp_path), root_box=[1.5, 0, 3, 3, 0, 0, 0, 0.9, 0, 0, 0, 3.5]),
                        verbose=False)
    assert any(p.startswith("t0: content") for p in rep["problems"]), rep["problems"]


def test_child_box_rotation_matters(tmp_path):
    # the child box must be expressed in the child's (rotated) frame: swapping its x/y half axes is wrong
    rep = check_tileset(make_tileset(str(tmp_path), child_box=[0, 0, 1, 0.26, 0, 0, 0, 1.01, 0, 0, 0, 0.51]),
                        verbose=False)
    assert any(p.startswith("t0_0: content") for p in rep["problems"]), rep["problems"]


def test_child_box_outside_parent_fails(tmp_path):
    # child box contains its content but sticks out of the root box (root x reaches 4.5 only)
    rep = check_tileset(make_tileset(str(tmp_path), child_box=[0, 0, 1, 1.01, 0, 0, 0, 2.0, 0, 0, 0, 0.51]),
                        verbose=False)
    assert not any(p.startswith("t0_0: content") for p in rep["problems"])
    assert any("outside its parent" in p for p in rep["problems"]), rep["problems"]


def test_glb_reader_strides_and_index_types(tmp_path):
    p = str(tmp_path / "a.glb")
    for it in (5121, 5123, 5125):
        for inter in (True, False):
            write_glb(p, [{"mesh": 0}], [0], index_type=it, interleave=inter)
            g = Glb(p)
            pts = g.accessor(0)
            idx = [e[0] for e in g.accessor(1)]
            assert len(pts) == 8 and len(idx) == 36
            assert min(x[0] for x in pts) == -1 and max(x[2] for x in pts) == 0.25
            assert sorted(set(idx)) == list(range(8))


def test_sample_building_glb_reads():
    """The bundled sample (if present) goes through the reader and USD without loss of triangles."""
    here = os.path.dirname(os.path.abspath(__file__))
    path = os.path.join(here, "..", "..", "samples", "sample_building.glb")
    exp = os.path.join(here, "..", "..", "samples", "sample_building.expect.json")
    if not (os.path.exists(path) and os.path.exists(exp)):
        pytest.skip("samples/sample_building.glb not generated")
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.Xform.Define(stage, "/S")
    notes = []
    tris = add_glb_to_stage(stage, "/S", Glb(path), notes)
    with open(exp) as fh:
        expect = json.load(fh)
    assert tris == expect["triangles"]
    rng = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_]).ComputeWorldBound(
        stage.GetPrimAtPath("/S")).ComputeAlignedRange()
    for got, want in zip(list(rng.GetMin()) + list(rng.GetMax()), expect["bbox_min"] + expect["bbox_max"]):
        assert got == pytest.approx(want, abs=1e-4)
