//! HLOD content (paper III.C(3)): every internal tile carries its subtree merged and simplified
//! with our QEM, built bottom-up with children in parallel; its declared geometricError is
//! measured against the full detail it stands for (honest), held above its children's.

use super::gather;
use crate::encode::glb::DEFAULT_MAX_POSITION_ERROR_M;
use crate::encode::Compression;
use crate::encode::TileRecord;
use crate::error::{Error, Result};
use crate::options::{ConvertOptions, ErrorMetric};
use crate::partition::content::TileContent;
use crate::partition::TilePlan;
use crate::scene::{ComponentId, Scene};
use crate::simplify::hlod::{simplify_children, ErrorReference, HlodContent};
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

pub(crate) type WriteTile<'a> =
    dyn Fn(usize, &TileContent, TileRecord) -> Result<TileRecord> + Sync + 'a;

/// Builds HLOD content bottom-up, children in parallel; each tile is written as soon as it is made
/// and only its content travels up to its parent.
pub(crate) struct HlodBuilder<'a> {
    pub(crate) scene: &'a Scene,
    pub(crate) plan: &'a TilePlan,
    pub(crate) opts: &'a ConvertOptions,
    pub(crate) write: &'a WriteTile<'a>,
    pub(crate) slots: &'a [std::sync::Mutex<Option<TileRecord>>],
    /// Tiles not to build: their subtrees were built elsewhere (sharded jobs) and their roots'
    /// results are in `provided`.
    pub(crate) stop: &'a std::collections::BTreeSet<usize>,
    pub(crate) provided: std::sync::Mutex<BTreeMap<usize, BuiltSubtree>>,
}

impl HlodBuilder<'_> {
    /// The content of every leaf below tile `i` (the full detail it stands for).
    fn leaves_below(&self, i: usize) -> Vec<&[crate::partition::ContentItem]> {
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

    pub(crate) fn build(&self, i: usize) -> Result<BuiltSubtree> {
        let tile = &self.plan.tiles[i];
        let path = || format!("tiles/{}.glb", tile.path);
        if self.stop.contains(&i) {
            let done = self.provided.lock().expect("provided").remove(&i);
            return done.ok_or_else(|| Error::output(path(), "no job built this subtree"));
        }
        let built = if tile.children.is_empty() {
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
            let written = (self.write)(i, &content, TileRecord::default())?;
            *self.slots[i].lock().expect("slot") = Some(written);
            BuiltSubtree {
                // Parents simplify one surface: instances go up as plain geometry.
                content: content.expand(),
                geometric_error_m: 0.0,
                coarse_to_full_m: 0.0,
                max_folding_edge_m: 0.0,
                cut_triangles,
            }
        } else {
            let kids: Vec<BuiltSubtree> = tile
                .children
                .par_iter()
                .map(|&c| self.build(c))
                .collect::<Result<_>>()?;
            let mut cut_triangles: BTreeMap<ComponentId, usize> = BTreeMap::new();
            for k in &kids {
                for (&c, &n) in &k.cut_triangles {
                    *cut_triangles.entry(c).or_default() += n;
                }
            }
            let continuing = continuing(self.scene, &cut_triangles);
            let contents: Vec<&TileContent> = kids.iter().map(|k| &k.content).collect();
            let children: Vec<(&TileContent, f64)> = kids
                .iter()
                .map(|k| (&k.content, k.coarse_to_full_m))
                .collect();
            let leaves = self.leaves_below(i);
            // How coarse the tile may get: its framed error (what a viewer that sees all of it
            // accepts), a fraction of it for the margin between the view's box distance and the
            // bounding sphere. `None`: the budget alone.
            let allowed_m = (self.opts.hlod_error_fraction > 0.0).then(|| {
                self.opts.hlod_error_fraction
                    * framed_error_m(tile.bounds.diagonal() / 2.0, &ViewOptions::default())
            });
            let reference =
                ErrorReference::new(self.scene, tile.bounds.center(), &children, &leaves, 0);
            // A try over `limit_m` is given up as soon as its measurement shows it (`None`).
            let build_at = |from: &[&TileContent], target: usize, limit_m: f64| -> Result<_> {
                let r = simplify_children(
                    from,
                    tile.bounds.center(),
                    &continuing,
                    target,
                    &self.opts.simplify,
                )
                .map_err(|e| Error::simplify(path(), e))?;
                let err = reference.measure_within(&r.content, &self.opts.simplify, limit_m);
                Ok(err.map(|e| (r, e)))
            };
            let input_triangles: usize = contents.iter().map(|c| c.triangle_count()).sum();
            let mut target = self
                .opts
                .octree
                .max_tile_triangles
                .min(input_triangles.div_ceil(HLOD_CHILDREN_DIVISOR))
                .max(1);
            let (mut r, mut err) = build_at(&contents, target, f64::INFINITY)?.expect("no limit");
            // Coarser while the measured error leaves room: the first view of a model is its root
            // alone, as small as its error allows. Each try costs a simplification and a
            // measurement against all full detail below, so the count is predicted (the error of
            // a simplified surface grows about as 1/triangles; aim at 0.7 of the allowed error)
            // and the tries are few. A try simplifies the last accepted content, a quarter or less
            // of the children's (it is measured against full detail all the same): on a
            // 1.9M-triangle campus the tries took as long as the first simplifications.
            if let Some(allowed) = allowed_m {
                for _ in 0..HLOD_COARSEN_TRIES {
                    let predicted = target as f64 * err.error_m / (0.7 * allowed);
                    let next = (predicted as usize).clamp(target / 16, target / 2);
                    if err.error_m >= allowed || next < HLOD_MIN_TRIANGLES {
                        break;
                    }
                    let Some((r2, err2)) = build_at(&[&r.content], next, allowed)? else {
                        break;
                    };
                    (r, err, target) = (
                        // Figures of the whole chain: children -> last content -> this one.
                        HlodContent {
                            input_triangles: r.input_triangles,
                            max_collapsed_edge_m: r
                                .max_collapsed_edge_m
                                .max(r2.max_collapsed_edge_m),
                            content: r2.content,
                        },
                        err2,
                        next,
                    );
                }
            }
            // The measurement's reference (children's BVHs) and inputs are not needed to write.
            drop(reference);
            drop((contents, children, leaves));
            let (position_error, measured) = with_quantization(self.opts.compression, err.error_m);
            let children_max = kids.iter().map(|k| k.geometric_error_m).fold(0.0, f64::max);
            let folding = kids
                .iter()
                .map(|k| k.max_folding_edge_m)
                .fold(r.max_collapsed_edge_m, f64::max);
            // Strictly above the children's, whatever the sampling found.
            let (ge, paper) =
                declared_error(self.opts.error_metric, measured, folding, children_max);
            drop(kids);
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
            *self.slots[i].lock().expect("slot") = Some(written);
            BuiltSubtree {
                content: r.content,
                geometric_error_m: ge,
                coarse_to_full_m: err.coarse_to_full_m,
                max_folding_edge_m: folding,
                cut_triangles,
            }
        };
        Ok(built)
    }
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

/// Coarsening an HLOD tile below the budget stops at this many triangles.
pub const HLOD_MIN_TRIANGLES: usize = 500;

/// At most this many coarser tries per HLOD tile: each simplifies the tile again and measures it
/// against all the full detail below it (Mini_Project.glb converts in 2.6 s with the tries, 1.5 s
/// without).
pub const HLOD_COARSEN_TRIES: usize = 2;

/// Share of a simplified tile's measured error that Draco's position quantization may add on top
/// of it: a tile that stands for full detail within 0.2 m needs no millimetre grid. Its vertices
/// then cost fewer bits (Mini_Project's root, 37 m across: 15 -> 11 bits per coordinate); the
/// declared error includes the quantization, so it stays honest and grows by at most this share.
pub const COARSE_QUANTIZATION_SHARE: f64 = 0.1;

/// Quantization of a simplified tile whose content lies within `measured_m` of full detail:
/// `(per_axis_m, error_m)`, the largest per-axis position error it may add (1 mm, or with Draco a
/// share of the measured error when that is more; KHR_mesh_quantization keeps 16 bits whatever
/// the grid, so gains nothing from a coarser one) and the tile's error with it added (decoded
/// vertices move by up to √3 times the per-axis error).
pub(crate) fn with_quantization(c: Compression, measured_m: f64) -> (f64, f64) {
    let per_axis_m = match c {
        Compression::Draco => {
            DEFAULT_MAX_POSITION_ERROR_M.max(COARSE_QUANTIZATION_SHARE * measured_m / 3f64.sqrt())
        }
        Compression::Quantized => DEFAULT_MAX_POSITION_ERROR_M,
        Compression::None => 0.0,
    };
    (per_axis_m, measured_m + per_axis_m * 3f64.sqrt())
}
