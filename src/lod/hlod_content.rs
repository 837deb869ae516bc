//! HLOD content of an internal tile (paper III.C(3), Fig. 6): the merged content of its children,
//! simplified with our QEM to the tile budget.
//!
//! Built bottom-up: a tile simplifies what its children draw (full detail at the leaves, their own
//! simplified content above), so every level costs about one pass over the model. Identity
//! survives: the simplifier's vertex groups are (material, feature) pairs, so no collapse joins two
//! components or two materials, and every output triangle still names its component. Parts of a
//! component that was cut across tiles keep their open-border vertices *locked* when the component
//! continues outside this tile's subtree: the neighbouring tile at the same level keeps the very
//! same border vertices, so the seam stays closed at every level (no cracks). Inside the subtree
//! the parts are welded back together by the simplifier and their former borders simplified.
//!
//! The declared error ([`ErrorReference::measure`]) bounds the distance between the tile's content P and the
//! full detail F it stands for, in both directions:
//! - F → P is measured directly: dense samples of every full-detail leaf below (gathered again from
//!   the scene one leaf at a time, so memory stays bounded by a tile) against P;
//! - P → F is bounded per sample p by `min_k d(p, C_k) + b_k` over the children k, whose content
//!   C_k lies within `b_k` of their own full detail (their own P → F bound, 0 at the leaves;
//!   triangle inequality).
//!
//! Adding the children's errors to the whole tile's simplification error instead is loose: errors
//! add only where they coincide (docs/benchmarks.md).

use super::clock::{self, Part};
use crate::partition::content::{ContentPrimitive, TileContent};
use crate::partition::ContentItem;
use crate::scene::{ComponentId, Scene};
use crate::simplify::hausdorff::{DenseSamples, MeshBvh, TriMesh};
use crate::simplify::{simplify, MeshInput, SimplifiedMesh, SimplifyError, SimplifyOptions};
use glam::DVec3;
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering::Relaxed};
use std::sync::{Arc, OnceLock};

/// What simplifying a tile's children gave.
#[derive(Debug, Clone)]
pub struct HlodContent {
    pub content: TileContent,
    pub input_triangles: usize,
    /// Longest edge the simplifier collapsed (the paper's maximum folding edge length, metres).
    pub max_collapsed_edge_m: f64,
}

/// One tile content as a single triangle soup (all primitives), for distance queries.
fn soup(c: &TileContent) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut pos = Vec::with_capacity(c.vertex_count());
    let mut idx = Vec::with_capacity(c.triangle_count() * 3);
    for p in &c.primitives {
        let base = pos.len() as u32;
        pos.extend_from_slice(&p.positions);
        idx.extend(p.indices.iter().map(|&i| base + i));
    }
    (pos, idx)
}

/// Margin on the measured full → coarse distance. Full detail is sampled at every vertex, edge
/// midpoint and centroid plus area-weighted points, and the largest distances (parts dropped or
/// flattened by the simplification) are reached at vertices; the independent 4x-denser check of
/// `tests/hlod.rs` finds at most this much more. Smaller than the simplifier's 10 % (which also
/// covers thin spikes of the coarse surface) because a larger margin here propagates: a parent's
/// error must exceed its children's.
pub const FULL_TO_COARSE_SAFETY: f64 = 1.02;

/// The declared error of an HLOD tile, and its two parts.
#[derive(Debug, Clone, Copy)]
pub struct TileError {
    /// `max(FULL_TO_COARSE_SAFETY * full_to_coarse_m, error_safety * coarse_to_full_m,
    /// error_floor_m)`.
    pub error_m: f64,
    /// Measured: largest distance from a full-detail sample to the tile's content.
    pub full_to_coarse_m: f64,
    /// Bound: largest distance from a sample of the tile's content to full detail.
    pub coarse_to_full_m: f64,
}

/// What a tile's content is measured against (see the module docs): the full detail `leaves`
/// below it and its `children`'s content with their `coarse_to_full_m` bounds. Built once per
/// tile, so that each candidate content (HLOD coarsening tries, LOD chain levels) only costs its
/// own measurement.
pub struct ErrorReference<'a> {
    scene: &'a Scene,
    center: DVec3,
    /// The children's content, re-anchored at `center`, and their bounds.
    kids: Vec<(MeshBvh, f64)>,
    leaves: &'a [&'a [ContentItem]],
    min_leaf_samples: usize,
    /// The leaves' geometry gathered by a measurement, for the next ones (every try of a tile
    /// measures against the same leaves), and its size.
    kept_leaves: Vec<OnceLock<Arc<Soup>>>,
    kept_bytes: AtomicUsize,
    /// At most this many bytes of them are kept ([`LEAF_SOUPS_KEPT_BYTES`]).
    kept_cap_bytes: usize,
}

/// Positions and triangles of one mesh.
type Soup = (Vec<[f32; 3]>, Vec<u32>);

/// At most this many bytes of a tile's full-detail leaves are kept between its measurements
/// (under `--memory-budget`, at most an eighth of it): every try of a tile measures against the
/// same leaves, and gathering them from the scene again for each was a large share of the
/// measurements (docs/benchmarks.md).
const LEAF_SOUPS_KEPT_BYTES: usize = 256 << 20;

fn leaf_soups_kept_bytes() -> usize {
    crate::scene::memory_budget().map_or(LEAF_SOUPS_KEPT_BYTES, |b| {
        LEAF_SOUPS_KEPT_BYTES.min((b.bytes / 8) as usize)
    })
}

impl<'a> ErrorReference<'a> {
    /// Each leaf is sampled at every vertex, edge midpoint and centroid plus as many area-weighted
    /// points as it has triangles, and at least `min_leaf_samples` (a small leaf alone, as under a
    /// discrete LOD chain, needs more than its triangle count). Measured contents must be centred
    /// at `center`.
    pub fn new(
        scene: &'a Scene,
        center: DVec3,
        children: &[(&TileContent, f64)],
        leaves: &'a [&'a [ContentItem]],
        min_leaf_samples: usize,
    ) -> Self {
        // A child that draws nothing is no way to full detail.
        let kids = children
            .iter()
            .filter(|(c, _)| c.triangle_count() > 0)
            .map(|(c, e)| {
                let moved = TileContent::merge(&[*c], center);
                let (cp, ci) = soup(&moved);
                (MeshBvh::new(TriMesh::new(&cp, &ci)), *e)
            })
            .collect();
        ErrorReference {
            scene,
            center,
            kids,
            kept_leaves: leaves.iter().map(|_| OnceLock::new()).collect(),
            kept_bytes: AtomicUsize::new(0),
            kept_cap_bytes: leaf_soups_kept_bytes(),
            leaves,
            min_leaf_samples,
        }
    }

    /// Declared error of `content` (the tile's simplified geometry, P) with respect to the full
    /// detail it stands for, with its P -> F part exact ([`Self::exact_coarse_to_full_m`]).
    pub fn measure(&self, content: &TileContent, opts: &SimplifyOptions) -> TileError {
        let mut error = self
            .measure_within(content, opts, f64::INFINITY)
            .expect("no error exceeds infinity");
        error.coarse_to_full_m = self.exact_coarse_to_full_m(content);
        error
    }

    /// The P -> F bound of `content` (see [`Self::measure_within`]) found exactly, not only up to
    /// the share of the error it would raise: the content a tile keeps hands it to its parent,
    /// whose own P -> F bound adds it.
    pub fn exact_coarse_to_full_m(&self, content: &TileContent) -> f64 {
        if content.triangle_count() == 0 {
            return 0.0;
        }
        let (pp, pi) = soup(content);
        clock::timed(Part::CoarseToFull, || {
            self.coarse_to_full_sampled(TriMesh::new(&pp, &pi), 0.0, f64::INFINITY)
        })
    }

    /// [`measure`](Self::measure), given up (`None`) as soon as the declared error is sure to
    /// exceed `limit_m`: a coarsening try past its limit is rejected whatever its exact error, and
    /// a measurement samples all the full detail below the tile.
    pub fn measure_within(
        &self,
        content: &TileContent,
        opts: &SimplifyOptions,
        limit_m: f64,
    ) -> Option<TileError> {
        debug_assert_eq!(content.center, self.center, "content centred elsewhere");
        if content.triangle_count() == 0 {
            // Nothing drawn: full detail is nowhere near it (the caller writes no content).
            let error_m = f64::INFINITY;
            return (limit_m == f64::INFINITY).then_some(TileError {
                error_m,
                full_to_coarse_m: error_m,
                coarse_to_full_m: 0.0,
            });
        }
        // Measured distances above these already declare more than `limit_m`.
        let f2c_limit = limit_m / FULL_TO_COARSE_SAFETY;
        let c2f_limit = limit_m / opts.error_safety;
        let (pp, pi) = soup(content);
        let p_bvh = MeshBvh::new(TriMesh::new(&pp, &pi));
        // F -> P: dense samples of each leaf, a running maximum shared by all (a point only needs
        // an exact distance when it could raise it).
        clock::count_measurement();
        let t_full = std::time::Instant::now();
        let sampled_m = self.full_to_coarse_sampled(&p_bvh, f2c_limit);
        clock::add(Part::FullToCoarse, t_full);
        if sampled_m > f2c_limit {
            return None;
        }
        let full_to_coarse_m = clock::timed(Part::Faces, || {
            self.faces_within(&p_bvh, sampled_m, opts.error_floor_m)
        });
        if full_to_coarse_m > f2c_limit {
            return None;
        }
        // P -> F: through the children, `min over children (distance + its bound)` per sample, a
        // running maximum again: a child nearer than the maximum (less its bound) settles that the
        // sample cannot raise it. Same result as exact queries against every child, which cost
        // much of the HLOD stage's time on large scenes (docs/benchmarks.md).
        // Children go nearest first by a lower bound of their term (box distance + bound), and a
        // child is only searched below the best term so far: most samples lie in one child, and
        // an exact query on a far one descends much of its tree (most of the full queries here,
        // and most of the measurement's time).
        // Below the distance at which it would raise the declared error, P -> F needs no exact
        // value to decide a try: its samples only show they are under it (most of them at once,
        // through the children's triangles their neighbours were settled by), and it is given as
        // that distance. The content a tile keeps is measured exactly (`exact_coarse_to_full_m`).
        let c2f_matters_m =
            (FULL_TO_COARSE_SAFETY * full_to_coarse_m).max(opts.error_floor_m) / opts.error_safety;
        let t_coarse = std::time::Instant::now();
        let coarse_to_full_m =
            self.coarse_to_full_sampled(TriMesh::new(&pp, &pi), c2f_matters_m, c2f_limit);
        clock::add(Part::CoarseToFull, t_coarse);
        let error = TileError {
            error_m: (FULL_TO_COARSE_SAFETY * full_to_coarse_m)
                .max(opts.error_safety * coarse_to_full_m)
                .max(opts.error_floor_m),
            full_to_coarse_m,
            coarse_to_full_m,
        };
        (error.error_m <= limit_m).then_some(error)
    }
}

impl ErrorReference<'_> {
    /// Full-detail leaf `k`'s geometry: kept from an earlier measurement of this tile, or
    /// gathered from the scene (and kept while the kept leaves stay within their cap).
    fn leaf_soup(&self, k: usize) -> Arc<Soup> {
        if let Some(kept) = self.kept_leaves[k].get() {
            return kept.clone();
        }
        let leaf = Arc::new(TileContent::gather_soup(
            self.scene,
            self.leaves[k],
            self.center,
        ));
        let bytes = std::mem::size_of_val(&leaf.0[..]) + std::mem::size_of_val(&leaf.1[..]);
        let kept = self.kept_bytes.fetch_add(bytes, Relaxed) + bytes <= self.kept_cap_bytes
            && self.kept_leaves[k].set(leaf.clone()).is_ok();
        if !kept {
            self.kept_bytes.fetch_sub(bytes, Relaxed);
        }
        leaf
    }

    /// The largest distance from a dense sample of the full detail to the content (`p_bvh`), or
    /// some value over `f2c_limit` as soon as one shows it. Samples go a triangle at a time: every
    /// sample on a triangle whose corners lie nearer than the maximum to one triangle of the
    /// content is nearer too (convexity), and needs no query.
    fn full_to_coarse_sampled(&self, p_bvh: &MeshBvh, f2c_limit: f64) -> f64 {
        let run = AtomicU64::new(0);
        (0..self.leaves.len()).into_par_iter().for_each(|k| {
            if f64::from_bits(run.load(Relaxed)) > f2c_limit {
                return;
            }
            let leaf = self.leaf_soup(k);
            let (lp, li) = (&leaf.0, &leaf.1);
            let samples = DenseSamples::new(
                TriMesh::new(lp, li),
                (li.len() / 3).max(self.min_leaf_samples),
            );
            let sample = |hint: &mut u32, x: DVec3| {
                let thr = f64::from_bits(run.load(Relaxed));
                if thr > f2c_limit {
                    return;
                }
                let d = p_bvh.distance_or_below(x, thr, hint);
                if d >= thr && d.is_finite() {
                    run.fetch_max(d.to_bits(), Relaxed);
                }
            };
            samples
                .lone_vertices
                .par_iter()
                .with_min_len(1024)
                .for_each_init(|| u32::MAX, |hint, &x| sample(hint, x));
            let triangles = &samples.triangles;
            runs_of(triangles.len())
                .into_par_iter()
                .with_min_len(256 / COVER_RUN)
                .for_each_init(
                    || u32::MAX,
                    |hint, run_of| {
                        // A run of triangles within a ball nearer than the maximum to one
                        // triangle of the content is nearer too, all of it (1-Lipschitz).
                        let thr = f64::from_bits(run.load(Relaxed));
                        let corners = triangles[run_of.clone()].iter().flatten();
                        if *hint != u32::MAX
                            && run_within(corners, thr, |c| p_bvh.distance_to_triangle(c, *hint))
                        {
                            return;
                        }
                        for i in run_of {
                            // Every sample on a triangle whose corners lie nearer than the
                            // maximum to one triangle of the content is nearer too (convexity).
                            let thr = f64::from_bits(run.load(Relaxed));
                            let covered = *hint != u32::MAX
                                && triangles[i].iter().all(|&v| {
                                    surely_below(p_bvh.distance_to_triangle(v, *hint), thr)
                                });
                            if !covered {
                                samples.for_each_on_triangle(i, |x| sample(hint, x));
                            }
                        }
                    },
                );
        });
        f64::from_bits(run.load(Relaxed))
    }

    /// The largest `min over children (distance + its bound)` of a dense sample of `coarse`, at
    /// least `from_m`, or some value over `c2f_limit` as soon as one shows it (see
    /// [`ErrorReference::measure_within`]).
    fn coarse_to_full_sampled(&self, coarse: TriMesh<'_>, from_m: f64, c2f_limit: f64) -> f64 {
        let sample_count = (coarse.indices.len() / 3).clamp(20_000, 250_000);
        let run = AtomicU64::new(from_m.max(0.0).to_bits());
        let samples = DenseSamples::new(coarse, sample_count);
        // Per thread: each child's last triangle, the scratch order, and the child that settled
        // the last sample.
        type Scratch = (Vec<u32>, Vec<(f64, usize)>, usize);
        let sample = |(hints, order, last): &mut Scratch, x: DVec3| {
            let thr = f64::from_bits(run.load(Relaxed));
            if thr > c2f_limit {
                return;
            }
            // Most samples lie near the triangle of the child that settled the last one: that
            // settles them too, without ordering the children.
            if let Some((b, e)) = self.kids.get(*last) {
                let t = hints[*last];
                if t != u32::MAX && b.distance_to_triangle(x, t) + e < thr {
                    return;
                }
            }
            order.clear();
            order.extend(
                self.kids
                    .iter()
                    .enumerate()
                    .map(|(k, (b, e))| (b.distance_lower_bound(x) + e, k)),
            );
            order.sort_unstable_by(|a: &(f64, usize), b| a.0.total_cmp(&b.0));
            let mut nearest = f64::INFINITY;
            for &(lower, k) in order.iter() {
                if lower >= nearest {
                    break;
                }
                let (b, e) = &self.kids[k];
                let below = thr - e;
                let d = b.distance_between(x, below, nearest - e, &mut hints[k]);
                if d < below {
                    *last = k;
                    return;
                }
                nearest = nearest.min(d + e);
            }
            if nearest.is_finite() && nearest > thr {
                run.fetch_max(nearest.to_bits(), Relaxed);
            }
        };
        samples
            .lone_vertices
            .par_iter()
            .with_min_len(1024)
            .for_each_init(
                || (vec![u32::MAX; self.kids.len()], Vec::new(), usize::MAX),
                |scratch, &x| sample(scratch, x),
            );
        let triangles = &samples.triangles;
        runs_of(triangles.len())
            .into_par_iter()
            .with_min_len(256 / COVER_RUN)
            .for_each_init(
                || (vec![u32::MAX; self.kids.len()], Vec::new(), usize::MAX),
                |scratch, run_of| {
                    // As above: a run, then each triangle, nearer than the maximum (less the
                    // child's bound) to one triangle of a child settles every sample on it.
                    let last = |scratch: &Scratch| {
                        let (b, e) = self.kids.get(scratch.2)?;
                        let t = scratch.0[scratch.2];
                        (t != u32::MAX).then_some((b, *e, t))
                    };
                    let thr = f64::from_bits(run.load(Relaxed));
                    let corners = triangles[run_of.clone()].iter().flatten();
                    if last(scratch).is_some_and(|(b, e, t)| {
                        run_within(corners, thr, |c| b.distance_to_triangle(c, t) + e)
                    }) {
                        return;
                    }
                    for i in run_of {
                        let thr = f64::from_bits(run.load(Relaxed));
                        let covered = last(scratch).is_some_and(|(b, e, t)| {
                            triangles[i]
                                .iter()
                                .all(|&v| surely_below(b.distance_to_triangle(v, t) + e, thr))
                        });
                        if !covered {
                            samples.for_each_on_triangle(i, |x| sample(scratch, x));
                        }
                    }
                },
            );
        f64::from_bits(run.load(Relaxed))
    }

    /// The largest distance from the full detail to `coarse`, given `sampled_m`, the largest
    /// distance of the samples (every vertex among them). Per full-detail triangle, two bounds of
    /// the distance anywhere on it: the distance is 1-Lipschitz (at most the largest corner's
    /// distance plus the longest edge over √3), and the distance to one coarse triangle is convex
    /// (at most the largest corner's distance to that triangle), as it is on each side of a plane
    /// through the edge two coarse triangles share ([`two_piece_bound`]). A triangle whose bound is
    /// over the certified distance ([`FULL_TO_COARSE_SAFETY`] times `sampled_m`) is split in four
    /// at its edge midpoints, measured there, and its parts checked again (at most [`FACE_SPLITS`]
    /// times), so the declared error covers every face, edge and open border. Samples alone missed peaks
    /// between corners, declaring less than the real distance.
    ///
    /// Most triangles lie within the certified distance of the coarse triangle the last one was
    /// certified by (a nearby one): three point-triangle distances then certify them, with no
    /// search. Only the others get their corners' exact distances. The result takes only
    /// distances over the certified one, which no certified triangle has, so it is the same
    /// whatever the threads do.
    fn faces_within(&self, coarse: &MeshBvh, sampled_m: f64, floor_m: f64) -> f64 {
        type Corner = (DVec3, f64, u32);
        let certified_m = (FULL_TO_COARSE_SAFETY * sampled_m).max(floor_m);
        let run = AtomicU64::new(sampled_m.to_bits());
        // Exact, searched from the last answer of the same thread (a nearby point): the same
        // result, sooner.
        let exact = |x: DVec3, hint: &mut u32| -> Corner {
            coarse
                .closest_near(x, hint)
                .map_or((x, f64::INFINITY, u32::MAX), |c| (x, c.0, c.1))
        };
        // Every point of the triangle within the certified distance of coarse triangle `t`.
        let within_of = |c: &[DVec3; 3], t: u32| {
            t != u32::MAX
                && c.iter()
                    .all(|&v| surely_below(coarse.distance_to_triangle(v, t), certified_m))
        };
        let certified = |c: &[Corner; 3]| {
            let far = c.iter().map(|k| k.1).fold(0.0, f64::max);
            let longest = (0..3)
                .map(|k| (c[k].0 - c[(k + 1) % 3].0).length())
                .fold(0.0, f64::max);
            let lipschitz = far + longest / 3f64.sqrt();
            let convex = c
                .iter()
                .filter(|k| k.2 != u32::MAX)
                .map(|k| {
                    c.iter()
                        .map(|j| {
                            if j.2 == k.2 {
                                j.1
                            } else {
                                coarse.distance_to_triangle(j.0, k.2)
                            }
                        })
                        .fold(0.0, f64::max)
                })
                .fold(f64::INFINITY, f64::min);
            if lipschitz.min(convex) <= certified_m {
                return true;
            }
            // Corners nearest to two coarse triangles that share an edge: a face of full detail
            // across an edge of the coarse content, often of one flat face. Each pair once.
            let pairs = [(c[0].2, c[1].2), (c[0].2, c[2].2), (c[1].2, c[2].2)];
            pairs.iter().enumerate().any(|(n, &(ka, kb))| {
                ka != u32::MAX
                    && kb != u32::MAX
                    && ka != kb
                    && !pairs[..n].contains(&(ka, kb))
                    && !pairs[..n].contains(&(kb, ka))
                    && two_piece_bound(coarse, c.map(|k| k.0), ka, kb)
                        .is_some_and(|b| surely_below(b, certified_m))
            })
        };
        // Triangles this small are within the bound whatever their corners (<= sampled).
        let small_m = (certified_m - sampled_m) * 3f64.sqrt();
        let certify = |stack: &mut Vec<([Corner; 3], u32)>, hint: &mut u32, p: [DVec3; 3]| {
            let large = (0..3).any(|k| (p[k] - p[(k + 1) % 3]).length() > small_m);
            if !large || within_of(&p, *hint) {
                return;
            }
            // A corner's nearest triangle often holds the whole triangle within the certified
            // distance (`certified` would then certify it by convexity): the corners after it need
            // no search.
            let mut corners = [(DVec3::ZERO, f64::INFINITY, u32::MAX); 3];
            for (corner, &v) in corners.iter_mut().zip(&p) {
                *corner = exact(v, hint);
                if within_of(&p, corner.2) {
                    return;
                }
            }
            // The corners' own nearest triangles are tried by `certified` (convexity, then pairs).
            stack.push((corners, 0));
            while let Some((c, splits)) = stack.pop() {
                if splits >= FACE_SPLITS || certified(&c) {
                    continue;
                }
                let m = [0, 1, 2].map(|k| exact((c[k].0 + c[(k + 1) % 3].0) * 0.5, hint));
                for k in &m {
                    if k.1.is_finite() && k.1 > certified_m {
                        run.fetch_max(k.1.to_bits(), Relaxed);
                    }
                }
                stack.push(([c[0], m[0], m[2]], splits + 1));
                stack.push(([m[0], c[1], m[1]], splits + 1));
                stack.push(([m[2], m[1], c[2]], splits + 1));
                stack.push((m, splits + 1));
            }
        };
        for k in 0..self.leaves.len() {
            let leaf = self.leaf_soup(k);
            let (lp, li) = (&leaf.0, &leaf.1);
            let point = |i: u32| {
                let v = lp[i as usize];
                DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)
            };
            li.par_chunks(3 * COVER_RUN)
                .with_min_len(64 / COVER_RUN)
                .for_each_init(
                    || (Vec::new(), u32::MAX),
                    |(stack, hint), run_of| {
                        // A run within a ball inside the certified distance of one coarse triangle
                        // is certified whole (1-Lipschitz), as its triangles would be one by one.
                        let corners = run_of.iter().map(|&i| point(i));
                        if *hint != u32::MAX
                            && run_within(corners, certified_m, |c| {
                                coarse.distance_to_triangle(c, *hint)
                            })
                        {
                            return;
                        }
                        for t in run_of.chunks_exact(3) {
                            certify(stack, hint, [point(t[0]), point(t[1]), point(t[2])]);
                        }
                    },
                );
        }
        f64::from_bits(run.load(Relaxed))
    }
}

/// An upper bound of the distance from every point of triangle `t` to the union of coarse
/// triangles `ka` and `kb`, when they share an edge (`None` otherwise). The plane through the
/// shared edge, across `ka`, cuts `t` into two convex pieces (or leaves it whole); the distance to
/// one triangle is convex, so each piece lies within its corners' largest distance of the coarse
/// triangle on its side. Any plane would give a bound; this one fits two triangles of one flat
/// face, which a full-detail face crossing their edge lies over.
fn two_piece_bound(coarse: &MeshBvh, t: [DVec3; 3], ka: u32, kb: u32) -> Option<f64> {
    let (a, b) = (coarse.triangle(ka), coarse.triangle(kb));
    let mut shared = a.iter().filter(|p| b.contains(p));
    let (o, q) = (*shared.next()?, *shared.next()?);
    let apex = *a.iter().find(|p| !b.contains(p))?;
    let normal = (a[1] - a[0]).cross(a[2] - a[0]);
    let mut across = (q - o).cross(normal);
    if across.dot(apex - o) < 0.0 {
        across = -across;
    }
    if across.length_squared() == 0.0 {
        return None;
    }
    let side = t.map(|p| across.dot(p - o));
    let mut far_a = 0.0f64;
    let mut far_b = 0.0f64;
    for k in 0..3 {
        if side[k] >= 0.0 {
            far_a = far_a.max(coarse.distance_to_triangle(t[k], ka));
        }
        if side[k] <= 0.0 {
            far_b = far_b.max(coarse.distance_to_triangle(t[k], kb));
        }
        let n = (k + 1) % 3;
        if (side[k] > 0.0 && side[n] < 0.0) || (side[k] < 0.0 && side[n] > 0.0) {
            let x = t[k] + (t[n] - t[k]) * (side[k] / (side[k] - side[n]));
            far_a = far_a.max(coarse.distance_to_triangle(x, ka));
            far_b = far_b.max(coarse.distance_to_triangle(x, kb));
        }
    }
    Some(far_a.max(far_b))
}

/// Triangles a run of which is first tried as one ball ([`Ball`]) by the measurements: a tile
/// far coarser than full detail covers whole runs of small triangles at once.
const COVER_RUN: usize = 32;

/// `0..n` in runs of [`COVER_RUN`].
fn runs_of(n: usize) -> Vec<std::ops::Range<usize>> {
    (0..n.div_ceil(COVER_RUN))
        .map(|r| r * COVER_RUN..((r + 1) * COVER_RUN).min(n))
        .collect()
}

/// A ball holding a run of triangles (their corners, so every point on them: a ball is convex).
/// A distance is 1-Lipschitz, so no point in it lies farther from a triangle than its center's
/// distance plus its radius.
struct Ball {
    center: DVec3,
    radius_m: f64,
}

/// Whether every point on a run of triangles (given by its corners) is surely nearer than `thr`
/// to a triangle whose distance from a point is `distance`: tried on the run's ball, built only
/// when there is a triangle to try.
fn run_within<P: std::borrow::Borrow<DVec3>>(
    corners: impl Iterator<Item = P> + Clone,
    thr: f64,
    distance: impl Fn(DVec3) -> f64,
) -> bool {
    let ball = Ball::around(corners);
    surely_below(ball.reach(distance(ball.center)), thr)
}

impl Ball {
    fn around(points: impl Iterator<Item = impl std::borrow::Borrow<DVec3>> + Clone) -> Ball {
        let (lo, hi) = points.clone().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p.borrow()), hi.max(*p.borrow())),
        );
        let center = (lo + hi) * 0.5;
        let radius2 = points.fold(0.0, |r, p| center.distance_squared(*p.borrow()).max(r));
        Ball {
            center,
            radius_m: radius2.sqrt(),
        }
    }

    /// The farthest any point of the ball can be from a triangle `center_m` from its center.
    fn reach(&self, center_m: f64) -> f64 {
        center_m + self.radius_m
    }
}

/// Whether `d` is below `thr` by more than rounding: the corners' largest distance to a triangle
/// then bounds every point between them (convexity) despite the points' own rounding.
fn surely_below(d: f64, thr: f64) -> bool {
    d + 1e-9 < thr * (1.0 - 1e-9)
}

/// At most this many four-way splits of a full-detail triangle when its distance to a tile's
/// content is bounded ([`ErrorReference::measure`]): 1/64 of its edges.
const FACE_SPLITS: u32 = 6;

/// Merges `children` around `center` and simplifies to `target_triangles` (and at most
/// `opts.target_ratio` of the input). `continuing` lists components that also have triangles
/// outside this tile's subtree (sorted): their open borders are locked.
pub fn simplify_children(
    children: &[&TileContent],
    center: DVec3,
    continuing: &[ComponentId],
    target_triangles: usize,
    opts: &SimplifyOptions,
) -> Result<HlodContent, SimplifyError> {
    let merged = TileContent::merge(children, center);
    let input_triangles = merged.triangle_count();
    let feature_count = merged.features.len().max(1) as u32;
    let with_uv = merged.primitives.iter().any(|p| !p.uvs.is_empty());
    let with_color = merged.primitives.iter().any(|p| !p.colors.is_empty());
    let n: usize = merged.vertex_count();
    let (mut pos, mut nrm, mut uv, mut col, mut grp, mut idx) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::new(),
        Vec::new(),
        Vec::with_capacity(n),
        Vec::with_capacity(input_triangles * 3),
    );
    for (pi, p) in merged.primitives.iter().enumerate() {
        let base = pos.len() as u32;
        pos.extend_from_slice(&p.positions);
        nrm.extend_from_slice(&p.normals);
        if with_uv {
            if p.uvs.is_empty() {
                uv.resize(pos.len(), [0.0; 2]);
            } else {
                uv.extend_from_slice(&p.uvs);
            }
        }
        if with_color {
            if p.colors.is_empty() {
                col.resize(pos.len(), [1.0; 4]);
            } else {
                col.extend_from_slice(&p.colors);
            }
        }
        // Group = (primitive, feature): never merged with another.
        grp.extend(p.feature_ids.iter().map(|&f| pi as u32 * feature_count + f));
        idx.extend(p.indices.iter().map(|&i| base + i));
    }
    let locked = lock_continuing_borders(&merged, &pos, &grp, &idx, continuing, feature_count);
    let input = MeshInput {
        positions: &pos,
        normals: Some(&nrm),
        uvs: with_uv.then_some(&uv[..]),
        colors: with_color.then_some(&col[..]),
        groups: Some(&grp),
        locked: locked.as_deref(),
        indices: &idx,
    };
    // The error is measured against full detail afterwards ([`ErrorReference`]), not against the input.
    let o = SimplifyOptions {
        target_triangles: Some(target_triangles),
        compute_error_bound: false,
        ..opts.clone()
    };
    let mut r = clock::timed(Part::Simplify, || simplify(&input, &o))?;
    if r.triangle_count() > target_triangles {
        // Angle control and curvature weighting can stall a coarse level (many small closed parts
        // whose every collapse turns a face far): there the budget wins.
        let relaxed = SimplifyOptions {
            max_normal_angle_deg: 180.0,
            curvature_weight: 0.0,
            ..o.clone()
        };
        let again = clock::timed(Part::Simplify, || simplify(&input, &relaxed))?;
        if again.triangle_count() < r.triangle_count() {
            r = again;
        }
    }
    if r.triangle_count() > target_triangles {
        drop_smallest_parts(&mut r, locked.as_deref(), target_triangles);
    }
    // Back to one primitive per material, vertices compacted per primitive.
    let mut prims: Vec<ContentPrimitive> = merged
        .primitives
        .iter()
        .map(|p| ContentPrimitive {
            material: p.material,
            ..Default::default()
        })
        .collect();
    let mut remap: HashMap<u32, u32> = HashMap::new();
    for t in r.indices.chunks_exact(3) {
        let g = r.groups[t[0] as usize];
        let (pi, fid) = ((g / feature_count) as usize, g % feature_count);
        let src = &merged.primitives[pi];
        let out = &mut prims[pi];
        for &v in t {
            let k = *remap.entry(v).or_insert_with(|| {
                let vi = v as usize;
                out.positions.push(r.positions[vi]);
                let nn = r.normals.as_ref().map_or([0.0, 0.0, 1.0], |n| n[vi]);
                out.normals.push(nn);
                if !src.uvs.is_empty() {
                    out.uvs.push(r.uvs.as_ref().map_or([0.0; 2], |u| u[vi]));
                }
                if !src.colors.is_empty() {
                    out.colors
                        .push(r.colors.as_ref().map_or([1.0; 4], |c| c[vi]));
                }
                out.feature_ids.push(fid);
                (out.positions.len() - 1) as u32
            });
            out.indices.push(k);
        }
    }
    let mut content = TileContent {
        center,
        features: merged.features,
        primitives: prims,
        instanced: Vec::new(),
    };
    content.compact_features();
    Ok(HlodContent {
        content,
        input_triangles,
        max_collapsed_edge_m: r.max_collapsed_edge_m,
    })
}

/// The budget's last resort, when collapses stall above it (many small closed parts, locked
/// borders can keep a root above its budget): whole parts (one feature of one
/// material: a vertex group) are dropped, smallest box diagonal first, until the tile fits. Parts
/// with a locked vertex stay (their neighbours rely on their borders). The error measured
/// afterwards ([`ErrorReference`]) accounts for what was dropped.
fn drop_smallest_parts(r: &mut SimplifiedMesh, locked: Option<&[bool]>, target: usize) {
    let mut parts: BTreeMap<u32, (usize, [f32; 3], [f32; 3], bool)> = BTreeMap::new();
    for t in r.indices.chunks_exact(3) {
        let e = parts.entry(r.groups[t[0] as usize]).or_insert((
            0,
            [f32::MAX; 3],
            [f32::MIN; 3],
            false,
        ));
        e.0 += 1;
        for &v in t {
            for (k, &c) in r.positions[v as usize].iter().enumerate() {
                e.1[k] = e.1[k].min(c);
                e.2[k] = e.2[k].max(c);
            }
            e.3 |= locked.is_some_and(|l| l[r.source_vertex[v as usize] as usize]);
        }
    }
    let mut order: Vec<(f32, u32, usize)> = parts
        .iter()
        .filter(|(_, p)| !p.3)
        .map(|(&g, p)| {
            let d = (0..3).map(|k| (p.2[k] - p.1[k]).powi(2)).sum::<f32>();
            (d, g, p.0)
        })
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut live = r.triangle_count();
    let mut dropped = Vec::new();
    for (_, g, n) in order {
        if live <= target {
            break;
        }
        dropped.push(g);
        live -= n;
    }
    dropped.sort_unstable();
    let keep: Vec<u32> = r
        .indices
        .chunks_exact(3)
        .filter(|t| dropped.binary_search(&r.groups[t[0] as usize]).is_err())
        .flatten()
        .copied()
        .collect();
    r.indices = keep;
}

/// Locks the open-border vertices of the features whose component continues outside the tile.
/// Borders are found by position (quantized to 0.1 mm, the weld tolerance), per group, so the
/// split vertices of attribute seams do not make false borders.
fn lock_continuing_borders(
    merged: &TileContent,
    pos: &[[f32; 3]],
    grp: &[u32],
    idx: &[u32],
    continuing: &[ComponentId],
    feature_count: u32,
) -> Option<Vec<bool>> {
    let is_continuing: Vec<bool> = merged
        .features
        .iter()
        .map(|c| continuing.binary_search(c).is_ok())
        .collect();
    if !is_continuing.iter().any(|&b| b) {
        return None;
    }
    let key = |v: u32| {
        let p = pos[v as usize];
        let q = |x: f32| (x as f64 * 1e4).round() as i64;
        (grp[v as usize], q(p[0]), q(p[1]), q(p[2]))
    };
    type Key = (u32, i64, i64, i64);
    let mut edges: BTreeMap<(Key, Key), u32> = BTreeMap::new();
    for t in idx.chunks_exact(3) {
        if !is_continuing[(grp[t[0] as usize] % feature_count) as usize] {
            continue;
        }
        for k in 0..3 {
            let (a, b) = (key(t[k]), key(t[(k + 1) % 3]));
            if a == b {
                continue;
            }
            *edges
                .entry(if a < b { (a, b) } else { (b, a) })
                .or_default() += 1;
        }
    }
    let mut border: Vec<Key> = edges
        .into_iter()
        .filter(|&(_, n)| n == 1)
        .flat_map(|((a, b), _)| [a, b])
        .collect();
    border.sort_unstable();
    border.dedup();
    let mut locked = vec![false; pos.len()];
    let mut any = false;
    for (v, l) in locked.iter_mut().enumerate() {
        if is_continuing[(grp[v] % feature_count) as usize]
            && border.binary_search(&key(v as u32)).is_ok()
        {
            *l = true;
            any = true;
        }
    }
    any.then_some(locked)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Numbers in [0, 1) from `seed`, the same on every run.
    fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn no_point_of_a_run_lies_beyond_its_balls_reach_from_a_triangle() {
        // A run of triangles scattered over a few metres, and triangles near and far.
        let mut uniform = uniform(7);
        let mut next = || uniform() * 4.0 - 2.0;
        for _ in 0..50 {
            let run: Vec<[DVec3; 3]> = (0..COVER_RUN)
                .map(|_| [0; 3].map(|_| DVec3::new(next(), next(), next() * 0.1)))
                .collect();
            let ball = Ball::around(run.iter().flatten());
            let offset = DVec3::new(next(), next(), next()) * 3.0;
            let (pos, idx) = (
                [[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 1.0, 0.2]]
                    .map(|v: [f32; 3]| [v[0] + offset.x as f32, v[1] + offset.y as f32, v[2]]),
                [0u32, 1, 2],
            );
            let tri = MeshBvh::new(TriMesh::new(&pos, &idx));
            let reach = ball.reach(tri.distance_to_triangle(ball.center, 0));
            for t in &run {
                // Corners, and points inside the triangles.
                for (a, b, c) in [
                    (1.0, 0.0, 0.0),
                    (0.0, 1.0, 0.0),
                    (0.0, 0.0, 1.0),
                    (0.2, 0.3, 0.5),
                ] {
                    let x = t[0] * a + t[1] * b + t[2] * c;
                    assert!(ball.center.distance(x) <= ball.radius_m * (1.0 + 1e-12));
                    assert!(tri.distance_to_triangle(x, 0) <= reach * (1.0 + 1e-12) + 1e-12);
                }
            }
        }
    }

    #[test]
    fn a_face_across_two_coarse_triangles_lies_within_their_two_piece_bound() {
        let mut next = uniform(11);
        // Two coarse triangles sharing the edge from (0, 0, 0) to (1, 1, 0): flat, then folded.
        for fold in [0.0f32, 0.3, -0.8] {
            let pos = [
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, fold],
            ];
            let coarse = MeshBvh::new(TriMesh::new(&pos, &[0, 1, 2, 0, 2, 3]));
            let to_both = |x: DVec3| {
                coarse
                    .distance_to_triangle(x, 0)
                    .min(coarse.distance_to_triangle(x, 1))
            };
            for _ in 0..200 {
                let t = [0; 3].map(|_| {
                    DVec3::new(next() * 1.4 - 0.2, next() * 1.4 - 0.2, next() * 0.4 - 0.2)
                });
                let bound = two_piece_bound(&coarse, t, 0, 1).expect("they share an edge");
                for i in 0..=20 {
                    for j in 0..=20 - i {
                        let (a, b) = (i as f64 / 20.0, j as f64 / 20.0);
                        let x = t[0] * (1.0 - a - b) + t[1] * a + t[2] * b;
                        assert!(to_both(x) <= bound + 1e-12, "{t:?} at {x}: over {bound}");
                    }
                }
            }
        }
        // A face of the flat square across the diagonal: on it, though neither triangle holds it.
        let pos = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let coarse = MeshBvh::new(TriMesh::new(&pos, &[0, 1, 2, 0, 2, 3]));
        let face = [
            DVec3::new(0.2, 0.1, 0.0),
            DVec3::new(0.9, 0.3, 0.0),
            DVec3::new(0.3, 0.8, 0.0),
        ];
        assert!(two_piece_bound(&coarse, face, 0, 1).unwrap() < 1e-12);
        let alone = |k| {
            face.iter()
                .map(|&v| coarse.distance_to_triangle(v, k))
                .fold(0.0, f64::max)
        };
        assert!(alone(0) > 0.1 && alone(1) > 0.1);
        // Triangles that share no edge give no bound.
        let pos = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [3.0, 0.0, 0.0],
            [4.0, 0.0, 0.0],
            [3.0, 1.0, 0.0],
        ];
        let apart = MeshBvh::new(TriMesh::new(&pos, &[0, 1, 2, 3, 4, 5]));
        assert!(two_piece_bound(&apart, face, 0, 1).is_none());
    }

    #[test]
    fn runs_cover_every_index_once() {
        for n in [
            0,
            1,
            COVER_RUN - 1,
            COVER_RUN,
            COVER_RUN + 1,
            5 * COVER_RUN + 3,
        ] {
            let all: Vec<usize> = runs_of(n).into_iter().flatten().collect();
            assert_eq!(all, (0..n).collect::<Vec<_>>());
        }
    }

    /// An n x n grid of quads on z = 0 spanning [x0, x0 + size] x [0, size], one feature.
    fn grid(n: usize, x0: f32, size: f32, feature: u32) -> TileContent {
        let mut p = ContentPrimitive::default();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 / n as f32 * size, j as f32 / n as f32 * size);
                p.positions
                    .push([x0 + x, y, 0.02 * ((x0 + x) * 3.0).sin() * (y * 2.0).cos()]);
                p.normals.push([0.0, 0.0, 1.0]);
                p.feature_ids.push(0);
            }
        }
        for j in 0..n as u32 {
            for i in 0..n as u32 {
                let a = j * (n as u32 + 1) + i;
                let b = a + n as u32 + 1;
                p.indices.extend_from_slice(&[a, a + 1, b + 1, a, b + 1, b]);
            }
        }
        TileContent {
            center: DVec3::ZERO,
            features: vec![ComponentId(feature)],
            primitives: vec![p],
            instanced: Vec::new(),
        }
    }

    #[test]
    fn reaches_the_budget_and_keeps_identity() {
        let kids = [grid(30, 0.0, 5.0, 3), grid(30, 6.0, 5.0, 7)];
        let r = simplify_children(
            &[&kids[0], &kids[1]],
            DVec3::new(5.0, 2.5, 0.0),
            &[],
            800,
            &SimplifyOptions::default(),
        )
        .unwrap();
        assert_eq!(r.input_triangles, 2 * 30 * 30 * 2);
        assert!(r.content.triangle_count() <= 800);
        assert!(r.content.triangle_count() > 100);
        assert_eq!(r.content.features, vec![ComponentId(3), ComponentId(7)]);
        // Each triangle lies on its own grid (x < 5.5 is feature 0 = component 3).
        let p = &r.content.primitives[0];
        for t in p.indices.chunks_exact(3) {
            let f = p.feature_ids[t[0] as usize];
            for &v in t {
                assert_eq!(p.feature_ids[v as usize], f);
                let x = p.positions[v as usize][0] + 5.0;
                assert_eq!(x < 5.5, f == 0);
            }
        }
    }

    #[test]
    fn smallest_unlocked_parts_go_when_over_budget() {
        // Parts 0..4 of 2 triangles each, part k of size k + 1; part 0 has a locked vertex.
        let mut r = crate::simplify::SimplifiedMesh::default();
        for k in 0..5u32 {
            let s = (k + 1) as f32;
            let b = r.positions.len() as u32;
            for p in [[0.0, 0.0, 0.0], [s, 0.0, 0.0], [s, s, 0.0], [0.0, s, 0.0]] {
                r.positions.push([p[0] + 10.0 * k as f32, p[1], p[2]]);
                r.groups.push(k);
                r.source_vertex.push(r.source_vertex.len() as u32);
            }
            r.indices.extend([b, b + 1, b + 2, b, b + 2, b + 3]);
        }
        let mut locked = vec![false; 20];
        locked[1] = true;
        // 10 triangles, budget 5: parts 1, 2 and 3 (the smallest unlocked) go, 0 (locked) and 4
        // stay.
        drop_smallest_parts(&mut r, Some(&locked), 5);
        let left: Vec<u32> = r
            .indices
            .chunks_exact(3)
            .map(|t| r.groups[t[0] as usize])
            .collect();
        assert_eq!(left, [0, 0, 4, 4]);
        // Within budget: nothing goes.
        let before = r.indices.clone();
        drop_smallest_parts(&mut r, None, 4);
        assert_eq!(r.indices, before);
    }

    #[test]
    fn borders_of_continuing_components_stay_exact() {
        // Two halves of one component; it continues outside (listed): the outer border of the
        // union must keep every original border vertex.
        let kids = [grid(20, 0.0, 5.0, 1), grid(20, 5.0, 5.0, 1)];
        let r = simplify_children(
            &[&kids[0], &kids[1]],
            DVec3::ZERO,
            &[ComponentId(1)],
            200,
            &SimplifyOptions::default(),
        )
        .unwrap();
        let p = &r.content.primitives[0];
        let on = |x: f32, y: f32| {
            p.positions
                .iter()
                .any(|q| (q[0] - x).abs() < 1e-5 && (q[1] - y).abs() < 1e-5)
        };
        for i in 0..=40 {
            let x = i as f32 * 0.25;
            assert!(on(x, 0.0) && on(x, 5.0), "border vertex at x = {x} kept");
        }
        // The internal seam between the halves was welded and simplified away.
        let seam = (1..20).filter(|&j| on(5.0, j as f32 * 0.25)).count();
        assert!(seam < 19, "seam vertices all kept");
        assert!(r.content.triangle_count() < 1600);
    }
}
