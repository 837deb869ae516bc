//! FBX reader (binary 6.x/7.x and ASCII), through the ufbx loader: it parses the node tree,
//! evaluates each node's transform with its pivots, offsets and geometric transform (FBX SDK
//! `FbxNode` transform chain), and converts the file's own axes and unit (`GlobalSettings`
//! `UpAxis`, `UnitScaleFactor`) to the scene's frame, metres with z up.
//!
//! Every node with a mesh is one element, named by the node, with its parents as hierarchy path;
//! Revit's element id at the end of a node name (`… [320878]`) is kept as the property
//! `revit.element_id`. A mesh several nodes draw is one scene mesh placed by each node (instances,
//! not copies). Faces are split per material and triangulated by ufbx; materials take their
//! diffuse colour and opacity, and their diffuse texture from the bytes embedded in the file or
//! from the file it names, found as written, with `\` as `/`, or by its bare name beside the model
//! ([`TextureFiles`]), never outside the model's folder.

use super::interchange::{push_image, revit_element_id, TextureFiles};
use crate::error::{Error, Result};
use crate::geometry::unit_normal_or_z;
use crate::scene::*;
use glam::DMat4;
use rustc_hash::FxHashMap;
use std::collections::HashMap;
use std::path::Path;

/// Reads one FBX file into a new scene.
pub fn read_fbx(path: &Path) -> Result<Scene> {
    let bytes = super::read_regular(path).map_err(|e| Error::input_from(path, "cannot read", e))?;
    read_fbx_bytes(path, &bytes)
}

/// Reads FBX bytes; `path` names the file in errors and anchors the textures it names.
pub fn read_fbx_bytes(path: &Path, bytes: &[u8]) -> Result<Scene> {
    let opts = ufbx::LoadOpts {
        target_axes: ufbx::CoordinateAxes::right_handed_z_up(),
        target_unit_meters: 1.0,
        // The unit and axis change sits in the root's transform, so every node's
        // `geometry_to_world` is in metres, z up.
        space_conversion: ufbx::SpaceConversion::TransformRoot,
        geometry_transform_handling: ufbx::GeometryTransformHandling::Preserve,
        generate_missing_normals: true,
        ignore_animation: true,
        // Textures are read here, inside the model's folder only.
        load_external_files: false,
        ..Default::default()
    };
    let fbx = ufbx::load_memory(bytes, opts).map_err(|e| {
        let info = e.info();
        let detail = match info.is_empty() {
            true => String::new(),
            false => format!(" ({info})"),
        };
        Error::input(
            path,
            format!(
                "not a readable FBX file: {}{detail}",
                e.description.as_ref()
            ),
        )
    })?;
    let base_dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let mut reader = Reader {
        path,
        textures: TextureFiles::new(&base_dir),
        scene: Scene::default(),
        texts: TextInterner::default(),
        nodes: HashMap::new(),
        materials: HashMap::new(),
        images: HashMap::new(),
        meshes: HashMap::new(),
    };
    for node in &fbx.nodes {
        if let Some(mesh) = node.mesh.as_ref() {
            reader.mesh_node(node, mesh)?;
        }
    }
    let mut scene = reader.scene;
    scene.reader_warnings.extend(reader.textures.warnings(path));
    scene.sources.push(SourceFile {
        path: path.to_path_buf(),
        bytes: bytes.len() as u64,
    });
    super::keep_ids_unique(&mut scene);
    scene.finish();
    Ok(scene)
}

struct Reader<'a> {
    path: &'a Path,
    textures: TextureFiles,
    scene: Scene,
    texts: TextInterner,
    /// ufbx node element id → hierarchy node.
    nodes: HashMap<u32, NodeId>,
    /// ufbx material element id → scene material.
    materials: HashMap<u32, MaterialId>,
    /// ufbx texture element id → its image (`None`: not found).
    images: HashMap<u32, Option<ImageId>>,
    /// (ufbx mesh element id, the materials it is drawn with) → scene mesh: one per shape.
    meshes: HashMap<(u32, Vec<Option<MaterialId>>), MeshId>,
}

impl Reader<'_> {
    /// The hierarchy node of a ufbx node (its parents first); the root is left out.
    fn node(&mut self, node: &ufbx::Node) -> Option<NodeId> {
        if node.is_root {
            return None;
        }
        if let Some(&n) = self.nodes.get(&node.element.element_id) {
            return Some(n);
        }
        let parent = node.parent.as_ref().and_then(|p| self.node(p));
        let id = NodeId(self.scene.nodes.len() as u32);
        let name = node.element.name.as_ref();
        self.scene.nodes.push(Node {
            name: (!name.is_empty()).then(|| name.to_string()),
            parent,
            ..Node::default()
        });
        self.nodes.insert(node.element.element_id, id);
        Some(id)
    }

    fn mesh_node(&mut self, node: &ufbx::Node, mesh: &ufbx::Mesh) -> Result<()> {
        if mesh.num_triangles == 0 {
            return Ok(());
        }
        // A node's own materials override its mesh's (per instance).
        let slots: Vec<&ufbx::Material> = match node.materials.len() {
            0 => mesh.materials.iter().map(|m| &**m).collect(),
            _ => node.materials.iter().map(|m| &**m).collect(),
        };
        let materials: Vec<Option<MaterialId>> =
            slots.iter().map(|m| Some(self.material(m))).collect();
        let key = (mesh.element.element_id, materials.clone());
        let mesh_id = match self.meshes.get(&key) {
            Some(&m) => m,
            None => {
                let m = self.scene.meshes.push(self.geometry(mesh, &materials)?);
                self.meshes.insert(key, m);
                m
            }
        };
        let hierarchy = self.node(node);
        let name = node.element.name.as_ref().to_string();
        let key = match name.is_empty() {
            true => hierarchy.map_or_else(String::new, |n| self.scene.node_path(n)),
            false => name.clone(),
        };
        let mut info = ElementInfo::keyed(key);
        info.name = (!name.is_empty()).then(|| name.clone());
        info.class = Some(self.texts.get("FbxMesh"));
        info.material = slots
            .first()
            .map(|m| self.texts.get(m.element.name.as_ref()));
        if let Some(id) = revit_element_id(&name) {
            info.properties.push(Property {
                set: self.texts.get("revit"),
                name: self.texts.get("element_id"),
                value: PropertyValue::Integer(id),
            });
        }
        let component = Component {
            node: hierarchy,
            ..Component::new(mesh_id, matrix(&node.geometry_to_world))
        };
        self.scene.push_component(component, &info);
        Ok(())
    }

    /// A mesh's faces, triangulated, one primitive per material used.
    fn geometry(&self, mesh: &ufbx::Mesh, materials: &[Option<MaterialId>]) -> Result<Mesh> {
        let textured = |m: Option<MaterialId>| {
            m.is_some_and(|m| self.scene.materials[m.index()].base_color_texture.is_some())
        };
        let mut out = Mesh {
            name: Some(mesh.element.name.as_ref().to_string()).filter(|n| !n.is_empty()),
            ..Mesh::default()
        };
        let mut corners = vec![0u32; mesh.max_face_triangles * 3];
        let mut parts: Vec<(u32, Vec<u32>)> = match mesh.material_parts.len() {
            0 => vec![(0, (0..mesh.num_faces as u32).collect())],
            _ => mesh
                .material_parts
                .iter()
                .map(|p| (p.index, p.face_indices.iter().copied().collect()))
                .collect(),
        };
        parts.retain(|(_, faces)| !faces.is_empty());
        for (slot, faces) in parts {
            let material = materials.get(slot as usize).copied().flatten();
            let with_uvs = mesh.vertex_uv.exists && textured(material);
            let mut index_of: FxHashMap<u32, u32> = FxHashMap::default();
            let mut prim = Primitive {
                material,
                uvs: with_uvs.then(Vec::new),
                normals: mesh.vertex_normal.exists.then(Vec::new),
                ..Primitive::default()
            };
            for f in faces {
                let face = *mesh.faces.get(f as usize).ok_or_else(|| {
                    Error::input(
                        self.path,
                        format!("mesh {}: face {f} out of range", mesh.element.name),
                    )
                })?;
                if face.num_indices < 3 {
                    continue;
                }
                let n = ufbx::triangulate_face(&mut corners, mesh, face) as usize;
                let mut tri = corners[..n * 3].to_vec();
                if mesh.reversed_winding {
                    tri.chunks_exact_mut(3).for_each(|t| t.swap(1, 2));
                }
                for ix in tri {
                    let next = prim.positions.len() as u32;
                    // Corners that share every attribute value are one vertex.
                    let k = *index_of.entry(ix).or_insert(next);
                    if k == next {
                        let p = mesh.vertex_position[ix as usize];
                        prim.positions.push([p.x as f32, p.y as f32, p.z as f32]);
                        if let Some(normals) = prim.normals.as_mut() {
                            let v = mesh.vertex_normal[ix as usize];
                            normals.push(unit_normal_or_z([v.x as f32, v.y as f32, v.z as f32]));
                        }
                        if let Some(uvs) = prim.uvs.as_mut() {
                            let v = mesh.vertex_uv[ix as usize];
                            // FBX's v runs up from the image's bottom, glTF's down from its top.
                            uvs.push([v.x as f32, 1.0 - v.y as f32]);
                        }
                    }
                    prim.indices.push(k);
                }
            }
            if !prim.indices.is_empty() {
                out.primitives.push(prim);
            }
        }
        Ok(out)
    }

    /// The scene material of a ufbx material (made once).
    fn material(&mut self, m: &ufbx::Material) -> MaterialId {
        if let Some(&id) = self.materials.get(&m.element.element_id) {
            return id;
        }
        let texture = [&m.pbr.base_color, &m.fbx.diffuse_color]
            .into_iter()
            .find_map(|map| map.texture.as_ref())
            .and_then(|t| self.texture(t));
        let value = |map: &ufbx::MaterialMap, default: f64| match map.has_value {
            true => map.value_vec4.x,
            false => default,
        };
        let colour = &m.pbr.base_color;
        let factor = value(&m.pbr.base_factor, 1.0);
        let opacity = value(&m.pbr.opacity, 1.0).clamp(0.0, 1.0) as f32;
        let rgb = match (texture.is_some(), colour.has_value) {
            // A texture shows its own colours.
            (true, _) | (false, false) => [1.0; 3],
            (false, true) => {
                let c = colour.value_vec4;
                [c.x, c.y, c.z].map(|v| (v * factor).clamp(0.0, 1.0) as f32)
            }
        };
        let id = MaterialId(self.scene.materials.len() as u32);
        self.scene.materials.push(Material {
            name: Some(m.element.name.as_ref().to_string()),
            base_color: [rgb[0], rgb[1], rgb[2], opacity],
            metallic: 0.0,
            roughness: 1.0,
            emissive: [0.0; 3],
            base_color_texture: texture,
            alpha_mode: if opacity < 1.0 {
                AlphaMode::Blend
            } else {
                AlphaMode::Opaque
            },
            alpha_cutoff: 0.5,
            double_sided: true,
        });
        self.materials.insert(m.element.element_id, id);
        id
    }

    /// A texture's image: embedded bytes, or the file it names (layered textures: their first).
    fn texture(&mut self, t: &ufbx::Texture) -> Option<TextureRef> {
        let t: &ufbx::Texture = match t.file_textures.iter().next() {
            Some(f) if !t.has_file => f,
            _ => t,
        };
        let image = match self.images.get(&t.element.element_id) {
            Some(&known) => known,
            None => {
                let image = self.image(t);
                self.images.insert(t.element.element_id, image);
                image
            }
        }?;
        let wrap = |w: ufbx::WrapMode| match w {
            ufbx::WrapMode::Clamp => Sampler::CLAMP_TO_EDGE,
            _ => Sampler::REPEAT,
        };
        Some(TextureRef {
            image,
            sampler: Sampler::wrapping(wrap(t.wrap_u), wrap(t.wrap_v)),
            tex_coord: 0,
        })
    }

    fn image(&mut self, t: &ufbx::Texture) -> Option<ImageId> {
        let name = [&t.relative_filename, &t.filename, &t.absolute_filename]
            .into_iter()
            .map(|n| n.as_ref())
            .find(|n| !n.is_empty())
            .unwrap_or("");
        let bare = name.rsplit(['/', '\\']).next().unwrap_or(name);
        let embedded: &[u8] = match (t.content.is_empty(), t.video.as_ref()) {
            (false, _) => &t.content,
            (true, Some(v)) => &v.content,
            (true, None) => &[],
        };
        if !embedded.is_empty() {
            if let Some(id) = push_image(&mut self.scene, bare, embedded.to_vec()) {
                return Some(id);
            }
        }
        if name.is_empty() {
            return None;
        }
        self.textures.image(name, &mut self.scene)
    }
}

/// A ufbx affine matrix (columns of a 3×4) as a 4×4.
fn matrix(m: &ufbx::Matrix) -> DMat4 {
    DMat4::from_cols_array(&[
        m.m00, m.m10, m.m20, 0.0, m.m01, m.m11, m.m21, 0.0, m.m02, m.m12, m.m22, 0.0, m.m03, m.m13,
        m.m23, 1.0,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    const QUAD: &[u8] = include_bytes!("../../../fuzz/corpus/fbx/quad-instanced-ascii.fbx");

    #[test]
    fn shared_meshes_are_instances_in_metres_with_revit_ids() {
        let s = read_fbx_bytes(Path::new("quad.fbx"), QUAD).unwrap();
        assert_eq!(s.components.len(), 2);
        assert_eq!(s.meshes.len(), 1, "one shape, placed twice");
        let wall = s.element(ComponentId(0));
        assert_eq!(wall.key, "Basic Wall [42]");
        assert!(wall
            .properties
            .iter()
            .any(|p| &*p.name == "element_id" && p.value == PropertyValue::Integer(42)));
        assert_eq!(
            s.node_path(s.components[1].node.unwrap()),
            "Basic Wall [42]/copy"
        );
        let mut area = 0.0;
        for c in &s.components {
            for p in &s.mesh(c.mesh).primitives {
                for t in p.indices.chunks_exact(3) {
                    let v = |i: u32| {
                        c.world.transform_point3(DVec3::from_array(
                            p.positions[i as usize].map(f64::from),
                        ))
                    };
                    area += (v(t[1]) - v(t[0])).cross(v(t[2]) - v(t[0])).length() / 2.0;
                }
            }
        }
        // A 7 cm² pentagon (centimetres), drawn twice.
        assert!((area - 2.0 * 7e-4).abs() < 1e-9, "{area}");
        // The wall is 10 cm east of the origin.
        let b = s.components[0].world_bounds;
        assert!((b.min - DVec3::new(0.1, 0.0, 0.0)).length() < 1e-9, "{b:?}");
        assert_eq!(s.materials.len(), 1);
    }

    #[test]
    fn broken_files_are_one_error_naming_the_file() {
        for bytes in [
            &b"Kaydara FBX Binary  \x00\x1a\x00"[..],
            b"",
            b"; FBX\nObjects: {",
        ] {
            if let Err(e) = read_fbx_bytes(Path::new("bad.fbx"), bytes) {
                assert!(e.to_string().contains("bad.fbx"), "{e}");
            }
        }
        let e = read_fbx_bytes(
            Path::new("bad.fbx"),
            b"Kaydara FBX Binary  \x00\x1a\x00\xe8\x1c",
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("bad.fbx: not a readable FBX file"),
            "{e}"
        );
    }
}
