"""Tile content bytes, whether the tile is a file or inlined in tileset.json as a data URI.

bimtiles puts the root tile's GLB into tileset.json as an RFC 2397 data URI by default (3D Tiles 1.1
allows data URIs as content URIs; ``--no-inline-root`` turns it off) and writes no file for it;
report.json keeps the tile's would-be file name in ``content`` and marks its record
``"inlined_in_tileset": true``. The independent checks here get every content through this module, so
an inlined tile is read, and checked, exactly as a file one. The decoding is Python's own (``base64``
with validation), no code shared with the writer.
"""

import base64
import binascii
import json
import pathlib

GLB_MEDIA_TYPE = "model/gltf-binary"


def is_data_uri(uri):
    return uri.startswith("data:")


def data_uri_media_type(uri):
    """The media type of a data URI (``text/plain`` when it names none, as RFC 2397 says)."""
    head = uri[len("data:"):].split(",", 1)[0]
    return head.split(";", 1)[0] or "text/plain"


def data_uri_bytes(uri, where):
    """The bytes of a base64 data URI; AssertionError (naming `where`) for any other, or for bad base64."""
    head, sep, payload = uri.partition(",")
    assert is_data_uri(uri) and sep, f"{where}: not a data URI: {uri[:60]!r}"
    assert head.endswith(";base64"), f"{where}: data URI is not base64: {head!r}"
    try:
        return base64.b64decode(payload, validate=True)
    except binascii.Error as e:
        raise AssertionError(f"{where}: data URI does not decode as base64: {e}") from None


def data_uri_label(json_path, pointer):
    """How an inlined content is named in messages: ``<folder>/tileset.json#<JSON pointer to the uri>``."""
    return f"{json_path}#{pointer}"


def read_tileset(tileset_dir):
    path = pathlib.Path(tileset_dir) / "tileset.json"
    return json.loads(path.read_text(encoding="utf-8"))


def content_uris(tileset):
    """(JSON pointer, uri) of every content of the tile tree of a parsed tileset.json (``content`` and
    ``contents[]``, 3D Tiles 1.0's ``url`` too), depth first."""
    out = []

    def walk(tile, ptr):
        content = tile.get("content")
        if content is not None:
            key = "uri" if "uri" in content else "url"
            if key in content:
                out.append((f"{ptr}/content/{key}", content[key]))
        for i, c in enumerate(tile.get("contents", [])):
            if "uri" in c:
                out.append((f"{ptr}/contents/{i}/uri", c["uri"]))
        for i, child in enumerate(tile.get("children", [])):
            walk(child, f"{ptr}/children/{i}")

    walk(tileset["root"], "/root")
    return out


def inlined_contents(tileset_dir):
    """(label, bytes) of every data-URI content of the tileset.json in `tileset_dir`."""
    json_path = pathlib.Path(tileset_dir) / "tileset.json"
    out = []
    for ptr, uri in content_uris(read_tileset(tileset_dir)):
        if is_data_uri(uri):
            label = data_uri_label(json_path, ptr)
            out.append((label, data_uri_bytes(uri, label)))
    return out


def content_bytes(tileset_dir, uri):
    """The bytes of the content `uri` of the tileset.json in `tileset_dir`: a data URI decoded, else
    the file it names relative to that folder."""
    if is_data_uri(uri):
        return data_uri_bytes(uri, f"{pathlib.Path(tileset_dir) / 'tileset.json'}: content")
    return (pathlib.Path(tileset_dir) / uri).read_bytes()


ROOT_POINTER = "/root/content/uri"


def record_label(report_dir, record):
    """How the tile of a report.json record is named in messages: its file, or for an inlined one the
    tileset.json pointer with the would-be file name."""
    d = pathlib.Path(report_dir)
    if record.get("inlined_in_tileset"):
        return f"{data_uri_label(d / 'tileset.json', ROOT_POINTER)} ({record['content']})"
    return str(d / record["content"])


def record_base(report_dir, record):
    """The folder the tile's own relative URIs (``schemaUri``, images, buffers) resolve against: the
    tileset folder for an inlined tile (its URIs are tileset.json's), else the tile file's folder."""
    d = pathlib.Path(report_dir)
    return d if record.get("inlined_in_tileset") else (d / record["content"]).parent


def record_bytes(report_dir, record):
    """The bytes of the tile of a report.json record (in `report_dir`, beside tileset.json): for a
    record with ``inlined_in_tileset`` (the root's) the root content data URI of tileset.json,
    else the file ``report_dir / record["content"]``."""
    d = pathlib.Path(report_dir)
    if not record.get("inlined_in_tileset"):
        return (d / record["content"]).read_bytes()
    label = record_label(d, record)
    content = read_tileset(d)["root"].get("content", {})
    uri = content.get("uri")
    assert uri is not None, f"{label}: report.json says the tile is inlined but the root has no content uri"
    assert is_data_uri(uri), f"{label}: report.json says the tile is inlined but the root content is {uri!r}"
    assert data_uri_media_type(uri) == GLB_MEDIA_TYPE, f"{label}: media type {data_uri_media_type(uri)!r}"
    assert not (d / record["content"]).exists(), f"{label}: inlined, yet {record['content']} was written too"
    return data_uri_bytes(uri, label)
