//! End-to-end texture checks (paper III.D–III.F) with the real binary, read back with the `gltf`
//! and `image` crates: leaves carry full-resolution images, coarser tiles the pyramid level their
//! geometricError calls for (recomputed here from the written triangles and UVs), cropped
//! textures show the same colours at every UV, shared texture files (the default) and embedded
//! ones (`--embed-textures`) show the same colours, each shared file is written once, and
//! gltf-validator finds 0 errors. Runs on the bundled sample and on
//! ../shared/data/LoD3_Railway.glb when it exists.

mod common;
use common::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One textured primitive of a tile, read back.
struct Textured {
    image: Vec<u8>,
    dims: (u32, u32),
    positions: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    indices: Vec<u32>,
}

/// Textured primitives of a GLB written without Draco (`--compression none`).
fn read_textured(path: &Path) -> Vec<Textured> {
    let bytes = std::fs::read(path).unwrap();
    let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
    let blob = g.blob.as_deref().unwrap();
    let mut out = Vec::new();
    for mesh in g.document.meshes() {
        for p in mesh.primitives() {
            let Some(info) = p.material().pbr_metallic_roughness().base_color_texture() else {
                continue;
            };
            let image = match info.texture().source().source() {
                gltf::image::Source::View { view, .. } => {
                    blob[view.offset()..view.offset() + view.length()].to_vec()
                }
                // A shared file, relative to the GLB.
                gltf::image::Source::Uri { uri, .. } => {
                    assert!(uri.starts_with("../textures/"), "{uri}");
                    std::fs::read(path.parent().unwrap().join(uri)).unwrap()
                }
            };
            let dims = image::ImageReader::new(std::io::Cursor::new(&image))
                .with_guessed_format()
                .unwrap()
                .into_dimensions()
                .unwrap();
            let r = p.reader(|_| Some(blob));
            out.push(Textured {
                image,
                dims,
                positions: r.read_positions().unwrap().collect(),
                uvs: r.read_tex_coords(0).unwrap().into_f32().collect(),
                indices: r.read_indices().unwrap().into_u32().collect(),
            });
        }
    }
    out
}

/// Level sizes: halving, rounded up, down to 1x1 (written again here, not taken from the crate).
fn sizes(w: u32, h: u32) -> Vec<(u32, u32)> {
    let mut v = vec![(w, h)];
    while v.last().unwrap().0 > 1 || v.last().unwrap().1 > 1 {
        let (a, b) = *v.last().unwrap();
        v.push((a.div_ceil(2), b.div_ceil(2)));
    }
    v
}

/// World and UV area of the triangles.
fn areas(t: &Textured) -> (f64, f64) {
    let (mut w, mut u) = (0.0, 0.0);
    for tri in t.indices.chunks_exact(3) {
        let p = |i: u32| glam::DVec3::from(t.positions[i as usize].map(|x| x as f64));
        let q = |i: u32| glam::DVec2::from(t.uvs[i as usize].map(|x| x as f64));
        w += (p(tri[1]) - p(tri[0]))
            .cross(p(tri[2]) - p(tri[0]))
            .length()
            / 2.0;
        u += (q(tri[1]) - q(tri[0]))
            .perp_dot(q(tri[2]) - q(tri[0]))
            .abs()
            / 2.0;
    }
    (w, u)
}

/// Texel colour (nearest, clamped) of an image at `uv`.
fn texel(img: &image::RgbaImage, uv: [f32; 2]) -> [u8; 4] {
    let (w, h) = img.dimensions();
    let x = ((uv[0] as f64 * w as f64).floor() as i64).clamp(0, w as i64 - 1) as u32;
    let y = ((uv[1] as f64 * h as f64).floor() as i64).clamp(0, h as i64 - 1) as u32;
    img.get_pixel(x, y).0
}

/// Points just inside each triangle at its corners (off texel borders, where rounding of a
/// remapped UV may pick the neighbour), and the triangle's centroid.
fn sample_uvs(t: &Textured) -> Vec<[f32; 2]> {
    let mut out = Vec::new();
    for tri in t.indices.chunks_exact(3) {
        let c: Vec<[f32; 2]> = tri.iter().map(|&i| t.uvs[i as usize]).collect();
        let m = [
            (c[0][0] + c[1][0] + c[2][0]) / 3.0,
            (c[0][1] + c[1][1] + c[2][1]) / 3.0,
        ];
        for k in &c {
            out.push([k[0] * 0.99 + m[0] * 0.01, k[1] * 0.99 + m[1] * 0.01]);
        }
        out.push(m);
    }
    out
}

struct Run {
    dir: PathBuf,
    report: Value,
    tiles: Vec<DecodedTile>,
    has_child: Vec<bool>,
}

fn run(model: &Path, name: &str, extra: &[&str]) -> Run {
    let dir = tmpdir(name).join("tiles");
    let mut args = vec!["--compression", "none"];
    args.extend_from_slice(extra);
    let report = convert(model, &dir, &args);
    let (_, tiles) = decode_tileset(&dir);
    let mut has_child = vec![false; tiles.len()];
    for t in &tiles {
        if let Some(p) = t.parent {
            has_child[p] = true;
        }
    }
    Run {
        dir,
        report,
        tiles,
        has_child,
    }
}

/// The checks of one model; returns (internal tiles with a coarser image, textured tiles).
fn check_levels(run: &Run, input_images: &BTreeMap<Vec<u8>, ()>) -> (usize, usize) {
    let tex = &run.report["textures"];
    // Level-0 sizes (after cropping) of every stored image, by pixel size; the report says which
    // images there are, the GLBs say which one a primitive uses (matched by the full-size bytes
    // in leaves and by being a pyramid level of one of them above).
    let stored: Vec<(u32, u32)> = tex["images"]
        .as_array()
        .unwrap()
        .iter()
        .map(|i| {
            (
                i["width"].as_u64().unwrap() as u32,
                i["height"].as_u64().unwrap() as u32,
            )
        })
        .collect();
    // Bytes per built level of each stored image (empty when its pyramid was not needed).
    let level_bytes: Vec<Vec<u64>> = tex["images"]
        .as_array()
        .unwrap()
        .iter()
        .map(|i| {
            i["levels"]
                .as_array()
                .unwrap()
                .iter()
                .map(|l| l[2].as_u64().unwrap())
                .collect()
        })
        .collect();
    let (mut coarser, mut textured) = (0, 0);
    for (i, t) in run.tiles.iter().enumerate() {
        let Some(uri) = &t.uri else { continue };
        let prims = read_textured(&run.dir.join(uri));
        if prims.is_empty() {
            continue;
        }
        textured += 1;
        for p in &prims {
            if !run.has_child[i] {
                // Leaves: full resolution, one of the stored level-0 images.
                assert!(
                    stored.contains(&p.dims),
                    "{uri}: leaf image {:?} is not a full-resolution image {stored:?}",
                    p.dims
                );
                let cropped = tex["crop"]["cropped"].as_u64().unwrap() > 0;
                if !cropped {
                    assert!(
                        input_images.contains_key(&p.image),
                        "{uri}: leaf image bytes are the input's, untouched"
                    );
                }
                continue;
            }
            // Internal tiles: the coarsest level whose texel size ≤ geometricError, of the
            // stored image this one is a level of, or a finer level of that image whose file is
            // no larger (the writer ships the smaller of the two).
            let (wa, ua) = areas(p);
            let ge = t.geometric_error;
            let candidates: Vec<usize> = stored
                .iter()
                .zip(&level_bytes)
                .filter_map(|(&(w, h), bytes)| {
                    let s = sizes(w, h);
                    let got = s.iter().position(|&d| d == p.dims)?;
                    let texel = |(w, h): (u32, u32)| (wa / (ua * w as f64 * h as f64)).sqrt();
                    let expected = if ua == 0.0 {
                        0
                    } else {
                        (0..s.len())
                            .take_while(|&l| texel(s[l]) <= ge * (1.0 + 1e-6))
                            .last()
                            .unwrap_or(0)
                    };
                    // Ties within float rounding may go either way.
                    let tie =
                        |l: usize| l + 1 < s.len() && (texel(s[l + 1]) / ge - 1.0).abs() < 1e-6;
                    let ok = got == expected
                        || (got == expected + 1 && tie(expected))
                        || (got < expected
                            && bytes
                                .get(got)
                                .zip(bytes.get(expected))
                                .is_some_and(|(a, b)| a <= b));
                    ok.then_some(got)
                })
                .collect();
            assert!(
                !candidates.is_empty(),
                "{uri}: image {:?} is not the level for error {ge} m (world {wa} m², uv {ua})",
                p.dims
            );
            if candidates.iter().all(|&l| l > 0) {
                coarser += 1;
            }
        }
    }
    (coarser, textured)
}

/// Leaves of two runs of the same model (same geometry, same tiles) sample the same colours.
fn same_colours(a: &Run, b: &Run) -> usize {
    let mut samples = 0;
    for (i, (ta, tb)) in a.tiles.iter().zip(&b.tiles).enumerate() {
        if a.has_child[i] {
            continue;
        }
        let (Some(ua), Some(ub)) = (&ta.uri, &tb.uri) else {
            continue;
        };
        assert_eq!(ua, ub);
        let (pa, pb) = (
            read_textured(&a.dir.join(ua)),
            read_textured(&b.dir.join(ub)),
        );
        assert_eq!(pa.len(), pb.len());
        for (x, y) in pa.iter().zip(&pb) {
            assert_eq!(x.positions, y.positions, "{ua}: same geometry");
            let ix = image::load_from_memory(&x.image).unwrap().to_rgba8();
            let iy = image::load_from_memory(&y.image).unwrap().to_rgba8();
            for (u, v) in sample_uvs(x).iter().zip(sample_uvs(y)) {
                assert_eq!(texel(&ix, *u), texel(&iy, v), "{ua}: uv {u:?} vs {v:?}");
                samples += 1;
            }
        }
    }
    samples
}

/// Every shared texture file is referenced, written once (distinct bytes), named by its bytes,
/// and at least 1 KiB (smaller levels are embedded by default).
fn check_shared_files(run: &Run) {
    let dir = run.dir.join("textures");
    let mut referenced = std::collections::BTreeSet::new();
    for t in &run.tiles {
        let Some(uri) = &t.uri else { continue };
        let json = glb_json(&std::fs::read(run.dir.join(uri)).unwrap());
        for im in json["images"].as_array().into_iter().flatten() {
            if let Some(u) = im["uri"].as_str() {
                referenced.insert(u.trim_start_matches("../textures/").to_string());
            }
        }
    }
    let mut contents = std::collections::BTreeSet::new();
    let mut files = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let e = e.unwrap();
        let name = e.file_name().to_string_lossy().to_string();
        let bytes = std::fs::read(e.path()).unwrap();
        assert!(referenced.contains(&name), "{name} is used by a tile");
        assert!(bytes.len() >= 1024, "{name}: {} B", bytes.len());
        assert!(contents.insert(bytes), "{name}: bytes written once");
        files += 1;
    }
    assert_eq!(files, referenced.len(), "every referenced file exists");
    assert_eq!(run.report["textures"]["external_files"], files);
}

/// Image bytes of a GLB input, as a set.
fn input_images(model: &Path) -> BTreeMap<Vec<u8>, ()> {
    let bytes = std::fs::read(model).unwrap();
    let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
    let blob = g.blob.as_deref().unwrap();
    g.document
        .images()
        .filter_map(|i| match i.source() {
            gltf::image::Source::View { view, .. } => Some((
                blob[view.offset()..view.offset() + view.length()].to_vec(),
                (),
            )),
            _ => None,
        })
        .collect()
}

fn check_model(model: &Path, name: &str, max_tris: &str) {
    let images = input_images(model);
    let on = run(
        model,
        &format!("tex-{name}"),
        &["--max-tile-triangles", max_tris],
    );
    let tex = &on.report["textures"];
    eprintln!(
        "{name}: classes {}, identical {}, crop {}",
        tex["classes"], tex["identical"], tex["crop"]
    );
    let (coarser, textured) = check_levels(&on, &images);
    eprintln!("{name}: {textured} textured tiles, {coarser} textured primitives of internal tiles at a coarser level");
    assert!(textured > 0, "{name}: textured tiles");
    assert!(
        coarser > 0,
        "{name}: some internal tile carries a coarser level"
    );
    check_shared_files(&on);
    // Without cropping the leaves carry the input's bytes; with it, the same colours (the
    // uncropped run embeds its textures: both ways of carrying an image are read).
    let uncropped = run(
        model,
        &format!("tex-{name}-nocrop"),
        &[
            "--max-tile-triangles",
            max_tris,
            "--texture-crop",
            "off",
            "--embed-textures",
        ],
    );
    assert!(!uncropped.dir.join("textures").exists());
    check_levels(&uncropped, &images);
    let n = same_colours(&on, &uncropped);
    eprintln!("{name}: {n} UV samples show the same colour with and without cropping");
    assert!(n > 0);
    // LOD off: every tile carries full resolution.
    let off = run(
        model,
        &format!("tex-{name}-nolod"),
        &["--max-tile-triangles", max_tris, "--texture-lod", "off"],
    );
    let written = off.report["textures"]["written_per_level"]
        .as_array()
        .unwrap();
    assert_eq!(written.len(), 1, "{name}: one level without texture LOD");
    assert_eq!(written[0]["level"], 0);
    let view = |dir: &Path| {
        bimtiles::texture::external::first_view_shared(dir, &Default::default())
            .unwrap()
            .0
    };
    let (v_on, v_off) = (view(&on.dir), view(&off.dir));
    let original = tex["original_bytes"].as_u64().unwrap();
    eprintln!(
        "{name}: first view (SSE 16 px, 1920x1080): {} tiles, texture bytes {} with texture LOD, {} without, original textures {} ({:.1} %)",
        v_on.tiles,
        v_on.texture_bytes,
        v_off.texture_bytes,
        original,
        100.0 * v_on.texture_bytes as f64 / original as f64
    );
    // Measured, not asserted against the <10 % target: whole-model views of these small models
    // reach leaves, which carry full resolution. Shared files count once, so a view never loads
    // more than the stored textures plus the small levels embedded below 1 KiB.
    assert!(v_on.texture_bytes <= v_off.texture_bytes);
    let stored = tex["stored_bytes"].as_u64().unwrap();
    assert!(
        v_off.texture_bytes <= stored + 1024 * v_off.images as u64,
        "{name}: LOD off loads {} B, stored {stored} B",
        v_off.texture_bytes
    );
    // Every output passes gltf-validator, with and without Draco.
    gltf_validator(&on.dir);
    let draco = tmpdir(&format!("tex-{name}-draco")).join("tiles");
    convert(model, &draco, &["--max-tile-triangles", max_tris]);
    gltf_validator(&draco);
}

#[test]
fn sample_textures_follow_the_tile_error() {
    check_model(&sample(), "sample", "2000");
}

#[test]
fn lod3_railway_textures_follow_the_tile_error() {
    let Some(sh) = shared() else {
        eprintln!("SKIPPED: ../shared/data not found (LoD3_Railway.glb not tested)");
        return;
    };
    let model = sh.join("data/LoD3_Railway.glb");
    if !model.is_file() {
        eprintln!("SKIPPED: {} not found", model.display());
        return;
    }
    check_model(&model, "railway", "3000");
}

#[test]
fn sample_texture_classes_and_crop_are_reported() {
    let r = run(
        &sample(),
        "tex-sample-report",
        &["--max-tile-triangles", "2000"],
    );
    let t = &r.report["textures"];
    // facade_photo: bound by two materials (shared, UVs inside [0,1]); floor_tiles: tiling.
    assert_eq!(t["classes"]["shared"], 1);
    assert_eq!(t["classes"]["repeated"], 1);
    assert_eq!(t["classes"]["standalone"], 0);
    assert_eq!(t["crop"]["cropped"], 1, "the facade photo is cropped");
    let c = &t["crop"];
    assert!(c["texels_after"].as_u64().unwrap() < c["texels_before"].as_u64().unwrap());
    assert!(t["written_bytes"].as_u64().unwrap() > 0);
    assert!(t["original_bytes"].as_u64().unwrap() > 0);
}
