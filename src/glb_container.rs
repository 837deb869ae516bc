//! The GLB container (glTF 2.0 §4.4, "Binary glTF Layout"): a 12-byte header, a JSON chunk
//! padded with spaces and a BIN chunk padded with zeros, each 4-byte aligned. Written by the
//! encoder; read back by the measurements of a written tileset (JSON chunk) and by an update that
//! replaces a tile's property table (both chunks). Below every stage.

use byteorder::{WriteBytesExt, LE};
use serde_json::Value;

/// Why a GLB's JSON chunk could not be read.
#[derive(Debug, thiserror::Error)]
pub enum GlbError {
    #[error("not a GLB (no glTF header)")]
    NotGlb,
    #[error("GLB shorter than its JSON chunk")]
    Short,
    #[error("invalid JSON chunk: {0}")]
    Json(#[from] serde_json::Error),
}

/// The GLB container: 12-byte header, JSON chunk (space-padded), BIN chunk (zero-padded).
pub fn glb_container(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let json_len = json.len() + pad(json.len());
    let bin_len = bin.len() + pad(bin.len());
    let total = 12 + 8 + json_len + if bin.is_empty() { 0 } else { 8 + bin_len };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.write_u32::<LE>(2).expect("vec write");
    out.write_u32::<LE>(total as u32).expect("vec write");
    out.write_u32::<LE>(json_len as u32).expect("vec write");
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()), b' ');
    if !bin.is_empty() {
        out.write_u32::<LE>(bin_len as u32).expect("vec write");
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin);
        out.resize(out.len() + pad(bin.len()), 0);
    }
    out
}

/// The JSON chunk (without its padding) and the BIN chunk (empty when there is none) of a GLB
/// whose header and chunk lengths agree with its size.
pub fn chunks(glb: &[u8]) -> Option<(&[u8], &[u8])> {
    let u32_at = |at: usize| -> Option<usize> {
        Some(u32::from_le_bytes(glb.get(at..at + 4)?.try_into().ok()?) as usize)
    };
    if glb.get(0..4)? != b"glTF" || u32_at(4)? != 2 || u32_at(8)? != glb.len() {
        return None;
    }
    let json_len = u32_at(12)?;
    if glb.get(16..20)? != b"JSON" {
        return None;
    }
    let json = glb.get(20..20 + json_len)?;
    let json = &json[..json.len() - json.iter().rev().take_while(|&&c| c == b' ').count()];
    let rest = 20 + json_len;
    if rest == glb.len() {
        return Some((json, &[]));
    }
    let bin_len = u32_at(rest)?;
    if glb.get(rest + 4..rest + 8)? != b"BIN\0" || rest + 8 + bin_len != glb.len() {
        return None;
    }
    Some((json, &glb[rest + 8..]))
}

/// The JSON chunk of a GLB, parsed.
pub fn json_chunk(glb: &[u8]) -> Result<Value, GlbError> {
    if glb.len() < 20 || &glb[0..4] != b"glTF" {
        return Err(GlbError::NotGlb);
    }
    let n = u32::from_le_bytes(glb[12..16].try_into().expect("4 bytes")) as usize;
    Ok(serde_json::from_slice(
        glb.get(20..20 + n).ok_or(GlbError::Short)?,
    )?)
}

/// The URIs a GLB's JSON (`json_chunk`) names outside the GLB: images and buffers with a `uri`,
/// and `EXT_structural_metadata`'s `schemaUri`. A GLB without any reads without its folder.
pub fn external_uris(json: &Value) -> Vec<String> {
    let mut uris: Vec<String> = ["images", "buffers"]
        .iter()
        .flat_map(|k| json[*k].as_array().into_iter().flatten())
        .filter_map(|item| item["uri"].as_str().map(str::to_string))
        .collect();
    let schema = json.pointer("/extensions/EXT_structural_metadata/schemaUri");
    uris.extend(schema.and_then(Value::as_str).map(str::to_string));
    uris
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_read_back_what_the_container_holds() {
        let g = glb_container(br#"{"a":1}"#, &[1, 2, 3]);
        assert_eq!(chunks(&g), Some((&br#"{"a":1}"#[..], &[1, 2, 3, 0][..])));
        let bare = glb_container(b"{}", &[]);
        assert_eq!(chunks(&bare), Some((&b"{}"[..], &[][..])));
        assert_eq!(chunks(&g[..g.len() - 4]), None);
        assert_eq!(chunks(b"glTF"), None);
    }

    #[test]
    fn container_is_aligned() {
        let g = glb_container(b"{}", &[1, 2, 3]);
        assert_eq!(g.len() % 4, 0);
        assert_eq!(
            u32::from_le_bytes(g[8..12].try_into().unwrap()) as usize,
            g.len()
        );
    }

    #[test]
    fn json_chunk_reads_back() {
        let g = glb_container(br#"{"asset":{"version":"2.0"}}"#, &[]);
        assert_eq!(json_chunk(&g).unwrap()["asset"]["version"], "2.0");
        assert!(matches!(json_chunk(b"nope"), Err(GlbError::NotGlb)));
    }

    #[test]
    fn external_uris_lists_what_a_glb_reads_beside_it() {
        let json = br#"{"images":[{"uri":"../textures/a.png"},{"bufferView":0}],
            "buffers":[{"byteLength":4}],
            "extensions":{"EXT_structural_metadata":{"schemaUri":"../schema.json"}}}"#;
        let g = glb_container(json, &[0; 4]);
        assert_eq!(
            external_uris(&json_chunk(&g).unwrap()),
            ["../textures/a.png", "../schema.json"]
        );
        let alone = glb_container(br#"{"images":[{"bufferView":0}]}"#, &[0; 4]);
        assert!(external_uris(&json_chunk(&alone).unwrap()).is_empty());
    }
}
