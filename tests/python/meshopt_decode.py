"""Tilesets with EXT_meshopt_compression tiles, decoded for the readers here (which read plain
accessors): each tile's meshopt streams are decoded by meshoptimizer's reference JavaScript
decoder (tools/decode_meshopt.mjs, written from the extension's bitstream description), which
shares no code with the Rust writer; it decodes the tiles inlined in tileset.json as data URIs too.
Other tilesets are read as they are."""

import json
import pathlib
import struct
import subprocess
import tempfile

from tile_content import inlined_contents

REPO = pathlib.Path(__file__).resolve().parents[2]
_decoded = {}


def uses_meshopt(glb):
    """Whether the GLB (a path, or its bytes) declares EXT_meshopt_compression."""
    if isinstance(glb, (bytes, bytearray)):
        data = glb
    else:
        with open(glb, "rb") as f:
            data = f.read(20)
            if len(data) == 20:
                data += f.read(struct.unpack_from("<I", data, 12)[0])
    if len(data) < 20 or data[:4] != b"glTF":
        return False
    (json_len,) = struct.unpack_from("<I", data, 12)
    doc = json.loads(data[20:20 + json_len])
    return "EXT_meshopt_compression" in doc.get("extensionsUsed", [])


def decoded_tileset(directory):
    """`directory`, or a decoded copy of it (once per run) when any of its tiles uses meshopt."""
    d = pathlib.Path(directory)
    if d in _decoded:
        return _decoded[d]
    out = d
    if any(uses_meshopt(p) for p in d.rglob("*.glb")) or any(
        uses_meshopt(data) for t in d.rglob("tileset.json") for _, data in inlined_contents(t.parent)
    ):
        out = pathlib.Path(tempfile.mkdtemp(prefix="bimtiles-meshopt-")) / d.name
        r = subprocess.run(["node", str(REPO / "tools/decode_meshopt.mjs"), str(d), str(out)],
                           capture_output=True, text=True)
        assert r.returncode == 0, f"decode_meshopt {d}: {r.stderr}"
    _decoded[d] = out
    return out
