//! Geometry helpers below every stage: what dedup, tile content, simplification and the encoder
//! all need (instance transforms, face normals), so none of them reaches into another.

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
}
