//! The geometry of one tile: its components merged per material into one primitive each, with a
//! feature ID per vertex naming the component it came from.
//!
//! This is what the HLOD builder simplifies and what the GLB encoder writes. Positions are f32 in
//! the scene frame (z-up, metres) relative to the tile's `center` (f64), so precision is bounded by
//! the tile's size, not the model's; turning to glTF's y-up is the encoder's business. Identity
//! survives merging and simplification: `feature_ids[v]` indexes [`TileContent::features`].
//!
//! A shape that several whole components of the tile draw (one mesh, shared after dedup or by
//! glTF-level reuse) can instead be kept once, in its own frame, with a rigid placement per
//! component ([`InstancedShape`], written with `EXT_mesh_gpu_instancing`); [`TileContent::expand`]
//! turns instances back into merged geometry for stages that need one surface (HLOD).

use super::ContentItem;
use crate::scene::{Aabb, Component, ComponentId, MaterialId, Mesh, MeshId, Primitive, Scene};
use glam::{DMat3, DMat4, DVec3};
use std::collections::BTreeMap;
use std::sync::Arc;

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

/// One shape drawn by several components of a tile: its geometry once, and where each copy goes.
#[derive(Debug, Clone, PartialEq)]
pub struct InstancedShape {
    /// The scene mesh it comes from.
    pub mesh: MeshId,
    /// The shape per material, in its own frame (the mesh frame moved to the mesh's box centre, so
    /// f32 positions stay small); `feature_ids` are unused (all 0): identity is per instance.
    pub primitives: Vec<ContentPrimitive>,
    pub instances: Vec<ShapeInstance>,
}

/// One placed copy of an [`InstancedShape`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShapeInstance {
    /// Index into [`TileContent::features`].
    pub feature: u32,
    /// Shape frame → tile frame (scene axes, relative to [`TileContent::center`]): a rotation and
    /// translation, or a positive scale (never a mirror or a shear: those are baked instead).
    pub transform: DMat4,
}

impl InstancedShape {
    fn triangle_count(&self) -> usize {
        self.primitives
            .iter()
            .map(|p| p.triangle_count())
            .sum::<usize>()
            * self.instances.len()
    }
    fn vertex_count(&self) -> usize {
        self.primitives
            .iter()
            .map(|p| p.positions.len())
            .sum::<usize>()
            * self.instances.len()
    }
    /// Triangles stored once for all instances.
    pub fn stored_triangle_count(&self) -> usize {
        self.primitives.iter().map(|p| p.triangle_count()).sum()
    }
}

/// Untextured materials that differ only in base colour form one *appearance class*; each class
/// has a white twin material in the scene. A tile's primitives of one class can then be written as
/// one primitive with the base colours moved into `COLOR_0` (glTF multiplies the two, so what is
/// drawn is unchanged). Why: CesiumJS pays per primitive (a draw call, and with Draco a decode
/// task scheduled one per frame per worker), and BIM exports carry dozens of plain-coloured
/// materials per tile.
#[derive(Debug, Clone, Default)]
pub struct AppearanceClasses {
    /// Per scene material: the white twin of its class (`None`: textured, left alone).
    twin: Vec<Option<MaterialId>>,
}

impl AppearanceClasses {
    /// Finds the classes of `scene`'s untextured materials and appends one white twin per class
    /// to `scene.materials` (the existing ids do not change).
    pub fn add_to(scene: &mut Scene) -> AppearanceClasses {
        let key = |m: &crate::scene::Material| {
            let bits = |v: f32| v.to_bits();
            (
                m.alpha_mode,
                bits(m.alpha_cutoff),
                m.double_sided,
                bits(m.metallic),
                bits(m.roughness),
                m.emissive.map(bits),
            )
        };
        let mut classes: BTreeMap<_, MaterialId> = BTreeMap::new();
        let original = scene.materials.len();
        let mut twin = Vec::with_capacity(original);
        for i in 0..original {
            let m = scene.materials[i].clone();
            if m.base_color_texture.is_some() {
                twin.push(None);
                continue;
            }
            let id = *classes.entry(key(&m)).or_insert_with(|| {
                let white = crate::scene::Material {
                    name: Some(format!(
                        "bimtiles-vertex-colour-{}",
                        scene.materials.len() - original
                    )),
                    base_color: [1.0; 4],
                    ..m
                };
                scene.materials.push(white);
                MaterialId((scene.materials.len() - 1) as u32)
            });
            twin.push(Some(id));
        }
        AppearanceClasses { twin }
    }

    /// The appearance class of scene material `m` (`None`: textured, or not a scene material):
    /// its index among the classes and its white twin.
    pub fn class_of(&self, m: MaterialId) -> Option<(usize, MaterialId)> {
        let twin = self.twin.get(m.index()).copied().flatten()?;
        Some((twin.index() - self.twin.len(), twin))
    }

    /// `content` with the plain primitives of each appearance class merged into one, base colours
    /// moved into the vertex colours; `None` when no class has two primitives in this tile.
    /// Instanced shapes are left as they are (a shape is one mesh already).
    pub fn merge(&self, scene: &Scene, content: &TileContent) -> Option<TileContent> {
        let twin_of = |p: &ContentPrimitive| {
            p.material
                .and_then(|m| self.twin.get(m.index()).copied().flatten())
        };
        let mut per_class: BTreeMap<u32, usize> = BTreeMap::new();
        for p in &content.primitives {
            if let Some(t) = twin_of(p) {
                *per_class.entry(t.0).or_default() += 1;
            }
        }
        if per_class.values().all(|&n| n < 2) {
            return None;
        }
        let mut kept = Vec::new();
        let mut merged: BTreeMap<u32, ContentPrimitive> = BTreeMap::new();
        for p in &content.primitives {
            let Some(t) = twin_of(p).filter(|t| per_class[&t.0] >= 2) else {
                kept.push(p.clone());
                continue;
            };
            let base =
                scene.materials[p.material.expect("a twin has a material").index()].base_color;
            let out = merged.entry(t.0).or_insert_with(|| ContentPrimitive {
                material: Some(t),
                ..Default::default()
            });
            let first = out.positions.len() as u32;
            out.positions.extend_from_slice(&p.positions);
            out.normals.extend_from_slice(&p.normals);
            out.feature_ids.extend_from_slice(&p.feature_ids);
            match p.colors.is_empty() {
                true => out
                    .colors
                    .extend(std::iter::repeat_n(base, p.positions.len())),
                false => out.colors.extend(
                    p.colors
                        .iter()
                        .map(|c| std::array::from_fn(|k| c[k] * base[k])),
                ),
            }
            out.indices.extend(p.indices.iter().map(|i| i + first));
        }
        // Textured first (by material id), then the merged classes, then unset materials, as
        // `gather` orders them.
        let (unset, textured): (Vec<_>, Vec<_>) =
            kept.into_iter().partition(|p| p.material.is_none());
        let mut primitives = textured;
        primitives.extend(merged.into_values());
        primitives.extend(unset);
        Some(TileContent {
            center: content.center,
            features: content.features.clone(),
            primitives,
            instanced: content.instanced.clone(),
        })
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
    /// Shapes drawn several times, kept once each (empty unless gathered with instancing).
    pub instanced: Vec<InstancedShape>,
}

/// Smallest number of copies of a shape in one tile that are written as instances: below it the
/// per-instance node, accessors and draw call cost more than the geometry saved.
pub const MIN_INSTANCES_PER_SHAPE: usize = 2;

/// Whether a component's placement can be an instance transform (translation, rotation, positive
/// scale): mirrors and shears are baked.
fn placeable_as_instance(world: &DMat4) -> bool {
    DMat3::from_mat4(*world).determinant() > 0.0
        && crate::geometry::instance_trs(world).is_some_and(|(_, _, s)| s.min_element() > 0.0)
}

fn material_key(m: Option<MaterialId>) -> u32 {
    m.map_or(u32::MAX, |m| m.0)
}

impl TileContent {
    fn plain_triangle_count(&self) -> usize {
        self.primitives.iter().map(|p| p.triangle_count()).sum()
    }

    /// Triangles drawn (an instanced shape counts once per instance).
    pub fn triangle_count(&self) -> usize {
        let instanced: usize = self.instanced.iter().map(|s| s.triangle_count()).sum();
        self.plain_triangle_count() + instanced
    }

    /// Triangles stored (an instanced shape counts once).
    pub fn stored_triangle_count(&self) -> usize {
        let instanced: usize = self
            .instanced
            .iter()
            .map(|s| s.stored_triangle_count())
            .sum();
        self.plain_triangle_count() + instanced
    }

    /// Vertices drawn (an instanced shape counts once per instance).
    pub fn vertex_count(&self) -> usize {
        let plain: usize = self.primitives.iter().map(|p| p.positions.len()).sum();
        plain
            + self
                .instanced
                .iter()
                .map(|s| s.vertex_count())
                .sum::<usize>()
    }

    /// Components drawn through an instanced shape.
    pub fn instance_count(&self) -> usize {
        self.instanced.iter().map(|s| s.instances.len()).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.triangle_count() == 0
    }

    /// Box of the vertices (every instance placed), scene frame.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        let f64v = |v: &[f32; 3]| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
        for p in &self.primitives {
            for v in &p.positions {
                b.extend(self.center + f64v(v));
            }
        }
        for shape in &self.instanced {
            for inst in &shape.instances {
                for p in &shape.primitives {
                    for v in &p.positions {
                        b.extend(self.center + inst.transform.transform_point3(f64v(v)));
                    }
                }
            }
        }
        b
    }

    /// Like [`gather`](Self::gather), but whole components that share a mesh with at least
    /// `MIN_INSTANCES_PER_SHAPE - 1` other whole components of `content` become instances of one
    /// [`InstancedShape`] (when their placement is rigid, see `placeable_as_instance`), if that
    /// stores at least `min_saved_triangles` fewer triangles: a shape costs a node, a mesh,
    /// accessors and a draw call of its own, which small savings do not pay for.
    pub fn gather_instanced(
        scene: &Scene,
        content: &[ContentItem],
        center: DVec3,
        min_saved_triangles: usize,
    ) -> TileContent {
        let mut users: BTreeMap<MeshId, Vec<ComponentId>> = BTreeMap::new();
        for item in content.iter().filter(|i| i.triangles.is_none()) {
            let c = scene.component(item.component);
            if placeable_as_instance(&c.world) && scene.meshes.triangle_count(c.mesh) > 0 {
                users.entry(c.mesh).or_default().push(c.id);
            }
        }
        users.retain(|&mesh, v| {
            v.len() >= MIN_INSTANCES_PER_SHAPE
                && (v.len() - 1) * scene.meshes.triangle_count(mesh) >= min_saved_triangles
        });
        let instanced: std::collections::HashSet<ComponentId> =
            users.values().flatten().copied().collect();
        let plain: Vec<ContentItem> = content
            .iter()
            .filter(|i| i.triangles.is_some() || !instanced.contains(&i.component))
            .cloned()
            .collect();
        let mut out = TileContent::gather(scene, &plain, center);
        for (mesh, comps) in users {
            let bounds = scene.meshes.local_bounds(mesh);
            let origin = match bounds.is_empty() {
                true => DVec3::ZERO,
                false => bounds.center(),
            };
            // The shape in its own frame: the mesh frame moved by -origin.
            let frame = Component::new(mesh, DMat4::from_translation(-origin));
            let primitives =
                TileContent::gather_component(scene, &frame, DVec3::ZERO, 0).primitives;
            let to_shape = DMat4::from_translation(origin);
            let instances = comps
                .iter()
                .map(|&c| {
                    out.features.push(c);
                    ShapeInstance {
                        feature: (out.features.len() - 1) as u32,
                        transform: DMat4::from_translation(-center)
                            * scene.component(c).world
                            * to_shape,
                    }
                })
                .collect();
            out.instanced.push(InstancedShape {
                mesh,
                primitives,
                instances,
            });
        }
        out
    }

    /// One component's geometry alone (feature `feature`), with the component's own `world`.
    fn gather_component(
        scene: &Scene,
        comp: &Component,
        center: DVec3,
        feature: u32,
    ) -> TileContent {
        let mut primitives: BTreeMap<u32, ContentPrimitive> = BTreeMap::new();
        let mesh = scene.mesh(comp.mesh);
        for prim in &mesh.primitives {
            let key = material_key(prim.material);
            let textured = prim
                .material
                .map(|m| scene.materials[m.index()].base_color_texture.is_some())
                .unwrap_or(false);
            let same_material = mesh
                .primitives
                .iter()
                .filter(|p| material_key(p.material) == key);
            let with_uv = textured || same_material.clone().any(|p| p.uvs.is_some());
            let with_color = same_material.clone().any(|p| p.colors.is_some());
            let out = primitives.entry(key).or_insert_with(|| ContentPrimitive {
                material: prim.material,
                ..Default::default()
            });
            append_primitive(out, comp, prim, None, feature, center, with_uv, with_color);
        }
        TileContent {
            center,
            features: vec![comp.id],
            primitives: primitives
                .into_values()
                .filter(|p| !p.indices.is_empty())
                .collect(),
            instanced: Vec::new(),
        }
    }

    /// Every instance turned into merged geometry (one surface for simplification and error
    /// measurement); features stay as they are.
    pub fn expand(mut self) -> TileContent {
        if self.instanced.is_empty() {
            return self;
        }
        let shapes = std::mem::take(&mut self.instanced);
        let mut placed: Vec<TileContent> = Vec::new();
        for shape in &shapes {
            for inst in &shape.instances {
                let mut part = TileContent {
                    center: self.center,
                    features: self.features.clone(),
                    primitives: Vec::new(),
                    instanced: Vec::new(),
                };
                for p in &shape.primitives {
                    let mut q = transformed(p, &inst.transform);
                    q.feature_ids.iter_mut().for_each(|f| *f = inst.feature);
                    part.primitives.push(q);
                }
                placed.push(part);
            }
        }
        let mut parts: Vec<&TileContent> = vec![&self];
        parts.extend(placed.iter());
        TileContent::merge(&parts, self.center)
    }

    /// Merges `content` of `scene` (whole components or parts of cut ones) around `center`.
    /// Features are numbered in content order (parts of one component share one).
    pub fn gather(scene: &Scene, content: &[ContentItem], center: DVec3) -> TileContent {
        let held = held_meshes(scene, content);
        let (features, groups) = grouped_parts(scene, content, &held);
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
            instanced: Vec::new(),
        }
    }

    /// The positions and triangles of [`gather`](Self::gather)'s content as one soup, its
    /// primitives one after the other: what distance queries need of full detail, without the
    /// normals, texture coordinates, colours and feature ids.
    pub fn gather_soup(
        scene: &Scene,
        content: &[ContentItem],
        center: DVec3,
    ) -> (Vec<[f32; 3]>, Vec<u32>) {
        let held = held_meshes(scene, content);
        let (_, groups) = grouped_parts(scene, content, &held);
        let (mut positions, mut indices) = (Vec::new(), Vec::new());
        for parts in groups.values() {
            let (p0, i0) = (positions.len(), indices.len());
            for (_, comp, prim, subset) in parts {
                let (verts, tris) = part_of(prim, subset.as_deref());
                let base = positions.len() as u32;
                append_geometry(&mut positions, comp, prim, &verts, center);
                append_triangles(&mut indices, comp, &tris, base);
            }
            // A primitive without triangles is not gathered.
            if indices.len() == i0 {
                positions.truncate(p0);
            }
        }
        (positions, indices)
    }

    /// Concatenates several contents (e.g. the children of an HLOD tile) around a new `center`:
    /// positions are re-anchored in f64, primitives of one material merged, features renumbered
    /// in component order (a component present in several parts keeps one feature). Instanced
    /// shapes of the parts are not taken: [`expand`](Self::expand) them first.
    pub fn merge(parts: &[&TileContent], center: DVec3) -> TileContent {
        debug_assert!(parts.iter().all(|p| p.instanced.is_empty()));
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
            instanced: Vec::new(),
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

/// `p` with positions moved by `m` (a rigid motion, possibly with a positive scale) and normals
/// turned with it.
fn transformed(p: &ContentPrimitive, m: &DMat4) -> ContentPrimitive {
    let normal_matrix = DMat3::from_mat4(*m).inverse().transpose();
    let f64v = |v: &[f32; 3]| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
    let f32v = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
    ContentPrimitive {
        positions: p
            .positions
            .iter()
            .map(|v| f32v(m.transform_point3(f64v(v))))
            .collect(),
        normals: p
            .normals
            .iter()
            .map(|n| f32v((normal_matrix * f64v(n)).normalize_or(DVec3::Z)))
            .collect(),
        ..p.clone()
    }
}

/// The meshes `content` draws, each read once and held while its parts borrow them.
fn held_meshes(scene: &Scene, content: &[ContentItem]) -> BTreeMap<MeshId, Arc<Mesh>> {
    let mut held: BTreeMap<MeshId, Arc<Mesh>> = BTreeMap::new();
    for item in content {
        let mesh = scene.component(item.component).mesh;
        held.entry(mesh).or_insert_with(|| scene.mesh(mesh));
    }
    held
}

/// One part of a tile's content: its feature number, component, primitive and the triangles it
/// keeps of it (`None`: all).
type Part<'a> = (u32, &'a Component, &'a Primitive, Option<Vec<u32>>);

/// The features of `content` (a component once, in item order) and its parts grouped by
/// material key, in that key's order.
fn grouped_parts<'a>(
    scene: &'a Scene,
    content: &[ContentItem],
    held: &'a BTreeMap<MeshId, Arc<Mesh>>,
) -> (Vec<ComponentId>, BTreeMap<u32, Vec<Part<'a>>>) {
    let mut features: Vec<ComponentId> = Vec::new();
    let mut groups: BTreeMap<u32, Vec<Part>> = BTreeMap::new();
    for item in content {
        if features.last() != Some(&item.component) {
            features.push(item.component);
        }
        let fid = (features.len() - 1) as u32;
        let comp = scene.component(item.component);
        for (pi, prim) in held[&comp.mesh].primitives.iter().enumerate() {
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
    (features, groups)
}

/// The vertices (the source vertex of each) and triangles (in the new indices) a part takes of
/// `prim`: all of it, or the triangles `subset`, re-indexed compactly over the vertices they use.
fn part_of(prim: &Primitive, subset: Option<&[u32]>) -> (Vec<u32>, Vec<u32>) {
    match subset {
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
    }
}

/// Appends the positions of vertices `verts` of `prim`, placed by `comp`, in the tile's frame.
fn append_geometry(
    positions: &mut Vec<[f32; 3]>,
    comp: &Component,
    prim: &Primitive,
    verts: &[u32],
    center: DVec3,
) {
    let m = comp.world;
    positions.extend(verts.iter().map(|&v| {
        let p = prim.positions[v as usize];
        let l = m.transform_point3(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)) - center;
        [l.x as f32, l.y as f32, l.z as f32]
    }));
}

/// A triangle of a part with the winding the viewer needs (a mirroring transform flips it).
fn oriented(t: &[u32], mirrored: bool) -> [u32; 3] {
    if mirrored {
        [t[0], t[2], t[1]]
    } else {
        [t[0], t[1], t[2]]
    }
}

/// Appends a part's triangles `tris`, oriented, its vertices starting at `base`.
fn append_triangles(indices: &mut Vec<u32>, comp: &Component, tris: &[u32], base: u32) {
    let mirrored = comp.mirrors();
    for t in tris.chunks_exact(3) {
        indices.extend(oriented(t, mirrored).iter().map(|&i| base + i));
    }
}

/// Appends a primitive (or, for a part of a cut mesh, only the triangles `subset`) to a merged
/// stream, transformed to the tile's frame.
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
    let (verts, tris) = part_of(prim, subset);
    let base = out.positions.len() as u32;
    let normal_matrix = comp.normal_matrix();
    let mirrored = comp.mirrors();
    append_geometry(&mut out.positions, comp, prim, &verts, center);
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
                let t = oriented(t, mirrored);
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
    append_triangles(&mut out.indices, comp, &tris, base);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{ElementInfo, Mesh, MeshId};
    use glam::DMat4;

    fn one_triangle_scene() -> Scene {
        let mut s = two_triangles_in(Scene::default(), None);
        s.finish();
        s
    }

    /// `s` with a one-triangle mesh of `material` (mesh 0), placed twice 10 m apart.
    fn two_triangles_in(mut s: Scene, material: Option<MaterialId>) -> Scene {
        s.meshes.push(Mesh {
            name: None,
            primitives: vec![Primitive {
                material,
                positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                indices: vec![0, 1, 2],
                ..Default::default()
            }],
            local_bounds: None,
        });
        for (i, x) in [0.0, 10.0].into_iter().enumerate() {
            s.push_component(
                Component::new(MeshId(0), DMat4::from_translation(DVec3::new(x, 0.0, 0.0))),
                &ElementInfo::keyed(format!("t{i}")),
            );
        }
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
    fn a_gathered_soup_is_the_gathered_contents_geometry() {
        use crate::scene::Material;
        // Two meshes on two materials, the second mirrored and cut: one triangle kept of its
        // first primitive, none of its second.
        let plain = Scene {
            materials: vec![Material::default(); 2],
            ..Default::default()
        };
        let mut s = two_triangles_in(plain, Some(MaterialId(1)));
        s.meshes.push(Mesh {
            name: None,
            primitives: vec![
                Primitive {
                    material: Some(MaterialId(0)),
                    positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 1.0]],
                    indices: vec![0, 1, 2, 1, 3, 2],
                    ..Default::default()
                },
                Primitive {
                    positions: vec![[0.0; 3], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],
                    indices: vec![0, 1, 2],
                    ..Default::default()
                },
            ],
            local_bounds: None,
        });
        let mirrored = DMat4::from_scale(DVec3::new(-1.0, 1.0, 1.0));
        s.push_component(
            Component::new(MeshId(1), mirrored),
            &ElementInfo::keyed("m"),
        );
        s.finish();
        let items = [
            ContentItem {
                component: ComponentId(2),
                triangles: Some(Arc::new(vec![(0, 1)])),
            },
            ContentItem {
                component: ComponentId(0),
                triangles: None,
            },
            ContentItem {
                component: ComponentId(1),
                triangles: None,
            },
        ];
        let center = DVec3::new(3.0, 0.5, 0.25);
        let gathered = TileContent::gather(&s, &items, center);
        let (mut positions, mut indices) = (Vec::new(), Vec::new());
        for p in &gathered.primitives {
            let base = positions.len() as u32;
            positions.extend_from_slice(&p.positions);
            indices.extend(p.indices.iter().map(|&i| base + i));
        }
        assert_eq!(gathered.primitives.len(), 2);
        assert_eq!(
            TileContent::gather_soup(&s, &items, center),
            (positions, indices)
        );
    }

    #[test]
    fn instances_expand_to_the_plain_geometry() {
        // Two copies of one mesh, one turned a quarter around z: one shape, two instances.
        let mut s = one_triangle_scene();
        s.components[1].world = DMat4::from_translation(DVec3::new(10.0, 0.0, 0.0))
            * DMat4::from_rotation_z(std::f64::consts::FRAC_PI_2);
        let items = [0, 1].map(|c| ContentItem {
            component: ComponentId(c),
            triangles: None,
        });
        let center = DVec3::new(5.0, 0.0, 0.0);
        let plain = TileContent::gather(&s, &items, center);
        let inst = TileContent::gather_instanced(&s, &items, center, 0);
        assert!(inst.primitives.is_empty());
        assert_eq!(inst.instanced.len(), 1);
        assert_eq!(inst.instance_count(), 2);
        assert_eq!(
            (inst.triangle_count(), inst.stored_triangle_count()),
            (2, 1)
        );
        let b = (inst.bounds(), plain.bounds());
        assert!((b.0.min - b.1.min).length() < 1e-6 && (b.0.max - b.1.max).length() < 1e-6);
        let e = inst.expand();
        assert_eq!(e.features, plain.features);
        let sorted = |c: &TileContent| {
            let p = &c.primitives[0];
            let mut v: Vec<(u32, [i64; 3], [i64; 3])> = (0..p.positions.len())
                .map(|i| {
                    let q = |x: [f32; 3]| x.map(|c| (c as f64 * 1e5).round() as i64);
                    (p.feature_ids[i], q(p.positions[i]), q(p.normals[i]))
                })
                .collect();
            v.sort();
            v
        };
        assert_eq!(sorted(&e), sorted(&plain));
        // A saving below the threshold keeps plain geometry.
        let few = TileContent::gather_instanced(&s, &items, center, 2);
        assert!(few.instanced.is_empty() && few.triangle_count() == 2);
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

    #[test]
    fn plain_materials_of_one_appearance_merge_into_one_primitive() {
        use crate::scene::{Material, TextureRef};
        // Three components on two meshes: red and green (same appearance otherwise), and a
        // textured one that must stay apart.
        let mut s = one_triangle_scene();
        let red = Material {
            base_color: [1.0, 0.0, 0.0, 1.0],
            metallic: 0.0,
            ..Default::default()
        };
        let green = Material {
            base_color: [0.0, 0.5, 0.0, 1.0],
            ..red.clone()
        };
        let textured = Material {
            base_color_texture: Some(TextureRef {
                image: crate::scene::ImageId(0),
                sampler: Default::default(),
                tex_coord: 0,
            }),
            ..red.clone()
        };
        s.materials = vec![red, green, textured];
        s.meshes.update(MeshId(0), |m| {
            m.primitives[0].material = Some(MaterialId(0))
        });
        let mut second = (*s.mesh(MeshId(0))).clone();
        second.primitives[0].material = Some(MaterialId(1));
        second.primitives[0].colors = Some(vec![[0.5; 4]; 3]);
        s.meshes.push(second);
        s.components[1].mesh = MeshId(1);
        let items = [0, 1].map(|c| ContentItem {
            component: ComponentId(c),
            triangles: None,
        });
        let classes = AppearanceClasses::add_to(&mut s);
        // One class (red, green), its white twin appended; the textured material has none.
        assert_eq!(s.materials.len(), 4);
        assert_eq!(s.materials[3].base_color, [1.0; 4]);
        assert_eq!(s.materials[3].metallic, 0.0);
        let c = TileContent::gather(&s, &items, DVec3::ZERO);
        assert_eq!(c.primitives.len(), 2);
        let m = classes.merge(&s, &c).expect("two primitives of one class");
        assert_eq!(m.primitives.len(), 1);
        let p = &m.primitives[0];
        assert_eq!(p.material, Some(MaterialId(3)));
        assert_eq!(m.triangle_count(), c.triangle_count());
        // Colour = vertex colour (white when absent) x base colour, per source primitive.
        let by_feature = |f: u32| p.colors[p.feature_ids.iter().position(|&x| x == f).unwrap()];
        assert_eq!(by_feature(0), [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(by_feature(1), [0.0, 0.25, 0.0, 0.5]);
        assert!(p.indices.iter().all(|&i| (i as usize) < p.positions.len()));
        // Nothing to merge: a single primitive per class.
        let one = TileContent::gather(&s, &items[..1], DVec3::ZERO);
        assert!(classes.merge(&s, &one).is_none());
        // Without classes (merging off) nothing merges.
        assert!(AppearanceClasses::default().merge(&s, &c).is_none());
    }
}
