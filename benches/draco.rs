//! Draco throughput and compression ratio per encoder speed, on a height field and on every
//! `.glb` of the shared data (the figures behind the README's Compression section):
//! `cargo bench --bench draco`.

#[path = "../tests/support/glb.rs"]
#[allow(dead_code)]
mod glb;
#[path = "../tests/support/height_field.rs"]
mod height_field;

use bimtiles::encode::draco::{
    decode_mesh, encode_mesh, encode_mesh_fast, EncodeAttribute, EncodeOptions, EncodingMethod,
};

/// Loads every mesh primitive of a GLB, merged into one mesh (node transforms ignored,
/// which is right for these files: world coordinates are baked in). Missing normals
/// or uvs are filled with constants when another primitive has them. Returns
/// (positions, normals, uvs or empty, per-vertex node id, indices).
#[allow(clippy::type_complexity)]
fn load_glb(bytes: &[u8]) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<u16>, Vec<u32>) {
    let g = gltf::Gltf::from_slice_without_validation(bytes).unwrap();
    let blob = g.blob.as_deref();
    let (mut pos, mut nrm, mut uv, mut fid, mut idx) = (vec![], vec![], vec![], vec![], vec![]);
    let mut any_uv = false;
    for (mi, mesh) in g.meshes().enumerate() {
        for prim in mesh.primitives() {
            let r = prim.reader(|_| blob);
            let Some(p) = r.read_positions() else {
                continue;
            };
            let base = (pos.len() / 3) as u32;
            let p: Vec<[f32; 3]> = p.collect();
            let n = p.len();
            pos.extend(p.iter().flatten());
            match r.read_normals() {
                Some(ns) => nrm.extend(ns.flatten()),
                None => nrm.extend(std::iter::repeat_n([0.0f32, 0.0, 1.0], n).flatten()),
            }
            match r.read_tex_coords(0) {
                Some(t) => {
                    any_uv = true;
                    uv.extend(t.into_f32().flatten())
                }
                None => uv.extend(std::iter::repeat_n(0.0f32, 2 * n)),
            }
            fid.extend(std::iter::repeat_n((mi % 65536) as u16, n));
            match r.read_indices() {
                Some(i) => idx.extend(i.into_u32().map(|v| v + base)),
                None => idx.extend(base..base + n as u32),
            }
        }
    }
    if !any_uv {
        uv.clear();
    }
    (pos, nrm, uv, fid, idx)
}

/// The throughput and ratio table (`BIMTILES_SHARED`: the folder holding `data/`, default
/// `../shared`).
fn main() {
    use std::time::Instant;
    let data_dir = std::env::var_os("BIMTILES_SHARED")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"))
        .join("data");
    type Model = (String, Vec<f32>, Vec<f32>, Vec<f32>, Vec<u16>, Vec<u32>);
    let mut models: Vec<Model> = vec![];
    let (p, n, u, i, x) = load_glb(&height_field::height_field_glb(708, 2000.0));
    models.push(("height field 708x708".into(), p, n, u, i, x));
    let mut files: Vec<_> = std::fs::read_dir(&data_dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| p.extension().is_some_and(|e| e == "glb"));
    files.sort();
    for f in files {
        let (p, n, u, i, x) = load_glb(&std::fs::read(&f).unwrap());
        models.push((
            f.file_stem().unwrap().to_string_lossy().into(),
            p,
            n,
            u,
            i,
            x,
        ));
    }
    println!("| model | tris | verts in->out | speed | encode s | Mtri/s | decode s | encode_mesh s | bytes | ratio | B/tri | +fid bytes |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, pos, nrm, uv, fid, idx) in &models {
        let tris = idx.len() / 3;
        let mut a = vec![
            EncodeAttribute::position(pos, 14),
            EncodeAttribute::normal(nrm, 10),
        ];
        if !uv.is_empty() {
            a.push(EncodeAttribute::tex_coord(uv, 12));
        }
        let raw = (pos.len() + nrm.len() + uv.len() + idx.len()) * 4;
        for speed in [0u8, 5, 7, 10] {
            let opts = EncodeOptions {
                encode_speed: speed,
                decode_speed: speed,
                method: EncodingMethod::Edgebreaker,
            };
            let reps = if tris < 100_000 { 5 } else { 1 };
            let t = Instant::now();
            let mut r = None;
            for _ in 0..reps {
                r = Some(encode_mesh_fast(&a, idx, &opts).unwrap());
            }
            let enc_s = t.elapsed().as_secs_f64() / reps as f64;
            let r = r.unwrap();
            let t = Instant::now();
            for _ in 0..reps {
                decode_mesh(&r.bytes).unwrap();
            }
            let dec_s = t.elapsed().as_secs_f64() / reps as f64;
            let t = Instant::now();
            let full = encode_mesh(&a, idx, &opts).unwrap();
            let full_s = t.elapsed().as_secs_f64();
            assert_eq!(full.bytes, r.bytes);
            let mut af = a.clone();
            af.push(EncodeAttribute::feature_id_u16(fid));
            let with_fid = encode_mesh_fast(&af, idx, &opts).unwrap().bytes.len();
            println!(
                "| {name} | {tris} | {}->{} | {speed} | {enc_s:.3} | {:.2} | {dec_s:.3} | {full_s:.3} | {} | {:.4} ({:.1}x) | {:.2} | {with_fid} |",
                pos.len() / 3,
                r.point_count,
                tris as f64 / enc_s / 1e6,
                r.bytes.len(),
                r.bytes.len() as f64 / raw as f64,
                raw as f64 / r.bytes.len() as f64,
                r.bytes.len() as f64 / tris as f64,
            );
        }
    }
}
