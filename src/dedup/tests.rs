//! Unit tests of dedup on small synthetic scenes: rotated/translated baked copies, shuffled vertex
//! order, symmetric shapes, near misses, mirrors, materials, exact duplicates.

use super::*;
use crate::scene::{Component, ElementInfo, Material, Mesh, Primitive};
use glam::{DMat4, DQuat, DVec3};

/// A box [lo, hi] as 6 faces of 4 vertices (split at the edges, face normals), UVs per face.
fn push_box(p: &mut Primitive, lo: [f64; 3], hi: [f64; 3]) {
    let (lo, hi) = (DVec3::from_array(lo), DVec3::from_array(hi));
    for axis in 0..3 {
        for side in [false, true] {
            let mut n = DVec3::ZERO;
            n[axis] = if side { 1.0 } else { -1.0 };
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = p.positions.len() as u32;
            for (cu, cv) in [(0, 0), (1, 0), (1, 1), (0, 1)] {
                let mut x = DVec3::ZERO;
                x[axis] = if side { hi[axis] } else { lo[axis] };
                x[u] = if cu == 0 { lo[u] } else { hi[u] };
                x[v] = if cv == 0 { lo[v] } else { hi[v] };
                p.positions.push(x.as_vec3().to_array());
                p.normals
                    .get_or_insert_with(Vec::new)
                    .push(n.as_vec3().to_array());
                p.uvs
                    .get_or_insert_with(Vec::new)
                    .push([cu as f32 * 0.5, cv as f32 * 0.25 + axis as f32 * 0.1]);
            }
            // Outward winding: (u × v) = +axis, so the +side face is 0,1,2 and the −side reversed.
            if side {
                p.indices.extend([0, 1, 2, 0, 2, 3].map(|i| base + i));
            } else {
                p.indices.extend([0, 2, 1, 0, 3, 2].map(|i| base + i));
            }
        }
    }
}

fn prim(material: u32, boxes: &[([f64; 3], [f64; 3])]) -> Primitive {
    let mut p = Primitive {
        material: Some(MaterialId(material)),
        ..Default::default()
    };
    for (lo, hi) in boxes {
        push_box(&mut p, *lo, *hi);
    }
    p
}

/// A chair-like solid: no symmetry, distinct principal extents.
fn chair() -> Vec<Primitive> {
    vec![
        prim(
            0,
            &[
                ([0.0, 0.0, 0.0], [0.5, 0.45, 0.05]),
                ([0.0, 0.4, 0.05], [0.5, 0.45, 0.9]),
                ([0.0, 0.0, -0.45], [0.05, 0.05, 0.0]),
            ],
        ),
        prim(1, &[([0.45, 0.0, -0.45], [0.5, 0.05, 0.0])]),
    ]
}

fn cube() -> Vec<Primitive> {
    vec![prim(0, &[([-0.3, -0.3, -0.3], [0.3, 0.3, 0.3])])]
}

/// A 12-sided prism (cylinder) on the z axis, smooth sides, flat caps; no UVs.
fn cylinder() -> Vec<Primitive> {
    let mut p = Primitive {
        material: Some(MaterialId(0)),
        normals: Some(Vec::new()),
        ..Default::default()
    };
    let seg = 12;
    for i in 0..seg {
        let a = std::f64::consts::TAU * i as f64 / seg as f64;
        for z in [0.0, 3.0] {
            p.positions
                .push([(0.2 * a.cos()) as f32, (0.2 * a.sin()) as f32, z]);
            p.normals
                .as_mut()
                .unwrap()
                .push([a.cos() as f32, a.sin() as f32, 0.0]);
        }
    }
    for i in 0..seg {
        let j = (i + 1) % seg;
        let (a0, a1, b0, b1) = (2 * i, 2 * i + 1, 2 * j, 2 * j + 1);
        p.indices.extend([a0, b0, b1, a0, b1, a1]);
    }
    for (z, n) in [(0.0f32, -1.0f32), (3.0, 1.0)] {
        let base = p.positions.len() as u32;
        for i in 0..seg {
            let a = std::f64::consts::TAU * i as f64 / seg as f64;
            p.positions
                .push([(0.2 * a.cos()) as f32, (0.2 * a.sin()) as f32, z]);
            p.normals.as_mut().unwrap().push([0.0, 0.0, n]);
        }
        for i in 1..seg - 1 {
            if n > 0.0 {
                p.indices.extend([base, base + i, base + i + 1]);
            } else {
                p.indices.extend([base, base + i + 1, base + i]);
            }
        }
    }
    vec![p]
}

/// The primitives with `m` baked into positions and normals; a mirroring `m` reverses the
/// winding, as an exporter does to keep the faces outward.
fn bake(prims: &[Primitive], m: &DMat4) -> Vec<Primitive> {
    let nm = DMat3::from_mat4(*m).inverse().transpose();
    let flip = DMat3::from_mat4(*m).determinant() < 0.0;
    prims
        .iter()
        .map(|p| {
            let mut q = p.clone();
            for v in &mut q.positions {
                *v = m
                    .transform_point3(DVec3::from_array(v.map(f64::from)))
                    .as_vec3()
                    .to_array();
            }
            if let Some(ns) = &mut q.normals {
                for n in ns {
                    *n = (nm * DVec3::from_array(n.map(f64::from)))
                        .normalize()
                        .as_vec3()
                        .to_array();
                }
            }
            if flip {
                for t in q.indices.chunks_exact_mut(3) {
                    t.swap(1, 2);
                }
            }
            q
        })
        .collect()
}

/// Same triangles, other vertex order, triangle order and first corners (deterministic).
fn shuffle(prims: &[Primitive], seed: u64) -> Vec<Primitive> {
    let mut state = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut next = move |n: usize| {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) as usize) % n
    };
    prims
        .iter()
        .map(|p| {
            let n = p.positions.len();
            let mut perm: Vec<usize> = (0..n).collect();
            for i in (1..n).rev() {
                perm.swap(i, next(i + 1));
            }
            // new vertex k = old vertex perm[k]
            let mut inv = vec![0u32; n];
            for (k, &o) in perm.iter().enumerate() {
                inv[o] = k as u32;
            }
            let mut tris: Vec<[u32; 3]> = p
                .indices
                .chunks_exact(3)
                .map(|t| {
                    let t = [inv[t[0] as usize], inv[t[1] as usize], inv[t[2] as usize]];
                    let r = next(3);
                    [t[r], t[(r + 1) % 3], t[(r + 2) % 3]]
                })
                .collect();
            for i in (1..tris.len()).rev() {
                tris.swap(i, next(i + 1));
            }
            Primitive {
                material: p.material,
                positions: perm.iter().map(|&o| p.positions[o]).collect(),
                normals: p
                    .normals
                    .as_ref()
                    .map(|a| perm.iter().map(|&o| a[o]).collect()),
                uvs: p.uvs.as_ref().map(|a| perm.iter().map(|&o| a[o]).collect()),
                colors: p
                    .colors
                    .as_ref()
                    .map(|a| perm.iter().map(|&o| a[o]).collect()),
                indices: tris.into_iter().flatten().collect(),
            }
        })
        .collect()
}

fn motion(axis: [f64; 3], angle_deg: f64, t: [f64; 3]) -> DMat4 {
    DMat4::from_rotation_translation(
        DQuat::from_axis_angle(DVec3::from_array(axis).normalize(), angle_deg.to_radians()),
        DVec3::from_array(t),
    )
}

/// A scene of one component per (primitives, world) pair, each with its own mesh.
fn scene(parts: Vec<(Vec<Primitive>, DMat4)>) -> Scene {
    let mut s = Scene::default();
    for i in 0..3 {
        s.materials.push(Material {
            base_color: [i as f32 * 0.3, 0.5, 0.5, 1.0],
            ..Default::default()
        });
    }
    for (i, (prims, world)) in parts.into_iter().enumerate() {
        let mesh = MeshId(s.meshes.len() as u32);
        s.meshes.push(Mesh {
            name: None,
            primitives: prims,
            local_bounds: None,
        });
        s.push_component(
            Component::new(mesh, world),
            &ElementInfo::keyed(format!("c{i}")),
        );
    }
    s.finish();
    s
}

/// The drawn triangles of a component in the scene frame, corners in drawn order (winding
/// flipped for mirroring worlds), each corner with its unit normal and UV.
type Corner = (DVec3, Option<DVec3>, Option<[f32; 2]>);
fn world_triangles(s: &Scene, c: &Component) -> Vec<Vec<[Corner; 3]>> {
    let nm = c.normal_matrix();
    let flip = c.mirrors();
    s.mesh(c.mesh)
        .primitives
        .iter()
        .map(|p| {
            p.indices
                .chunks_exact(3)
                .map(|t| {
                    let order = if flip { [0, 2, 1] } else { [0, 1, 2] };
                    order.map(|k| {
                        let i = t[k] as usize;
                        (
                            c.world
                                .transform_point3(DVec3::from_array(p.positions[i].map(f64::from))),
                            p.normals
                                .as_ref()
                                .map(|n| (nm * DVec3::from_array(n[i].map(f64::from))).normalize()),
                            p.uvs.as_ref().map(|u| u[i]),
                        )
                    })
                })
                .collect()
        })
        .collect()
}

/// Every component of `after` (aliases too, with their own geometry) draws the same oriented
/// triangles as in `before`, corner by corner within `tol` (brute force: small scenes only).
fn assert_expands_to(before: &Scene, after: &Scene, tol: f64) {
    assert_eq!(before.components.len(), after.components.len());
    for (b, a) in before.components.iter().zip(&after.components) {
        let key = before.element(b.id).key;
        assert_eq!((b.id, &key), (a.id, &after.element(a.id).key));
        let tb = world_triangles(before, b);
        let ta = world_triangles(after, a);
        assert_eq!(tb.len(), ta.len(), "{key}: primitive count");
        for (pb, pa) in tb.iter().zip(&ta) {
            assert_eq!(pb.len(), pa.len());
            let mut used = vec![false; pb.len()];
            for t in pa {
                let corner_eq = |x: &Corner, y: &Corner| {
                    x.0.distance(y.0) <= tol
                        && match (x.1, y.1) {
                            (Some(m), Some(n)) => m.dot(n) > 0.999,
                            (None, None) => true,
                            _ => false,
                        }
                        && match (x.2, y.2) {
                            (Some(m), Some(n)) => {
                                (m[0] - n[0]).abs() < 1e-4 && (m[1] - n[1]).abs() < 1e-4
                            }
                            (None, None) => true,
                            _ => false,
                        }
                };
                let hit = (0..pb.len()).find(|&j| {
                    !used[j]
                        && (0..3).any(|r| (0..3).all(|k| corner_eq(&t[k], &pb[j][(k + r) % 3])))
                });
                let j = hit.unwrap_or_else(|| panic!("{key}: triangle {t:?} not in the input"));
                used[j] = true;
            }
        }
    }
}

fn run(parts: Vec<(Vec<Primitive>, DMat4)>, opts: &DedupOptions) -> (Scene, Scene, DedupReport) {
    let before = scene(parts);
    let mut after = before.clone();
    let r = deduplicate(&mut after, opts);
    assert_expands_to(&before, &after, opts.tolerance_m);
    (before, after, r)
}

fn meshes(s: &Scene) -> Vec<u32> {
    s.components.iter().map(|c| c.mesh.0).collect()
}

#[test]
fn baked_rotated_and_translated_copies_share_one_mesh() {
    let base = chair();
    let parts = vec![
        (base.clone(), DMat4::IDENTITY),
        (
            bake(&base, &motion([0.0, 0.0, 1.0], 90.0, [5.0, 0.0, 0.0])),
            DMat4::IDENTITY,
        ),
        (
            bake(&base, &motion([1.0, 2.0, 3.0], 137.0, [-3.0, 8.0, 1.0])),
            DMat4::IDENTITY,
        ),
        // Baked 2 km away: f32 still resolves 0.1 mm there.
        (
            bake(&base, &motion([0.0, 0.0, 1.0], 180.0, [0.0, 2e3, 0.0])),
            DMat4::IDENTITY,
        ),
    ];
    let (_, after, r) = run(parts, &DedupOptions::default());
    assert_eq!(meshes(&after), vec![0, 0, 0, 0]);
    assert_eq!(r.congruent_rewritten, 3);
    assert_eq!(r.matched_same_order, 3);
    assert_eq!(r.unique_shapes, 1);
    assert_eq!(r.instanced_components, 4);
    assert_eq!(r.redundant_removed, 0);
    assert_eq!(r.meshes_released, 3);
    assert!(after.mesh(MeshId(1)).primitives.is_empty());
    assert!(r.bytes_after < r.bytes_before / 3);
    assert_eq!(r.triangles_after, r.triangles_before);
    assert_eq!(r.triangles_stored_after * 4, r.triangles_stored_before);
}

#[test]
fn shuffled_vertex_order_is_found_by_the_frame_search() {
    let base = chair();
    let parts = vec![
        (base.clone(), DMat4::IDENTITY),
        (
            shuffle(
                &bake(&base, &motion([0.3, -1.0, 0.2], 71.0, [2.0, 3.0, 4.0])),
                7,
            ),
            DMat4::IDENTITY,
        ),
        // Rigid motion in the world matrix instead of baked (a glTF node transform).
        (
            shuffle(&base, 9),
            motion([0.0, 1.0, 0.0], -33.0, [0.0, 0.0, 10.0]),
        ),
    ];
    let (_, after, r) = run(parts, &DedupOptions::default());
    assert_eq!(meshes(&after), vec![0, 0, 0]);
    assert_eq!(r.matched_by_search, 2);
}

/// `prims` with every vertex moved by up to `amplitude` along each axis (deterministic).
fn jitter(prims: &[Primitive], amplitude: f64, seed: u64) -> Vec<Primitive> {
    let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut out = prims.to_vec();
    for p in &mut out {
        for v in &mut p.positions {
            for x in v.iter_mut() {
                *x += (amplitude * next()) as f32;
            }
        }
    }
    out
}

#[test]
fn a_copy_is_found_among_many_near_twins() {
    // Noisy copies (every vertex up to 2 mm off: near-twins, no match) come first and become
    // prototypes; the true copy, shuffled so that only the frame search can find it, must still
    // find the exact prototype behind them: candidates go nearest first, and the search is
    // bounded to the first few.
    let base = chair();
    let noisy = 12;
    let mut parts: Vec<(Vec<Primitive>, DMat4)> = (0..noisy)
        .map(|i| (jitter(&base, 0.002, i as u64 + 1), DMat4::IDENTITY))
        .collect();
    parts.push((base.clone(), DMat4::IDENTITY));
    parts.push((
        shuffle(
            &bake(&base, &motion([0.0, 0.0, 1.0], 40.0, [9.0, 0.0, 0.0])),
            5,
        ),
        DMat4::IDENTITY,
    ));
    let tol = Tol {
        pos: 0.001,
        cos_normal: 2f64.to_radians().cos(),
        allow_scale: false,
    };
    // The noisy copies are candidates of the true one (else this tests nothing).
    let s = scene(parts.clone());
    let inv = |i: usize| {
        let c = &s.components[i];
        matcher::Invariants::of(&Shape::new(s.mesh(c.mesh), &c.world)).unwrap()
    };
    let last = inv(noisy + 1);
    let compatible = (0..noisy)
        .filter(|&i| last.key().mismatch(&inv(i).key(), &tol) <= 1.0)
        .count();
    assert!(
        compatible > SEARCH_TRIES,
        "{compatible} compatible near-twins"
    );
    let (_, after, r) = run(parts, &DedupOptions::default());
    let mut want: Vec<u32> = (0..=noisy as u32).collect();
    want.push(noisy as u32);
    assert_eq!(meshes(&after), want);
    assert_eq!(r.matched_by_search, 1);
    assert_eq!(r.congruent_rewritten, 1);
    // The later noisy copies and the exact one (same vertex order as the first noisy prototype,
    // every vertex a few mm off) are reported as near-twins.
    assert_eq!(r.near_twins, noisy);
}

#[test]
fn prototype_shapes_rebuilt_on_use_match_the_same() {
    // Under a small memory budget a bucket keeps no prototype shape and rebuilds each one it
    // compares with: the matches (prototype, motion, kind) must be the same, bit for bit.
    let base = chair();
    let mut parts: Vec<(Vec<Primitive>, DMat4)> = (0..6)
        .map(|i| (jitter(&base, 0.002, i as u64 + 1), DMat4::IDENTITY))
        .collect();
    parts.push((base.clone(), motion([0.0, 0.0, 1.0], 30.0, [4.0, 0.0, 0.0])));
    parts.push((base.clone(), motion([0.0, 0.0, 1.0], 75.0, [6.0, 0.0, 0.0])));
    parts.push((
        shuffle(
            &bake(&base, &motion([0.0, 0.0, 1.0], 40.0, [9.0, 0.0, 0.0])),
            5,
        ),
        DMat4::IDENTITY,
    ));
    let s = scene(parts);
    let bucket: Vec<(MeshId, ComponentId)> = s.components.iter().map(|c| (c.mesh, c.id)).collect();
    let tol = Tol {
        pos: 0.001,
        cos_normal: 2f64.to_radians().cos(),
        allow_scale: false,
    };
    let key = |(found, twins): (Vec<Found>, usize)| {
        let f: Vec<_> = found
            .iter()
            .map(|f| {
                let m = f.motion.to_mat4().to_cols_array().map(f64::to_bits);
                (
                    f.mesh,
                    f.rep,
                    f.proto_rep,
                    m,
                    f.kind == MatchKind::SameOrder,
                )
            })
            .collect();
        (f, twins)
    };
    let kept = key(cluster(&s, &bucket, &tol, usize::MAX));
    let rebuilt = key(cluster(&s, &bucket, &tol, 0));
    assert_eq!(kept.0.len(), 2, "the later true copies match the first");
    assert!(kept.0.iter().any(|f| f.4), "one in the same order");
    assert!(kept.0.iter().any(|f| !f.4), "one by the frame search");
    assert_eq!(kept, rebuilt);
}

#[test]
fn symmetric_shapes_cube_and_cylinder() {
    for (name, base) in [("cube", cube()), ("cylinder", cylinder())] {
        let parts = vec![
            (base.clone(), DMat4::IDENTITY),
            // Same order, any rotation: the direct fit has no ambiguity.
            (
                bake(&base, &motion([0.0, 0.0, 1.0], 90.0, [3.0, 0.0, 0.0])),
                DMat4::IDENTITY,
            ),
            // Shuffled: principal axes are undefined (cube: all equal; cylinder: two equal),
            // so the motion must come from the vertex-feature candidates; the cube's UVs and
            // the cylinder's normals only allow the right one.
            (
                shuffle(
                    &bake(&base, &motion([1.0, 1.0, 0.0], 90.0, [0.0, 5.0, 0.0])),
                    3,
                ),
                DMat4::IDENTITY,
            ),
            (
                shuffle(
                    &bake(&base, &motion([0.2, 0.1, 1.0], 15.0, [7.0, 7.0, 1.0])),
                    4,
                ),
                DMat4::IDENTITY,
            ),
        ];
        let (_, after, r) = run(parts, &DedupOptions::default());
        assert_eq!(meshes(&after), vec![0, 0, 0, 0], "{name}");
        assert_eq!(r.matched_by_search, 2, "{name}");
    }
}

#[test]
fn near_misses_do_not_match() {
    let base = chair();
    // One vertex moved by 3 mm (three times the tolerance); the others exact.
    let mut bumped = bake(&base, &motion([0.0, 0.0, 1.0], 90.0, [5.0, 0.0, 0.0]));
    bumped[0].positions[5][2] += 0.003;
    // The back 2.5 mm taller: the best rigid fit splits the difference, still 1.25 mm off.
    // (2 mm taller would be a match: shifted by 1 mm, every vertex lands within 1 mm.)
    let mut longer = chair();
    for p in &mut longer {
        for v in &mut p.positions {
            if v[2] > 0.5 {
                v[2] += 0.0025;
            }
        }
    }
    // Scaled by 1 %: a different product unless scale is allowed.
    let scaled = bake(
        &base,
        &(motion([0.0, 0.0, 1.0], 30.0, [9.0, 0.0, 0.0]) * DMat4::from_scale(DVec3::splat(1.01))),
    );
    // Within tolerance: moved by 0.4 mm.
    let mut close = bake(&base, &motion([0.0, 0.0, 1.0], 90.0, [5.0, 5.0, 0.0]));
    close[0].positions[5][0] += 0.0004;
    let parts = vec![
        (base.clone(), DMat4::IDENTITY),
        (bumped, DMat4::IDENTITY),
        (
            shuffle(&longer, 2),
            motion([1.0, 0.0, 0.0], 45.0, [0.0, 0.0, 3.0]),
        ),
        (scaled.clone(), DMat4::IDENTITY),
        (close, DMat4::IDENTITY),
    ];
    let (_, after, r) = run(parts.clone(), &DedupOptions::default());
    assert_eq!(meshes(&after), vec![0, 1, 2, 3, 0]);
    assert_eq!(r.congruent_rewritten, 1);
    let (_, after, _) = run(
        parts,
        &DedupOptions {
            allow_uniform_scale: true,
            ..Default::default()
        },
    );
    // The bumped vertex still does not fit; the 1 % copy now does. (The 2.5 mm taller back may
    // too: scaled by ~1.0019 it lands within 1 mm everywhere, which the expansion check above
    // confirms whichever way it goes.)
    let m = meshes(&after);
    assert_eq!((m[0], m[1], m[3], m[4]), (0, 1, 0, 0));
    let s = after.components[3].world;
    assert!((DMat3::from_mat4(s).determinant().cbrt() - 1.01).abs() < 1e-6);
}

#[test]
fn mirrored_copies_match_only_mirrored_prototypes() {
    let base = chair();
    let mirror = DMat4::from_scale(DVec3::new(-1.0, 1.0, 1.0));
    let parts = vec![
        (base.clone(), DMat4::IDENTITY),
        // A baked mirror image (winding reversed to stay outward): a left-hand chair.
        (
            bake(
                &base,
                &(motion([0.0, 0.0, 1.0], 90.0, [5.0, 0.0, 0.0]) * mirror),
            ),
            DMat4::IDENTITY,
        ),
        // The original mesh drawn through a mirroring node transform: also a left-hand chair,
        // congruent to the previous one but not to the first.
        (
            base.clone(),
            motion([0.0, 0.0, 1.0], -20.0, [0.0, 9.0, 0.0]) * mirror,
        ),
        // Another baked left-hand chair, vertex order shuffled.
        (
            shuffle(
                &bake(
                    &base,
                    &(motion([0.0, 1.0, 0.0], 60.0, [3.0, 3.0, 3.0]) * mirror),
                ),
                5,
            ),
            DMat4::IDENTITY,
        ),
    ];
    let (_, after, r) = run(parts, &DedupOptions::default());
    let m = meshes(&after);
    assert_eq!(m[0], 0);
    assert!(m[1] != 0 && m[1] == m[2] && m[2] == m[3], "{m:?}");
    assert_eq!(r.unique_shapes, 2);
}

#[test]
fn flat_mirror_is_a_different_face() {
    // A single quad with no normals: mirroring across its plane leaves every vertex in place
    // but turns the drawn face around.
    let quad = Primitive {
        material: None,
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 2.0, 0.0],
            [0.0, 2.0, 0.0],
        ],
        indices: vec![0, 1, 2, 0, 2, 3],
        ..Default::default()
    };
    let flip_z = DMat4::from_scale(DVec3::new(1.0, 1.0, -1.0));
    let parts = vec![
        (vec![quad.clone()], DMat4::IDENTITY),
        (vec![quad.clone()], flip_z),
        (
            vec![quad.clone()],
            motion([0.0, 0.0, 1.0], 90.0, [4.0, 0.0, 0.0]),
        ),
    ];
    let (_, after, r) = run(parts, &DedupOptions::default());
    assert_eq!(r.redundant_removed, 0);
    assert_eq!(meshes(&after), vec![0, 1, 0]);
}

#[test]
fn materials_must_match() {
    let base = chair();
    let mut other = bake(&base, &motion([0.0, 0.0, 1.0], 90.0, [5.0, 0.0, 0.0]));
    other[1].material = Some(MaterialId(2));
    // Material 3 renders exactly like material 0: that is not a different shape.
    let mut same_look = bake(&base, &motion([0.0, 0.0, 1.0], 180.0, [5.0, 5.0, 0.0]));
    same_look[0].material = Some(MaterialId(3));
    let mut s = scene(vec![
        (base.clone(), DMat4::IDENTITY),
        (other, DMat4::IDENTITY),
        (same_look, DMat4::IDENTITY),
    ]);
    s.materials.push(s.materials[0].clone());
    let before = s.clone();
    let r = deduplicate(&mut s, &DedupOptions::default());
    assert_expands_to(&before, &s, 0.001);
    assert_eq!(meshes(&s), vec![0, 1, 0]);
    assert_eq!(r.unique_shapes, 2);
}

#[test]
fn exact_duplicates_become_aliases_of_the_lowest_id() {
    let base = chair();
    let at = motion([0.0, 0.0, 1.0], 90.0, [5.0, 0.0, 0.0]);
    let parts = vec![
        (bake(&base, &at), DMat4::IDENTITY),
        // Same place, other vertex order.
        (shuffle(&bake(&base, &at), 11), DMat4::IDENTITY),
        // Same place through a node transform, 0.4 mm off.
        (
            base.clone(),
            DMat4::from_translation(DVec3::new(0.0004, 0.0, 0.0)) * at,
        ),
        // 3 mm off: not redundant, but congruent.
        (
            bake(&base, &at),
            DMat4::from_translation(DVec3::new(0.0, 0.003, 0.0)),
        ),
        // A second copy elsewhere, and its duplicate.
        (
            bake(&base, &motion([0.0, 0.0, 1.0], 0.0, [0.0, 20.0, 0.0])),
            DMat4::IDENTITY,
        ),
        (
            bake(&base, &motion([0.0, 0.0, 1.0], 0.0, [0.0, 20.0, 0.0])),
            DMat4::IDENTITY,
        ),
    ];
    let (before, after, r) = run(parts, &DedupOptions::default());
    let aliases: Vec<Option<u32>> = after
        .components
        .iter()
        .map(|c| c.alias_of.map(|a| a.0))
        .collect();
    assert_eq!(aliases, vec![None, Some(0), Some(0), None, None, Some(4)]);
    assert_eq!(r.redundant_removed, 3);
    // Aliases keep their own geometry (and so their meshes); drawn components share one mesh.
    for i in [1, 2, 5] {
        assert_eq!(after.components[i].mesh, before.components[i].mesh);
        assert_eq!(after.components[i].world, before.components[i].world);
    }
    assert_eq!(after.components[3].mesh, MeshId(0));
    assert_eq!(after.components[4].mesh, MeshId(0));
    assert_eq!(r.unique_shapes, 1);
    assert_eq!(r.triangles_after * 2, r.triangles_before);
    let groups = shape_groups(&after);
    assert_eq!(
        groups,
        vec![ShapeGroup {
            mesh: MeshId(0),
            components: vec![ComponentId(0), ComponentId(3), ComponentId(4)]
        }]
    );
    // Exact only: no congruence rewrite.
    let mut s = before.clone();
    let r = deduplicate(
        &mut s,
        &DedupOptions {
            congruent: false,
            ..Default::default()
        },
    );
    assert_eq!(r.redundant_removed, 3);
    assert_eq!(r.congruent_rewritten, 0);
    assert_eq!(meshes(&s), meshes(&before));
}

#[test]
fn gltf_reuse_is_kept_and_joined() {
    // Mesh 0 used by two nodes (glTF reuse), mesh 1 a baked copy of the same shape, mesh 2 used
    // by two nodes and congruent to mesh 0 as well: everything ends on mesh 0.
    let base = chair();
    let mut s = scene(vec![
        (base.clone(), DMat4::IDENTITY),
        (
            bake(&base, &motion([0.0, 0.0, 1.0], 45.0, [4.0, 0.0, 0.0])),
            DMat4::IDENTITY,
        ),
        (
            shuffle(
                &bake(&base, &motion([0.0, 1.0, 0.0], 45.0, [0.0, 0.0, 0.0])),
                1,
            ),
            DMat4::from_translation(DVec3::new(0.0, 0.0, 7.0)),
        ),
    ]);
    for (mesh, w) in [
        (0, motion([0.0, 0.0, 1.0], 10.0, [10.0, 0.0, 0.0])),
        (2, motion([1.0, 0.0, 0.0], 90.0, [10.0, 10.0, 0.0])),
    ] {
        s.push_component(
            Component::new(MeshId(mesh), w),
            &ElementInfo::keyed(format!("r{mesh}")),
        );
    }
    s.finish();
    let before = s.clone();
    let r = deduplicate(&mut s, &DedupOptions::default());
    assert_expands_to(&before, &s, 0.001);
    assert_eq!(meshes(&s), vec![0, 0, 0, 0, 0]);
    assert_eq!(r.instanced_components_before, 4);
    assert_eq!(r.instanced_components, 5);
    assert_eq!(r.unique_shapes_before, 3);
    assert_eq!(r.unique_shapes, 1);
    assert_eq!(r.congruent_rewritten, 3);
}

#[test]
fn deterministic_and_idempotent() {
    let base = chair();
    let parts: Vec<(Vec<Primitive>, DMat4)> = (0..40)
        .map(|i| {
            let m = motion([0.0, 0.0, 1.0], i as f64 * 37.0, [i as f64 * 3.0, 0.0, 0.0]);
            let p = if i % 3 == 0 {
                shuffle(&bake(&base, &m), i)
            } else {
                bake(&base, &m)
            };
            let p = if i % 5 == 0 { bake(&cube(), &m) } else { p };
            (p, DMat4::IDENTITY)
        })
        .collect();
    let (_, a, ra) = run(parts.clone(), &DedupOptions::default());
    let (_, b, rb) = run(parts, &DedupOptions::default());
    assert_eq!(meshes(&a), meshes(&b));
    let wa: Vec<DMat4> = a.components.iter().map(|c| c.world).collect();
    let wb: Vec<DMat4> = b.components.iter().map(|c| c.world).collect();
    assert_eq!(wa, wb);
    assert_eq!(
        (ra.unique_shapes, ra.congruent_rewritten),
        (rb.unique_shapes, rb.congruent_rewritten)
    );
    assert_eq!(ra.unique_shapes, 2);
    // A second pass finds nothing more.
    let mut again = a.clone();
    let r2 = deduplicate(&mut again, &DedupOptions::default());
    assert_eq!(r2.congruent_rewritten, 0);
    assert_eq!(r2.redundant_removed, 0);
    assert_eq!(meshes(&again), meshes(&a));
}

#[test]
fn empty_meshes_and_bad_transforms_do_not_panic() {
    let mut s = scene(vec![
        (Vec::new(), DMat4::IDENTITY),
        (chair(), DMat4::from_scale(DVec3::ZERO)),
        (chair(), DMat4::IDENTITY),
        (chair(), DMat4::from_scale(DVec3::new(1.0, 0.0, 1.0))),
    ]);
    s.components[1].world = DMat4::from_cols_array(&[f64::NAN; 16]);
    let r = deduplicate(&mut s, &DedupOptions::default());
    assert_eq!(r.components, 4);
}
