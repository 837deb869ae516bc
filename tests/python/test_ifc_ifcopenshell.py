"""Independent cross-check of the bimtiles IFC reader with IfcOpenShell (PyPI `ifcopenshell`).

Shares no code with the Rust crate. The Rust test `tests/ifc_crosscheck.rs` (test
`ifc_matches_ifcopenshell_exports`) writes, when BIMTILES_IFC_DUMP_DIR is set, one JSON per IFC file:
`$BIMTILES_IFC_DUMP_DIR/<name>.json` = {"file", "schema", "elements": [{guid, class, storey, building,
site, name, bbox_min, bbox_max (IFC world frame, z-up, metres), triangles}], "skipped": [...]}.

This test opens the same IFC files with IfcOpenShell, triangulates every product with its geometry
iterator in world coordinates (openings, spaces, annotations, grids, virtual elements excluded, as
bimtiles does), resolves each element's storey by walking IfcRelContainedInSpatialStructure and
IfcRelAggregates upwards (ifcopenshell.util.element.get_container / get_aggregate), and compares:
elements (ours / IfcOpenShell / common), class mismatches, storey mismatches, share of element boxes
within 1 cm, triangles (ours vs theirs). It prints the table and fails on clear disagreement.

Tested with ifcopenshell==0.9.0.post1 (pin: `ifcopenshell==0.9.0.post1` in tests/python/requirements.txt).
IfcOpenShell refuses IFC4X3_RC2 files (KIT-Simple-Road): those are reported and skipped.

Run:
    pip install ifcopenshell==0.9.0.post1 pytest
    mkdir -p /tmp/ifcdump
    BIMTILES_IFC_DUMP_DIR=/tmp/ifcdump cargo test --release --test tests -- ifc_crosscheck::ifc_matches --nocapture
    BIMTILES_IFC_DUMP_DIR=/tmp/ifcdump python3 -m pytest -s tests/python/test_ifc_ifcopenshell.py
"""

import glob
import json
import multiprocessing
import os
import time

import pytest

DUMP_DIR = os.environ.get("BIMTILES_IFC_DUMP_DIR")
if not DUMP_DIR:
    pytest.skip(
        "BIMTILES_IFC_DUMP_DIR is not set: run the Rust test ifc_crosscheck with it first (see the module doc)",
        allow_module_level=True,
    )
ifcopenshell = pytest.importorskip(
    "ifcopenshell", reason="ifcopenshell is not installed (pip install ifcopenshell==0.9.0.post1)"
)
import ifcopenshell.geom  # noqa: E402
import ifcopenshell.util.element  # noqa: E402

from ifc_classes import EXCLUDED  # noqa: E402
TOL_M = 0.01


def data_dir():
    cands = []
    if os.environ.get("BIMTILES_SHARED"):
        cands.append(os.path.join(os.environ["BIMTILES_SHARED"], "data"))
    here = os.path.dirname(os.path.abspath(__file__))
    cands.append(os.path.normpath(os.path.join(here, "..", "..", "..", "shared", "data")))
    cands.append("/work/shared/data")
    for c in cands:
        if os.path.isdir(c):
            return c
    return None


def storey_of(el):
    """Name of the IfcBuildingStorey above `el`, through containment and aggregation."""
    cur = el
    for _ in range(64):
        container = ifcopenshell.util.element.get_container(cur)
        nxt = container if container is not None else ifcopenshell.util.element.get_aggregate(cur)
        if nxt is None:
            return None
        if nxt.is_a("IfcBuildingStorey"):
            return nxt.Name
        cur = nxt
    return None


def ifcopenshell_elements(path):
    f = ifcopenshell.open(path)
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    it = ifcopenshell.geom.iterator(settings, f, max(1, multiprocessing.cpu_count()), exclude=EXCLUDED)
    out = {}
    if not it.initialize():
        return out
    while True:
        shape = it.get()
        verts = shape.geometry.verts
        tris = len(shape.geometry.faces) // 3
        if tris > 0 and len(verts) >= 3:
            xs, ys, zs = verts[0::3], verts[1::3], verts[2::3]
            el = f.by_id(shape.id)
            out[shape.guid] = {
                "class": el.is_a(),
                "storey": storey_of(el),
                "bbox_min": [min(xs), min(ys), min(zs)],
                "bbox_max": [max(xs), max(ys), max(zs)],
                "triangles": tris,
            }
        if not it.next():
            break
    return out


def box_diff(a, b):
    return max(
        max(abs(a["bbox_min"][c] - b["bbox_min"][c]), abs(a["bbox_max"][c] - b["bbox_max"][c])) for c in range(3)
    )


def test_ifc_reader_matches_ifcopenshell():
    dumps = sorted(glob.glob(os.path.join(DUMP_DIR, "*.json")))
    if not dumps:
        pytest.skip(f"no dumps in {DUMP_DIR}: run the Rust test first")
    ddir = data_dir()
    if ddir is None:
        pytest.skip("shared data folder not found (set BIMTILES_SHARED)")
    print(f"\nifcopenshell {ifcopenshell.version}")
    rows = []
    failures = []
    for dump in dumps:
        d = json.load(open(dump))
        name = os.path.splitext(os.path.basename(dump))[0]
        ifc = os.path.join(ddir, name + ".ifc")
        if not os.path.isfile(ifc):
            print(f"{name}: no IFC file beside the dump, skipped")
            continue
        ours = {e["guid"]: e for e in d["elements"]}
        t0 = time.time()
        try:
            theirs = ifcopenshell_elements(ifc)
        except Exception as e:  # IfcOpenShell refuses some schemas (IFC4X3_RC2)
            print(f"{name}: IfcOpenShell cannot read it ({type(e).__name__}: {e}); ours read {len(ours)} elements")
            rows.append((name, len(ours), "–", "–", "–", "–", "–", sum(e["triangles"] for e in ours.values()), "–", "–"))
            continue
        secs = time.time() - t0
        common = sorted(set(ours) & set(theirs))
        class_mm = [g for g in common if ours[g]["class"] != theirs[g]["class"]]
        storey_mm = [g for g in common if ours[g]["storey"] != theirs[g]["storey"]]
        bbox_ok = [g for g in common if box_diff(ours[g], theirs[g]) <= TOL_M]
        only_ours = sorted(set(ours) - set(theirs))
        only_theirs = sorted(set(theirs) - set(ours))
        t_ours = sum(ours[g]["triangles"] for g in common)
        t_theirs = sum(theirs[g]["triangles"] for g in common)
        print(f"\n== {name}: IfcOpenShell {secs:.2f} s")
        print(f"   only ours: {len(only_ours)} {[ours[g]['class'] for g in only_ours[:8]]}")
        print(f"   only IfcOpenShell: {len(only_theirs)} {[theirs[g]['class'] for g in only_theirs[:8]]}")
        for g in class_mm[:10]:
            print(f"   class: {g} ours {ours[g]['class']} / theirs {theirs[g]['class']}")
        for g in storey_mm[:10]:
            print(f"   storey: {g} {ours[g]['class']} ours {ours[g]['storey']!r} / theirs {theirs[g]['storey']!r}")
        worst = sorted(((box_diff(ours[g], theirs[g]), g) for g in common if g not in set(bbox_ok)), reverse=True)
        for dd, g in worst[:8]:
            print(
                f"   box: {g} {ours[g]['class']} off by {dd:.3f} m "
                f"(tris ours {ours[g]['triangles']} / theirs {theirs[g]['triangles']})"
            )
        pct = 100.0 * len(bbox_ok) / len(common) if common else 0.0
        rows.append(
            (name, len(ours), len(theirs), len(common), len(class_mm), len(storey_mm), f"{pct:.1f} %",
             sum(e["triangles"] for e in ours.values()), sum(e["triangles"] for e in theirs.values()),
             f"{t_ours} / {t_theirs}")
        )
        if theirs and len(common) < 0.95 * len(theirs):
            failures.append(f"{name}: only {len(common)}/{len(theirs)} of IfcOpenShell's elements found")
        if class_mm:
            failures.append(f"{name}: {len(class_mm)} class mismatches")
        if storey_mm:
            failures.append(f"{name}: {len(storey_mm)} storey mismatches")
        if common and pct < 90.0:
            failures.append(f"{name}: only {pct:.1f} % of boxes within 1 cm")
        if t_theirs and not (0.5 <= t_ours / t_theirs <= 2.0):
            failures.append(f"{name}: triangle ratio {t_ours / t_theirs:.2f}")
    print("\n| file | elements ours | IfcOpenShell | common | class mism. | storey mism. | bbox ≤1 cm | tris ours (all) | tris IfcOpenShell (all) | tris common ours / theirs |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(str(x) for x in r) + " |")
    assert not failures, "; ".join(failures)
