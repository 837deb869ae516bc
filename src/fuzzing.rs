//! Entry points for fuzzing (book: guide/safety.md): each feeds arbitrary bytes to one reader of
//! untrusted input, the same library function a run calls, and ignores the error it may return.
//! A panic, an abort or a hang is the defect. The cargo-fuzz targets in `fuzz/` call these, and
//! `tests/fuzz_corpus.rs` runs every corpus file through them on stable ([`TARGETS`]).

use crate::texture::admit::{header_size, ImageLimits};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// What a fuzz target calls with each input.
pub type EntryPoint = fn(&[u8]);

/// Each fuzz target's name (its folder under `fuzz/corpus/`) and entry point.
pub const TARGETS: &[(&str, EntryPoint)] = &[
    ("gltf", gltf),
    ("ifc", ifc),
    ("manifest", manifest),
    ("citygml", citygml),
    ("image", image),
    ("inspect", inspect),
    ("http_head", http_head),
    ("obj", obj),
    ("fbx", fbx),
];

/// A fuzz target's `init` where bimtiles catches some dependencies' panics on purpose and turns
/// them into errors naming the file (ifc-lite in `ingest::ifc`, the image decoders in
/// `texture::codec`): libfuzzer-sys's hook aborts on every panic, caught or not. This one lets a
/// panic raised in a source path containing one of `caught` through (printed), and aborts on any
/// other, as libfuzzer-sys does; one that escapes an entry point still aborts in libfuzzer-sys's
/// `catch_unwind` around the target.
pub fn abort_on_panics_outside(caught: &'static [&'static str]) {
    std::panic::set_hook(Box::new(move |info| {
        eprintln!("{info}");
        let file = info.location().map(|l| l.file()).unwrap_or_default();
        if !caught.iter().any(|c| file.contains(c)) {
            std::process::abort();
        }
    }));
}

/// The image decoders `texture::codec` runs (crate source paths): their panics become errors.
pub const IMAGE_DECODER_CRATES: &[&str] = &["/png-", "/image-", "/zune-", "/jpeg-decoder-"];

/// A glTF or GLB file (`ingest::gltf`); relative URIs resolve in an empty folder.
pub fn gltf(data: &[u8]) {
    let _ = crate::ingest::gltf::read_gltf_bytes(&scratch().join("model.glb"), data);
}

/// An IFC (STEP) file: the STEP check, ifc-lite's geometry and data model, the georeference.
pub fn ifc(data: &[u8]) {
    #[cfg(feature = "ifc")]
    let _ = crate::ingest::ifc::read_ifc_bytes_with_crs(&scratch().join("model.ifc"), data, None);
    #[cfg(not(feature = "ifc"))]
    let _ = data;
}

/// A Wavefront OBJ file (`ingest::obj`), read as a stream; its MTL libraries and textures
/// resolve in an empty folder.
pub fn obj(data: &[u8]) {
    let _ = crate::ingest::obj::read_obj_from(
        &scratch().join("model.obj"),
        data,
        crate::ingest::interchange::MeshFrame::default(),
    );
}

/// An FBX file (`ingest::fbx`, binary or ASCII); the textures it names resolve in an empty
/// folder.
pub fn fbx(data: &[u8]) {
    let _ = crate::ingest::fbx::read_fbx_bytes(&scratch().join("model.fbx"), data);
}

/// A manifest's text, checked against a folder that holds one model (`model.glb`).
pub fn manifest(data: &[u8]) {
    let _ = crate::ingest::manifest::Manifest::from_bytes(&scratch().join("campus.json"), data);
}

/// A CityGML document (`ingest::citygml`): the XML stream, geometry, references, appearances
/// and the srsName; image paths resolve in an empty folder.
pub fn citygml(data: &[u8]) {
    let _ = crate::ingest::citygml::read_citygml_bytes(
        &scratch().join("model.gml"),
        data,
        Default::default(),
    );
}

/// An image: its header against small limits (as `texture::admit`), then, if admitted, the one
/// decoding pass (`identical::pixel_key`) and its pyramid (`texture::build_pyramid`).
pub fn image(data: &[u8]) {
    // Small limits keep each run fast; the checks are those of any budget.
    let limits = ImageLimits {
        max_side_px: 1024,
        max_decoded_bytes: Some(1 << 20),
    };
    let Ok((_, None)) = header_size(data, &limits) else {
        return;
    };
    if crate::texture::identical::pixel_key(data).is_err() {
        return;
    }
    let mime = crate::uri::mime::sniff_image(data).unwrap_or("image/png");
    let image = crate::scene::Image {
        name: None,
        mime_type: mime.into(),
        bytes: std::sync::Arc::new(data.to_vec()),
    };
    let _ = crate::texture::build_pyramid(&image, Default::default(), 85);
}

/// A tileset.json for `inspect`, in a folder that holds one tile (`tile.glb`, the sample).
pub fn inspect(data: &[u8]) {
    let _ = crate::inspect::inspect_text(scratch(), data);
}

/// An HTTP request head as `serve` reads it from a connection.
pub fn http_head(data: &[u8]) {
    let mut reader = std::io::BufReader::new(data);
    while crate::serve::read_request(&mut reader).is_ok() {}
}

/// A folder of this process holding `model.glb` and `tile.glb` (the embedded sample), for the
/// readers that look up files beside their input.
fn scratch() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("bimtiles-fuzz-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        for name in ["model.glb", "tile.glb"] {
            let _ = std::fs::write(dir.join(name), crate::ingest::EMBEDDED_SAMPLE);
        }
        dir
    })
}
