//! Wavefront OBJ reader (the "Object Files (.obj)" appendix of the Wavefront Advanced Visualizer
//! manual: `v`/`vt`/`vn` vertex data, `f` polygons, `g`/`o` grouping, `usemtl`/`mtllib` with
//! materials from [`mtl`]).
//!
//! The file is read line by line, never whole: only the vertex pools (every face may name any
//! earlier vertex) and the group being read are held, and each group goes to the scene's mesh
//! store when the next one starts, so a photogrammetry mesh of gigabytes reads under
//! `--memory-budget` (the store spills). Every group (`g`, within its `o` object) is one element
//! named by it; faces before any group are an element named after the file. A group name that
//! comes back after another group is a new element (its id numbered, as any repeated id).
//! Polygons of any size are triangulated on their plane ([`crate::geometry::triangulate`]);
//! indices may be negative (relative); faces without normals get area-weighted ones, faces without
//! UVs draw untextured. The file does not say its frame: `--up`/`--unit` ([`MeshFrame`]), else y up
//! in metres, or centimetres when the header says so as FBX converters write it. Revit's element
//! id at the end of a group name (`… [320878]`) is kept as the property `revit.element_id`.

pub mod mtl;

use super::interchange::{
    revit_element_id, unescape_fbx_name, LengthUnit, MeshFrame, TextureFiles,
};
use crate::error::{Error, Result};
use crate::geometry::unit_normal_or_z;
use crate::scene::*;
use glam::{DMat4, DVec3};
use rustc_hash::FxHashMap;
use std::collections::{BTreeMap, HashMap};
use std::io::BufRead;
use std::path::Path;

/// Reads one OBJ file (and the MTL libraries it names) into a new scene, in `frame`.
pub fn read_obj(path: &Path, frame: MeshFrame) -> Result<Scene> {
    let file = super::open_regular(path).map_err(|e| Error::input_from(path, "cannot read", e))?;
    let bytes = file.metadata().map(|m| m.len()).unwrap_or(0);
    let mut scene = read_obj_from(
        path,
        std::io::BufReader::with_capacity(1 << 20, file),
        frame,
    )?;
    scene.sources.push(SourceFile {
        path: path.to_path_buf(),
        bytes,
    });
    Ok(scene)
}

/// Reads OBJ text from `input`; `path` names the file in errors and anchors its MTL and textures.
pub fn read_obj_from(path: &Path, input: impl BufRead, frame: MeshFrame) -> Result<Scene> {
    let mut reader = Reader::new(path, frame);
    reader.read(input)?;
    reader.finish()
}

/// A corner: indices into the position, UV and normal pools (`NONE`: not given).
type Corner = [u32; 3];
const NONE: u32 = u32::MAX;

/// One material's triangles of the group being read, indexed by distinct corners.
#[derive(Default)]
struct PrimitiveBuilder {
    corners: Vec<Corner>,
    index_of: FxHashMap<Corner, u32>,
    indices: Vec<u32>,
}

impl PrimitiveBuilder {
    fn push(&mut self, c: Corner) {
        let next = self.corners.len() as u32;
        let i = *self.index_of.entry(c).or_insert(next);
        if i == next {
            self.corners.push(c);
        }
        self.indices.push(i);
    }
}

/// The group being read.
#[derive(Default)]
struct GroupBuilder {
    object: Option<String>,
    group: Option<String>,
    first_material: Option<String>,
    by_material: BTreeMap<Option<MaterialId>, PrimitiveBuilder>,
}

/// A material of the scene made from an MTL material: its id and its map's UV scale and offset.
#[derive(Clone, Copy)]
struct UsedMaterial {
    id: MaterialId,
    uv_scale: [f32; 2],
    uv_offset: [f32; 2],
    textured: bool,
}

struct Reader<'a> {
    path: &'a Path,
    base_dir: std::path::PathBuf,
    frame: MeshFrame,
    /// Whether geometry has been seen (a unit comment counts only before it).
    seen_geometry: bool,
    positions: Vec<DVec3>,
    uvs: Vec<[f32; 2]>,
    normals: Vec<[f32; 3]>,
    library: HashMap<String, mtl::MtlMaterial>,
    /// Libraries that could not be read (one warning each).
    missing_libraries: Vec<String>,
    used: HashMap<String, UsedMaterial>,
    /// `usemtl` names no library defines.
    undefined_materials: Vec<String>,
    current_material: Option<String>,
    current_object: Option<String>,
    group: GroupBuilder,
    /// Node of each object name, and of each (object, group).
    object_nodes: HashMap<String, NodeId>,
    textures: TextureFiles,
    texts: TextInterner,
    scene: Scene,
    /// Faces with fewer than three corners, skipped.
    degenerate_faces: usize,
    /// Scratch of one face.
    face: Vec<Corner>,
}

impl<'a> Reader<'a> {
    fn new(path: &'a Path, frame: MeshFrame) -> Self {
        let base_dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
        Reader {
            path,
            textures: TextureFiles::new(&base_dir),
            base_dir,
            frame,
            seen_geometry: false,
            positions: Vec::new(),
            uvs: Vec::new(),
            normals: Vec::new(),
            library: HashMap::new(),
            missing_libraries: Vec::new(),
            used: HashMap::new(),
            undefined_materials: Vec::new(),
            current_material: None,
            current_object: None,
            group: GroupBuilder::default(),
            object_nodes: HashMap::new(),
            texts: TextInterner::default(),
            scene: Scene::default(),
            degenerate_faces: 0,
            face: Vec::new(),
        }
    }

    fn err(&self, line: usize, m: impl std::fmt::Display) -> Error {
        Error::input(self.path, format!("line {line}: {m}"))
    }

    fn read(&mut self, mut input: impl BufRead) -> Result<()> {
        let mut raw = Vec::with_capacity(256);
        let mut line = Vec::with_capacity(256);
        let mut number = 0usize;
        loop {
            line.clear();
            let first = number + 1;
            // A line ending in `\` continues on the next.
            loop {
                raw.clear();
                let n = input
                    .read_until(b'\n', &mut raw)
                    .map_err(|e| Error::input_from(self.path, format!("line {}", number + 1), e))?;
                if n == 0 {
                    break;
                }
                number += 1;
                let text = raw.trim_ascii_end();
                match text.strip_suffix(b"\\") {
                    Some(head) => {
                        line.extend_from_slice(head);
                        line.push(b' ');
                    }
                    None => {
                        line.extend_from_slice(text);
                        break;
                    }
                }
            }
            if number < first && line.is_empty() {
                return Ok(());
            }
            self.statement(&line, first)?;
        }
    }

    fn statement(&mut self, line: &[u8], at: usize) -> Result<()> {
        // A byte-order mark some Windows tools write.
        let line = match at {
            1 => line.strip_prefix(b"\xef\xbb\xbf").unwrap_or(line),
            _ => line,
        };
        let line = line.trim_ascii();
        if line.is_empty() {
            return Ok(());
        }
        if line[0] == b'#' {
            if !self.seen_geometry && self.frame.unit.is_none() {
                let text = String::from_utf8_lossy(line).to_ascii_lowercase();
                if text.contains("uses centimeters as units") {
                    self.frame.unit = Some(LengthUnit::Cm);
                }
            }
            return Ok(());
        }
        let split = line
            .iter()
            .position(|b| b.is_ascii_whitespace())
            .unwrap_or(line.len());
        let (keyword, rest) = (&line[..split], line[split..].trim_ascii());
        match keyword {
            b"v" => {
                self.seen_geometry = true;
                let [x, y, z] = self.numbers::<3>(rest, at, "vertex")?;
                self.positions.push(DVec3::new(x, y, z));
            }
            b"vt" => {
                let mut uv = [0.0; 2];
                for (k, t) in rest
                    .split(|b| b.is_ascii_whitespace())
                    .filter(|t| !t.is_empty())
                    .take(2)
                    .enumerate()
                {
                    uv[k] = self.number(t, at, "texture coordinate")?;
                }
                self.uvs.push(uv.map(|c| c as f32));
            }
            b"vn" => {
                let n = self.numbers::<3>(rest, at, "normal")?;
                self.normals.push(n.map(|c| c as f32));
            }
            b"f" => self.face(rest, at)?,
            b"g" | b"o" => {
                let name = unescape_fbx_name(&String::from_utf8_lossy(rest));
                let name = (!name.is_empty()).then_some(name);
                if keyword == b"o" {
                    self.flush_group();
                    self.current_object = name;
                    self.group.object = self.current_object.clone();
                } else if name != self.group.group || self.group.object != self.current_object {
                    self.flush_group();
                    self.group.object = self.current_object.clone();
                    self.group.group = name;
                }
            }
            b"usemtl" => {
                let name = String::from_utf8_lossy(rest).into_owned();
                self.current_material = (!name.is_empty()).then_some(name);
            }
            b"mtllib" => self.library(rest),
            // Lines, points, curves, smoothing groups and render attributes draw no surface.
            _ => {}
        }
        Ok(())
    }

    fn number(&self, token: &[u8], at: usize, what: &str) -> Result<f64> {
        std::str::from_utf8(token)
            .ok()
            .and_then(|t| t.parse::<f64>().ok())
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                self.err(
                    at,
                    format!(
                        "{what}: '{}' is not a number",
                        String::from_utf8_lossy(token)
                    ),
                )
            })
    }

    fn numbers<const N: usize>(&self, rest: &[u8], at: usize, what: &str) -> Result<[f64; N]> {
        let mut out = [0.0; N];
        let mut tokens = rest
            .split(|b| b.is_ascii_whitespace())
            .filter(|t| !t.is_empty());
        for v in &mut out {
            let t = tokens
                .next()
                .ok_or_else(|| self.err(at, format!("{what} has fewer than {N} numbers")))?;
            *v = self.number(t, at, what)?;
        }
        Ok(out)
    }

    /// `mtllib` names one or more libraries beside the file (inside its folder).
    fn library(&mut self, rest: &[u8]) {
        let names = String::from_utf8_lossy(rest).into_owned();
        // Names may hold spaces: the whole rest first, then its words.
        if self.read_library(&names) {
            return;
        }
        for name in names.split_whitespace() {
            if !self.read_library(name) {
                self.missing_libraries.push(name.to_string());
            }
        }
    }

    fn read_library(&mut self, name: &str) -> bool {
        let path = crate::uri::confine::inside(&self.base_dir, name, &crate::uri::confine::INPUT)
            .ok()
            .or_else(|| {
                let bare = name.rsplit(['/', '\\']).next()?;
                crate::uri::confine::inside(&self.base_dir, bare, &crate::uri::confine::INPUT).ok()
            });
        let Some(text) = path.and_then(|p| super::read_regular(&p).ok()) else {
            return false;
        };
        self.library
            .extend(mtl::parse_mtl(&String::from_utf8_lossy(&text)));
        true
    }

    /// The scene material of the current `usemtl` (made on first use).
    fn material(&mut self) -> Option<UsedMaterial> {
        let name = self.current_material.as_ref()?;
        if let Some(&m) = self.used.get(name) {
            return Some(m);
        }
        let name = name.clone();
        let source = match self.library.get(&name) {
            Some(m) => m.clone(),
            None => {
                self.undefined_materials.push(name.clone());
                mtl::MtlMaterial::default()
            }
        };
        let texture = source.diffuse_map.as_ref().and_then(|map| {
            let image = self.textures.image(&map.file, &mut self.scene)?;
            let wrap = if map.clamp {
                Sampler::CLAMP_TO_EDGE
            } else {
                Sampler::REPEAT
            };
            Some(TextureRef::on_first_uvs(image, wrap))
        });
        let [r, g, b] = source.diffuse;
        let id = MaterialId(self.scene.materials.len() as u32);
        self.scene.materials.push(Material {
            name: Some(name.clone()),
            base_color: [r, g, b, source.opacity],
            metallic: 0.0,
            roughness: 1.0,
            emissive: [0.0; 3],
            alpha_mode: if source.opacity < 1.0 {
                AlphaMode::Blend
            } else {
                AlphaMode::Opaque
            },
            alpha_cutoff: 0.5,
            double_sided: true,
            base_color_texture: texture.clone(),
        });
        let map = source.diffuse_map.as_ref();
        let used = UsedMaterial {
            id,
            uv_scale: map.map_or([1.0; 2], |m| m.scale),
            uv_offset: map.map_or([0.0; 2], |m| m.offset),
            textured: texture.is_some(),
        };
        self.used.insert(name, used);
        Some(used)
    }

    /// A pool index as written (1-based, or negative from the end) checked against the pool.
    fn index(&self, token: &[u8], pool: usize, at: usize, what: &str) -> Result<u32> {
        let bad = || {
            self.err(
                at,
                format!(
                    "face: {what} index '{}' is not in 1..={pool} (or -1..=-{pool})",
                    String::from_utf8_lossy(token)
                ),
            )
        };
        let i: i64 = std::str::from_utf8(token)
            .ok()
            .and_then(|t| t.parse().ok())
            .ok_or_else(bad)?;
        let zero_based = match i {
            1.. if (i as u64) <= pool as u64 => i - 1,
            ..=-1 if i.unsigned_abs() <= pool as u64 => pool as i64 + i,
            _ => return Err(bad()),
        };
        Ok(zero_based as u32)
    }

    fn face(&mut self, rest: &[u8], at: usize) -> Result<()> {
        self.seen_geometry = true;
        let mut face = std::mem::take(&mut self.face);
        face.clear();
        for token in rest
            .split(|b| b.is_ascii_whitespace())
            .filter(|t| !t.is_empty())
        {
            let mut parts = token.split(|&b| b == b'/');
            let v = parts.next().unwrap_or_default();
            let v = self.index(v, self.positions.len(), at, "vertex")?;
            let t = match parts.next() {
                Some(t) if !t.is_empty() => {
                    self.index(t, self.uvs.len(), at, "texture coordinate")?
                }
                _ => NONE,
            };
            let n = match parts.next() {
                Some(n) if !n.is_empty() => self.index(n, self.normals.len(), at, "normal")?,
                _ => NONE,
            };
            face.push([v, t, n]);
        }
        if face.len() < 3 {
            self.degenerate_faces += 1;
            self.face = face;
            return Ok(());
        }
        let material = self.material();
        if self.group.first_material.is_none() {
            self.group.first_material = self.current_material.clone();
        }
        let prim = self
            .group
            .by_material
            .entry(material.map(|m| m.id))
            .or_default();
        if face.len() == 3 {
            face.iter().for_each(|&c| prim.push(c));
        } else {
            let points: Vec<DVec3> = face.iter().map(|c| self.positions[c[0] as usize]).collect();
            match crate::geometry::triangulate(&points, &[]) {
                Ok(Some(t)) => t.indices.iter().for_each(|&i| prim.push(face[i])),
                // No area: nothing to draw.
                Ok(None) => {}
                // earcut refused the ring (self-touching): a fan keeps its area.
                Err(_) => {
                    for k in 1..face.len() - 1 {
                        [face[0], face[k], face[k + 1]]
                            .iter()
                            .for_each(|&c| prim.push(c));
                    }
                }
            }
        }
        self.face = face;
        Ok(())
    }

    /// The hierarchy node of the group being read (its object's node above it).
    fn group_node(&mut self) -> NodeId {
        let object = self.group.object.clone();
        let parent = object.as_ref().map(|o| match self.object_nodes.get(o) {
            Some(&n) => n,
            None => {
                let n = NodeId(self.scene.nodes.len() as u32);
                self.scene.nodes.push(Node {
                    name: Some(o.clone()),
                    ..Node::default()
                });
                self.object_nodes.insert(o.clone(), n);
                n
            }
        });
        match (&self.group.group, parent) {
            (None, Some(p)) => p,
            (name, parent) => {
                let stem = self
                    .path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned());
                let n = NodeId(self.scene.nodes.len() as u32);
                self.scene.nodes.push(Node {
                    name: name.clone().or(stem),
                    parent,
                    ..Node::default()
                });
                n
            }
        }
    }

    /// Hands the group read to the scene as one element (nothing when it has no faces).
    fn flush_group(&mut self) {
        let group = std::mem::take(&mut self.group);
        if group.by_material.values().all(|p| p.indices.is_empty()) {
            self.group.object = group.object;
            return;
        }
        self.group.object = group.object.clone();
        let saved = std::mem::replace(&mut self.group, group);
        let node = self.group_node();
        let group = std::mem::replace(&mut self.group, saved);
        let origin = group
            .by_material
            .values()
            .flat_map(|p| &p.corners)
            .fold(DVec3::splat(f64::INFINITY), |a, c| {
                a.min(self.positions[c[0] as usize])
            });
        let name = group
            .group
            .clone()
            .or(group.object.clone())
            .unwrap_or_else(|| {
                self.scene.nodes[node.index()]
                    .name
                    .clone()
                    .unwrap_or_default()
            });
        let mut mesh = Mesh {
            name: Some(name.clone()),
            ..Mesh::default()
        };
        let textured: HashMap<MaterialId, UsedMaterial> =
            self.used.values().map(|u| (u.id, *u)).collect();
        for (material, p) in group.by_material {
            let positions: Vec<[f32; 3]> = p
                .corners
                .iter()
                .map(|c| {
                    (self.positions[c[0] as usize] - origin)
                        .as_vec3()
                        .to_array()
                })
                .collect();
            let mut normals: Vec<[f32; 3]> = p
                .corners
                .iter()
                .map(|c| match c[2] {
                    NONE => [f32::NAN; 3],
                    n => unit_normal_or_z(self.normals[n as usize]),
                })
                .collect();
            if normals.iter().any(|n| n[0].is_nan()) {
                let mut from_faces = vec![[0.0; 3]; positions.len()];
                crate::geometry::normals_from_faces(&positions, &p.indices, &mut from_faces);
                for (n, f) in normals.iter_mut().zip(from_faces) {
                    if n[0].is_nan() {
                        *n = unit_normal_or_z(f);
                    }
                }
            }
            let used = material
                .and_then(|m| textured.get(&m))
                .filter(|u| u.textured);
            let uvs = used.map(|u| {
                p.corners
                    .iter()
                    .map(|c| {
                        let [s, t] = match c[1] {
                            NONE => [0.0, 0.0],
                            i => self.uvs[i as usize],
                        };
                        // OBJ's v runs up from the image's bottom, glTF's down from its top.
                        let s = s * u.uv_scale[0] + u.uv_offset[0];
                        let t = t * u.uv_scale[1] + u.uv_offset[1];
                        [s, 1.0 - t]
                    })
                    .collect()
            });
            mesh.primitives.push(Primitive {
                material,
                positions,
                normals: Some(normals),
                uvs,
                colors: None,
                indices: p.indices,
            });
        }
        let mut info = ElementInfo::keyed(name.clone());
        info.name = Some(name.clone());
        info.class = Some(self.texts.get(match group.group {
            Some(_) => "ObjGroup",
            None if group.object.is_some() => "ObjObject",
            None => "ObjUngrouped",
        }));
        info.material = group.first_material.as_deref().map(|m| self.texts.get(m));
        if let Some(id) = revit_element_id(&name) {
            info.properties.push(Property {
                set: self.texts.get("revit"),
                name: self.texts.get("element_id"),
                value: PropertyValue::Integer(id),
            });
        }
        let mesh_id = self.scene.meshes.push(mesh);
        let world = self.frame.to_scene() * DMat4::from_translation(origin);
        let component = Component {
            node: Some(node),
            ..Component::new(mesh_id, world)
        };
        self.scene.push_component(component, &info);
    }

    fn finish(mut self) -> Result<Scene> {
        self.flush_group();
        let warnings = &mut self.scene.reader_warnings;
        let file = self.path.display();
        if !self.missing_libraries.is_empty() {
            warnings.push(format!(
                "{file}: material libraries not found or unreadable ({}): their materials are drawn plain",
                self.missing_libraries.join(", ")
            ));
        }
        if !self.undefined_materials.is_empty() {
            warnings.push(format!(
                "{file}: {} materials used but not defined ({}): drawn plain grey",
                self.undefined_materials.len(),
                self.undefined_materials
                    .iter()
                    .take(3)
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        if self.degenerate_faces > 0 {
            warnings.push(format!(
                "{file}: {} faces with fewer than three corners were skipped",
                self.degenerate_faces
            ));
        }
        let texture_warnings = self.textures.warnings(self.path);
        self.scene.reader_warnings.extend(texture_warnings);
        super::keep_ids_unique(&mut self.scene);
        self.scene.finish();
        Ok(self.scene)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<Scene> {
        read_obj_from(Path::new("t.obj"), text.as_bytes(), MeshFrame::default())
    }

    fn area(scene: &Scene) -> f64 {
        scene
            .components
            .iter()
            .map(|c| {
                let m = scene.mesh(c.mesh);
                m.primitives
                    .iter()
                    .map(|p| {
                        p.indices
                            .chunks_exact(3)
                            .map(|t| {
                                let v = |i: u32| {
                                    c.world.transform_point3(DVec3::from_array(
                                        p.positions[i as usize].map(f64::from),
                                    ))
                                };
                                (v(t[1]) - v(t[0])).cross(v(t[2]) - v(t[0])).length() / 2.0
                            })
                            .sum::<f64>()
                    })
                    .sum::<f64>()
            })
            .sum()
    }

    #[test]
    fn groups_polygons_and_negative_indices() {
        let s = read(
            "v 0 0 0\nv 2 0 0\nv 2 0 2\nv 0 0 2\nv 1 0 3\nf 1 2 3\ng wall [42]\nf -5 -4 -3 -2 -1\no thing\nf 1 2 4\n",
        )
        .unwrap();
        assert_eq!(s.components.len(), 3);
        let keys: Vec<String> = s.elements.iter().map(|e| e.key).collect();
        assert_eq!(keys, ["t", "wall [42]", "thing"]);
        let wall = s.element(ComponentId(1));
        assert!(wall
            .properties
            .iter()
            .any(|p| &*p.name == "element_id" && p.value == PropertyValue::Integer(42)));
        // 2 + (4 + 1) + 2 square metres.
        assert!((area(&s) - 9.0).abs() < 1e-9, "{}", area(&s));
        // y up: the model's +y (up) is the scene's +z; the pentagon lies in y = 0.
        let b = s.bounds();
        assert!(b.min.z.abs() < 1e-12 && b.max.z.abs() < 1e-12);
    }

    #[test]
    fn bad_indices_and_numbers_name_the_line() {
        let e = read("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.obj") && e.contains("line 4") && e.contains("'4'"),
            "{e}"
        );
        let e = read("v 0 0 x\n").unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("'x'"), "{e}");
        let e = read("v 0 0 0\nf 0 1 1\n").unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
        let e = read("v 0 0\n").unwrap_err().to_string();
        assert!(e.contains("fewer than 3"), "{e}");
    }

    #[test]
    fn units_scale_and_continuation_lines_join() {
        let s = read_obj_from(
            Path::new("t.obj"),
            "v 0 0 0\nv 100 0 0\nv 0 \\\n 100 0\nf 1 2 3\n".as_bytes(),
            MeshFrame {
                up: Some(super::super::interchange::UpAxis::Z),
                unit: Some(LengthUnit::Cm),
            },
        )
        .unwrap();
        assert!((area(&s) - 0.5).abs() < 1e-9);
        let s = read("# This file uses centimeters as units for non-parametric coordinates.\nv 0 0 0\nv 100 0 0\nv 0 100 0\nf 1 2 3\n").unwrap();
        assert!((area(&s) - 0.5).abs() < 1e-9);
    }
}
