//! Data URIs (RFC 2397): `data:[<mediatype>][;base64],<data>`, the bytes carried in the URI
//! itself. A glTF embeds buffers and images this way, and a tileset its inlined root content.
//! Only the base64 form (RFC 4648, section 4) is read: that is what glTF exporters and bimtiles
//! write.

use super::UriError;
use base64::Engine;

/// The media type the glTF 2.0 specification registers for a GLB.
const GLB_DATA_URI_PREFIX: &str = "data:model/gltf-binary;base64,";

/// The bytes of `uri` if it is a data URI; `None` for any other URI (a file, relative to the
/// document that names it).
pub fn decode(uri: &str) -> Option<Result<Vec<u8>, UriError>> {
    let rest = uri.strip_prefix("data:")?;
    Some((|| {
        // The media type holds no comma (RFC 2397 escapes one in a parameter), so the first
        // comma ends it.
        let (header, payload) = rest.split_once(',').ok_or(UriError::DataNoComma)?;
        if !header.ends_with(";base64") {
            return Err(UriError::DataNotBase64);
        }
        base64::engine::general_purpose::STANDARD
            .decode(payload)
            .map_err(|source| UriError::BadBase64 { source })
    })())
}

/// The data URI of a GLB: its media type and its bytes in base64.
pub fn encode_glb(glb: &[u8]) -> String {
    let mut uri = String::from(GLB_DATA_URI_PREFIX);
    base64::engine::general_purpose::STANDARD.encode_string(glb, &mut uri);
    uri
}

/// How listings name a tile's content `uri`: the URI itself, or `tileset.json (inlined)` for a
/// data URI (which is the whole GLB).
pub fn content_label(uri: &str) -> &str {
    if uri.starts_with("data:") {
        "tileset.json (inlined)"
    } else {
        uri
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_glb_data_uri_reads_back() {
        let bytes: Vec<u8> = (0..=255).collect();
        let uri = encode_glb(&bytes);
        assert!(uri.starts_with("data:model/gltf-binary;base64,"));
        assert_eq!(decode(&uri).unwrap().unwrap(), bytes);
        assert!(decode("tiles/r.glb").is_none());
        assert_eq!(content_label(&uri), "tileset.json (inlined)");
        assert_eq!(content_label("tiles/r.glb"), "tiles/r.glb");
        assert!(matches!(
            decode("data:text/plain,hello"),
            Some(Err(UriError::DataNotBase64))
        ));
        assert!(matches!(
            decode("data:;base64"),
            Some(Err(UriError::DataNoComma))
        ));
        assert!(matches!(
            decode("data:;base64,@@"),
            Some(Err(UriError::BadBase64 { .. }))
        ));
    }

    #[test]
    fn any_media_type_and_parameters_decode() {
        let ok = decode("data:application/octet-stream;base64,AAEC").unwrap();
        assert_eq!(ok.unwrap(), vec![0, 1, 2]);
        let ok = decode("data:application/gltf-buffer;name=b0;base64,AAEC").unwrap();
        assert_eq!(ok.unwrap(), vec![0, 1, 2]);
        assert_eq!(decode("data:;base64,").unwrap().unwrap(), Vec::<u8>::new());
        // `;base64` belongs before the first comma; one later is data.
        assert!(matches!(
            decode("data:text/plain,abc;base64,AAAA"),
            Some(Err(UriError::DataNotBase64))
        ));
    }

    #[test]
    fn bad_base64_keeps_its_cause() {
        let e = decode("data:application/octet-stream;base64,@@@")
            .unwrap()
            .unwrap_err();
        assert!(matches!(e, UriError::BadBase64 { .. }), "{e}");
        assert!(std::error::Error::source(&e).is_some());
        let line = crate::error::chain_text(&e);
        assert!(line.starts_with("bad base64 in data URI: "), "{line}");
    }
}
