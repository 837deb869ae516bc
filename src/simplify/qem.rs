//! The edge-collapse core: Garland–Heckbert quadrics with optimal placement,
//! the paper's curvature weighting, angle error control and maximum collapsed
//! edge length, on flat arrays, in passes of non-overlapping collapses.
//!
//! Data layout: *position vertices* carry position, quadric, curvature and
//! lock flag; *wedges* (attribute vertices) point to a position vertex;
//! triangles are wedge triples. Vertex -> corner adjacency (`4 * tri + k`) is
//! a CSR array rebuilt at the start of every pass.
//!
//! Driver (as meshoptimizer's): each pass ranks the live edges (in parallel;
//! the order is a total order on `(cost, u, v)`, so the result does not depend
//! on the thread count), then walks them cheapest first, re-validating each
//! against the current geometry and skipping edges with an endpoint already
//! touched in the pass, until the triangle goal is met or costs exceed 1.5x
//! the cost at the pass's goal rank.
//!
//! Speed:
//! * incremental ranking: only edges with an endpoint in the closed 1-ring
//!   of a collapse of the last pass (*dirty*) are ranked again; the others
//!   keep their entry, and edges found invalid stay out of the order until
//!   their neighbourhood changes;
//! * lazy coverage in exact order: the ranking computes the quadric key of
//!   every edge, the coverage error (~10x the cost of a quadric key) only
//!   when the walk reaches an edge with both endpoints untouched (most edges
//!   of a pass are skipped as touched); the walk merges the edges sorted by
//!   quadric key with a heap of edges whose coverage raised their key, which
//!   is the exact order by full key. The sorted order is built in chunks
//!   (partial selection) as the walk reaches them;
//! * the walk visits edges in cost order, so nearly every load would be a
//!   cache miss: the data of the edges a few steps ahead is prefetched, one
//!   dependent load per stage (`State::prefetch`);
//! * exact early exits: the coverage is skipped when its bound (the larger
//!   squared distance of an endpoint to the new position) cannot raise the
//!   key; coverage and interior checks take the current cost as a threshold
//!   and stop as soon as they cannot exceed it (box and plane distance
//!   bounds before exact point-triangle distances); at apply time the
//!   threshold is raised to what cannot change the outcome (the collapse
//!   stays within the pass goal and below the largest error so far), and
//!   both checks are skipped when how far the endpoints move bounds them
//!   below it (the interior check also per sample point); an edge whose
//!   neighbourhood is untouched since its coverage was computed reuses it;
//!   the ranking reads each vertex's star once for all its edges
//!   (`star_edges`, straight from the CSR) and keeps only the cheapest
//!   placement (a placement one endpoint's term already rules out skips the
//!   other's); the interior check resolves the old star once;
//! * a visited edge resolves its two stars once (`StarTri`: corner and the
//!   other two vertices) for all its checks, and the edge's own triangles,
//!   in both stars, are measured once.
//!
//! Cost: face quadrics weighted by sqrt(area) (border planes by edge length),
//! and the error of a collapse is the larger of
//! * the two endpoints' mean squared plane distances at the new position (not
//!   the mean over the union, which let large surfaces dilute small parts), and
//! * the *coverage* error (`State::coverage2`): squared distance of the old
//!   endpoint positions to the new star and of the new position to the old
//!   star. Plane distances alone let a thin plate or bar be squashed flat and
//!   then lose its last triangles for a few millimetres of plane error (whole
//!   plates and bars of metres vanished). When nothing survives around the
//!   edge the coverage error is the radius of the connected part;
//! * at apply time also the distance of the new triangles' edge midpoints and
//!   centroids to the old star (`State::interior2`; catches triangles cutting
//!   across a concave corner, which vertex checks miss).
//!
//! Part removal (as meshoptimizer's component pruning): every connected part
//! is also a candidate of cost = the square of its radius (half the
//! bounding-box diagonal of the input part) plus its gap to the nearest other
//! part, the gap counted up to the radius (`removal_costs2`), removed whole
//! when the pass reaches that cost.
//! Small closed parts (door handles, bolts) often cannot be collapsed at all
//! (link condition); without this they kept hundreds of triangles and forced
//! far worse collapses elsewhere. Parts with a locked vertex or larger than
//! `max_edge_length_m` are never removed, nor the largest part of each island
//! standing farther than `keep_parts_apart_m` from the rest (`island_keepers`):
//! the removal cost counts the gap only up to the radius, so a small group of
//! parts far from everything else would otherwise go early and leave an error
//! of its whole distance.
//!
//! Placement rules (they keep attribute seams, open borders and non-manifold
//! edges intact — together called *constraint edges*):
//! * a vertex with no incident constraint edge is *free*: it may move anywhere;
//! * a vertex with constraint edges may only slide along one of them, so a
//!   collapse along a constraint edge is placed on that segment, and any other
//!   collapse keeps it fixed;
//! * a locked vertex never moves.

use rayon::prelude::*;
use std::cmp::Ordering;

use glam::DVec3;

use super::hausdorff::closest_point_on_triangle;
use super::quadric::Quadric;

const NONE: u32 = u32::MAX;
/// `NEXT[k]`, `NEXT[k + 1]`: the corners after corner `k` of a triangle.
const NEXT: [usize; 4] = [1, 2, 0, 1];

/// Hint to load the cache line holding `x` (no-op off x86-64).
#[inline(always)]
fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetching is a hint; it never faults, whatever the address.
    unsafe {
        std::arch::x86_64::_mm_prefetch(x as *const T as *const i8, std::arch::x86_64::_MM_HINT_T0);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// Parameters of one run.
#[derive(Clone, Debug)]
pub(crate) struct QemParams {
    pub target_tris: usize,
    pub target_error2: f64,
    pub curvature_weight: f64,
    pub cos_max_angle: f64,
    pub max_edge_len2: f64,
    pub lock_borders: bool,
    pub boundary_weight: f64,
    /// Attributes other than normals present: see [`State::valid`].
    pub strict_wedges: bool,
    /// Parts standing farther apart than this are not all removed ([`island_keepers`]).
    pub keep_apart_m: f64,
}

impl QemParams {
    /// The same parameters with another triangle goal.
    pub fn with_target(&self, target_tris: usize) -> QemParams {
        QemParams {
            target_tris,
            ..self.clone()
        }
    }
}

/// Result of a run (state after the collapses).
pub(crate) struct QemOutput {
    pub pos: Vec<DVec3>,
    /// Lock flags after the run (a vertex that took a locked one's place is
    /// locked).
    pub locked: Vec<bool>,
    pub wedge_pos: Vec<u32>,
    pub attr: Vec<f32>,
    pub tris: Vec<[u32; 3]>,
    /// Largest QEM distance estimate (RMS distance to merged planes) of an
    /// applied collapse, metres.
    pub max_qem_distance: f64,
    /// Longest edge actually collapsed (the paper's maximum folding edge length, III.C(3)),
    /// metres; a connected part dropped whole counts as its diameter.
    pub max_collapsed_edge: f64,
    /// Quadrics and curvature after the run (to carry them over).
    pub quad: Vec<Quadric>,
    pub curv: Vec<f32>,
}

/// An edge of `ranked` (index) whose full key is known, waiting in the
/// deferred heap; ordered as [`rank_cmp`] (reversed: a min-heap).
#[derive(Clone, Copy, PartialEq)]
struct Deferred {
    /// Index in `ranked`.
    ranked: u32,
    /// Its full key (cost).
    key: f64,
    u: u32,
    v: u32,
}
impl Deferred {
    /// Comes before `r` in [`rank_cmp`] order.
    #[inline]
    fn before(&self, r: &Ranked) -> bool {
        self.key
            .total_cmp(&r.key)
            .then(self.u.cmp(&r.u))
            .then(self.v.cmp(&r.v))
            .is_lt()
    }
}
impl Eq for Deferred {}
impl Ord for Deferred {
    fn cmp(&self, o: &Self) -> Ordering {
        o.key
            .total_cmp(&self.key)
            .then(o.u.cmp(&self.u))
            .then(o.v.cmp(&self.v))
    }
}
impl PartialOrd for Deferred {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

/// A ranked edge: `key` is the quadric key, raised to the full key (with
/// the coverage error) once computed; `f > 0` (the curvature factor) while the
/// coverage is still to be computed for placement `p`.
#[derive(Clone, Copy)]
struct Ranked {
    key: f64,
    u: u32,
    v: u32,
    p: DVec3,
    f: f64,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Mobility {
    Fixed,
    Segment,
    Any,
}

/// Wedge pairs `(wedge at u, wedge at v)` of the edge triangles that are
/// one-to-one; those are merged by a collapse.
fn merge_pairs(e: &EdgeInfo) -> ([(u32, u32); MAX_EDGE_TRIS], usize) {
    let m = e.count.min(MAX_EDGE_TRIS);
    let mut merged = [(NONE, NONE); MAX_EDGE_TRIS];
    let mut nm = 0;
    for i in 0..m {
        let (a, b) = e.pairs[i];
        let ok = (0..m).all(|j| {
            let (x, y) = e.pairs[j];
            (x == a) == (y == b)
        });
        if ok && !merged[..nm].contains(&(a, b)) {
            merged[nm] = (a, b);
            nm += 1;
        }
    }
    (merged, nm)
}

/// Up to this many triangles on one edge are tracked for wedge pairing.
const MAX_EDGE_TRIS: usize = 8;

#[derive(Clone, Copy)]
struct EdgeInfo {
    count: usize,
    pairs: [(u32, u32); MAX_EDGE_TRIS],
    opp: [u32; MAX_EDGE_TRIS],
    constraint: bool,
}

impl Default for EdgeInfo {
    fn default() -> Self {
        EdgeInfo {
            count: 0,
            pairs: [(NONE, NONE); MAX_EDGE_TRIS],
            opp: [NONE; MAX_EDGE_TRIS],
            constraint: false,
        }
    }
}

impl EdgeInfo {
    /// One more triangle on the edge: wedges at `u` and `v`, opposite vertex.
    #[inline]
    fn push(&mut self, wu: u32, wv: u32, opp: u32) {
        if self.count < MAX_EDGE_TRIS {
            self.pairs[self.count] = (wu, wv);
            self.opp[self.count] = opp;
        }
        self.count += 1;
    }

    /// Sets `constraint` once every triangle is pushed: anything but two
    /// triangles with the same wedge pairs is a seam, border or
    /// non-manifold edge.
    #[inline]
    fn finish(&mut self) {
        self.constraint = match self.count {
            2 => self.pairs[0] != self.pairs[1],
            _ => true,
        };
    }
}

#[derive(Clone, Copy)]
struct Candidate {
    p: DVec3,
    key: f64,
    dist2: f64,
}

struct Eval {
    cands: [Candidate; 4],
    n: usize,
}

/// A live triangle of a vertex's star, resolved once per edge visit
/// ([`State::gather`]): its corner at the star's centre and its two other
/// vertices, in the triangle's winding order. Each check of a visit reads
/// the star several times; resolving corners through triangles and wedges
/// each time was a good part of the walk.
#[derive(Clone, Copy)]
struct StarTri {
    c: u32,
    a: u32,
    b: u32,
}

struct State<'a> {
    pos: Vec<DVec3>,
    quad: Vec<Quadric>,
    curv: Vec<f32>,
    locked: Vec<bool>,
    alive: Vec<bool>,
    tris: Vec<[u32; 3]>,
    tri_alive: Vec<bool>,
    wedge_pos: Vec<u32>,
    attr: Vec<f32>,
    stride: usize,
    normal_offset: Option<usize>,
    /// CSR vertex -> corners (`4 * tri + k`: decoded by shift and mask, where
    /// `3 * tri + k` took a division), rebuilt at the start of every
    /// pass; dead triangles are filtered when reading.
    off: Vec<u32>,
    corners: Vec<u32>,
    /// Per-pass cache: vertex has an incident constraint edge.
    cflag: Vec<bool>,
    mark: Vec<u32>,
    /// Connected component of each position vertex (input connectivity) and
    /// the squared radius of each component (half its bounding box diagonal).
    comp: Vec<u32>,
    comp_r2: Vec<f64>,
    /// Squared cost of removing each component whole ([`removal_costs2`]).
    comp_removal2: Vec<f64>,
    /// Per component: never removed whole ([`island_keepers`]).
    comp_kept_whole: Vec<bool>,
    gen: u32,
    live: usize,
    p: &'a QemParams,
}

/// The cost of collapsing one edge (u, v) to a placement, with what depends only on the edge
/// (inverse quadric weights, curvature factor, tie-break) computed once. Used by
/// [`State::evaluate`] for each placement, and by the walk for the ranked placement of an edge
/// whose endpoints are untouched since the ranking (its cost is then as ranked, without the
/// solve and the other placements, which are evaluated only if that one is rejected).
struct EdgeCost<'s> {
    qu: &'s Quadric,
    qv: &'s Quadric,
    iu: f64,
    iv: f64,
    factor: f64,
    tie: f64,
}

impl<'s> EdgeCost<'s> {
    #[inline]
    fn new(st: &'s State<'_>, u: u32, v: u32) -> EdgeCost<'s> {
        let (pu, pv) = (st.pos[u as usize], st.pos[v as usize]);
        let (qu, qv) = (&st.quad[u as usize], &st.quad[v as usize]);
        let inv = |w: f64| if w > 0.0 { 1.0 / w } else { 0.0 };
        EdgeCost {
            qu,
            qv,
            iu: inv(qu.weight),
            iv: inv(qv.weight),
            factor: st.factor(u, v),
            tie: 1e-10 * (pu - pv).length_squared(),
        }
    }

    #[inline]
    fn at(&self, p: DVec3) -> Candidate {
        // The error of a collapse is the larger of the two endpoints' mean squared distances
        // to their own planes (as in meshoptimizer, which uses the removed vertex's quadric
        // only): averaging over the union of planes would dilute the planes of a small part
        // (the end cap of a bar) by the large ones of its neighbour.
        let d2 = (self.qu.eval(p) * self.iu).max(self.qv.eval(p) * self.iv);
        Candidate {
            p,
            key: d2 * self.factor + self.tie,
            dist2: d2,
        }
    }

    /// The key of [`EdgeCost::at`] if it is below `best` (total order), else `None`; the key is
    /// never below either endpoint's term, so one term at or above `best` settles it. `at_u`:
    /// `p` is `u`'s position, where `u`'s own term is usually 0, so `v`'s is tried first.
    #[inline]
    fn key_below(&self, p: DVec3, best: f64, at_u: bool) -> Option<f64> {
        let (first, iq, second, is) = if at_u {
            (self.qv, self.iv, self.qu, self.iu)
        } else {
            (self.qu, self.iu, self.qv, self.iv)
        };
        let a = first.eval(p) * iq;
        if (a * self.factor + self.tie).total_cmp(&best).is_ge() && !a.is_nan() {
            return None;
        }
        let b = second.eval(p) * is;
        // In `at`'s order (`max` may pick either zero of ±0).
        let d2 = if at_u { b.max(a) } else { a.max(b) };
        let key = d2 * self.factor + self.tie;
        key.total_cmp(&best).is_lt().then_some(key)
    }
}

impl State<'_> {
    #[inline]
    fn corner_wedge(&self, c: u32) -> u32 {
        self.tris[(c >> 2) as usize][(c & 3) as usize]
    }

    /// Other two vertices of the triangle of corner `c`.
    #[inline]
    fn corner_others(&self, c: u32) -> (u32, u32) {
        let t = &self.tris[(c >> 2) as usize];
        let k = (c & 3) as usize;
        (
            self.wedge_pos[t[NEXT[k]] as usize],
            self.wedge_pos[t[NEXT[k + 1]] as usize],
        )
    }

    /// Software prefetch of the data the walk will read for edge (u, v), in
    /// stages of one dependent load each (`stage` 0: the vertices' own
    /// entries; 1: their CSR corners; 2: the corners' triangles; 3: the
    /// triangles' wedges; 4: the neighbours' positions). Issued for edges a
    /// few steps ahead in the order, each stage reading what the previous
    /// one fetched: the walk visits edges in cost order, so without this
    /// nearly every load is a cache miss.
    #[inline]
    fn prefetch(&self, u: u32, v: u32, stage: u32, touched: &[bool]) {
        for x in [u, v] {
            let x = x as usize;
            match stage {
                0 => {
                    prefetch(&touched[x]);
                    prefetch(&self.off[x]);
                    prefetch(&self.pos[x]);
                }
                _ => {
                    if touched[x] {
                        return;
                    }
                    let (a, b) = (self.off[x] as usize, self.off[x + 1] as usize);
                    if stage == 1 {
                        prefetch(&self.corners[a]);
                        prefetch(&self.corners[b.saturating_sub(1).max(a)]);
                        continue;
                    }
                    for &c in &self.corners[a..b] {
                        let t = (c >> 2) as usize;
                        match stage {
                            2 => {
                                prefetch(&self.tris[t]);
                                prefetch(&self.tri_alive[t]);
                            }
                            3 => {
                                // The other two corners' wedges (the own one
                                // maps to `x`, whose entries stage 0 fetched).
                                let tr = &self.tris[t];
                                let k = (c & 3) as usize;
                                prefetch(&self.wedge_pos[tr[NEXT[k]] as usize]);
                                prefetch(&self.wedge_pos[tr[NEXT[k + 1]] as usize]);
                                // The vertex's own wedge: its attributes
                                // are interpolated by `apply`.
                                if let Some(a) = self.attr.get(tr[k] as usize * self.stride) {
                                    prefetch(a);
                                }
                            }
                            _ => {
                                let tr = &self.tris[t];
                                let k = (c & 3) as usize;
                                for w in [tr[NEXT[k]], tr[NEXT[k + 1]]] {
                                    let y = self.wedge_pos[w as usize] as usize;
                                    prefetch(&self.pos[y]);
                                    prefetch(&self.mark[y]);
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// Live triangles of `x`'s star into `out` (from the per-pass CSR).
    /// The centre of every one is `x` itself while `x` is untouched in the
    /// pass (a collapse rewrites only the dead endpoint's corners).
    #[inline]
    fn gather(&self, x: u32, out: &mut Vec<StarTri>) {
        out.clear();
        let (a, b) = (
            self.off[x as usize] as usize,
            self.off[x as usize + 1] as usize,
        );
        for &c in &self.corners[a..b] {
            if self.tri_alive[(c >> 2) as usize] {
                let (a, b) = self.corner_others(c);
                out.push(StarTri { c, a, b });
            }
        }
    }

    /// Corners of `x` straight from the CSR: all live between
    /// [`State::rebuild_csr`] and the first collapse of the pass (the
    /// ranking), so no copy is needed there.
    #[inline]
    fn csr_star(&self, x: u32) -> &[u32] {
        &self.corners[self.off[x as usize] as usize..self.off[x as usize + 1] as usize]
    }

    /// Rebuilds the CSR adjacency from the live triangles.
    fn rebuild_csr(&mut self) {
        let nv = self.pos.len();
        self.off.clear();
        self.off.resize(nv + 1, 0);
        for (t, &alive) in self.tris.iter().zip(&self.tri_alive) {
            if alive {
                for &w in t {
                    self.off[self.wedge_pos[w as usize] as usize + 1] += 1;
                }
            }
        }
        for i in 0..nv {
            self.off[i + 1] += self.off[i];
        }
        self.corners.clear();
        self.corners.resize(self.off[nv] as usize, 0);
        let mut fill: Vec<u32> = self.off[..nv].to_vec();
        for (ti, (t, &alive)) in self.tris.iter().zip(&self.tri_alive).enumerate() {
            if alive {
                for (k, &w) in t.iter().enumerate() {
                    let x = self.wedge_pos[w as usize] as usize;
                    self.corners[fill[x] as usize] = 4 * ti as u32 + k as u32;
                    fill[x] += 1;
                }
            }
        }
    }

    fn next_gen(&mut self) -> u32 {
        self.gen = self.gen.wrapping_add(2);
        if self.gen < 2 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.gen = 2;
        }
        self.gen
    }

    /// True if `x` has an incident constraint edge (seam, border or
    /// non-manifold edge).
    fn constrained(&self, star: &[u32], s: &mut Vec<u32>) -> bool {
        let Some(&c0) = star.first() else {
            return false;
        };
        let w0 = self.corner_wedge(c0);
        if star.iter().any(|&c| self.corner_wedge(c) != w0) {
            return true;
        }
        s.clear();
        for &c in star {
            let (a, b) = self.corner_others(c);
            s.push(a);
            s.push(b);
        }
        s.sort_unstable();
        let mut res = false;
        let mut i = 0;
        while i < s.len() {
            let mut j = i + 1;
            while j < s.len() && s[j] == s[i] {
                j += 1;
            }
            if j - i != 2 {
                res = true;
                break;
            }
            i = j;
        }
        res
    }

    /// The triangles of edge `(u, v)` seen from `u`'s star `star_u`.
    fn edge_info(&self, v: u32, star_u: &[StarTri]) -> EdgeInfo {
        let mut e = EdgeInfo::default();
        for s in star_u {
            if s.a != v && s.b != v {
                continue;
            }
            let t = &self.tris[(s.c >> 2) as usize];
            let k = (s.c & 3) as usize;
            let (w1, w2) = (t[NEXT[k]], t[NEXT[k + 1]]);
            if s.a == v {
                e.push(t[k], w1, s.b);
            } else {
                e.push(t[k], w2, s.a);
            }
        }
        e.finish();
        e
    }

    /// [`State::edge_info`] of every edge `(a, b)` with `b > a`, in one scan
    /// of `a`'s star (ranking called `edge_info` per edge: a scan of the
    /// star per neighbour). Order: first appearance of `b` in the star.
    /// `lower(b)`: also list the edge when `b < a` (its pairs are then
    /// still seen from `a`; the ranking only reads `count` and
    /// `constraint`, which do not depend on the side).
    fn star_edges(
        &self,
        a: u32,
        star: &[u32],
        lower: impl Fn(u32) -> bool,
        out: &mut Vec<(u32, EdgeInfo)>,
    ) {
        out.clear();
        for &c in star {
            let t = &self.tris[(c >> 2) as usize];
            let k = (c & 3) as usize;
            let (w1, w2) = (t[NEXT[k]], t[NEXT[k + 1]]);
            let (x1, x2) = (self.wedge_pos[w1 as usize], self.wedge_pos[w2 as usize]);
            // As `edge_info`: a corner counts once, for `x1` first.
            for (b, wb, o) in [(x1, w1, x2), (x2, w2, x1)] {
                if b == a || (b < a && !lower(b)) || (b == x2 && x1 == x2) {
                    continue;
                }
                let i = match out.iter().position(|(y, _)| *y == b) {
                    Some(i) => i,
                    None => {
                        out.push((b, EdgeInfo::default()));
                        out.len() - 1
                    }
                };
                out[i].1.push(t[k], wb, o);
            }
        }
        out.iter_mut().for_each(|(_, e)| e.finish());
    }

    fn mobility(&self, x: u32, constrained: bool, edge_constraint: bool) -> Mobility {
        if self.locked[x as usize] {
            Mobility::Fixed
        } else if constrained {
            if edge_constraint {
                Mobility::Segment
            } else {
                Mobility::Fixed
            }
        } else {
            Mobility::Any
        }
    }

    /// Candidate placements of collapsing edge (u, v), cheapest first.
    /// `e`: [`State::edge_info`] of the edge; constraint flags from
    /// [`State::cflag`].
    fn evaluate(&self, u: u32, v: u32, e: &EdgeInfo) -> Option<Eval> {
        let (pts, n) = self.placements(u, v, e)?;
        let mut cands = [Candidate {
            p: DVec3::ZERO,
            key: 0.0,
            dist2: 0.0,
        }; 4];
        let cost = EdgeCost::new(self, u, v);
        for i in 0..n {
            cands[i] = cost.at(pts[i]);
        }
        cands[..n].sort_by(|a, b| a.key.total_cmp(&b.key));
        Some(Eval { cands, n })
    }

    /// The cheapest candidate of [`State::evaluate`] (the first of equal
    /// keys, as its stable sort), its key and placement only: what the
    /// ranking needs, without the sort and with the second quadric skipped
    /// for placements the first already rules out.
    fn evaluate_best(&self, u: u32, v: u32, e: &EdgeInfo) -> Option<(f64, DVec3)> {
        let (pts, n) = self.placements(u, v, e)?;
        let cost = EdgeCost::new(self, u, v);
        let pu = self.pos[u as usize];
        let mut best = (cost.at(pts[0]).key, pts[0]);
        for &p in &pts[1..n] {
            if let Some(k) = cost.key_below(p, best.0, p == pu) {
                best = (k, p);
            }
        }
        Some(best)
    }

    /// Candidate placements of collapsing edge (u, v) (see [`State::evaluate`]).
    fn placements(&self, u: u32, v: u32, e: &EdgeInfo) -> Option<([DVec3; 4], usize)> {
        if !self.alive[u as usize] || !self.alive[v as usize] {
            return None;
        }
        let (pu, pv) = (self.pos[u as usize], self.pos[v as usize]);
        if (pu - pv).length_squared() > self.p.max_edge_len2 {
            return None;
        }
        if e.count == 0 {
            return None;
        }
        let cu = self.cflag[u as usize];
        let cv = self.cflag[v as usize];
        let mu = self.mobility(u, cu, e.constraint);
        let mv = self.mobility(v, cv, e.constraint);
        let q = Quadric::sum(&self.quad[u as usize], &self.quad[v as usize]);
        let mut pts = [DVec3::ZERO; 4];
        let mut n = 0;
        match (mu, mv) {
            (Mobility::Fixed, Mobility::Fixed) => return None,
            (Mobility::Fixed, _) => {
                pts[0] = pu;
                n = 1;
            }
            (_, Mobility::Fixed) => {
                pts[0] = pv;
                n = 1;
            }
            (Mobility::Any, Mobility::Any) => {
                let mid = (pu + pv) * 0.5;
                let len2 = (pu - pv).length_squared();
                if let Some(x) = q.optimize() {
                    // Far-away optima come from ill-conditioned quadrics.
                    if (x - mid).length_squared() <= 4.0 * len2 {
                        pts[n] = x;
                        n += 1;
                    }
                }
                pts[n] = mid;
                pts[n + 1] = pu;
                pts[n + 2] = pv;
                n += 3;
            }
            _ => {
                pts[0] = q.optimize_on_segment(pu, pv);
                pts[1] = pu;
                pts[2] = pv;
                n = 3;
            }
        }
        Some((pts, n))
    }

    /// Topology check of collapsing (u, v), whatever the placement: the
    /// link condition (common neighbours must be the edge's opposite
    /// vertices). Checked once per edge, not per candidate placement.
    fn link_ok(&mut self, u: u32, v: u32, su: &[StarTri], sv: &[StarTri], e: &EdgeInfo) -> bool {
        let g = self.next_gen();
        for s in su {
            self.mark[s.a as usize] = g;
            self.mark[s.b as usize] = g;
        }
        let mut common = 0;
        for s in sv {
            for x in [s.a, s.b] {
                if x != u && x != v && self.mark[x as usize] == g {
                    self.mark[x as usize] = g + 1;
                    common += 1;
                }
            }
        }
        let mut opp = 0;
        for i in 0..e.count.min(MAX_EDGE_TRIS) {
            if !e.opp[..i].contains(&e.opp[i]) {
                opp += 1;
            }
        }
        common <= opp
    }

    /// Wedge / flip / angle checks for collapsing (u, v) to `p` (after
    /// [`State::link_ok`]).
    fn valid(
        &self,
        u: u32,
        v: u32,
        p: DVec3,
        su: &[StarTri],
        sv: &[StarTri],
        e: &EdgeInfo,
    ) -> bool {
        if self.p.strict_wedges {
            // With UVs/colours, a vertex may only move if each of its wedges
            // is merged with a wedge across the edge (else the texture seam
            // would be dragged with stale attributes).
            let (merged, nm) = merge_pairs(e);
            for (star, x, side) in [(su, u, 0), (sv, v, 1)] {
                if self.pos[x as usize] == p {
                    continue;
                }
                for s in star {
                    let w = self.corner_wedge(s.c);
                    let found =
                        merged[..nm]
                            .iter()
                            .any(|pr| if side == 0 { pr.0 == w } else { pr.1 == w });
                    if !found {
                        return false;
                    }
                }
            }
        }
        let cos_lim = self.p.cos_max_angle.max(0.0);
        for (star, x) in [(su, u), (sv, v)] {
            let px = self.pos[x as usize];
            for &StarTri { a, b, .. } in star {
                if a == u || a == v || b == u || b == v {
                    continue; // a triangle on the collapsed edge
                }
                let (pa, pb) = (self.pos[a as usize], self.pos[b as usize]);
                let n0 = (pa - px).cross(pb - px);
                let n1 = (pa - p).cross(pb - p);
                let l0 = n0.length_squared();
                let l1 = n1.length_squared();
                if l1.is_nan() || l1 <= 1e-12 * l0 {
                    return false;
                }
                let d = n0.dot(n1);
                if d <= 0.0 || d * d <= cos_lim * cos_lim * l0 * l1 {
                    return false;
                }
            }
        }
        true
    }

    /// Curvature factor of the cost of collapsing (u, v).
    #[inline]
    fn factor(&self, u: u32, v: u32) -> f64 {
        1.0 + self.p.curvature_weight * self.curv[u as usize].max(self.curv[v as usize]) as f64
    }

    /// One-step coverage error of collapsing (u, v) to `p`: the larger squared
    /// distance of the old positions of `u` and `v` to the new star (the
    /// surviving triangles around `p`) and of `p` to the old star; the squared
    /// radius of the part if nothing survives. Only values above `t` are
    /// exact: a result `<= t` means the error is `<= t`.
    fn coverage2(&self, u: u32, v: u32, p: DVec3, su: &[StarTri], sv: &[StarTri], t: f64) -> f64 {
        let (pu, pv) = (self.pos[u as usize], self.pos[v as usize]);
        // Exact shortcuts: `p` at an endpoint is a vertex of the old star
        // (dp = 0) and of every new triangle (distance of that endpoint 0).
        let (at_u, at_v) = (p == pu, p == pv);
        let need_p = !at_u && !at_v;
        let mut du = if at_u { 0.0 } else { f64::INFINITY };
        let mut dv = if at_v { 0.0 } else { f64::INFINITY };
        let mut dp = if need_p { f64::INFINITY } else { 0.0 };
        let mut survives = false;
        for (star, px, other) in [(su, pu, NONE), (sv, pv, u)] {
            for &StarTri { a, b, .. } in star {
                if survives && du <= t && dv <= t && dp <= t {
                    // Each minimum is below the threshold: the result is too.
                    return du.max(dv).max(dp);
                }
                let (pa, pb) = (self.pos[a as usize], self.pos[b as usize]);
                // (The edge's own triangles are in both stars: measured from `u`'s.)
                if dp > t && a != other && b != other {
                    dp = tri_dist2_min(p, px, pa, pb, dp);
                }
                if a == u || a == v || b == u || b == v {
                    continue;
                }
                survives = true;
                if du <= t && dv <= t {
                    continue;
                }
                // The new triangle (p, pa, pb): one normal for both endpoints.
                let n = (pa - p).cross(pb - p);
                let l2 = n.length_squared();
                let upd = |q: DVec3, d: f64| -> f64 {
                    if d <= t {
                        return d;
                    }
                    if l2 > 0.0 {
                        let h = n.dot(q - p);
                        if h * h >= d * l2 {
                            return d;
                        }
                    }
                    d.min((closest_point_on_triangle(q, p, pa, pb) - q).length_squared())
                };
                du = upd(pu, du);
                dv = upd(pv, dv);
            }
        }
        if !survives {
            // Nothing survives around the edge: the part (or this end of it)
            // vanishes; its size is the error.
            return self.comp_r2[self.comp[v as usize] as usize];
        }
        du.max(dv).max(dp)
    }

    /// Upper bound of [`State::coverage2`] when some triangle of `u`'s star
    /// (`su_len` triangles; `e`: [`State::edge_info`] of the edge) is not
    /// on the edge (u, v): `p` is a vertex of every new triangle and `u`,
    /// `v` are vertices of the old star.
    fn coverage2_bound(
        &self,
        u: u32,
        v: u32,
        p: DVec3,
        su_len: usize,
        e: &EdgeInfo,
    ) -> Option<f64> {
        // The triangles of the star on the edge are the ones `e` counted.
        if e.count >= su_len {
            return None;
        }
        let (pu, pv) = (self.pos[u as usize], self.pos[v as usize]);
        Some((pu - p).length_squared().max((pv - p).length_squared()))
    }

    /// Squared distance from sample points of the new triangles around `p`
    /// (edge midpoints and centroids) to the old surface around the edge,
    /// or `t` if it is not larger (early exits). `old`: scratch for the old
    /// star with its normals (each point scans it, so it is resolved once).
    #[allow(clippy::too_many_arguments)]
    fn interior2(
        &mut self,
        u: u32,
        v: u32,
        p: DVec3,
        su: &[StarTri],
        sv: &[StarTri],
        t: f64,
        old: &mut Vec<OldTri>,
    ) -> f64 {
        let mut worst: f64 = t.max(0.0);
        old.clear();
        let (pu, pv) = (self.pos[u as usize], self.pos[v as usize]);
        // The edge's own triangles are in both stars: kept once, from `u`'s.
        let stars = su
            .iter()
            .map(|s| (s, pu))
            .chain(sv.iter().filter(|s| s.a != u && s.b != u).map(|s| (s, pv)));
        for (&StarTri { a, b, .. }, px) in stars {
            let (pa, pb) = (self.pos[a as usize], self.pos[b as usize]);
            let n = (pa - px).cross(pb - px);
            old.push(OldTri {
                px,
                pa,
                pb,
                n,
                l2: n.length_squared(),
                lo: px.min(pa).min(pb),
                hi: px.max(pa).max(pb),
                a,
                b,
                survives: !(a == u || a == v || b == u || b == v),
                spoke_a: false,
                spoke_b: false,
            });
        }
        // A spoke (p, a) is shared by two new triangles: its midpoint is
        // measured once, with the first (marks: vertices of earlier ones).
        let g = self.next_gen();
        for o in old.iter_mut().filter(|o| o.survives) {
            o.spoke_a = self.mark[o.a as usize] != g;
            o.spoke_b = self.mark[o.b as usize] != g;
            self.mark[o.a as usize] = g;
            self.mark[o.b as usize] = g;
        }
        for (i, tr) in old.iter().enumerate() {
            if !tr.survives || tr.px == p {
                continue; // on the edge, or the new triangle is the old one
            }
            let (pa, pb) = (tr.pa, tr.pb);
            // A point is within (its weight of `p`) x (how far `x` moved) of
            // the old triangle's matching point: those bounds below `worst`
            // (with a margin for rounding) cannot raise it.
            let m2 = (p - tr.px).length_squared() * (1.0 + 1e-3);
            let (spokes, centroid) = (0.25 * m2 >= worst, m2 / 9.0 >= worst);
            let pts = [
                (spokes && tr.spoke_a, (p + pa) * 0.5),
                (spokes && tr.spoke_b, (p + pb) * 0.5),
                (centroid, (p + pa + pb) / 3.0),
            ];
            for (_, q) in pts.into_iter().filter(|x| x.0) {
                // The old triangle this one replaces first (often the
                // nearest: an early exit for the rest).
                let mut d = tr.dist2_min(q, f64::INFINITY);
                if d <= worst {
                    continue;
                }
                for (j, o) in old.iter().enumerate() {
                    if j != i {
                        d = o.dist2_min(q, d);
                        if d <= worst {
                            break;
                        }
                    }
                }
                worst = worst.max(d);
            }
        }
        worst
    }

    fn apply(&mut self, u: u32, v: u32, p: DVec3, dist2: f64, su: &[StarTri], e: &EdgeInfo) -> f64 {
        let (pu, pv) = (self.pos[u as usize], self.pos[v as usize]);
        let d = pv - pu;
        let t = if d.length_squared() > 0.0 {
            ((p - pu).dot(d) / d.length_squared()).clamp(0.0, 1.0) as f32
        } else {
            0.5
        };
        // 1:1 wedge pairs across the edge are merged (attributes interpolated).
        let (merged, nm) = merge_pairs(e);
        let s = self.stride;
        for &(wu, wv) in &merged[..nm] {
            let (bu, bv) = (wu as usize * s, wv as usize * s);
            for k in 0..s {
                self.attr[bv + k] = self.attr[bu + k] * (1.0 - t) + self.attr[bv + k] * t;
            }
            if let Some(o) = self.normal_offset {
                let nrm = &mut self.attr[bv + o..bv + o + 3];
                let l = (nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]).sqrt();
                if l > 0.0 {
                    nrm.iter_mut().for_each(|x| *x /= l);
                }
            }
        }
        for &StarTri { c, a, b } in su {
            let ti = (c >> 2) as usize;
            if !self.tri_alive[ti] {
                continue;
            }
            if a == v || b == v {
                self.tri_alive[ti] = false;
                self.live -= 1;
                continue;
            }
            let k = (c & 3) as usize;
            let w = self.tris[ti][k];
            if let Some(&(_, wv)) = merged[..nm].iter().find(|x| x.0 == w) {
                self.tris[ti][k] = wv;
            } else {
                self.wedge_pos[w as usize] = v;
            }
        }
        self.pos[v as usize] = p;
        let qu = self.quad[u as usize];
        self.quad[v as usize].add(&qu);
        self.curv[v as usize] = self.curv[v as usize].max(self.curv[u as usize]);
        self.alive[u as usize] = false;
        self.locked[v as usize] |= self.locked[u as usize];
        dist2
    }
}

/// A triangle of the old star around an edge (as seen from its vertex `x`,
/// then `a`, `b`) with its normal `n = (pa - px) x (pb - px)`, `l2 = |n|²`.
#[derive(Clone, Copy)]
struct OldTri {
    px: DVec3,
    pa: DVec3,
    pb: DVec3,
    n: DVec3,
    l2: f64,
    /// Bounding box: points whose box distance is not below the best so
    /// far skip the exact test (most of the star, for a point on one side).
    lo: DVec3,
    hi: DVec3,
    a: u32,
    b: u32,
    /// Not on the collapsed edge (it survives with `x` moved).
    survives: bool,
    /// Its new triangle is the first with the spoke to `a` / `b`.
    spoke_a: bool,
    spoke_b: bool,
}

impl OldTri {
    /// `min(best, squared distance from q to this triangle)`, as
    /// [`tri_dist2_min`] with the normal already known.
    #[inline]
    fn dist2_min(&self, q: DVec3, best: f64) -> f64 {
        let d = (self.lo - q).max(q - self.hi).max(DVec3::ZERO);
        if d.length_squared() >= best {
            return best;
        }
        if self.l2 > 0.0 {
            let h = self.n.dot(q - self.px);
            if h * h >= best * self.l2 {
                return best;
            }
        }
        best.min((closest_point_on_triangle(q, self.px, self.pa, self.pb) - q).length_squared())
    }
}

/// `min(best, squared distance from q to triangle (a, b, c))`, skipping the
/// exact computation when the plane distance alone is not smaller.
#[inline]
fn tri_dist2_min(q: DVec3, a: DVec3, b: DVec3, c: DVec3, best: f64) -> f64 {
    let n = (b - a).cross(c - a);
    let l2 = n.length_squared();
    if l2 > 0.0 {
        let h = n.dot(q - a);
        if h * h >= best * l2 {
            return best;
        }
    }
    best.min((closest_point_on_triangle(q, a, b, c) - q).length_squared())
}

/// Ranking output and scratch of one chunk of vertices: entries, the edges
/// of a star.
type RankBuf = (Vec<Ranked>, Vec<(u32, EdgeInfo)>);

/// Total order of the walk: key, then endpoints.
#[inline]
fn rank_cmp(a: &Ranked, b: &Ranked) -> Ordering {
    a.key
        .total_cmp(&b.key)
        .then(a.u.cmp(&b.u))
        .then(a.v.cmp(&b.v))
}

/// Extends the sorted prefix `ranked[..m]` to `ranked[..want]`: the next
/// `want - m` smallest entries are selected from the rest and sorted.
fn extend_order(ranked: &mut [Ranked], m: &mut usize, want: usize) {
    let n = ranked.len();
    if want <= *m {
        return;
    }
    if want < n {
        ranked[*m..].select_nth_unstable_by(want - *m, rank_cmp);
    }
    ranked[*m..want].par_sort_unstable_by(rank_cmp);
    *m = want;
}

/// Connected components of the position vertices and their squared radii.
pub(crate) fn components(
    pos: &[DVec3],
    wedge_pos: &[u32],
    tris: &[[u32; 3]],
) -> (Vec<u32>, Vec<f64>) {
    let (comp, lo, hi) = component_boxes(pos, wedge_pos, tris);
    (comp, radii2(&lo, &hi))
}

/// Squared radius (half the box diagonal) of each component.
fn radii2(lo: &[DVec3], hi: &[DVec3]) -> Vec<f64> {
    lo.iter()
        .zip(hi)
        .map(|(l, h)| 0.25 * (*h - *l).length_squared())
        .collect()
}

/// The root of `x`'s set in a union-find forest (path halving).
fn find_root(p: &mut [u32], mut x: u32) -> u32 {
    while p[x as usize] != x {
        p[x as usize] = p[p[x as usize] as usize];
        x = p[x as usize];
    }
    x
}

/// Joins the sets of `a` and `b` (the smaller root stays).
fn join(p: &mut [u32], a: u32, b: u32) {
    let (a, b) = (find_root(p, a), find_root(p, b));
    if a != b {
        p[a.max(b) as usize] = a.min(b);
    }
}

/// Connected components of the position vertices (per vertex) and each one's bounding box.
fn component_boxes(
    pos: &[DVec3],
    wedge_pos: &[u32],
    tris: &[[u32; 3]],
) -> (Vec<u32>, Vec<DVec3>, Vec<DVec3>) {
    let nv = pos.len();
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    for t in tris {
        let v = t.map(|w| wedge_pos[w as usize]);
        for k in 1..3 {
            join(&mut parent, v[0], v[k]);
        }
    }
    let mut comp = vec![0u32; nv];
    let mut id = vec![u32::MAX; nv];
    let mut lo: Vec<DVec3> = Vec::new();
    let mut hi: Vec<DVec3> = Vec::new();
    for x in 0..nv {
        let r = find_root(&mut parent, x as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = lo.len() as u32;
            lo.push(pos[x]);
            hi.push(pos[x]);
        }
        let c = id[r];
        comp[x] = c;
        lo[c as usize] = lo[c as usize].min(pos[x]);
        hi[c as usize] = hi[c as usize].max(pos[x]);
    }
    (comp, lo, hi)
}

/// Squared cost of removing each component whole: its radius plus its gap, the distance from its
/// box to the nearest other component's box (a lower bound of how far the rest of the mesh is
/// from its points), the gap counted up to the radius. The radius alone lets small parts standing
/// apart go first, leaving an error as large as their gap; counting the whole gap keeps widely
/// scattered parts so long that coarse levels get worse (both measured: docs/benchmarks.md).
/// With no other component the mesh's diagonal stands for the gap.
fn removal_costs2(lo: &[DVec3], hi: &[DVec3]) -> Vec<f64> {
    let gaps = crate::geometry::box_gaps(lo, hi);
    (0..lo.len())
        .map(|c| {
            let r = 0.5 * (hi[c] - lo[c]).length();
            let g = gaps[c].min(r);
            (r + g) * (r + g)
        })
        .collect()
}

/// The components never to remove whole, given `keep_apart_m`: components whose boxes lie within
/// it of each other form islands (linked in chains), and every point of an island is farther than
/// it from any other island's. An island removed whole would leave at least that error, so each
/// keeps its largest component (the others may go: that one stays near them). None with an
/// infinite distance.
fn island_keepers(lo: &[DVec3], hi: &[DVec3], keep_apart_m: f64) -> Vec<bool> {
    let n = lo.len();
    let mut keep = vec![false; n];
    if !keep_apart_m.is_finite() || n == 0 {
        return keep;
    }
    let mut parent: Vec<u32> = (0..n as u32).collect();
    // Sweep along the axis the boxes spread widest (a tower's parts share their x range): only
    // boxes whose ranges on it come within the distance can be linked.
    let (first, last) = lo.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(a, b), l| (a.min(*l), b.max(*l)),
    );
    let axis = (last - first).max_position();
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_unstable_by(|&a, &b| lo[a as usize][axis].total_cmp(&lo[b as usize][axis]));
    for (k, &a) in order.iter().enumerate() {
        let (la, ha) = (lo[a as usize], hi[a as usize]);
        for &b in &order[k + 1..] {
            let (lb, hb) = (lo[b as usize], hi[b as usize]);
            if lb[axis] - ha[axis] > keep_apart_m {
                break;
            }
            if crate::geometry::box_gap(la, ha, lb, hb) <= keep_apart_m {
                join(&mut parent, a, b);
            }
        }
    }
    // Per island, its largest component (by box diagonal; ties: the first).
    let mut largest = vec![(f64::NEG_INFINITY, u32::MAX); n];
    for c in 0..n as u32 {
        let size = (hi[c as usize] - lo[c as usize]).length_squared();
        let island = &mut largest[find_root(&mut parent, c) as usize];
        if size > island.0 {
            *island = (size, c);
        }
    }
    for &(_, c) in largest.iter().filter(|l| l.1 != u32::MAX) {
        keep[c as usize] = true;
    }
    keep
}

/// Face quadrics of the position vertices: each triangle's plane, weighted
/// by sqrt(area), added to its three vertices.
fn face_quadrics(pos: &[DVec3], wedge_pos: &[u32], tris: &[[u32; 3]]) -> Vec<Quadric> {
    let mut quad = vec![Quadric::default(); pos.len()];
    for t in tris {
        let v = t.map(|w| wedge_pos[w as usize] as usize);
        if let Some(mut q) = Quadric::from_triangle(pos[v[0]], pos[v[1]], pos[v[2]]) {
            // Weight sqrt(area) instead of area (as meshoptimizer): small
            // faces (thin plates, small parts) keep more say in the mean.
            let s = 1.0 / q.weight.sqrt();
            q.a.iter_mut().for_each(|x| *x *= s);
            q.b.iter_mut().for_each(|x| *x *= s);
            q.c *= s;
            q.weight *= s;
            for &x in &v {
                quad[x].add(&q);
            }
        }
    }
    quad
}

/// Border edges (one triangle): a plane through the edge, perpendicular to
/// its triangle, added to both vertices' quadrics (weighted by the edge's
/// length), and the vertices locked if `lock_borders`. `su`: scratch.
fn add_border_planes(st: &mut State, locked: &mut [bool], su: &mut Vec<StarTri>) {
    let nv = st.pos.len();
    // Triangles of `a`'s star at each neighbour (a count per neighbour, not
    // a scan of the star per neighbour), reset after each star.
    let mut at = vec![0u32; nv];
    for a in 0..nv as u32 {
        st.gather(a, su);
        for s in su.iter() {
            at[s.a as usize] += 1;
            at[s.b as usize] += 1;
        }
        for &StarTri { a: n1, b: n2, .. } in su.iter() {
            for (b, other) in [(n1, n2), (n2, n1)] {
                if b < a || at[b as usize] != 1 {
                    continue;
                }
                if st.p.lock_borders {
                    locked[a as usize] = true;
                    locked[b as usize] = true;
                }
                let (pa, pb) = (st.pos[a as usize], st.pos[b as usize]);
                let pc = st.pos[other as usize];
                let e = pb - pa;
                let n = e.cross(e.cross(pc - pa)).normalize_or_zero();
                if n != DVec3::ZERO {
                    let w = e.length() * st.p.boundary_weight;
                    let q = Quadric::from_plane(n, -n.dot(pa), w);
                    st.quad[a as usize].add(&q);
                    st.quad[b as usize].add(&q);
                }
            }
        }
        for s in su.iter() {
            at[s.a as usize] = 0;
            at[s.b as usize] = 0;
        }
    }
}

/// Welded input of a run: position vertices (position, lock flag,
/// curvature), wedges (position vertex, `stride` attributes each, normals at
/// `normal_offset`) and triangles (wedge triples).
pub(crate) struct QemInput {
    pub pos: Vec<DVec3>,
    pub locked: Vec<bool>,
    pub curv: Vec<f32>,
    pub wedge_pos: Vec<u32>,
    pub tris: Vec<[u32; 3]>,
    pub attr: Vec<f32>,
    pub stride: usize,
    pub normal_offset: Option<usize>,
    /// The quadrics of the position vertices, when carried over from an
    /// earlier run (see `parts.rs`); else computed from the triangles (face
    /// and border planes).
    pub quadrics: Option<Vec<Quadric>>,
}

/// Runs the simplification on welded data.
pub(crate) fn run(input: QemInput, params: &QemParams) -> QemOutput {
    let mut st = setup(input, params);
    // Passes (as in meshoptimizer): rank every live edge, then apply the
    // cheapest collapses whose endpoints were not touched earlier in the
    // pass (re-validated against the current geometry), until the pass has
    // done enough work or the costs rise well above the pass's goal.
    let mut passes = Passes::new(&st);
    while st.live > params.target_tris {
        if !std::mem::take(&mut passes.csr_fresh) {
            st.rebuild_csr();
        }
        passes.update_constraint_flags(&mut st);
        passes.rank_dirty_edges(&st);
        passes.rank_parts(&st);
        if passes.ranked.is_empty() {
            break;
        }
        if passes.walk(&mut st) == 0 {
            break;
        }
        passes.keep_clean_entries(&st);
    }
    passes.finish(st)
}

/// The state of a run before its first pass: quadrics (face planes plus
/// border planes; carried ones have both), connected parts, the CSR
/// adjacency, and border vertices locked if `lock_borders`.
fn setup(input: QemInput, params: &QemParams) -> State<'_> {
    let QemInput {
        pos,
        mut locked,
        curv,
        wedge_pos,
        tris,
        attr,
        stride,
        normal_offset,
        quadrics,
    } = input;
    let nv = pos.len();
    let nt = tris.len();
    let carried = quadrics.is_some();
    let quad = quadrics.unwrap_or_else(|| face_quadrics(&pos, &wedge_pos, &tris));
    let (comp, comp_lo, comp_hi) = component_boxes(&pos, &wedge_pos, &tris);
    let comp_r2 = radii2(&comp_lo, &comp_hi);
    let comp_removal2 = removal_costs2(&comp_lo, &comp_hi);
    let comp_kept_whole = island_keepers(&comp_lo, &comp_hi, params.keep_apart_m);
    let mut st = State {
        pos,
        quad,
        curv,
        locked: Vec::new(),
        alive: vec![true; nv],
        tris,
        tri_alive: vec![true; nt],
        wedge_pos,
        attr,
        stride,
        normal_offset,
        off: Vec::new(),
        corners: Vec::new(),
        cflag: vec![false; nv],
        mark: vec![0; nv],
        comp,
        comp_r2,
        comp_removal2,
        comp_kept_whole,
        gen: 0,
        live: nt,
        p: params,
    };
    // Border edges: extra perpendicular planes (weighted by length²) and
    // optional locking of border vertices.
    st.rebuild_csr();
    if !carried {
        add_border_planes(&mut st, &mut locked, &mut Vec::new());
    }
    st.locked = locked;
    st
}

/// What the passes of a run keep between passes and share within one: the
/// ranked edges, the deferred heap, dirty and touched flags, the parts'
/// triangle lists, the largest error and edge so far, and scratch vectors.
struct Passes {
    /// Triangles of each connected part: `comp_tris[comp_off[c]..comp_off[c + 1]]`.
    comp_off: Vec<u32>,
    comp_tris: Vec<u32>,
    /// Live triangles of each part (counted at each pass's ranking).
    comp_live: Vec<usize>,
    /// Parts that may be dropped whole (no locked vertex, not larger than
    /// the longest collapsible edge).
    prunable: Vec<bool>,
    /// Largest squared error and squared collapsed edge length so far.
    max_d2: f64,
    max_edge2: f64,
    /// Vertex is an endpoint of a collapse of this pass.
    touched: Vec<bool>,
    deferred: std::collections::BinaryHeap<Deferred>,
    /// Keys of the entries the walk reached, in order (the pass goal is the
    /// cost at rank `goal_idx`).
    popped: Vec<f64>,
    /// Incremental ranking: a vertex is dirty when a collapse of the pass
    /// changed its star (it is in the closed 1-ring of a collapsed edge).
    /// Every input to the evaluation of an edge (quadrics, positions,
    /// constraint flags, stars) is local to its endpoints' stars, so an edge
    /// with two clean endpoints has the same entry (and the same coverage,
    /// and the same validity) as in the last pass: only dirty edges are
    /// ranked again. Validity failures are remembered too (the entry is
    /// dropped) since rejected collapses recur pass after pass.
    dirty: Vec<bool>,
    ranked: Vec<Ranked>,
    /// Ranking chunks of ~4096 vertices: output and scratch vectors.
    n_rank_bufs: usize,
    rank_bufs: Vec<RankBuf>,
    cflag_scratch: Vec<u32>,
    /// Stars of the edge at hand, and the old star of the interior check.
    su: Vec<StarTri>,
    sv: Vec<StarTri>,
    old: Vec<OldTri>,
    /// The CSR built by [`setup`] (for the border planes) is the first
    /// pass's too.
    csr_fresh: bool,
}

/// Where the walk of one pass stands.
struct Walk {
    /// Next entry of the sorted prefix `ranked[..m]` of the `n_ranked` entries.
    i: usize,
    m: usize,
    n_ranked: usize,
    /// Triangles the pass should remove, and the live count at its start.
    tri_goal: usize,
    live0: usize,
    /// Rank of the goal edge in `popped` (moved on by invalid edges), and a
    /// lower bound of its key until the walk reaches it.
    goal_idx: usize,
    goal_lb: f64,
    collapses: usize,
}

/// An entry reached by the walk, after its lazy coverage.
enum Reached {
    /// Skipped (an endpoint touched) or deferred (its full key moved it
    /// behind the next entry).
    Skipped,
    /// To be taken now; `Some(d1)`: its coverage was just computed, and its
    /// stars are gathered in `su` and `sv`.
    Ready(Option<f64>),
}

impl Passes {
    fn new(st: &State) -> Passes {
        let nv = st.pos.len();
        let ncomp = st.comp_r2.len();
        let mut comp_off = vec![0u32; ncomp + 1];
        for t in &st.tris {
            comp_off[st.comp[st.wedge_pos[t[0] as usize] as usize] as usize + 1] += 1;
        }
        for i in 0..ncomp {
            comp_off[i + 1] += comp_off[i];
        }
        let mut comp_tris = vec![0u32; st.tris.len()];
        let mut fill = comp_off[..ncomp].to_vec();
        for (ti, t) in st.tris.iter().enumerate() {
            let c = st.comp[st.wedge_pos[t[0] as usize] as usize] as usize;
            comp_tris[fill[c] as usize] = ti as u32;
            fill[c] += 1;
        }
        let mut prunable: Vec<bool> = st
            .comp_r2
            .iter()
            .zip(&st.comp_kept_whole)
            .map(|(&r2, &kept)| 4.0 * r2 <= st.p.max_edge_len2 && !kept)
            .collect();
        for (x, &l) in st.locked.iter().enumerate() {
            if l {
                prunable[st.comp[x] as usize] = false;
            }
        }
        let n_rank_bufs = nv.div_ceil(4096).clamp(1, 256);
        Passes {
            comp_off,
            comp_tris,
            comp_live: vec![0usize; ncomp],
            prunable,
            max_d2: 0.0,
            max_edge2: 0.0,
            touched: vec![false; nv],
            deferred: Default::default(),
            popped: Vec::new(),
            dirty: vec![true; nv],
            ranked: Vec::new(),
            n_rank_bufs,
            rank_bufs: (0..n_rank_bufs).map(|_| Default::default()).collect(),
            cflag_scratch: Vec::new(),
            su: Vec::new(),
            sv: Vec::new(),
            old: Vec::new(),
            csr_fresh: true,
        }
    }

    /// Constraint flags of the dirty vertices (the others' stars did not
    /// change).
    fn update_constraint_flags(&mut self, st: &mut State) {
        let mut cflag = std::mem::take(&mut st.cflag);
        let stref = &*st;
        let dirty = &self.dirty;
        let cflag_chunk = |lo: usize, cf: &mut [bool], scratch: &mut Vec<u32>| {
            for (i, cf) in cf.iter_mut().enumerate() {
                let a = lo + i;
                if !stref.alive[a] {
                    *cf = false;
                } else if dirty[a] {
                    *cf = stref.constrained(stref.csr_star(a as u32), scratch);
                }
            }
        };
        // Small meshes (they come by the thousand) stay on this thread: a
        // hand-off to the thread pool costs more than their work.
        if self.n_rank_bufs == 1 {
            cflag_chunk(0, &mut cflag, &mut self.cflag_scratch);
        } else {
            cflag
                .par_chunks_mut(4096)
                .enumerate()
                .for_each_init(Vec::new, |scratch, (ci, cf)| {
                    cflag_chunk(ci * 4096, cf, scratch)
                });
        }
        st.cflag = cflag;
    }

    /// Ranks the edges with a dirty endpoint (in parallel chunks) and appends
    /// them to `ranked`; every vertex is clean afterwards.
    fn rank_dirty_edges(&mut self, st: &State) {
        let nv = st.pos.len();
        let n_rank_bufs = self.n_rank_bufs;
        let dirty = &self.dirty;
        // Per-chunk vectors, kept across passes (growing fresh ones every
        // pass cost page faults and copies); the order of `ranked` does not
        // matter (everything below uses the total order).
        let rank_chunk = |ci: usize, (out, nb): &mut RankBuf| {
            out.clear();
            let lo = (ci * nv / n_rank_bufs) as u32;
            let hi = ((ci + 1) * nv / n_rank_bufs) as u32;
            for a in lo..hi {
                // An edge with an unchanged neighbourhood (two clean
                // endpoints) keeps its entry from the last pass (kept in `ranked`), or
                // stays out of the order if it was found invalid. The others
                // are ranked from their smaller dirty endpoint.
                if !st.alive[a as usize] || !dirty[a as usize] {
                    continue;
                }
                let star = st.csr_star(a);
                // Those edges with their triangles, in one scan.
                st.star_edges(a, star, |b| !dirty[b as usize], nb);
                for &(b, ref e) in nb.iter() {
                    let (a, b) = (a.min(b), a.max(b));
                    if let Some((key, p)) = st.evaluate_best(a, b, e) {
                        let f = st.factor(a, b);
                        // Coverage can only raise the key: computed lazily
                        // (below) unless its bound is no larger.
                        let skip = st
                            .coverage2_bound(a, b, p, star.len(), e)
                            .is_some_and(|ub| ub * f <= key);
                        out.push(Ranked {
                            key,
                            u: a,
                            v: b,
                            p,
                            f: if skip { 0.0 } else { f },
                        });
                    }
                }
            }
        };
        if n_rank_bufs == 1 {
            rank_chunk(0, &mut self.rank_bufs[0]);
        } else {
            self.rank_bufs
                .par_iter_mut()
                .enumerate()
                .for_each(|(ci, b)| rank_chunk(ci, b));
        }
        let n_new: usize = self.rank_bufs.iter().map(|b| b.0.len()).sum();
        self.ranked.reserve(n_new + self.comp_live.len());
        for b in &self.rank_bufs {
            self.ranked.extend_from_slice(&b.0);
        }
        self.dirty.iter_mut().for_each(|d| *d = false);
    }

    /// Whole-part removal: every prunable part with live triangles is an
    /// entry of cost = its squared radius.
    fn rank_parts(&mut self, st: &State) {
        self.comp_live.iter_mut().for_each(|c| *c = 0);
        for (t, &a) in st.tris.iter().zip(&st.tri_alive) {
            if a {
                self.comp_live[st.comp[st.wedge_pos[t[0] as usize] as usize] as usize] += 1;
            }
        }
        for (c, &n) in self.comp_live.iter().enumerate() {
            if n > 0 && self.prunable[c] {
                self.ranked.push(Ranked {
                    key: st.comp_removal2[c],
                    u: NONE,
                    v: c as u32,
                    p: DVec3::ZERO,
                    f: 0.0,
                });
            }
        }
    }

    /// The walk of one pass; returns the number of collapses (parts dropped
    /// included).
    ///
    /// Lazy coverage, in exact order. The full key (quadric key raised by
    /// the coverage error) is never below the quadric key, so the walk
    /// merges two ordered sources: the edges by quadric key (`ranked`,
    /// sorted in chunks as the walk reaches them) and a heap of edges
    /// whose full key is known but was larger than the next quadric key
    /// (deferred). The coverage is computed when an edge is reached and
    /// neither endpoint is touched yet: edges skipped as touched (most
    /// of them on dense meshes) never pay for it.
    fn walk(&mut self, st: &mut State) -> usize {
        let mut w = self.start_walk(st);
        while let Some(ri) = self.next_entry(st, &mut w) {
            if st.live <= st.p.target_tris {
                break;
            }
            let fresh = match self.lazy_coverage(st, &mut w, ri) {
                Reached::Skipped => continue,
                Reached::Ready(fresh) => fresh,
            };
            let en = self.ranked[ri];
            self.popped.push(en.key);
            let error_goal = 1.5
                * self
                    .popped
                    .get(w.goal_idx)
                    .copied()
                    .unwrap_or(w.goal_lb.max(en.key));
            if en.key > error_goal && w.live0 - st.live > w.tri_goal / 6 {
                break;
            }
            let done = if en.u == NONE {
                self.drop_part(st, en)
            } else {
                self.try_collapse(st, &mut w, ri, fresh, error_goal)
            };
            if done {
                w.collapses += 1;
            }
        }
        w.collapses
    }

    /// Starts the walk of a pass: the first chunk of the order, the goal.
    fn start_walk(&mut self, st: &State) -> Walk {
        let tri_goal = st.live - st.p.target_tris;
        let goal0 = tri_goal / 2;
        let n_ranked = self.ranked.len();
        self.touched.iter_mut().for_each(|t| *t = false);
        let mut m = 0usize;
        let first = (goal0 + goal0 / 2 + 4096).min(n_ranked);
        extend_order(&mut self.ranked, &mut m, first);
        // The goal edge's full key is at least the `goal0`-th smallest
        // quadric key (full keys are never smaller), and at least the key
        // of the edge at hand: the bound of the pass goal until the walk
        // reaches the goal edge.
        let goal_lb = self.ranked.get(goal0).map_or(f64::INFINITY, |r| r.key);
        self.deferred.clear();
        self.popped.clear();
        // As in meshoptimizer, the cost of the `tri_goal / 2`-th edge of the
        // order (skipping invalid ones) times 1.5 bounds what a pass accepts.
        Walk {
            i: 0,
            m,
            n_ranked,
            tri_goal,
            live0: st.live,
            goal_idx: goal0,
            goal_lb,
            collapses: 0,
        }
    }

    /// Sorts the next chunk of the order when the walk has reached the end
    /// of the sorted prefix.
    #[inline]
    fn extend_if_reached(&mut self, w: &mut Walk) {
        if w.i == w.m && w.m < w.n_ranked {
            let want = (w.m + w.m / 2).max(w.m + 4096).min(w.n_ranked);
            extend_order(&mut self.ranked, &mut w.m, want);
        }
    }

    /// The next entry of the walk (index in `ranked`): the smaller of the
    /// next sorted entry and the deferred heap's top; `None` at the end.
    /// Prefetches the data of the entries a few steps ahead.
    #[inline]
    fn next_entry(&mut self, st: &State, w: &mut Walk) -> Option<usize> {
        self.extend_if_reached(w);
        let from_heap = match (w.i < w.m, self.deferred.peek()) {
            (true, Some(d)) => d.before(&self.ranked[w.i]),
            (false, Some(_)) => true,
            (true, None) => false,
            (false, None) => return None,
        };
        if w.i < w.m {
            for (stage, ahead) in [(0u32, 32usize), (1, 24), (2, 16), (3, 8), (4, 4)] {
                if let Some(r) = self.ranked.get(w.i + ahead).filter(|_| w.i + ahead < w.m) {
                    if r.u != NONE {
                        st.prefetch(r.u, r.v, stage, &self.touched);
                    }
                }
            }
        }
        Some(if from_heap {
            self.deferred.pop().map_or(0, |d| d.ranked as usize)
        } else {
            w.i += 1;
            w.i - 1
        })
    }

    /// Computes the coverage of entry `ri` if it is still to be computed
    /// (on the current state), and defers the edge if its full key moved it
    /// behind the next edge of the order.
    #[inline]
    fn lazy_coverage(&mut self, st: &State, w: &mut Walk, ri: usize) -> Reached {
        let en = self.ranked[ri];
        if !(en.u != NONE && en.f > 0.0) {
            return Reached::Ready(None);
        }
        let (u, v) = (en.u, en.v);
        if self.touched[u as usize] || self.touched[v as usize] {
            self.popped.push(en.key);
            return Reached::Skipped;
        }
        st.gather(u, &mut self.su);
        st.gather(v, &mut self.sv);
        let d1 = st.coverage2(u, v, en.p, &self.su, &self.sv, en.key / en.f);
        let full = en.key.max(d1 * en.f);
        self.ranked[ri].key = full;
        self.ranked[ri].f = 0.0;
        self.extend_if_reached(w);
        let r = self.ranked[ri];
        let later = (w.i < w.m && rank_cmp(&r, &self.ranked[w.i]).is_gt())
            || self.deferred.peek().is_some_and(|d| d.before(&r));
        if later {
            self.deferred.push(Deferred {
                ranked: ri as u32,
                key: r.key,
                u: r.u,
                v: r.v,
            });
            return Reached::Skipped;
        }
        Reached::Ready(Some(d1))
    }

    /// Drops the part of entry `en` whole, if it still has live triangles,
    /// the triangle goal leaves room for it and its radius is within the
    /// error target; returns whether it was dropped.
    fn drop_part(&mut self, st: &mut State, en: Ranked) -> bool {
        let c = en.v as usize;
        let tl = &self.comp_tris[self.comp_off[c] as usize..self.comp_off[c + 1] as usize];
        let n = tl.iter().filter(|&&t| st.tri_alive[t as usize]).count();
        if n == 0 || st.live < n + st.p.target_tris || en.key > st.p.target_error2 {
            return false;
        }
        for &t in tl {
            if st.tri_alive[t as usize] {
                st.tri_alive[t as usize] = false;
                st.live -= 1;
                for &w in &st.tris[t as usize] {
                    self.dirty[st.wedge_pos[w as usize] as usize] = true;
                }
            }
        }
        self.comp_live[c] = 0;
        self.max_d2 = self.max_d2.max(en.key);
        self.max_edge2 = self.max_edge2.max(4.0 * st.comp_r2[c]);
        true
    }

    /// Collapses the edge of entry `ri` if neither endpoint is touched and
    /// a valid placement is within the pass goal; returns whether it did.
    /// `fresh`: see [`Reached::Ready`].
    #[inline]
    fn try_collapse(
        &mut self,
        st: &mut State,
        w: &mut Walk,
        ri: usize,
        fresh: Option<f64>,
        error_goal: f64,
    ) -> bool {
        let en = self.ranked[ri];
        let (u, v) = (en.u, en.v);
        if self.touched[u as usize] || self.touched[v as usize] {
            return false;
        }
        if fresh.is_none() {
            st.gather(u, &mut self.su);
            st.gather(v, &mut self.sv);
        }
        let e = st.edge_info(v, &self.su);
        // Both endpoints are untouched: the edge evaluates as ranked
        // (its triangles only die with a part dropped whole), and its
        // first placement is the ranked one (`en.p`). The others are
        // computed only if that one is rejected.
        if e.count == 0 {
            w.goal_idx += 1;
            self.ranked[ri].f = -1.0;
            return false;
        }
        let (chosen, over_target) = self.choose_placement(st, en, fresh.is_some(), &e, error_goal);
        // A fallback placement (the first one failed validation) costs
        // more than the rank: only take it if it is within the pass goal.
        let Some(cand) = chosen.filter(|c| c.key <= en.key * (1.0 + 1e-9) || c.key <= error_goal)
        else {
            w.goal_idx += 1;
            match chosen {
                // Next pass (if still clean) it ranks at its real cost.
                Some(c) => self.ranked[ri].key = c.key,
                None if !over_target => self.ranked[ri].f = -1.0,
                None => {}
            }
            return false;
        };
        for s in self.su.iter().chain(&self.sv) {
            self.dirty[s.a as usize] = true;
            self.dirty[s.b as usize] = true;
        }
        self.dirty[u as usize] = true;
        self.dirty[v as usize] = true;
        self.max_edge2 = self
            .max_edge2
            .max((st.pos[u as usize] - st.pos[v as usize]).length_squared());
        let d2 = st.apply(u, v, cand.p, cand.dist2, &self.su, &e);
        self.max_d2 = self.max_d2.max(d2);
        self.touched[u as usize] = true;
        self.touched[v as usize] = true;
        true
    }

    /// The first placement of edge `en` (ranked one first, then the others
    /// in cost order) that passes the link condition and validity, with its
    /// full cost; and whether a placement was over the error target.
    /// `fresh`: the coverage of the ranked placement was just computed.
    #[inline]
    fn choose_placement(
        &mut self,
        st: &mut State,
        en: Ranked,
        fresh: bool,
        e: &EdgeInfo,
        error_goal: f64,
    ) -> (Option<Candidate>, bool) {
        let (u, v) = (en.u, en.v);
        let first = EdgeCost::new(st, u, v).at(en.p);
        let mut ev: Option<Option<Eval>> = None;
        let mut over_target = false;
        // The known coverage of the first placement holds if it was just
        // computed, or if nothing around the edge changed in this pass.
        let touched = &self.touched;
        let unchanged = fresh
            || [&self.su, &self.sv].iter().all(|star| {
                star.iter()
                    .all(|s| !touched[s.a as usize] && !touched[s.b as usize])
            });
        let mut link = None;
        for ci in 0..4 {
            let cand = if ci == 0 {
                first
            } else {
                // (`None` cannot happen for a ranked untouched edge; it
                // would end as an invalid edge, as before.)
                match ev.get_or_insert_with(|| st.evaluate(u, v, e)) {
                    Some(ev) if ci < ev.n => ev.cands[ci],
                    _ => break,
                }
            };
            if cand.dist2 > st.p.target_error2 {
                over_target = true;
                break;
            }
            if !*link.get_or_insert_with(|| st.link_ok(u, v, &self.su, &self.sv, e)) {
                // No placement passes the link condition. Without an error target the other
                // placements cannot even set `over_target`: not worth evaluating them.
                if st.p.target_error2 == f64::INFINITY {
                    break;
                }
                continue;
            }
            if st.valid(u, v, cand.p, &self.su, &self.sv, e) {
                let known = ci == 0 && unchanged;
                return (
                    Some(self.full_cost(st, en, cand, known, e, error_goal)),
                    over_target,
                );
            }
        }
        (None, over_target)
    }

    /// Candidate `c` of edge `en` with its key and distance raised by the
    /// coverage and interior errors. `known`: the coverage of `c` is the one
    /// computed for the ranked entry.
    #[inline]
    fn full_cost(
        &mut self,
        st: &mut State,
        en: Ranked,
        mut c: Candidate,
        known: bool,
        e: &EdgeInfo,
        error_goal: f64,
    ) -> Candidate {
        let (u, v) = (en.u, en.v);
        // Only values above the cost matter (`t`: early exits;
        // the key also holds the tie-break term).
        let f = st.factor(u, v);
        let t = c.key / f;
        // Errors up to `t_free` change nothing either: the
        // collapse is still within the pass goal and its
        // distance does not raise the largest one so far
        // (`max_d2`), so the checks below may stop at that
        // threshold instead of `t`.
        let t_free = self.max_d2.min(error_goal / f);
        let tt = if c.key <= error_goal && c.dist2 <= self.max_d2 && t_free * f <= error_goal {
            t.max(t_free)
        } else {
            t
        };
        // Below the threshold, both checks are bounded by how far the endpoints
        // move (`p` is a vertex of every new triangle, `u` and `v` of the old
        // star; a new triangle's sample point is within half that of the old
        // triangle it replaces): skipped when the bound cannot exceed it (with
        // a margin for rounding).
        let (pu, pv) = (st.pos[u as usize], st.pos[v as usize]);
        let moved2 = (pu - c.p).length_squared().max((pv - c.p).length_squared());
        let below = |b: f64, t: f64| b < t * (1.0 - 1e-3);
        let mut d1 = if known {
            if en.key > c.key {
                en.key / f
            } else {
                0.0
            }
        } else if st
            .coverage2_bound(u, v, c.p, self.su.len(), e)
            .is_some_and(|b| below(b, tt))
        {
            0.0
        } else {
            st.coverage2(u, v, c.p, &self.su, &self.sv, tt)
        };
        if !below(0.25 * moved2, tt.max(d1)) {
            d1 = d1.max(st.interior2(u, v, c.p, &self.su, &self.sv, tt.max(d1), &mut self.old));
        }
        if d1 > tt {
            c.key = c.key.max(d1 * f);
            c.dist2 = c.dist2.max(d1);
        }
        c
    }

    /// Keeps the entries of edges with two clean live endpoints, valid so
    /// far, for the next pass (compacted in place at the front of `ranked`,
    /// not copied out and back).
    fn keep_clean_entries(&mut self, st: &State) {
        let dirty = &self.dirty;
        self.ranked.retain(|r| {
            r.u != NONE
                && r.f >= 0.0
                && st.alive[r.u as usize]
                && st.alive[r.v as usize]
                && !dirty[r.u as usize]
                && !dirty[r.v as usize]
        });
    }

    /// The output of the run: the state's arrays with the live triangles.
    fn finish(self, st: State) -> QemOutput {
        let tris: Vec<[u32; 3]> = st
            .tris
            .iter()
            .zip(&st.tri_alive)
            .filter(|(_, &a)| a)
            .map(|(t, _)| *t)
            .collect();
        QemOutput {
            pos: st.pos,
            locked: st.locked,
            wedge_pos: st.wedge_pos,
            attr: st.attr,
            tris,
            max_qem_distance: self.max_d2.sqrt(),
            max_collapsed_edge: self.max_edge2.sqrt(),
            quad: st.quad,
            curv: st.curv,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_island_standing_apart_keeps_its_largest_part() {
        // A 10 m building; 10 m east, two small parts 2 cm apart (one island); 40 m north, a
        // lone marker.
        let boxes = [
            (DVec3::ZERO, DVec3::splat(10.0)),
            (DVec3::new(20.0, 0.0, 0.0), DVec3::new(20.1, 0.1, 0.1)),
            (DVec3::new(20.12, 0.0, 0.0), DVec3::new(20.32, 0.2, 0.2)),
            (DVec3::new(0.0, 50.0, 0.0), DVec3::new(0.05, 50.05, 0.05)),
        ];
        let (lo, hi): (Vec<DVec3>, Vec<DVec3>) = boxes.into_iter().unzip();
        assert_eq!(
            island_keepers(&lo, &hi, 1.0),
            [true, false, true, true],
            "three islands, each keeps its largest"
        );
        assert_eq!(
            island_keepers(&lo, &hi, 15.0),
            [true, false, false, true],
            "the pair joins the building's island"
        );
        assert_eq!(island_keepers(&lo, &hi, 45.0), [true, false, false, false]);
        assert_eq!(island_keepers(&lo, &hi, f64::INFINITY), [false; 4]);
    }

    #[test]
    fn parts_sharing_their_x_range_are_kept_apart_by_height() {
        // A tower: three floors of one footprint, 4 m apart in height, the top one smallest.
        let floors = [0.0, 4.0, 8.0].map(|z| (DVec3::new(0.0, 0.0, z), DVec3::new(10.0, 10.0, z)));
        let (lo, mut hi): (Vec<DVec3>, Vec<DVec3>) = floors.into_iter().unzip();
        hi[2].x = 5.0;
        assert_eq!(
            island_keepers(&lo, &hi, 1.0),
            [true; 3],
            "each floor its own island"
        );
        assert_eq!(
            island_keepers(&lo, &hi, 4.0),
            [true, false, false],
            "one island"
        );
    }
}
