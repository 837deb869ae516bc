//! End-to-end texture checks (paper III.D–III.F) with the real binary, read back with the `gltf`
//! and `image` crates: leaves carry full-resolution images, coarser tiles the pyramid level their
//! geometricError calls for (recomputed here from the written triangles and UVs), cropped
//! textures show the same colours at every UV, shared texture files (the default) and embedded
//! ones (`--embed-textures`) show the same colours, each shared file is written once, and
//! gltf-validator finds 0 errors. Runs on the bundled sample and on
//! ../shared/data/LoD3_Railway.glb when it exists.

use crate::common::*;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

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

/// `model` converted with the atlas off, then on (outputs `{name}-off` and `{name}-on`).
fn run_atlas_off_on(model: &Path, name: &str, extra: &[&str]) -> (Run, Run) {
    let with = |state: &str| {
        let args = [extra, &["--texture-atlas", state]].concat();
        run(model, &format!("{name}-{state}"), &args)
    };
    (with("off"), with("on"))
}

/// The checks of one model; returns (internal tiles with a coarser image, textured tiles).
fn check_levels(run: &Run, input_images: &BTreeSet<Vec<u8>>) -> (usize, usize) {
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
        let prims = read_textured(&run.dir, uri);
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
                        input_images.contains(&p.image),
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

/// Every shared texture file is referenced by tiles whose copies of it would cost more than a
/// request (100 KB; cheaper files are moved into their tiles), written once (distinct bytes),
/// named by its bytes, and at least 1 KiB (smaller levels are embedded by default); returns how
/// many files there are.
fn check_shared_files(run: &Run) -> usize {
    let dir = run.dir.join("textures");
    let mut users: BTreeMap<String, usize> = BTreeMap::new();
    for t in &run.tiles {
        let Some(uri) = &t.uri else { continue };
        let json = glb_json(&content_bytes(&run.dir, uri));
        let mut names: Vec<String> = (json["images"].as_array().into_iter().flatten())
            .filter_map(|im| {
                Some(
                    im["uri"]
                        .as_str()?
                        .trim_start_matches("../textures/")
                        .into(),
                )
            })
            .collect();
        names.dedup();
        for name in names {
            *users.entry(name).or_default() += 1;
        }
    }
    let mut contents = std::collections::BTreeSet::new();
    let mut files = 0;
    for e in std::fs::read_dir(&dir).into_iter().flatten() {
        let e = e.unwrap();
        let name = e.file_name().to_string_lossy().to_string();
        let bytes = std::fs::read(e.path()).unwrap();
        let tiles = users.get(&name).copied().unwrap_or(0);
        assert!(
            tiles >= 2
                && (tiles as u64 - 1) * bytes.len() as u64
                    > bimtiles::transfer::SEQUENTIAL_REQUEST_WORTH_BYTES as u64,
            "{name} ({} B) is used by {tiles} tiles: cheaper copied than shared",
            bytes.len()
        );
        assert!(bytes.len() >= 1024, "{name}: {} B", bytes.len());
        assert_eq!(
            name,
            bimtiles::texture::external::file_name(&bytes, mime_of(&name))
        );
        assert!(contents.insert(bytes), "{name}: bytes written once");
        files += 1;
    }
    assert_eq!(files, users.len(), "every referenced file exists");
    assert_eq!(run.report["textures"]["external_files"], files);
    files
}

/// The MIME type a shared file's extension stands for.
fn mime_of(name: &str) -> &'static str {
    match name.rsplit('.').next() {
        Some("png") => "image/png",
        Some("jpg") => "image/jpeg",
        Some("webp") => "image/webp",
        Some("ktx2") => "image/ktx2",
        _ => "application/octet-stream",
    }
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
    let (n, _) = same_colours(&on, &uncropped, Tiles::Leaves);
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
        bimtiles::inspect::first_view::first_view_shared(dir, &Default::default())
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
    // reach leaves, which carry full resolution. Shared files count once, and a file is copied
    // into its tiles only while the copies add at most 100 KB (a request's worth), so a view
    // never loads more than the stored textures, those copies, and the small levels embedded
    // below 1 KiB.
    assert!(v_on.texture_bytes <= v_off.texture_bytes);
    let stored = tex["stored_bytes"].as_u64().unwrap();
    let images = tex["images_bound"].as_u64().unwrap();
    assert!(
        v_off.texture_bytes
            <= stored
                + bimtiles::transfer::SEQUENTIAL_REQUEST_WORTH_BYTES as u64 * images
                + 1024 * v_off.images as u64,
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
    let Some(model) = shared_file("LoD3_Railway.glb") else {
        return;
    };
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

/// The bundled sample with a second facade image: the planters' material (`Stone cladding dark`)
/// gets its own darker, warmer copy of the facade photo. The bundled sample has one
/// non-repeating image (the photo, bound by both materials; the floor tiles repeat), so none of
/// its tiles has two images to pack; here the tiles holding the west cladding and a planter do.
fn sample_with_two_facades(out: &Path) {
    let (mut json, mut bin) = glb_chunks(&std::fs::read(sample()).unwrap());
    let photo = json["images"]
        .as_array()
        .unwrap()
        .iter()
        .position(|i| i["name"] == "facade_photo.png")
        .unwrap();
    let view = &json["bufferViews"][json["images"][photo]["bufferView"].as_u64().unwrap() as usize];
    let (off, len) = (
        view["byteOffset"].as_u64().unwrap() as usize,
        view["byteLength"].as_u64().unwrap() as usize,
    );
    let mut px = image::load_from_memory(&bin[off..off + len])
        .unwrap()
        .to_rgba8();
    for p in px.pixels_mut() {
        let [r, g, b, a] = p.0;
        p.0 = [
            (r as u32 * 7 / 10) as u8,
            (g as u32 * 6 / 10) as u8,
            b / 2,
            a,
        ];
    }
    let mut png = Vec::new();
    px.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let views = json["bufferViews"].as_array_mut().unwrap();
    views.push(serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": png.len()}));
    let view = views.len() - 1;
    bin.extend_from_slice(&png);
    json["buffers"][0]["byteLength"] = bin.len().into();
    let images = json["images"].as_array_mut().unwrap();
    images.push(
        serde_json::json!({"name": "facade_dark.png", "bufferView": view, "mimeType": "image/png"}),
    );
    let image = images.len() - 1;
    let sampler = json["textures"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["source"] == photo)
        .unwrap()["sampler"]
        .clone();
    let textures = json["textures"].as_array_mut().unwrap();
    textures.push(serde_json::json!({"name": "Facade dark", "sampler": sampler, "source": image}));
    let texture = textures.len() - 1;
    let dark = json["materials"]
        .as_array_mut()
        .unwrap()
        .iter_mut()
        .find(|m| m["name"] == "Stone cladding dark")
        .unwrap();
    dark["pbrMetallicRoughness"]["baseColorTexture"]["index"] = texture.into();
    std::fs::write(out, glb(&serde_json::to_vec(&json).unwrap(), &bin)).unwrap();
}

/// Which tiles [`same_colours`] compares.
#[derive(Clone, Copy, PartialEq)]
enum Tiles {
    /// The leaves (full resolution).
    Leaves,
    /// Every tile, internal ones too. Their coarse levels can put a sample on a texel border
    /// (a centroid at 2/3 of a 3-texel level), which may round to either texel: such samples
    /// are skipped.
    All,
}

/// Every textured primitive of the `tiles` of two runs of the same model shows the same texel
/// colour at points by each vertex and at each triangle's centroid (nearest texel, read back
/// with the `gltf` and `image` crates); returns the samples taken and the primitives whose
/// image differs between the runs (an atlas or a crop in one of them).
fn same_colours(a: &Run, b: &Run, tiles: Tiles) -> (usize, usize) {
    let (mut samples, mut differ) = (0, 0);
    for (i, (ta, tb)) in a.tiles.iter().zip(&b.tiles).enumerate() {
        if tiles == Tiles::Leaves && a.has_child[i] {
            continue;
        }
        let (Some(ua), Some(ub)) = (&ta.uri, &tb.uri) else {
            continue;
        };
        assert_eq!(ta.name, tb.name);
        let tile = ta.name.as_deref().unwrap();
        let (pa, pb) = (read_textured(&a.dir, ua), read_textured(&b.dir, ub));
        assert_eq!(pa.len(), pb.len(), "{tile}: textured primitives");
        for (x, y) in pa.iter().zip(&pb) {
            assert_eq!(x.positions, y.positions, "{tile}: same geometry");
            assert_eq!(x.indices, y.indices, "{tile}: same triangles");
            differ += (x.image != y.image) as usize;
            let ix = image::load_from_memory(&x.image).unwrap().to_rgba8();
            let iy = image::load_from_memory(&y.image).unwrap().to_rgba8();
            for (u, v) in sample_uvs(x).iter().zip(sample_uvs(y)) {
                if tiles == Tiles::All && (on_texel_border(&ix, *u) || on_texel_border(&iy, v)) {
                    continue;
                }
                assert_eq!(texel(&ix, *u), texel(&iy, v), "{tile}: uv {u:?} vs {v:?}");
                samples += 1;
            }
        }
    }
    (samples, differ)
}

/// Whether `uv` lies within 1/1000 texel of a texel border of `img`.
fn on_texel_border(img: &image::RgbaImage, uv: [f32; 2]) -> bool {
    let (w, h) = img.dimensions();
    [(uv[0], w), (uv[1], h)].iter().any(|&(t, n)| {
        let x = t as f64 * n as f64;
        (x - x.round()).abs() < 1e-3
    })
}

#[test]
fn atlas_declines_the_two_facades_where_it_does_not_save() {
    // At 3000 triangles a tile, only the root holds both facades, at 7x7 and 1x1 texels (199 and
    // 72 bytes, both embedded): an atlas with its borders is larger, so the root keeps them.
    let model = tmpdir("atlas-model-facades").join("sample_two_facades.glb");
    sample_with_two_facades(&model);
    let budget = ["--max-tile-triangles", "3000"];
    let (off, on) = run_atlas_off_on(&model, "atlas-two", &budget);
    let a = &on.report["textures"]["atlas"];
    eprintln!("two facades: atlas {a}");
    assert_eq!(on.report["textures"]["classes"]["repeated"], 1);
    assert!(
        a["declined"].as_u64().unwrap() >= 1,
        "the root's two facades were candidates"
    );
    assert_eq!(a["atlases"], 0);
    assert_same_tiles(&off, &on);
}

/// The bundled sample has one non-repeating image, so nothing to pack: the atlas changes no
/// byte of its tiles.
#[test]
fn atlas_leaves_the_bundled_sample_unchanged() {
    let budget = ["--max-tile-triangles", "2000"];
    let (off, on) = run_atlas_off_on(&sample(), "atlas-sample", &budget);
    assert_eq!(on.report["textures"]["atlas"]["atlases"], 0);
    assert_eq!(on.report["textures"]["atlas"]["images_packed"], 0);
    assert_same_tiles(&off, &on);
}

/// Every tile GLB and shared texture file of two runs is byte-identical.
fn assert_same_tiles(a: &Run, b: &Run) {
    assert_eq!(a.tiles.len(), b.tiles.len());
    for (ta, tb) in a.tiles.iter().zip(&b.tiles) {
        assert_eq!(ta.uri, tb.uri);
        if let (Some(u), Some(name)) = (&ta.uri, &ta.name) {
            assert!(
                content_bytes(&a.dir, u) == content_bytes(&b.dir, u),
                "{name} differs"
            );
        }
    }
    let files = |d: &Path| {
        let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(d.join("textures"))
            .into_iter()
            .flatten()
            .map(|e| {
                let e = e.unwrap();
                (
                    e.file_name().to_string_lossy().to_string(),
                    std::fs::read(e.path()).unwrap(),
                )
            })
            .collect();
        v.sort();
        v
    };
    assert!(files(&a.dir) == files(&b.dir), "texture files differ");
}

/// LoD3_Railway's 28 textures all repeat: with the atlas on, none is packed and the tiles are
/// those of the atlas off.
#[test]
fn lod3_railway_repeated_textures_are_never_packed() {
    let Some(model) = shared_file("LoD3_Railway.glb") else {
        return;
    };
    let budget = ["--max-tile-triangles", "3000"];
    let (off, on) = run_atlas_off_on(&model, "atlas-railway", &budget);
    let t = &on.report["textures"];
    assert_eq!(t["classes"]["repeated"], 28);
    assert_eq!(
        t["atlas"]["images_packed"], 0,
        "repeated textures are never packed"
    );
    assert_eq!(t["atlas"]["atlases"], 0);
    assert_same_tiles(&off, &on);
}

/// A quad primitive (two triangles) with one normal and the given UVs; its JSON.
fn quad(
    b: &mut GlbBuilder,
    corners: [[f32; 3]; 4],
    uvs: [[f32; 2]; 4],
    normal: [f32; 3],
    material: usize,
) -> Value {
    const VERTICES: Option<u32> = Some(34962);
    let p = b.positions(&corners, VERTICES);
    let vec = |n: usize| serde_json::json!({"componentType": 5126, "count": 4, "type": format!("VEC{n}")});
    let n = b.accessor(&f32_bytes(&[normal; 4]), VERTICES, vec(3));
    let t = b.accessor(&f32_bytes(&uvs), VERTICES, vec(2));
    let idx: Vec<u8> = [0u16, 1, 2, 0, 2, 3]
        .iter()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let i = b.accessor(
        &idx,
        Some(34963),
        serde_json::json!({"componentType": 5123, "count": 6, "type": "SCALAR"}),
    );
    serde_json::json!({"attributes": {"POSITION": p, "NORMAL": n, "TEXCOORD_0": t},
        "indices": i, "material": material})
}

fn png_of(img: &image::RgbaImage) -> Vec<u8> {
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    png
}

/// A wall of `n` posters (1 m quads, each with its own small PNG, UVs inside [0, 1], CLAMP) in
/// rows of 4, and a floor in front with a tiling texture (UVs 0..6, REPEAT). Each poster and the
/// floor is its own node and mesh. Poster images are smooth patterns of 48-128 texels a side
/// times `scale`, each different; their materials are `Poster <k>`, the floor's `Floor`.
fn poster_wall(n: usize, scale: u32) -> Vec<u8> {
    use serde_json::json;
    let mut b = GlbBuilder::default();
    let (mut meshes, mut nodes, mut materials, mut textures, mut images) =
        (vec![], vec![], vec![], vec![], vec![]);
    for k in 0..n {
        let (w, h) = (
            (48 + (k as u32 * 37) % 81) * scale,
            (48 + (k as u32 * 53) % 81) * scale,
        );
        let px = image::RgbaImage::from_fn(w, h, |x, y| {
            let stripe = ((x / 6 + y / 9 + k as u32) % 3) as u8;
            image::Rgba([
                (x * 255 / w) as u8 ^ (k as u8 * 29),
                (y * 255 / h) as u8,
                60 + stripe * 50,
                255,
            ])
        });
        let v = b.view(&png_of(&px), None);
        images.push(
            json!({"name": format!("poster_{k}.png"), "bufferView": v, "mimeType": "image/png"}),
        );
        textures.push(json!({"sampler": 0, "source": images.len() - 1}));
        materials.push(
            json!({"name": format!("Poster {k}"), "pbrMetallicRoughness": {
            "baseColorTexture": {"index": textures.len() - 1}, "metallicFactor": 0.0}}),
        );
        let (x, y) = ((k % 4) as f32 * 1.25, (k / 4) as f32 * 1.25);
        let c = [
            [x, y, 0.0],
            [x + 1.0, y, 0.0],
            [x + 1.0, y + 1.0, 0.0],
            [x, y + 1.0, 0.0],
        ];
        // v runs down the image: the poster's top edge samples row 0.
        let uv = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
        meshes.push(
            json!({"primitives": [quad(&mut b, c, uv, [0.0, 0.0, 1.0], materials.len() - 1)]}),
        );
        nodes.push(json!({"name": format!("Poster-{k:02}"), "mesh": meshes.len() - 1}));
    }
    let tile = image::RgbaImage::from_fn(32, 32, |x, y| {
        image::Rgba([((x / 8 + y / 8) % 2 * 120 + 60) as u8, 90, 70, 255])
    });
    let v = b.view(&png_of(&tile), None);
    images.push(json!({"name": "floor.png", "bufferView": v, "mimeType": "image/png"}));
    textures.push(json!({"sampler": 1, "source": images.len() - 1}));
    materials.push(json!({"name": "Floor", "pbrMetallicRoughness": {
        "baseColorTexture": {"index": textures.len() - 1}, "metallicFactor": 0.0}}));
    let c = [
        [0.0, 0.0, 3.0],
        [5.0, 0.0, 3.0],
        [5.0, 0.0, 0.5],
        [0.0, 0.0, 0.5],
    ];
    let uv = [[0.0, 6.0], [6.0, 6.0], [6.0, 0.0], [0.0, 0.0]];
    meshes.push(json!({"primitives": [quad(&mut b, c, uv, [0.0, 1.0, 0.0], materials.len() - 1)]}));
    nodes.push(json!({"name": "Floor", "mesh": meshes.len() - 1}));
    b.finish(json!({
        "asset": {"version": "2.0", "generator": "bimtiles tests/textures.rs poster_wall"},
        "scene": 0, "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes, "meshes": meshes, "materials": materials, "textures": textures,
        "images": images,
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071},
                     {"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}],
    }))
}

/// Tiles whose GLB binds one image to two or more materials named `prefix…`: an atlas.
fn tiles_sharing_an_image(run: &Run, prefix: &str) -> usize {
    let mut n = 0;
    for t in &run.tiles {
        let Some(uri) = &t.uri else { continue };
        let json = glb_json(&content_bytes(&run.dir, uri));
        let mut per_image: BTreeMap<u64, usize> = BTreeMap::new();
        for m in json["materials"].as_array().into_iter().flatten() {
            let Some(tex) = m["pbrMetallicRoughness"]["baseColorTexture"]["index"].as_u64() else {
                continue;
            };
            if m["name"].as_str().is_some_and(|s| s.starts_with(prefix)) {
                *per_image
                    .entry(json["textures"][tex as usize]["source"].as_u64().unwrap())
                    .or_default() += 1;
            }
        }
        n += per_image.values().any(|&k| k >= 2) as usize;
    }
    n
}

#[test]
fn atlas_packs_a_poster_wall_and_keeps_its_colours() {
    let model = tmpdir("atlas-model").join("poster_wall.glb");
    std::fs::write(&model, poster_wall(16, 1)).unwrap();
    // For `make bench` (examples/bench_textures.rs): posters of 192-512 texels.
    std::fs::write(
        model.with_file_name("poster_wall_large.glb"),
        poster_wall(16, 4),
    )
    .unwrap();
    let budget = ["--max-tile-triangles", "8"];
    let (off, on) = run_atlas_off_on(&model, "atlas-posters", &budget);
    let a = &on.report["textures"]["atlas"];
    eprintln!("poster wall: atlas {a}");
    let atlases = a["atlases"].as_u64().unwrap();
    assert!(atlases > 0, "tiles pack their posters");
    assert!(a["images_packed"].as_u64().unwrap() >= 2 * atlases);
    let saved = atlases * bimtiles::texture::atlas::ATLAS_BYTES_PER_SAVED_REQUEST;
    assert!(a["bytes_after"].as_u64().unwrap() <= a["bytes_before"].as_u64().unwrap() + saved);
    assert_eq!(off.report["textures"]["atlas"]["atlases"], 0);
    // Used where it should: every atlas binds two or more posters' materials to one image...
    assert_eq!(tiles_sharing_an_image(&on, "Poster") as u64, atlases);
    assert_eq!(tiles_sharing_an_image(&off, "Poster"), 0);
    // ...and never the tiling floor.
    for t in &on.tiles {
        let Some(uri) = &t.uri else { continue };
        let json = glb_json(&content_bytes(&on.dir, uri));
        let source = |m: &Value| {
            let tex = m["pbrMetallicRoughness"]["baseColorTexture"]["index"].as_u64()?;
            json["textures"][tex as usize]["source"].as_u64()
        };
        let mats = json["materials"].as_array().cloned().unwrap_or_default();
        if let Some(floor) = mats.iter().find(|m| m["name"] == "Floor") {
            for m in mats.iter().filter(|m| m["name"] != "Floor") {
                assert_ne!(
                    source(m),
                    source(floor),
                    "{uri}: the repeated floor texture is packed"
                );
            }
        }
    }
    let (samples, differ) = same_colours(&off, &on, Tiles::All);
    eprintln!("poster wall: {samples} UV samples show the same colour with and without the atlas ({differ} primitives sample an atlas)");
    assert!(differ >= 2 * atlases as usize && samples > 0);
    check_shared_files(&on);
    gltf_validator(&on.dir);
    // Embedded, and Draco-compressed (UV bits follow the atlas): valid too.
    for (name, extra) in [
        ("embed", &["--embed-textures"][..]),
        ("draco", &["--compression", "draco"][..]),
    ] {
        let dir = tmpdir(&format!("atlas-posters-{name}")).join("tiles");
        let mut args = budget.to_vec();
        args.extend(["--texture-atlas", "on"]);
        args.extend(extra);
        let r = convert(&model, &dir, &args);
        assert_eq!(r["textures"]["atlas"]["atlases"], atlases, "{name}");
        gltf_validator(&dir);
    }
}

/// A sharded build (plan / build-job in reverse order / merge) of the poster wall with the atlas
/// writes the tiles, texture files and tileset.json of `convert`, byte for byte: atlases depend
/// on the tile's content only, not on which process or thread wrote it.
#[test]
fn atlas_sharded_build_is_byte_identical() {
    let model = tmpdir("atlas-shard-model").join("poster_wall.glb");
    std::fs::write(&model, poster_wall(16, 1)).unwrap();
    let extra = ["--max-tile-triangles", "8", "--texture-atlas", "on"];
    let whole = run(&model, "atlas-shard-convert", &extra);
    assert!(
        whole.report["textures"]["atlas"]["atlases"]
            .as_u64()
            .unwrap()
            > 0
    );
    let dir = tmpdir("atlas-shard-jobs").join("tiles");
    let d = dir.to_str().unwrap();
    let ok = |args: &[&str]| {
        let o = crate::common::run(args);
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    let mut plan = vec![
        "plan",
        model.to_str().unwrap(),
        "--out",
        d,
        "--jobs",
        "3",
        "--quiet",
    ];
    plan.extend_from_slice(&extra);
    plan.extend_from_slice(&["--compression", "none"]);
    ok(&plan);
    for k in ["2", "1", "0"] {
        ok(&["build-job", d, "--job", k, "--quiet"]);
    }
    ok(&["merge", d, "--quiet"]);
    let (_, tiles) = decode_tileset(&dir);
    let sharded = Run {
        dir: dir.clone(),
        report: Value::Null,
        has_child: vec![false; tiles.len()],
        tiles,
    };
    assert_same_tiles(&whole, &sharded);
    assert!(
        std::fs::read(whole.dir.join("tileset.json")).unwrap()
            == std::fs::read(dir.join("tileset.json")).unwrap()
    );
}

/// Mean RGB (0-255) of each input image of a GLB, decoded with the `image` crate.
fn input_image_means(model: &Path) -> Vec<[f64; 3]> {
    input_images(model)
        .iter()
        .map(|bytes| {
            let img = image::load_from_memory(bytes).unwrap().to_rgb8();
            let n = (img.width() * img.height()) as f64;
            let mut sum = [0.0; 3];
            for p in img.pixels() {
                for c in 0..3 {
                    sum[c] += p[c] as f64;
                }
            }
            sum.map(|s| s / n)
        })
        .collect()
}

/// `--texture-format ktx2` on LoD3_Railway (also the KTX2 tileset of the browser test,
/// `target/test-out/ktx2-LoD3_Railway`): every texture is a KHR_texture_basisu source, required,
/// with no PNG/JPEG left; gltf-validator finds no error; npm ktx-parse and the Basis transcoder
/// CesiumJS ships (tools/check_ktx2.mjs) read and decode every level of every KTX2 file, sized in
/// multiples of 4 with the full mip chain, and each decodes to the mean colour of an input image
/// (crop off: levels are averages of the whole image).
#[test]
fn lod3_railway_ktx2_textures_decode_with_an_independent_reader() {
    let Some(model) = shared_file("LoD3_Railway.glb") else {
        return;
    };
    let run = run(
        &model,
        "ktx2-LoD3_Railway",
        &[
            "--texture-format",
            "ktx2",
            "--texture-crop",
            "off",
            "--max-tile-triangles",
            "3000",
        ],
    );
    let mut textured_tiles = 0;
    for t in &run.tiles {
        let Some(uri) = &t.uri else { continue };
        let json = glb_json(&content_bytes(&run.dir, uri));
        let Some(textures) = json["textures"].as_array() else {
            continue;
        };
        textured_tiles += 1;
        for key in ["extensionsUsed", "extensionsRequired"] {
            let list = json[key].as_array().unwrap();
            assert!(list.contains(&"KHR_texture_basisu".into()), "{uri}: {key}");
        }
        for tex in textures {
            assert!(tex.get("source").is_none(), "{uri}: no fallback source");
            let source = tex["extensions"]["KHR_texture_basisu"]["source"]
                .as_u64()
                .unwrap();
            assert_eq!(
                json["images"][source as usize]["mimeType"], "image/ktx2",
                "{uri}"
            );
        }
    }
    assert!(textured_tiles > 0);
    gltf_validator(&run.dir);

    if !repo().join("tools/node_modules/ktx-parse").is_dir() {
        assert!(
            !tools_required(),
            "ktx-parse is not installed (run `make test`)"
        );
        eprintln!("SKIPPED KTX2 decoding: tools/node_modules missing (run `make test`)");
        return;
    }
    let o = std::process::Command::new("node")
        .arg(repo().join("tools/check_ktx2.mjs"))
        .arg(&run.dir)
        .output()
        .expect("run node");
    let v: Value = serde_json::from_slice(&o.stdout)
        .unwrap_or_else(|e| panic!("check_ktx2: {e}: {}", String::from_utf8_lossy(&o.stderr)));
    assert!(o.status.success(), "check_ktx2 errors: {}", v["errors"]);
    let means = input_image_means(&model);
    let files = v["files"].as_array().unwrap();
    assert!(files.len() >= means.len() / 2, "{} KTX2 files", files.len());
    for f in files {
        let (w, h) = (f["width"].as_u64().unwrap(), f["height"].as_u64().unwrap());
        assert_eq!(
            f["levels"].as_u64().unwrap(),
            64 - w.max(h).leading_zeros() as u64,
            "{f}"
        );
        assert_eq!(
            (f["codec"].as_str(), f["srgb"].as_bool()),
            (Some("etc1s"), Some(true))
        );
        let mean: Vec<f64> = f["meanRgb"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        let nearest = means
            .iter()
            .map(|m| (0..3).map(|c| (m[c] - mean[c]).abs()).fold(0.0, f64::max))
            .fold(f64::INFINITY, f64::min);
        assert!(
            nearest <= 8.0,
            "{}: mean {mean:?} is {nearest:.1} from every input image",
            f["name"]
        );
    }
}
