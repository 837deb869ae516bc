//! What a 3D Tiles client loads for a first view of the whole model (the measurement behind the
//! paper's loading claim, III.F and Table V): tiles are selected as CesiumJS does, by screen-space
//! error `sse = geometricError * screenHeight / (2 * distance * tan(fovY / 2))`, refining while it
//! is above the limit (16 px by default); the image bytes embedded in the selected tiles are
//! summed. The camera looks at the root's bounding box from a distance at which its bounding
//! sphere fills the vertical field of view, from the south-east and above. No frustum culling:
//! the whole model is in view.

use glam::DVec3;
use serde::Serialize;
use serde_json::Value;
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ViewOptions {
    pub width_px: u32,
    pub height_px: u32,
    pub fov_y_deg: f64,
    pub max_sse_px: f64,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            width_px: 1920,
            height_px: 1080,
            fov_y_deg: 60.0,
            max_sse_px: 16.0,
        }
    }
}

#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FirstView {
    /// Tiles selected (with content).
    pub tiles: usize,
    /// Their GLB bytes.
    pub glb_bytes: u64,
    /// Image bytes embedded in them.
    pub texture_bytes: u64,
    pub images: usize,
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

/// Image bytes embedded in a GLB, and how many images.
pub fn glb_image_bytes(glb: &[u8]) -> Result<(u64, usize), String> {
    if glb.len() < 20 || &glb[0..4] != b"glTF" {
        return Err("not a GLB".into());
    }
    let n = u32::from_le_bytes(glb[12..16].try_into().expect("4 bytes")) as usize;
    let json: Value = serde_json::from_slice(glb.get(20..20 + n).ok_or("short GLB")?)
        .map_err(|e| e.to_string())?;
    let views = json["bufferViews"].as_array().cloned().unwrap_or_default();
    let images = json["images"].as_array().cloned().unwrap_or_default();
    let bytes = images
        .iter()
        .filter_map(|i| i["bufferView"].as_u64())
        .filter_map(|v| views.get(v as usize)?["byteLength"].as_u64())
        .sum();
    Ok((bytes, images.len()))
}

/// Selects the tiles of the tileset in `dir` for a whole-model view and sums their bytes.
pub fn first_view(dir: &Path, v: &ViewOptions) -> Result<FirstView, String> {
    let ts: Value = serde_json::from_slice(
        &std::fs::read(dir.join("tileset.json")).map_err(|e| e.to_string())?,
    )
    .map_err(|e| e.to_string())?;
    let root = &ts["root"];
    let rb = Obb::from_json(&root["boundingVolume"]["box"]).ok_or("root has no box")?;
    let half_fov = (v.fov_y_deg.to_radians() / 2.0).tan();
    let dir_view = DVec3::new(1.0, -1.0, 0.7).normalize();
    let eye = rb.center + dir_view * (rb.radius() / (v.fov_y_deg.to_radians() / 2.0).sin());
    let mut out = FirstView::default();
    let default_refine = root["refine"].as_str().unwrap_or("REPLACE").to_string();
    let mut stack = vec![(root, default_refine)];
    while let Some((t, inherited)) = stack.pop() {
        let refine = t["refine"].as_str().map_or(inherited, str::to_string);
        let ge = t["geometricError"].as_f64().unwrap_or(0.0);
        let dist = Obb::from_json(&t["boundingVolume"]["box"]).map_or(0.0, |b| b.distance(eye));
        let sse = if dist <= 0.0 {
            f64::INFINITY
        } else {
            ge * v.height_px as f64 / (2.0 * dist * half_fov)
        };
        let children = t["children"].as_array().filter(|c| !c.is_empty());
        let refines = sse > v.max_sse_px && children.is_some();
        if !refines || refine == "ADD" {
            if let Some(uri) = t["content"]["uri"].as_str() {
                let glb = std::fs::read(dir.join(uri)).map_err(|e| format!("{uri}: {e}"))?;
                let (bytes, n) = glb_image_bytes(&glb).map_err(|e| format!("{uri}: {e}"))?;
                out.tiles += 1;
                out.glb_bytes += glb.len() as u64;
                out.texture_bytes += bytes;
                out.images += n;
            }
        }
        if refines {
            for c in children.into_iter().flatten() {
                stack.push((c, refine.clone()));
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obb_distance_and_radius() {
        let b = Obb::from_json(&serde_json::json!([0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3])).unwrap();
        assert_eq!(b.distance(DVec3::new(0.5, 0.0, 0.0)), 0.0);
        assert!((b.distance(DVec3::new(4.0, 0.0, 0.0)) - 3.0).abs() < 1e-12);
        assert!((b.distance(DVec3::new(4.0, 6.0, 0.0)) - 5.0).abs() < 1e-12);
        assert!((b.radius() - 14f64.sqrt()).abs() < 1e-12);
    }
}
