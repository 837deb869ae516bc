//! Reads a written tileset back and summarises it per level: tiles, triangles, bytes and geometric
//! error. It reads only what is on disk (tileset.json and the GLB headers), so it also describes
//! tilesets made by other tools.

use crate::error::{Error, Result};
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
}

/// Triangle count of a GLB: sum of index counts (or vertex counts) / 3 over triangle primitives.
pub fn glb_triangle_count(path: &Path) -> Result<u64> {
    let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    let g = gltf::Gltf::from_slice_without_validation(&bytes)
        .map_err(|e| Error::input(path, format!("not a valid GLB: {e}")))?;
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
    let text =
        std::fs::read(&ts_path).map_err(|e| Error::input(&ts_path, format!("cannot read: {e}")))?;
    let ts: Value = serde_json::from_slice(&text)
        .map_err(|e| Error::input(&ts_path, format!("invalid JSON: {e}")))?;
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
            let p = dir.join(uri);
            l.tiles_with_content += 1;
            l.bytes += std::fs::metadata(&p)
                .map_err(|e| Error::input(&p, e.to_string()))?
                .len();
            l.triangles += glb_triangle_count(&p)?;
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
        Ok(())
    }
}
