//! Speed of `bimtiles::simplify` vs meshoptimizer (`harness = false`):
//! `cargo bench --bench simplify`. Uses ISSUE_021_Mini_Project.glb from
//! /work/shared/data when present and a ~1M-triangle synthetic grid.

use std::time::Instant;

use bimtiles::simplify::{simplify, MeshInput, SimplifyOptions};

fn grid(n: usize) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut p = Vec::new();
    for y in 0..=n {
        for x in 0..=n {
            let (fx, fy) = (x as f32 / n as f32, y as f32 / n as f32);
            p.push([
                fx * 100.0,
                fy * 100.0,
                2.0 * (fx * 13.0).sin() * (fy * 11.0).cos(),
            ]);
        }
    }
    let w = n as u32 + 1;
    let mut idx = Vec::new();
    for y in 0..n as u32 {
        for x in 0..n as u32 {
            let i = y * w + x;
            idx.extend([i, i + 1, i + w + 1, i, i + w + 1, i + w]);
        }
    }
    (p, idx)
}

fn load(path: &str) -> Option<(Vec<[f32; 3]>, Vec<u32>)> {
    let bytes = std::fs::read(path).ok()?;
    let g = gltf::Gltf::from_slice_without_validation(&bytes).ok()?;
    let blob = g.blob.as_deref();
    let (mut p, mut idx) = (Vec::new(), Vec::new());
    // World transforms do not matter for speed: positions are taken as stored.
    for mesh in g.meshes() {
        for prim in mesh.primitives() {
            let r = prim.reader(|_| blob);
            let Some(pos) = r.read_positions() else {
                continue;
            };
            let base = p.len() as u32;
            let pos: Vec<[f32; 3]> = pos.collect();
            let i: Vec<u32> = r
                .read_indices()
                .map(|i| i.into_u32().collect())
                .unwrap_or_else(|| (0..pos.len() as u32).collect());
            p.extend(pos);
            idx.extend(i.iter().map(|i| i + base));
        }
    }
    Some((p, idx))
}

fn bench(name: &str, p: &[[f32; 3]], idx: &[u32]) {
    let tris = idx.len() / 3;
    let m = MeshInput {
        positions: p,
        indices: idx,
        ..Default::default()
    };
    let bytes: Vec<u8> = p
        .iter()
        .flat_map(|v| v.iter().flat_map(|x| x.to_le_bytes()))
        .collect();
    let ad = meshopt::VertexDataAdapter::new(&bytes, 12, 0).unwrap();
    for ratio in [0.5f32, 0.1] {
        let o = SimplifyOptions {
            target_ratio: ratio,
            compute_error_bound: false,
            ..Default::default()
        };
        let t = Instant::now();
        let r = simplify(&m, &o).unwrap();
        let ours = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mo = meshopt::simplify(
            idx,
            &ad,
            r.indices.len(),
            1.0,
            meshopt::SimplifyOptions::Permissive,
            None,
        );
        let theirs = t.elapsed().as_secs_f64();
        println!(
            "{name:<28} {:>4.0}% {:>9} -> {:>8} | ours {:>6.3} s ({:>5.2} Mtri/s) | meshopt {:>6.3} s ({:>5.2} Mtri/s, {} tris) | ratio {:.2}x",
            ratio * 100.0,
            tris,
            r.triangle_count(),
            ours,
            tris as f64 / ours / 1e6,
            theirs,
            tris as f64 / theirs / 1e6,
            mo.len() / 3,
            ours / theirs
        );
    }
}

fn main() {
    if let Some((p, i)) = load("/work/shared/data/ISSUE_021_Mini_Project.glb") {
        bench("ISSUE_021_Mini_Project", &p, &i);
    } else {
        println!("ISSUE_021_Mini_Project.glb not found, skipped");
    }
    let (p, i) = grid(708);
    bench("grid-1M", &p, &i);
}
