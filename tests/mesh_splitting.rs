//! Large meshes are cut across tiles (whole triangles, by centroid): the one-node textured railway
//! scene, merged-by-material exports, and a million-triangle surface.

use crate::common::height_field::height_field_glb;
use crate::common::world::WorldMatrix;
use crate::common::*;
use glam::{DMat4, DVec3};
use std::collections::HashMap;
use std::path::Path;

/// Every vertex of every triangle primitive of a GLB in the scene frame (z-up), with its UV and
/// its base-colour image (decoded), read with the gltf crate (not our reader).
struct TexturedVertex {
    pos: DVec3,
    color: Option<[u8; 4]>,
}

fn textured_vertices(
    glb: &[u8],
    folder: &Path,
    offset: DVec3,
) -> (Vec<TexturedVertex>, usize, f64) {
    let g = gltf::Gltf::from_slice_without_validation(&plain_glb(glb.to_vec())).unwrap();
    let blob = g.blob.as_deref().unwrap();
    let images: Vec<image::RgbaImage> = g
        .document
        .images()
        .map(|im| match im.source() {
            gltf::image::Source::View { view, .. } => {
                let b = &blob[view.offset()..view.offset() + view.length()];
                image::load_from_memory(b).unwrap().to_rgba8()
            }
            // Shared texture files, relative to the tile's `folder`.
            gltf::image::Source::Uri { uri, .. } => {
                let b = std::fs::read(folder.join(uri)).unwrap();
                image::load_from_memory(&b).unwrap().to_rgba8()
            }
        })
        .collect();
    let mut out = Vec::new();
    let (mut tris, mut area) = (0usize, 0.0f64);
    for node in g.document.nodes() {
        let Some(mesh) = node.mesh() else { continue };
        let m = Y_UP_TO_Z_UP * DMat4::from_gltf(node.transform().matrix());
        for p in mesh.primitives() {
            let r = p.reader(|_| Some(blob));
            let pos: Vec<DVec3> = r
                .read_positions()
                .unwrap()
                .map(|v| {
                    m.transform_point3(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)) + offset
                })
                .collect();
            let uvs: Option<Vec<[f32; 2]>> = r.read_tex_coords(0).map(|t| t.into_f32().collect());
            let img = p
                .material()
                .pbr_metallic_roughness()
                .base_color_texture()
                .map(|t| t.texture().source().index());
            let idx: Vec<u32> = r.read_indices().unwrap().into_u32().collect();
            for t in idx.chunks_exact(3) {
                let v = |i: u32| pos[i as usize];
                area += (v(t[1]) - v(t[0])).cross(v(t[2]) - v(t[0])).length() * 0.5;
            }
            tris += idx.len() / 3;
            for (i, p) in pos.iter().enumerate() {
                let color = match (&uvs, img) {
                    (Some(uv), Some(ii)) => {
                        let im = &images[ii];
                        // Repeat wrapping, nearest texel.
                        let (u, v) = (uv[i][0].rem_euclid(1.0), uv[i][1].rem_euclid(1.0));
                        let x = ((u * im.width() as f32) as u32).min(im.width() - 1);
                        let y = ((v * im.height() as f32) as u32).min(im.height() - 1);
                        Some(im.get_pixel(x, y).0)
                    }
                    _ => None,
                };
                out.push(TexturedVertex { pos: *p, color });
            }
        }
    }
    (out, tris, area)
}

fn key(p: DVec3) -> (i64, i64, i64) {
    (
        (p.x * 1e3).round() as i64,
        (p.y * 1e3).round() as i64,
        (p.z * 1e3).round() as i64,
    )
}

#[test]
fn railway_scene_is_cut_into_tiles_with_textures_intact() {
    let Some(input) = shared_file("LoD3_Railway.glb") else {
        return;
    };
    let out = tmpdir("split-railway").join("tiles");
    let report = convert(
        &input,
        &out,
        // The cut itself, without HLOD levels (tests/hlod.rs covers those).
        &[
            "--max-tile-triangles",
            "2000",
            "--compression",
            "none",
            "--lod",
            "none",
        ],
    );
    assert_eq!(report["input"]["triangles"], 26797);
    let tiles = check_tileset(&out, 26797);
    let with_content = tiles.iter().filter(|t| t.uri.is_some()).count();
    assert!(with_content >= 8, "{with_content} tiles with content");
    for t in &tiles {
        assert!(
            t.triangles <= 2000,
            "{:?} holds {} triangles",
            t.name,
            t.triangles
        );
    }
    // Same triangles (count and total area) and the same texture colour at every vertex.
    let (before, in_tris, in_area) = textured_vertices(
        &std::fs::read(&input).unwrap(),
        input.parent().unwrap(),
        DVec3::ZERO,
    );
    let mut colors: HashMap<(i64, i64, i64), Vec<[u8; 4]>> = HashMap::new();
    for v in &before {
        if let Some(c) = v.color {
            colors.entry(key(v.pos)).or_default().push(c);
        }
    }
    let ts: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("tileset.json")).unwrap()).unwrap();
    let a = &ts["asset"]["extras"]["bimtiles"]["anchor_m"];
    let anchor = DVec3::new(
        a[0].as_f64().unwrap(),
        a[1].as_f64().unwrap(),
        a[2].as_f64().unwrap(),
    );
    let (mut out_tris, mut out_area, mut checked, mut textured) = (0, 0.0, 0usize, 0usize);
    for uri in tiles.iter().filter_map(|t| t.uri.as_deref()) {
        // Texture files are relative to the tile (an inlined root names none).
        let folder = out.join(uri).parent().unwrap().to_path_buf();
        let (after, n, area) = textured_vertices(&content_bytes(&out, uri), &folder, anchor);
        out_tris += n;
        out_area += area;
        for v in after {
            if let Some(c) = v.color {
                textured += 1;
                let Some(cands) = colors.get(&key(v.pos)) else {
                    continue;
                };
                assert!(cands.contains(&c), "texture colour changed at {}", v.pos);
                checked += 1;
            }
        }
    }
    assert_eq!(in_tris, out_tris);
    assert!(
        (in_area - out_area).abs() < 1e-6 * in_area,
        "area {in_area} vs {out_area}"
    );
    assert!(
        textured > 30_000 && checked * 100 >= textured * 99,
        "checked {checked} of {textured} textured vertices"
    );
    gltf_validator(&out);
    eprintln!(
        "railway: {} tiles ({} with content), depth {}, {} bytes",
        report["output"]["tiles"],
        with_content,
        report["output"]["max_depth"],
        report["output"]["bytes"]
    );
}

/// Bakes every component of `input` into one mesh per material (world coordinates, y-up), as
/// exporters that merge by material do; returns a GLB.
fn merge_by_material(input: &Path) -> Vec<u8> {
    let bytes = std::fs::read(input).unwrap();
    let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
    let blob = g.blob.as_deref().unwrap();
    // Positions, normals, indices per material.
    type Merged = (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<u32>);
    let mut per_material: std::collections::BTreeMap<usize, Merged> = Default::default();
    let roots = g.document.default_scene().unwrap().nodes();
    for (node, m) in world_nodes(roots, glam::Mat4::IDENTITY) {
        let Some(mesh) = node.mesh() else { continue };
        for p in mesh.primitives() {
            let r = p.reader(|_| Some(blob));
            let e = per_material
                .entry(p.material().index().unwrap_or(usize::MAX))
                .or_default();
            let base = e.0.len() as u32;
            let pos: Vec<[f32; 3]> = r.read_positions().unwrap().collect();
            let nrm: Vec<[f32; 3]> =
                r.read_normals()
                    .map(|n| n.collect())
                    .unwrap_or(vec![[0.0, 1.0, 0.0]; pos.len()]);
            for (p, n) in pos.iter().zip(&nrm) {
                e.0.push(m.transform_point3(glam::Vec3::from(*p)).to_array());
                e.1.push(
                    m.transform_vector3(glam::Vec3::from(*n))
                        .normalize_or_zero()
                        .to_array(),
                );
            }
            e.2.extend(r.read_indices().unwrap().into_u32().map(|i| i + base));
        }
    }
    let mut b = GlbBuilder::default();
    let (mut meshes, mut nodes, mut materials) = (vec![], vec![], vec![]);
    for (mat, (pos, nrm, idx)) in &per_material {
        let pa = b.positions(pos, None);
        let na = b.accessor(
            &f32_bytes(nrm),
            None,
            serde_json::json!({"componentType": 5126, "count": nrm.len(), "type": "VEC3"}),
        );
        let ia = b.indices(idx, None);
        let color = g
            .document
            .materials()
            .nth(*mat)
            .map(|m| m.pbr_metallic_roughness().base_color_factor())
            .unwrap_or([0.8; 4]);
        materials.push(serde_json::json!({"pbrMetallicRoughness": {"baseColorFactor": color}}));
        meshes.push(serde_json::json!({"primitives": [{"attributes": {"POSITION": pa, "NORMAL": na}, "indices": ia, "material": materials.len() - 1}]}));
        nodes
            .push(serde_json::json!({"mesh": meshes.len() - 1, "name": format!("material-{mat}")}));
    }
    b.finish(serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes, "meshes": meshes, "materials": materials,
    }))
}

#[test]
fn merged_by_material_exports_tile_like_per_element_ones() {
    for name in ["duplex.glb", "ISSUE_021_Mini_Project.glb"] {
        let Some(model) = shared_file(name) else {
            continue;
        };
        let d = tmpdir(&format!("split-merged-{name}"));
        let merged = d.join("merged.glb");
        std::fs::write(&merged, merge_by_material(&model)).unwrap();
        let budget = "5000";
        let per_element = convert(
            &model,
            &d.join("per-element"),
            &["--max-tile-triangles", budget],
        );
        let by_material = convert(
            &merged,
            &d.join("merged-out"),
            &["--max-tile-triangles", budget],
        );
        let tris = per_element["input"]["triangles"].as_u64().unwrap();
        assert_eq!(by_material["input"]["triangles"].as_u64().unwrap(), tris);
        assert!(
            by_material["input"]["components"].as_u64().unwrap() < 25,
            "merged into a few meshes"
        );
        let tiles = check_tileset(&d.join("merged-out"), tris as usize);
        for t in &tiles {
            assert!(
                t.triangles <= 5000,
                "{:?}: {} triangles over the budget",
                t.name,
                t.triangles
            );
        }
        let (n_e, n_m) = (
            per_element["output"]["tiles"].as_f64().unwrap(),
            by_material["output"]["tiles"].as_f64().unwrap(),
        );
        // Geometry bytes: the per-element output also carries one metadata row per element.
        let geometry = |r: &serde_json::Value| {
            r["output"]["bytes"].as_f64().unwrap() - r["output"]["metadata_bytes"].as_f64().unwrap()
        };
        let (b_e, b_m) = (geometry(&per_element), geometry(&by_material));
        eprintln!(
            "{name}: per element {n_e} tiles {b_e} B; merged by material {n_m} tiles {b_m} B"
        );
        assert!(
            n_m <= n_e * 3.0 && n_m * 3.0 >= n_e,
            "tile counts of the same order"
        );
        assert!(
            b_m <= b_e * 2.0 && b_m * 2.0 >= b_e,
            "bytes of the same order"
        );
        gltf_validator(&d.join("merged-out"));
    }
}

#[test]
fn a_million_triangle_surface_is_tiled_under_the_budget() {
    let d = tmpdir("split-surface");
    let input = d.join("terrain.glb");
    std::fs::write(&input, height_field_glb(708, 2000.0)).unwrap();
    let out = d.join("out");
    let report = convert(&input, &out, &["--max-tile-triangles", "40000"]);
    let tris = report["input"]["triangles"].as_u64().unwrap() as usize;
    assert_eq!(tris, 2 * 708 * 708);
    let tiles = check_tileset(&out, tris);
    assert!(tiles.iter().all(|t| t.triangles <= 40000));
    assert!(tiles.iter().filter(|t| t.uri.is_some()).count() >= 25);
    eprintln!(
        "surface: {} tiles, depth {}, {} bytes, {:.2} s, peak {} MB",
        report["output"]["tiles"],
        report["output"]["max_depth"],
        report["output"]["bytes"],
        report["timings_s"]["total"].as_f64().unwrap(),
        report["peak_memory_bytes"].as_u64().unwrap() / 1_000_000
    );
}
