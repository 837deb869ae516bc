//! Discrete LOD chains (paper III.C and Table IV: the original model as LOD0 and QEM
//! simplifications as LOD1..LOD3, `--lod-ratios 0.85,0.7,0.5`), as 3D Tiles: every leaf of the
//! octree becomes a chain of tiles with the same bounds, coarsest first, each child replacing its
//! parent (`refine: "REPLACE"`), full detail last.
//!
//! Each chain level is simplified from the leaf's full detail by our QEM to its ratio of the full
//! triangle count ([`simplify_children`] with the leaf alone as child, so the borders of components
//! cut across tiles stay locked and neighbouring chains meet without cracks at any levels), and
//! its error is measured against that full detail by the same code as HLOD tiles ([`ErrorReference`]).
//! Internal octree tiles carry no content.

use super::hlod_content::{simplify_children, ErrorReference, TileError};
use crate::partition::content::TileContent;
use crate::partition::{PlannedTile, TilePlan};
use crate::scene::{ComponentId, Scene};
use crate::simplify::{SimplifyError, SimplifyOptions};

/// Area-weighted samples of a leaf's full detail when measuring a chain level's error (as many as
/// the independent checker of `tests/hlod.rs` takes; a leaf's own triangle count can be too few
/// samples to find the largest distance: docs/benchmarks.md).
pub const CHAIN_LEAF_SAMPLES: usize = 20_000;

/// Unusable LOD-chain ratios (an options error: the user's `--lod-ratios`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RatiosError {
    #[error("give at least one ratio")]
    Empty,
    #[error("every ratio must be in (0, 1), got {ratio}")]
    OutOfRange { ratio: f32 },
    #[error("ratios must be distinct")]
    Repeated,
}

/// The chain levels, finest first, from the user's ratios: each in (0, 1), distinct; sorted
/// decreasing (LOD1 is the largest ratio).
pub fn chain_ratios(ratios: &[f32]) -> Result<Vec<f32>, RatiosError> {
    if ratios.is_empty() {
        return Err(RatiosError::Empty);
    }
    let mut r = ratios.to_vec();
    if let Some(&ratio) = r.iter().find(|x| !(**x > 0.0 && **x < 1.0)) {
        return Err(RatiosError::OutOfRange { ratio });
    }
    r.sort_by(|a, b| b.total_cmp(a));
    if r.windows(2).any(|w| w[0] == w[1]) {
        return Err(RatiosError::Repeated);
    }
    Ok(r)
}

/// A plan whose leaves with content became chains of `levels + 1` tiles.
#[derive(Debug, Clone)]
pub struct ChainPlan {
    pub plan: TilePlan,
    /// Per tile of `plan`: its LOD in the chain (0 = full detail, k = the k-th ratio, finest
    /// first), `None` for the (empty) internal tiles.
    pub level: Vec<Option<usize>>,
}

/// Turns every leaf with content of `plan` (built with all content in leaves) into a chain: the
/// coarsest level (`<path>-lod<levels>`) takes the leaf's place in the tree, each level has the
/// next finer one as only child, and the full-detail tile keeps the leaf's path.
pub fn with_lod_chains(plan: &TilePlan, levels: usize) -> ChainPlan {
    fn visit(old: &[PlannedTile], i: usize, depth: u32, levels: usize, out: &mut ChainPlan) {
        let t = &old[i];
        let me = out.plan.tiles.len();
        let chain = t.children.is_empty() && !t.content.is_empty();
        let n = if chain { levels } else { 0 };
        for k in (1..=n).rev() {
            let at = out.plan.tiles.len();
            out.plan.tiles.push(PlannedTile {
                path: format!("{}-lod{k}", t.path),
                depth: depth + (n - k) as u32,
                children: vec![at + 1],
                omitted_size_m: 0.0,
                ..t.clone()
            });
            out.level.push(Some(k));
        }
        let own = out.plan.tiles.len();
        out.plan.tiles.push(PlannedTile {
            depth: depth + n as u32,
            children: Vec::new(),
            ..t.clone()
        });
        out.level.push(chain.then_some(0));
        for &c in &t.children {
            let ci = out.plan.tiles.len();
            out.plan.tiles[own].children.push(ci);
            visit(old, c, depth + 1, levels, out);
        }
        debug_assert!(me <= own);
    }
    let mut out = ChainPlan {
        plan: TilePlan::default(),
        level: Vec::new(),
    };
    if !plan.tiles.is_empty() {
        visit(&plan.tiles, 0, 0, levels, &mut out);
    }
    out
}

/// One simplified level of a chain.
#[derive(Debug, Clone)]
pub struct ChainLevel {
    pub content: TileContent,
    /// Its error against the full detail.
    pub error: TileError,
    /// Longest edge the simplifier collapsed for it (metres).
    pub max_collapsed_edge_m: f64,
}

/// The simplified levels of one leaf, finest first: `full` (its full detail, plain geometry) taken
/// to `ratio * full triangles` for each of `ratios`. `tile` is the leaf (for the full detail's
/// items), `continuing` its components that go on in other tiles (sorted; their borders are locked).
pub fn chain_levels(
    scene: &Scene,
    tile: &PlannedTile,
    full: &TileContent,
    continuing: &[ComponentId],
    ratios: &[f32],
    opts: &SimplifyOptions,
) -> Result<Vec<ChainLevel>, SimplifyError> {
    let n = full.triangle_count();
    let leaves = [&tile.content[..]];
    let reference = ErrorReference::new(
        scene,
        full.center,
        &[(full, 0.0)],
        &leaves,
        CHAIN_LEAF_SAMPLES,
    );
    ratios
        .iter()
        .map(|&r| {
            let o = SimplifyOptions {
                target_ratio: r,
                ..opts.clone()
            };
            let target = (r as f64 * n as f64).round() as usize;
            let s = simplify_children(&[full], full.center, continuing, target, &o)?;
            let error = reference.measure(&s.content, opts);
            Ok(ChainLevel {
                content: s.content,
                error,
                max_collapsed_edge_m: s.max_collapsed_edge_m,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Aabb;

    fn leaf(path: &str, depth: u32, content: bool) -> PlannedTile {
        PlannedTile {
            path: path.into(),
            depth,
            cell: Aabb::EMPTY,
            content: if content {
                vec![crate::partition::ContentItem {
                    component: ComponentId(0),
                    triangles: None,
                }]
            } else {
                Vec::new()
            },
            children: Vec::new(),
            content_bounds: Aabb::EMPTY,
            bounds: Aabb::EMPTY,
            content_triangles: 0,
            omitted_size_m: 0.0,
        }
    }

    #[test]
    fn ratios_are_checked_and_sorted() {
        assert_eq!(
            chain_ratios(&[0.5, 0.85, 0.7]).unwrap(),
            vec![0.85, 0.7, 0.5]
        );
        assert_eq!(chain_ratios(&[]), Err(RatiosError::Empty));
        assert_eq!(
            chain_ratios(&[0.5, 1.0]),
            Err(RatiosError::OutOfRange { ratio: 1.0 })
        );
        assert_eq!(
            chain_ratios(&[0.0]),
            Err(RatiosError::OutOfRange { ratio: 0.0 })
        );
        assert_eq!(chain_ratios(&[0.5, 0.5]), Err(RatiosError::Repeated));
        assert!(matches!(
            chain_ratios(&[f32::NAN]),
            Err(RatiosError::OutOfRange { ratio }) if ratio.is_nan()
        ));
    }

    #[test]
    fn leaves_become_chains_in_pre_order() {
        // root -> (a: leaf with content, b: empty leaf)
        let mut root = leaf("r", 0, false);
        root.children = vec![1, 2];
        let plan = TilePlan {
            tiles: vec![root, leaf("r0", 1, true), leaf("r1", 1, false)],
        };
        let c = with_lod_chains(&plan, 2);
        let paths: Vec<&str> = c.plan.tiles.iter().map(|t| t.path.as_str()).collect();
        assert_eq!(paths, ["r", "r0-lod2", "r0-lod1", "r0", "r1"]);
        assert_eq!(c.level, [None, Some(2), Some(1), Some(0), None]);
        let kids: Vec<&[usize]> = c.plan.tiles.iter().map(|t| &t.children[..]).collect();
        assert_eq!(kids, [&[1, 4][..], &[2], &[3], &[], &[]]);
        let depths: Vec<u32> = c.plan.tiles.iter().map(|t| t.depth).collect();
        assert_eq!(depths, [0, 1, 2, 3, 1]);
        // Same content everywhere along the chain.
        assert!(c.plan.tiles[1..4].iter().all(|t| t.content.len() == 1));
    }
}
