//! Reads a written tileset back and summarises it per level: tiles, triangles, bytes and geometric
//! error. It reads only what is on disk (tileset.json and the GLB headers), so it also describes
//! tilesets made by other tools; a bimtiles `report.json` beside them adds the levels of detail as
//! the paper's Table I (both error metrics, see [`crate::report::LodLevelReport`]). [`first_view`]
//! measures what a client loads for a whole-model view of it.

pub mod first_view;

use crate::error::{Error, Result};
use crate::uri::confine;
use serde::Serialize;
use serde_json::Value;
use std::path::Path;

#[derive(Debug, Clone, Serialize, Default)]
pub struct LevelSummary {
    pub depth: u32,
    pub tiles: usize,
    pub tiles_with_content: usize,
    pub triangles: u64,
    pub bytes: u64,
    pub geometric_error_min_m: f64,
    pub geometric_error_max_m: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct TilesetSummary {
    pub version: String,
    pub geometric_error_m: f64,
    pub tiles: usize,
    pub triangles: u64,
    pub bytes: u64,
    pub levels: Vec<LevelSummary>,
    /// From `report.json`, when bimtiles wrote one with levels of detail.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub lod_levels: Vec<crate::report::LodLevelReport>,
    /// Where the tileset was placed (`report.json`'s `georeference`), when bimtiles wrote one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub placement: Option<crate::report::GeoReport>,
}

/// The `georeference` of the `report.json` in `dir`, if it has a readable one.
fn read_placement(dir: &Path) -> Option<crate::report::GeoReport> {
    let text = std::fs::read(dir.join("report.json")).ok()?;
    let r: Value = serde_json::from_slice(&text).ok()?;
    serde_json::from_value(r.get("georeference")?.clone()).ok()
}

/// The `lod_levels` table of the `report.json` in `dir`, empty if there is none (other tools,
/// `--lod none`); an unreadable one is an error naming it.
fn read_lod_levels(dir: &Path) -> Result<Vec<crate::report::LodLevelReport>> {
    let path = dir.join("report.json");
    let Ok(text) = std::fs::read(&path) else {
        return Ok(Vec::new());
    };
    let r: Value =
        serde_json::from_slice(&text).map_err(|e| Error::input_from(&path, "invalid JSON", e))?;
    match r.get("lod_levels") {
        None => Ok(Vec::new()),
        Some(l) => serde_json::from_value(l.clone())
            .map_err(|e| Error::input_from(&path, "unreadable lod_levels", e)),
    }
}

/// Triangle count of a GLB: sum of index counts (or vertex counts) / 3 over triangle primitives.
pub fn glb_triangle_count(path: &Path) -> Result<u64> {
    let bytes =
        crate::ingest::read_regular(path).map_err(|e| Error::input_from(path, "cannot read", e))?;
    triangles_in(&bytes, path)
}

/// Triangles of the GLB `bytes` (read from `path`, which errors name).
fn triangles_in(bytes: &[u8], path: &Path) -> Result<u64> {
    let g = gltf::Gltf::from_slice_without_validation(bytes)
        .map_err(|e| Error::input_from(path, "not a valid GLB", e))?;
    let mut tris = 0u64;
    for m in g.document.meshes() {
        for p in m.primitives() {
            if p.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let n = match p.indices() {
                Some(a) => a.count(),
                None => p.get(&gltf::Semantic::Positions).map_or(0, |a| a.count()),
            };
            tris += n as u64 / 3;
        }
    }
    Ok(tris)
}

pub fn inspect(dir: &Path) -> Result<TilesetSummary> {
    let ts_path = dir.join("tileset.json");
    let text = crate::ingest::read_regular(&ts_path)
        .map_err(|e| Error::input_from(&ts_path, "cannot read", e))?;
    inspect_text(dir, &text)
}

/// [`inspect`] of the tileset.json text `text` of the tileset in `dir` (its tiles are read from
/// `dir`).
pub fn inspect_text(dir: &Path, text: &[u8]) -> Result<TilesetSummary> {
    let ts_path = dir.join("tileset.json");
    let ts: Value =
        serde_json::from_slice(text).map_err(|e| Error::input_from(&ts_path, "invalid JSON", e))?;
    let root = ts
        .get("root")
        .ok_or_else(|| Error::input(&ts_path, "no root tile"))?;
    let mut levels: Vec<LevelSummary> = Vec::new();
    let mut stack = vec![(root, 0u32)];
    while let Some((tile, depth)) = stack.pop() {
        let d = depth as usize;
        while levels.len() <= d {
            levels.push(LevelSummary {
                depth: levels.len() as u32,
                geometric_error_min_m: f64::INFINITY,
                ..Default::default()
            });
        }
        let ge = tile
            .get("geometricError")
            .and_then(Value::as_f64)
            .unwrap_or(0.0);
        let l = &mut levels[d];
        l.tiles += 1;
        l.geometric_error_min_m = l.geometric_error_min_m.min(ge);
        l.geometric_error_max_m = l.geometric_error_max_m.max(ge);
        if let Some(uri) = tile.pointer("/content/uri").and_then(Value::as_str) {
            let (bytes, p) = tile_content(dir, uri)?;
            l.tiles_with_content += 1;
            l.bytes += bytes.len() as u64;
            l.triangles += triangles_in(&bytes, &p)?;
        }
        if let Some(children) = tile.get("children").and_then(Value::as_array) {
            for c in children.iter().rev() {
                stack.push((c, depth + 1));
            }
        }
    }
    Ok(TilesetSummary {
        version: ts
            .pointer("/asset/version")
            .and_then(Value::as_str)
            .unwrap_or("?")
            .into(),
        geometric_error_m: ts
            .get("geometricError")
            .and_then(Value::as_f64)
            .unwrap_or(0.0),
        tiles: levels.iter().map(|l| l.tiles).sum(),
        triangles: levels.iter().map(|l| l.triangles).sum(),
        bytes: levels.iter().map(|l| l.bytes).sum(),
        levels,
        lod_levels: read_lod_levels(dir)?,
        placement: read_placement(dir),
    })
}

/// Human-readable bytes.
pub fn human_bytes(b: u64) -> String {
    match b {
        b if b >= 1 << 30 => format!("{:.2} GiB", b as f64 / (1u64 << 30) as f64),
        b if b >= 1 << 20 => format!("{:.2} MiB", b as f64 / (1u64 << 20) as f64),
        b if b >= 1 << 10 => format!("{:.1} KiB", b as f64 / 1024.0),
        b => format!("{b} B"),
    }
}

impl std::fmt::Display for TilesetSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "3D Tiles {}: {} tiles, {} triangles, {} of content, top geometric error {:.3} m",
            self.version,
            self.tiles,
            self.triangles,
            human_bytes(self.bytes),
            self.geometric_error_m
        )?;
        writeln!(
            f,
            "{:>5} {:>7} {:>9} {:>12} {:>11}  geometric error (m)",
            "level", "tiles", "w/content", "triangles", "bytes"
        )?;
        for l in &self.levels {
            writeln!(
                f,
                "{:>5} {:>7} {:>9} {:>12} {:>11}  {:.3} .. {:.3}",
                l.depth,
                l.tiles,
                l.tiles_with_content,
                l.triangles,
                human_bytes(l.bytes),
                l.geometric_error_min_m,
                l.geometric_error_max_m
            )?;
        }
        if let Some(g) = &self.placement {
            writeln!(
                f,
                "placed at {:.7}° E, {:.7}° N, {:.3} m (origin: {}); anchor {:.3}, {:.3}, {:.3}: {}",
                g.origin.longitude_deg,
                g.origin.latitude_deg,
                g.origin.height_m,
                g.origin_source,
                g.anchor_m[0],
                g.anchor_m[1],
                g.anchor_m[2],
                g.anchor_rule
            )?;
            for c in &g.crs {
                writeln!(
                    f,
                    "  {}: {} ({}, from {}) E {:.3} N {:.3} -> {:.7}° E, {:.7}° N; convergence {:.5}°, scale factor {:.7}; PROJ: {} (accuracy {}); height {}",
                    c.file,
                    c.crs,
                    c.crs_name,
                    c.source,
                    c.easting,
                    c.northing,
                    c.longitude_deg,
                    c.latitude_deg,
                    c.convergence_deg,
                    c.scale_factor,
                    c.operation,
                    c.accuracy_m.map_or("unknown".into(), |a| format!("{a} m")),
                    c.height_reference
                )?;
            }
            for w in &g.warnings {
                writeln!(f, "  warning: {w}")?;
            }
        }
        if !self.lod_levels.is_empty() {
            writeln!(
                f,
                "\nlevels of detail (paper Table I; distances and pixels at 1920x1080, 60°, 16 px):"
            )?;
            writeln!(
                f,
                "{:<20} {:>6} {:>10} {:>12} {:>11} {:>10} {:>10} {:>12} {:>10} {:>9}",
                "LOD level",
                "tiles",
                "patches",
                "fold edge m",
                "measured m",
                "paper m",
                "declared m",
                "visible ≥ m",
                "Δ(mesh)px",
                "real px"
            )?;
            for l in &self.lod_levels {
                writeln!(
                    f,
                    "{:<20} {:>6} {:>10} {:>12.3} {:>11.4} {:>10.4} {:>10.4} {:>12.1} {:>10.1} {:>9.1}",
                    l.level,
                    l.tiles,
                    l.patches,
                    l.max_folding_edge_m,
                    l.measured_error_max_m,
                    l.paper_error_max_m,
                    l.geometric_error_max_m,
                    l.range_of_visibility_m,
                    l.delta_mesh_px,
                    l.measured_sse_px
                )?;
            }
        }
        Ok(())
    }
}

/// One element found in a tileset's property tables.
#[derive(Debug, Clone, Serialize)]
pub struct FeatureSummary {
    pub id: String,
    /// Property name (the schema's display name when it has one) → value as text.
    pub properties: std::collections::BTreeMap<String, String>,
    /// Content URIs of the tiles that draw (part of) the element.
    pub tiles: Vec<String>,
}

/// Reads one property value of row `row` as text (STRING, SCALAR FLOAT64 and ENUM, the types
/// bimtiles writes; others are reported as unsupported).
fn property_text(
    def: &Value,
    prop: &Value,
    enums: &Value,
    bin: &[u8],
    views: &[Value],
    row: usize,
) -> Option<String> {
    let view = |i: &Value| -> Option<&[u8]> {
        let v = views.get(i.as_u64()? as usize)?;
        let off = v.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
        bin.get(off..off + v.get("byteLength")?.as_u64()? as usize)
    };
    let values = view(&prop["values"])?;
    let text = match def["type"].as_str()? {
        "STRING" => {
            let offs = view(&prop["stringOffsets"])?;
            let size = type_size(prop["stringOffsetType"].as_str().unwrap_or("UINT32"))?;
            let at = |i: usize| {
                offs.get(i * size..(i + 1) * size)
                    .map(|b| le_uint(b) as usize)
            };
            String::from_utf8_lossy(values.get(at(row)?..at(row + 1)?)?).to_string()
        }
        "SCALAR" if def["componentType"] == "FLOAT64" => {
            let b = values.get(row * 8..row * 8 + 8)?;
            f64::from_le_bytes(b.try_into().ok()?).to_string()
        }
        "ENUM" => {
            let e = &enums[def["enumType"].as_str()?];
            let size = type_size(e["valueType"].as_str().unwrap_or("UINT16"))?;
            let code = le_uint(values.get(row * size..(row + 1) * size)?);
            e["values"]
                .as_array()?
                .iter()
                .find(|v| v["value"].as_u64() == Some(code))?["name"]
                .as_str()?
                .to_string()
        }
        other => format!("({other} not shown)"),
    };
    // noData values mean "no value".
    if def.get("noData").is_some_and(|n| {
        n.as_str() == Some(&text) || n.as_f64().map(|x| x.to_string()) == Some(text.clone())
    }) {
        return None;
    }
    Some(text)
}

/// Size in bytes of an unsigned integer type of the metadata spec (None: not one).
fn type_size(name: &str) -> Option<usize> {
    match name {
        "UINT8" => Some(1),
        "UINT16" => Some(2),
        "UINT32" => Some(4),
        "UINT64" => Some(8),
        _ => None,
    }
}

/// A little-endian unsigned integer of 1 to 8 bytes.
fn le_uint(b: &[u8]) -> u64 {
    b.iter().rev().fold(0, |a, &x| a << 8 | u64::from(x))
}

/// The ids of an `aliases` value: a JSON array of ids, or (tilesets written before ids could
/// hold spaces) a space-separated list.
fn alias_ids(value: &str) -> Box<dyn Iterator<Item = String> + '_> {
    match serde_json::from_str::<Vec<String>>(value) {
        Ok(ids) => Box::new(ids.into_iter()),
        Err(_) => Box::new(value.split_whitespace().map(str::to_string)),
    }
}

/// The bytes of a tile's content `uri` in the tileset at `dir`, and the path errors about them
/// name: the file (inside the tileset, [`inside_tileset`]), or tileset.json for a data URI.
fn tile_content(dir: &Path, uri: &str) -> Result<(Vec<u8>, std::path::PathBuf)> {
    if let Some(decoded) = crate::uri::data::decode(uri) {
        let ts_path = dir.join("tileset.json");
        let bytes = decoded.map_err(|e| Error::input_from(&ts_path, "a tile's content", e))?;
        return Ok((bytes, ts_path));
    }
    let path = inside_tileset(dir, dir, uri)?;
    let bytes = crate::ingest::read_regular(&path)
        .map_err(|e| Error::input_from(&path, "cannot read", e))?;
    Ok((bytes, path))
}

/// The file a URI of the tileset at `dir` names, relative to `base` (a folder of the tileset),
/// refused unless it stays inside the tileset's folder, by its text and through symlinks
/// ([`confine::TILESET`]): a tileset from elsewhere must not make `inspect` read other files.
/// Every refusal reads the same: the tileset's author needs no more.
fn inside_tileset(dir: &Path, base: &Path, uri: &str) -> Result<std::path::PathBuf> {
    confine::reference(dir, base, uri, &confine::TILESET).map_err(|_| {
        Error::input(
            dir.join("tileset.json"),
            format!("URI '{uri}' leads outside the tileset's folder (refused)"),
        )
    })
}

/// Finds the element whose `id` property is `id` in every tile of the tileset at `dir`.
pub fn find_feature(dir: &Path, id: &str) -> Result<Option<FeatureSummary>> {
    let summary_tiles = {
        let ts_path = dir.join("tileset.json");
        let text =
            std::fs::read(&ts_path).map_err(|e| Error::input_from(&ts_path, "cannot read", e))?;
        let ts: Value = serde_json::from_slice(&text)
            .map_err(|e| Error::input_from(&ts_path, "invalid JSON", e))?;
        let mut uris = Vec::new();
        let mut stack = vec![ts["root"].clone()];
        while let Some(t) = stack.pop() {
            if let Some(u) = t.pointer("/content/uri").and_then(Value::as_str) {
                uris.push(u.to_string());
            }
            if let Some(c) = t.get("children").and_then(Value::as_array) {
                stack.extend(c.iter().rev().cloned());
            }
        }
        uris
    };
    let mut found: Option<FeatureSummary> = None;
    let mut schemas: std::collections::HashMap<std::path::PathBuf, Value> = Default::default();
    for uri in summary_tiles {
        let (bytes, path) = tile_content(dir, &uri)?;
        let glb = gltf::binary::Glb::from_slice(&bytes)
            .map_err(|e| Error::input_from(&path, "not a GLB", e))?;
        let doc: Value = serde_json::from_slice(&glb.json)
            .map_err(|e| Error::input_from(&path, "invalid JSON", e))?;
        let Some(ext) = doc.pointer("/extensions/EXT_structural_metadata") else {
            continue;
        };
        let schema = match (
            ext.get("schema"),
            ext.get("schemaUri").and_then(Value::as_str),
        ) {
            (Some(s), _) => s.clone(),
            (None, Some(u)) => {
                let p = inside_tileset(dir, path.parent().unwrap_or(dir), u)?;
                if !schemas.contains_key(&p) {
                    let t =
                        std::fs::read(&p).map_err(|e| Error::input_from(&p, "cannot read", e))?;
                    let v: Value = serde_json::from_slice(&t)
                        .map_err(|e| Error::input_from(&p, "invalid JSON", e))?;
                    schemas.insert(p.clone(), v);
                }
                schemas[&p].clone()
            }
            _ => continue,
        };
        let bin = glb.bin.as_deref().unwrap_or(&[]);
        let views = doc["bufferViews"].as_array().cloned().unwrap_or_default();
        let Some(table) = ext.pointer("/propertyTables/0") else {
            continue;
        };
        let class = &schema["classes"][table["class"].as_str().unwrap_or("")]["properties"];
        let props = table["properties"].as_object().cloned().unwrap_or_default();
        if !props.contains_key("id") {
            continue;
        }
        let count = table["count"].as_u64().unwrap_or(0) as usize;
        let text = |pid: &str, r: usize| {
            props
                .get(pid)
                .and_then(|p| property_text(&class[pid], p, &schema["enums"], bin, &views, r))
        };
        // An exact duplicate that was not drawn is found through the row of the kept element.
        let is_alias =
            |r: usize| text("aliases", r).is_some_and(|a| alias_ids(&a).any(|x| x == id));
        let Some(row) = (0..count).find(|&r| text("id", r).as_deref() == Some(id) || is_alias(r))
        else {
            continue;
        };
        let f = found.get_or_insert_with(|| FeatureSummary {
            id: id.to_string(),
            properties: Default::default(),
            tiles: Vec::new(),
        });
        f.tiles
            .push(crate::uri::data::content_label(&uri).to_string());
        if is_alias(row) {
            if let Some(kept) = text("id", row) {
                f.properties.insert("Alias of".into(), kept);
            }
        }
        for (pid, prop) in &props {
            if let Some(v) = property_text(&class[pid], prop, &schema["enums"], bin, &views, row) {
                let name = class[pid]["name"].as_str().unwrap_or(pid).to_string();
                f.properties.insert(name, v);
            }
        }
    }
    Ok(found)
}

impl std::fmt::Display for FeatureSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "element {}", self.id)?;
        let w = self.properties.keys().map(|k| k.len()).max().unwrap_or(0);
        for (k, v) in &self.properties {
            writeln!(f, "  {k:<w$}  {v}")?;
        }
        writeln!(
            f,
            "drawn by {} tile(s): {}",
            self.tiles.len(),
            self.tiles.join(", ")
        )
    }
}
