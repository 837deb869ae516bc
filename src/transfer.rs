//! What a client pays to fetch a tileset: the exchange rate between requests and bytes that every
//! choice between one shared file and copies in the tiles uses (the metadata schema's placement,
//! texture files, a coarse root above a one-tile model, the root's content inlined in tileset.json;
//! book: design/first-view.md). The data URIs (RFC 2397) inlined content travels in are
//! [`crate::uri::data`]'s.

/// What a sequential request costs, in bytes that could be sent instead: one round trip on the
/// link the browser benchmark throttles to (book: design/first-view.md): 20 Mbit/s x 40 ms = 100
/// KB.
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
    fn copies_pay_off_up_to_a_request() {
        let worth = SEQUENTIAL_REQUEST_WORTH_BYTES as u64;
        assert!(copies_cost_less_than_a_request(1, u64::MAX));
        assert!(copies_cost_less_than_a_request(0, 1));
        assert!(copies_cost_less_than_a_request(3, worth / 2));
        assert!(!copies_cost_less_than_a_request(3, worth / 2 + 1));
        assert!(!copies_cost_less_than_a_request(u64::MAX, 2));
    }
}
