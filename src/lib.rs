//! bimtiles: building models (glTF/GLB, IFC) to OGC 3D Tiles 1.1.
//!
//! The pipeline follows the modules in order, data flowing one way:
//! `ingest` (readers) → `scene` (the model) → `partition` (octree plan) → `encode` (GLB) →
//! `tileset` (tileset.json, georeferencing); `convert` runs it end to end and `inspect` reads a
//! result back.

pub mod convert;
pub mod encode;
pub mod error;
pub mod ingest;
pub mod inspect;
pub mod partition;
pub mod scene;
pub mod tileset;

pub use error::{Error, Result};
