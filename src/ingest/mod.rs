//! Readers: turn input files (glTF/GLB, IFC, CityJSON) into a [`Scene`](crate::scene::Scene). One file per format; each
//! checks its input completely and reports problems as [`Error::Input`](crate::error::Error)
//! naming the file.

pub mod cityjson;
pub mod gltf;
mod gltf_compressed;
mod gltf_index;
#[cfg(feature = "ifc")]
pub mod ifc;
pub mod manifest;

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
    if ext == "ifc" || looks_like_step(path) {
        return read_ifc(path);
    }
    if cityjson::is_cityjson(path) {
        return cityjson::read_cityjson(path);
    }
    gltf::read_gltf(path)
}

/// IFC files are ISO 10303-21 (STEP) text, whatever their extension.
fn looks_like_step(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 64];
    let n = std::fs::File::open(path)
        .and_then(|mut f| f.read(&mut head))
        .unwrap_or(0);
    let text = String::from_utf8_lossy(&head[..n]);
    text.trim_start_matches('\u{feff}')
        .trim_start()
        .starts_with("ISO-10303-21")
}

#[cfg(feature = "ifc")]
fn read_ifc(path: &Path) -> Result<Scene> {
    let (mut scene, report) = ifc::read_ifc_with_report(path)?;
    scene.skipped_elements += report.skipped.len();
    // A repeated GlobalId (a broken exporter) must not make two elements one.
    keep_ids_unique(&mut scene);
    scene.georeference = report.georef.map(|g| crate::scene::SourceGeoreference {
        longitude_deg: g.longitude_deg,
        latitude_deg: g.latitude_deg,
        height_m: g.height_m,
        true_north_deg: g.true_north_deg,
        anchor: g.anchor,
    });
    Ok(scene)
}

#[cfg(not(feature = "ifc"))]
fn read_ifc(path: &Path) -> Result<Scene> {
    Err(Error::input(
        path,
        "IFC input needs bimtiles built with the `ifc` feature (cargo build --features ifc)",
    ))
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
    // The first scene is taken as it is: appending it to an empty one would copy every vector
    // (briefly twice the metadata of a whole campus).
    let mut scene: Option<Scene> = None;
    for p in paths {
        let next = read_input(p.as_ref())?;
        match scene.as_mut() {
            None => scene = Some(next),
            Some(s) => s.append(next),
        }
    }
    let mut scene = scene.unwrap_or_default();
    if paths.len() > 1 {
        // Files are unique on their own; two of them may still share ids.
        keep_ids_unique(&mut scene);
    }
    Ok(scene)
}

/// Numbers any repeated element id (`scene::ids`, rule 3), counting the renamed ones.
pub(crate) fn keep_ids_unique(scene: &mut Scene) {
    let (table, renamed) = crate::scene::ids::make_keys_unique(std::mem::take(&mut scene.elements));
    scene.elements = table;
    scene.renamed_ids += renamed;
}

/// What a conversion reads: the embedded sample, model files, or a campus manifest.
#[derive(Debug, Clone, PartialEq)]
pub enum InputSet {
    Sample,
    Files(Vec<std::path::PathBuf>),
    Manifest(std::path::PathBuf),
}

impl InputSet {
    /// Model files (none: the sample) or a manifest.
    pub fn new(files: &[std::path::PathBuf], manifest: Option<&Path>) -> InputSet {
        match (manifest, files) {
            (Some(m), _) => InputSet::Manifest(m.to_path_buf()),
            (None, []) => InputSet::Sample,
            (None, f) => InputSet::Files(f.to_vec()),
        }
    }

    pub fn read(&self) -> Result<Scene> {
        match self {
            InputSet::Sample => read_embedded_sample(),
            InputSet::Files(f) => read_inputs(f),
            InputSet::Manifest(m) => manifest::read_manifest(m),
        }
    }
}
