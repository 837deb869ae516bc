//! What a client pays to fetch a tileset: the exchange rate between requests and bytes that every
//! choice between one shared file and copies in the tiles uses (the metadata schema's placement,
//! texture files, a coarse root above a one-tile model; README, "First view: round trips").

/// What a sequential request costs, in bytes that could be sent instead: one round trip on the
/// link the browser benchmark throttles to (README, "First view"): 20 Mbit/s x 40 ms = 100 KB.
pub const SEQUENTIAL_REQUEST_WORTH_BYTES: usize = 100_000;

/// Whether copying a file of `bytes` into each of the `users` tiles that reference it costs no
/// more than the request a shared file costs them: `(users - 1) x bytes` at most
/// [`SEQUENTIAL_REQUEST_WORTH_BYTES`] (one user: always, the same bytes and one request fewer).
pub fn copies_cost_less_than_a_request(users: u64, bytes: u64) -> bool {
    users.saturating_sub(1).saturating_mul(bytes) <= SEQUENTIAL_REQUEST_WORTH_BYTES as u64
}

#[cfg(test)]
mod tests {
    use super::*;

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
