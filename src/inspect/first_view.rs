//! What a 3D Tiles client loads for a first view of a written tileset, read back from disk: the
//! measurement behind the paper's loading claims (III.C(3), III.F, Table V). Tiles are selected as
//! CesiumJS does, by screen-space error
//! `sse = geometricError * screenHeight / (2 * distance * tan(fovY / 2))`
//! ([`crate::tileset::view::sse_px`]), refining while it is above the limit (16 px by default);
//! the selected tiles' GLB bytes, image bytes, drawn triangles and levels are summed
//! ([`first_view`]). The camera looks at the root's bounding box from a distance at which its
//! bounding sphere fills the vertical field of view, from the south-east and above. No frustum
//! culling: the whole model is in view. [`full_view`] is the same selection refined to the end
//! (every tile with `geometricError` > 0 refines): the full model.

use crate::glb_container::{json_chunk, GlbError};
use crate::tileset::view::{sse_px, ViewOptions};
use glam::DVec3;
use serde::Serialize;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// What the tiles of one view cost a client.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FirstView {
    /// Tiles selected (with content).
    pub tiles: usize,
    /// Their GLB bytes.
    pub glb_bytes: u64,
    /// Image bytes embedded in them.
    pub texture_bytes: u64,
    pub images: usize,
    /// Triangles the selected tiles draw (an instanced mesh once per instance).
    pub triangles: u64,
    /// Distinct tree depths (root = 0) among the selected tiles, and the deepest.
    pub levels: usize,
    pub max_depth: u32,
    /// Content URIs of the selected tiles, in selection order (relative to tileset.json).
    #[serde(skip)]
    pub selected: Vec<String>,
}

/// An oriented box: centre and three half-axis vectors (the 3D Tiles `box`).
struct Obb {
    center: DVec3,
    axes: [DVec3; 3],
}

impl Obb {
    fn from_json(b: &Value) -> Option<Obb> {
        let v: Vec<f64> = b.as_array()?.iter().filter_map(Value::as_f64).collect();
        (v.len() == 12).then(|| Obb {
            center: DVec3::new(v[0], v[1], v[2]),
            axes: [
                DVec3::new(v[3], v[4], v[5]),
                DVec3::new(v[6], v[7], v[8]),
                DVec3::new(v[9], v[10], v[11]),
            ],
        })
    }

    fn distance(&self, p: DVec3) -> f64 {
        let d = p - self.center;
        let mut sq = 0.0;
        for a in &self.axes {
            let len = a.length();
            if len == 0.0 {
                continue;
            }
            let t = d.dot(*a / len);
            let out = (t.abs() - len).max(0.0);
            sq += out * out;
        }
        sq.sqrt()
    }

    fn radius(&self) -> f64 {
        (self.axes[0] + self.axes[1] + self.axes[2])
            .length()
            .max((self.axes[0] - self.axes[1] + self.axes[2]).length())
            .max((self.axes[0] + self.axes[1] - self.axes[2]).length())
            .max((self.axes[0] - self.axes[1] - self.axes[2]).length())
    }
}

/// Why a written tileset could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    #[error("{path}: cannot read")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a readable GLB")]
    Glb { path: PathBuf, source: GlbError },
    #[error("{path}: invalid JSON")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{path}: the root tile has no bounding box")]
    NoRootBox { path: PathBuf },
    #[error("{path}: a tile's content data URI")]
    DataUri {
        path: PathBuf,
        source: crate::uri::UriError,
    },
}

/// The bytes of `path`.
fn read(path: &Path) -> Result<Vec<u8>, ViewError> {
    std::fs::read(path).map_err(|source| ViewError::Read {
        path: path.to_path_buf(),
        source,
    })
}

/// The JSON chunk of the GLB at `path` (`glb`: its bytes).
fn glb_json_of(path: &Path, glb: &[u8]) -> Result<Value, ViewError> {
    json_chunk(glb).map_err(|source| ViewError::Glb {
        path: path.to_path_buf(),
        source,
    })
}

/// Image bytes embedded in a GLB, and how many images.
pub fn glb_image_bytes(glb: &[u8]) -> Result<(u64, usize), GlbError> {
    let json = json_chunk(glb)?;
    let views = json["bufferViews"].as_array().cloned().unwrap_or_default();
    let images = json["images"].as_array().cloned().unwrap_or_default();
    let bytes = images
        .iter()
        .filter_map(|i| i["bufferView"].as_u64())
        .filter_map(|v| views.get(v as usize)?["byteLength"].as_u64())
        .sum();
    Ok((bytes, images.len()))
}

/// Triangles a GLB draws: index (or vertex) count / 3 of each triangle primitive of each node's
/// mesh, times the node's instance count (`EXT_mesh_gpu_instancing`).
pub fn glb_drawn_triangles(glb: &[u8]) -> Result<u64, GlbError> {
    let json = json_chunk(glb)?;
    let accessors = json["accessors"].as_array().cloned().unwrap_or_default();
    let count = |a: &Value| {
        a.as_u64()
            .and_then(|i| accessors.get(i as usize)?["count"].as_u64())
            .unwrap_or(0)
    };
    let meshes = json["meshes"].as_array().cloned().unwrap_or_default();
    let mesh_tris: Vec<u64> = meshes
        .iter()
        .map(|m| {
            m["primitives"]
                .as_array()
                .into_iter()
                .flatten()
                .filter(|p| p["mode"].as_u64().unwrap_or(4) == 4)
                .map(|p| {
                    if p["indices"].is_null() {
                        count(&p["attributes"]["POSITION"]) / 3
                    } else {
                        count(&p["indices"]) / 3
                    }
                })
                .sum()
        })
        .collect();
    let mut tris = 0;
    for node in json["nodes"].as_array().into_iter().flatten() {
        let Some(m) = node["mesh"].as_u64() else {
            continue;
        };
        let inst = &node["extensions"]["EXT_mesh_gpu_instancing"]["attributes"];
        let copies = inst
            .as_object()
            .and_then(|a| a.values().next())
            .map_or(1, count);
        tris += mesh_tris.get(m as usize).copied().unwrap_or(0) * copies;
    }
    Ok(tris)
}

/// Selects the tiles of the tileset in `dir` for a whole-model view and sums their bytes.
pub fn first_view(dir: &Path, v: &ViewOptions) -> Result<FirstView, ViewError> {
    let ts_path = dir.join("tileset.json");
    let ts: Value = serde_json::from_slice(&read(&ts_path)?).map_err(|source| ViewError::Json {
        path: ts_path.clone(),
        source,
    })?;
    let root = &ts["root"];
    let rb = Obb::from_json(&root["boundingVolume"]["box"])
        .ok_or(ViewError::NoRootBox { path: ts_path })?;
    let dir_view = DVec3::new(1.0, -1.0, 0.7).normalize();
    let eye = rb.center + dir_view * (rb.radius() / (v.fov_y_deg.to_radians() / 2.0).sin());
    let mut out = FirstView::default();
    let default_refine = root["refine"].as_str().unwrap_or("REPLACE").to_string();
    let mut depths = std::collections::BTreeSet::new();
    let mut stack = vec![(root, default_refine, 0u32)];
    while let Some((t, inherited, depth)) = stack.pop() {
        let refine = t["refine"].as_str().map_or(inherited, str::to_string);
        let ge = t["geometricError"].as_f64().unwrap_or(0.0);
        let dist = Obb::from_json(&t["boundingVolume"]["box"]).map_or(0.0, |b| b.distance(eye));
        let sse = if dist <= 0.0 {
            f64::INFINITY
        } else {
            sse_px(ge, dist, v)
        };
        let children = t["children"].as_array().filter(|c| !c.is_empty());
        let refines = sse > v.max_sse_px && children.is_some();
        if !refines || refine == "ADD" {
            if let Some(uri) = t["content"]["uri"].as_str() {
                let (path, glb) = match crate::uri::data::decode(uri) {
                    Some(decoded) => {
                        let path = dir.join("tileset.json");
                        let glb = decoded.map_err(|source| ViewError::DataUri {
                            path: path.clone(),
                            source,
                        })?;
                        (path, glb)
                    }
                    None => {
                        let path = dir.join(uri);
                        let glb = read(&path)?;
                        (path, glb)
                    }
                };
                let glb_error = |source| ViewError::Glb {
                    path: path.clone(),
                    source,
                };
                let (bytes, n) = glb_image_bytes(&glb).map_err(glb_error)?;
                out.tiles += 1;
                out.glb_bytes += glb.len() as u64;
                out.texture_bytes += bytes;
                out.images += n;
                out.triangles += glb_drawn_triangles(&glb).map_err(glb_error)?;
                out.selected
                    .push(crate::uri::data::content_label(uri).to_string());
                depths.insert(depth);
            }
        }
        if refines {
            for c in children.into_iter().flatten() {
                stack.push((c, refine.clone(), depth + 1));
            }
        }
    }
    out.levels = depths.len();
    out.max_depth = depths.last().copied().unwrap_or(0);
    Ok(out)
}

/// [`first_view`] counting shared texture files once (paper III.F): the texture bytes a
/// client loads for the first whole-model view are the embedded images of the selected tiles
/// plus each distinct external file they reference (`../textures/`). Also returns how many
/// distinct files that is (requests on top of the tiles').
pub fn first_view_shared(dir: &Path, v: &ViewOptions) -> Result<(FirstView, usize), ViewError> {
    let mut out = first_view(dir, v)?;
    let mut files = BTreeSet::new();
    let mut references = 0;
    for uri in &out.selected {
        let tile = dir.join(uri);
        let glb = read(&tile)?;
        let json = glb_json_of(&tile, &glb)?;
        for im in json["images"].as_array().into_iter().flatten() {
            if let Some(u) = im["uri"].as_str() {
                references += 1;
                let base = tile.parent().unwrap_or(dir);
                files.insert(normalize(&base.join(u)));
            }
        }
    }
    for f in &files {
        out.texture_bytes += std::fs::metadata(f)
            .map_err(|source| ViewError::Read {
                path: f.clone(),
                source,
            })?
            .len();
    }
    // `images` counts what is downloaded: embedded copies and distinct files.
    out.images = out.images - references + files.len();
    Ok((out, files.len()))
}

/// `a/b/../c` → `a/c` (no file system access).
fn normalize(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            std::path::Component::ParentDir => {
                out.pop();
            }
            std::path::Component::CurDir => {}
            c => out.push(c),
        }
    }
    out
}

/// The whole model at full detail, as [`first_view`] counts it: the selection refined to the end
/// (a screen-space error limit of 0 refines every tile whose `geometricError` is above 0).
pub fn full_view(dir: &Path) -> Result<FirstView, ViewError> {
    first_view(
        dir,
        &ViewOptions {
            max_sse_px: 0.0,
            ..ViewOptions::default()
        },
    )
}

/// The gzipped edge data of the tiles a first whole-model view of the tileset in `dir` selects;
/// 0 without edges, or when the view cannot be worked out (the build's own checks report that).
pub fn edge_gzip_bytes(tiles: &[crate::encode::TileRecord], dir: &Path) -> u64 {
    if tiles.iter().all(|t| t.content.edge_gzip_bytes == 0) {
        return 0;
    }
    let Ok(view) = first_view(dir, &crate::tileset::view::ViewOptions::default()) else {
        return 0;
    };
    let inlined = crate::uri::data::content_label("data:");
    tiles
        .iter()
        .filter(|t| {
            let label = if t.inlined_in_tileset {
                Some(inlined)
            } else {
                t.uri.as_deref()
            };
            label.is_some_and(|l| view.selected.iter().any(|s| s == l))
        })
        .map(|t| t.content.edge_gzip_bytes)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalize_resolves_parent_steps() {
        assert_eq!(
            normalize(Path::new("/x/tiles/../textures/a.png")),
            PathBuf::from("/x/textures/a.png")
        );
    }

    #[test]
    fn obb_distance_and_radius() {
        let b = Obb::from_json(&serde_json::json!([0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3])).unwrap();
        assert_eq!(b.distance(DVec3::new(0.5, 0.0, 0.0)), 0.0);
        assert!((b.distance(DVec3::new(4.0, 0.0, 0.0)) - 3.0).abs() < 1e-12);
        assert!((b.distance(DVec3::new(4.0, 6.0, 0.0)) - 5.0).abs() < 1e-12);
        assert!((b.radius() - 14f64.sqrt()).abs() < 1e-12);
    }
}
