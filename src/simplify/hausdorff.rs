//! Hausdorff distance between triangle meshes.
//!
//! * [`hausdorff_one_sided`] / [`hausdorff`]: **sampled** distances. Points are
//!   taken on the first surface with a deterministic sampler (every vertex plus
//!   an area-weighted low-discrepancy set of surface points) and their distance
//!   to the second surface is found with a closest-point query on an `obvhs`
//!   BVH2 built over the triangle bounding boxes. A sampled value is a *lower*
//!   estimate of the true distance.
//! * [`hausdorff_bound_one_sided`] / [`hausdorff_bound`]: a **certified upper
//!   bound** by branch and bound over the triangles of the first surface. For a
//!   (sub)triangle `T` with vertex distances `d_i` the distance function is
//!   bounded by `max d_i + 0.58 * longest_edge(T)` (it is 1-Lipschitz, and every
//!   point of a triangle is within `L/sqrt(3)` of a vertex) and by
//!   `max_i dist(v_i, t_j)` for any single triangle `t_j` of the other surface
//!   (distance to a convex set is convex). Triangles whose bound exceeds the
//!   target are split in four, up to a query budget; whatever is left keeps its
//!   (looser, still valid) bound. Up to `f32`/`f64` rounding the result is a
//!   true upper bound of the one-sided Hausdorff distance.
//!
//! [`MeshBvh`] exposes the closest-point query for other users (HLOD checks).

use std::time::Duration;

use glam::{DVec3, Vec3A};
use obvhs::{aabb::Aabb, bvh2::builder::build_bvh2, bvh2::Bvh2, BvhBuildParams};
use rayon::prelude::*;

/// A borrowed triangle mesh (positions and triangle indices).
#[derive(Clone, Copy, Debug)]
pub struct TriMesh<'a> {
    /// Vertex positions.
    pub positions: &'a [[f32; 3]],
    /// Triangle list; out-of-range and degenerate triangles are ignored.
    pub indices: &'a [u32],
}

impl<'a> TriMesh<'a> {
    /// Creates a view.
    pub fn new(positions: &'a [[f32; 3]], indices: &'a [u32]) -> Self {
        TriMesh { positions, indices }
    }

    fn triangles(&self) -> Vec<[DVec3; 3]> {
        let n = self.positions.len();
        let p = |i: u32| {
            let v = self.positions[i as usize];
            DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)
        };
        self.indices
            .chunks_exact(3)
            .filter(|t| t.iter().all(|&i| (i as usize) < n))
            .map(|t| [p(t[0]), p(t[1]), p(t[2])])
            .filter(|t| t.iter().all(|v| v.is_finite()))
            .filter(|t| (t[1] - t[0]).cross(t[2] - t[0]) != DVec3::ZERO)
            .collect()
    }
}

/// Closest point on triangle `(a, b, c)` to `p` (Ericson, Real-Time Collision
/// Detection 5.1.5), in `f64`.
pub fn closest_point_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    closest_point_on(p, &Corners::new(a, b, c))
}

/// A triangle's corners and its two edges from `a`, as [`closest_point_on_triangle`] computes
/// them: a [`MeshBvh`] keeps them so that its queries skip the subtractions and give the very
/// same results.
#[derive(Clone, Copy, Debug)]
struct Corners {
    a: DVec3,
    b: DVec3,
    c: DVec3,
    ab: DVec3,
    ac: DVec3,
}

impl Corners {
    fn new(a: DVec3, b: DVec3, c: DVec3) -> Self {
        Corners {
            a,
            b,
            c,
            ab: b - a,
            ac: c - a,
        }
    }
}

/// [`closest_point_on_triangle`] with the edges from `a` given.
#[inline(always)]
fn closest_point_on(p: DVec3, t: &Corners) -> DVec3 {
    let Corners { a, b, c, ab, ac } = *t;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return a + ab * v;
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return a + ac * w;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return b + (c - b) * w;
    }
    let denom = va + vb + vc;
    if denom.is_nan() || denom == 0.0 {
        // Degenerate triangle: best of the three edges.
        let e = [
            closest_on_segment(p, a, b),
            closest_on_segment(p, b, c),
            closest_on_segment(p, c, a),
        ];
        return e
            .into_iter()
            .min_by(|x, y| {
                (*x - p)
                    .length_squared()
                    .total_cmp(&(*y - p).length_squared())
            })
            .unwrap_or(a);
    }
    let denom = 1.0 / denom;
    a + ab * (vb * denom) + ac * (vc * denom)
}

fn closest_on_segment(p: DVec3, a: DVec3, b: DVec3) -> DVec3 {
    let d = b - a;
    let l = d.length_squared();
    if l <= 0.0 {
        return a;
    }
    a + d * ((p - a).dot(d) / l).clamp(0.0, 1.0)
}

/// What can rule a triangle out of a query before its closest point is computed: its plane and a
/// ball holding it, in one cache line. Both give lower bounds of the distance; the plane's misses
/// neighbours in the same plane (a tessellated floor or wall), the ball's catches them.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Cull {
    /// Unit normal (zero for a triangle without a reliable one).
    n: DVec3,
    /// The corners' mean, on the plane up to rounding.
    centre: DVec3,
    /// Radius of the ball around `centre` holding the triangle, widened for the rounding of the
    /// closest-point computation (which grows with the coordinates, not the distance).
    radius_m: f64,
    /// The plane distance's error: `eta` per metre from `centre` (the normal's own error, large
    /// for a needle, whose cross product is mostly rounding) plus `off_m`; rounded up to `f32`.
    eta: f32,
    off_m: f32,
}

impl Cull {
    fn new(t: &Corners) -> Self {
        let x = t.ab.cross(t.ac);
        // The computed normal is off by a few rounding units of |ab| |ac| / |ab x ac| (plus the
        // dot product's own), with a wide margin.
        let eta =
            64.0 * f64::EPSILON * t.ab.length() * t.ac.length() / x.length() + 8.0 * f64::EPSILON;
        let centre = (t.a + t.b + t.c) / 3.0;
        let r = [t.a, t.b, t.c]
            .iter()
            .map(|&v| (v - centre).length())
            .fold(0.0, f64::max);
        let slack_m = 1e-12 * (centre.abs().max_element() + r);
        let (n, eta, off_m) = if eta.is_finite() && eta < 1e-3 {
            (x.normalize(), eta, 2.0 * eta * r + slack_m)
        } else {
            (DVec3::ZERO, 0.0, 0.0)
        };
        Cull {
            n,
            centre,
            radius_m: r * (1.0 + 1e-12) + slack_m,
            eta: f32_up(eta),
            off_m: f32_up(off_m),
        }
    }

    /// Whether the triangle is surely farther from `p` than `best_m` (`best2` its square): then it
    /// can neither beat nor tie the best.
    #[inline(always)]
    fn beyond(&self, p: DVec3, best2: f64, best_m: f64) -> bool {
        let pc = p - self.centre;
        // The distance to the plane less its error (`|p - a| <= |pc| + r`, `|pc| <= |pc|_1`).
        let l1 = pc.x.abs() + pc.y.abs() + pc.z.abs();
        let h = (self.n.dot(pc).abs() - self.eta as f64 * l1 - self.off_m as f64).max(0.0);
        let reach = self.radius_m + best_m * (1.0 + 1e-12);
        // Both tests, without a branch between them (which goes either way).
        (h * h * (1.0 - 1e-12) > best2) | (pc.length_squared() * (1.0 - 2e-12) > reach * reach)
    }
}

/// Two sibling boxes of the BVH side by side, axis by axis (`f32`, rounded outwards), and what
/// each child is: `count` triangles from `first` (a leaf) or, with `count` 0, the pair of its own
/// children at `first`. One cache line per step down the tree.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
struct Pair {
    lo: [[f32; 2]; 3],
    hi: [[f32; 2]; 3],
    first: [u32; 2],
    count: [u32; 2],
}

impl Pair {
    /// Squared distances from `p` to both boxes, shrunk by a relative 1e-12 against rounding.
    #[inline(always)]
    fn dist2(&self, p: DVec3) -> [f64; 2] {
        let p = p.to_array();
        let mut d2 = [0.0f64; 2];
        for (k, d2) in d2.iter_mut().enumerate() {
            let mut s = 0.0;
            for ((lo, hi), &x) in self.lo.iter().zip(&self.hi).zip(&p) {
                let v = (lo[k] as f64 - x).max(x - hi[k] as f64).max(0.0);
                s += v * v;
            }
            *d2 = s * (1.0 - 1e-12);
        }
        d2
    }
}

/// A node to visit: `(first, count, squared box distance)`, as a child of a [`Pair`].
type Visit = (u32, u32, f64);

/// A traversal stack without an allocation per query: a fixed array, spilling to the heap only
/// for a pathologically deep tree.
struct Stack {
    fixed: [Visit; 64],
    len: usize,
    spill: Vec<Visit>,
}

impl Stack {
    fn new(v: Visit) -> Self {
        let mut fixed = [(0, 0, 0.0); 64];
        fixed[0] = v;
        Stack {
            fixed,
            len: 1,
            spill: Vec::new(),
        }
    }

    #[inline(always)]
    fn push(&mut self, v: Visit) {
        if self.len < self.fixed.len() {
            self.fixed[self.len] = v;
            self.len += 1;
        } else {
            self.spill.push(v);
        }
    }

    /// Last in, first out: the spill only grows while the array is full, so it is newer.
    #[inline(always)]
    fn pop(&mut self) -> Option<Visit> {
        if let Some(v) = self.spill.pop() {
            return Some(v);
        }
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        Some(self.fixed[self.len])
    }

    /// Pushes the children of `pair` nearer than `best2`, the farther first so that the nearer is
    /// visited first.
    #[inline(always)]
    fn push_children(&mut self, pair: &Pair, p: DVec3, best2: f64) {
        let [d0, d1] = pair.dist2(p);
        let c0 = (pair.first[0], pair.count[0], d0);
        let c1 = (pair.first[1], pair.count[1], d1);
        let (near, far) = if d0 <= d1 { (c0, c1) } else { (c1, c0) };
        if far.2 <= best2 {
            self.push(far);
        }
        if near.2 <= best2 {
            self.push(near);
        }
    }
}

/// A BVH over the triangles of a mesh answering closest-point queries.
///
/// Built with `obvhs` (a BVH2 over the triangle boxes), then laid out for the queries: sibling
/// boxes side by side in depth-first order, and the triangles of each leaf stored contiguously
/// (in the BVH's order, with their index in the mesh) with their [`Cull`] data.
pub struct MeshBvh {
    /// Per triangle in leaf order: corners and edges, cull data, index among the valid triangles.
    corners: Vec<Corners>,
    culls: Vec<Cull>,
    index: Vec<u32>,
    /// Per index among the valid triangles: its place in leaf order.
    slot: Vec<u32>,
    /// Per place in leaf order: the leaf (first place, count) holding it.
    leaf_of: Vec<(u32, u32)>,
    pairs: Vec<Pair>,
    /// The root: its box, and what it is (as a child of a [`Pair`]).
    root_box: Aabb,
    root: (u32, u32),
}

impl MeshBvh {
    /// Builds the BVH (a `obvhs` BVH2 over triangle AABBs, rounded outwards
    /// to `f32` so the boxes always contain the `f64` triangles).
    pub fn new(mesh: TriMesh<'_>) -> Self {
        let tris = mesh.triangles();
        let mut out = MeshBvh {
            corners: Vec::new(),
            culls: Vec::new(),
            index: Vec::new(),
            slot: Vec::new(),
            leaf_of: Vec::new(),
            pairs: Vec::new(),
            root_box: Aabb::INVALID,
            root: (0, 0),
        };
        if tris.is_empty() {
            return out;
        }
        let aabbs: Vec<Aabb> = tris
            .iter()
            .map(|t| {
                let lo = t[0].min(t[1]).min(t[2]);
                let hi = t[0].max(t[1]).max(t[2]);
                Aabb::new(
                    Vec3A::new(f32_down(lo.x), f32_down(lo.y), f32_down(lo.z)),
                    Vec3A::new(f32_up(hi.x), f32_up(hi.y), f32_up(hi.z)),
                )
            })
            .collect();
        let bvh = build_bvh2(
            &aabbs,
            BvhBuildParams::fast_build(),
            &mut Duration::default(),
        );
        out.index = bvh.primitive_indices.clone();
        out.slot = vec![u32::MAX; tris.len()];
        for (s, &i) in out.index.iter().enumerate() {
            out.slot[i as usize] = s as u32;
        }
        out.corners = out
            .index
            .iter()
            .map(|&i| {
                let t = &tris[i as usize];
                Corners::new(t[0], t[1], t[2])
            })
            .collect();
        out.culls = out.corners.iter().map(Cull::new).collect();
        out.root_box = bvh.nodes[0].aabb;
        (out.pairs, out.root) = pairs_of(&bvh);
        out.leaf_of = vec![(0, 0); tris.len()];
        let leaves = out.pairs.iter().flat_map(|q| {
            (0..2)
                .filter(|&k| q.count[k] > 0)
                .map(|k| (q.first[k], q.count[k]))
        });
        for (first, count) in leaves.chain((out.root.1 > 0).then_some(out.root)) {
            out.leaf_of[first as usize..(first + count) as usize].fill((first, count));
        }
        out
    }

    /// A lower bound of the distance from `p` to the mesh (its bounding box); `INFINITY` for an
    /// empty mesh.
    pub fn distance_lower_bound(&self, p: DVec3) -> f64 {
        if self.corners.is_empty() {
            return f64::INFINITY;
        }
        box_dist2(&self.root_box, p).sqrt()
    }

    /// Number of (valid) triangles.
    pub fn triangle_count(&self) -> usize {
        self.corners.len()
    }

    /// The corners of triangle `i` of this mesh.
    pub fn triangle(&self, i: u32) -> [DVec3; 3] {
        let t = &self.corners[self.slot[i as usize] as usize];
        [t.a, t.b, t.c]
    }

    /// Distance from `p` to triangle `i` of this mesh.
    pub fn distance_to_triangle(&self, p: DVec3, i: u32) -> f64 {
        let t = &self.corners[self.slot[i as usize] as usize];
        (closest_point_on(p, t) - p).length()
    }

    /// Closest point: `(distance, triangle index, point)`; `None` for an empty
    /// mesh. Ties are broken by the smaller triangle index (deterministic).
    pub fn closest(&self, p: DVec3) -> Option<(f64, u32, DVec3)> {
        let mut from_root = u32::MAX;
        self.closest_near(p, &mut from_root)
    }

    /// The search's start: the root as a node to visit.
    fn root_visit(&self, p: DVec3) -> Visit {
        (self.root.0, self.root.1, box_dist2(&self.root_box, p))
    }

    /// [`closest`](Self::closest), the same answer, starting from triangle `hint` (the last
    /// answer for a nearby point), which is updated: its distance prunes the search from the
    /// start, where a search from the root visits every box nearer than the first leaves it meets.
    pub fn closest_near(&self, p: DVec3, hint: &mut u32) -> Option<(f64, u32, DVec3)> {
        if self.corners.is_empty() {
            return None;
        }
        // (squared distance, triangle index, point), the smallest pair wherever the search goes.
        let mut best = (f64::INFINITY, u32::MAX, p);
        let mut best_m = f64::INFINITY;
        // The hint's whole leaf first (its neighbours, often nearer still).
        let mut searched = u32::MAX;
        if let Some(&s) = self.slot.get(*hint as usize) {
            let (first, count) = self.leaf_of[s as usize];
            self.nearest_in_leaf(p, first, count, &mut best, &mut best_m);
            searched = first;
        }
        let mut stack = Stack::new(self.root_visit(p));
        while let Some((first, count, d2)) = stack.pop() {
            if d2 > best.0 {
                continue;
            }
            if count == 0 {
                stack.push_children(&self.pairs[first as usize], p, best.0);
            } else if first != searched {
                self.nearest_in_leaf(p, first, count, &mut best, &mut best_m);
            }
        }
        *hint = best.1;
        (best.1 != u32::MAX).then(|| (best.0.sqrt(), best.1, best.2))
    }

    /// Updates `best` (and `best_m`, its square root) with the triangles of a leaf.
    #[inline(always)]
    fn nearest_in_leaf(
        &self,
        p: DVec3,
        first: u32,
        count: u32,
        best: &mut (f64, u32, DVec3),
        best_m: &mut f64,
    ) {
        for s in first as usize..(first + count) as usize {
            if self.culls[s].beyond(p, best.0, *best_m) {
                continue;
            }
            let q = closest_point_on(p, &self.corners[s]);
            let dd = (q - p).length_squared();
            let i = self.index[s];
            if dd < best.0 || (dd == best.0 && i < best.1) {
                *best = (dd, i, q);
                *best_m = dd.sqrt();
            }
        }
    }

    /// Distance from `p` to the mesh, or, as soon as some triangle closer
    /// than `thr` is found, that triangle's distance (then `< thr`, an upper
    /// bound of the distance). `INFINITY` for an empty mesh. For maxima over
    /// many points where only distances above a running maximum matter.
    /// `hint`: a triangle tried first (the last answer for a nearby point),
    /// updated to the closest triangle found.
    pub fn distance_or_below(&self, p: DVec3, thr: f64, hint: &mut u32) -> f64 {
        self.distance_between(p, thr, f64::INFINITY, hint)
    }

    /// [`distance_or_below`](Self::distance_or_below) that also gives up above `cap`: the
    /// distance when it lies in `[thr, cap)`, else some value below `thr` (as there) or `cap`
    /// itself (the distance is at least `cap`). For minima over several meshes, where a mesh
    /// farther than the best so far needs no exact answer.
    pub fn distance_between(&self, p: DVec3, thr: f64, cap: f64, hint: &mut u32) -> f64 {
        if self.corners.is_empty() {
            return f64::INFINITY;
        }
        let thr2 = if thr > 0.0 { thr * thr } else { 0.0 };
        // Nothing at or beyond the cap is looked at: boxes that far are pruned from the start.
        let mut best = Below {
            d2: cap * cap,
            m: cap,
            i: *hint,
            thr2,
        };
        // The hint, then its whole leaf (its neighbours, often nearer still).
        let mut searched = u32::MAX;
        if let Some(&s) = self.slot.get(*hint as usize) {
            let h = (closest_point_on(p, &self.corners[s as usize]) - p).length_squared();
            if h < thr2 || h == 0.0 {
                return h.sqrt();
            }
            if h < best.d2 {
                (best.d2, best.m) = (h, h.sqrt());
            }
            let (first, count) = self.leaf_of[s as usize];
            if self.below_in_leaf(p, first, count, s as usize, &mut best) {
                *hint = best.i;
                return best.d2.sqrt();
            }
            searched = first;
        }
        let mut stack = Stack::new(self.root_visit(p));
        while let Some((first, count, d2)) = stack.pop() {
            if d2 >= best.d2 {
                continue;
            }
            if count == 0 {
                stack.push_children(&self.pairs[first as usize], p, best.d2);
            } else if first != searched
                && self.below_in_leaf(p, first, count, usize::MAX, &mut best)
            {
                break;
            }
        }
        *hint = best.i;
        best.d2.sqrt()
    }

    /// Updates `best` with the triangles of a leaf but `skip`; whether one is closer than the
    /// threshold (or touches `p`), which settles the query.
    #[inline(always)]
    fn below_in_leaf(
        &self,
        p: DVec3,
        first: u32,
        count: u32,
        skip: usize,
        best: &mut Below,
    ) -> bool {
        for s in first as usize..(first + count) as usize {
            if s == skip || self.culls[s].beyond(p, best.d2, best.m) {
                continue;
            }
            let dd = (closest_point_on(p, &self.corners[s]) - p).length_squared();
            if dd < best.d2 {
                (best.d2, best.m, best.i) = (dd, dd.sqrt(), self.index[s]);
                if dd < best.thr2 || dd == 0.0 {
                    return true;
                }
            }
        }
        false
    }
}

/// The best of a [`MeshBvh::distance_between`] query so far: squared distance, distance, triangle
/// index, and the squared threshold below which any triangle settles it.
struct Below {
    d2: f64,
    m: f64,
    i: u32,
    thr2: f64,
}

/// The [`Pair`]s of `bvh` in depth-first order, and its root as a child of a pair.
fn pairs_of(bvh: &Bvh2) -> (Vec<Pair>, (u32, u32)) {
    let nodes = &bvh.nodes;
    if nodes[0].prim_count > 0 {
        return (Vec::new(), (nodes[0].first_index, nodes[0].prim_count));
    }
    let mut pairs: Vec<Pair> = Vec::with_capacity(nodes.len() / 2);
    // (inner node, where its pair's place is written: parent pair and side)
    let mut todo: Vec<(usize, Option<(usize, usize)>)> = vec![(0, None)];
    while let Some((ni, parent)) = todo.pop() {
        let at = pairs.len();
        if let Some((q, k)) = parent {
            pairs[q].first[k] = at as u32;
        }
        let c0 = nodes[ni].first_index as usize;
        let mut pair = Pair::default();
        for k in 0..2 {
            let c = &nodes[c0 + k];
            for ax in 0..3 {
                pair.lo[ax][k] = c.aabb.min[ax];
                pair.hi[ax][k] = c.aabb.max[ax];
            }
            (pair.first[k], pair.count[k]) = (c.first_index, c.prim_count);
        }
        pairs.push(pair);
        for k in (0..2).rev() {
            if nodes[c0 + k].prim_count == 0 {
                todo.push((c0 + k, Some((at, k))));
            }
        }
    }
    (pairs, (0, 0))
}

/// `x` rounded to the nearest `f32` not above it.
fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 <= x || !f.is_finite() {
        f
    } else if f == 0.0 {
        -f32::from_bits(1)
    } else if f > 0.0 {
        f32::from_bits(f.to_bits() - 1)
    } else {
        f32::from_bits(f.to_bits() + 1)
    }
}

/// `x` rounded to the nearest `f32` not below it.
fn f32_up(x: f64) -> f32 {
    -f32_down(-x)
}

/// Squared distance from `p` to box `a`, in `f64` and shrunk by a relative
/// 1e-12 against rounding: a lower bound of the distance to anything in the
/// box. (It was computed in `f32` with a slack of 1e-6 of the coordinates,
/// 0.1 mm at 100 m: as large as the distances measured on a fine mesh, so
/// queries could prune nothing near the point and visited many leaves.)
#[inline]
fn box_dist2(a: &Aabb, p: DVec3) -> f64 {
    let lo = DVec3::new(a.min.x as f64, a.min.y as f64, a.min.z as f64);
    let hi = DVec3::new(a.max.x as f64, a.max.y as f64, a.max.z as f64);
    let d = (lo - p).max(p - hi).max(DVec3::ZERO);
    d.length_squared() * (1.0 - 1e-12)
}

/// Deterministic surface samples: every referenced vertex plus `samples`
/// points distributed over the triangles proportionally to their area
/// (R2 low-discrepancy sequence inside each triangle).
pub fn sample_surface(mesh: TriMesh<'_>, samples: usize) -> Vec<DVec3> {
    let tris = mesh.triangles();
    let mut out: Vec<DVec3> = Vec::with_capacity(tris.len() * 3 / 2 + samples);
    let mut seen = vec![false; mesh.positions.len()];
    let n = mesh.positions.len();
    for &i in mesh.indices {
        if (i as usize) < n && !seen[i as usize] {
            seen[i as usize] = true;
            let v = mesh.positions[i as usize];
            let v = DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
            if v.is_finite() {
                out.push(v);
            }
        }
    }
    sample_area_into(&tris, samples, &mut out);
    out
}

/// The area-weighted part of [`sample_surface`].
fn sample_area_into(tris: &[[DVec3; 3]], samples: usize, out: &mut Vec<DVec3>) {
    for (t, (before, after)) in tris.iter().zip(area_point_ranges(tris, samples)) {
        out.extend((before + 1..=after).map(|k| area_point(t, k)));
    }
}

/// Per triangle, the indices `(before, after]` of the low-discrepancy sequence's points that fall
/// on it: `samples` points over the whole area, each triangle taking its share (none when the
/// area is zero or not a number).
fn area_point_ranges(tris: &[[DVec3; 3]], samples: usize) -> Vec<(u64, u64)> {
    let areas: Vec<f64> = tris
        .iter()
        .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length())
        .collect();
    let total: f64 = areas.iter().sum();
    if total.is_nan() || total <= 0.0 || samples == 0 {
        return vec![(0, 0); tris.len()];
    }
    let scale = samples as f64 / total;
    let mut acc = 0.0f64;
    areas
        .iter()
        .map(|&a| {
            let before = (acc * scale).floor() as u64;
            acc += a;
            (before, (acc * scale).floor() as u64)
        })
        .collect()
}

/// The `k`-th point of the low-discrepancy (plastic number) sequence, folded into triangle `t`.
fn area_point(t: &[DVec3; 3], k: u64) -> DVec3 {
    const G: f64 = 1.324_717_957_244_746; // plastic number
    let (a1, a2) = (1.0 / G, 1.0 / (G * G));
    let mut u = (0.5 + a1 * k as f64).fract();
    let mut v = (0.5 + a2 * k as f64).fract();
    if u + v > 1.0 {
        u = 1.0 - u;
        v = 1.0 - v;
    }
    t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v
}

/// Denser deterministic samples for the *measured* error of [`super::simplify`]:
/// [`sample_surface`] plus the midpoint of every triangle edge and every
/// triangle centroid, so that small triangles (thin parts) are always seen.
pub fn sample_surface_dense(mesh: TriMesh<'_>, samples: usize) -> Vec<DVec3> {
    let mut out = sample_surface(mesh, samples);
    for t in mesh.triangles() {
        out.push((t[0] + t[1]) * 0.5);
        out.push((t[1] + t[2]) * 0.5);
        out.push((t[2] + t[0]) * 0.5);
        out.push((t[0] + t[1] + t[2]) / 3.0);
    }
    out
}

/// The points of [`sample_surface_dense`], grouped by the triangle they lie on: a triangle's
/// corners, its area-weighted points, edge midpoints and centroid, plus the referenced vertices on
/// no valid triangle. The same points (as a set: a corner shared by triangles is listed with each),
/// so that a maximum of distances over them can skip a whole triangle at once: the distance to one
/// triangle of the other surface is convex, so its largest value on a triangle is at a corner.
pub struct DenseSamples {
    /// The valid triangles (as [`TriMesh`] keeps them).
    pub triangles: Vec<[DVec3; 3]>,
    /// Per triangle, the range of the low-discrepancy sequence's indices of its area points.
    area_points: Vec<(u64, u64)>,
    /// Referenced vertices on no valid triangle.
    pub lone_vertices: Vec<DVec3>,
}

impl DenseSamples {
    /// The points of `sample_surface_dense(mesh, samples)`.
    pub fn new(mesh: TriMesh<'_>, samples: usize) -> Self {
        let n = mesh.positions.len();
        let at = |i: u32| {
            let v = mesh.positions[i as usize];
            DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)
        };
        let mut on_triangle = vec![false; n];
        let mut triangles = Vec::with_capacity(mesh.indices.len() / 3);
        for t in mesh.indices.chunks_exact(3) {
            if !t.iter().all(|&i| (i as usize) < n) {
                continue;
            }
            let tri = [at(t[0]), at(t[1]), at(t[2])];
            if tri.iter().all(|v| v.is_finite())
                && (tri[1] - tri[0]).cross(tri[2] - tri[0]) != DVec3::ZERO
            {
                triangles.push(tri);
                for &i in t {
                    on_triangle[i as usize] = true;
                }
            }
        }
        let mut seen = vec![false; n];
        let mut lone_vertices = Vec::new();
        for &i in mesh.indices {
            if (i as usize) < n && !seen[i as usize] {
                seen[i as usize] = true;
                let v = at(i);
                if !on_triangle[i as usize] && v.is_finite() {
                    lone_vertices.push(v);
                }
            }
        }
        let area_points = area_point_ranges(&triangles, samples);
        DenseSamples {
            triangles,
            area_points,
            lone_vertices,
        }
    }

    /// Calls `f` on every point on triangle `i`: its corners, area points, edge midpoints and
    /// centroid.
    pub fn for_each_on_triangle(&self, i: usize, mut f: impl FnMut(DVec3)) {
        let t = &self.triangles[i];
        for &v in t {
            f(v);
        }
        let (before, after) = self.area_points[i];
        for k in before + 1..=after {
            f(area_point(t, k));
        }
        f((t[0] + t[1]) * 0.5);
        f((t[1] + t[2]) * 0.5);
        f((t[2] + t[0]) * 0.5);
        f((t[0] + t[1] + t[2]) / 3.0);
    }
}

/// Measured one-sided Hausdorff distances `(A->B, B->A)` with the points of
/// [`sample_surface_dense`] (`samples` area-weighted points on each side),
/// plus a 45-point barycentric grid on every triangle whose own vertex /
/// midpoint / centroid distances reach half the maximum found (narrow spikes
/// at concave corners were missed by the plain sampling).
/// A sampled value is a lower estimate of the true distance; see
/// [`super::SimplifyOptions::error_safety`] for how it is turned into a
/// declared error.
pub fn hausdorff_measured(a: TriMesh<'_>, b: TriMesh<'_>, samples: usize) -> (f64, f64) {
    use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
    let one = |x: TriMesh<'_>, y: TriMesh<'_>| {
        let bvh = MeshBvh::new(y);
        // Running maximum of the exact distances found (non-negative f64 bits
        // order like the values). A point's distance is only computed exactly
        // when it is at least `frac` times the running maximum (a bounded
        // query stops at the first triangle closer than that); the others
        // cannot change the result, so it does not depend on the thread
        // timing. `frac` 0.5 where the refinement below needs every value
        // >= half the maximum.
        let run = AtomicU64::new(0);
        let d = |p: DVec3, frac: f64, hint: &mut u32| -> f64 {
            let thr = frac * f64::from_bits(run.load(Relaxed));
            let r = bvh.distance_or_below(p, thr, hint);
            if r >= thr {
                run.fetch_max(r.to_bits(), Relaxed);
            }
            r
        };
        // Every referenced vertex once (as in `sample_surface`), by index.
        let n = x.positions.len();
        let mut referenced = vec![false; n];
        for &i in x.indices {
            if (i as usize) < n {
                referenced[i as usize] = true;
            }
        }
        let vd: Vec<f64> = (0..n)
            .into_par_iter()
            .with_min_len(1024)
            .map_init(
                || u32::MAX,
                |h, i| {
                    let v = x.positions[i];
                    let v = DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
                    if referenced[i] && v.is_finite() {
                        d(v, 0.5, h)
                    } else {
                        0.0
                    }
                },
            )
            .collect();
        // The valid triangles (as `TriMesh::triangles`) with their indices.
        let (tri_idx, tris): (Vec<[u32; 3]>, Vec<[DVec3; 3]>) = x
            .indices
            .chunks_exact(3)
            .filter(|t| t.iter().all(|&i| (i as usize) < n))
            .map(|t| {
                let p = |i: u32| {
                    let v = x.positions[i as usize];
                    DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)
                };
                ([t[0], t[1], t[2]], [p(t[0]), p(t[1]), p(t[2])])
            })
            .filter(|(_, t)| t.iter().all(|v| v.is_finite()))
            .filter(|(_, t)| (t[1] - t[0]).cross(t[2] - t[0]) != DVec3::ZERO)
            .unzip();
        let mut area = Vec::new();
        sample_area_into(&tris, samples, &mut area);
        area.par_iter().with_min_len(1024).for_each_init(
            || u32::MAX,
            |h, &p| {
                d(p, 0.5, h);
            },
        );
        // Per triangle: vertices, edge midpoints and centroid.
        let tmax: Vec<f64> = tris
            .par_iter()
            .zip(&tri_idx)
            .with_min_len(256)
            .map_init(
                || u32::MAX,
                |h, (t, ti)| {
                    let v = vd[ti[0] as usize]
                        .max(vd[ti[1] as usize])
                        .max(vd[ti[2] as usize]);
                    [
                        (t[0] + t[1]) * 0.5,
                        (t[1] + t[2]) * 0.5,
                        (t[2] + t[0]) * 0.5,
                        (t[0] + t[1] + t[2]) / 3.0,
                    ]
                    .into_iter()
                    .map(|p| d(p, 0.5, h))
                    .fold(v, f64::max)
                },
            )
            .collect();
        // Degenerate-only (zero-area) surfaces count as empty.
        if tris.is_empty() {
            return 0.0;
        }
        let h0 = f64::from_bits(run.load(Relaxed));
        // Refinement: the maximum is often a narrow spike (a triangle leaving
        // the other surface at a concave corner); triangles already near the
        // maximum get a barycentric grid of 45 points.
        const N: usize = 8;
        tris.par_iter()
            .zip(&tmax)
            .with_min_len(64)
            .filter(|(_, &m)| m >= 0.5 * h0 && m > 0.0)
            .for_each_init(
                || u32::MAX,
                |h, (t, _)| {
                    for i in 0..=N {
                        for j in 0..=N - i {
                            let (a, b) = (i as f64 / N as f64, j as f64 / N as f64);
                            d(t[0] * (1.0 - a - b) + t[1] * a + t[2] * b, 1.0, h);
                        }
                    }
                },
            );
        f64::from_bits(run.load(Relaxed))
    };
    (one(a, b), one(b, a))
}

/// Sampled one-sided Hausdorff distance `max_{p in A} d(p, B)` using
/// [`sample_surface`] on `a` with `samples` area-weighted points. Returns
/// `f64::INFINITY` if `b` is empty while `a` is not, 0 if `a` is empty.
pub fn hausdorff_one_sided(a: TriMesh<'_>, b: TriMesh<'_>, samples: usize) -> f64 {
    let bvh = MeshBvh::new(b);
    hausdorff_one_sided_bvh(a, &bvh, samples)
}

/// As [`hausdorff_one_sided`] with a prebuilt BVH of `b`.
pub fn hausdorff_one_sided_bvh(a: TriMesh<'_>, b: &MeshBvh, samples: usize) -> f64 {
    let pts = sample_surface(a, samples);
    if pts.is_empty() {
        return 0.0;
    }
    pts.par_iter()
        .map(|&p| b.closest(p).map_or(f64::INFINITY, |c| c.0))
        .reduce(|| 0.0, f64::max)
}

/// Sampled symmetric Hausdorff distance (max of both one-sided distances).
pub fn hausdorff(a: TriMesh<'_>, b: TriMesh<'_>, samples: usize) -> f64 {
    hausdorff_one_sided(a, b, samples).max(hausdorff_one_sided(b, a, samples))
}

/// Lower and upper bound of a Hausdorff distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HausdorffBound {
    /// Largest distance actually found at a point (a valid lower bound).
    pub lower: f64,
    /// Certified upper bound.
    pub upper: f64,
}

/// Controls [`hausdorff_bound_one_sided`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoundParams {
    /// Stop refining a triangle once its bound is within `lower * (1 + rel)`.
    pub rel_tolerance: f64,
    /// ... or below this absolute distance (metres).
    pub abs_tolerance: f64,
    /// Maximum closest-point queries spent refining one triangle.
    pub max_queries_per_triangle: usize,
}

impl Default for BoundParams {
    fn default() -> Self {
        BoundParams {
            rel_tolerance: 0.05,
            abs_tolerance: 1e-3,
            max_queries_per_triangle: 48,
        }
    }
}

/// Certified upper bound (and a lower bound) of the one-sided Hausdorff
/// distance from `a` to `b`, see the module docs.
pub fn hausdorff_bound_one_sided(
    a: TriMesh<'_>,
    b: TriMesh<'_>,
    params: &BoundParams,
) -> HausdorffBound {
    let bvh = MeshBvh::new(b);
    hausdorff_bound_one_sided_bvh(a, &bvh, params)
}

/// Symmetric version of [`hausdorff_bound_one_sided`].
pub fn hausdorff_bound(a: TriMesh<'_>, b: TriMesh<'_>, params: &BoundParams) -> HausdorffBound {
    let x = hausdorff_bound_one_sided(a, b, params);
    let y = hausdorff_bound_one_sided(b, a, params);
    HausdorffBound {
        lower: x.lower.max(y.lower),
        upper: x.upper.max(y.upper),
    }
}

/// As [`hausdorff_bound_one_sided`] with a prebuilt BVH of `b`.
pub fn hausdorff_bound_one_sided_bvh(
    a: TriMesh<'_>,
    b: &MeshBvh,
    params: &BoundParams,
) -> HausdorffBound {
    let tris = a.triangles();
    if tris.is_empty() {
        return HausdorffBound {
            lower: 0.0,
            upper: 0.0,
        };
    }
    if b.triangle_count() == 0 {
        return HausdorffBound {
            lower: f64::INFINITY,
            upper: f64::INFINITY,
        };
    }
    let query = |p: DVec3| -> (f64, u32) {
        b.closest(p)
            .map_or((f64::INFINITY, u32::MAX), |(d, t, _)| (d, t))
    };
    // Vertex and centroid distances first: the lower bound sets the target.
    let vq: Vec<[(f64, u32); 3]> = tris
        .par_iter()
        .map(|t| [query(t[0]), query(t[1]), query(t[2])])
        .collect();
    let lower0 = vq
        .iter()
        .flat_map(|q| q.iter().map(|x| x.0))
        .fold(0.0, f64::max);
    let target = (lower0 * (1.0 + params.rel_tolerance)).max(params.abs_tolerance);
    let budget = params.max_queries_per_triangle;

    let per_tri: Vec<(f64, f64)> = tris
        .par_iter()
        .zip(vq.par_iter())
        .map(|(t, q)| {
            let mut lower = q[0].0.max(q[1].0).max(q[2].0);
            let mut upper: f64 = 0.0;
            let mut used = 0usize;
            let mut stack: Vec<SubTri> = vec![(*t, *q)];
            while let Some((v, d)) = stack.pop() {
                let bound = sub_bound(b, &v, &d);
                if bound <= target || used + 3 > budget {
                    upper = upper.max(bound);
                    continue;
                }
                let m01 = (v[0] + v[1]) * 0.5;
                let m12 = (v[1] + v[2]) * 0.5;
                let m20 = (v[2] + v[0]) * 0.5;
                let (q01, q12, q20) = (query(m01), query(m12), query(m20));
                used += 3;
                lower = lower.max(q01.0).max(q12.0).max(q20.0);
                stack.push(([v[0], m01, m20], [d[0], q01, q20]));
                stack.push(([m01, v[1], m12], [q01, d[1], q12]));
                stack.push(([m20, m12, v[2]], [q20, q12, d[2]]));
                stack.push(([m01, m12, m20], [q01, q12, q20]));
            }
            (lower, upper)
        })
        .collect();
    let lower = per_tri.iter().map(|x| x.0).fold(lower0, f64::max);
    let upper = per_tri.iter().map(|x| x.1).fold(lower, f64::max);
    HausdorffBound { lower, upper }
}

/// A sub-triangle with the (distance, closest triangle) of its corners.
type SubTri = ([DVec3; 3], [(f64, u32); 3]);

fn sub_bound(b: &MeshBvh, v: &[DVec3; 3], d: &[(f64, u32); 3]) -> f64 {
    let maxd = d[0].0.max(d[1].0).max(d[2].0);
    let l = (v[1] - v[0])
        .length_squared()
        .max((v[2] - v[1]).length_squared())
        .max((v[0] - v[2]).length_squared())
        .sqrt();
    let mut bound = maxd + 0.5774 * l * (1.0 + 1e-9);
    for (_, tri) in d.iter() {
        if *tri == u32::MAX {
            continue;
        }
        let c = v
            .iter()
            .map(|&p| b.distance_to_triangle(p, *tri))
            .fold(0.0, f64::max);
        bound = bound.min(c);
    }
    bound
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(z: f32) -> (Vec<[f32; 3]>, Vec<u32>) {
        (
            vec![[0.0, 0.0, z], [1.0, 0.0, z], [1.0, 1.0, z], [0.0, 1.0, z]],
            vec![0, 1, 2, 0, 2, 3],
        )
    }

    #[test]
    fn grouped_samples_are_the_dense_samples() {
        // Uneven triangles, a degenerate one, an out-of-range index and a vertex on no valid
        // triangle (only on the degenerate one).
        let pos: Vec<[f32; 3]> = vec![
            [0.0, 0.0, 0.0],
            [3.0, 0.0, 0.1],
            [0.0, 1.0, 0.2],
            [5.0, 4.0, 1.0],
            [7.0, 7.0, 7.0],
            [1.0, 1.0, 1.0],
            [2.0, 2.0, 2.0],
        ];
        let idx = [0, 1, 2, 1, 3, 2, 4, 5, 6, 0, 1, 99];
        let mesh = TriMesh::new(&pos, &idx);
        let key = |v: DVec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
        let mut dense: Vec<_> = sample_surface_dense(mesh, 40)
            .into_iter()
            .map(key)
            .collect();
        let grouped = DenseSamples::new(mesh, 40);
        let mut ours: Vec<_> = grouped.lone_vertices.iter().map(|&v| key(v)).collect();
        for i in 0..grouped.triangles.len() {
            grouped.for_each_on_triangle(i, |x| ours.push(key(x)));
        }
        for v in [&mut dense, &mut ours] {
            v.sort_unstable();
            v.dedup();
        }
        assert_eq!(grouped.triangles.len(), 2);
        assert_eq!(grouped.lone_vertices.len(), 3);
        assert!(dense.len() > 40);
        assert_eq!(ours, dense);
    }

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        assert_eq!(
            closest_point_on_triangle(DVec3::new(-1.0, -1.0, 0.0), a, b, c),
            a
        );
        let p = closest_point_on_triangle(DVec3::new(0.2, 0.2, 5.0), a, b, c);
        assert!((p - DVec3::new(0.2, 0.2, 0.0)).length() < 1e-12);
        let p = closest_point_on_triangle(DVec3::new(1.0, 1.0, 0.0), a, b, c);
        assert!((p - DVec3::new(0.5, 0.5, 0.0)).length() < 1e-12);
    }

    #[test]
    fn parallel_planes() {
        let (pa, ia) = quad(0.0);
        let (pb, ib) = quad(0.25);
        let h = hausdorff(TriMesh::new(&pa, &ia), TriMesh::new(&pb, &ib), 1000);
        assert!((h - 0.25).abs() < 1e-6, "{h}");
        let bd = hausdorff_bound(
            TriMesh::new(&pa, &ia),
            TriMesh::new(&pb, &ib),
            &BoundParams::default(),
        );
        assert!(
            bd.upper >= h - 1e-9 && bd.upper < 0.25 * 1.06 + 1e-3,
            "{bd:?}"
        );
    }

    #[test]
    fn one_sided_is_asymmetric() {
        // a: unit quad; b: the quad plus a far away triangle.
        let (pa, ia) = quad(0.0);
        let mut pb = pa.clone();
        pb.extend([[5.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, 1.0, 0.0]]);
        let mut ib = ia.clone();
        ib.extend([4, 5, 6]);
        let ab = hausdorff_one_sided(TriMesh::new(&pa, &ia), TriMesh::new(&pb, &ib), 500);
        let ba = hausdorff_one_sided(TriMesh::new(&pb, &ib), TriMesh::new(&pa, &ia), 500);
        assert!(ab < 1e-9);
        assert!(ba > 3.9);
        let bound = hausdorff_bound_one_sided(
            TriMesh::new(&pb, &ib),
            TriMesh::new(&pa, &ia),
            &BoundParams::default(),
        );
        assert!(bound.upper >= ba && bound.lower <= ba + 1e-9);
    }

    #[test]
    fn brute_force_matches_bvh() {
        // A bumpy grid against random-ish points.
        let n = 20;
        let mut p = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                let (fx, fy) = (x as f32 / n as f32, y as f32 / n as f32);
                p.push([fx, fy, 0.1 * (fx * 7.0).sin() * (fy * 5.0).cos()]);
            }
        }
        let mut idx = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let i = (y * (n + 1) + x) as u32;
                let w = n as u32 + 1;
                idx.extend([i, i + 1, i + w + 1, i, i + w + 1, i + w]);
            }
        }
        let m = MeshBvh::new(TriMesh::new(&p, &idx));
        for k in 0..50 {
            let q = DVec3::new(
                (k as f64 * 0.37).fract() * 1.4 - 0.2,
                (k as f64 * 0.61).fract() * 1.4 - 0.2,
                (k as f64 * 0.23).fract() - 0.5,
            );
            let brute = (0..idx.len() / 3)
                .map(|t| m.distance_to_triangle(q, t as u32))
                .fold(f64::INFINITY, f64::min);
            let (d, near, _) = m.closest(q).unwrap();
            assert!((d - brute).abs() < 1e-9, "{d} vs {brute}");
            // From any hint, the same answer (ties to the smaller index included).
            for start in [0, near, (k * 13) % (idx.len() as u32 / 3), u32::MAX] {
                let mut hint = start;
                assert_eq!(m.closest_near(q, &mut hint), m.closest(q));
                assert_eq!(hint, near);
            }
            assert!(m.distance_lower_bound(q) <= brute);
            // Within [thr, cap): exact; below thr: some value below thr; at or above cap: cap.
            for (thr, cap) in [(0.0, f64::INFINITY), (0.05, 0.3), (0.2, 0.25), (0.0, 0.01)] {
                let mut hint = u32::MAX;
                let got = m.distance_between(q, thr, cap, &mut hint);
                if brute < thr {
                    assert!(got < thr, "{got} for {brute} below {thr}");
                } else if brute < cap {
                    assert!((got - brute).abs() < 1e-9, "{got} vs {brute}");
                } else {
                    assert!((got - cap).abs() < 1e-12, "{got} for {brute} over {cap}");
                }
            }
        }
    }

    /// The closest-point computation as it was before the edges were kept with the triangles.
    fn reference_closest(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
        let ab = b - a;
        let ac = c - a;
        let ap = p - a;
        let d1 = ab.dot(ap);
        let d2 = ac.dot(ap);
        if d1 <= 0.0 && d2 <= 0.0 {
            return a;
        }
        let bp = p - b;
        let d3 = ab.dot(bp);
        let d4 = ac.dot(bp);
        if d3 >= 0.0 && d4 <= d3 {
            return b;
        }
        let vc = d1 * d4 - d3 * d2;
        if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
            return a + ab * (d1 / (d1 - d3));
        }
        let cp = p - c;
        let d5 = ab.dot(cp);
        let d6 = ac.dot(cp);
        if d6 >= 0.0 && d5 <= d6 {
            return c;
        }
        let vb = d5 * d2 - d1 * d6;
        if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
            return a + ac * (d2 / (d2 - d6));
        }
        let va = d3 * d6 - d5 * d4;
        if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
            return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
        }
        let denom = va + vb + vc;
        if denom.is_nan() || denom == 0.0 {
            let e = [
                closest_on_segment(p, a, b),
                closest_on_segment(p, b, c),
                closest_on_segment(p, c, a),
            ];
            return e
                .into_iter()
                .min_by(|x, y| {
                    (*x - p)
                        .length_squared()
                        .total_cmp(&(*y - p).length_squared())
                })
                .unwrap_or(a);
        }
        let denom = 1.0 / denom;
        a + ab * (vb * denom) + ac * (vc * denom)
    }

    /// A small deterministic generator (xorshift) of values in `[-1, 1)`.
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        }
        fn vec(&mut self, scale: f64) -> DVec3 {
            DVec3::new(self.next(), self.next(), self.next()) * scale
        }
    }

    /// Triangles of every kind the kernels must handle: general, needles, zero-area (collinear,
    /// repeated corners), far from the origin, and points on their corners, edges and planes.
    fn kernel_cases() -> Vec<(DVec3, [DVec3; 3])> {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let mut out = Vec::new();
        for k in 0..4000 {
            let offset = if k % 4 == 0 {
                DVec3::new(512_345.25, 5_412_345.5, 37.0)
            } else {
                DVec3::ZERO
            };
            let a = offset + rng.vec(10.0);
            let (b, c) = match k % 5 {
                0 => (a + rng.vec(10.0), a + rng.vec(10.0)),
                // A needle: the third corner a hair off the first edge.
                1 => {
                    let b = a + rng.vec(10.0);
                    (b, a + (b - a) * 0.37 + rng.vec(1e-9))
                }
                // Collinear corners (zero area).
                2 => {
                    let b = a + rng.vec(10.0);
                    (b, a + (b - a) * 2.5)
                }
                // A repeated corner.
                3 => (a, a + rng.vec(10.0)),
                _ => (a + DVec3::X * 3.0, a + DVec3::Y * 2.0),
            };
            let t = [a, b, c];
            let u = rng.next().abs();
            let v = rng.next().abs() * (1.0 - u);
            let on_plane = a + (b - a) * u + (c - a) * v;
            let points = [
                offset + rng.vec(20.0),
                a,
                b,
                c,
                (a + b) * 0.5,
                b + (c - b) * u,
                on_plane,
                on_plane + (b - a).cross(c - a).normalize_or_zero() * rng.next(),
            ];
            out.extend(points.into_iter().map(|p| (p, t)));
        }
        out
    }

    #[test]
    fn kept_edges_give_the_reference_closest_point() {
        for (p, [a, b, c]) in kernel_cases() {
            let want = reference_closest(p, a, b, c);
            let got = closest_point_on(p, &Corners::new(a, b, c));
            assert_eq!(
                want.to_array().map(f64::to_bits),
                got.to_array().map(f64::to_bits),
                "{p} {a} {b} {c}"
            );
        }
    }

    #[test]
    fn cull_rules_out_no_triangle_as_near_as_the_best() {
        let mut rng = Rng(7);
        let mut ruled_out = 0;
        for (p, [a, b, c]) in kernel_cases() {
            let t = Corners::new(a, b, c);
            if t.ab.cross(t.ac) == DVec3::ZERO {
                // Not kept by a `MeshBvh` (zero area).
                continue;
            }
            let cull = Cull::new(&t);
            let dd = (reference_closest(p, a, b, c) - p).length_squared();
            // A best exactly this triangle's distance (a tie), and bests around it.
            for f in [1.0, 1.0 + 1e-15, 1.0 - 1e-15, 0.5, 0.999, 0.0, 2.0] {
                let best2 = dd * f;
                if cull.beyond(p, best2, best2.sqrt()) {
                    assert!(dd > best2, "{p} {a} {b} {c}: {dd} ruled out at {best2}");
                    ruled_out += 1;
                }
            }
            let best2 = (rng.next().abs() * 30.0).powi(2);
            if cull.beyond(p, best2, best2.sqrt()) {
                assert!(dd > best2, "{p} {a} {b} {c}: {dd} ruled out at {best2}");
            }
        }
        // The test means something: most bests well below the distance are ruled out.
        assert!(ruled_out > 10_000, "{ruled_out}");
    }

    #[test]
    fn queries_match_brute_force_on_a_soup() {
        // Random, coplanar, duplicated (ties) and degenerate triangles, in leaves of several.
        let mut rng = Rng(42);
        let mut pos: Vec<[f32; 3]> = Vec::new();
        let mut idx = Vec::new();
        for k in 0..600 {
            let a = rng.vec(5.0);
            let (b, c) = if k % 3 == 0 {
                (a + DVec3::X * 0.3, a + DVec3::Y * 0.2)
            } else {
                (a + rng.vec(0.5), a + rng.vec(0.5))
            };
            let base = pos.len() as u32;
            for v in [a, b, c] {
                pos.push([v.x as f32, v.y as f32, v.z as f32]);
            }
            idx.extend([base, base + 1, base + 2]);
            if k % 7 == 0 {
                idx.extend([base, base + 1, base + 2]);
            }
            if k % 11 == 0 {
                idx.extend([base, base, base + 1]);
            }
        }
        let m = MeshBvh::new(TriMesh::new(&pos, &idx));
        let valid = m.triangle_count() as u32;
        for _ in 0..300 {
            let q = rng.vec(6.0);
            let (mut brute, mut near) = (f64::INFINITY, u32::MAX);
            for t in 0..valid {
                let d = m.distance_to_triangle(q, t);
                if d < brute {
                    (brute, near) = (d, t);
                }
            }
            let (d, t, _) = m.closest(q).unwrap();
            assert_eq!((d.to_bits(), t), (brute.to_bits(), near));
            for start in [0, near, valid / 2, u32::MAX] {
                let mut hint = start;
                assert_eq!(m.closest_near(q, &mut hint), m.closest(q));
                let mut hint = start;
                let got = m.distance_between(q, 0.0, f64::INFINITY, &mut hint);
                assert_eq!(got.to_bits(), brute.to_bits());
            }
        }
    }

    #[test]
    fn stack_spills_and_keeps_its_order() {
        let mut s = Stack::new((0, 0, 0.0));
        for i in 1..200u32 {
            s.push((i, 0, 0.0));
        }
        for i in (0..200u32).rev() {
            assert_eq!(s.pop().map(|v| v.0), Some(i));
            if i % 50 == 0 && i > 0 {
                // Pushes after pops still come back first.
                s.push((1000, 0, 0.0));
                assert_eq!(s.pop().map(|v| v.0), Some(1000));
            }
        }
        assert!(s.pop().is_none());
    }
}
