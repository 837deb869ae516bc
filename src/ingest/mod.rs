//! Readers: turn input files into a [`Scene`](crate::scene::Scene). One file per format; each
//! checks its input completely and reports problems as [`Error::Input`](crate::error::Error)
//! naming the file.

pub mod gltf;

use crate::error::{Error, Result};
use crate::scene::Scene;
use std::path::Path;

/// Reads any supported input, chosen by content (GLB magic, JSON) and extension.
pub fn read_input(path: &Path) -> Result<Scene> {
    if !path.exists() {
        return Err(Error::input(path, "no such file"));
    }
    if path.is_dir() {
        return Err(Error::input(path, "is a folder, not a model file"));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    match ext.as_str() {
        "ifc" => Err(Error::input(
            path,
            "IFC input is not supported yet (convert it to glTF first)",
        )),
        _ => gltf::read_gltf(path),
    }
}

/// The bundled sample building (`samples/sample_building.glb`), compiled into the binary so that
/// `bimtiles convert --out DIR` works anywhere with no input at hand.
pub const EMBEDDED_SAMPLE: &[u8] = include_bytes!("../../samples/sample_building.glb");
/// The name the embedded sample goes by in reports and errors.
pub const EMBEDDED_SAMPLE_NAME: &str = "samples/sample_building.glb (embedded)";

/// Reads the embedded sample building.
pub fn read_embedded_sample() -> Result<Scene> {
    gltf::read_gltf_bytes(Path::new(EMBEDDED_SAMPLE_NAME), EMBEDDED_SAMPLE)
}

/// Reads several inputs into one scene, in the order given.
pub fn read_inputs(paths: &[impl AsRef<Path>]) -> Result<Scene> {
    let mut scene = Scene::default();
    for p in paths {
        scene.append(read_input(p.as_ref())?);
    }
    Ok(scene)
}
