//! `make bench`, texture section (paper Tables II and V, III.D–III.F):
//!
//! - Table II equivalent: resolution and bytes of each Haar pyramid level of the largest texture
//!   of the textured models (raw RGBA, PNG, JPEG q85), with the PSNR of each level against the
//!   `image` crate's own area downsample of the original (they must agree: a bug shows as a low
//!   PSNR).
//! - Table V equivalent: per textured model, the original texture MB, after identical images are
//!   merged and unused areas cropped, and the MB of pyramid levels 1-4 (default encoding).
//! - First view: texture bytes of the tiles a client selects for a whole-model view (SSE 16 px,
//!   1920x1080, 60° fov) against the original textures: shared texture files (the default, each
//!   file counted once), textures embedded in every tile (`--embed-textures`), and texture LOD off;
//!   with the requests (tiles plus distinct texture files).
//!
//! Usage: cargo run --release --example bench_textures -- [DATA_DIR [MAX_TILE_TRIANGLES]]
//! (the tile budget of the first-view conversions; default 3000, as `tests/textures.rs`: at the
//! tool's default budget these small models fit one tile and a first view loads everything).

use bimtiles::texture::{self, external, haar, view, TextureFormat, TextureOptions};
use std::path::{Path, PathBuf};
use std::process::Command;

fn mb(b: u64) -> f64 {
    b as f64 / 1e6
}

fn convert(bin: &Path, input: &Path, out: &Path, extra: &[&str]) -> bool {
    Command::new(bin)
        .arg("convert")
        .arg(input)
        .arg("--out")
        .arg(out)
        .args(["--force", "--quiet"])
        .args(extra)
        .status()
        .is_ok_and(|s| s.success())
}

fn main() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let data = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| repo.join("../shared/data"));
    let budget = std::env::args().nth(2).unwrap_or_else(|| "3000".into());
    let bin = repo.join("target/release/bimtiles");
    let work = repo.join("target/bench");
    std::fs::create_dir_all(&work).unwrap();
    let mut inputs = vec![repo.join("samples/sample_building.glb")];
    if let Ok(rd) = std::fs::read_dir(&data) {
        let mut glbs: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "glb"))
            .collect();
        glbs.sort();
        inputs.extend(glbs);
    } else {
        eprintln!("{} not found: the bundled sample only", data.display());
    }
    // Textured models, read once.
    let mut scenes = Vec::new();
    for input in &inputs {
        let Ok(scene) = bimtiles::ingest::read_input(input) else {
            eprintln!("cannot read {}", input.display());
            continue;
        };
        if !texture::classify::bound_images(&scene).is_empty() {
            scenes.push((input.clone(), scene));
        }
    }

    // Table II: the largest texture (by texels).
    let mut largest: Option<(String, bimtiles::scene::Image, u64)> = None;
    for (input, scene) in &scenes {
        for id in texture::classify::bound_images(scene) {
            let im = &scene.images[id.index()];
            if let Ok((w, h)) = texture::codec::dimensions(&im.bytes) {
                let n = w as u64 * h as u64;
                if largest.as_ref().map_or(true, |l| n > l.2) {
                    let name = format!(
                        "{} image {} {}",
                        input.file_name().unwrap().to_string_lossy(),
                        id.0,
                        im.name.clone().unwrap_or_default()
                    );
                    largest = Some((name, im.clone(), n));
                }
            }
        }
    }
    if let Some((name, im, _)) = largest {
        println!(
            "Table II equivalent: Haar pyramid of {name} ({}, {} bytes)",
            im.mime_type,
            im.bytes.len()
        );
        println!(
            "{:<6} {:>11} {:>10} {:>10} {:>10} {:>12}",
            "level", "resolution", "raw KiB", "PNG B", "JPEG85 B", "PSNR dB"
        );
        let png = texture::build_pyramid(&im, TextureFormat::Png, 85).unwrap();
        let jpg = texture::build_pyramid(&im, TextureFormat::Jpeg, 85).unwrap();
        let orig = texture::codec::decode(&im.bytes).unwrap().to_rgba8();
        for (l, (p, j)) in png.iter().zip(&jpg).enumerate().take(6) {
            let psnr = if l == 0 {
                f64::INFINITY
            } else {
                let got = texture::codec::decode(&p.bytes).unwrap().to_rgba8();
                let reference = image::imageops::thumbnail(&orig, p.width, p.height);
                haar::psnr(got.as_raw(), reference.as_raw())
            };
            println!(
                "{:<6} {:>11} {:>10.1} {:>10} {:>10} {:>12.1}",
                l,
                format!("{}x{}", p.width, p.height),
                (p.width * p.height * 4) as f64 / 1024.0,
                if l == 0 {
                    im.bytes.len()
                } else {
                    p.bytes.len()
                },
                if l == 0 {
                    im.bytes.len()
                } else {
                    j.bytes.len()
                },
                psnr
            );
        }
        println!("(level 0 is the original file; PSNR against image::imageops::thumbnail of the original)");
    }

    // Table V.
    println!("\nTable V equivalent: texture MB per model (levels in the default encoding: PNG stays PNG, JPEG stays JPEG q85)");
    println!(
        "{:<28} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}   classes",
        "model", "images", "orig MB", "stored", "first", "second", "third", "fourth"
    );
    for (input, scene) in &scenes {
        let mut s = scene.clone();
        let prepared = texture::prepare(&mut s, &TextureOptions::default());
        let mut levels = [0u64; 5];
        for id in texture::classify::bound_images(&s) {
            if let Ok(p) = texture::build_pyramid(&s.images[id.index()], TextureFormat::Auto, 85) {
                for (l, lv) in p.iter().enumerate().take(5) {
                    levels[l] += lv.bytes.len() as u64;
                }
            }
        }
        println!(
            "{:<28} {:>7} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>9.4}   {}",
            input.file_name().unwrap().to_string_lossy(),
            prepared.images_bound,
            mb(prepared.original_bytes),
            mb(levels[0]),
            mb(levels[1]),
            mb(levels[2]),
            mb(levels[3]),
            mb(levels[4]),
            serde_json::to_string(&prepared.classes).unwrap()
        );
    }

    // First view.
    println!("\nFirst whole-model view (SSE 16 px, 1920x1080, fov 60°), --max-tile-triangles {budget}: texture bytes loaded");
    println!(
        "{:<24} {:>8} {:>9} {:>6} {:>5} {:>9} {:>6} {:>5} {:>9} {:>6} {:>5}",
        "model", "orig B", "shared B", "%", "req", "embed B", "%", "req", "LOD off B", "%", "req"
    );
    for (input, _) in &scenes {
        let name = input.file_stem().unwrap().to_string_lossy().to_string();
        let b = budget.as_str();
        let runs: Vec<(PathBuf, Vec<&str>)> = vec![
            (work.join(format!("tex-{name}-shared")), vec![]),
            (
                work.join(format!("tex-{name}-embed")),
                vec!["--embed-textures"],
            ),
            (
                work.join(format!("tex-{name}-off")),
                vec!["--texture-lod", "off"],
            ),
        ]
        .into_iter()
        .map(|(d, mut a)| {
            a.extend(["--max-tile-triangles", b]);
            (d, a)
        })
        .collect();
        if !runs
            .iter()
            .all(|(dir, extra)| convert(&bin, input, dir, extra))
        {
            eprintln!("conversion of {name} failed");
            continue;
        }
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(runs[0].0.join("report.json")).unwrap()).unwrap();
        let original = report["textures"]["original_bytes"].as_u64().unwrap_or(0);
        let v: Vec<(view::FirstView, usize)> = runs
            .iter()
            .map(|(dir, _)| external::first_view_shared(dir, &Default::default()).unwrap())
            .collect();
        let requests = |k: usize| v[k].0.tiles + v[k].1;
        let v: Vec<view::FirstView> = v.iter().map(|x| x.0.clone()).collect();
        let pct = |b: u64| 100.0 * b as f64 / original.max(1) as f64;
        println!(
            "{:<24} {:>8} {:>9} {:>6.1} {:>5} {:>9} {:>6.1} {:>5} {:>9} {:>6.1} {:>5}",
            name,
            original,
            v[0].texture_bytes,
            pct(v[0].texture_bytes),
            requests(0),
            v[1].texture_bytes,
            pct(v[1].texture_bytes),
            requests(1),
            v[2].texture_bytes,
            pct(v[2].texture_bytes),
            requests(2),
        );
        for (dir, _) in &runs {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}
