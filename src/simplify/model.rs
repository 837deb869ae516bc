//! Whole-model simplification (the `bimtiles simplify` command, for comparing simplifiers): all
//! components merged in the scene frame into one mesh whose vertex groups are the materials, so
//! one global queue takes the cheapest collapses anywhere in the model and no collapse crosses a
//! material boundary; the result is one component with one primitive per material.

use super::{simplify, MeshInput, SimplifyError, SimplifyOptions};
use crate::scene::{Component, ElementInfo, Mesh, MeshId, Primitive, Scene};
use glam::{DMat4, DVec3};

/// A simplified model: one component at `center`, in a scene of its own.
pub struct SimplifiedModel {
    pub scene: Scene,
    /// Where the merged mesh's local frame sits in the scene frame.
    pub center: DVec3,
    /// The simplification error (metres; measured Hausdorff distance with the simplifier's
    /// safety factor).
    pub error_m: f64,
}

/// Simplifies every component of `scene` as one mesh (see the module doc).
pub fn simplify_scene(
    scene: &Scene,
    opts: &SimplifyOptions,
) -> Result<SimplifiedModel, SimplifyError> {
    let center = scene.bounds().center();
    let all_have = |f: &dyn Fn(&Primitive) -> bool| {
        scene
            .components
            .iter()
            .all(|c| scene.mesh(c.mesh).primitives.iter().all(f))
    };
    let (with_n, with_uv, with_c) = (
        all_have(&|p| p.normals.is_some()),
        all_have(&|p| p.uvs.is_some()),
        all_have(&|p| p.colors.is_some()),
    );
    let (mut pos, mut nrm, mut uv, mut col, mut grp, mut idx) = (
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
    );
    for c in &scene.components {
        let nm = c.normal_matrix();
        let flip = c.mirrors();
        for p in &scene.mesh(c.mesh).primitives {
            let base = pos.len() as u32;
            let g = p.material.map_or(u32::MAX, |m| m.0);
            for v in &p.positions {
                let w = c
                    .world
                    .transform_point3(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
                    - center;
                pos.push([w.x as f32, w.y as f32, w.z as f32]);
                grp.push(g);
            }
            if let (true, Some(ns)) = (with_n, &p.normals) {
                nrm.extend(ns.iter().map(|n| {
                    let w = (nm * DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64))
                        .normalize_or(DVec3::Z);
                    [w.x as f32, w.y as f32, w.z as f32]
                }));
            }
            if let (true, Some(u)) = (with_uv, &p.uvs) {
                uv.extend_from_slice(u);
            }
            if let (true, Some(k)) = (with_c, &p.colors) {
                col.extend_from_slice(k);
            }
            for t in p.indices.chunks_exact(3) {
                let t = if flip {
                    [t[0], t[2], t[1]]
                } else {
                    [t[0], t[1], t[2]]
                };
                idx.extend(t.iter().map(|i| base + i));
            }
        }
    }
    let mesh_in = MeshInput {
        positions: &pos,
        normals: with_n.then_some(&nrm[..]),
        uvs: with_uv.then_some(&uv[..]),
        colors: with_c.then_some(&col[..]),
        groups: Some(&grp),
        locked: None,
        indices: &idx,
    };
    let r = simplify(&mesh_in, opts)?;
    // One primitive per material (vertex group), in the scene frame around `center`.
    let mut out = Scene {
        sources: scene.sources.clone(),
        materials: scene.materials.clone(),
        images: scene.images.clone(),
        ..Default::default()
    };
    let mut by_group: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
    for t in r.indices.chunks_exact(3) {
        by_group
            .entry(r.groups[t[0] as usize])
            .or_default()
            .extend_from_slice(t);
    }
    let mut prims = Vec::new();
    for (g, tris) in by_group {
        let mut used: Vec<u32> = tris.clone();
        used.sort_unstable();
        used.dedup();
        let remap = |i: &u32| used.binary_search(i).expect("used vertex") as u32;
        prims.push(Primitive {
            material: (g != u32::MAX).then_some(crate::scene::MaterialId(g)),
            positions: used.iter().map(|&v| r.positions[v as usize]).collect(),
            normals: r
                .normals
                .as_ref()
                .map(|n| used.iter().map(|&v| n[v as usize]).collect()),
            uvs: r
                .uvs
                .as_ref()
                .map(|u| used.iter().map(|&v| u[v as usize]).collect()),
            colors: r
                .colors
                .as_ref()
                .map(|c| used.iter().map(|&v| c[v as usize]).collect()),
            indices: tris.iter().map(remap).collect(),
        });
    }
    out.meshes.push(Mesh {
        name: Some("simplified".into()),
        primitives: prims,
        local_bounds: None,
    });
    out.push_component(
        Component::new(MeshId(0), DMat4::from_translation(center)),
        &ElementInfo {
            name: Some("simplified".into()),
            ..ElementInfo::keyed("simplified")
        },
    );
    out.finish();
    Ok(SimplifiedModel {
        scene: out,
        center,
        error_m: r.error_m,
    })
}
