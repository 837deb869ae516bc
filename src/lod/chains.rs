//! The paper's discrete LOD chains (III.C, Table IV; `--lod-ratios`): every leaf becomes a chain
//! of tiles with its bounds, coarsest first, full detail last.

use super::chain_levels::chain_levels;
use super::gather;
use super::hlod::{continuing, declared_error, with_quantization, WriteTile};
use crate::encode::TileRecord;
use crate::error::{Error, Result};
use crate::options::Settings;
use crate::partition::TilePlan;
use crate::scene::Scene;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Discrete LOD chains: each chain (found at its full-detail tile, level 0) is built and written
/// at once, chains in parallel; then the empty internal tiles get their size-bound error, bottom
/// up, strictly above their children's.
pub(crate) fn build_chains(
    scene: &Scene,
    plan: &TilePlan,
    chain_level: &[Option<usize>],
    ratios: &[f32],
    opts: &Settings,
    write: &WriteTile<'_>,
) -> Result<Vec<(usize, TileRecord)>> {
    let n = ratios.len();
    let fulls: Vec<usize> = (0..plan.tiles.len())
        .filter(|&i| chain_level[i] == Some(0))
        .collect();
    let built: Vec<Vec<(usize, TileRecord)>> = fulls
        .par_iter()
        .map(|&i| -> Result<Vec<(usize, TileRecord)>> {
            let tile = &plan.tiles[i];
            let center = tile.content_bounds.center();
            let content = gather(scene, opts, &tile.content, center);
            let mut out = vec![(i, write(i, &content, TileRecord::default())?)];
            let full = content.expand();
            let mut cut = BTreeMap::new();
            for item in &tile.content {
                if let Some(t) = &item.triangles {
                    *cut.entry(item.component).or_default() += t.len();
                }
            }
            let levels = chain_levels(
                scene,
                tile,
                &full,
                &continuing(scene, &cut),
                ratios,
                &opts.simplify,
            )
            .map_err(|e| Error::simplify(format!("tiles/{}.glb", tile.path), e))?;
            // Finest first: chain tile i - k holds level k.
            let mut below = 0.0;
            for (k, l) in levels.iter().enumerate() {
                let (position_error, measured) =
                    with_quantization(opts.compression, l.error.error_m, &l.content);
                let (ge, paper) =
                    declared_error(opts.error_metric, measured, l.max_collapsed_edge_m, below);
                below = ge;
                let record = TileRecord {
                    geometric_error_m: ge,
                    simplified_from_triangles: Some(full.triangle_count()),
                    full_to_coarse_m: Some(l.error.full_to_coarse_m),
                    coarse_to_full_bound_m: Some(l.error.coarse_to_full_m),
                    measured_error_m: Some(measured),
                    max_folding_edge_m: Some(l.max_collapsed_edge_m),
                    paper_error_m: Some(paper),
                    max_position_error_m: Some(position_error),
                    ..Default::default()
                };
                let at = i - (k + 1);
                debug_assert_eq!(chain_level[at], Some(k + 1));
                out.push((at, write(at, &l.content, record)?));
            }
            debug_assert_eq!(levels.len(), n);
            Ok(out)
        })
        .collect::<Result<_>>()?;
    let mut slots: Vec<Option<TileRecord>> = vec![None; plan.tiles.len()];
    for (i, record) in built.into_iter().flatten() {
        slots[i] = Some(record);
    }
    // Internal tiles (pre-order: children after parents).
    for i in (0..plan.tiles.len()).rev() {
        if slots[i].is_some() {
            continue;
        }
        let t = &plan.tiles[i];
        let children_max = t
            .children
            .iter()
            .filter_map(|&c| slots[c].as_ref().map(|s| s.geometric_error_m))
            .fold(0.0, f64::max);
        let ge = if t.children.is_empty() {
            0.0
        } else {
            t.bounds.diagonal().max(children_max * (1.0 + 1e-6) + 1e-6)
        };
        slots[i] = Some(TileRecord::with_error(ge));
    }
    Ok(slots
        .into_iter()
        .enumerate()
        .map(|(i, s)| (i, s.expect("every tile built")))
        .collect())
}
