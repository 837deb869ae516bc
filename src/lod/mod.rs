//! The LOD stage (paper III.C): the levels of detail a tile plan gets, made bottom-up and handed
//! to a writer tile by tile.
//! - [`hlod_content`]: a tile's children merged and simplified with our QEM, the error measured;
//! - [`hlod`]: the HLOD builder, with the ladder of errors between levels, the coarser and finer
//!   tries, and the position grid of simplified content;
//! - [`hlod_update`] and [`subtree_cache`]: an update builds only what changed, and takes the
//!   rest from the tile cache ([`wire`]: the encoding of what it keeps);
//! - [`coarse_root`]: a simplified root above a model the budgets keep to one heavy tile;
//! - [`chain_levels`] and [`chains`]: the paper's discrete LOD chains (`--lod-ratios`);
//! - [`clock`]: the seconds each part of the HLOD stage took (report.json).
//!
//! The stage makes content and records; encoding and writing stay with the caller, which passes
//! a [`hlod::WriteTile`].

pub mod chain_levels;
pub mod chains;
pub mod clock;
pub mod coarse_root;
pub mod hlod;
pub mod hlod_content;
pub(crate) mod hlod_update;
pub(crate) mod subtree_cache;
pub(crate) mod wire;

use crate::options::Settings;
use crate::partition::content::TileContent;
use crate::partition::ContentItem;
use crate::scene::Scene;
use glam::DVec3;

/// A tile's content as the options want it written: instanced or plain.
pub(crate) fn gather(
    scene: &Scene,
    opts: &Settings,
    items: &[ContentItem],
    center: DVec3,
) -> TileContent {
    if opts.instancing {
        TileContent::gather_instanced(scene, items, center, opts.min_instanced_triangles_saved)
    } else {
        TileContent::gather(scene, items, center)
    }
}
