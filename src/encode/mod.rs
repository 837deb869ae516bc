//! Encoders: tile content as glTF binary (GLB), geometry compressed with Draco.

pub mod draco;
pub mod glb;
pub mod metadata;

pub use glb::{encode_content, encode_tile, Compression, EncodedTile, TableMaker, TileEncoding};
