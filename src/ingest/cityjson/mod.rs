//! CityJSON reader (1.0, 1.1, 2.0 `.json`, and CityJSONSeq `.city.jsonl`; CityJSON 2.0 spec §3
//! CityObjects, §4 geometry objects, §5 transform, §8 appearance).
//!
//! Every CityObject with geometry becomes an element: its id is the CityObject id, its class the
//! CityObject type, its attributes typed properties (set `attributes`), and its parents (Building
//! → BuildingPart) the hierarchy path. One LoD of each object is read: its highest, or the one
//! asked for (`--cityjson-lod`). Surfaces keep their semantics by being split per semantic type:
//! each type is one primitive with its own material (named `RoofSurface`, `WallSurface`…,
//! coloured so roofs and walls differ), and each element lists its triangles per type as
//! properties of the set `semantics`. A textured surface ([`appearance`]) gets a material with
//! its image and its UVs. Polygons (with holes) are triangulated by `earcutr` on their best-fit
//! plane. Vertices are read in f64 (`transform` applied) and each object's mesh is stored
//! relative to its own corner, placed by its component transform, so projected coordinates keep
//! their millimetres; `metadata.referenceSystem` is returned for the placement
//! ([`crate::ingest::read_input_with`]).

pub(crate) mod appearance;

use crate::error::{Error, Result};
use crate::geometry::triangulate;
use crate::scene::*;
use appearance::{DocumentTextures, ImageFiles};
use glam::{DMat4, DVec3};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

/// Whether a file is CityJSON or CityJSONSeq: by name (`.city.json`, `.jsonl`) or, for a plain
/// `.json`, by its opening bytes naming the type.
pub fn is_cityjson(path: &Path) -> bool {
    let name = super::lowercase_name(path);
    if name.ends_with(".city.json") || name.ends_with(".jsonl") {
        return true;
    }
    if !name.ends_with(".json") {
        return false;
    }
    let head = super::file_head(path, 4096);
    let text = String::from_utf8_lossy(&head);
    // The "type" member may come last (3dfier writes "CityObjects" first).
    text.contains("\"CityJSON\"") || text.contains("\"CityObjects\"")
}

/// Colours of the semantic surface types (linear RGBA), so a viewer tells them apart.
pub(crate) const SEMANTIC_COLOURS: &[(&str, [f32; 4])] = &[
    ("RoofSurface", [0.55, 0.12, 0.08, 1.0]),
    ("WallSurface", [0.80, 0.78, 0.72, 1.0]),
    ("GroundSurface", [0.30, 0.30, 0.30, 1.0]),
    ("ClosureSurface", [0.60, 0.60, 0.80, 1.0]),
    ("OuterCeilingSurface", [0.70, 0.70, 0.65, 1.0]),
    ("OuterFloorSurface", [0.45, 0.45, 0.45, 1.0]),
    ("Window", [0.35, 0.55, 0.75, 1.0]),
    ("Door", [0.45, 0.30, 0.20, 1.0]),
];
/// Surfaces without semantics.
pub(crate) const NO_SEMANTICS: &str = "Surface";

/// A CityJSON file read: its scene (in the file's coordinates) and the CRS its
/// `metadata.referenceSystem` names ("EPSG:7415"), if any.
#[derive(Debug)]
pub struct CityModel {
    pub scene: Scene,
    pub reference_system: Option<String>,
}

/// Reads a CityJSON or CityJSONSeq file into a new scene, each object at `lod` ("2.2"; `None`:
/// its highest). A `lod` no object has is an error naming the LoDs present.
pub fn read_cityjson(path: &Path, lod: Option<&str>) -> Result<CityModel> {
    let text = super::read_regular(path).map_err(|e| Error::input_from(path, "cannot read", e))?;
    let is_seq = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("jsonl"));
    let mut reader = Reader::new(path, lod);
    if is_seq {
        let mut lines = text
            .split(|&b| b == b'\n')
            .enumerate()
            .filter(|(_, l)| l.iter().any(|b| !b.is_ascii_whitespace()));
        let (_, head) = lines
            .next()
            .ok_or_else(|| Error::input(path, "empty CityJSONSeq file"))?;
        let header: Value = serde_json::from_slice(head)
            .map_err(|e| Error::input_from(path, "line 1: invalid JSON", e))?;
        reader.header(&header)?;
        for (i, line) in lines {
            let feature: Value = serde_json::from_slice(line)
                .map_err(|e| Error::input_from(path, format!("line {}: invalid JSON", i + 1), e))?;
            reader.document(&feature, &format!("line {}", i + 1))?;
        }
    } else {
        let doc: Value = serde_json::from_slice(&text)
            .map_err(|e| Error::input_from(path, "invalid JSON", e))?;
        reader.header(&doc)?;
        reader.document(&doc, "CityObjects")?;
    }
    let reference_system = reader.reference_system.clone();
    let mut scene = reader.finish()?;
    scene.sources.push(SourceFile {
        path: path.to_path_buf(),
        bytes: text.len() as u64,
    });
    scene.finish();
    Ok(CityModel {
        scene,
        reference_system,
    })
}

/// The CRS of a `metadata.referenceSystem`: an EPSG URL (`https://www.opengis.net/def/crs/EPSG/0/7415`)
/// or URN (`urn:ogc:def:crs:EPSG::7415`) becomes `EPSG:7415`; other texts go to PROJ as written.
pub fn reference_system_crs(text: &str) -> String {
    let t = text.trim();
    let code = t.rsplit(['/', ':']).next().unwrap_or("");
    let is_epsg = t.to_ascii_uppercase().contains("EPSG");
    if is_epsg && !code.is_empty() && code.chars().all(|c| c.is_ascii_digit()) {
        format!("EPSG:{code}")
    } else {
        t.to_string()
    }
}

/// An LoD as written (`"2.2"`, or a number in CityJSON 1.0), as text.
fn lod_text(g: &Value) -> String {
    match g.get("lod") {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Number(n)) => n.to_string(),
        _ => "0".into(),
    }
}

/// Whether two LoD texts name the same LoD ("2" and "2.0" do).
fn same_lod(a: &str, b: &str) -> bool {
    match (a.parse::<f64>(), b.parse::<f64>()) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

/// Triangles of one material, in f64 world coordinates, each corner with its normal (and UV when
/// the material is textured).
#[derive(Default)]
pub(crate) struct Triangles {
    pub(crate) corners: Vec<DVec3>,
    pub(crate) normals: Vec<DVec3>,
    pub(crate) uvs: Vec<[f32; 2]>,
}

/// One object's triangles: per material, and counted per semantic type.
#[derive(Default)]
pub(crate) struct ObjectTriangles {
    pub(crate) by_material: BTreeMap<MaterialId, Triangles>,
    pub(crate) per_semantic: BTreeMap<String, i64>,
}

/// What a polygon is drawn with: its semantic type and, when textured, its texture.
struct SurfaceLook<'v> {
    semantic: &'v str,
    /// The ring texture values of the polygon (`[[t, uv…], …]`, one list per ring).
    texture_rings: Option<&'v Value>,
}

struct Reader<'a> {
    path: &'a Path,
    base_dir: std::path::PathBuf,
    lod_wanted: Option<&'a str>,
    /// Every LoD of a surface geometry seen (for the error on a LoD no object has).
    lods_present: BTreeSet<String>,
    /// Objects with geometry but none at the LoD asked for.
    objects_without_lod: usize,
    reference_system: Option<String>,
    scale: DVec3,
    translate: DVec3,
    scene: Scene,
    texts: TextInterner,
    /// The sequence header's appearance (features without their own use it).
    header_appearance: Option<Value>,
    images: ImageFiles,
    /// Material of each semantic type and texture, made on first use.
    materials: HashMap<(String, Option<TextureRef>), MaterialId>,
    /// CityObject id → its hierarchy node.
    node_of: HashMap<String, NodeId>,
    /// (child node, parent CityObject id), linked once every object is known.
    parents: Vec<(NodeId, String)>,
}

impl<'a> Reader<'a> {
    fn new(path: &'a Path, lod_wanted: Option<&'a str>) -> Self {
        Reader {
            path,
            base_dir: path.parent().unwrap_or(Path::new("")).to_path_buf(),
            lod_wanted,
            lods_present: BTreeSet::new(),
            objects_without_lod: 0,
            reference_system: None,
            scale: DVec3::ONE,
            translate: DVec3::ZERO,
            scene: Scene::default(),
            texts: TextInterner::default(),
            header_appearance: None,
            images: ImageFiles::default(),
            materials: HashMap::new(),
            node_of: HashMap::new(),
            parents: Vec::new(),
        }
    }

    fn err(&self, m: impl Into<String>) -> Error {
        Error::input(self.path, m)
    }

    /// The file (or sequence header): its type, `transform`, reference system and appearance.
    fn header(&mut self, doc: &Value) -> Result<()> {
        if doc.get("type").and_then(Value::as_str) != Some("CityJSON") {
            return Err(self.err("not a CityJSON file (no \"type\": \"CityJSON\")"));
        }
        if let Some(t) = doc.get("transform") {
            let vec3 = |key: &str| -> Option<DVec3> {
                let a = t.get(key)?.as_array()?;
                Some(DVec3::new(
                    a.first()?.as_f64()?,
                    a.get(1)?.as_f64()?,
                    a.get(2)?.as_f64()?,
                ))
            };
            self.scale =
                vec3("scale").ok_or_else(|| self.err("transform.scale is not 3 numbers"))?;
            self.translate = vec3("translate")
                .ok_or_else(|| self.err("transform.translate is not 3 numbers"))?;
        }
        self.reference_system = doc
            .pointer("/metadata/referenceSystem")
            .and_then(Value::as_str)
            .map(reference_system_crs);
        self.header_appearance = doc.get("appearance").cloned();
        Ok(())
    }

    /// The CityObjects of a CityJSON file or of one CityJSONFeature, with its own `vertices`
    /// (and `appearance`).
    fn document(&mut self, doc: &Value, what: &str) -> Result<()> {
        let vertices = doc
            .get("vertices")
            .and_then(Value::as_array)
            .ok_or_else(|| self.err(format!("{what}: no \"vertices\" array")))?;
        let mut points = Vec::with_capacity(vertices.len());
        for (i, v) in vertices.iter().enumerate() {
            let c = v.as_array().filter(|a| a.len() >= 3);
            let xyz = c.and_then(|a| Some([a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?]));
            let xyz =
                xyz.ok_or_else(|| self.err(format!("{what}: vertex {i} is not 3 numbers")))?;
            points.push(DVec3::from_array(xyz) * self.scale + self.translate);
        }
        let textures = match doc.get("appearance").or(self.header_appearance.as_ref()) {
            Some(a) => {
                let a = a.clone();
                self.images
                    .document_textures(&a, &self.base_dir, &mut self.scene)
            }
            None => DocumentTextures::default(),
        };
        let objects = doc
            .get("CityObjects")
            .and_then(Value::as_object)
            .ok_or_else(|| self.err(format!("{what}: no \"CityObjects\" object")))?;
        for (id, object) in objects {
            self.object(id, object, &points, &textures)?;
        }
        Ok(())
    }

    /// The surface geometries of an object at the LoD read (its highest, or the one asked for).
    fn geometries_at_lod<'v>(&mut self, object: &'v Value) -> Vec<&'v Value> {
        let surfaces_of = |g: &Value| {
            matches!(
                g.get("type").and_then(Value::as_str),
                Some(
                    "MultiSurface" | "CompositeSurface" | "Solid" | "MultiSolid" | "CompositeSolid"
                )
            )
        };
        // Surface geometries only (points and lines draw nothing).
        let geometries: Vec<&Value> = object
            .get("geometry")
            .and_then(Value::as_array)
            .map(|g| g.iter().filter(|g| surfaces_of(g)).collect())
            .unwrap_or_default();
        self.lods_present
            .extend(geometries.iter().map(|g| lod_text(g)));
        let chosen = match self.lod_wanted {
            Some(wanted) => wanted.to_string(),
            // The highest (3D BAG: LoD 0, 1.2, 1.3 and 2.2 of the same building).
            None => geometries
                .iter()
                .map(|g| lod_text(g))
                .max_by(|a, b| {
                    let n = |s: &str| s.parse::<f64>().unwrap_or(0.0);
                    n(a).total_cmp(&n(b))
                })
                .unwrap_or_default(),
        };
        let at_lod: Vec<&Value> = geometries
            .iter()
            .copied()
            .filter(|g| same_lod(&lod_text(g), &chosen))
            .collect();
        if at_lod.is_empty() && !geometries.is_empty() {
            self.objects_without_lod += 1;
        }
        at_lod
    }

    fn object(
        &mut self,
        id: &str,
        object: &Value,
        points: &[DVec3],
        textures: &DocumentTextures,
    ) -> Result<()> {
        let node = NodeId(self.scene.nodes.len() as u32);
        self.scene.nodes.push(Node {
            name: Some(id.to_string()),
            ..Node::default()
        });
        self.node_of.insert(id.to_string(), node);
        if let Some(p) = object
            .get("parents")
            .and_then(Value::as_array)
            .and_then(|p| p.first())
            .and_then(Value::as_str)
        {
            self.parents.push((node, p.to_string()));
        }
        let mut triangles = ObjectTriangles::default();
        let what = format!("CityObject {id}");
        for g in self.geometries_at_lod(object) {
            self.geometry(g, points, textures, &what, &mut triangles)?;
        }
        if triangles.by_material.is_empty() {
            return Ok(());
        }
        let mut info = ElementInfo::keyed(id);
        for (semantic, count) in &triangles.per_semantic {
            info.properties.push(Property {
                set: self.texts.get("semantics"),
                name: self.texts.get(semantic),
                value: PropertyValue::Integer(*count),
            });
        }
        info.class = object
            .get("type")
            .and_then(Value::as_str)
            .map(|t| self.texts.get(t));
        self.attributes(object, &mut info);
        let (mesh, origin) = object_mesh(id, triangles);
        let mesh_id = self.scene.meshes.push(mesh);
        let component = Component {
            node: Some(node),
            ..Component::new(mesh_id, DMat4::from_translation(origin))
        };
        self.scene.push_component(component, &info);
        Ok(())
    }

    /// The object's `attributes` as typed properties (set `attributes`); `name` also names it.
    fn attributes(&mut self, object: &Value, info: &mut ElementInfo) {
        let Some(attributes) = object.get("attributes").and_then(Value::as_object) else {
            return;
        };
        for (k, v) in attributes {
            // Arrays and objects (addresses, say) are kept as their JSON text.
            let value = match PropertyValue::from_json_scalar(v) {
                Some(value) => value,
                None if v.is_null() => continue,
                None => PropertyValue::Text(v.to_string()),
            };
            if k == "name" {
                info.name = v.as_str().map(str::to_string);
            }
            info.properties.push(Property {
                set: self.texts.get("attributes"),
                name: self.texts.get(k),
                value,
            });
        }
        info.properties.shrink_to_fit();
    }

    /// The material of a semantic type, plain or with a texture (made once).
    fn material(&mut self, semantic: &str, texture: Option<&TextureRef>) -> MaterialId {
        let key = (semantic.to_string(), texture.cloned());
        if let Some(&m) = self.materials.get(&key) {
            return m;
        }
        let id = push_surface_material(&mut self.scene, semantic, None, texture);
        self.materials.insert(key, id);
        id
    }

    /// Triangulates one geometry's surfaces into `out` (per material).
    fn geometry(
        &mut self,
        g: &Value,
        points: &[DVec3],
        textures: &DocumentTextures,
        what: &str,
        out: &mut ObjectTriangles,
    ) -> Result<()> {
        let kind = g.get("type").and_then(Value::as_str).unwrap_or("");
        let boundaries = g
            .get("boundaries")
            .ok_or_else(|| self.err(format!("{what}: {kind} without boundaries")))?;
        // Depth of the surface level: MultiSurface [surface], Solid [shell][surface],
        // MultiSolid [solid][shell][surface]; semantics.values and texture values have the same
        // nesting down to the surface.
        let depth = match kind {
            "MultiSurface" | "CompositeSurface" => 0,
            "Solid" => 1,
            _ => 2,
        };
        let surfaces_sem = g.pointer("/semantics/surfaces").and_then(Value::as_array);
        let values = g.pointer("/semantics/values");
        let texture_values = g
            .get("texture")
            .and_then(Value::as_object)
            .and_then(|themes| {
                let theme = textures
                    .default_theme
                    .as_deref()
                    .and_then(|t| themes.get(t))
                    .or_else(|| themes.values().next())?;
                theme.get("values")
            });
        type Level<'v> = (&'v Value, Option<&'v Value>, Option<&'v Value>, usize);
        let mut stack: Vec<Level> = vec![(boundaries, values, texture_values, depth)];
        while let Some((b, v, t, d)) = stack.pop() {
            let list = b
                .as_array()
                .ok_or_else(|| self.err(format!("{what}: boundaries are not arrays")))?;
            for (k, item) in list.iter().enumerate() {
                let v_item = v.and_then(|v| v.as_array()).and_then(|a| a.get(k));
                let t_item = t.and_then(|t| t.as_array()).and_then(|a| a.get(k));
                if d > 0 {
                    stack.push((item, v_item, t_item, d - 1));
                    continue;
                }
                let semantic = v_item
                    .and_then(Value::as_u64)
                    .and_then(|i| surfaces_sem?.get(i as usize))
                    .and_then(|s| s.get("type"))
                    .and_then(Value::as_str)
                    .unwrap_or(NO_SEMANTICS);
                let look = SurfaceLook {
                    semantic,
                    texture_rings: t_item,
                };
                self.surface(item, points, textures, &look, what, out)?;
            }
        }
        Ok(())
    }

    /// One polygon (outer ring, then holes) triangulated on its best-fit plane.
    fn surface(
        &mut self,
        rings: &Value,
        points: &[DVec3],
        textures: &DocumentTextures,
        look: &SurfaceLook<'_>,
        what: &str,
        out: &mut ObjectTriangles,
    ) -> Result<()> {
        let rings = rings
            .as_array()
            .ok_or_else(|| self.err(format!("{what}: a surface is not a list of rings")))?;
        let mut ring_points: Vec<DVec3> = Vec::new();
        let mut holes: Vec<usize> = Vec::new();
        // The polygon's texture (its outer ring's) and the UV of each corner, while every ring
        // has UVs that fit it.
        let mut texture: Option<TextureRef> = None;
        let mut uvs: Option<Vec<[f32; 2]>> = Some(Vec::new());
        for (r, ring) in rings.iter().enumerate() {
            let ring = ring
                .as_array()
                .ok_or_else(|| self.err(format!("{what}: a ring is not a list of vertices")))?;
            if r > 0 {
                holes.push(ring_points.len());
            }
            for i in ring {
                let p = i
                    .as_u64()
                    .and_then(|i| points.get(i as usize))
                    .ok_or_else(|| {
                        self.err(format!(
                            "{what}: vertex index {i} is out of range ({} vertices)",
                            points.len()
                        ))
                    })?;
                ring_points.push(*p);
            }
            let ring_values = look
                .texture_rings
                .and_then(Value::as_array)
                .and_then(|a| a.get(r));
            let fitted = appearance::ring_texture(ring_values, ring.len()).and_then(|(t, idx)| {
                let t = textures.textures.get(t)?.clone()?;
                let ring_uvs: Option<Vec<[f32; 2]>> =
                    idx.iter().map(|&i| textures.uvs.get(i).copied()).collect();
                Some((t, ring_uvs?))
            });
            match (fitted, uvs.as_mut()) {
                (Some((t, ring_uvs)), Some(all)) => {
                    texture.get_or_insert(t);
                    all.extend(ring_uvs);
                }
                _ => uvs = None,
            }
        }
        let texture = texture.filter(|_| uvs.is_some());
        let Some(corners) = triangulate(&ring_points, &holes)
            .map_err(|e| self.err(format!("{what}: polygon not triangulated: {e}")))?
        else {
            return Ok(()); // A degenerate polygon covers no area.
        };
        let material = self.material(look.semantic, texture.as_ref());
        let into = out.by_material.entry(material).or_default();
        *out.per_semantic
            .entry(look.semantic.to_string())
            .or_default() += (corners.indices.len() / 3) as i64;
        for &i in &corners.indices {
            into.corners.push(ring_points[i]);
            into.normals.push(corners.normal);
            if let (Some(_), Some(uvs)) = (&texture, &uvs) {
                into.uvs.push(uvs[i]);
            }
        }
        Ok(())
    }

    /// Links parents and hands the scene over, with the warnings of the read; a LoD no object
    /// has is an error naming those present.
    fn finish(mut self) -> Result<Scene> {
        if let Some(wanted) = self.lod_wanted {
            if self.scene.components.is_empty() {
                let present: Vec<&str> = self.lods_present.iter().map(String::as_str).collect();
                return Err(self.err(format!(
                    "--cityjson-lod {wanted}: no object has geometry at LoD {wanted}; the LoDs present are {}",
                    if present.is_empty() { "none".into() } else { present.join(", ") }
                )));
            }
            if self.objects_without_lod > 0 {
                let line = format!(
                    "{}: {} CityObjects with geometry have none at LoD {wanted} and are left out (--cityjson-lod)",
                    self.path.display(),
                    self.objects_without_lod
                );
                self.scene.reader_warnings.push(line);
            }
        }
        if let Some(line) = self.images.missing_warning(self.path) {
            self.scene.reader_warnings.push(line);
        }
        for (child, parent) in std::mem::take(&mut self.parents) {
            if let Some(&p) = self.node_of.get(&parent) {
                if p != child {
                    self.scene.nodes[child.index()].parent = Some(p);
                }
            }
        }
        Ok(self.scene)
    }
}

/// A new material for a semantic surface type: its colour from [`SEMANTIC_COLOURS`] unless one is
/// given, white under a texture (a texture shows its own colours), named after the type and image.
pub(crate) fn push_surface_material(
    scene: &mut Scene,
    semantic: &str,
    colour: Option<[f32; 4]>,
    texture: Option<&TextureRef>,
) -> MaterialId {
    let colour = colour.unwrap_or_else(|| {
        SEMANTIC_COLOURS
            .iter()
            .find(|(s, _)| *s == semantic)
            .map_or([0.75, 0.75, 0.75, 1.0], |(_, c)| *c)
    });
    let id = MaterialId(scene.materials.len() as u32);
    let name = match texture {
        None => semantic.to_string(),
        Some(t) => {
            let image = &scene.images[t.image.index()];
            format!("{semantic} {}", image.name.as_deref().unwrap_or(""))
        }
    };
    scene.materials.push(Material {
        name: Some(name),
        base_color: if texture.is_some() { [1.0; 4] } else { colour },
        metallic: 0.0,
        roughness: 1.0,
        emissive: [0.0; 3],
        base_color_texture: texture.cloned(),
        alpha_mode: if colour[3] < 1.0 && texture.is_none() {
            AlphaMode::Blend
        } else {
            AlphaMode::Opaque
        },
        alpha_cutoff: 0.5,
        double_sided: true,
    });
    id
}

/// An object's mesh, relative to its lowest corner (returned: the component's translation), so
/// f32 positions keep projected coordinates' millimetres.
pub(crate) fn object_mesh(id: &str, triangles: ObjectTriangles) -> (Mesh, DVec3) {
    let origin = triangles
        .by_material
        .values()
        .flat_map(|t| &t.corners)
        .fold(DVec3::splat(f64::INFINITY), |a, &p| a.min(p));
    let mut mesh = Mesh {
        name: Some(id.to_string()),
        ..Mesh::default()
    };
    for (material, t) in triangles.by_material {
        mesh.primitives.push(Primitive {
            material: Some(material),
            positions: t
                .corners
                .iter()
                .map(|p| (*p - origin).as_vec3().to_array())
                .collect(),
            normals: Some(t.normals.iter().map(|n| n.as_vec3().to_array()).collect()),
            uvs: (!t.uvs.is_empty()).then_some(t.uvs),
            colors: None,
            indices: (0..t.corners.len() as u32).collect(),
        });
    }
    (mesh, origin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_square_with_a_hole_is_triangulated_to_its_area() {
        let doc = serde_json::json!({
            "type": "CityJSON", "version": "2.0",
            "transform": {"scale": [0.001, 0.001, 0.001], "translate": [100000.0, 400000.0, 0.0]},
            "vertices": [[0,0,0],[10000,0,0],[10000,10000,0],[0,10000,0],
                         [2000,2000,0],[2000,4000,0],[4000,4000,0],[4000,2000,0]],
            "CityObjects": {
                "b1": {"type": "Building", "attributes": {"yearOfConstruction": 1990, "name": "B"},
                       "children": ["b1-0"]},
                "b1-0": {"type": "BuildingPart", "parents": ["b1"],
                         "geometry": [
                            {"type": "MultiSurface", "lod": "1", "boundaries": [[[0,1,2]]]},
                            {"type": "MultiSurface", "lod": "2.2",
                             "boundaries": [[[0,1,2,3],[4,5,6,7]]],
                             "semantics": {"surfaces": [{"type": "RoofSurface"}], "values": [0]}}]}
            }
        });
        let path = Path::new("test.city.json");
        let mut r = Reader::new(path, None);
        r.header(&doc).unwrap();
        r.document(&doc, "CityObjects").unwrap();
        let mut scene = r.finish().unwrap();
        scene.finish();
        assert_eq!(scene.components.len(), 1, "b1 has no geometry");
        let info = scene.element(ComponentId(0));
        assert_eq!(info.key, "b1-0");
        assert_eq!(
            scene.node_path(scene.components[0].node.unwrap()),
            "b1/b1-0"
        );
        let mesh = scene.mesh(scene.components[0].mesh);
        assert_eq!(mesh.primitives.len(), 1);
        assert_eq!(scene.materials[0].name.as_deref(), Some("RoofSurface"));
        let p = &mesh.primitives[0];
        let area: f64 = p
            .indices
            .chunks_exact(3)
            .map(|t| {
                let v = |i: u32| DVec3::from_array(p.positions[i as usize].map(f64::from));
                (v(t[1]) - v(t[0])).cross(v(t[2]) - v(t[0])).length() / 2.0
            })
            .sum();
        assert!(
            (area - 96.0).abs() < 1e-6,
            "100 m² minus a 4 m² hole: {area}"
        );
        let b = scene.components[0].world_bounds;
        assert!((b.min - DVec3::new(100000.0, 400000.0, 0.0)).length() < 1e-9);
    }

    #[test]
    fn reference_systems_name_their_epsg_code() {
        for (text, crs) in [
            ("https://www.opengis.net/def/crs/EPSG/0/7415", "EPSG:7415"),
            ("http://www.opengis.net/def/crs/EPSG/0/28992", "EPSG:28992"),
            ("urn:ogc:def:crs:EPSG::7415", "EPSG:7415"),
            ("urn:ogc:def:crs:EPSG:6.18:3:2056", "EPSG:2056"),
            ("ETRS89 / UTM zone 32N", "ETRS89 / UTM zone 32N"),
        ] {
            assert_eq!(reference_system_crs(text), crs, "{text}");
        }
    }

    #[test]
    fn a_lod_no_object_has_names_the_lods_present() {
        let doc = serde_json::json!({"type": "CityJSON", "vertices": [[0,0,0],[1,0,0],[0,1,0]],
            "CityObjects": {"x": {"type": "Building", "geometry": [
                {"type": "MultiSurface", "lod": "1.2", "boundaries": [[[0, 1, 2]]]},
                {"type": "MultiSurface", "lod": 2, "boundaries": [[[0, 1, 2]]]}]}}});
        let path = Path::new("lods.city.json");
        let read = |lod| {
            let mut r = Reader::new(path, lod);
            r.header(&doc).unwrap();
            r.document(&doc, "CityObjects").unwrap();
            r.finish()
        };
        assert_eq!(read(Some("2.0")).unwrap().components.len(), 1, "2 is 2.0");
        let e = read(Some("3")).unwrap_err().to_string();
        assert!(e.contains("lods.city.json") && e.contains("1.2, 2"), "{e}");
    }

    #[test]
    fn bad_input_is_an_error_naming_the_problem() {
        let path = Path::new("bad.city.json");
        let mut r = Reader::new(path, None);
        let e = r
            .header(&serde_json::json!({"type": "FeatureCollection"}))
            .unwrap_err();
        assert!(e.to_string().contains("not a CityJSON"), "{e}");
        let doc = serde_json::json!({"type": "CityJSON", "vertices": [[0,0,0]],
            "CityObjects": {"x": {"type": "Building", "geometry": [
                {"type": "MultiSurface", "lod": "1", "boundaries": [[[0, 1, 7]]]}]}}});
        let e = r.document(&doc, "CityObjects").unwrap_err();
        assert!(e.to_string().contains("out of range"), "{e}");
    }
}
