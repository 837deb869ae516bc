//! Deciding whether one component's world geometry is another's moved by a rigid motion (or a
//! similarity), and finding that motion.
//!
//! Two ways, cheapest first:
//! * **Same order**: exporters that bake copies keep the vertex and index order, so when both index
//!   buffers are equal, vertex i corresponds to vertex i; the motion is the closed-form best fit
//!   of all pairs (Horn), then every vertex is checked. No frame ambiguity arises, whatever the
//!   symmetry of the shape.
//! * **Search**: otherwise, candidate motions come from canonical frames (principal axes, signs
//!   fixed by third moments; every sign that the moments cannot fix is tried) and, for symmetric
//!   shapes whose axes are not defined (equal moments: cubes, cylinders), from pairs of distinctive
//!   vertices (farthest from the centroid, farthest from that axis). Each candidate is refined by
//!   ICP (nearest vertex, Horn fit, repeat), then accepted only if every triangle of the prototype
//!   lands on a distinct triangle of the candidate, corner by corner, within the tolerance, with
//!   matching normals, UVs and colours.
//!
//! Orientation: the transform found is always proper (det > 0), and a component whose world
//! mirrors draws its triangles with flipped winding; so the oriented triangles are compared, which
//! rejects a mirrored copy unless the prototype is mirrored the same way.

use super::geom::{fit_similarity, KdTree, Moments, Similarity};
use crate::scene::{Mesh, Primitive};
use glam::{DMat3, DMat4, DVec3};
use std::sync::Arc;

/// How close two geometries must be to count as the same.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Tol {
    /// Metres, per vertex.
    pub pos: f64,
    /// Minimum cosine between corresponding unit normals.
    pub cos_normal: f64,
    pub allow_scale: bool,
}

/// Absolute UV difference allowed, per unit of UV magnitude (tiling UVs run into the thousands
/// and carry f32 rounding in proportion).
const UV_TOL: f32 = 1e-4;
const COLOR_TOL: f32 = 2e-3;

/// One component's geometry in the scene frame (f64), primitive by primitive. It holds its mesh
/// (an `Arc` from the store), so a prototype's shape can be kept or dropped on its own: dedup
/// keeps only as many as its share of the memory budget allows and rebuilds the others.
pub(crate) struct Shape {
    pub prims: Vec<ShapePrim>,
    /// The component's world transform mirrors: its triangles are drawn with flipped winding.
    pub mirrored: bool,
}

pub(crate) struct ShapePrim {
    mesh: Arc<Mesh>,
    index: usize,
    pub pos: Vec<DVec3>,
    /// Unit normals in the scene frame (zero where the input normal is zero).
    pub nrm: Option<Vec<DVec3>>,
}

impl ShapePrim {
    /// The primitive as stored (indices, UVs, colours).
    pub fn src(&self) -> &Primitive {
        &self.mesh.primitives[self.index]
    }
}

impl Shape {
    pub fn new(mesh: Arc<Mesh>, world: &DMat4) -> Shape {
        let nm = normal_matrix(world);
        let prims = mesh
            .primitives
            .iter()
            .enumerate()
            .map(|(index, p)| ShapePrim {
                mesh: mesh.clone(),
                index,
                pos: p
                    .positions
                    .iter()
                    .map(|v| world.transform_point3(DVec3::from_array(v.map(f64::from))))
                    .collect(),
                nrm: p.normals.as_ref().map(|ns| {
                    ns.iter()
                        .map(|n| (nm * DVec3::from_array(n.map(f64::from))).normalize_or_zero())
                        .collect()
                }),
            })
            .collect();
        Shape {
            prims,
            mirrored: DMat3::from_mat4(*world).determinant() < 0.0,
        }
    }

    /// Bytes this shape holds beyond its mesh: positions and normals in f64.
    pub fn heap_bytes(&self) -> usize {
        self.prims
            .iter()
            .map(|p| size_of_val(&p.pos[..]) + p.nrm.as_ref().map_or(0, |n| size_of_val(&n[..])))
            .sum()
    }

    pub fn points(&self) -> impl Iterator<Item = DVec3> + Clone + '_ {
        self.prims.iter().flat_map(|p| p.pos.iter().copied())
    }

    pub fn all_points(&self) -> Vec<DVec3> {
        self.points().collect()
    }

    /// Both index buffers identical primitive by primitive, so vertex i may correspond to i.
    pub fn same_layout(&self, other: &Shape) -> bool {
        self.prims.len() == other.prims.len()
            && self
                .prims
                .iter()
                .zip(&other.prims)
                .all(|(a, b)| a.pos.len() == b.pos.len() && a.src().indices == b.src().indices)
    }

    /// Surface area and the sum of triangle perimeters (the latter bounds how much the area can
    /// change when every vertex moves by δ: |ΔA| ≤ ½·δ·perimeter per triangle, to first order).
    pub fn area_perimeter(&self) -> (f64, f64) {
        let (mut area, mut perim) = (0.0, 0.0);
        for p in &self.prims {
            for t in p.src().indices.chunks_exact(3) {
                let [a, b, c] = [0, 1, 2].map(|k| p.pos[t[k] as usize]);
                area += 0.5 * (b - a).cross(c - a).length();
                perim += a.distance(b) + b.distance(c) + c.distance(a);
            }
        }
        (area, perim)
    }
}

/// Inverse transpose of the linear part: carries normals (direction only) through `m`.
pub(crate) fn normal_matrix(m: &DMat4) -> DMat3 {
    let l = DMat3::from_mat4(*m);
    if l.determinant().abs() > 1e-300 {
        l.inverse().transpose()
    } else {
        l
    }
}

/// Do vertex `j` of `p` (normals already carried by `nm`) and vertex `k` of `c` carry the same
/// attributes (positions are checked by the caller)?
fn attrs_match(p: &ShapePrim, j: usize, c: &ShapePrim, k: usize, nm: &DMat3, tol: &Tol) -> bool {
    match (&p.nrm, &c.nrm) {
        (Some(pn), Some(cn)) => {
            let a = (*nm * pn[j]).normalize_or_zero();
            let b = cn[k];
            let both_zero = a == DVec3::ZERO && b == DVec3::ZERO;
            if !both_zero && a.dot(b) < tol.cos_normal {
                return false;
            }
        }
        (None, None) => {}
        _ => return false,
    }
    match (&p.src().uvs, &c.src().uvs) {
        (Some(pu), Some(cu)) => {
            let (a, b) = (pu[j], cu[k]);
            for i in 0..2 {
                if (a[i] - b[i]).abs() > UV_TOL * a[i].abs().max(1.0) {
                    return false;
                }
            }
        }
        (None, None) => {}
        _ => return false,
    }
    match (&p.src().colors, &c.src().colors) {
        (Some(pc), Some(cc)) => (0..4).all(|i| (pc[j][i] - cc[k][i]).abs() <= COLOR_TOL),
        (None, None) => true,
        _ => false,
    }
}

/// `c` equals `p` mapped by `m` (scene frame → scene frame) vertex by vertex in the same order,
/// with the same index buffers. `new_mirrored`: whether `c`'s new world (m · p's world) mirrors.
pub(crate) fn verify_same_order(
    c: &Shape,
    p: &Shape,
    m: &DMat4,
    new_mirrored: bool,
    tol: &Tol,
) -> bool {
    // Same indices, same vertices: the drawn winding agrees only if both mirror or neither does.
    if c.mirrored != new_mirrored || !c.same_layout(p) {
        return false;
    }
    let tol2 = tol.pos * tol.pos;
    same_order_distance2(c, p, m, tol2) <= tol2 && same_order_attrs(c, p, m, tol)
}

/// Largest squared distance between vertex i of `p` mapped by `m` and vertex i of `c` (same
/// layout), or the first one found above `cap2`.
fn same_order_distance2(c: &Shape, p: &Shape, m: &DMat4, cap2: f64) -> f64 {
    let mut worst2 = 0.0f64;
    for (a, b) in p.points().zip(c.points()) {
        worst2 = worst2.max(m.transform_point3(a).distance_squared(b));
        if worst2 > cap2 {
            break;
        }
    }
    worst2
}

/// Vertex i of `p` and vertex i of `c` carry the same attributes (normals through `m`).
fn same_order_attrs(c: &Shape, p: &Shape, m: &DMat4, tol: &Tol) -> bool {
    let nm = normal_matrix(m);
    c.prims
        .iter()
        .zip(&p.prims)
        .all(|(cp, pp)| (0..cp.pos.len()).all(|i| attrs_match(pp, i, cp, i, &nm, tol)))
}

/// `c` equals `p` mapped by `m` as a set of oriented triangles, each primitive on its own: every
/// triangle of `p` lands on a distinct triangle of `c` (corners in the same cyclic order) within
/// the tolerance, with matching attributes at each corner.
pub(crate) fn verify_triangles(
    c: &Shape,
    p: &Shape,
    m: &DMat4,
    new_mirrored: bool,
    tol: &Tol,
) -> bool {
    if c.prims.len() != p.prims.len() {
        return false;
    }
    let nm = normal_matrix(m);
    let tol2 = tol.pos * tol.pos;
    for (cp, pp) in c.prims.iter().zip(&p.prims) {
        let (ci, pi) = (&cp.src().indices, &pp.src().indices);
        if ci.len() != pi.len() {
            return false;
        }
        // Corners in drawn order: a mirroring world flips the winding.
        let oriented = |t: &[u32], mirrored: bool| -> [usize; 3] {
            if mirrored {
                [t[0] as usize, t[2] as usize, t[1] as usize]
            } else {
                [t[0] as usize, t[1] as usize, t[2] as usize]
            }
        };
        let ctris: Vec<[usize; 3]> = ci
            .chunks_exact(3)
            .map(|t| oriented(t, c.mirrored))
            .collect();
        let centroids: Vec<DVec3> = ctris
            .iter()
            .map(|t| (cp.pos[t[0]] + cp.pos[t[1]] + cp.pos[t[2]]) / 3.0)
            .collect();
        let tree = KdTree::new(centroids);
        let ppos: Vec<DVec3> = pp.pos.iter().map(|&x| m.transform_point3(x)).collect();
        // For every prototype triangle, the candidate triangles it may land on.
        let mut cands: Vec<Vec<u32>> = Vec::with_capacity(pi.len() / 3);
        for t in pi.chunks_exact(3) {
            let pt = oriented(t, new_mirrored);
            let corners = pt.map(|k| ppos[k]);
            let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
            let mut list = Vec::new();
            // Corners within δ put the centroids within δ.
            tree.within(centroid, tol.pos * (1.0 + 1e-9), &mut |i| {
                let ct = ctris[i as usize];
                let fits = (0..3).any(|rot| {
                    (0..3).all(|k| {
                        let (pj, ck) = (pt[k], ct[(k + rot) % 3]);
                        corners[k].distance_squared(cp.pos[ck]) <= tol2
                            && attrs_match(pp, pj, cp, ck, &nm, tol)
                    })
                });
                if fits {
                    list.push(i);
                }
            });
            if list.is_empty() {
                return false;
            }
            // Lowest first: the result must not depend on tree traversal order.
            list.sort_unstable();
            cands.push(list);
        }
        if !perfect_matching(&cands, ctris.len()) {
            return false;
        }
    }
    true
}

/// Whether every left node (prototype triangle) can be paired with a distinct right node
/// (candidate triangle) among its candidates. Greedy first (lowest free candidate), then
/// augmenting paths (Kuhn) for the few left over: slivers and near-coincident faces make several
/// triangles fit one, and a greedy choice could reject a true copy.
fn perfect_matching(cands: &[Vec<u32>], right: usize) -> bool {
    const NONE: u32 = u32::MAX;
    let mut owner = vec![NONE; right];
    let mut pending = Vec::new();
    for (l, list) in cands.iter().enumerate() {
        match list.iter().find(|&&r| owner[r as usize] == NONE) {
            Some(&r) => owner[r as usize] = l as u32,
            None => pending.push(l),
        }
    }
    // Depth-first augmenting path search, iterative (paths can be long in large meshes); the
    // `seen` stamps make each search visit a right node once.
    let mut seen = vec![0u32; right];
    for (stamp, &start) in pending.iter().enumerate() {
        let stamp = stamp as u32 + 1;
        // Stack of (left node, next candidate position); `via[k]` = right node taken at depth k.
        let mut stack: Vec<(u32, usize)> = vec![(start as u32, 0)];
        let mut via: Vec<u32> = Vec::new();
        let mut done = false;
        while let Some(&mut (l, ref mut pos)) = stack.last_mut() {
            let list = &cands[l as usize];
            if *pos >= list.len() {
                stack.pop();
                via.pop();
                continue;
            }
            let r = list[*pos];
            *pos += 1;
            if seen[r as usize] == stamp {
                continue;
            }
            seen[r as usize] = stamp;
            via.push(r);
            if owner[r as usize] == NONE {
                // Flip the path: each left node on the stack takes the right node after it.
                for (k, &(l, _)) in stack.iter().enumerate() {
                    owner[via[k] as usize] = l;
                }
                done = true;
                break;
            }
            stack.push((owner[r as usize], 0));
        }
        if !done {
            return false;
        }
    }
    true
}

/// Which test accepted a match; the same test re-checks other components of the same mesh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum MatchKind {
    SameOrder,
    Triangles,
}

impl MatchKind {
    pub fn verify(self, c: &Shape, p: &Shape, m: &DMat4, new_mirrored: bool, tol: &Tol) -> bool {
        match self {
            MatchKind::SameOrder => verify_same_order(c, p, m, new_mirrored, tol),
            MatchKind::Triangles => verify_triangles(c, p, m, new_mirrored, tol),
        }
    }
}

/// Shape summary used to prune candidates before any matching.
pub(crate) struct Invariants {
    pub moments: Moments,
    pub area: f64,
    pub perimeter: f64,
}

impl Invariants {
    pub fn of(shape: &Shape) -> Option<Invariants> {
        let moments = Moments::of(&shape.all_points())?;
        let (area, perimeter) = shape.area_perimeter();
        Some(Invariants {
            moments,
            area,
            perimeter,
        })
    }

    /// The quantities [`mismatch`](Self::mismatch) compares.
    pub fn key(&self) -> InvariantKey {
        InvariantKey {
            sigma: self.moments.sigma,
            area: self.area,
            perimeter: self.perimeter,
        }
    }
}

/// The part of [`Invariants`] that candidates are compared by, compact: a component is compared
/// with every prototype near it in invariant space, hundreds in a crowd of near-twins.
#[derive(Debug, Clone, Copy)]
pub(crate) struct InvariantKey {
    pub sigma: [f64; 3],
    pub area: f64,
    pub perimeter: f64,
}

impl InvariantKey {
    /// How far apart the two summaries are, in units of what true copies may differ by (the
    /// largest ratio over the compared quantities): at most 1 for every congruent pair (sound
    /// bounds: every vertex moving by at most δ moves each σ by at most δ, 2δ allowed, and the
    /// area by at most ½·δ·perimeter per triangle), about 0 for exact copies. Above 1, the two
    /// cannot be congruent; below, it orders candidates, nearest first.
    pub fn mismatch(&self, o: &InvariantKey, tol: &Tol) -> f64 {
        let (a, b) = (&self.sigma, &o.sigma);
        if tol.allow_scale {
            let (a0, b0) = (a[0], b[0]);
            if a0 <= 0.0 || b0 <= 0.0 {
                return if a0 == b0 { 0.0 } else { f64::INFINITY };
            }
            let r = 4.0 * tol.pos / a0.min(b0) + 1e-9;
            (1..3)
                .map(|k| (a[k] / a0 - b[k] / b0).abs() / r)
                .fold(0.0, f64::max)
        } else {
            let s_tol = 2.0 * tol.pos + 1e-9 * a[0].max(b[0]);
            let a_tol =
                tol.pos * self.perimeter.max(o.perimeter) + 1e-9 * self.area.max(o.area) + 1e-12;
            (0..3)
                .map(|k| (a[k] - b[k]).abs() / s_tol)
                .fold((self.area - o.area).abs() / a_tol, f64::max)
        }
    }
}

/// What the same-order fit says about a candidate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum SameOrder {
    /// Verified: the motion carries vertex i of the prototype onto vertex i of the candidate.
    Match(Similarity),
    /// The vertex orders correspond (the best fit puts every vertex within
    /// `NEAR_TWIN_FACTOR`·δ of its counterpart) but some vertex is farther than δ: a noisy
    /// copy, not a congruent one.
    NearTwin,
    /// Different layouts, a mirrored winding, or vertices that do not correspond in order.
    No,
}

/// A same-order fit whose every vertex lands within this many tolerances makes the pair a
/// near-twin: copies baked in the same vertex order whose vertices were then moved (noise,
/// rounding of a coarser exporter). The frame search is skipped for such a candidate: with the
/// correspondence known, the least-squares motion is the one ICP would converge to, and another
/// motion would need a vertex permutation that maps the mesh's triangles onto themselves and
/// also undoes the noise. On noisy copies the search spends its ICP runs and finds nothing; on
/// the shared models no match is lost (tests/dedup.rs prints the table; docs/benchmarks.md).
const NEAR_TWIN_FACTOR: f64 = 8.0;

/// The motion (scene frame) that carries prototype `p` onto candidate `c` with vertex i on
/// vertex i (same index buffers), verified. Cheap: one fit, one pass.
pub(crate) fn find_motion_same_order(c: &Shape, p: &Shape, tol: &Tol) -> SameOrder {
    // p's new world is (motion · p's world), with a proper motion: it mirrors iff p's does, and
    // the same index buffers draw the same winding only if c mirrors alike.
    if c.mirrored != p.mirrored || !c.same_layout(p) {
        return SameOrder::No;
    }
    let Some(t) = fit_similarity(p.points(), c.points(), tol.allow_scale) else {
        return SameOrder::No;
    };
    let m = t.to_mat4();
    let near2 = (NEAR_TWIN_FACTOR * tol.pos).powi(2);
    let worst2 = same_order_distance2(c, p, &m, near2);
    if worst2 > tol.pos * tol.pos {
        return if worst2 <= near2 {
            SameOrder::NearTwin
        } else {
            SameOrder::No
        };
    }
    if same_order_attrs(c, p, &m, tol) {
        SameOrder::Match(t)
    } else {
        SameOrder::No
    }
}

/// The motion (scene frame) that carries prototype `p` onto candidate `c` whatever their vertex
/// order, verified triangle by triangle; None when they are not congruent within the tolerance.
/// `icp_budget`: ICP runs left for this candidate (see `ICP_RUNS_PER_CANDIDATE`), spent here.
pub(crate) fn find_motion_search(
    c: &Shape,
    ci: &Invariants,
    p: &Shape,
    pi: &Invariants,
    tol: &Tol,
    icp_budget: &mut usize,
) -> Option<Similarity> {
    let new_mirrored = p.mirrored;
    let cpts = c.all_points();
    let ppts = p.all_points();
    // Both profiles scale with the shape: only used for rigid matching.
    let profiles_agree = tol.allow_scale
        || (same_distance_profile(&cpts, ci, &ppts, pi, tol) && same_area_profile(c, p, tol));
    if !profiles_agree {
        return None;
    }
    let tree = KdTree::new(cpts.clone());
    let mut tried: Vec<Similarity> = Vec::new();
    let step = ppts.len().div_ceil(ICP_SAMPLE).max(1);
    let mut attempt =
        |t0: Similarity, bound: f64, tried: &mut Vec<Similarity>| -> Option<Similarity> {
            if *icp_budget == 0 {
                return None;
            }
            // A proposal with a known error bound is dropped at the first sampled vertex that has
            // no candidate vertex within it: most wrong proposals cost a few lookups.
            if bound.is_finite()
                && !ppts.iter().step_by(step).all(|&x| {
                    tree.nearest(t0.apply(x))
                        .is_some_and(|(_, d2)| d2 <= bound * bound)
                })
            {
                return None;
            }
            *icp_budget -= 1;
            let t = icp(&tree, &ppts, t0, tol)?;
            // Several proposals often converge to the same motion: verify it once.
            if tried.iter().any(|u| same_motion(u, &t, &ppts, tol)) {
                return None;
            }
            tried.push(t);
            verify_triangles(c, p, &t.to_mat4(), new_mirrored, tol).then_some(t)
        };
    for t0 in pca_proposals(&ci.moments, &pi.moments, tol) {
        // Principal axes may be off by an angle that noise and the extents' gaps decide: no
        // useful bound, ICP has to pull these in.
        if let Some(t) = attempt(t0, f64::INFINITY, &mut tried) {
            return Some(t);
        }
    }
    for (t0, bound) in feature_proposals(&cpts, &ci.moments, &ppts, &pi.moments, tol) {
        if let Some(t) = attempt(t0, bound, &mut tried) {
            return Some(t);
        }
    }
    None
}

fn same_motion(a: &Similarity, b: &Similarity, pts: &[DVec3], tol: &Tol) -> bool {
    let step = (pts.len() / 64).max(1);
    pts.iter()
        .step_by(step)
        .all(|&x| a.apply(x).distance(b.apply(x)) <= 0.1 * tol.pos)
}

/// Sorted distances to the centroid agree within 2δ (each moves by at most δ plus the centroid's
/// δ): a cheap, permutation- and motion-invariant rejection before any search.
fn same_distance_profile(
    c: &[DVec3],
    ci: &Invariants,
    p: &[DVec3],
    pi: &Invariants,
    tol: &Tol,
) -> bool {
    if c.len() != p.len() {
        return false;
    }
    let prof = |pts: &[DVec3], cen: DVec3| {
        let mut d: Vec<f64> = pts.iter().map(|x| x.distance(cen)).collect();
        d.sort_unstable_by(f64::total_cmp);
        d
    };
    let (dc, dp) = (prof(c, ci.moments.centroid), prof(p, pi.moments.centroid));
    let t = 2.0 * tol.pos * (1.0 + 1e-9);
    dc.iter().zip(&dp).all(|(a, b)| (a - b).abs() <= t)
}

/// Sorted triangle areas agree within δ·(largest perimeter): moving each vertex by ≤ δ changes a
/// triangle's area by ≤ ½·δ·perimeter (+O(δ²)), and sorting does not increase the largest
/// difference. Rejects the same vertices triangulated differently before any search.
fn same_area_profile(c: &Shape, p: &Shape, tol: &Tol) -> bool {
    let prof = |s: &Shape| {
        let mut areas = Vec::new();
        let mut max_perim = 0f64;
        for pr in &s.prims {
            for t in pr.src().indices.chunks_exact(3) {
                let [a, b, c] = [0, 1, 2].map(|k| pr.pos[t[k] as usize]);
                areas.push(0.5 * (b - a).cross(c - a).length());
                max_perim = max_perim.max(a.distance(b) + b.distance(c) + c.distance(a));
            }
        }
        areas.sort_unstable_by(f64::total_cmp);
        (areas, max_perim)
    };
    let ((ac, pc), (ap, pp)) = (prof(c), prof(p));
    let t = tol.pos * pc.max(pp) + 2.0 * tol.pos * tol.pos + 1e-12;
    ac.len() == ap.len() && ac.iter().zip(&ap).all(|(x, y)| (x - y).abs() <= t)
}

/// Iterative closest point from `t0`: pair every prototype vertex with its nearest candidate
/// vertex, refit, until every pair is within the tolerance (then the motion goes to the exact
/// triangle check) or the pairing stops changing.
fn icp(tree: &KdTree, ppts: &[DVec3], t0: Similarity, tol: &Tol) -> Option<Similarity> {
    // Converge on an evenly spread sample first (a wrong proposal is usually rejected there, at
    // a fraction of the cost), then confirm and polish on every vertex.
    let step = ppts.len().div_ceil(ICP_SAMPLE).max(1);
    let sample: Vec<DVec3> = ppts.iter().step_by(step).copied().collect();
    let mut t = refine(tree, &sample, t0, tol, 16)?;
    if step > 1 {
        t = refine(tree, ppts, t, tol, 4)?;
    }
    Some(t)
}

/// Proposals refined by ICP for one candidate component, over all the prototypes it is searched
/// against: a bound on the work when nothing fits. A near-twin (a noisy copy, every vertex 2 mm
/// off) passes the proposals' bounds and converges just outside the tolerance from every one of
/// up to `MAX_FEATURE_PROPOSALS` per prototype, which can dominate the dedup of noisy copies.
/// (Stopping at the first run that settles within a few tolerances fails: on dense meshes a
/// wrong motion settles there too, and matches are lost.) On the shared models, the matches
/// found are the same as without a bound, with a margin (docs/benchmarks.md).
pub(crate) const ICP_RUNS_PER_CANDIDATE: usize = 32;

/// Vertices used while a proposal converges.
const ICP_SAMPLE: usize = 64;

/// Up to `rounds` ICP steps on `pts`; the motion once every point has a candidate vertex within
/// the tolerance, None if the pairing stops changing first.
fn refine(
    tree: &KdTree,
    pts: &[DVec3],
    t0: Similarity,
    tol: &Tol,
    rounds: usize,
) -> Option<Similarity> {
    let mut t = t0;
    let mut prev: Vec<u32> = Vec::new();
    let mut pairs: Vec<u32> = Vec::with_capacity(pts.len());
    for _ in 0..rounds {
        pairs.clear();
        let mut worst = 0.0f64;
        for &x in pts {
            let (k, d2) = tree.nearest(t.apply(x))?;
            pairs.push(k);
            worst = worst.max(d2);
        }
        if worst <= tol.pos * tol.pos {
            return Some(t);
        }
        if pairs == prev {
            return None;
        }
        t = fit_similarity(
            pts.iter().copied(),
            pairs.iter().map(|&k| tree.point(k)),
            tol.allow_scale,
        )?;
        std::mem::swap(&mut prev, &mut pairs);
    }
    None
}

/// Principal axes closer than this (in σ, metres) are treated as interchangeable: their
/// eigenvectors are then not stable under δ-sized noise.
fn axis_gap(m: &Moments, tol: &Tol) -> f64 {
    8.0 * tol.pos + 0.02 * m.sigma[0]
}

fn frame_motion(fc: DMat3, cc: DVec3, fp: DMat3, cp: DVec3, scale: f64) -> Similarity {
    let rotation = fc * fp.transpose();
    Similarity {
        rotation,
        scale,
        translation: cc - rotation * cp * scale,
    }
}

fn scale_estimate(c: &Moments, p: &Moments, tol: &Tol) -> f64 {
    if tol.allow_scale && p.sigma[0] > 0.0 {
        c.sigma[0] / p.sigma[0]
    } else {
        1.0
    }
}

/// Motions from principal frames, when the three principal extents are well apart in both
/// shapes. Axis k's sign follows the sign of the third moment along it when that is clearly
/// non-zero in both shapes; otherwise both signs are tried. The third axis follows from the
/// first two by the right-hand rule (only proper rotations are proposed).
fn pca_proposals(c: &Moments, p: &Moments, tol: &Tol) -> Vec<Similarity> {
    let distinct = |m: &Moments| {
        let g = axis_gap(m, tol);
        m.sigma[0] - m.sigma[1] > g && m.sigma[1] - m.sigma[2] > g
    };
    if !distinct(c) || !distinct(p) {
        return Vec::new();
    }
    let s = scale_estimate(c, p, tol);
    // |Δ third moment| ≤ ~3σ²·2δ for δ-moves of every point: below twice that, the sign is noise.
    let clear = |m: &Moments, k: usize, scale: f64| {
        m.third[k].abs() > 12.0 * tol.pos * (m.sigma[k] * scale).powi(2) + 1e-15
    };
    let mut sign_options: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    let mut c_sign = [1.0; 2];
    for k in 0..2 {
        if clear(c, k, 1.0) && clear(p, k, s) {
            c_sign[k] = c.third[k].signum();
            sign_options[k] = vec![p.third[k].signum()];
        } else {
            sign_options[k] = vec![1.0, -1.0];
        }
    }
    let frame = |a: DVec3, b: DVec3| DMat3::from_cols(a, b, a.cross(b));
    let fc = frame(c.axes[0] * c_sign[0], c.axes[1] * c_sign[1]);
    let mut out = Vec::new();
    for &s0 in &sign_options[0] {
        for &s1 in &sign_options[1] {
            let fp = frame(p.axes[0] * s0, p.axes[1] * s1);
            out.push(frame_motion(fc, c.centroid, fp, p.centroid, s));
        }
    }
    out
}

/// Most motions proposed from distinctive vertex pairs (symmetric shapes can have many).
const MAX_FEATURE_PROPOSALS: usize = 192;
const MAX_A_CANDIDATES: usize = 64;

/// Motions from distinctive vertices, for shapes whose principal axes are ambiguous (equal
/// extents: a cube, a cylinder, a regular prism). In the candidate: `a` = a vertex farthest from
/// the centroid, `b` = a vertex farthest from the line centroid→a. In the prototype, every vertex
/// pair with the same distances (and the same position along that line) proposes the motion that
/// carries its frame onto the candidate's. Each comes with a bound on how far a true match's
/// vertices can be from where the proposal puts them: the centroids and both features are within
/// ~2δ, so the frame is turned by at most ~2δ/|a| + 2δ/|b⊥|, which moves a vertex at radius r by
/// r times that.
fn feature_proposals(
    cpts: &[DVec3],
    cm: &Moments,
    ppts: &[DVec3],
    pm: &Moments,
    tol: &Tol,
) -> Vec<(Similarity, f64)> {
    let (cc, cp) = (cm.centroid, pm.centroid);
    let s = scale_estimate(cm, pm, tol);
    let Some(a_c) = argmax(cpts, |x| x.distance_squared(cc)) else {
        return Vec::new();
    };
    let ua = a_c - cc;
    let ra = ua.length();
    if ra <= tol.pos {
        // All vertices on the centroid: a point-like shape, only a translation to try.
        return vec![(
            frame_motion(DMat3::IDENTITY, cc, DMat3::IDENTITY, cp, s),
            f64::INFINITY,
        )];
    }
    let axis_c = ua / ra;
    let perp = |x: DVec3, o: DVec3, axis: DVec3| {
        let d = x - o;
        d - axis * d.dot(axis)
    };
    let b_c = argmax(cpts, |x| perp(x, cc, axis_c).length_squared()).unwrap_or(a_c);
    let hb_c = (b_c - cc).dot(axis_c);
    let rb_c = perp(b_c, cc, axis_c).length();
    // Line-like shapes (every vertex on the axis): any turn about the axis is as good.
    let line_like = rb_c <= tol.pos;
    // Turn of a proposed frame against the true one (see above), with a factor 2 of margin; the
    // largest radius is `ra` (a is the farthest vertex).
    let bound = if line_like {
        f64::INFINITY
    } else {
        2.0 * (2.0 * tol.pos + ra * (4.0 * tol.pos / ra + 4.0 * tol.pos / rb_c))
    };
    let frame = |axis: DVec3, side: DVec3| {
        let e1 = side
            .try_normalize()
            .unwrap_or_else(|| axis.any_orthonormal_vector());
        DMat3::from_cols(axis, e1, axis.cross(e1))
    };
    let fc = frame(axis_c, perp(b_c, cc, axis_c));
    // Feature distances agree within 2δ (both the vertex and the centroid move by ≤ δ).
    let t = 2.0 * tol.pos * (1.0 + 1e-9) + 1e-9 * ra;
    let dedup_positions = |mut v: Vec<usize>, pts: &[DVec3]| {
        let mut kept: Vec<usize> = Vec::new();
        v.sort_unstable();
        for i in v.drain(..) {
            // Coincident vertices (split at hard edges) propose the same motion.
            if !kept
                .iter()
                .any(|&k| pts[k].distance_squared(pts[i]) <= (0.1 * tol.pos).powi(2))
            {
                kept.push(i);
            }
        }
        kept
    };
    let a_cands = dedup_positions(
        (0..ppts.len())
            .filter(|&i| (ppts[i].distance(cp) * s - ra).abs() <= t)
            .collect(),
        ppts,
    );
    let mut out = Vec::new();
    // Bounded work on large symmetric shapes (thousands of rim vertices at one radius): the first
    // few dozen distinct `a` candidates, in vertex order. A symmetric mesh matches from any of
    // them; an asymmetric one has few.
    for &ai in a_cands.iter().take(MAX_A_CANDIDATES) {
        let Some(axis_p) = (ppts[ai] - cp).try_normalize() else {
            continue;
        };
        if line_like {
            out.push((
                frame_motion(fc, cc, frame(axis_p, DVec3::ZERO), cp, s),
                bound,
            ));
            continue;
        }
        let b_cands = dedup_positions(
            (0..ppts.len())
                .filter(|&i| {
                    let h = (ppts[i] - cp).dot(axis_p) * s;
                    let r = perp(ppts[i], cp, axis_p).length() * s;
                    (h - hb_c).abs() <= 2.0 * t && (r - rb_c).abs() <= 2.0 * t
                })
                .collect(),
            ppts,
        );
        for &bi in &b_cands {
            let fp = frame(axis_p, perp(ppts[bi], cp, axis_p));
            out.push((frame_motion(fc, cc, fp, cp, s), bound));
            if out.len() >= MAX_FEATURE_PROPOSALS {
                return out;
            }
        }
    }
    out
}

/// The first point where `f` is largest.
fn argmax(pts: &[DVec3], f: impl Fn(DVec3) -> f64) -> Option<DVec3> {
    let mut best: Option<(f64, DVec3)> = None;
    for &x in pts {
        let v = f(x);
        match best {
            Some((b, _)) if v <= b => {}
            _ => best = Some((v, x)),
        }
    }
    best.map(|(_, x)| x)
}
