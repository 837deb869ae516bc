"""Tilesets with EXT_meshopt_compression tiles, decoded for the readers here (which read plain
accessors): each tile's meshopt streams are decoded by meshoptimizer's reference JavaScript
decoder (tools/decode_meshopt.mjs, written from the extension's bitstream description), which
shares no code with the Rust writer. Other tilesets are read as they are."""

import json
import pathlib
import struct
import subprocess
import tempfile

REPO = pathlib.Path(__file__).resolve().parents[2]
_decoded = {}


def uses_meshopt(glb_path):
    """Whether the GLB at `glb_path` declares EXT_meshopt_compression."""
    with open(glb_path, "rb") as f:
        head = f.read(20)
        if len(head) < 20 or head[:4] != b"glTF":
            return False
        (json_len,) = struct.unpack_from("<I", head, 12)
        doc = json.loads(f.read(json_len))
    return "EXT_meshopt_compression" in doc.get("extensionsUsed", [])


def decoded_tileset(directory):
    """`directory`, or a decoded copy of it (once per run) when any of its tiles uses meshopt."""
    d = pathlib.Path(directory)
    if d in _decoded:
        return _decoded[d]
    out = d
    if any(uses_meshopt(p) for p in d.rglob("*.glb")):
        out = pathlib.Path(tempfile.mkdtemp(prefix="bimtiles-meshopt-")) / d.name
        r = subprocess.run(["node", str(REPO / "tools/decode_meshopt.mjs"), str(d), str(out)],
                           capture_output=True, text=True)
        assert r.returncode == 0, f"decode_meshopt {d}: {r.stderr}"
    _decoded[d] = out
    return out
