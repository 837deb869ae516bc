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
//! - Texture atlas: first-view and whole-tileset bytes and requests with `--texture-atlas` off
//!   and on (plus the atlas models `tests/textures.rs` writes, when present).
//!
//! - Memory (issue 6: texture work must not need more than a few times an image's pixel bytes):
//!   peak RSS of the pyramid, crop and identical passes on generated 4096² and 16384² RGBA
//!   images (PNG, and JPEG at 4096²), each pass in a child process (this example re-run with
//!   `--child`). `BENCH_TEXTURES_WHOLE=1` adds the code path before row streaming (whole images
//!   decoded); `BENCH_TEXTURES_SIZES=4096,8192` picks the sizes; `BENCH_TEXTURES_BIG_JPEG=1` adds
//!   JPEG at every size.
//!
//! Usage: cargo run --release --example bench_textures -- [DATA_DIR [MAX_TILE_TRIANGLES]]
//! (the tile budget of the first-view conversions; default 3000, as `tests/textures.rs`: at the
//! tool's default budget these small models fit one tile and a first view loads everything).

use bimtiles::inspect::first_view as view;
use bimtiles::texture::{self, external, haar, TextureFormat, TextureOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::time::Instant;

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
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("--child") {
        child(&args[2], Path::new(&args[3]));
        return;
    }
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
                if largest.as_ref().is_none_or(|l| n > l.2) {
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
        let limits = texture::admit::ImageLimits::under_budget(None);
        let prepared = match texture::prepare(&mut s, &TextureOptions::default(), &limits) {
            Ok(p) => p,
            Err((file, refused)) => panic!("{}: {refused}", file.display()),
        };
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
            .map(|(dir, _)| view::first_view_shared(dir, &Default::default()).unwrap())
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

    atlas(&bin, &work, &repo, &scenes, &budget);

    let sizes: Vec<u32> = std::env::var("BENCH_TEXTURES_SIZES")
        .ok()
        .map(|v| v.split(',').filter_map(|n| n.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![4096, 16384]);
    memory(&work, &sizes);
}

/// Bytes and requests of a tileset: the first whole-model view (tiles selected, plus each
/// distinct texture file they reference) and all of it (every tile and texture file).
struct Load {
    view_bytes: u64,
    view_requests: usize,
    total_bytes: u64,
    total_requests: usize,
}

fn load(dir: &Path) -> Load {
    let (shared, files) = view::first_view_shared(dir, &Default::default()).unwrap();
    let plain = view::first_view(dir, &Default::default()).unwrap();
    let sizes = |sub: &str| -> Vec<u64> {
        std::fs::read_dir(dir.join(sub))
            .into_iter()
            .flatten()
            .filter_map(|e| e.ok()?.metadata().ok().map(|m| m.len()))
            .collect()
    };
    let (tiles, textures) = (sizes("tiles"), sizes(external::TEXTURE_DIR));
    Load {
        // Tile GLBs (embedded images included) plus the shared files they reference.
        view_bytes: shared.glb_bytes + shared.texture_bytes - plain.texture_bytes,
        view_requests: shared.tiles + files,
        total_bytes: tiles.iter().sum::<u64>() + textures.iter().sum::<u64>(),
        total_requests: tiles.len() + textures.len(),
    }
}

/// Per-tile atlas (`--texture-atlas`) on vs off: first-view and whole-tileset bytes and
/// requests. Besides the textured inputs, the models `tests/textures.rs` writes to
/// `target/test-out/atlas-model*/` (walls of 16 posters of 48-128 and 192-512 texels; the sample
/// with a second facade image) when that test has run: the sample and LoD3_Railway have nothing
/// to pack.
fn atlas(
    bin: &Path,
    work: &Path,
    repo: &Path,
    scenes: &[(PathBuf, bimtiles::scene::Scene)],
    budget: &str,
) {
    let mut inputs: Vec<PathBuf> = scenes.iter().map(|(p, _)| p.clone()).collect();
    for extra in [
        "atlas-model/poster_wall.glb",
        "atlas-model/poster_wall_large.glb",
        "atlas-model-facades/sample_two_facades.glb",
    ] {
        let p = repo.join("target/test-out").join(extra);
        if p.is_file() {
            inputs.push(p);
        } else {
            eprintln!(
                "{} not found (run `cargo test --release --test tests textures::atlas`)",
                p.display()
            );
        }
    }
    println!("\nPer-tile texture atlas, --max-tile-triangles {budget}: bytes and requests (first view SSE 16 px, 1920x1080; all: every tile and texture file)");
    println!(
        "{:<22} {:>5} {:>9} {:>5} {:>9} {:>5} {:>10} {:>5} {:>10} {:>5} {:>7} {:>6} {:>10}",
        "model",
        "",
        "view B",
        "req",
        "view B",
        "req",
        "all B",
        "req",
        "all B",
        "req",
        "atlases",
        "packed",
        "B before>after"
    );
    println!(
        "{:<22} {:>5} {:>15} {:>15} {:>16} {:>16}",
        "", "", "atlas off", "atlas on", "atlas off", "atlas on"
    );
    for input in &inputs {
        let name = input.file_stem().unwrap().to_string_lossy().to_string();
        let dirs: Vec<PathBuf> = ["off", "on"]
            .iter()
            .map(|s| work.join(format!("atlas-{name}-{s}")))
            .collect();
        let ok = ["off", "on"].iter().zip(&dirs).all(|(s, d)| {
            convert(
                bin,
                input,
                d,
                &["--max-tile-triangles", budget, "--texture-atlas", s],
            )
        });
        if !ok {
            eprintln!("conversion of {name} failed");
            continue;
        }
        let (off, on) = (load(&dirs[0]), load(&dirs[1]));
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dirs[1].join("report.json")).unwrap()).unwrap();
        let a = &report["textures"]["atlas"];
        println!(
            "{:<22} {:>5} {:>9} {:>5} {:>9} {:>5} {:>10} {:>5} {:>10} {:>5} {:>7} {:>6} {:>10}",
            name,
            "",
            off.view_bytes,
            off.view_requests,
            on.view_bytes,
            on.view_requests,
            off.total_bytes,
            off.total_requests,
            on.total_bytes,
            on.total_requests,
            a["atlases"].as_u64().unwrap_or(0),
            a["images_packed"].as_u64().unwrap_or(0),
            format!("{}>{}", a["bytes_before"], a["bytes_after"]),
        );
        for d in &dirs {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

/// The UV box the crop pass keeps: the middle half in each direction (a quarter of the texels).
const CROP_UV: ([f32; 2], [f32; 2]) = ([0.25, 0.25], [0.75, 0.75]);

/// One texture pass on one image file, run in a child process (`--child PASS FILE`) so its
/// peak RSS is its own; prints `peak=<bytes> seconds=<s>`. The `*-whole` passes are the code
/// before row streaming (whole images decoded), for comparison. `identical` hashes the image and
/// compares it with a copy of its bytes (the file is held twice).
fn child(pass: &str, file: &Path) {
    let bytes = std::fs::read(file).unwrap();
    let mime = if bytes.starts_with(b"\x89PNG") {
        "image/png"
    } else {
        "image/jpeg"
    };
    let t = Instant::now();
    let (w, h) = texture::codec::dimensions(&bytes).unwrap();
    let rect = texture::crop::used_rect(CROP_UV, w, h, texture::crop::CROP_PADDING_TEXELS);
    let [x0, y0, x1, y1] = rect;
    let out_bytes: usize = match pass {
        "pyramid" => {
            let image = bimtiles::scene::Image {
                name: None,
                mime_type: mime.into(),
                bytes: Arc::new(bytes),
            };
            let p = texture::build_pyramid(&image, TextureFormat::Auto, 85).unwrap();
            p[1..].iter().map(|l| l.bytes.len()).sum()
        }
        "crop" => {
            let px = texture::crop::crop_rgba8(&bytes, rect).unwrap();
            drop(bytes);
            let png = texture::codec::encode_rgba(x1 - x0, y1 - y0, px, TextureFormat::Png, "", 0);
            png.unwrap().0.len()
        }
        "pyramid-whole" => {
            let img = texture::codec::decode(&bytes).unwrap().to_rgba8();
            let mut level = haar::next_level_rgba8(w, h, img.as_raw());
            drop(img);
            let mut total = 0;
            loop {
                let px = level.to_rgba8();
                let enc = texture::codec::encode_rgba(
                    level.width,
                    level.height,
                    px,
                    TextureFormat::Auto,
                    mime,
                    85,
                );
                total += enc.unwrap().0.len();
                if level.width <= 1 && level.height <= 1 {
                    break total;
                }
                level = haar::next_level(&level);
            }
        }
        "crop-whole" => {
            let img = texture::codec::decode(&bytes).unwrap();
            let sub =
                image::imageops::crop_imm(&img.to_rgba8(), x0, y0, x1 - x0, y1 - y0).to_image();
            drop(img);
            let png = texture::codec::encode_rgba(
                x1 - x0,
                y1 - y0,
                sub.into_raw(),
                TextureFormat::Png,
                "",
                0,
            );
            png.unwrap().0.len()
        }
        "identical" => {
            // The pixel hash of one image, then the row-by-row comparison with a copy (both
            // decoders at once).
            let copy = bytes.clone();
            let key = texture::identical::pixel_key(&bytes).unwrap();
            assert!(texture::identical::same_pixels(&bytes, &copy));
            key.2 as usize % 2
        }
        "identical-whole" => {
            use std::hash::{Hash, Hasher};
            let copy = bytes.clone();
            let img = texture::codec::decode(&bytes).unwrap();
            let mut h = std::collections::hash_map::DefaultHasher::new();
            img.as_bytes().hash(&mut h);
            drop(img);
            let (a, b) = (
                texture::codec::decode(&bytes).unwrap(),
                texture::codec::decode(&copy).unwrap(),
            );
            assert!(a.as_bytes() == b.as_bytes());
            h.finish() as usize % 2
        }
        other => panic!("unknown pass {other}"),
    };
    println!(
        "peak={} seconds={:.2} out={out_bytes}",
        bimtiles::memory::peak_memory_bytes(),
        t.elapsed().as_secs_f64()
    );
}

/// A `n x n` RGBA PNG streamed to `path` row by row (never a whole image in memory): gradients,
/// a grid of "windows", a translucent band at the bottom, and 2 bits of noise, so that it is
/// neither trivially compressible nor noise.
fn write_test_png(path: &Path, n: u32) {
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut e = png::Encoder::new(f, n, n);
    e.set_color(png::ColorType::Rgba);
    e.set_depth(png::BitDepth::Eight);
    e.set_compression(png::Compression::Fast);
    let mut w = e.write_header().unwrap().into_stream_writer().unwrap();
    let mut row = vec![0u8; n as usize * 4];
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    for y in 0..n {
        for (x, px) in row.chunks_exact_mut(4).enumerate() {
            let x = x as u32;
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let noise = (s >> 62) as u8;
            let (gx, gy) = (
                (x as u64 * 255 / n as u64) as u8,
                (y as u64 * 255 / n as u64) as u8,
            );
            let window = x % 64 < 40 && y % 96 < 60;
            let rgb = if window {
                [gx / 4 + 20, gy / 4 + 30, 90]
            } else {
                [gx, gy, gx / 2 + gy / 2]
            };
            let alpha = if y >= n / 8 * 7 { 128 + gx / 2 } else { 255 };
            px.copy_from_slice(&[rgb[0] ^ noise, rgb[1] ^ noise, rgb[2], alpha]);
        }
        w.write_all(&row).unwrap();
    }
    w.finish().unwrap();
}

/// A `n x n` JPEG (q90) of the same content, through `image` (no row-wise JPEG encoder).
fn write_test_jpeg(png_path: &Path, path: &Path) {
    let img = texture::codec::decode(&std::fs::read(png_path).unwrap())
        .unwrap()
        .to_rgb8();
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    image::codecs::jpeg::JpegEncoder::new_with_quality(f, 90)
        .encode_image(&img)
        .unwrap();
}

/// Peak RSS of the pyramid, crop and identical passes on one big image, per size and format,
/// each pass in a child process. `BENCH_TEXTURES_WHOLE=1` adds the whole-image code path.
fn memory(work: &Path, sizes: &[u32]) {
    let whole = std::env::var_os("BENCH_TEXTURES_WHOLE").is_some();
    let dir = tempfile::tempdir_in(work).unwrap();
    let exe = std::env::current_exe().unwrap();
    println!("\nMemory of the texture passes on one image (each pass in its own process: peak RSS is VmHWM; pixels = w*h*4 bytes; file = encoded input, read whole)");
    println!(
        "{:<6} {:>12} {:<16} {:>10} {:>9} {:>9} {:>10} {:>8}",
        "format", "size", "pass", "pixels MB", "file MB", "peak MB", "peak/pix", "s"
    );
    for &n in sizes {
        let png_path = dir.path().join(format!("{n}.png"));
        write_test_png(&png_path, n);
        let mut files = vec![("png", png_path.clone())];
        if n <= 4096 || std::env::var_os("BENCH_TEXTURES_BIG_JPEG").is_some() {
            let jpg = dir.path().join(format!("{n}.jpg"));
            write_test_jpeg(&png_path, &jpg);
            files.push(("jpeg", jpg));
        }
        let pixels = n as u64 * n as u64 * 4;
        for (format, file) in &files {
            let size = std::fs::metadata(file).unwrap().len();
            let mut passes = vec!["pyramid", "crop", "identical"];
            if whole {
                passes.extend(["pyramid-whole", "crop-whole", "identical-whole"]);
            }
            for pass in passes {
                let out = Command::new(&exe)
                    .arg("--child")
                    .arg(pass)
                    .arg(file)
                    .output()
                    .unwrap();
                let text = String::from_utf8_lossy(&out.stdout);
                let field = |k: &str| {
                    text.split_whitespace()
                        .find_map(|f| f.strip_prefix(k))
                        .and_then(|v| v.parse::<f64>().ok())
                };
                let (Some(peak), Some(secs)) = (field("peak="), field("seconds=")) else {
                    eprintln!(
                        "{pass} on {}: failed: {}",
                        file.display(),
                        String::from_utf8_lossy(&out.stderr)
                    );
                    continue;
                };
                println!(
                    "{:<6} {:>12} {:<16} {:>10.0} {:>9.0} {:>9.0} {:>10.2} {:>8.1}",
                    format,
                    format!("{n}x{n}"),
                    pass,
                    mb(pixels),
                    mb(size),
                    mb(peak as u64),
                    peak / pixels as f64,
                    secs
                );
            }
        }
    }
}
