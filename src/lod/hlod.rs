//! HLOD content (paper III.C(3)): every internal tile carries its subtree merged and simplified
//! with our QEM, built bottom-up with children in parallel; its declared geometricError is
//! measured against the full detail it stands for (honest), and at least twice its children's.
//!
//! The ladder of levels: a tile's error is kept near its framed error (what a viewer whose screen
//! it fills accepts), which halves from a cell to its children: coarser tries while the measured
//! error is well under it, and finer ones (up to the tile budget) while it is over it (a sparse
//! scene's simplification drops whole buildings hundreds of metres from anything kept). Declaring
//! at least [`1 / LADDER_CHILD_RATIO`](LADDER_CHILD_RATIO) times the children's error keeps every
//! step between levels at least a factor of two, so that a client switches levels at distances at
//! least twice apart; with the octree's extent rule (`partition::octree`) the step to full detail
//! is bounded too.

use super::gather;
use super::hlod_content::{simplify_children, ErrorReference, HlodContent, TileError};
use super::subtree_cache::SubtreeCache;
use crate::encode::glb::{grid_flattens, DEFAULT_MAX_POSITION_ERROR_M};
use crate::encode::Compression;
use crate::encode::TileRecord;
use crate::error::{Error, Result};
use crate::options::{ErrorMetric, Settings};
use crate::partition::content::TileContent;
use crate::partition::TilePlan;
use crate::scene::{ComponentId, Scene};
use crate::tileset::view::{
    framed_error_m, paper_geometric_error_m, ViewOptions, PAPER_MAX_DELTA_PX,
};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// What a subtree gives its parent when building HLOD bottom-up.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct BuiltSubtree {
    /// What the tile draws (full detail for leaves, simplified above).
    pub content: TileContent,
    pub geometric_error_m: f64,
    /// Bound of the distance from `content` to full detail (0 for leaves).
    pub coarse_to_full_m: f64,
    /// Longest edge collapsed between full detail and `content` (0 for leaves).
    pub max_folding_edge_m: f64,
    /// Triangles per cut component in the subtree (only components cut across tiles).
    pub cut_triangles: BTreeMap<ComponentId, usize>,
}

/// How an internal tile's hand-over was made, to make it again without measuring
/// ([`HlodBuilder::replay`]): the simplifications in turn, each to a triangle count, from the
/// children's content (`true`) or from the step before; the grid whose flattened triangles were
/// then dropped; and the figures it handed up.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Recipe {
    pub steps: Vec<(bool, usize)>,
    pub flattened_grid_m: Option<f64>,
    pub geometric_error_m: f64,
    pub coarse_to_full_m: f64,
    pub max_folding_edge_m: f64,
}

pub(crate) type WriteTile<'a> =
    dyn Fn(usize, &TileContent, TileRecord) -> Result<TileRecord> + Sync + 'a;

/// What a leaf's file holds beside its content's geometry and materials (its features' metadata
/// as written), as bytes a key can cover: an update takes the leaf's file whole when they and its
/// geometry are what they were.
pub(crate) type LeafFile<'a> = dyn Fn(&TileContent) -> Vec<u8> + Sync + 'a;

/// Writes tile `i`'s file again from its live `file`, with the property table of `features` (its
/// rows) in place of its own, and returns its `record` with the new file's figures; `None` when
/// `file` is not laid out as the encoder writes one.
pub(crate) type Retable<'a> =
    dyn Fn(usize, &[u8], &[ComponentId], TileRecord) -> Result<Option<TileRecord>> + Sync + 'a;

/// Builds HLOD content bottom-up, children in parallel; each tile is written as soon as it is made
/// and only its content travels up to its parent.
pub(crate) struct HlodBuilder<'a> {
    pub(crate) scene: &'a Scene,
    pub(crate) plan: &'a TilePlan,
    pub(crate) opts: &'a Settings,
    pub(crate) write: &'a WriteTile<'a>,
    pub(crate) slots: &'a [std::sync::Mutex<Option<TileRecord>>],
    /// Tiles not to build: their subtrees were built elsewhere (sharded jobs) and their roots'
    /// results are in `provided`.
    pub(crate) stop: &'a std::collections::BTreeSet<usize>,
    pub(crate) provided: std::sync::Mutex<BTreeMap<usize, BuiltSubtree>>,
    /// Per plan tile, the error its content is aimed at ([`allowed_errors_m`]).
    pub(crate) allowed_m: Vec<Option<f64>>,
    /// The update's tile cache: tiles whose subtree did not change are taken from it.
    pub(crate) cache: Option<&'a SubtreeCache>,
    /// With a cache: what leaves' files hold beside their geometry.
    pub(crate) leaf_file: Option<&'a LeafFile<'a>>,
    /// With a cache: how a tile whose elements' metadata alone changed is written again.
    pub(crate) retable: Option<&'a Retable<'a>>,
}

/// The error each tile of `plan` is allowed (`None` for all when `--hlod-error-fraction` is 0):
/// `hlod_error_fraction` of its framed error (what a viewer whose screen the tile fills accepts,
/// with a margin between the view's box distance and the bounding sphere), and at most
/// [`LADDER_CHILD_RATIO`] of its parent's allowed error, so that tiles that meet theirs form the
/// ladder without their parents declaring more than they measured. Top-down, from the plan only:
/// every job of a sharded build finds the same.
pub(crate) fn allowed_errors_m(plan: &TilePlan, opts: &Settings) -> Vec<Option<f64>> {
    let mut allowed = vec![None; plan.tiles.len()];
    if opts.hlod_error_fraction <= 0.0 || plan.tiles.is_empty() {
        return allowed;
    }
    let own = |i: usize| {
        opts.hlod_error_fraction
            * framed_error_m(
                plan.tiles[i].bounds.diagonal() / 2.0,
                &ViewOptions::default(),
            )
    };
    allowed[0] = Some(own(0));
    // Pre-order: a parent comes before its children.
    for i in 0..plan.tiles.len() {
        let cap = allowed[i].map(|a: f64| a * LADDER_CHILD_RATIO);
        for &c in &plan.tiles[i].children {
            allowed[c] = Some(own(c).min(cap.unwrap_or(f64::INFINITY)));
        }
    }
    allowed
}

impl HlodBuilder<'_> {
    /// The content of every leaf below tile `i` (the full detail it stands for).
    pub(super) fn leaves_below(&self, i: usize) -> Vec<&[crate::partition::ContentItem]> {
        let mut out = Vec::new();
        let mut stack = vec![i];
        while let Some(j) = stack.pop() {
            let t = &self.plan.tiles[j];
            if t.children.is_empty() {
                out.push(&t.content[..]);
            }
            stack.extend(t.children.iter().rev());
        }
        out
    }

    /// A leaf's content at full detail, as it is written, and the triangles of its cut
    /// components.
    pub(super) fn leaf_content(&self, i: usize) -> (TileContent, BTreeMap<ComponentId, usize>) {
        let tile = &self.plan.tiles[i];
        let content = gather(
            self.scene,
            self.opts,
            &tile.content,
            tile.content_bounds.center(),
        );
        let mut cut_triangles = BTreeMap::new();
        for item in &tile.content {
            if let Some(t) = &item.triangles {
                *cut_triangles.entry(item.component).or_default() += t.len();
            }
        }
        (content, cut_triangles)
    }

    /// What leaf `i` hands its parent.
    pub(super) fn leaf_handover(&self, i: usize) -> BuiltSubtree {
        let (content, cut_triangles) = self.leaf_content(i);
        leaf_built(content, cut_triangles)
    }

    /// A leaf: its content at full detail, written as it is; what it hands up.
    fn build_leaf(&self, i: usize) -> Result<BuiltSubtree> {
        let (content, cut_triangles) = self.leaf_content(i);
        let written = (self.write)(i, &content, TileRecord::default())?;
        *self.slots[i].lock().expect("slot") = Some(written);
        Ok(leaf_built(content, cut_triangles))
    }

    /// The position grid (metres per axis) of a simplified tile's content, which it may thin. The
    /// coarse grid flattens some thin triangles, and a flat triangle draws nothing: the tile is
    /// then farther from full detail than it declares (docs/benchmarks.md). The ones the
    /// compression's grid flattens are dropped and the rest measured again, kept if that costs no
    /// more than the grid's share; otherwise a grid [`GRID_FALLBACK_STEP`] times finer is tried, a
    /// few times, before the grid stays finer than the thinnest triangle.
    fn fit_grid(
        &self,
        reference: &ErrorReference,
        content: &mut TileContent,
        err: &mut TileError,
    ) -> (f64, Option<f64>) {
        let fine_m = fine_grid_m(self.opts.compression);
        let mut per_axis_m = coarse_grid_m(self.opts.compression, err.error_m);
        // A measurement over the limit stops as soon as it shows it.
        let limit_m = err.error_m * (1.0 + COARSE_QUANTIZATION_SHARE);
        for _ in 0..GRID_TRIES {
            if per_axis_m <= fine_m {
                return (fine_m, None);
            }
            let Some(kept) = without_flattened(self.opts.compression, content, per_axis_m) else {
                return (per_axis_m, None);
            };
            if let Some(kept_err) = reference.measure_within(&kept, &self.opts.simplify, limit_m) {
                (*content, *err) = (kept, kept_err);
                return (per_axis_m, Some(per_axis_m));
            }
            per_axis_m /= GRID_FALLBACK_STEP;
        }
        let per_axis_m = with_quantization(self.opts.compression, err.error_m, content).0;
        (per_axis_m, None)
    }

    /// The children's content `from` of internal tile `i` simplified to `target` triangles, the
    /// components of `continuing` locked.
    fn simplify_to(
        &self,
        i: usize,
        from: &[&TileContent],
        target: usize,
        continuing: &[ComponentId],
        keep_apart_m: Option<f64>,
    ) -> Result<HlodContent> {
        let tile = &self.plan.tiles[i];
        let input: usize = from.iter().map(|c| c.triangle_count()).sum();
        let simplify_opts = crate::simplify::SimplifyOptions {
            // Finer tries may keep more than the simplifier's default share of the input.
            target_ratio: match 2 * target > input {
                true => 1.0,
                false => self.opts.simplify.target_ratio,
            },
            // A group of parts standing farther apart than the tile's aim would miss it alone.
            keep_parts_apart_m: keep_apart_m,
            ..self.opts.simplify.clone()
        };
        simplify_children(
            from,
            tile.bounds.center(),
            continuing,
            target,
            &simplify_opts,
        )
        .map_err(|e| Error::simplify(format!("tiles/{}.glb", tile.path), e))
    }

    /// What internal tile `i` handed up when it was built as `recipe` says, made again from its
    /// children's hand-overs `kids` (simplified, not measured).
    pub(super) fn replay(
        &self,
        i: usize,
        kids: Vec<BuiltSubtree>,
        recipe: &Recipe,
    ) -> Result<BuiltSubtree> {
        let cut_triangles = cut_triangles(kids.iter().map(|k| &k.cut_triangles));
        let continuing = continuing(self.scene, &cut_triangles);
        let contents: Vec<&TileContent> = kids.iter().map(|k| &k.content).collect();
        let keep_m = self.keep_apart_m(&kids, self.aim_m(i, &kids));
        let mut made: Option<TileContent> = None;
        for &(from_children, target) in &recipe.steps {
            let r = match &made {
                Some(last) if !from_children => {
                    self.simplify_to(i, &[last], target, &continuing, keep_m)?
                }
                _ => self.simplify_to(i, &contents, target, &continuing, keep_m)?,
            };
            made = Some(r.content);
        }
        let mut content = made.unwrap_or_default();
        if let Some(per_axis_m) = recipe.flattened_grid_m {
            if let Some(kept) = without_flattened(self.opts.compression, &content, per_axis_m) {
                content = kept;
            }
        }
        Ok(BuiltSubtree {
            content,
            geometric_error_m: recipe.geometric_error_m,
            coarse_to_full_m: recipe.coarse_to_full_m,
            max_folding_edge_m: recipe.max_folding_edge_m,
            cut_triangles,
        })
    }

    /// The error internal tile `i` aims at (`None`: the budget alone): its allowed error
    /// ([`allowed_errors_m`]), and at least twice its children's (the ladder: finer content buys
    /// nothing but bytes in the first view).
    fn aim_m(&self, i: usize, kids: &[BuiltSubtree]) -> Option<f64> {
        let children_max = kids.iter().map(|k| k.geometric_error_m).fold(0.0, f64::max);
        let allowed = self.allowed_m.get(i).copied().flatten()?;
        Some(allowed.max(children_max / LADDER_CHILD_RATIO))
    }

    /// The distance beyond which the simplifier keeps a group of parts standing apart
    /// ([`crate::simplify::SimplifyOptions::keep_parts_apart_m`]): the tile's aim, when its first
    /// try is under the triangle budget. A tile at its budget has its error set by the budget, far
    /// above its aim: there the aim tells nothing of which parts matter, and parts kept there cost
    /// the budget other content needs.
    fn keep_apart_m(&self, kids: &[BuiltSubtree], aim_m: Option<f64>) -> Option<f64> {
        let input: usize = kids.iter().map(|k| k.content.triangle_count()).sum();
        let under_budget =
            input.div_ceil(HLOD_CHILDREN_DIVISOR) < self.opts.octree.max_tile_triangles;
        aim_m.filter(|_| under_budget)
    }

    /// Builds the subtree of tile `i`; what it hands up (`None`: with a tile cache, when
    /// nothing above needs it).
    pub(crate) fn build(&self, i: usize) -> Result<Option<BuiltSubtree>> {
        if self.stop.contains(&i) {
            // Built before (convert builds its whole tree, then merges it): what it handed up, if
            // anything above needs it.
            return Ok(self.provided.lock().expect("provided").remove(&i));
        }
        match self.cache {
            Some(cache) => self.build_updated(cache, i),
            _ => self.build_all(i).map(Some),
        }
    }

    /// Builds every tile of the subtree of tile `i` but those of `stop`.
    fn build_all(&self, i: usize) -> Result<BuiltSubtree> {
        let tile = &self.plan.tiles[i];
        if self.stop.contains(&i) {
            let done = self.provided.lock().expect("provided").remove(&i);
            return done.ok_or_else(|| {
                Error::output(
                    format!("tiles/{}.glb", tile.path),
                    "no job built this subtree",
                )
            });
        }
        if tile.children.is_empty() {
            return self.build_leaf(i);
        }
        let kids: Vec<BuiltSubtree> = tile
            .children
            .par_iter()
            .map(|&c| self.build_all(c))
            .collect::<Result<_>>()?;
        let (built, record, _) = self.build_internal(i, kids)?;
        *self.slots[i].lock().expect("slot") = Some(record);
        Ok(built)
    }

    /// An internal tile: its children's content simplified and measured, written; what it hands
    /// up, the record of what it wrote, and how to make its hand-over again.
    pub(super) fn build_internal(
        &self,
        i: usize,
        kids: Vec<BuiltSubtree>,
    ) -> Result<(BuiltSubtree, TileRecord, Recipe)> {
        let tile = &self.plan.tiles[i];
        let cut_triangles = cut_triangles(kids.iter().map(|k| &k.cut_triangles));
        let continuing = &continuing(self.scene, &cut_triangles);
        {
            let contents: Vec<&TileContent> = kids.iter().map(|k| &k.content).collect();
            let children: Vec<(&TileContent, f64)> = kids
                .iter()
                .map(|k| (&k.content, k.coarse_to_full_m))
                .collect();
            let leaves = self.leaves_below(i);
            // How coarse the tile may get (`None`: the budget alone).
            let aim_m = self.aim_m(i, &kids);
            let keep_m = self.keep_apart_m(&kids, aim_m);
            let reference =
                ErrorReference::new(self.scene, tile.bounds.center(), &children, &leaves, 0);
            let simplify_at = |from: &[&TileContent], target: usize| {
                self.simplify_to(i, from, target, continuing, keep_m)
            };
            // The children simplified to the first finer try's count, made before the first try
            // (see below) and taken by the finer try if it comes.
            let prepared: std::sync::Mutex<Option<(usize, HlodContent)>> = Default::default();
            let build_at = |from: &[&TileContent], target: usize, limit_m: f64| -> Result<_> {
                let made = prepared.lock().expect("prepared").take_if(|(t, _)| {
                    *t == target && std::ptr::eq(from.as_ptr(), contents.as_ptr())
                });
                let r = match made {
                    Some((_, r)) => r,
                    None => simplify_at(from, target)?,
                };
                let err = reference.measure_within(&r.content, &self.opts.simplify, limit_m);
                Ok(err.map(|e| (r, e)))
            };
            let input_triangles: usize = contents.iter().map(|c| c.triangle_count()).sum();
            let target = self
                .opts
                .octree
                .max_tile_triangles
                .min(input_triangles.div_ceil(HLOD_CHILDREN_DIVISOR))
                .max(1);
            let most = self.opts.octree.max_tile_triangles.min(input_triangles);
            // Most tiles need the first finer try (twice the triangles) too: the children are
            // simplified once, to that count, and the first try is simplified from it (a quarter
            // of the children or less to simplify, not all of them again).
            let mut tried = if aim_m.is_some() && 2 * target <= most {
                let (first, finer) = first_through_finer(&simplify_at, &contents, target)?;
                *prepared.lock().expect("prepared") = Some((2 * target, finer));
                let err = reference
                    .measure_within(&first.content, &self.opts.simplify, f64::INFINITY)
                    .expect("no limit");
                (first, err, vec![(true, 2 * target), (false, target)])
            } else {
                let (r, err) = build_at(&contents, target, f64::INFINITY)?.expect("no limit");
                (r, err, vec![(true, target)])
            };
            let children_max = kids.iter().map(|k| k.geometric_error_m).fold(0.0, f64::max);
            if let Some(aim_m) = aim_m {
                tried = refine(&build_at, &contents, most, aim_m, tried)?;
                drop(prepared.lock().expect("prepared").take());
                tried = coarsen(&build_at, aim_m, tried)?;
            }
            let (mut r, mut err, steps) = tried;
            let (per_axis_m, flattened) = self.fit_grid(&reference, &mut r.content, &mut err);
            err.coarse_to_full_m = reference.exact_coarse_to_full_m(&r.content);
            let (position_error, measured) = (per_axis_m, err.error_m + per_axis_m * 3f64.sqrt());
            // The measurement's reference (children's BVHs) and inputs are not needed to write.
            drop(reference);
            drop((contents, children, leaves));
            let folding = kids
                .iter()
                .map(|k| k.max_folding_edge_m)
                .fold(r.max_collapsed_edge_m, f64::max);
            // At least twice the children's (the ladder), whatever the sampling found.
            let (mut ge, paper) = declared_error(
                self.opts.error_metric,
                measured,
                folding,
                children_max / LADDER_CHILD_RATIO,
            );
            drop(kids);
            // Content that draws nothing is not written: the tile stands for everything below it
            // missing, at most its box's diagonal away from anything drawn.
            let empty = r.content.triangle_count() == 0;
            let (built, record) = if empty {
                ge = tile
                    .bounds
                    .diagonal()
                    .max(children_max / LADDER_CHILD_RATIO * (1.0 + 1e-6) + 1e-6);
                let record = TileRecord {
                    geometric_error_m: ge,
                    ..Default::default()
                };
                let built = BuiltSubtree {
                    content: r.content,
                    geometric_error_m: ge,
                    coarse_to_full_m: tile.bounds.diagonal(),
                    max_folding_edge_m: folding,
                    cut_triangles,
                };
                (built, record)
            } else {
                let record = TileRecord {
                    geometric_error_m: ge,
                    simplified_from_triangles: Some(r.input_triangles),
                    full_to_coarse_m: Some(err.full_to_coarse_m),
                    coarse_to_full_bound_m: Some(err.coarse_to_full_m),
                    measured_error_m: Some(measured),
                    max_folding_edge_m: Some(folding),
                    paper_error_m: Some(paper),
                    max_position_error_m: Some(position_error),
                    ..Default::default()
                };
                let written = (self.write)(i, &r.content, record)?;
                let built = BuiltSubtree {
                    content: r.content,
                    geometric_error_m: ge,
                    coarse_to_full_m: err.coarse_to_full_m,
                    max_folding_edge_m: folding,
                    cut_triangles,
                };
                (built, written)
            };
            let recipe = Recipe {
                steps,
                flattened_grid_m: flattened,
                geometric_error_m: built.geometric_error_m,
                coarse_to_full_m: built.coarse_to_full_m,
                max_folding_edge_m: built.max_folding_edge_m,
            };
            Ok((built, record, recipe))
        }
    }
}

/// The first try at an HLOD tile (`target` triangles) simplified from the children's content
/// simplified to twice that, which is returned too (the first finer try's content), with the
/// figures of the whole chain.
fn first_through_finer(
    simplify_at: &dyn Fn(&[&TileContent], usize) -> Result<HlodContent>,
    contents: &[&TileContent],
    target: usize,
) -> Result<(HlodContent, HlodContent)> {
    let finer = simplify_at(contents, 2 * target)?;
    let first = simplify_at(&[&finer.content], target)?;
    let first = HlodContent {
        input_triangles: finer.input_triangles,
        max_collapsed_edge_m: first.max_collapsed_edge_m.max(finer.max_collapsed_edge_m),
        content: first.content,
    };
    Ok((first, finer))
}

/// One try at an HLOD tile: its content simplified from `from` to a triangle target, with its
/// error measured (`None`: over the limit, given up as soon as the measurement showed it).
type BuildAt<'a> =
    dyn Fn(&[&TileContent], usize, f64) -> Result<Option<(HlodContent, TileError)>> + Sync + 'a;

/// A try's content, measured error and how it was made ([`Recipe::steps`]; the last count is its
/// triangle target).
type Tried = (HlodContent, TileError, Vec<(bool, usize)>);

fn target_of(steps: &[(bool, usize)]) -> usize {
    steps.last().map_or(0, |&(_, target)| target)
}

/// Finer while over the `allowed` error: twice the triangles of the last try, up to `most` (the
/// budget, or all of the children's, which then stand as they are), so the tries span the four
/// times between a first try (a quarter of the children's) and all of them. Doubling, not the
/// 1/triangles prediction [`coarsen`] uses: a building's error falls much faster than that as its
/// small elements come back, and the prediction jumped past the count that met the error to every
/// triangle, a root no coarser than its child. Each try starts again from the children (the first
/// was made before the first try, which is simplified from it), and is kept when it meets the
/// allowed error or at least halves the error so far ([`REFINE_MIN_GAIN`]): halving buys the parent
/// a rung (it declares at least twice its children's error), while a finer tile that gains less
/// costs its bytes in every view for nothing. The tries' effect on measured models:
/// docs/benchmarks.md.
fn refine(
    build_at: &BuildAt,
    contents: &[&TileContent],
    most: usize,
    allowed: f64,
    (mut r, mut err, mut steps): Tried,
) -> Result<Tried> {
    let mut tried = target_of(&steps);
    for _ in 0..HLOD_REFINE_TRIES {
        if err.error_m <= allowed || tried >= most {
            break;
        }
        let next = (2 * tried).min(most);
        tried = next;
        if let Some(met) = build_at(contents, next, allowed.max(err.error_m * REFINE_MIN_GAIN))? {
            (r, err) = met;
            steps = vec![(true, next)];
        }
    }
    Ok((r, err, steps))
}

/// Coarser while the measured error leaves room under `allowed`: the first view of a model is its
/// root alone, as small as its error allows. Each try costs a simplification and a measurement
/// against all full detail below, so the count is predicted (the error of a simplified surface
/// grows about as 1/triangles; aim at 0.7 of the allowed error) and the tries are few. A try
/// simplifies the last accepted content, a quarter or less of the children's (it is measured
/// against full detail all the same): simplifying the children again each time costs as much as the
/// first simplifications. A rejected try is followed by one between it and the last accepted count
/// (their geometric mean), once: the halving steps otherwise leave a tile up to twice the triangles
/// its error allows, and a finer tile below can move the steps.
fn coarsen(build_at: &BuildAt, allowed: f64, (mut r, mut err, mut steps): Tried) -> Result<Tried> {
    let mut tries = 0;
    let mut target = target_of(&steps);
    let mut too_coarse: Option<usize> = None;
    while tries < HLOD_COARSEN_TRIES || too_coarse.is_some() {
        let next = match too_coarse {
            Some(rejected) => {
                ((target as f64 * rejected as f64).sqrt() as usize).max(HLOD_MIN_TRIANGLES)
            }
            None => {
                let predicted = target as f64 * err.error_m / (0.7 * allowed);
                (predicted as usize).clamp(target / 16, target / 2)
            }
        };
        if err.error_m >= allowed || next < HLOD_MIN_TRIANGLES || next >= target {
            break;
        }
        tries += 1;
        let Some((r2, err2)) = build_at(&[&r.content], next, allowed)? else {
            if too_coarse.is_some() {
                break;
            }
            too_coarse = Some(next);
            continue;
        };
        too_coarse = None;
        (r, err, target) = (
            // Figures of the whole chain: children -> last content -> this one.
            HlodContent {
                input_triangles: r.input_triangles,
                max_collapsed_edge_m: r.max_collapsed_edge_m.max(r2.max_collapsed_edge_m),
                content: r2.content,
            },
            err2,
            next,
        );
        steps.push((false, next));
    }
    Ok((r, err, steps))
}

/// What a leaf with `content` hands its parent.
pub(super) fn leaf_built(
    content: TileContent,
    cut_triangles: BTreeMap<ComponentId, usize>,
) -> BuiltSubtree {
    BuiltSubtree {
        // Parents simplify one surface: instances go up as plain geometry.
        content: content.expand(),
        geometric_error_m: 0.0,
        coarse_to_full_m: 0.0,
        max_folding_edge_m: 0.0,
        cut_triangles,
    }
}

/// Triangles per cut component of a tile, from its children's.
pub(super) fn cut_triangles<'a>(
    kids: impl Iterator<Item = &'a BTreeMap<ComponentId, usize>>,
) -> BTreeMap<ComponentId, usize> {
    let mut sum: BTreeMap<ComponentId, usize> = BTreeMap::new();
    for k in kids {
        for (&c, &n) in k {
            *sum.entry(c).or_default() += n;
        }
    }
    sum
}

/// Components of `cut_triangles` (triangles per component cut across tiles, in a subtree) that go
/// on outside the subtree: their open borders stay locked (no cracks). Sorted.
pub(crate) fn continuing(
    scene: &Scene,
    cut_triangles: &BTreeMap<ComponentId, usize>,
) -> Vec<ComponentId> {
    cut_triangles
        .iter()
        .filter(|&(&c, &n)| n < scene.meshes.triangle_count(scene.component(c).mesh))
        .map(|(&c, _)| c)
        .collect()
}

/// The geometricError a simplified tile declares under `metric`, from its measured error and its
/// longest folding edge, held strictly above its children's (3D Tiles); also the paper's value.
pub(crate) fn declared_error(
    metric: ErrorMetric,
    measured_m: f64,
    folding_edge_m: f64,
    children_max_m: f64,
) -> (f64, f64) {
    let paper_m =
        paper_geometric_error_m(folding_edge_m, &ViewOptions::default(), PAPER_MAX_DELTA_PX);
    let base = match metric {
        ErrorMetric::Measured => measured_m,
        ErrorMetric::PaperSse => paper_m,
    };
    (base.max(children_max_m * (1.0 + 1e-6) + 1e-6), paper_m)
}

/// An HLOD tile keeps at most this fraction (1/n) of what its children draw, and the tile budget:
/// about one child's worth in an octree, so every level costs about the same to draw.
pub const HLOD_CHILDREN_DIVISOR: usize = 4;

/// A child's declared geometricError is at most this share of its parent's (the ladder: the
/// parent declares at least its children's error divided by this).
pub const LADDER_CHILD_RATIO: f64 = 0.5;

/// A finer try that misses its allowed error is kept when its error is at most this share of the
/// error so far ([`refine`]).
pub const REFINE_MIN_GAIN: f64 = 0.5;

/// At most this many finer tries per HLOD tile whose error is over its allowed error (each
/// simplifies the children again, to more triangles, and measures against full detail).
pub const HLOD_REFINE_TRIES: usize = 2;

/// Coarsening an HLOD tile below the budget stops at this many triangles.
pub const HLOD_MIN_TRIANGLES: usize = 500;

/// At most this many coarser tries per HLOD tile: each simplifies the tile again and measures it
/// against all the full detail below it, so the tries can take most of a conversion's time
/// (docs/benchmarks.md).
pub const HLOD_COARSEN_TRIES: usize = 2;

/// Share of a simplified tile's measured error that position quantization may add on top of it: a
/// tile that stands for full detail within 0.2 m needs no millimetre grid. Its vertices then cost
/// fewer bits (fewer bits per coordinate for Draco, fewer distinct values for meshopt's codec); the
/// declared error includes the quantization, so it stays honest and grows by at most this share.
pub const COARSE_QUANTIZATION_SHARE: f64 = 0.1;

/// Grids a simplified tile tries, each [`GRID_FALLBACK_STEP`] times finer than the last, before
/// its grid is kept finer than its thinnest triangle: a sparse model's root can flatten
/// triangles that matter on the grid of its error's share and not on one 16 times finer. Five
/// reach the finest grid from the share of an error of metres (256 times finer): one sliver of a
/// whole element would otherwise put a large root on the finest grid when a grid of a few
/// millimetres keeps it.
const GRID_TRIES: usize = 5;
const GRID_FALLBACK_STEP: f64 = 4.0;

/// Quantization of a simplified tile whose content lies within `measured_m` of full detail:
/// `(per_axis_m, error_m)`, the largest per-axis position error it may add and the tile's error
/// with it added (decoded vertices move by up to √3 times the per-axis error). The grid is
/// [`coarse_grid_m`]'s, kept below the `content`'s thinnest triangle (a triangle the grid
/// flattens draws nothing, and the full detail it stood for is then farther than the moved
/// vertices: vertices move by at most √3 times the per-axis error, so a triangle at least twice
/// that high keeps an area). HLOD tiles first try dropping such triangles and measuring again.
pub(crate) fn with_quantization(
    c: Compression,
    measured_m: f64,
    content: &TileContent,
) -> (f64, f64) {
    let keeps_every_triangle_m = thinnest_triangle_m(content) / (2.0 * 3f64.sqrt());
    let per_axis_m = coarse_grid_m(c, measured_m)
        .min(keeps_every_triangle_m)
        .max(fine_grid_m(c));
    (per_axis_m, measured_m + per_axis_m * 3f64.sqrt())
}

/// The finest grid of `c`: 1 mm per axis, none without compression.
fn fine_grid_m(c: Compression) -> f64 {
    match c {
        Compression::Draco | Compression::Quantized | Compression::Meshopt => {
            DEFAULT_MAX_POSITION_ERROR_M
        }
        Compression::None => 0.0,
    }
}

/// The per-axis position error a simplified tile measured within `measured_m` of full detail
/// may add: a share of the measured error, at least 1 mm; none without compression.
pub(crate) fn coarse_grid_m(c: Compression, measured_m: f64) -> f64 {
    match c {
        Compression::None => fine_grid_m(c),
        _ => DEFAULT_MAX_POSITION_ERROR_M.max(COARSE_QUANTIZATION_SHARE * measured_m / 3f64.sqrt()),
    }
}

/// `content` without the triangles the grid of `c` for `per_axis_m` flattens
/// ([`grid_flattens`]), or `None` when it flattens none.
fn without_flattened(
    c: Compression,
    content: &TileContent,
    per_axis_m: f64,
) -> Option<TileContent> {
    let flat = grid_flattens(c, &content.primitives, per_axis_m);
    if !flat.iter().flatten().any(|&f| f) {
        return None;
    }
    let mut kept = content.clone();
    for (p, flat) in kept.primitives.iter_mut().zip(&flat) {
        let indices: Vec<u32> = p
            .indices
            .chunks_exact(3)
            .zip(flat)
            .filter(|(_, &f)| !f)
            .flat_map(|(t, _)| t.iter().copied())
            .collect();
        p.indices = indices;
    }
    kept.primitives.retain(|p| !p.indices.is_empty());
    kept.compact_features();
    Some(kept)
}

/// The smallest height of a triangle of `content` (twice its area over its longest edge;
/// triangles already flat are left out: they draw nothing before quantization either).
fn thinnest_triangle_m(content: &TileContent) -> f64 {
    let mut thinnest = f64::INFINITY;
    for p in &content.primitives {
        let at = |i: u32| {
            let v = p.positions[i as usize];
            glam::DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)
        };
        for t in p.indices.chunks_exact(3) {
            let [a, b, c] = [at(t[0]), at(t[1]), at(t[2])];
            let twice_area = (b - a).cross(c - a).length();
            let longest = (b - a).length().max((c - b).length()).max((a - c).length());
            if twice_area > 0.0 && longest > 0.0 {
                thinnest = thinnest.min(twice_area / longest);
            }
        }
    }
    thinnest
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A try at `target` triangles with a steep error curve, as a BIM model's (small elements come
    /// back), over `limit_m` given up as the real measurement does.
    fn steep(
        _: &[&TileContent],
        target: usize,
        limit_m: f64,
    ) -> Result<Option<(HlodContent, TileError)>> {
        let error_m = match target {
            t if t >= 28_916 => 0.0001,
            t if t >= 14_000 => 0.03,
            t if t >= 10_000 => 0.07,
            _ => 0.63,
        };
        let content = HlodContent {
            content: TileContent::default(),
            input_triangles: 28_916,
            max_collapsed_edge_m: 0.0,
        };
        let err = TileError {
            error_m,
            full_to_coarse_m: error_m,
            coarse_to_full_m: error_m,
        };
        Ok((error_m <= limit_m).then_some((content, err)))
    }

    #[test]
    fn finer_tries_double_and_stop_at_the_first_count_that_meets_the_error() {
        let (r, err) = steep(&[], 7_229, f64::INFINITY).unwrap().unwrap();
        let (_, err, steps) =
            refine(&steep, &[], 28_916, 0.2, (r, err, vec![(true, 7_229)])).unwrap();
        // Not every triangle (the 1/triangles prediction asked for 32k): a root that keeps them
        // all is no coarser than the tile below it.
        assert_eq!(steps, [(true, 14_458)]);
        assert!(err.error_m <= 0.2);
    }

    #[test]
    fn a_finer_try_is_kept_only_while_it_halves_the_error() {
        let (r, err) = steep(&[], 7_229, f64::INFINITY).unwrap().unwrap();
        // An allowance only every triangle meets, and a budget of 20k: 14.5k halves the error
        // (0.63 -> 0.03 m) and is kept; 20k gains nothing more and is not.
        let (_, err, steps) =
            refine(&steep, &[], 20_000, 0.01, (r, err, vec![(true, 7_229)])).unwrap();
        assert_eq!(steps, [(true, 14_458)]);
        assert!((err.error_m - 0.03).abs() < 1e-12);
    }
}
