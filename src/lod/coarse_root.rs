//! A coarse root for compact models (the paper's HLOD, III.C(3), for a model the tile
//! budgets keep to one tile). Such a model is one tile at full detail, drawn whole at any
//! distance: a textured building sends every texel of its photographs before its first frame,
//! while a viewer that frames it accepts far less. When that tile is heavy, the HLOD builder
//! makes a root above it aimed at the error a viewer framing the model accepts
//! ([`hlod::allowed_errors_m`]), and the full-detail tile becomes its only child.
//!
//! The root declares at least that error, also when no simplification meets it and the root keeps
//! every triangle: its texture levels follow its error (texels no larger than it), so the first
//! view of a photo-textured model is its geometry with coarse textures. It stays honest: the
//! declared error bounds the distance to full detail, which is then below it. The root is kept
//! only when it saves the first view more bytes than a sequential request is worth (the request
//! that a viewer zooming in then pays), as the schema's and the atlas's placements weigh requests
//! against bytes; that is decided before it is written, from the written tile and the encoded
//! texture levels, so nothing is left to remove.

use super::hlod::{self, BuiltSubtree, HlodBuilder};
use crate::encode::TileRecord;
use crate::error::Result;
use crate::options::{LodMode, Settings};
use crate::partition::content::TileContent;
use crate::partition::{PlannedTile, TilePlan};
use crate::scene::Scene;
use crate::texture::single_use::fetched_bytes;
use crate::texture::{TextureLevels, TileTextures};
use crate::transfer::SEQUENTIAL_REQUEST_WORTH_BYTES;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::sync::Mutex;

/// A one-tile model is considered for a coarse root when a client fetches at least this much for
/// its tile (GLB and texture files): a root can then save a request's worth
/// ([`SEQUENTIAL_REQUEST_WORTH_BYTES`]) by keeping half of it.
pub const COARSE_ROOT_MIN_FETCHED_BYTES: u64 = 2 * SEQUENTIAL_REQUEST_WORTH_BYTES as u64;

/// Writes a tile of a plan: encodes its content and returns its record with the written file.
pub(crate) type WritePlannedTile<'a> =
    dyn Fn(&PlannedTile, &TileContent, TileRecord) -> Result<TileRecord> + Sync + 'a;

/// What a coarse root is made from: the build's scene, plan, options, output folder and texture
/// levels, and how a tile is written.
pub(crate) struct RootInputs<'a> {
    pub scene: &'a Scene,
    pub plan: &'a TilePlan,
    pub opts: &'a Settings,
    pub dir: &'a Path,
    pub textures: &'a TextureLevels<'a>,
    pub write_tile: &'a WritePlannedTile<'a>,
}

/// The plan and records with a coarse root above the one tile of `records` (`full`: what
/// building that tile handed up), when the plan is one tile with HLOD and the root pays for
/// itself (module docs); `None` otherwise.
pub(crate) fn coarse_root(
    inputs: &RootInputs,
    records: &[TileRecord],
    full: BuiltSubtree,
) -> Result<Option<(TilePlan, Vec<TileRecord>)>> {
    if inputs.opts.lod != LodMode::Hlod || !inputs.opts.coarse_root {
        return Ok(None);
    }
    let (Some(plan), [leaf]) = (inputs.plan.under_coarse_root(), records) else {
        return Ok(None);
    };
    let Some(uri) = &leaf.uri else {
        return Ok(None);
    };
    let leaf_fetched = fetched_bytes(inputs.dir, uri)?;
    if leaf_fetched < COARSE_ROOT_MIN_FETCHED_BYTES {
        return Ok(None);
    }
    let leaf_textures = texture_bytes(
        inputs.textures,
        &inputs.textures.for_tile(&full.content, 0.0),
    );
    let leaf_geometry = leaf_fetched.saturating_sub(leaf_textures);
    let leaf_triangles = full.content.triangle_count().max(1);
    let allowed_m = hlod::allowed_errors_m(&plan, inputs.opts);
    let aim_m = allowed_m[0].unwrap_or(0.0);
    let write = |i: usize, content: &TileContent, mut record: TileRecord| {
        record.geometric_error_m = record.geometric_error_m.max(aim_m);
        let textures = texture_bytes(
            inputs.textures,
            &inputs.textures.for_tile(content, record.geometric_error_m),
        );
        // The geometry's share of the written tile, scaled by the triangles kept.
        let geometry = leaf_geometry * content.triangle_count() as u64 / leaf_triangles as u64;
        if leaf_fetched.saturating_sub(geometry + textures) < SEQUENTIAL_REQUEST_WORTH_BYTES as u64
        {
            return Ok(record);
        }
        (inputs.write_tile)(&plan.tiles[i], content, record)
    };
    let slots: Vec<Mutex<Option<TileRecord>>> = plan.tiles.iter().map(|_| None.into()).collect();
    let builder = HlodBuilder {
        scene: inputs.scene,
        plan: &plan,
        opts: inputs.opts,
        write: &write,
        slots: &slots,
        stop: &BTreeSet::from([1]),
        provided: Mutex::new(BTreeMap::from([(1, full)])),
        allowed_m,
        cache: None,
        leaf_file: None,
        retable: None,
    };
    builder.build(0)?;
    drop(builder);
    let root = slots
        .into_iter()
        .next()
        .and_then(|slot| slot.into_inner().expect("no poisoned slot"));
    // Declined, or simplified to nothing: the model stays one tile.
    let Some(mut root) = root.filter(|r| r.uri.is_some()) else {
        return Ok(None);
    };
    root.path = plan.tiles[0].path.clone();
    let leaf = TileRecord {
        depth: 1,
        ..leaf.clone()
    };
    Ok(Some((plan, vec![root, leaf])))
}

/// Bytes a tile fetches for the images of `chosen` at their levels.
fn texture_bytes(textures: &TextureLevels, chosen: &TileTextures) -> u64 {
    (chosen.0.iter())
        .map(|(&id, &level)| textures.shipped_bytes(id, level) as u64)
        .sum()
}
