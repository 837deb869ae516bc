//! Spatial partition of the scene into tiles (paper IV.A). The partition is a plan made from bounds
//! and counts only, before any heavy work, so later stages can run per tile; [`content`] gathers
//! a planned tile's geometry, which simplification, textures and the encoder all read.

pub mod content;
pub mod octree;

pub use octree::{plan_octree, ContentItem, OctreeOptions, PlannedTile, TilePlan, TriRef};
