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

/// A BVH over the triangles of a mesh answering closest-point queries.
pub struct MeshBvh {
    tris: Vec<[DVec3; 3]>,
    /// Unit normal and plane offset of each triangle (`n . x = d`): the
    /// plane distance is a cheap lower bound that skips most exact
    /// closest-point computations in [`MeshBvh::distance_or_below`].
    planes: Vec<(DVec3, f64)>,
    bvh: Option<Bvh2>,
}

impl MeshBvh {
    /// Builds the BVH (a `obvhs` BVH2 over triangle AABBs, rounded outwards
    /// to `f32` so the boxes always contain the `f64` triangles).
    pub fn new(mesh: TriMesh<'_>) -> Self {
        let tris = mesh.triangles();
        if tris.is_empty() {
            return MeshBvh {
                tris,
                planes: Vec::new(),
                bvh: None,
            };
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
        let planes = tris
            .iter()
            .map(|t| {
                let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                (n, n.dot(t[0]))
            })
            .collect();
        MeshBvh {
            tris,
            planes,
            bvh: Some(bvh),
        }
    }

    /// A lower bound of the distance from `p` to the mesh (its bounding box); `INFINITY` for an
    /// empty mesh.
    pub fn distance_lower_bound(&self, p: DVec3) -> f64 {
        self.bvh
            .as_ref()
            .map_or(f64::INFINITY, |b| box_dist2(&b.nodes[0].aabb, p).sqrt())
    }

    /// Number of (valid) triangles.
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Distance from `p` to triangle `i` of this mesh.
    pub fn distance_to_triangle(&self, p: DVec3, i: u32) -> f64 {
        let t = &self.tris[i as usize];
        (closest_point_on_triangle(p, t[0], t[1], t[2]) - p).length()
    }

    /// Closest point: `(distance, triangle index, point)`; `None` for an empty
    /// mesh. Ties are broken by the smaller triangle index (deterministic).
    pub fn closest(&self, p: DVec3) -> Option<(f64, u32, DVec3)> {
        let mut from_root = u32::MAX;
        self.closest_near(p, &mut from_root)
    }

    /// [`closest`](Self::closest), the same answer, starting from triangle `hint` (the last
    /// answer for a nearby point), which is updated: its distance prunes the search from the
    /// start, where a search from the root visits every box nearer than the first leaves it meets.
    pub fn closest_near(&self, p: DVec3, hint: &mut u32) -> Option<(f64, u32, DVec3)> {
        let bvh = self.bvh.as_ref()?;
        let box_d2 = |a: &Aabb| box_dist2(a, p);
        let mut best = (f64::INFINITY, u32::MAX, p);
        if let Some(t) = self.tris.get(*hint as usize) {
            let q = closest_point_on_triangle(p, t[0], t[1], t[2]);
            best = ((q - p).length_squared(), *hint, q);
        }
        let mut stack: Vec<(u32, f64)> = Vec::with_capacity(64);
        stack.push((0, box_d2(&bvh.nodes[0].aabb)));
        while let Some((ni, d2)) = stack.pop() {
            if d2 > best.0 {
                continue;
            }
            let node = &bvh.nodes[ni as usize];
            if node.prim_count > 0 {
                let s = node.first_index as usize;
                for &prim in &bvh.primitive_indices[s..s + node.prim_count as usize] {
                    // The plane distance, less a slack far above its rounding (which grows with
                    // the coordinates, not the distance), is a lower bound: a triangle strictly
                    // beyond the best can neither beat nor tie it.
                    let (n, d) = self.planes[prim as usize];
                    let np = n.dot(p);
                    let h = ((np - d).abs() - 1e-12 * (np.abs() + d.abs())).max(0.0);
                    if h * h > best.0 {
                        continue;
                    }
                    let t = &self.tris[prim as usize];
                    let q = closest_point_on_triangle(p, t[0], t[1], t[2]);
                    let dd = (q - p).length_squared();
                    if dd < best.0 || (dd == best.0 && prim < best.1) {
                        best = (dd, prim, q);
                    }
                }
            } else {
                let c0 = node.first_index;
                let c1 = c0 + 1;
                let d0 = box_d2(&bvh.nodes[c0 as usize].aabb);
                let d1 = box_d2(&bvh.nodes[c1 as usize].aabb);
                // Push the farther first so the nearer is visited first.
                if d0 <= d1 {
                    stack.push((c1, d1));
                    stack.push((c0, d0));
                } else {
                    stack.push((c0, d0));
                    stack.push((c1, d1));
                }
            }
        }
        *hint = best.1;
        (best.1 != u32::MAX).then(|| (best.0.sqrt(), best.1, best.2))
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
        let Some(bvh) = self.bvh.as_ref() else {
            return f64::INFINITY;
        };
        let thr2 = if thr > 0.0 { thr * thr } else { 0.0 };
        // Nothing at or beyond the cap is looked at: boxes that far are pruned from the start.
        let mut best = cap * cap;
        let mut best_i = *hint;
        if let Some(t) = self.tris.get(*hint as usize) {
            let h = (closest_point_on_triangle(p, t[0], t[1], t[2]) - p).length_squared();
            if h < thr2 || h == 0.0 {
                return h.sqrt();
            }
            best = best.min(h);
        }
        let box_d2 = |a: &Aabb| box_dist2(a, p);
        const CAP: usize = 128;
        let mut stack = [(0u32, 0.0f64); CAP];
        let mut sp = 1;
        stack[0] = (0, box_d2(&bvh.nodes[0].aabb));
        while sp > 0 {
            sp -= 1;
            let (ni, d2) = stack[sp];
            if d2 >= best {
                continue;
            }
            let node = &bvh.nodes[ni as usize];
            if node.prim_count > 0 {
                let s = node.first_index as usize;
                for &prim in &bvh.primitive_indices[s..s + node.prim_count as usize] {
                    // Plane distance first (shrunk by a relative 1e-9 for
                    // rounding): not closer than `best`, so no update.
                    let (n, d) = self.planes[prim as usize];
                    let h = (n.dot(p) - d).abs() * (1.0 - 1e-9);
                    if h * h >= best {
                        continue;
                    }
                    let t = &self.tris[prim as usize];
                    let dd = (closest_point_on_triangle(p, t[0], t[1], t[2]) - p).length_squared();
                    if dd < best {
                        best = dd;
                        best_i = prim;
                    }
                }
                if best < thr2 || best == 0.0 {
                    *hint = best_i;
                    return best.sqrt();
                }
            } else {
                if sp + 2 > CAP {
                    // Pathologically deep tree: the unbounded query.
                    return self.closest(p).map_or(f64::INFINITY, |c| {
                        *hint = c.1;
                        c.0
                    });
                }
                let c0 = node.first_index;
                let c1 = c0 + 1;
                let d0 = box_d2(&bvh.nodes[c0 as usize].aabb);
                let d1 = box_d2(&bvh.nodes[c1 as usize].aabb);
                if d0 <= d1 {
                    stack[sp] = (c1, d1);
                    stack[sp + 1] = (c0, d0);
                } else {
                    stack[sp] = (c0, d0);
                    stack[sp + 1] = (c1, d1);
                }
                sp += 2;
            }
        }
        *hint = best_i;
        best.sqrt()
    }
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
}
