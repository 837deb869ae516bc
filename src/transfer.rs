//! What a client pays to fetch a tileset: the exchange rate between requests and bytes that every
//! choice between one shared file and copies in the tiles uses (the metadata schema's placement,
//! texture files, a coarse root above a one-tile model, the root's content inlined in tileset.json;
//! README, "First view: round trips"), and the data URIs (RFC 2397) inlined content travels in.

/// What a sequential request costs, in bytes that could be sent instead: one round trip on the
/// link the browser benchmark throttles to (README, "First view"): 20 Mbit/s x 40 ms = 100 KB.
pub const SEQUENTIAL_REQUEST_WORTH_BYTES: usize = 100_000;

/// Whether copying a file of `bytes` into each of the `users` tiles that reference it costs no
/// more than the request a shared file costs them: `(users - 1) x bytes` at most
/// [`SEQUENTIAL_REQUEST_WORTH_BYTES`] (one user: always, the same bytes and one request fewer).
pub fn copies_cost_less_than_a_request(users: u64, bytes: u64) -> bool {
    users.saturating_sub(1).saturating_mul(bytes) <= SEQUENTIAL_REQUEST_WORTH_BYTES as u64
}

/// Bytes a file grows by as base64 (RFC 4648: 4 characters per 3 bytes, the last group padded):
/// what inlining it in tileset.json as a data URI adds where the server does not compress JSON.
pub fn base64_growth_bytes(bytes: u64) -> u64 {
    bytes.div_ceil(3) * 4 - bytes
}

/// Whether a file of `bytes` inlined as a base64 data URI costs no more than the request it
/// saves: its growth at most [`SEQUENTIAL_REQUEST_WORTH_BYTES`].
pub fn inlining_costs_less_than_a_request(bytes: u64) -> bool {
    base64_growth_bytes(bytes) <= SEQUENTIAL_REQUEST_WORTH_BYTES as u64
}

/// The data URI (RFC 2397) of a GLB: its media type and its bytes in base64.
pub fn glb_data_uri(glb: &[u8]) -> String {
    use base64::Engine;
    let mut uri = String::from(GLB_DATA_URI_PREFIX);
    base64::engine::general_purpose::STANDARD.encode_string(glb, &mut uri);
    uri
}

const GLB_DATA_URI_PREFIX: &str = "data:model/gltf-binary;base64,";

/// How listings name a tile's content `uri`: the URI itself, or `tileset.json (inlined)` for a
/// data URI (which is the whole GLB).
pub fn content_label(uri: &str) -> &str {
    if uri.starts_with("data:") {
        "tileset.json (inlined)"
    } else {
        uri
    }
}

/// Why a data URI could not be read.
#[derive(Debug, thiserror::Error)]
pub enum DataUriError {
    #[error("a data URI without a comma")]
    NoComma,
    #[error("a data URI that is not base64 (only base64 content is read)")]
    NotBase64,
    #[error("invalid base64 in a data URI: {0}")]
    Base64(#[from] base64::DecodeError),
}

/// The bytes of a content URI that is a data URI (RFC 2397, base64 form); `None` for any other
/// URI (a file, relative to the tileset).
pub fn data_uri_bytes(uri: &str) -> Option<Result<Vec<u8>, DataUriError>> {
    use base64::Engine;
    let rest = uri.strip_prefix("data:")?;
    Some((|| {
        let (header, payload) = rest.split_once(',').ok_or(DataUriError::NoComma)?;
        if !header.ends_with(";base64") {
            return Err(DataUriError::NotBase64);
        }
        Ok(base64::engine::general_purpose::STANDARD.decode(payload)?)
    })())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inlining_pays_off_while_base64_grows_less_than_a_request() {
        assert_eq!(base64_growth_bytes(0), 0);
        assert_eq!(base64_growth_bytes(1), 3);
        assert_eq!(base64_growth_bytes(3), 1);
        assert_eq!(base64_growth_bytes(300), 100);
        let worth = SEQUENTIAL_REQUEST_WORTH_BYTES as u64;
        assert!(inlining_costs_less_than_a_request(3 * worth));
        assert!(!inlining_costs_less_than_a_request(3 * worth + 3));
    }

    #[test]
    fn a_glb_data_uri_reads_back() {
        let bytes: Vec<u8> = (0..=255).collect();
        let uri = glb_data_uri(&bytes);
        assert!(uri.starts_with("data:model/gltf-binary;base64,"));
        assert_eq!(data_uri_bytes(&uri).unwrap().unwrap(), bytes);
        assert!(data_uri_bytes("tiles/r.glb").is_none());
        assert_eq!(content_label(&uri), "tileset.json (inlined)");
        assert_eq!(content_label("tiles/r.glb"), "tiles/r.glb");
        assert!(matches!(
            data_uri_bytes("data:text/plain,hello"),
            Some(Err(DataUriError::NotBase64))
        ));
        assert!(matches!(
            data_uri_bytes("data:;base64"),
            Some(Err(DataUriError::NoComma))
        ));
        assert!(matches!(
            data_uri_bytes("data:;base64,@@"),
            Some(Err(DataUriError::Base64(_)))
        ));
    }

    #[test]
    fn copies_pay_off_up_to_a_request() {
        let worth = SEQUENTIAL_REQUEST_WORTH_BYTES as u64;
        assert!(copies_cost_less_than_a_request(1, u64::MAX));
        assert!(copies_cost_less_than_a_request(0, 1));
        assert!(copies_cost_less_than_a_request(3, worth / 2));
        assert!(!copies_cost_less_than_a_request(3, worth / 2 + 1));
        assert!(!copies_cost_less_than_a_request(u64::MAX, 2));
    }
}
