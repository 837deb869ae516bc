//! bimtiles: building models (glTF/GLB, IFC) to OGC 3D Tiles 1.1.
//!
//! The pipeline follows the modules in order, data flowing one way:
//! `ingest` (readers) → `scene` (the model) → `dedup` (repeated shapes shared, duplicates
//! aliased) → `partition` (octree plan) → `tile_content` (a tile's merged geometry) →
//! `simplify` (QEM, HLOD) → `texture` (redundant textures removed, Haar pyramid level per tile)
//! → `encode` (GLB) → `tileset` (tileset.json, georeferencing);
//! `convert` runs it end to end, `inspect` reads a
//! result back and `serve` shows it in a local CesiumJS viewer.

pub mod convert;
pub mod dedup;
pub mod encode;
pub mod error;
pub mod ingest;
pub mod inspect;
pub mod memory;
pub mod partition;
pub mod scene;
pub mod serve;
pub mod shard;
pub mod simplify;
pub mod texture;
pub mod tile_content;
pub mod tileset;

pub use error::{Error, Result};
