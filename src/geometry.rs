//! Geometry helpers below every stage: what dedup, tile content, simplification and the encoder
//! all need (instance transforms, face normals), so none of them reaches into another; and the
//! polygon triangulation every reader of polygon faces shares (earcut on the best-fit plane).

use glam::{DMat3, DMat4, DQuat, DVec3};

/// `world` as translation, rotation and scale (the instancing attributes), when it is exactly
/// such a product (no shear, affine); None otherwise, and the writer must bake that instance.
/// A mirroring `world` comes out with a negative scale component.
pub fn instance_trs(world: &DMat4) -> Option<(DVec3, DQuat, DVec3)> {
    if !world.is_finite() || world.row(3) != glam::DVec4::new(0.0, 0.0, 0.0, 1.0) {
        return None;
    }
    let (s, r, t) = world.to_scale_rotation_translation();
    let back = DMat4::from_scale_rotation_translation(s, r, t);
    let size = DMat3::from_mat4(*world)
        .to_cols_array()
        .iter()
        .fold(0f64, |a, x| a.max(x.abs()));
    let err = (0..4)
        .map(|i| (back.col(i) - world.col(i)).abs().max_element())
        .fold(0f64, f64::max);
    (err <= 1e-9 * size.max(1.0) && s.is_finite() && r.is_finite()).then_some((t, r, s))
}

/// A unit normal, or +z for a zero or non-finite one (exporters write both).
pub fn unit_normal_or_z(n: [f32; 3]) -> [f32; 3] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l.is_finite() && l > 1e-12 {
        n.map(|c| c / l)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// Replaces `normals` (one per vertex) by the area-weighted face normals of the triangles of
/// `indices` that use each vertex.
pub fn normals_from_faces(positions: &[[f32; 3]], indices: &[u32], normals: &mut [[f32; 3]]) {
    set_normals(&face_vectors(positions, indices), indices, normals);
}

/// Per triangle, the cross product of two edges: its normal, with twice its area as length.
pub fn face_vectors(positions: &[[f32; 3]], indices: &[u32]) -> Vec<DVec3> {
    let at = |i: u32| DVec3::from_array(positions[i as usize].map(f64::from));
    indices
        .chunks_exact(3)
        .map(|t| (at(t[1]) - at(t[0])).cross(at(t[2]) - at(t[0])))
        .collect()
}

/// What a vertex's triangles add up to.
#[derive(Clone, Copy, Default)]
pub struct VertexSum {
    /// Sum of their face vectors (area-weighted normal).
    pub sum: DVec3,
    /// Sum of their face vectors' lengths.
    pub area: f64,
    /// The first one with area, for faces that cancel out (both sides of a sheet).
    pub first: DVec3,
}

pub fn vertex_sums(faces: &[DVec3], indices: &[u32], n: usize) -> Vec<VertexSum> {
    let mut sums = vec![VertexSum::default(); n];
    for (t, &f) in indices.chunks_exact(3).zip(faces) {
        for &v in t {
            let s = &mut sums[v as usize];
            s.sum += f;
            s.area += f.length();
            if s.first == DVec3::ZERO {
                s.first = f;
            }
        }
    }
    sums
}

/// [`normals_from_faces`] from the face vectors.
pub fn set_normals(faces: &[DVec3], indices: &[u32], normals: &mut [[f32; 3]]) {
    let sums = vertex_sums(faces, indices, normals.len());
    for (out, s) in normals.iter_mut().zip(sums) {
        let old = DVec3::from_array(out.map(f64::from));
        // Interpolation can leave a zero normal (opposite normals merged): glTF wants unit ones.
        let n = s
            .sum
            .try_normalize()
            .or_else(|| s.first.try_normalize())
            .or_else(|| old.try_normalize())
            .unwrap_or(DVec3::Z);
        *out = n.as_vec3().to_array();
    }
}

/// The distance between box `a` and box `b` (0 when they touch or overlap).
pub(crate) fn box_gap(lo_a: DVec3, hi_a: DVec3, lo_b: DVec3, hi_b: DVec3) -> f64 {
    (lo_b - hi_a).max(lo_a - hi_b).max(DVec3::ZERO).length()
}

/// For each box, the distance to the nearest other box (0 when they touch or overlap), capped at
/// the diagonal of all boxes. Boxes go into a uniform grid (about one box per cell); each box
/// searches rings of cells outwards until a ring cannot hold a nearer box. Boxes spanning many
/// cells (slabs, terrain) are kept aside and compared with every box.
pub(crate) fn box_gaps(lo: &[DVec3], hi: &[DVec3]) -> Vec<f64> {
    use rayon::prelude::*;
    let n = lo.len();
    let (all_lo, all_hi) = lo.iter().zip(hi).fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(a, b), (l, h)| (a.min(*l), b.max(*h)),
    );
    let diag = (all_hi - all_lo).length();
    if n < 2 || diag.is_nan() || diag <= 0.0 {
        return vec![diag.max(0.0); n];
    }
    let box_dist = |i: usize, j: usize| box_gap(lo[i], hi[i], lo[j], hi[j]);
    const MAX_CELLS_PER_AXIS: f64 = 64.0;
    const MAX_CELLS_PER_BOX: usize = 64;
    let ext = (all_hi - all_lo).max(DVec3::splat(diag * 1e-9));
    let cell = (ext.x * ext.y * ext.z / n as f64)
        .cbrt()
        .max(ext.max_element() / MAX_CELLS_PER_AXIS);
    let dims = (ext / cell).ceil().as_uvec3().max(glam::UVec3::ONE);
    let at = |p: DVec3| -> glam::IVec3 {
        ((p - all_lo) / cell)
            .floor()
            .as_ivec3()
            .clamp(glam::IVec3::ZERO, dims.as_ivec3() - 1)
    };
    let slot = |c: glam::IVec3| {
        (c.x as usize * dims.y as usize + c.y as usize) * dims.z as usize + c.z as usize
    };
    let mut cells: Vec<Vec<u32>> = vec![Vec::new(); (dims.x * dims.y * dims.z) as usize];
    let mut large: Vec<u32> = Vec::new();
    for i in 0..n {
        let (a, b) = (at(lo[i]), at(hi[i]));
        let span = (b - a + 1).as_uvec3();
        if (span.x * span.y * span.z) as usize > MAX_CELLS_PER_BOX {
            large.push(i as u32);
            continue;
        }
        for x in a.x..=b.x {
            for y in a.y..=b.y {
                for z in a.z..=b.z {
                    cells[slot(glam::IVec3::new(x, y, z))].push(i as u32);
                }
            }
        }
    }
    (0..n)
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let mut best = diag;
            for &j in &large {
                if j as usize != i {
                    best = best.min(box_dist(i, j as usize));
                }
            }
            let (a, b) = (at(lo[i]), at(hi[i]));
            let top = dims.as_ivec3() - 1;
            let mut ring = 0i32;
            // A box in ring k is at least (k - 1) cells away from box i.
            while (ring as f64 - 1.0) * cell < best {
                let (ra, rb) = (a - ring, b + ring);
                if ra.cmplt(glam::IVec3::ZERO).all() && rb.cmpgt(top).all() {
                    break;
                }
                let mut visit = |x: i32, y: i32, z: i32| {
                    for &j in &cells[slot(glam::IVec3::new(x, y, z))] {
                        if j as usize != i {
                            best = best.min(box_dist(i, j as usize));
                        }
                    }
                };
                // Only the ring's shell: its cells with a coordinate on the ring's faces.
                for x in ra.x.max(0)..=rb.x.min(top.x) {
                    for y in ra.y.max(0)..=rb.y.min(top.y) {
                        if ring == 0 || x == ra.x || x == rb.x || y == ra.y || y == rb.y {
                            for z in ra.z.max(0)..=rb.z.min(top.z) {
                                visit(x, y, z);
                            }
                        } else {
                            for z in [ra.z, rb.z] {
                                if (0..=top.z).contains(&z) {
                                    visit(x, y, z);
                                }
                            }
                        }
                    }
                }
                ring += 1;
            }
            best
        })
        .collect()
}

/// For unit tests: a deterministic uniform generator in [0, 1) (a 64-bit LCG's top 53 bits), so
/// randomized tests give the same cases on every machine.
#[cfg(test)]
pub(crate) fn test_uniform(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A polygon's triangles: indices into its ring points (outer ring, then holes), wound like the
/// polygon, and the polygon's normal.
pub struct PolygonTriangles {
    pub indices: Vec<usize>,
    pub normal: DVec3,
}

/// Triangulates a polygon with holes on its best-fit plane (`None`: degenerate, no area).
pub fn triangulate(
    ring_points: &[DVec3],
    holes: &[usize],
) -> std::result::Result<Option<PolygonTriangles>, String> {
    if ring_points.len() < 3 {
        return Ok(None);
    }
    // Newell's normal of the outer ring (robust for non-convex and slightly warped rings).
    let outer = holes.first().copied().unwrap_or(ring_points.len());
    let centre = ring_points[..outer].iter().sum::<DVec3>() / outer as f64;
    let mut normal = DVec3::ZERO;
    for k in 0..outer {
        let (a, b) = (
            ring_points[k] - centre,
            ring_points[(k + 1) % outer] - centre,
        );
        normal += DVec3::new(
            (a.y - b.y) * (a.z + b.z),
            (a.z - b.z) * (a.x + b.x),
            (a.x - b.x) * (a.y + b.y),
        );
    }
    let Some(normal) = normal.try_normalize() else {
        return Ok(None);
    };
    let u = normal.any_orthonormal_vector();
    let v = normal.cross(u);
    let flat: Vec<f64> = ring_points
        .iter()
        .flat_map(|p| {
            let d = *p - centre;
            [d.dot(u), d.dot(v)]
        })
        .collect();
    let mut indices = earcutr::earcut(&flat, holes, 2).map_err(|e| format!("{e:?}"))?;
    for t in indices.chunks_exact_mut(3) {
        let [a, b, c] = [ring_points[t[0]], ring_points[t[1]], ring_points[t[2]]];
        // earcut's winding follows the 2-D frame: keep the polygon's own orientation.
        if (b - a).cross(c - a).dot(normal) < 0.0 {
            t.swap(1, 2);
        }
    }
    Ok(Some(PolygonTriangles { indices, normal }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn instance_trs_decomposes_rigid_and_rejects_shear() {
        let w = DMat4::from_rotation_translation(
            DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 40f64.to_radians()),
            DVec3::new(1.0, 2.0, 3.0),
        ) * DMat4::from_scale(DVec3::new(2.0, 2.0, -2.0));
        let (t, r, s) = instance_trs(&w).unwrap();
        let back = DMat4::from_scale_rotation_translation(s, r, t);
        assert!(back.abs_diff_eq(w, 1e-12));
        let shear = DMat4::from_cols_array(&[
            1.0, 0.0, 0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ]);
        assert!(instance_trs(&shear).is_none());
    }

    /// The grid search finds what comparing every pair finds, on scattered small boxes, a slab
    /// spanning many cells and a box far from all others.
    #[test]
    fn box_gaps_match_all_pairs() {
        let mut lo = Vec::new();
        let mut hi = Vec::new();
        let mut rnd = crate::geometry::test_uniform(12345);
        for _ in 0..400 {
            let c = DVec3::new(rnd() * 100.0, rnd() * 80.0, rnd() * 10.0);
            let h = DVec3::new(rnd(), rnd(), rnd()) * 0.8;
            lo.push(c - h);
            hi.push(c + h);
        }
        lo.push(DVec3::new(0.0, 0.0, -1.0));
        hi.push(DVec3::new(100.0, 80.0, -0.5));
        lo.push(DVec3::new(400.0, 400.0, 0.0));
        hi.push(DVec3::new(401.0, 401.0, 1.0));
        let gaps = box_gaps(&lo, &hi);
        for i in 0..lo.len() {
            let brute = (0..lo.len())
                .filter(|&j| j != i)
                .map(|j| (lo[j] - hi[i]).max(lo[i] - hi[j]).max(DVec3::ZERO).length())
                .fold(f64::INFINITY, f64::min);
            assert!(
                (gaps[i] - brute).abs() < 1e-9,
                "box {i}: {} vs {brute}",
                gaps[i]
            );
        }
        assert!(gaps[401] > 400.0);
        // One box alone: the diagonal of everything stands for the gap.
        assert_eq!(box_gaps(&lo[..1], &hi[..1]), vec![(hi[0] - lo[0]).length()]);
    }
}
