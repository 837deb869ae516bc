//! Texture classification (paper III.D): each image is *repeated*, *shared* or *standalone*.
//!
//! - **repeated**: some texture coordinate that samples the image lies outside [0, 1] (tiling,
//!   the paper's "anomalous"/"repetitive" textures). Takes precedence over the two below.
//! - **shared**: bound by more than one material, or drawn by more than one component.
//! - **standalone**: bound once, by one material drawn by one component.
//! - images no material binds (or no drawn primitive uses) are counted as *unused*.
//!
//! The pass also gathers, per image, the union of the UV boxes that sample it, which is what
//! cropping (`crop.rs`) cuts to. Only `TEXCOORD_0` is considered: a texture bound with another
//! `texCoord` set is classified by its binding but never cropped.

use crate::scene::{ImageId, Scene};
use serde::Serialize;

/// A texture coordinate this far outside [0, 1] counts as outside (float noise of exporters).
pub const UV_RANGE_TOLERANCE: f32 = 1e-5;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TextureClass {
    Repeated,
    Shared,
    Standalone,
    Unused,
}

/// How one image is used.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageUse {
    pub class: TextureClass,
    /// Materials that bind the image.
    pub materials: usize,
    /// Drawn components (not dedup aliases) whose primitives sample it.
    pub components: usize,
    /// Union of the UVs that sample it: (min, max); `None` when nothing samples it.
    pub uv_box: Option<([f32; 2], [f32; 2])>,
    /// Some primitive samples it without UVs, or through a texCoord set other than 0: its UV use
    /// is not known, so it must not be cropped.
    pub uv_unknown: bool,
}

/// Counts per class, as the report shows them.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct ClassCounts {
    pub repeated: usize,
    pub shared: usize,
    pub standalone: usize,
    pub unused: usize,
}

/// Classifies every image of the scene (`result[i]` is image `i`).
pub fn classify(scene: &Scene) -> Vec<ImageUse> {
    let n = scene.images.len();
    let mut materials = vec![0usize; n];
    for m in &scene.materials {
        if let Some(t) = &m.base_color_texture {
            materials[t.image.index()] += 1;
        }
    }
    let image_of = |p: &crate::scene::Primitive| {
        p.material
            .and_then(|m| scene.materials[m.index()].base_color_texture.as_ref())
    };
    // UV boxes per mesh primitive (once per mesh, however many components draw it).
    let mut lo = vec![[f32::INFINITY; 2]; n];
    let mut hi = vec![[f32::NEG_INFINITY; 2]; n];
    let mut unknown = vec![false; n];
    let mut mesh_used = vec![false; scene.meshes.len()];
    let mut last_component = vec![u32::MAX; n];
    let mut components = vec![0usize; n];
    for c in scene.components.iter().filter(|c| c.alias_of.is_none()) {
        let first_use = !mesh_used[c.mesh.index()];
        mesh_used[c.mesh.index()] = true;
        for p in &scene.mesh(c.mesh).primitives {
            let Some(t) = image_of(p) else { continue };
            let i = t.image.index();
            if last_component[i] != c.id.0 {
                last_component[i] = c.id.0;
                components[i] += 1;
            }
            if !first_use {
                continue;
            }
            match (&p.uvs, t.tex_coord) {
                (Some(uvs), 0) => {
                    for &k in &p.indices {
                        let uv = uvs[k as usize];
                        for a in 0..2 {
                            lo[i][a] = lo[i][a].min(uv[a]);
                            hi[i][a] = hi[i][a].max(uv[a]);
                        }
                    }
                }
                _ => unknown[i] = true,
            }
        }
    }
    (0..n)
        .map(|i| {
            let uv_box = (lo[i][0] <= hi[i][0]).then_some((lo[i], hi[i]));
            let outside = uv_box.is_some_and(|(l, h)| {
                l.iter().any(|&x| x < -UV_RANGE_TOLERANCE)
                    || h.iter().any(|&x| x > 1.0 + UV_RANGE_TOLERANCE)
            });
            let class = if components[i] == 0 {
                TextureClass::Unused
            } else if outside {
                TextureClass::Repeated
            } else if materials[i] > 1 || components[i] > 1 {
                TextureClass::Shared
            } else {
                TextureClass::Standalone
            };
            ImageUse {
                class,
                materials: materials[i],
                components: components[i],
                uv_box,
                uv_unknown: unknown[i],
            }
        })
        .collect()
}

/// Counts of each class.
pub fn counts(uses: &[ImageUse]) -> ClassCounts {
    let mut c = ClassCounts::default();
    for u in uses {
        match u.class {
            TextureClass::Repeated => c.repeated += 1,
            TextureClass::Shared => c.shared += 1,
            TextureClass::Standalone => c.standalone += 1,
            TextureClass::Unused => c.unused += 1,
        }
    }
    c
}

/// The images materials bind, in id order.
pub fn bound_images(scene: &Scene) -> Vec<ImageId> {
    let mut v: Vec<ImageId> = scene
        .materials
        .iter()
        .filter_map(|m| m.base_color_texture.as_ref().map(|t| t.image))
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::scene::*;
    use glam::DMat4;
    use std::sync::Arc;

    /// A quad (two triangles) with the given UV corners.
    pub fn quad(material: u32, uv0: [f32; 2], uv1: [f32; 2]) -> Primitive {
        Primitive {
            material: Some(MaterialId(material)),
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 0.0, 1.0],
                [0.0, 0.0, 1.0],
            ],
            uvs: Some(vec![
                [uv0[0], uv1[1]],
                [uv1[0], uv1[1]],
                [uv1[0], uv0[1]],
                [uv0[0], uv0[1]],
            ]),
            indices: vec![0, 1, 2, 0, 2, 3],
            ..Default::default()
        }
    }

    pub fn textured_material(image: u32) -> Material {
        Material {
            base_color_texture: Some(TextureRef {
                image: ImageId(image),
                sampler: Sampler::default(),
                tex_coord: 0,
            }),
            ..Default::default()
        }
    }

    pub fn image(bytes: Vec<u8>) -> Image {
        Image {
            name: None,
            mime_type: "image/png".into(),
            bytes: Arc::new(bytes),
        }
    }

    /// One component per primitive list.
    pub fn scene_of(meshes: Vec<Vec<Primitive>>, materials: Vec<Material>, images: usize) -> Scene {
        let mut s = Scene {
            materials,
            images: (0..images).map(|i| image(vec![i as u8])).collect(),
            ..Default::default()
        };
        for (k, prims) in meshes.into_iter().enumerate() {
            s.meshes.push(Mesh {
                name: None,
                primitives: prims,
                local_bounds: None,
            });
            s.push_component(
                Component::new(MeshId(k as u32), DMat4::IDENTITY),
                &ElementInfo::keyed(format!("c{k}")),
            );
        }
        s.finish();
        s
    }

    #[test]
    fn classes_by_uv_range_and_binding() {
        // image 0: one material, one component, UVs inside → standalone
        // image 1: UVs up to 3 → repeated (even though bound once)
        // image 2: two materials → shared; image 3: one material on two components → shared
        // image 4: bound by nothing → unused
        let s = scene_of(
            vec![
                vec![quad(0, [0.1, 0.2], [0.6, 0.7])],
                vec![quad(1, [0.0, 0.0], [3.0, 1.0])],
                vec![quad(2, [0.0, 0.0], [1.0, 1.0])],
                vec![
                    quad(3, [0.0, 0.0], [0.5, 0.5]),
                    quad(4, [0.0, 0.0], [1.0, 1.0]),
                ],
                vec![quad(4, [0.5, 0.5], [1.0, 1.0])],
            ],
            vec![
                textured_material(0),
                textured_material(1),
                textured_material(2),
                textured_material(2),
                textured_material(3),
            ],
            5,
        );
        let u = classify(&s);
        assert_eq!(u[0].class, TextureClass::Standalone);
        assert_eq!(u[0].uv_box, Some(([0.1, 0.2], [0.6, 0.7])));
        assert_eq!(u[1].class, TextureClass::Repeated);
        assert_eq!(u[2].class, TextureClass::Shared);
        assert_eq!(u[2].materials, 2);
        assert_eq!(u[3].class, TextureClass::Shared);
        assert_eq!(u[3].components, 2);
        assert_eq!(u[3].uv_box, Some(([0.0, 0.0], [1.0, 1.0])));
        assert_eq!(u[4].class, TextureClass::Unused);
        assert_eq!(
            counts(&u),
            ClassCounts {
                repeated: 1,
                shared: 2,
                standalone: 1,
                unused: 1
            }
        );
    }
}
