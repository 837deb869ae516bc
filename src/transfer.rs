//! What a client pays to fetch a tileset: the exchange rate between requests and bytes that every
//! choice between one shared file and copies in the tiles uses (the metadata schema's placement,
//! texture files, a coarse root above a one-tile model; README, "First view: round trips").

/// What a sequential request costs, in bytes that could be sent instead: one round trip on the
/// link the browser benchmark throttles to (README, "First view"): 20 Mbit/s x 40 ms = 100 KB.
pub const SEQUENTIAL_REQUEST_WORTH_BYTES: usize = 100_000;
