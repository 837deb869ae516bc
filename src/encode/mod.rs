//! Encoders: tile content as glTF binary (GLB), geometry compressed with Draco or meshoptimizer.

/// Draco lives below the readers (they decode compressed glTF with it); re-exported here, where
/// tiles are encoded with it.
pub use crate::draco;
pub mod edges;
pub mod glb;
pub mod meshopt;
pub mod metadata;
pub mod record;

pub use glb::{encode_content, encode_tile, Compression, EncodedTile, TableMaker, TileEncoding};
pub use record::{ContentFigures, TileRecord};

/// Why a tile could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    #[error("Draco compression")]
    Draco(#[from] draco::DracoError),
    #[error("meshopt compression")]
    Meshopt(#[from] meshopt::MeshoptEncodeError),
    /// The tile's image (texture level) could not be written.
    #[error("tile image")]
    Image(#[from] crate::texture::external::StoreError),
    #[error("an instance transform is not translation-rotation-scale")]
    InstanceTransform,
    #[error("glTF JSON")]
    Json(#[from] serde_json::Error),
}
