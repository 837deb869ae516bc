//! The geometry of one tile: its components merged per material into one primitive each, with a
//! feature ID per vertex naming the component it came from.
//!
//! This is what the HLOD builder simplifies and what the GLB encoder writes. Positions are f32 in
//! the scene frame (z-up, metres) relative to the tile's `center` (f64), so precision is bounded by
//! the tile's size, not the model's; turning to glTF's y-up is the encoder's business. Identity
//! survives merging and simplification: `feature_ids[v]` indexes [`TileContent::features`].

use crate::partition::ContentItem;
use crate::scene::{Aabb, Component, ComponentId, MaterialId, Primitive, Scene};
use glam::DVec3;
use std::collections::BTreeMap;

/// One material's merged geometry. `normals` always has one entry per vertex; `uvs` and `colors`
/// have one per vertex or none.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContentPrimitive {
    pub material: Option<MaterialId>,
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub colors: Vec<[f32; 4]>,
    /// Index into [`TileContent::features`], per vertex (all vertices of a triangle agree).
    pub feature_ids: Vec<u32>,
    pub indices: Vec<u32>,
}

impl ContentPrimitive {
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }
}

/// A tile's content, ready to simplify or encode.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TileContent {
    /// Origin of the positions, scene frame.
    pub center: DVec3,
    /// The component of each feature ID.
    pub features: Vec<ComponentId>,
    /// One per material, ordered by material id (untextured/unset last).
    pub primitives: Vec<ContentPrimitive>,
}

fn material_key(m: Option<MaterialId>) -> u32 {
    m.map_or(u32::MAX, |m| m.0)
}

impl TileContent {
    pub fn triangle_count(&self) -> usize {
        self.primitives.iter().map(|p| p.triangle_count()).sum()
    }

    pub fn vertex_count(&self) -> usize {
        self.primitives.iter().map(|p| p.positions.len()).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.triangle_count() == 0
    }

    /// Box of the vertices, scene frame.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for p in &self.primitives {
            for v in &p.positions {
                b.extend(self.center + DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64));
            }
        }
        b
    }

    /// Merges `content` of `scene` (whole components or parts of cut ones) around `center`.
    /// Features are numbered in content order (parts of one component share one).
    pub fn gather(scene: &Scene, content: &[ContentItem], center: DVec3) -> TileContent {
        let mut features: Vec<ComponentId> = Vec::new();
        type Part<'a> = (u32, &'a Component, &'a Primitive, Option<Vec<u32>>);
        let mut groups: BTreeMap<u32, Vec<Part>> = BTreeMap::new();
        for item in content {
            if features.last() != Some(&item.component) {
                features.push(item.component);
            }
            let fid = (features.len() - 1) as u32;
            let comp = scene.component(item.component);
            for (pi, prim) in scene.mesh(comp.mesh).primitives.iter().enumerate() {
                let subset: Option<Vec<u32>> = item.triangles.as_ref().map(|tris| {
                    let lo = tris.partition_point(|t| t.0 < pi as u32);
                    let hi = tris.partition_point(|t| t.0 <= pi as u32);
                    tris[lo..hi].iter().map(|t| t.1).collect()
                });
                if subset.as_ref().is_some_and(|s| s.is_empty()) {
                    continue;
                }
                groups
                    .entry(material_key(prim.material))
                    .or_default()
                    .push((fid, comp, prim, subset));
            }
        }
        let mut primitives = Vec::new();
        for (key, parts) in &groups {
            let material = (*key != u32::MAX).then_some(MaterialId(*key));
            let textured = material
                .map(|m| scene.materials[m.index()].base_color_texture.is_some())
                .unwrap_or(false);
            let with_uv = textured || parts.iter().any(|(_, _, p, _)| p.uvs.is_some());
            let with_color = parts.iter().any(|(_, _, p, _)| p.colors.is_some());
            let mut out = ContentPrimitive {
                material,
                ..Default::default()
            };
            for (fid, comp, prim, subset) in parts {
                append_primitive(
                    &mut out,
                    comp,
                    prim,
                    subset.as_deref(),
                    *fid,
                    center,
                    with_uv,
                    with_color,
                );
            }
            if !out.indices.is_empty() {
                primitives.push(out);
            }
        }
        TileContent {
            center,
            features,
            primitives,
        }
    }

    /// Concatenates several contents (e.g. the children of an HLOD tile) around a new `center`:
    /// positions are re-anchored in f64, primitives of one material merged, features renumbered
    /// (a component present in several parts keeps one feature).
    pub fn merge(parts: &[&TileContent], center: DVec3) -> TileContent {
        let mut features: Vec<ComponentId> = parts
            .iter()
            .flat_map(|p| p.features.iter().copied())
            .collect();
        features.sort_unstable();
        features.dedup();
        let mut by_material: BTreeMap<u32, ContentPrimitive> = BTreeMap::new();
        // Whether any part of a material has UVs / colours decides for the merged primitive.
        let mut flags: BTreeMap<u32, (bool, bool)> = BTreeMap::new();
        for part in parts {
            for p in &part.primitives {
                let f = flags.entry(material_key(p.material)).or_default();
                f.0 |= !p.uvs.is_empty();
                f.1 |= !p.colors.is_empty();
            }
        }
        for part in parts {
            let shift = part.center - center;
            let remap: Vec<u32> = part
                .features
                .iter()
                .map(|c| features.binary_search(c).expect("merged feature") as u32)
                .collect();
            for p in &part.primitives {
                let key = material_key(p.material);
                let (with_uv, with_color) = flags[&key];
                let out = by_material.entry(key).or_insert_with(|| ContentPrimitive {
                    material: p.material,
                    ..Default::default()
                });
                let base = out.positions.len() as u32;
                out.positions.extend(p.positions.iter().map(|v| {
                    let w = DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64) + shift;
                    [w.x as f32, w.y as f32, w.z as f32]
                }));
                out.normals.extend_from_slice(&p.normals);
                if with_uv {
                    if p.uvs.is_empty() {
                        out.uvs.resize(out.positions.len(), [0.0; 2]);
                    } else {
                        out.uvs.extend_from_slice(&p.uvs);
                    }
                }
                if with_color {
                    if p.colors.is_empty() {
                        out.colors.resize(out.positions.len(), [1.0; 4]);
                    } else {
                        out.colors.extend_from_slice(&p.colors);
                    }
                }
                out.feature_ids
                    .extend(p.feature_ids.iter().map(|&f| remap[f as usize]));
                out.indices.extend(p.indices.iter().map(|&i| base + i));
            }
        }
        TileContent {
            center,
            features,
            primitives: by_material.into_values().collect(),
        }
    }

    /// Drops features no vertex refers to any more (after simplification removed them) and
    /// renumbers the rest in order.
    pub fn compact_features(&mut self) {
        let mut used = vec![false; self.features.len()];
        for p in &self.primitives {
            for t in p.indices.iter() {
                used[p.feature_ids[*t as usize] as usize] = true;
            }
        }
        let mut remap = vec![u32::MAX; self.features.len()];
        let mut kept = Vec::new();
        for (i, &c) in self.features.iter().enumerate() {
            if used[i] {
                remap[i] = kept.len() as u32;
                kept.push(c);
            }
        }
        for p in &mut self.primitives {
            for f in &mut p.feature_ids {
                // Unreferenced vertices keep a valid (if arbitrary) feature.
                *f = if remap[*f as usize] == u32::MAX {
                    0
                } else {
                    remap[*f as usize]
                };
            }
        }
        self.primitives.retain(|p| !p.indices.is_empty());
        self.features = kept;
    }
}

/// Appends a primitive (or, for a part of a cut mesh, only the triangles `subset`, re-indexed
/// compactly over the vertices they use) to a merged stream, transformed to the tile's frame.
#[allow(clippy::too_many_arguments)]
fn append_primitive(
    out: &mut ContentPrimitive,
    comp: &Component,
    prim: &Primitive,
    subset: Option<&[u32]>,
    feature_id: u32,
    center: DVec3,
    with_uv: bool,
    with_color: bool,
) {
    // `verts`: source vertex of each new vertex; `tris`: triangles in new indices.
    let (verts, tris): (Vec<u32>, Vec<u32>) = match subset {
        None => (
            (0..prim.positions.len() as u32).collect(),
            prim.indices.clone(),
        ),
        Some(sel) => {
            let corners = |t: &u32| prim.indices[*t as usize * 3..*t as usize * 3 + 3].iter();
            let mut used: Vec<u32> = sel.iter().flat_map(corners).copied().collect();
            used.sort_unstable();
            used.dedup();
            let tris = sel
                .iter()
                .flat_map(corners)
                .map(|i| {
                    used.binary_search(i)
                        .expect("vertex of a selected triangle") as u32
                })
                .collect();
            (used, tris)
        }
    };
    let base = out.positions.len() as u32;
    let m = comp.world;
    let normal_matrix = comp.normal_matrix();
    let mirrored = comp.mirrors();
    for &v in &verts {
        let p = prim.positions[v as usize];
        let l = m.transform_point3(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)) - center;
        out.positions.push([l.x as f32, l.y as f32, l.z as f32]);
    }
    // Triangles with the winding the viewer needs (a mirroring transform flips it).
    let oriented = |t: &[u32]| {
        if mirrored {
            [t[0], t[2], t[1]]
        } else {
            [t[0], t[1], t[2]]
        }
    };
    match &prim.normals {
        Some(ns) => {
            for &v in &verts {
                let n = ns[v as usize];
                let w = (normal_matrix * DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64))
                    .normalize_or(DVec3::Z);
                out.normals.push([w.x as f32, w.y as f32, w.z as f32]);
            }
        }
        None => {
            // Area-weighted vertex normals from the output triangles.
            let mut acc = vec![DVec3::ZERO; verts.len()];
            for t in tris.chunks_exact(3) {
                let t = oriented(t);
                let v = |i: u32| {
                    let q = out.positions[(base + i) as usize];
                    DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64)
                };
                let n = (v(t[1]) - v(t[0])).cross(v(t[2]) - v(t[0]));
                for &i in &t {
                    acc[i as usize] += n;
                }
            }
            out.normals.extend(acc.into_iter().map(|a| {
                let n = a.normalize_or(DVec3::Z);
                [n.x as f32, n.y as f32, n.z as f32]
            }));
        }
    }
    if with_uv {
        match &prim.uvs {
            Some(u) => out.uvs.extend(verts.iter().map(|&v| u[v as usize])),
            None => out.uvs.resize(out.positions.len(), [0.0; 2]),
        }
    }
    if with_color {
        match &prim.colors {
            Some(c) => out.colors.extend(verts.iter().map(|&v| c[v as usize])),
            None => out.colors.resize(out.positions.len(), [1.0; 4]),
        }
    }
    out.feature_ids.resize(out.positions.len(), feature_id);
    for t in tris.chunks_exact(3) {
        out.indices.extend(oriented(t).iter().map(|&i| base + i));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{ElementInfo, Mesh, MeshId};
    use glam::DMat4;

    fn one_triangle_scene() -> Scene {
        let mut s = Scene::default();
        s.meshes.push(Mesh {
            name: None,
            primitives: vec![Primitive {
                positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                indices: vec![0, 1, 2],
                ..Default::default()
            }],
            local_bounds: None,
        });
        for (i, x) in [0.0, 10.0].into_iter().enumerate() {
            s.push_component(
                Component::new(
                    format!("t{i}"),
                    MeshId(0),
                    DMat4::from_translation(DVec3::new(x, 0.0, 0.0)),
                ),
                ElementInfo::default(),
            );
        }
        s.finish();
        s
    }

    #[test]
    fn gather_and_merge_keep_positions_and_identity() {
        let s = one_triangle_scene();
        let item = |c: u32| ContentItem {
            component: ComponentId(c),
            triangles: None,
        };
        let a = TileContent::gather(&s, &[item(0)], DVec3::new(0.5, 0.5, 0.0));
        let b = TileContent::gather(&s, &[item(1)], DVec3::new(10.5, 0.5, 0.0));
        // Computed normals point up (+z) for a counter-clockwise triangle in the xy plane.
        assert_eq!(a.primitives[0].normals[0], [0.0, 0.0, 1.0]);
        let m = TileContent::merge(&[&b, &a], DVec3::new(5.0, 0.0, 0.0));
        assert_eq!(m.features, vec![ComponentId(0), ComponentId(1)]);
        assert_eq!(m.triangle_count(), 2);
        let bounds = m.bounds();
        assert!((bounds.min - DVec3::ZERO).length() < 1e-6);
        assert!((bounds.max - DVec3::new(11.0, 1.0, 0.0)).length() < 1e-6);
        // b came first: its vertices carry feature 1 (component 1) after renumbering.
        assert_eq!(m.primitives[0].feature_ids[0], 1);
        assert_eq!(m.primitives[0].feature_ids[3], 0);
    }

    #[test]
    fn compact_features_drops_unused() {
        let s = one_triangle_scene();
        let items = [0, 1].map(|c| ContentItem {
            component: ComponentId(c),
            triangles: None,
        });
        let mut c = TileContent::gather(&s, &items, DVec3::ZERO);
        // Remove the first component's triangle.
        c.primitives[0].indices.drain(0..3);
        c.compact_features();
        assert_eq!(c.features, vec![ComponentId(1)]);
        assert!(c.primitives[0]
            .indices
            .iter()
            .all(|&i| c.primitives[0].feature_ids[i as usize] == 0));
    }
}
