//! Shading normals of a simplified mesh, taken from its own faces.
//!
//! The collapses interpolate the input's normals (`qem.rs`), but the faces around a vertex turn as
//! the surface coarsens, and a wedge kept from a box's side can end up on its top, its normal far
//! off the faces that use it (docs/benchmarks.md). Coarse tiles were shaded wrongly, and changed
//! shade when refined (popping).
//! Draco also predicts normals from the faces (geometric normal prediction), so normals that
//! disagree with them cost nearly as much as the positions; taken from the faces they cost little.
//!
//! Each vertex (wedge) gets the area-weighted mean of the normals of the triangles that use it, in
//! their winding's direction (what the glTF front face is). Attribute seams split wedges, so hard
//! edges stay hard and smooth surfaces smooth. A vertex whose faces cancel out (both sides of a
//! sheet) takes one face's normal; one whose faces have no area keeps its normal if it has one.
//! Every normal comes out of unit length, as glTF requires.
//!
//! Before that, [`split_opposite_faces`] gives each side of a sheet its own vertices: collapses
//! can merge the two sides' wedges where they share positions (a glass pane drawn as two
//! triangles back to back), and one normal cannot shade both (the interpolated one was zero,
//! which glTF forbids).

use glam::DVec3;

use super::SimplifiedMesh;
#[cfg(test)]
use crate::geometry::normals_from_faces;
use crate::geometry::{face_vectors, set_normals, vertex_sums};

/// A vertex is split when its faces' area-weighted mean normal is shorter than this share of
/// their total area: its faces face opposite ways nearly as much as not (two sides of a sheet),
/// so the mean's direction is arbitrary. Each split costs bytes (QEM leaves many flattened parts
/// whose two sides share vertices), so only the most ambiguous vertices split (chosen by
/// measurement: docs/benchmarks.md).
const SPLIT_BELOW_MEAN_SHARE: f64 = 0.1;

/// Gives `m` normals from its faces: splits the vertices whose faces face opposite ways about
/// equally ([`split_opposite_faces`]), then [`normals_from_faces`]; the face vectors are computed
/// once for both (a copy keeps its vertex's position).
pub fn take_normals_from_faces(m: &mut SimplifiedMesh) {
    let faces = face_vectors(&m.positions, &m.indices);
    split_opposite_faces(m, &faces);
    if let Some(n) = m.normals.as_mut() {
        set_normals(&faces, &m.indices, n);
    }
}

/// Splits every vertex whose triangles face opposite ways about equally (see
/// [`SPLIT_BELOW_MEAN_SHARE`]): the triangles whose normal points against the vertex's
/// area-weighted mean (or, where the two sides cancel exactly, against its first triangle) get a
/// copy of the vertex with all its attributes. `faces`: [`face_vectors`] of `m`.
fn split_opposite_faces(m: &mut SimplifiedMesh, faces: &[DVec3]) {
    let n = m.positions.len();
    let sums = vertex_sums(faces, &m.indices, n);
    let mut twin = vec![u32::MAX; n];
    for (t, &f) in m.indices.chunks_exact_mut(3).zip(faces) {
        for v in t {
            let i = *v as usize;
            let s = &sums[i];
            // Faces that mostly agree keep one vertex: the mean shades the larger side right.
            if s.sum.length() > SPLIT_BELOW_MEAN_SHARE * s.area {
                continue;
            }
            let reference = if s.sum != DVec3::ZERO { s.sum } else { s.first };
            if f.dot(reference) >= 0.0 {
                continue;
            }
            if twin[i] == u32::MAX {
                twin[i] = m.positions.len() as u32;
                m.positions.push(m.positions[i]);
                m.groups.push(m.groups[i]);
                m.source_vertex.push(m.source_vertex[i]);
                if let Some(a) = m.normals.as_mut() {
                    a.push(a[i]);
                }
                if let Some(a) = m.uvs.as_mut() {
                    a.push(a[i]);
                }
                if let Some(a) = m.colors.as_mut() {
                    a.push(a[i]);
                }
            }
            *v = twin[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_two_sides_of_a_sheet_get_their_own_vertices_and_normals() {
        // One triangle drawn both ways round on the same three vertices.
        let mut m = SimplifiedMesh {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            normals: Some(vec![[0.0; 3]; 3]),
            uvs: Some(vec![[0.5, 0.5]; 3]),
            groups: vec![7; 3],
            source_vertex: vec![0, 1, 2],
            indices: vec![0, 1, 2, 0, 2, 1],
            ..Default::default()
        };
        take_normals_from_faces(&mut m);
        // The second triangle's corners (0, 2, 1) get copies 3, 4, 5.
        assert_eq!(m.indices, [0, 1, 2, 3, 4, 5]);
        let p = &m.positions;
        assert_eq!([p[3], p[4], p[5]], [p[0], p[2], p[1]]);
        assert_eq!(m.source_vertex, [0, 1, 2, 0, 2, 1]);
        assert_eq!(m.groups, [7; 6]);
        assert_eq!(m.uvs.as_ref().map(Vec::len), Some(6));
        let n = m.normals.as_ref().unwrap();
        assert_eq!(n[..3], [[0.0, 0.0, 1.0]; 3]);
        assert_eq!(n[3..], [[0.0, 0.0, -1.0]; 3]);
        // A convex corner (faces 90 degrees apart) shares its vertices: nothing to split.
        let mut corner = SimplifiedMesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, -1.0],
            ],
            groups: vec![0; 4],
            source_vertex: vec![0, 1, 2, 3],
            indices: vec![0, 1, 2, 0, 2, 3],
            ..Default::default()
        };
        take_normals_from_faces(&mut corner);
        assert_eq!(corner.positions.len(), 4);
    }

    #[test]
    fn a_flat_quad_gets_its_face_normal_whatever_it_had() {
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let mut normals = [[1.0, 0.0, 0.0]; 4];
        normals_from_faces(&positions, &[0, 1, 2, 0, 2, 3], &mut normals);
        assert!(normals.iter().all(|n| *n == [0.0, 0.0, 1.0]), "{normals:?}");
    }

    #[test]
    fn winding_sets_the_direction_and_every_normal_comes_out_unit() {
        // Triangle 0-1-2 wound clockwise seen from +z: its normal is -z.
        let positions = [
            [0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [5.0, 5.0, 5.0],
        ];
        let mut normals = [[0.0, 0.0, 1.0]; 4];
        normals_from_faces(&positions, &[0, 1, 2], &mut normals);
        assert_eq!(normals[0], [0.0, 0.0, -1.0]);
        assert_eq!(normals[3], [0.0, 0.0, 1.0], "unused vertex");
        // The same triangle both ways round: the sum cancels, the first face's normal is taken.
        let mut normals = [[0.0, 0.0, 0.0]; 4];
        normals_from_faces(&positions, &[0, 1, 2, 0, 2, 1], &mut normals);
        assert_eq!(normals[0], [0.0, 0.0, -1.0]);
        // No face with area: a unit normal is kept, a zero one becomes +z.
        let mut normals = [[0.0, 2.0, 0.0], [0.0; 3], [0.0; 3], [0.0; 3]];
        normals_from_faces(&positions, &[0, 0, 1], &mut normals);
        assert_eq!(normals[0], [0.0, 1.0, 0.0]);
        assert_eq!(normals[1], [0.0, 0.0, 1.0]);
        assert_eq!(normals[3], [0.0, 0.0, 1.0]);
    }

    #[test]
    fn a_vertex_shared_by_two_faces_takes_their_area_weighted_mean() {
        // A large face in z = 0 and a small one in x = 0 share vertices 0 and 1.
        let positions = [
            [0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [4.0, 0.0, 0.0],
            [0.0, 0.0, -0.25],
        ];
        let mut normals = [[0.0; 3]; 4];
        normals_from_faces(&positions, &[0, 2, 1, 0, 1, 3], &mut normals);
        let n = DVec3::from_array(normals[0].map(f64::from));
        // Areas 2 and 0.125: the mean leans 1/16 towards the small face's normal (-x).
        let want = DVec3::new(-0.125, 0.0, 2.0).normalize();
        assert!((n - want).length() < 1e-6, "{n} vs {want}");
        assert_eq!(normals[2], [0.0, 0.0, 1.0]);
    }
}
