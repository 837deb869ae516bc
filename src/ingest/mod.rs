//! Readers: turn input files (glTF/GLB, IFC, CityJSON, Wavefront OBJ, FBX) into a [`Scene`](crate::scene::Scene). One file per format; each
//! checks its input completely and reports problems as [`Error::Input`](crate::error::Error)
//! naming the file.

pub mod citygml;
pub mod cityjson;
pub mod fbx;
pub mod gltf;
mod gltf_compressed;
mod gltf_index;
#[cfg(feature = "ifc")]
pub mod ifc;
pub mod interchange;
pub mod manifest;
pub mod obj;

/// `EXT_meshopt_compression` views, decoded as the glTF reader does (the tests' tile reader uses
/// them too).
pub use gltf_compressed::{decode_meshopt_view, MeshoptError};
pub use gltf_index::MeshoptView;

use crate::error::{Error, Result};
use crate::scene::placement::PerVertexError;
use crate::scene::Scene;
use std::path::Path;

/// Opens an input file for reading, refusing what is not a regular file: a FIFO would hold the
/// run forever and a device such as `/dev/zero` never ends. Opened non-blocking, so a FIFO is
/// refused without waiting for a writer (the flag changes nothing for regular files).
pub fn open_regular(path: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    let kind = file.metadata()?.file_type();
    let what = if kind.is_file() {
        return Ok(file);
    } else if kind.is_dir() {
        "a folder"
    } else if kind.is_fifo() {
        "a FIFO (named pipe)"
    } else if kind.is_char_device() || kind.is_block_device() {
        "a device"
    } else {
        "a socket"
    };
    Err(std::io::Error::new(
        std::io::ErrorKind::InvalidInput,
        format!("{what}, not a regular file"),
    ))
}

/// Reads a whole input file ([`open_regular`]).
pub fn read_regular(path: &Path) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let mut bytes = Vec::new();
    open_regular(path)?.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Reads any supported input, chosen by content (GLB magic, JSON) and extension.
pub fn read_input(path: &Path) -> Result<Scene> {
    read_input_with(path, ReadOptions::default())
}

/// A CRS given for inputs: the text (`EPSG:28992`) and where it came from (`option` for
/// `--crs`, `manifest` for an entry's `"crs"`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GivenCrs<'a> {
    pub crs: &'a str,
    pub source: &'a str,
}

/// How inputs are read: the CRS of their map coordinates (`--crs`, a manifest entry's `"crs"`)
/// and which CityJSON LoD to read (`--cityjson-lod`; `None`: each object's highest).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ReadOptions<'a> {
    pub crs: Option<GivenCrs<'a>>,
    pub cityjson_lod: Option<&'a str>,
    /// The up axis and unit of OBJ files (`--up`, `--unit`).
    pub mesh_frame: interchange::MeshFrame,
    /// CityGML: the LoD (`--citygml-lod`) and appearance theme (`--citygml-theme`) to read.
    pub citygml_lod: Option<&'a str>,
    pub citygml_theme: Option<&'a str>,
}

/// Like [`read_input`], with [`ReadOptions`]. A given CRS is the CRS of the input's coordinates:
/// an IFC file's IfcMapConversion that names no usable CRS is in it, and an input with no
/// georeference of its own (glTF, IFC in map coordinates) has map coordinates of it; a CityJSON
/// file is in it whatever its `metadata.referenceSystem` says. A CRS that cannot be used is one
/// warning ([`Scene::georef_warnings`]) and the default placement.
pub fn read_input_with(path: &Path, opts: ReadOptions<'_>) -> Result<Scene> {
    check_input_file(path)?;
    let mut scene = if cityjson::is_cityjson(path) {
        read_cityjson(path, opts)?
    } else if citygml::is_citygml(path) {
        read_citygml(path, opts)?
    } else {
        let mut scene = read_model(path, opts)?;
        if let (Some(given), None) = (opts.crs, scene.georeference) {
            if let Err(e) = crate::scene::placement::georeference_map_coordinates(
                &mut scene,
                given.crs,
                given.source,
            ) {
                warn_georef(&mut scene, path, format!("--crs {}: {e}", given.crs));
            }
        }
        scene
    };
    if let Some(given) = opts.crs {
        for u in &mut scene.crs_used {
            if u.source == "option" {
                u.source = given.source.into();
            }
        }
    }
    Ok(scene)
}

/// Records a georeference that could not be used (`convert` prints it, or fails under
/// `--strict-georef`).
fn warn_georef(scene: &mut Scene, path: &Path, message: String) {
    scene.georef_warnings.push(crate::scene::GeorefWarning {
        file: path.to_path_buf(),
        message,
    });
}

/// An input must be a readable regular file ([`open_regular`]).
fn check_input_file(path: &Path) -> Result<()> {
    if std::fs::symlink_metadata(path).is_err() {
        return Err(Error::input(path, "no such file"));
    }
    if path.is_dir() {
        return Err(Error::input(path, "is a folder, not a model file"));
    }
    if let Err(e) = open_regular(path) {
        return Err(Error::input_from(path, "cannot read", e));
    }
    Ok(())
}

/// An IFC, OBJ or glTF/GLB file.
fn read_model(path: &Path, opts: ReadOptions<'_>) -> Result<Scene> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if ext == "ifc" || looks_like_step(path) {
        return read_ifc(path, opts.crs.map(|c| c.crs));
    }
    if ext == "obj" {
        return obj::read_obj(path, opts.mesh_frame);
    }
    if ext == "fbx" || looks_like_fbx(path) {
        return fbx::read_fbx(path);
    }
    gltf::read_gltf(path)
}

/// A CityJSON file, placed by the given CRS or else its own `metadata.referenceSystem`, every
/// vertex on its own ([`georeference_map_coordinates_per_vertex`](crate::scene::placement::georeference_map_coordinates_per_vertex)).
/// With neither, it stays in its local coordinates, with a warning when they look like map
/// coordinates.
fn read_cityjson(path: &Path, opts: ReadOptions<'_>) -> Result<Scene> {
    let cityjson::CityModel {
        mut scene,
        reference_system,
    } = cityjson::read_cityjson(path, opts.cityjson_lod)?;
    let (crs, source) = match (opts.crs, reference_system) {
        (Some(given), _) => (given.crs.to_string(), "option"),
        (None, Some(own)) => (own, "cityjson-reference-system"),
        (None, None) => {
            let (_, rule) = crate::scene::placement::choose_anchor(&scene.bounds());
            if scene.bounds().center().length()
                > crate::scene::placement::PROJECTED_COORDINATES_THRESHOLD_M
            {
                scene.reader_warnings.push(format!(
                    "{}: no metadata.referenceSystem, and the coordinates look like map coordinates ({rule}): the model is placed at the default origin; give --crs EPSG:CODE to place it",
                    path.display()
                ));
            }
            return Ok(scene);
        }
    };
    let what = match source {
        "option" => "--crs",
        _ => "metadata.referenceSystem",
    };
    place_per_vertex(&mut scene, path, (&crs, source), what)?;
    Ok(scene)
}

/// Places a scene in map coordinates of `crs` vertex by vertex
/// ([`georeference_map_coordinates_per_vertex`](crate::scene::placement::georeference_map_coordinates_per_vertex)):
/// a CRS that cannot place it is a warning (the scene stays as it was), a vertex PROJ refuses
/// midway an error. `what` names the CRS's field in both.
fn place_per_vertex(
    scene: &mut Scene,
    path: &Path,
    (crs, source): (&str, &str),
    what: &str,
) -> Result<()> {
    match crate::scene::placement::georeference_map_coordinates_per_vertex(scene, crs, source) {
        Ok(()) => Ok(()),
        Err(PerVertexError::NotPlaced(e)) => {
            warn_georef(scene, path, format!("{what} {crs}: {e}"));
            Ok(())
        }
        Err(e @ PerVertexError::Midway(_)) => Err(Error::input(path, format!("{what} {crs}: {e}"))),
    }
}

/// Binary FBX files open with the magic `Kaydara FBX Binary`, whatever their extension.
fn looks_like_fbx(path: &Path) -> bool {
    file_head(path, 18) == b"Kaydara FBX Binary"
}

/// A file's name in lower case, for choosing a reader by extension.
pub(crate) fn lowercase_name(path: &Path) -> String {
    path.file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// The first `n` bytes of a file (fewer when it is shorter or unreadable): what format sniffing
/// looks at.
pub(crate) fn file_head(path: &Path, n: usize) -> Vec<u8> {
    use std::io::Read;
    let mut head = vec![0u8; n];
    let read = open_regular(path)
        .and_then(|mut f| f.read(&mut head))
        .unwrap_or(0);
    head.truncate(read);
    head
}

/// A CityGML file: a geographic CRS is placed by the reader; a projected one (the given CRS, else
/// the file's `srsName`) every vertex on its own, as CityJSON.
fn read_citygml(path: &Path, opts: ReadOptions<'_>) -> Result<Scene> {
    let citygml::CityModel { mut scene, map_crs } = citygml::read_citygml(
        path,
        citygml::CityGmlOptions {
            lod: opts.citygml_lod,
            theme: opts.citygml_theme,
            crs: opts.crs.map(|c| c.crs),
        },
    )?;
    if let Some((crs, source)) = map_crs {
        let what = if source == "option" {
            "--crs"
        } else {
            "srsName"
        };
        place_per_vertex(&mut scene, path, (&crs, source), what)?;
    }
    Ok(scene)
}

/// IFC files are ISO 10303-21 (STEP) text, whatever their extension.
fn looks_like_step(path: &Path) -> bool {
    let head = file_head(path, 64);
    let text = String::from_utf8_lossy(&head);
    text.trim_start_matches('\u{feff}')
        .trim_start()
        .starts_with("ISO-10303-21")
}

#[cfg(feature = "ifc")]
fn read_ifc(path: &Path, crs: Option<&str>) -> Result<Scene> {
    let (mut scene, report) = ifc::read_ifc_with_crs(path, crs)?;
    scene.skipped_elements += report.skipped.len();
    scene.curve_only_elements += report.curve_only;
    // A repeated GlobalId (a broken exporter) must not make two elements one.
    keep_ids_unique(&mut scene);
    scene.georeference = report
        .georef
        .as_ref()
        .map(|g| crate::scene::SourceGeoreference {
            longitude_deg: g.longitude_deg,
            latitude_deg: g.latitude_deg,
            height_m: g.height_m,
            true_north_deg: g.true_north_deg,
            anchor: g.anchor,
            map_linear: g.map_linear,
        });
    if let Some(w) = report.georef_warning {
        warn_georef(&mut scene, path, w);
    }
    let Some(georef) = report.georef else {
        return Ok(scene);
    };
    match (georef.per_vertex_map, georef.crs) {
        (Some(to_map), Some(crs)) => place_ifc_per_vertex(&mut scene, path, to_map, crs)?,
        (_, crs) => scene.crs_used.extend(crs),
    }
    Ok(scene)
}

/// A map placement too wide for one linear map: the scene goes to map coordinates, then every
/// vertex through PROJ, as CityJSON; the report keeps the CRS as the IFC reader named it. PROJ
/// refusing the anchor there puts the components back where they were and the linear map stays
/// (the IFC reader placed that anchor already, so the vertices around it are within the CRS's
/// reach); PROJ refusing a vertex is an error.
#[cfg(feature = "ifc")]
fn place_ifc_per_vertex(
    scene: &mut Scene,
    path: &Path,
    to_map: glam::DMat4,
    crs: crate::geodesy::crs::CrsUse,
) -> Result<()> {
    let before = scene.components.clone();
    scene.apply_transform(&to_map);
    let placed = crate::scene::placement::georeference_map_coordinates_per_vertex(
        scene,
        &crs.crs,
        &crs.source,
    );
    match placed {
        Ok(()) => {
            if let Some(u) = scene.crs_used.last_mut() {
                u.crs = crs.crs;
                u.crs_name = crs.crs_name;
            }
        }
        Err(PerVertexError::NotPlaced(_)) => {
            scene.components = before;
            scene.crs_used.push(crs);
        }
        Err(e @ PerVertexError::Midway(_)) => {
            return Err(Error::input(
                path,
                format!("{} ({}): {e}", crs.crs, crs.source),
            ))
        }
    }
    Ok(())
}

#[cfg(not(feature = "ifc"))]
fn read_ifc(path: &Path, _crs: Option<&str>) -> Result<Scene> {
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
    read_inputs_with(paths, ReadOptions::default())
}

/// Like [`read_inputs`], every file read with `opts` ([`read_input_with`]).
pub fn read_inputs_with(paths: &[impl AsRef<Path>], opts: ReadOptions<'_>) -> Result<Scene> {
    // The first scene is taken as it is: appending it to an empty one would copy every vector
    // (briefly twice the metadata of a whole site).
    let mut scene: Option<Scene> = None;
    for p in paths {
        let next = read_input_with(p.as_ref(), opts)?;
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

/// What a conversion reads: the embedded sample, model files, or a manifest of many models.
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
        self.read_with(ReadOptions::default())
    }

    /// Reads the inputs with `opts` ([`read_input_with`]); a manifest's entries name their own
    /// CRS.
    pub fn read_with(&self, opts: ReadOptions<'_>) -> Result<Scene> {
        match self {
            InputSet::Sample => read_embedded_sample(),
            InputSet::Files(f) => read_inputs_with(f, opts),
            InputSet::Manifest(m) => manifest::read_manifest(m, opts),
        }
    }
}
