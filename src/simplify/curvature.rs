//! Discrete vertex curvature used for the paper's curvature weighting
//! (section III.C (2)): edges whose endpoints have a large curvature are
//! pushed back in the collapse order.
//!
//! The measure is the *normal spread* of a vertex: `k = 1 - min_f (n_f . n̄)`
//! over the incident faces `f`, where `n̄` is the area-weighted mean normal,
//! clamped to `[0, 1]`. It is 0 on flat regions, small on smooth curved
//! surfaces (about `θ²/2` for facets turning by `θ`), ~0.42 at a box corner and
//! 1 at folded (back-to-back) geometry. Unlike angle-deficit (Gaussian)
//! curvature it also sees creases, which matter most in BIM models.

use glam::DVec3;

/// Curvature per position vertex for triangles `tris` given as position
/// vertex indices.
pub(crate) fn vertex_curvature(pos: &[DVec3], tris: &[[u32; 3]]) -> Vec<f32> {
    let n = pos.len();
    let mut sum = vec![DVec3::ZERO; n];
    // Face normals are recomputed in the second pass rather than stored (a
    // stored array was 24 bytes a triangle of memory traffic).
    let face_n = |t: &[u32; 3]| {
        let (a, b, c) = (pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]);
        (b - a).cross(c - a)
    };
    for t in tris {
        let fnrm = face_n(t);
        for &v in t {
            sum[v as usize] += fnrm;
        }
    }
    // Mean normals normalised once per vertex, not once per corner.
    for m in &mut sum {
        *m = m.normalize_or_zero();
    }
    let mut k = vec![0.0f32; n];
    let mut seen = vec![false; n];
    for t in tris {
        let f = face_n(t).normalize_or_zero();
        for &v in t {
            let m = sum[v as usize];
            let kv = if m == DVec3::ZERO {
                1.0
            } else {
                (1.0 - f.dot(m)).clamp(0.0, 1.0)
            };
            let v = v as usize;
            if !seen[v] || kv as f32 > k[v] {
                k[v] = kv as f32;
                seen[v] = true;
            }
        }
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_is_zero_corner_is_positive() {
        let pos = vec![
            DVec3::ZERO,
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            DVec3::new(-1.0, 0.0, 0.0),
        ];
        // flat fan around 0 in the z=0 plane
        let k = vertex_curvature(&pos, &[[0, 1, 2], [0, 2, 4]]);
        assert!(k[0].abs() < 1e-6);
        // corner of a cube-like fan (three orthogonal faces)
        let k = vertex_curvature(&pos, &[[0, 1, 2], [0, 3, 1], [0, 2, 3]]);
        assert!(k[0] > 0.3 && k[0] < 0.5, "{}", k[0]);
    }
}
