#!/usr/bin/env python3
"""Generate samples/sample_building.glb: a small, deterministic office building for bimtiles.

Python 3 standard library only. Running it twice gives byte-identical output (the PNG textures are
compressed with the standard zlib module; their bytes depend only on the zlib version).

    python3 samples/make_sample.py            # writes samples/sample_building.glb + .expect.json
    python3 samples/make_sample.py OUT_DIR    # writes both files into OUT_DIR instead

The building (glTF y-up, metres, footprint 30 m (x) by 15 m (z), 3 storeys of 3.5 m, roof with parapet and a
stair penthouse; overall about 30 x 13.8 x 15 m) is modelled the way BIM exporters write it:

* one glTF node per building element (node name = 22-character IFC GlobalId, `extras` = ifc_class, name,
  storey, guid) under storey nodes under one building node;
* repeated elements (windows, doors, columns, walls, slabs, stairs ...) are separate meshes with world
  coordinates baked in, some rotated by 90/180/270 degrees about the vertical axis (rigid copies);
* two elements are exact redundant duplicates (same geometry at the same place, other GlobalId);
* furniture (desks) and light fixtures are glTF-level instances (many nodes, one mesh, node TRS / matrix);
* a stone-clad facade and two planters are textured with one "photo" image of which the UVs use ~60 %;
  the lobby floor has a small tiling texture with UVs far outside [0, 1] (REPEAT sampler).

All counts that tests rely on are computed here from the generated geometry and written to
sample_building.expect.json (never hand-typed).
"""

import hashlib
import json
import math
import os
import struct
import sys
import zlib

# --------------------------------------------------------------------------------------------------------------
# Dimensions
# --------------------------------------------------------------------------------------------------------------
LEN_X = 30.0          # building length (x)
LEN_Z = 15.0          # building depth (z)
STOREY_H = 3.5        # floor-to-floor height
N_STOREYS = 3
SLAB_T = 0.3          # slab thickness
EXT_T = 0.3           # exterior wall thickness
INT_T = 0.12          # partition thickness
CORE_T = 0.25         # core wall thickness
CORE = (13.0, 17.0, 1.0, 6.0)   # core outer footprint x0, x1, z0, z1
CLEAR_H = STOREY_H - SLAB_T     # floor to slab underside
ROOF_Y = N_STOREYS * STOREY_H   # top of roof slab
WIN_A = (1.8, 1.5, 0.9)         # window type A: width, height, sill height
WIN_B = (1.2, 1.5, 0.9)         # window type B (east facade)
DOOR = (0.9, 2.1)               # interior door opening
ENTRANCE = (2.0, 2.4)           # entrance double door opening

F32 = struct.Struct('<f')


def f32(x):
    """Round a Python float to the nearest float32 (what the GLB stores)."""
    return F32.unpack(F32.pack(x))[0]


# --------------------------------------------------------------------------------------------------------------
# Small vector helpers
# --------------------------------------------------------------------------------------------------------------
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(a):
    n = math.sqrt(dot(a, a))
    return (a[0] / n, a[1] / n, a[2] / n)


# Rotations about +Y by k * 90 degrees, exact: (x, z) -> (x cos + z sin, -x sin + z cos)
ROT_CS = {0: (1, 0), 1: (0, 1), 2: (-1, 0), 3: (0, -1)}


def rot_y(p, k):
    c, s = ROT_CS[k % 4]
    return (p[0] * c + p[2] * s, p[1], -p[0] * s + p[2] * c)


# --------------------------------------------------------------------------------------------------------------
# Mesh building: flat faces, vertices split at hard edges (shared only inside one planar face)
# --------------------------------------------------------------------------------------------------------------
class Prim:
    def __init__(self, material, uv_mode=None):
        self.material = material
        self.uv_mode = uv_mode      # None, or a function (pos, normal) -> (u, v)
        self.pos = []
        self.nrm = []
        self.uv = []
        self.idx = []

    def _add_face(self, tris, normal):
        """tris: list of 3-tuples of 3D points, all in one plane with outward `normal`."""
        n = norm(normal)
        lookup = {}
        for tri in tris:
            a, b, c = tri
            if dot(cross(sub(b, a), sub(c, a)), n) < 0:
                tri = (a, c, b)
            for p in tri:
                key = (round(p[0], 9), round(p[1], 9), round(p[2], 9))
                i = lookup.get(key)
                if i is None:
                    i = len(self.pos)
                    lookup[key] = i
                    self.pos.append(p)
                    self.nrm.append(n)
                self.idx.append(i)

    def quad(self, a, b, c, d, normal):
        self._add_face([(a, b, c), (a, c, d)], normal)

    def face(self, tris, normal):
        self._add_face(tris, normal)

    def box(self, x0, x1, y0, y1, z0, z1, skip=()):
        P = lambda x, y, z: (x, y, z)
        faces = {
            '-x': ([P(x0, y0, z0), P(x0, y0, z1), P(x0, y1, z1), P(x0, y1, z0)], (-1, 0, 0)),
            '+x': ([P(x1, y0, z0), P(x1, y1, z0), P(x1, y1, z1), P(x1, y0, z1)], (1, 0, 0)),
            '-y': ([P(x0, y0, z0), P(x1, y0, z0), P(x1, y0, z1), P(x0, y0, z1)], (0, -1, 0)),
            '+y': ([P(x0, y1, z0), P(x0, y1, z1), P(x1, y1, z1), P(x1, y1, z0)], (0, 1, 0)),
            '-z': ([P(x0, y0, z0), P(x0, y1, z0), P(x1, y1, z0), P(x1, y0, z0)], (0, 0, -1)),
            '+z': ([P(x0, y0, z1), P(x1, y0, z1), P(x1, y1, z1), P(x0, y1, z1)], (0, 0, 1)),
        }
        for name, (q, n) in faces.items():
            if name not in skip:
                self.quad(*q, n)

    def transformed(self, k, t):
        """Rigid copy: rotate about +Y by k*90 deg, then translate by t. UVs are kept (they belong to the shape)."""
        out = Prim(self.material)
        out.pos = [tuple(a + b for a, b in zip(rot_y(p, k), t)) for p in self.pos]
        out.nrm = [rot_y(n, k) for n in self.nrm]
        out.uv = list(self.uv)
        out.idx = list(self.idx)
        return out

    def finish_uvs(self, uv_fn):
        self.uv = [uv_fn(p, n) for p, n in zip(self.pos, self.nrm)]


def rect_with_hole_2d(ua, ub, va, vb, hole):
    """Triangles (2D) of the rectangle [ua,ub]x[va,vb] minus an optional hole (hu0,hu1,hv0,hv1).
    No T-junctions: trapezoids around an inner hole, a U shape for a hole that touches the bottom."""
    if hole is None:
        return [((ua, va), (ub, va), (ub, vb)), ((ua, va), (ub, vb), (ua, vb))]
    hu0, hu1, hv0, hv1 = hole
    if hv0 <= va + 1e-9:      # doorway: U shape
        return [((ua, va), (hu0, va), (hu0, hv1)), ((ua, va), (hu0, hv1), (ua, vb)),
                ((ua, vb), (hu0, hv1), (hu1, hv1)), ((ua, vb), (hu1, hv1), (ub, vb)),
                ((hu1, hv1), (hu1, va), (ub, va)), ((hu1, hv1), (ub, va), (ub, vb))]
    o = [(ua, va), (ub, va), (ub, vb), (ua, vb)]
    h = [(hu0, hv0), (hu1, hv0), (hu1, hv1), (hu0, hv1)]
    tris = []
    for i in range(4):
        j = (i + 1) % 4
        tris.append((o[i], o[j], h[j]))
        tris.append((o[i], h[j], h[i]))
    return tris


def wall_panel(prim, length, height, thick, openings, y0=0.0):
    """A wall in its local frame: u along +x (0..length), v up (y0..y0+height), w = z (0..thick; the w=0 face is
    the outer face). `openings`: list of (u_centre, width, sill, head) through the whole thickness.
    Closed and conforming: split into bays, one opening per bay, with reveals."""
    ops = sorted(openings)
    cuts = [0.0]
    for a, b in zip(ops, ops[1:]):
        cuts.append(0.5 * ((a[0] + a[1] / 2) + (b[0] - b[1] / 2)))
    cuts.append(length)
    v0, v1 = y0, y0 + height
    for bi in range(len(cuts) - 1):
        ua, ub = cuts[bi], cuts[bi + 1]
        hole = None
        if ops:
            c, wdt, sill, head = ops[bi]
            hole = (c - wdt / 2, c + wdt / 2, v0 + sill, v0 + head)
            assert ua < hole[0] and hole[1] < ub and hole[3] < v1
        tris2 = rect_with_hole_2d(ua, ub, v0, v1, hole)
        for w, nz in ((0.0, -1), (thick, 1)):
            prim.face([tuple((p[0], p[1], w) for p in t) for t in tris2], (0, 0, nz))
        # top, bottom (bottom interrupted by a doorway)
        prim.quad((ua, v1, 0), (ub, v1, 0), (ub, v1, thick), (ua, v1, thick), (0, 1, 0))
        if hole is not None and hole[2] <= v0 + 1e-9:
            for a, b in ((ua, hole[0]), (hole[1], ub)):
                prim.quad((a, v0, 0), (b, v0, 0), (b, v0, thick), (a, v0, thick), (0, -1, 0))
        else:
            prim.quad((ua, v0, 0), (ub, v0, 0), (ub, v0, thick), (ua, v0, thick), (0, -1, 0))
        if hole is not None:  # reveals, facing into the opening
            hu0, hu1, hv0, hv1 = hole
            prim.quad((hu0, hv0, 0), (hu0, hv1, 0), (hu0, hv1, thick), (hu0, hv0, thick), (1, 0, 0))
            prim.quad((hu1, hv0, 0), (hu1, hv1, 0), (hu1, hv1, thick), (hu1, hv0, thick), (-1, 0, 0))
            prim.quad((hu0, hv1, 0), (hu1, hv1, 0), (hu1, hv1, thick), (hu0, hv1, thick), (0, -1, 0))
            if hv0 > v0 + 1e-9:
                prim.quad((hu0, hv0, 0), (hu1, hv0, 0), (hu1, hv0, thick), (hu0, hv0, thick), (0, 1, 0))
    # wall ends
    prim.quad((0, v0, 0), (0, v1, 0), (0, v1, thick), (0, v0, thick), (-1, 0, 0))
    prim.quad((length, v0, 0), (length, v1, 0), (length, v1, thick), (length, v0, thick), (1, 0, 0))


def frame_prism(prim, w, h, fw, z0, z1, y0=0.0):
    """Rectangular frame (outer w x h centred on x=0, from y0; frame width fw), extruded z0..z1. Closed."""
    ox0, ox1, oy0, oy1 = -w / 2, w / 2, y0, y0 + h
    hole = (ox0 + fw, ox1 - fw, oy0 + fw, oy1 - fw)
    tris2 = rect_with_hole_2d(ox0, ox1, oy0, oy1, hole)
    for z, nz in ((z0, -1), (z1, 1)):
        prim.face([tuple((p[0], p[1], z) for p in t) for t in tris2], (0, 0, nz))
    hx0, hx1, hy0, hy1 = hole
    for (xa, ya, xb, yb, n) in ((ox0, oy0, ox1, oy0, (0, -1, 0)), (ox1, oy0, ox1, oy1, (1, 0, 0)),
                                (ox1, oy1, ox0, oy1, (0, 1, 0)), (ox0, oy1, ox0, oy0, (-1, 0, 0)),
                                (hx0, hy0, hx1, hy0, (0, 1, 0)), (hx1, hy0, hx1, hy1, (-1, 0, 0)),
                                (hx1, hy1, hx0, hy1, (0, -1, 0)), (hx0, hy1, hx0, hy0, (1, 0, 0))):
        prim.quad((xa, ya, z0), (xb, yb, z0), (xb, yb, z1), (xa, ya, z1), n)


def cylinder(prim, r, y0, y1, seg):
    """Vertical cylinder on the y axis: smooth sides (shared normals), flat caps (split at the hard edge)."""
    angs = [2 * math.pi * i / seg for i in range(seg)]
    ring = [(r * math.cos(a), r * math.sin(a)) for a in angs]
    base = len(prim.pos)
    for (x, z), a in zip(ring, angs):
        n = (math.cos(a), 0.0, math.sin(a))
        prim.pos += [(x, y0, z), (x, y1, z)]
        prim.nrm += [n, n]
    for i in range(seg):
        j = (i + 1) % seg
        a0, a1, b0, b1 = base + 2 * i, base + 2 * i + 1, base + 2 * j, base + 2 * j + 1
        # outward winding: (a0, a1, b1), (a0, b1, b0) — checked below
        prim.idx += [a0, a1, b1, a0, b1, b0]
    cap_b = [((x, y0, z)) for x, z in ring]
    cap_t = [((x, y1, z)) for x, z in ring]
    prim.face([(cap_b[0], cap_b[i], cap_b[i + 1]) for i in range(1, seg - 1)], (0, -1, 0))
    prim.face([(cap_t[0], cap_t[i], cap_t[i + 1]) for i in range(1, seg - 1)], (0, 1, 0))


# --------------------------------------------------------------------------------------------------------------
# Materials and textures
# --------------------------------------------------------------------------------------------------------------
MATERIALS = {}   # name -> glTF material dict (insertion order = index order)


def mat(name, rgba, double=False, blend=False, texture=None, rough=0.8):
    pbr = {"baseColorFactor": [round(c, 4) for c in rgba], "metallicFactor": 0.0, "roughnessFactor": rough}
    if texture is not None:
        pbr["baseColorTexture"] = {"index": texture, "texCoord": 0}
    m = {"name": name, "pbrMetallicRoughness": pbr}
    if blend:
        m["alphaMode"] = "BLEND"
    if double:
        m["doubleSided"] = True
    MATERIALS[name] = m


mat("Concrete", (0.62, 0.61, 0.58, 1))
mat("Render white", (0.88, 0.87, 0.83, 1))
mat("Plaster", (0.80, 0.80, 0.78, 1))
mat("Aluminium frame", (0.25, 0.27, 0.29, 1), rough=0.5)
mat("Glass", (0.55, 0.72, 0.80, 0.35), double=True, blend=True, rough=0.1)
mat("Door leaf oak", (0.58, 0.42, 0.26, 1))
mat("Door frame", (0.35, 0.35, 0.36, 1))
mat("Column concrete", (0.70, 0.69, 0.66, 1))
mat("Stair concrete", (0.74, 0.73, 0.70, 1))
mat("Roof membrane", (0.30, 0.31, 0.33, 1), rough=0.9)
mat("Desk top", (0.76, 0.62, 0.45, 1))
mat("Desk frame", (0.15, 0.15, 0.16, 1), rough=0.6)
mat("Light fixture", (0.95, 0.95, 0.93, 1), double=True, rough=0.4)
mat("Stone cladding", (1, 1, 1, 1), texture=0)
mat("Stone cladding dark", (0.62, 0.58, 0.55, 1), texture=0)   # same texture/image, other tint
mat("Floor tiles", (1, 1, 1, 1), texture=1)
MAT_INDEX = {n: i for i, n in enumerate(MATERIALS)}

# "Photo" texture: the facade occupies UV [PHOTO_U0, PHOTO_U1]^2 (~59 % of the area); the rest of the image is
# sky / street / vegetation that no UV references (a cropping stage can drop it).
PHOTO_SIZE = 512
PHOTO_U0, PHOTO_U1 = 0.05, 0.82
TILE_SIZE = 128
TILE_M = 1.2   # one texture repeat = 1.2 m (2 x 2 tiles of 0.6 m)


def hash01(*ints):
    h = 0x811C9DC5
    for v in ints:
        h = ((h ^ (v & 0xFFFFFFFF)) * 0x01000193) & 0xFFFFFFFF
        h ^= h >> 15
        h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
        h ^= h >> 12
    return h / 4294967296.0


def png_rgb(width, height, row_fn):
    raw = bytearray()
    for y in range(height):
        raw.append(0)             # filter: none
        raw += row_fn(y)
    def chunk(tag, data):
        return struct.pack('>I', len(data)) + tag + data + struct.pack('>I', zlib.crc32(tag + data) & 0xFFFFFFFF)
    ihdr = struct.pack('>IIBBBBB', width, height, 8, 2, 0, 0, 0)
    return b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', ihdr) + chunk(b'IDAT', zlib.compress(bytes(raw), 9)) + chunk(b'IEND', b'')


def photo_texture():
    S = PHOTO_SIZE
    p0, p1 = int(round(PHOTO_U0 * S)), int(round(PHOTO_U1 * S))
    bw, bh, mortar = 20, 10, 2

    def pixel(x, y):
        if p0 <= x < p1 and p0 <= y < p1:      # the clad facade: running-bond stone blocks
            yy, xx = y - p0, x - p0
            row = yy // bh
            xo = xx + (bw // 2 if row % 2 else 0)
            col = xo // bw
            if yy % bh < mortar or xo % bw < mortar:
                return (176, 170, 158)
            t = hash01(row, col)
            shade = 0.82 + 0.3 * t - 0.002 * (yy % bh)
            return (min(255, int(168 * shade)), min(255, int(96 * shade)), min(255, int(70 * shade)))
        if y < p0:                              # sky
            k = y / max(p0, 1)
            return (int(120 + 60 * k), int(170 + 40 * k), int(225 + 20 * k))
        if y >= p1:                             # pavement
            return (120, 118, 112) if (x // 32 + y // 16) % 2 else (132, 130, 124)
        # right of the facade: a hedge
        return (int(40 + 40 * hash01(x // 6, y // 6)), int(90 + 50 * hash01(y // 6, x // 6)), 40)

    return png_rgb(S, S, lambda y: bytes(c for x in range(S) for c in pixel(x, y)))


def tile_texture():
    S = TILE_SIZE
    half = S // 2

    def pixel(x, y):
        if x % half < 2 or y % half < 2:
            return (90, 88, 84)
        dark = ((x // half) + (y // half)) % 2
        base = (150, 146, 138) if dark else (214, 208, 196)
        d = int(8 * hash01(x // 16, y // 16))
        return (base[0] - d, base[1] - d, base[2] - d)

    return png_rgb(S, S, lambda y: bytes(c for x in range(S) for c in pixel(x, y)))


# --------------------------------------------------------------------------------------------------------------
# Shape prototypes (local frame) keyed by a shape key; placing one = rigid transform (rotation k*90 + translation)
# --------------------------------------------------------------------------------------------------------------
_PROTO = {}


def proto(key):
    if key in _PROTO:
        return _PROTO[key]
    kind = key[0]
    prims = []
    if kind == 'window':
        _, w, h = key
        frame = Prim('Aluminium frame')
        fw, d = 0.07, 0.08
        frame_prism(frame, w, h, fw, -d / 2, d / 2)
        frame.box(-0.03, 0.03, fw, h - fw, -d / 2 + 0.01, d / 2 - 0.01)            # mullion
        frame.box(-w / 2 - 0.05, w / 2 + 0.05, -0.04, 0.0, -EXT_T / 2 - 0.06, -d / 2)  # outer sill (w<0 side)
        glass = Prim('Glass')
        for xa, xb in ((-w / 2 + fw, -0.03), (0.03, w / 2 - fw)):
            glass.box(xa, xb, fw, h - fw, -0.006, 0.006)
        prims = [frame, glass]
    elif kind == 'door':
        _, w, h, t = key
        frame = Prim('Door frame')
        fw = 0.05
        frame.box(-w / 2, -w / 2 + fw, 0, h, -t / 2, t / 2)
        frame.box(w / 2 - fw, w / 2, 0, h, -t / 2, t / 2)
        frame.box(-w / 2 + fw, w / 2 - fw, h - fw, h, -t / 2, t / 2)
        leaf = Prim('Door leaf oak')
        leaf.box(-w / 2 + fw + 0.005, w / 2 - fw - 0.005, 0.01, h - fw - 0.005, -0.02, 0.02)
        leaf.box(w / 2 - fw - 0.12, w / 2 - fw - 0.06, 1.0, 1.04, -0.07, -0.02)        # handle, one side only
        prims = [frame, leaf]
    elif kind == 'entrance':
        _, w, h, t = key
        frame = Prim('Door frame')
        fw = 0.08
        frame.box(-w / 2, -w / 2 + fw, 0, h, -t / 2, t / 2)
        frame.box(w / 2 - fw, w / 2, 0, h, -t / 2, t / 2)
        frame.box(-w / 2 + fw, w / 2 - fw, h - fw, h, -t / 2, t / 2)
        frame.box(-0.03, 0.03, 0.0, h - fw, -0.04, 0.04)                             # centre post
        glass = Prim('Glass')
        for xa, xb in ((-w / 2 + fw, -0.03), (0.03, w / 2 - fw)):
            glass.box(xa, xb, 0.0, h - fw, -0.01, 0.01)
        prims = [frame, glass]
    elif kind == 'wall':
        _, material, length, height, thick, openings = key
        p = Prim(material)
        wall_panel(p, length, height, thick, list(openings))
        prims = [p]
    elif kind == 'box':
        _, material, sx, sy, sz = key
        p = Prim(material)
        p.box(0, sx, 0, sy, 0, sz)
        prims = [p]
    elif kind == 'slab':
        _, material, sx, sz, t, hole = key
        p = Prim(material)
        tris2 = rect_with_hole_2d(0, sx, 0, sz, hole)   # in (x, z)
        for y, ny in ((0.0, -1), (t, 1)):
            p.face([tuple((q[0], y, q[1]) for q in tr) for tr in tris2], (0, ny, 0))
        for (xa, za, xb, zb, n) in ((0, 0, sx, 0, (0, 0, -1)), (sx, 0, sx, sz, (1, 0, 0)),
                                    (sx, sz, 0, sz, (0, 0, 1)), (0, sz, 0, 0, (-1, 0, 0))):
            p.quad((xa, 0, za), (xb, 0, zb), (xb, t, zb), (xa, t, za), n)
        if hole:
            hx0, hx1, hz0, hz1 = hole
            for (xa, za, xb, zb, n) in ((hx0, hz0, hx1, hz0, (0, 0, 1)), (hx1, hz0, hx1, hz1, (-1, 0, 0)),
                                        (hx1, hz1, hx0, hz1, (0, 0, -1)), (hx0, hz1, hx0, hz0, (1, 0, 0))):
                p.quad((xa, 0, za), (xb, 0, zb), (xb, t, zb), (xa, t, za), n)
        prims = [p]
    elif kind == 'column':
        _, r, h, seg = key
        p = Prim('Column concrete')
        cylinder(p, r, 0.0, h, seg)
        prims = [p]
    elif kind == 'core':
        # four core walls (local origin = outer corner x0,z0 of the core), door in the south (+z) wall
        _, sx, sz, t, h = key
        p = Prim('Concrete')
        parts = []
        n_ = Prim('Concrete'); wall_panel(n_, sx, h, t, []); parts.append(n_.transformed(0, (0, 0, 0)))
        s_ = Prim('Concrete'); wall_panel(s_, sx, h, t, [(sx - 1.0, DOOR[0] + 0.02, 0.0, DOOR[1] + 0.01)])
        parts.append(s_.transformed(2, (sx, 0, sz)))
        w_ = Prim('Concrete'); wall_panel(w_, sz - 2 * t, h, t, []); parts.append(w_.transformed(1, (0, 0, sz - t)))
        e_ = Prim('Concrete'); wall_panel(e_, sz - 2 * t, h, t, []); parts.append(e_.transformed(3, (sx, 0, t)))
        for q in parts:
            base = len(p.pos)
            p.pos += q.pos; p.nrm += q.nrm; p.idx += [i + base for i in q.idx]
        prims = [p]
    elif kind == 'stair':
        # dog-leg stair inside the core (local origin = inner corner of the core); 20 risers of h/20
        _, ix, iz, h = key
        p = Prim('Stair concrete')
        r, g = h / 20, 0.25
        mid = ix / 2
        z_top = iz - 1.15                       # flights run between z_land and z_top
        z_land = z_top - 9 * g
        p.box(0, ix, -0.2, 0.0, z_top, iz)                           # floor landing at this level (south)
        for i in range(9):                                           # flight 1 (west half), ascending to -z
            top = (i + 1) * r
            p.box(0, mid - 0.05, top - r - 0.15, top, z_top - (i + 1) * g, z_top - i * g)
        p.box(0, ix, 10 * r - 0.2, 10 * r, 0.0, z_land)              # half landing (north)
        for j in range(9):                                           # flight 2 (east half), ascending to +z
            top = (11 + j) * r
            p.box(mid + 0.05, ix, top - r - 0.15, top, z_land + j * g, z_land + (j + 1) * g)
        prims = [p]
    elif kind == 'desk':
        top = Prim('Desk top')
        top.box(-0.8, 0.8, 0.72, 0.75, -0.4, 0.4)
        legs = Prim('Desk frame')
        for x in (-0.75, 0.71):
            legs.box(x, x + 0.04, 0.0, 0.72, -0.36, 0.36)      # two side frames
        legs.box(-0.71, 0.71, 0.55, 0.62, 0.30, 0.33)            # modesty panel (back side only)
        prims = [top, legs]
    elif kind == 'light':
        p = Prim('Light fixture')
        p.box(-0.6, 0.6, -0.05, 0.0, -0.15, 0.15)
        prims = [p]
    else:
        raise ValueError(key)
    _PROTO[key] = prims
    return prims


# --------------------------------------------------------------------------------------------------------------
# The building
# --------------------------------------------------------------------------------------------------------------
IFC_CHARS = '0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_$'


def ifc_guid(seed):
    n = int.from_bytes(hashlib.md5(seed.encode()).digest(), 'big')
    out = [IFC_CHARS[(n >> 126) & 0x3]]
    for i in range(21):
        out.append(IFC_CHARS[(n >> (120 - 6 * i)) & 0x3F])
    return ''.join(out)


STOREYS = [f'Level {i}' for i in range(N_STOREYS)] + ['Roof']
ELEMENTS = []      # baked components, in node order
INSTANCES = []     # glTF-level instances
_counters = {}


def _next_name(prefix):
    _counters[prefix] = _counters.get(prefix, 0) + 1
    return f'{prefix}-{_counters[prefix]:02d}'


def element(ifc_class, prefix, storey, key, k=0, t=(0, 0, 0), uv=None, name=None):
    name = name or _next_name(prefix)
    e = {'ifc_class': ifc_class, 'name': name, 'storey': storey, 'key': key, 'k': k, 't': t,
         'guid': ifc_guid('bimtiles-sample/' + name), 'uv': uv, 'duplicate_of': None}
    ELEMENTS.append(e)
    return e


def opening_list(centres, size, sill):
    w, h = size[0], size[1]
    return tuple((c, w + 0.02, sill, sill + h + 0.01) for c in centres)


def build():
    win_a_w, win_a_h, win_a_sill = WIN_A
    win_b_w, win_b_h, win_b_sill = WIN_B
    bay_centres = [1.5 + 3 * j for j in range(10)]
    cx0, cx1, cz0, cz1 = CORE
    core_hole = (cx0, cx1, cz0, cz1)

    for li in range(N_STOREYS):
        st = STOREYS[li]
        y = li * STOREY_H
        # slab of this level (top at y)
        hole = None if li == 0 else core_hole
        element('IfcSlab', 'Slab', st, ('slab', 'Concrete', LEN_X, LEN_Z, SLAB_T, hole), t=(0, y - SLAB_T, 0))

        # exterior walls: back (z = 0, outer normal -z), front (z = 15, +z), east (x = 30), west (x = 0)
        back_open = opening_list(bay_centres, WIN_A, win_a_sill)
        element('IfcWall', 'Exterior wall', st, ('wall', 'Render white', LEN_X, CLEAR_H, EXT_T, back_open), 0, (0, y, 0))
        if li == 0:   # front wall with the entrance between bays 4 and 5 (x = 15)
            fr_centres = [c for c in bay_centres if abs(c - 15) > 2]
            fr_open = tuple(sorted(opening_list(fr_centres, WIN_A, win_a_sill)
                                   + ((LEN_X - 15.0, ENTRANCE[0] + 0.02, 0.0, ENTRANCE[1] + 0.01),)))
        else:
            fr_centres = bay_centres
            fr_open = back_open
        element('IfcWall', 'Exterior wall', st, ('wall', 'Render white', LEN_X, CLEAR_H, EXT_T, fr_open), 2, (LEN_X, y, LEN_Z))
        end_len = LEN_Z - 2 * EXT_T
        east_centres = [end_len / 2 - 2.5, end_len / 2 + 2.5]
        element('IfcWall', 'Exterior wall', st,
                ('wall', 'Render white', end_len, CLEAR_H, EXT_T, opening_list(east_centres, WIN_B, win_b_sill)),
                3, (LEN_X, y, EXT_T))
        element('IfcWall', 'Exterior wall', st, ('wall', 'Render white', end_len, CLEAR_H, EXT_T, ()),
                1, (0, y, LEN_Z - EXT_T))

        # windows (separate meshes, baked; rotation follows the facade)
        zc = EXT_T / 2
        for c in bay_centres:                             # back facade, rotation 0
            element('IfcWindow', 'Window', st, ('window', win_a_w, win_a_h), 0, (c, y + win_a_sill, zc))
        for c in fr_centres:                              # front facade, rotation 180
            element('IfcWindow', 'Window', st, ('window', win_a_w, win_a_h), 2, (LEN_X - c, y + win_a_sill, LEN_Z - zc))
        for c in east_centres:                            # east facade, rotation 270 (local -z -> +x)
            element('IfcWindow', 'Window', st, ('window', win_b_w, win_b_h), 3, (LEN_X - zc, y + win_b_sill, EXT_T + c))
        if li == 0:
            element('IfcDoor', 'Entrance door', st, ('entrance', ENTRANCE[0], ENTRANCE[1], EXT_T - 0.1), 2,
                    (15.0, y, LEN_Z - zc))

        # columns (translation copies)
        for cz in (4.5, 10.5):
            for cx in (6.0, 12.0, 18.0, 24.0):
                element('IfcColumn', 'Column', st, ('column', 0.2, CLEAR_H, 12), 0, (cx, y, cz))

        # core + stair + core door
        element('IfcWall', 'Core wall', st, ('core', cx1 - cx0, cz1 - cz0, CORE_T, STOREY_H), 0, (cx0, y, cz0))
        element('IfcStair', 'Stair', st, ('stair', cx1 - cx0 - 2 * CORE_T, cz1 - cz0 - 2 * CORE_T, STOREY_H), 0,
                (cx0 + CORE_T, y, cz0 + CORE_T))
        element('IfcDoor', 'Door', st, ('door', DOOR[0], DOOR[1], CORE_T), 2, (cx1 - 1.0, y, cz1 - CORE_T / 2))

        # partitions: corridor walls (z = 7) west and east (rigid copies, 180 deg), cross walls with doors
        corr_len = cx0 - EXT_T
        corr_doors = (2.1, 8.2)
        zc7 = 7.0
        element('IfcWall', 'Partition', st, ('wall', 'Plaster', corr_len, CLEAR_H, INT_T,
                                              opening_list(corr_doors, DOOR, 0.0)), 0, (EXT_T, y, zc7 - INT_T / 2))
        element('IfcWall', 'Partition', st, ('wall', 'Plaster', corr_len, CLEAR_H, INT_T,
                                              opening_list(corr_doors, DOOR, 0.0)), 2, (LEN_X - EXT_T, y, zc7 + INT_T / 2))
        for d in corr_doors:
            element('IfcDoor', 'Door', st, ('door', DOOR[0], DOOR[1], INT_T), 0, (EXT_T + d, y, zc7))
            element('IfcDoor', 'Door', st, ('door', DOOR[0], DOOR[1], INT_T), 2, (LEN_X - EXT_T - d, y, zc7))
        cross_len = zc7 - INT_T / 2 - EXT_T
        cross_door = (cross_len / 2,)
        # west cross wall at x = 4.5 (rotation 90: u runs to -z), east cross wall at x = 25.5 (rotation 270)
        element('IfcWall', 'Partition', st, ('wall', 'Plaster', cross_len, CLEAR_H, INT_T,
                                              opening_list(cross_door, DOOR, 0.0)), 1, (4.5 - INT_T / 2, y, EXT_T + cross_len))
        element('IfcWall', 'Partition', st, ('wall', 'Plaster', cross_len, CLEAR_H, INT_T,
                                              opening_list(cross_door, DOOR, 0.0)), 3, (25.5 + INT_T / 2, y, EXT_T))
        element('IfcDoor', 'Door', st, ('door', DOOR[0], DOOR[1], INT_T), 1, (4.5, y, EXT_T + cross_len / 2))
        element('IfcDoor', 'Door', st, ('door', DOOR[0], DOOR[1], INT_T), 3, (25.5, y, EXT_T + cross_len / 2))

        # glTF-level instances: desks (translation + rotation) and light fixtures (matrix)
        for row, dz in enumerate((9.6, 12.6)):
            for dx in (2.5, 6.5, 22.5, 26.5):
                INSTANCES.append({'mesh': 'desk', 'ifc_class': 'IfcFurniture', 'prefix': 'Desk', 'storey': st,
                                  'k': 2 * row, 't': (dx, y, dz), 'use_matrix': False})
        for lz in (3.5, 11.0):
            for n_, lx in enumerate((3.0, 9.0, 21.0, 27.0)):
                INSTANCES.append({'mesh': 'light', 'ifc_class': 'IfcLightFixture', 'prefix': 'Light', 'storey': st,
                                  'k': 1 if (n_ % 2 and lz < 5) else 0, 't': (lx, y + CLEAR_H - 0.05, lz),
                                  'use_matrix': True})

    # roof storey
    st = 'Roof'
    element('IfcSlab', 'Slab', st, ('slab', 'Roof membrane', LEN_X, LEN_Z, SLAB_T, core_hole), t=(0, ROOF_Y - SLAB_T, 0))
    pt, ph = 0.2, 1.0
    element('IfcWall', 'Parapet', st, ('box', 'Render white', LEN_X, ph, pt), 0, (0, ROOF_Y, 0))
    element('IfcWall', 'Parapet', st, ('box', 'Render white', LEN_X, ph, pt), 2, (LEN_X, ROOF_Y, LEN_Z))
    element('IfcWall', 'Parapet', st, ('box', 'Render white', LEN_Z - 2 * pt, ph, pt), 1, (0, ROOF_Y, LEN_Z - pt))
    element('IfcWall', 'Parapet', st, ('box', 'Render white', LEN_Z - 2 * pt, ph, pt), 3, (LEN_X, ROOF_Y, pt))
    element('IfcWall', 'Core wall', st, ('core', cx1 - cx0, cz1 - cz0, CORE_T, STOREY_H - SLAB_T + SLAB_T), 0,
            (cx0, ROOF_Y, cz0))
    element('IfcDoor', 'Door', st, ('door', DOOR[0], DOOR[1], CORE_T), 2, (cx1 - 1.0, ROOF_Y, cz1 - CORE_T / 2))
    ix, iz = cx1 - cx0 - 2 * CORE_T, cz1 - cz0 - 2 * CORE_T
    element('IfcSlab', 'Landing', st, ('box', 'Stair concrete', ix, 0.2, 1.15), 0,
            (cx0 + CORE_T, ROOF_Y - 0.2, cz0 + CORE_T + iz - 1.15))
    element('IfcRoof', 'Penthouse roof', st, ('box', 'Roof membrane', cx1 - cx0 + 0.4, SLAB_T, cz1 - cz0 + 0.4), 0,
            (cx0 - 0.2, ROOF_Y + STOREY_H, cz0 - 0.2))

    # textured elements (Level 0): stone cladding on the west facade ("photo" texture, ~60 % of it used),
    # two planters in front of the entrance (same image through a second, darker material), lobby floor tiles
    st = STOREYS[0]
    clad_t = 0.06
    clad_h = ROOF_Y + ph + SLAB_T
    element('IfcCovering', 'Cladding', st, ('box', 'Stone cladding', LEN_Z, clad_h, clad_t), 1,
            (-clad_t, -SLAB_T, LEN_Z), uv='photo', name='Cladding West')
    for px in (9.0, 17.0):
        element('IfcBuildingElementProxy', 'Planter', st, ('box', 'Stone cladding dark', 4.0, 0.6, 0.4), 0,
                (px, 0.0, LEN_Z + 1.0), uv='photo')
    element('IfcCovering', 'Floor finish', st, ('box', 'Floor tiles', 10.0, 0.02, LEN_Z - EXT_T - 7.06), 0,
            (10.0, 0.0, 7.06), uv='tiles', name='Lobby floor')

    # redundant exact duplicates (same geometry, same place, other GlobalId), as found in real exports
    for victim in ('Column-03', 'Window-05'):
        src = next(e for e in ELEMENTS if e['name'] == victim)
        dup = dict(src)
        dup['guid'] = ifc_guid('bimtiles-sample/duplicate-of/' + victim)
        dup['duplicate_of'] = src['guid']
        ELEMENTS.append(dup)


def uv_for(kind, shape_dims):
    """UV functions in the shape's local frame (so rigid copies keep identical UVs)."""
    if kind == 'photo':
        sx, sy, sz = shape_dims
        span = PHOTO_U1 - PHOTO_U0

        def f(p, n):
            ax = max(range(3), key=lambda i: abs(n[i]))
            if ax == 2:      # large faces: x across, y up
                u, v = p[0] / sx, p[1] / sy
            elif ax == 0:    # ends: z across
                u, v = p[2] / sz, p[1] / sy
            else:            # top / bottom: x across, z
                u, v = p[0] / sx, p[2] / sz
            return (PHOTO_U0 + span * u, PHOTO_U1 - span * v)
        return f
    if kind == 'tiles':
        def f(p, n):
            return (p[0] / TILE_M, p[2] / TILE_M)
        return f
    raise ValueError(kind)


# --------------------------------------------------------------------------------------------------------------
# glTF writing
# --------------------------------------------------------------------------------------------------------------
class GltfWriter:
    def __init__(self):
        self.bin = bytearray()
        self.buffer_views = []
        self.accessors = []
        self.meshes = []

    def _view(self, data, target=None, stride=None):
        while len(self.bin) % 4:
            self.bin.append(0)
        v = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if stride:
            v["byteStride"] = stride
        if target:
            v["target"] = target
        self.bin += data
        self.buffer_views.append(v)
        return len(self.buffer_views) - 1

    def add_prim(self, prim, with_uv):
        n = len(prim.pos)
        stride = 32 if with_uv else 24
        data = bytearray()
        pos32 = [tuple(f32(c) for c in p) for p in prim.pos]
        for i in range(n):
            data += struct.pack('<3f', *prim.pos[i]) + struct.pack('<3f', *prim.nrm[i])
            if with_uv:
                data += struct.pack('<2f', *prim.uv[i])
        view = self._view(bytes(data), 34962, stride)
        acc = {}
        lo = [min(p[i] for p in pos32) for i in range(3)]
        hi = [max(p[i] for p in pos32) for i in range(3)]
        self.accessors.append({"bufferView": view, "byteOffset": 0, "componentType": 5126, "count": n,
                               "type": "VEC3", "min": lo, "max": hi})
        acc["POSITION"] = len(self.accessors) - 1
        self.accessors.append({"bufferView": view, "byteOffset": 12, "componentType": 5126, "count": n,
                               "type": "VEC3"})
        acc["NORMAL"] = len(self.accessors) - 1
        if with_uv:
            self.accessors.append({"bufferView": view, "byteOffset": 24, "componentType": 5126, "count": n,
                                   "type": "VEC2"})
            acc["TEXCOORD_0"] = len(self.accessors) - 1
        assert n < 65536
        iv = self._view(struct.pack(f'<{len(prim.idx)}H', *prim.idx), 34963)
        self.accessors.append({"bufferView": iv, "byteOffset": 0, "componentType": 5123, "count": len(prim.idx),
                               "type": "SCALAR"})
        return {"attributes": acc, "indices": len(self.accessors) - 1, "material": MAT_INDEX[prim.material]}

    def add_mesh(self, name, prims):
        self.meshes.append({"name": name, "primitives": [self.add_prim(p, bool(p.uv)) for p in prims]})
        return len(self.meshes) - 1

    def add_image(self, png):
        return self._view(png)


def quat_y(k):
    a = (k % 4) * math.pi / 4          # half angle
    s = [0.0, math.sqrt(0.5), 1.0, math.sqrt(0.5)][k % 4]
    c = [1.0, math.sqrt(0.5), 0.0, -math.sqrt(0.5)][k % 4]
    assert abs(s - math.sin(a)) < 1e-12 and abs(c - math.cos(a)) < 1e-12
    return [0.0, s, 0.0, c]


def matrix_y(k, t):
    c, s = ROT_CS[k % 4]
    # column-major; rotation about +Y: columns (c,0,-s), (0,1,0), (s,0,c)
    return [c, 0, -s, 0, 0, 1, 0, 0, s, 0, c, 0, t[0], t[1], t[2], 1]


def shape_signature(prims):
    """Rigid-motion-invariant fingerprint of baked geometry (float32 positions): per primitive material and
    counts, sorted distances to the centroid, sorted triangle areas. Used to verify the shape-key grouping."""
    pts = [tuple(f32(c) for c in p) for q in prims for p in q.pos]
    cx = sum(p[0] for p in pts) / len(pts)
    cy = sum(p[1] for p in pts) / len(pts)
    cz = sum(p[2] for p in pts) / len(pts)
    dists = sorted(math.sqrt((p[0] - cx) ** 2 + (p[1] - cy) ** 2 + (p[2] - cz) ** 2) for p in pts)
    areas = []
    for q in prims:
        P = [tuple(f32(c) for c in p) for p in q.pos]
        for i in range(0, len(q.idx), 3):
            a, b, c = P[q.idx[i]], P[q.idx[i + 1]], P[q.idx[i + 2]]
            x = cross(sub(b, a), sub(c, a))
            areas.append(0.5 * math.sqrt(dot(x, x)))
    head = tuple((q.material, len(q.pos), len(q.idx)) for q in prims)
    return (head, dists, sorted(areas))


def same_shape(a, b, tol=1e-3):
    """Signatures equal up to `tol` (float32 rounding of world coordinates differs between copies)."""
    return a[0] == b[0] and all(abs(x - y) <= tol for x, y in zip(a[1], b[1])) \
        and all(abs(x - y) <= tol for x, y in zip(a[2], b[2]))


def key_str(key):
    def fmt(x):
        if isinstance(x, float):
            return f'{x:g}'
        if isinstance(x, tuple):
            return '[' + ','.join(fmt(y) for y in x) + ']'
        return str(x)
    return fmt(key)


def main():
    out_dir = sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.abspath(__file__))
    os.makedirs(out_dir, exist_ok=True)
    build()
    w = GltfWriter()
    nodes = []
    storey_children = {s: [] for s in STOREYS}
    total_tris = 0
    total_verts = 0
    baked = []          # (element, baked prims)

    for e in ELEMENTS:
        key = e['key']
        prims = [p.transformed(0, (0, 0, 0)) for p in proto(key)]
        if e['uv']:
            dims = key[2:5]
            for p in prims:
                p.finish_uvs(uv_for(e['uv'], dims))
        prims = [p.transformed(e['k'], e['t']) for p in prims]
        baked.append((e, prims))
        mi = w.add_mesh(e['name'], prims)
        extras = {"ifc_class": e['ifc_class'], "name": e['name'], "storey": e['storey'], "guid": e['guid']}
        nodes.append({"name": e['guid'], "mesh": mi, "extras": extras})
        storey_children[e['storey']].append(len(nodes) - 1)
        total_tris += sum(len(p.idx) // 3 for p in prims)
        total_verts += sum(len(p.pos) for p in prims)

    inst_mesh = {}
    for kind, name in (('desk', 'Desk'), ('light', 'Light fixture')):
        prims = proto((kind,))
        inst_mesh[kind] = (w.add_mesh(name, prims), sum(len(p.idx) // 3 for p in prims), sum(len(p.pos) for p in prims))
    for inst in INSTANCES:
        name = _next_name(inst['prefix'])
        guid = ifc_guid('bimtiles-sample/' + name)
        node = {"name": guid, "mesh": inst_mesh[inst['mesh']][0]}
        if inst['use_matrix']:
            node["matrix"] = matrix_y(inst['k'], [round(c, 6) for c in inst['t']])
        else:
            node["translation"] = [round(c, 6) for c in inst['t']]
            if inst['k']:
                node["rotation"] = quat_y(inst['k'])
        node["extras"] = {"ifc_class": inst['ifc_class'], "name": name, "storey": inst['storey'], "guid": guid}
        inst['name'], inst['guid'] = name, guid
        nodes.append(node)
        storey_children[inst['storey']].append(len(nodes) - 1)
        total_tris += inst_mesh[inst['mesh']][1]
        total_verts += inst_mesh[inst['mesh']][2]

    storey_nodes = []
    for i, s in enumerate(STOREYS):
        elev = i * STOREY_H if s != 'Roof' else ROOF_Y
        nodes.append({"name": ifc_guid('bimtiles-sample/storey/' + s), "children": storey_children[s],
                      "extras": {"ifc_class": "IfcBuildingStorey", "name": s, "storey": s, "elevation": elev,
                                 "guid": ifc_guid('bimtiles-sample/storey/' + s)}})
        storey_nodes.append(len(nodes) - 1)
    bguid = ifc_guid('bimtiles-sample/building')
    nodes.append({"name": bguid, "children": storey_nodes,
                  "extras": {"ifc_class": "IfcBuilding", "name": "Sample office building", "storey": None,
                             "guid": bguid}})
    building = len(nodes) - 1

    img0 = w.add_image(photo_texture())
    img1 = w.add_image(tile_texture())
    gltf = {
        "asset": {"version": "2.0", "generator": "bimtiles samples/make_sample.py",
                  "copyright": "Synthetic sample building, public domain (CC0)"},
        "scene": 0,
        "scenes": [{"name": "Sample office building", "nodes": [building]}],
        "nodes": nodes,
        "meshes": w.meshes,
        "materials": list(MATERIALS.values()),
        "textures": [{"name": "Facade photo", "sampler": 0, "source": 0},
                     {"name": "Floor tiles", "sampler": 1, "source": 1}],
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071},
                     {"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}],
        "images": [{"name": "facade_photo.png", "bufferView": img0, "mimeType": "image/png"},
                   {"name": "floor_tiles.png", "bufferView": img1, "mimeType": "image/png"}],
        "accessors": w.accessors,
        "bufferViews": w.buffer_views,
        "buffers": [{"byteLength": 0}],
    }
    while len(w.bin) % 4:
        w.bin.append(0)
    gltf["buffers"][0]["byteLength"] = len(w.bin)
    js = json.dumps(gltf, separators=(',', ':'), ensure_ascii=True).encode()
    js += b' ' * ((4 - len(js) % 4) % 4)
    glb = (struct.pack('<4sII', b'glTF', 2, 12 + 8 + len(js) + 8 + len(w.bin))
           + struct.pack('<I4s', len(js), b'JSON') + js + struct.pack('<I4s', len(w.bin), b'BIN\x00') + bytes(w.bin))
    glb_path = os.path.join(out_dir, 'sample_building.glb')
    with open(glb_path, 'wb') as fh:
        fh.write(glb)

    # ---------------- expectations, computed from what was written ----------------
    originals = [(e, p) for e, p in baked if e['duplicate_of'] is None]
    dups = [(e, p) for e, p in baked if e['duplicate_of'] is not None]
    # exact duplicates really are byte-identical to their source
    by_guid = {e['guid']: p for e, p in baked}
    for e, p in dups:
        src = by_guid[e['duplicate_of']]
        assert [(q.material, q.pos, q.idx) for q in p] == [(q.material, q.pos, q.idx) for q in src]
    groups = {}
    for e, p in originals:
        groups.setdefault(key_str(e['key']), []).append((e, p))
    # verify: same shape key <=> same rigid-invariant signature
    sig_of_group = {}
    for k, members in groups.items():
        sig = shape_signature(members[0][1])
        for _, p in members[1:]:
            assert same_shape(sig, shape_signature(p)), f'members of {k} differ'
        for k2, sig2 in sig_of_group.items():
            assert not same_shape(sig, sig2), f'{k} is congruent with {k2}'
        sig_of_group[k] = sig
    rigid_groups = []
    for k, members in groups.items():
        if len(members) < 2:
            continue
        rot = {}
        for e, _ in members:
            rot[str(90 * (e['k'] % 4))] = rot.get(str(90 * (e['k'] % 4)), 0) + 1
        rigid_groups.append({"shape": k, "ifc_class": members[0][0]['ifc_class'], "count": len(members),
                             "rotations_deg": dict(sorted(rot.items(), key=lambda kv: int(kv[0]))),
                             "triangles_each": sum(len(q.idx) // 3 for q in members[0][1]),
                             "names": [e['name'] for e, _ in members],
                             "guids": [e['guid'] for e, _ in members]})
    textured = [e for e, _ in baked if e['uv']]
    bb_lo = [min(f32(p[i]) for _, ps in baked for q in ps for p in q.pos) for i in range(3)]
    bb_hi = [max(f32(p[i]) for _, ps in baked for q in ps for p in q.pos) for i in range(3)]
    expect = {
        "file": "sample_building.glb",
        "generator": "samples/make_sample.py",
        "bytes": len(glb),
        "components": len(baked) + len(INSTANCES),
        "baked_components": len(baked),
        "gltf_instances": len(INSTANCES),
        "gltf_instanced_meshes": {"Desk": sum(1 for i in INSTANCES if i['mesh'] == 'desk'),
                                  "Light fixture": sum(1 for i in INSTANCES if i['mesh'] == 'light')},
        "meshes": len(w.meshes),
        "primitives": sum(len(m['primitives']) for m in w.meshes),
        "materials": len(MATERIALS),
        "textures": 2,
        "images": 2,
        "triangles": total_tris,
        "vertices": total_verts,
        "triangles_stored": sum(w.accessors[pr["indices"]]["count"] // 3 for m in w.meshes for pr in m["primitives"]),
        "storeys": STOREYS,
        "exact_duplicates": len(dups),
        "exact_duplicate_pairs": [{"name": e['name'], "kept": e['duplicate_of'], "duplicate": e['guid']}
                                  for e, _ in dups],
        "unique_shapes": len(groups),
        "unique_shapes_incl_instanced": len(groups) + len(inst_mesh),
        "baked_copies": sum(g["count"] - 1 for g in rigid_groups),
        "rigid_copy_groups": rigid_groups,
        "textured_components": len(textured),
        "textured_component_names": [e['name'] for e in textured],
        "photo_texture_used_uv_fraction": round((PHOTO_U1 - PHOTO_U0) ** 2, 4),
        "bbox_min": bb_lo,
        "bbox_max": bb_hi,
        "by_ifc_class": {},
    }
    for e in ELEMENTS:
        expect["by_ifc_class"][e['ifc_class']] = expect["by_ifc_class"].get(e['ifc_class'], 0) + 1
    for i in INSTANCES:
        expect["by_ifc_class"][i['ifc_class']] = expect["by_ifc_class"].get(i['ifc_class'], 0) + 1
    expect["by_ifc_class"] = dict(sorted(expect["by_ifc_class"].items()))
    with open(os.path.join(out_dir, 'sample_building.expect.json'), 'w') as fh:
        json.dump(expect, fh, indent=1)
        fh.write('\n')
    print(f'wrote {glb_path}: {len(glb)} bytes, {expect["components"]} components, {total_tris} triangles, '
          f'{len(groups)} unique shapes, {expect["baked_copies"]} baked copies, {len(dups)} exact duplicates, '
          f'{len(INSTANCES)} glTF instances')


if __name__ == '__main__':
    main()
