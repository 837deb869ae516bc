//! Encoders: tile content as glTF binary (GLB).

pub mod glb;

pub use glb::{encode_tile, EncodedTile};
