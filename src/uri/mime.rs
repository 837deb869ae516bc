//! Media types (RFC 6838): a file's `Content-Type` by its extension, with how each type takes
//! gzip, for `serve`; and an image's type by its magic bytes (the PNG signature, JPEG's SOI
//! marker, the RIFF `WEBP` header), since a glTF's declared `mimeType` may be wrong or missing.

use std::path::Path;

/// How a type responds to gzip.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compress {
    /// Text-like: always compresses well.
    Always,
    /// Binary that may or may not shrink (GLB, .bin, wasm...): compress once, keep the result only
    /// if it saves enough (`serve`'s `GZIP_MIN_SAVING`).
    IfSmaller,
    /// Already compressed (images, fonts, archives): never.
    Never,
}

/// The `Content-Type` for a path (by extension, case-insensitive) and its gzip policy.
pub fn for_path(path: &Path) -> (&'static str, Compress) {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    use Compress::*;
    match ext.as_str() {
        "html" | "htm" => ("text/html; charset=utf-8", Always),
        "js" | "mjs" | "cjs" => ("text/javascript; charset=utf-8", Always),
        "css" => ("text/css; charset=utf-8", Always),
        "json" | "map" => ("application/json", Always),
        "geojson" => ("application/geo+json", Always),
        "czml" => ("application/json", Always),
        "txt" | "md" => ("text/plain; charset=utf-8", Always),
        "xml" => ("application/xml", Always),
        "kml" => ("application/vnd.google-earth.kml+xml", Always),
        "svg" => ("image/svg+xml", Always),
        "gltf" => ("model/gltf+json", Always),
        "glb" => ("model/gltf-binary", IfSmaller),
        "wasm" => ("application/wasm", IfSmaller),
        // 3D Tiles binaries (implicit-tiling subtrees, legacy formats) and glTF buffers.
        "bin" | "subtree" | "b3dm" | "i3dm" | "pnts" | "cmpt" | "terrain" => {
            ("application/octet-stream", IfSmaller)
        }
        "png" => ("image/png", Never),
        "jpg" | "jpeg" => ("image/jpeg", Never),
        "gif" => ("image/gif", Never),
        "webp" => ("image/webp", Never),
        "avif" => ("image/avif", Never),
        "ktx2" => ("image/ktx2", Never),
        "ico" => ("image/vnd.microsoft.icon", IfSmaller),
        "woff" => ("font/woff", Never),
        "woff2" => ("font/woff2", Never),
        "ttf" => ("font/ttf", IfSmaller),
        "otf" => ("font/otf", IfSmaller),
        "zip" => ("application/zip", Never),
        "gz" => ("application/gzip", Never),
        _ => ("application/octet-stream", Never),
    }
}

/// The media type of an image by its magic bytes: PNG, JPEG or WebP, the formats the readers
/// take; `None` for anything else.
pub fn sniff_image(b: &[u8]) -> Option<&'static str> {
    if b.starts_with(&[0x89, b'P', b'N', b'G']) {
        Some("image/png")
    } else if b.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some("image/jpeg")
    } else if b.len() >= 12 && &b[0..4] == b"RIFF" && &b[8..12] == b"WEBP" {
        Some("image/webp")
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn common_types() {
        let t = |p: &str| for_path(Path::new(p)).0;
        assert_eq!(t("tileset.json"), "application/json");
        assert_eq!(t("tiles/r0.glb"), "model/gltf-binary");
        assert_eq!(t("tiles/R0.GLB"), "model/gltf-binary");
        assert_eq!(t("Cesium.js"), "text/javascript; charset=utf-8");
        assert_eq!(t("widgets.css"), "text/css; charset=utf-8");
        assert_eq!(t("draco_decoder.wasm"), "application/wasm");
        assert_eq!(t("a.png"), "image/png");
        assert_eq!(t("a.jpg"), "image/jpeg");
        assert_eq!(t("a.jpeg"), "image/jpeg");
        assert_eq!(t("a.ktx2"), "image/ktx2");
        assert_eq!(t("index.html"), "text/html; charset=utf-8");
        assert_eq!(t("icon.svg"), "image/svg+xml");
        assert_eq!(t("0.0.0.subtree"), "application/octet-stream");
        assert_eq!(t("no_extension"), "application/octet-stream");
    }

    #[test]
    fn gzip_policy() {
        assert_eq!(for_path(Path::new("a.json")).1, Compress::Always);
        assert_eq!(for_path(Path::new("a.glb")).1, Compress::IfSmaller);
        assert_eq!(for_path(Path::new("a.png")).1, Compress::Never);
        assert_eq!(for_path(Path::new("a.ktx2")).1, Compress::Never);
    }

    #[test]
    fn sniff_mime() {
        assert_eq!(sniff_image(&[0x89, b'P', b'N', b'G', 0]), Some("image/png"));
        assert_eq!(sniff_image(&[0xff, 0xd8, 0xff, 0]), Some("image/jpeg"));
        assert_eq!(sniff_image(b"RIFF\0\0\0\0WEBPVP8 "), Some("image/webp"));
        assert_eq!(sniff_image(b"RIFF\0\0\0\0WEB"), None);
        assert_eq!(sniff_image(b"hello"), None);
    }
}
