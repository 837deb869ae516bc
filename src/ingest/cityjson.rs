//! CityJSON reader (1.0, 1.1, 2.0 `.json`, and CityJSONSeq `.city.jsonl`).
//!
//! Every CityObject with geometry becomes an element: its id is the CityObject id, its class the
//! CityObject type, its attributes typed properties (set `attributes`), and its parents (Building
//! → BuildingPart) the hierarchy path. Only the highest LoD of each object is read. Surfaces keep
//! their semantics by being split per semantic type: each type is one primitive with its own
//! material (named `RoofSurface`, `WallSurface`…, coloured so roofs and walls differ), and each
//! element lists its triangles per type as properties of the set `semantics`. Polygons (with
//! holes) are triangulated by `earcutr` on their best-fit plane. Vertices are read in f64
//! (`transform` applied) and each object's mesh is stored relative to its own corner, placed by
//! its component transform, so projected coordinates keep their millimetres.

use crate::error::{Error, Result};
use crate::scene::*;
use glam::{DMat4, DVec3};
use serde_json::Value;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Whether a file is CityJSON or CityJSONSeq: by name (`.city.json`, `.jsonl`) or, for a plain
/// `.json`, by its opening bytes naming the type.
pub fn is_cityjson(path: &Path) -> bool {
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    if name.ends_with(".city.json") || name.ends_with(".jsonl") {
        return true;
    }
    if !name.ends_with(".json") {
        return false;
    }
    use std::io::Read;
    let mut head = vec![0u8; 4096];
    let n = std::fs::File::open(path)
        .and_then(|mut f| f.read(&mut head))
        .unwrap_or(0);
    let text = String::from_utf8_lossy(&head[..n]);
    // The "type" member may come last (3dfier writes "CityObjects" first).
    text.contains("\"CityJSON\"") || text.contains("\"CityObjects\"")
}

/// Colours of the semantic surface types (linear RGBA), so a viewer tells them apart.
const SEMANTIC_COLOURS: &[(&str, [f32; 4])] = &[
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
const NO_SEMANTICS: &str = "Surface";

/// Reads a CityJSON or CityJSONSeq file into a new scene.
pub fn read_cityjson(path: &Path) -> Result<Scene> {
    let text = std::fs::read(path).map_err(|e| Error::input_from(path, "cannot read", e))?;
    let is_seq = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("jsonl"));
    let mut reader = Reader::new(path);
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
    let mut scene = reader.finish();
    scene.sources.push(SourceFile {
        path: path.to_path_buf(),
        bytes: text.len() as u64,
    });
    scene.finish();
    Ok(scene)
}

struct Reader<'a> {
    path: &'a Path,
    scale: DVec3,
    translate: DVec3,
    scene: Scene,
    texts: TextInterner,
    /// Material of each semantic type, made on first use.
    materials: HashMap<String, MaterialId>,
    /// CityObject id → its hierarchy node.
    node_of: HashMap<String, NodeId>,
    /// (child node, parent CityObject id), linked once every object is known.
    parents: Vec<(NodeId, String)>,
}

impl<'a> Reader<'a> {
    fn new(path: &'a Path) -> Self {
        Reader {
            path,
            scale: DVec3::ONE,
            translate: DVec3::ZERO,
            scene: Scene::default(),
            texts: TextInterner::default(),
            materials: HashMap::new(),
            node_of: HashMap::new(),
            parents: Vec::new(),
        }
    }

    fn err(&self, m: impl Into<String>) -> Error {
        Error::input(self.path, m)
    }

    /// The file (or sequence header): its type and `transform`.
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
        Ok(())
    }

    /// The CityObjects of a CityJSON file or of one CityJSONFeature, with its own `vertices`.
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
        let objects = doc
            .get("CityObjects")
            .and_then(Value::as_object)
            .ok_or_else(|| self.err(format!("{what}: no \"CityObjects\" object")))?;
        for (id, object) in objects {
            self.object(id, object, &points)?;
        }
        Ok(())
    }

    fn object(&mut self, id: &str, object: &Value, points: &[DVec3]) -> Result<()> {
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
        // The highest LoD only (3D BAG: LoD 0, 1.2, 1.3 and 2.2 of the same building).
        let lod = |g: &Value| -> f64 {
            match g.get("lod") {
                Some(Value::String(s)) => s.parse().unwrap_or(0.0),
                Some(v) => v.as_f64().unwrap_or(0.0),
                None => 0.0,
            }
        };
        let best = geometries
            .iter()
            .map(|g| lod(g))
            .fold(f64::NEG_INFINITY, f64::max);
        // Triangles per semantic type, in f64 world coordinates, each corner with its normal.
        let mut by_semantic: BTreeMap<String, (Vec<DVec3>, Vec<DVec3>)> = BTreeMap::new();
        let what = format!("CityObject {id}");
        for g in geometries.iter().filter(|g| lod(g) == best) {
            self.geometry(g, points, &what, &mut by_semantic)?;
        }
        if by_semantic.is_empty() {
            return Ok(());
        }
        let origin = by_semantic
            .values()
            .flat_map(|(p, _)| p)
            .fold(DVec3::splat(f64::INFINITY), |a, &p| a.min(p));
        let mut mesh = Mesh {
            name: Some(id.to_string()),
            ..Mesh::default()
        };
        let mut info = ElementInfo::keyed(id);
        for (semantic, (corners, normals)) in by_semantic {
            let triangles = corners.len() / 3;
            info.properties.push(Property {
                set: self.texts.get("semantics"),
                name: self.texts.get(&semantic),
                value: PropertyValue::Integer(triangles as i64),
            });
            let material = self.material(&semantic);
            mesh.primitives.push(Primitive {
                material: Some(material),
                positions: corners
                    .iter()
                    .map(|p| (*p - origin).as_vec3().to_array())
                    .collect(),
                normals: Some(normals.iter().map(|n| n.as_vec3().to_array()).collect()),
                uvs: None,
                colors: None,
                indices: (0..corners.len() as u32).collect(),
            });
        }
        info.class = object
            .get("type")
            .and_then(Value::as_str)
            .map(|t| self.texts.get(t));
        if let Some(attributes) = object.get("attributes").and_then(Value::as_object) {
            for (k, v) in attributes {
                let value = match v {
                    Value::String(s) => PropertyValue::Text(s.clone()),
                    Value::Bool(b) => PropertyValue::Bool(*b),
                    Value::Number(n) => match n.as_i64() {
                        Some(i) => PropertyValue::Integer(i),
                        None => PropertyValue::Number(n.as_f64().unwrap_or(f64::NAN)),
                    },
                    Value::Null => continue,
                    other => PropertyValue::Text(other.to_string()),
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
        }
        info.properties.shrink_to_fit();
        let mesh_id = self.scene.meshes.push(mesh);
        let component = Component {
            node: Some(node),
            ..Component::new(mesh_id, DMat4::from_translation(origin))
        };
        self.scene.push_component(component, &info);
        Ok(())
    }

    /// The material of a semantic type (made once).
    fn material(&mut self, semantic: &str) -> MaterialId {
        if let Some(&m) = self.materials.get(semantic) {
            return m;
        }
        let colour = SEMANTIC_COLOURS
            .iter()
            .find(|(s, _)| *s == semantic)
            .map_or([0.75, 0.75, 0.75, 1.0], |(_, c)| *c);
        let id = MaterialId(self.scene.materials.len() as u32);
        self.scene.materials.push(Material {
            name: Some(semantic.to_string()),
            base_color: colour,
            metallic: 0.0,
            roughness: 1.0,
            emissive: [0.0; 3],
            base_color_texture: None,
            alpha_mode: AlphaMode::Opaque,
            alpha_cutoff: 0.5,
            double_sided: true,
        });
        self.materials.insert(semantic.to_string(), id);
        id
    }

    /// Triangulates one geometry's surfaces into `out` (per semantic type).
    fn geometry(
        &self,
        g: &Value,
        points: &[DVec3],
        what: &str,
        out: &mut BTreeMap<String, (Vec<DVec3>, Vec<DVec3>)>,
    ) -> Result<()> {
        let kind = g.get("type").and_then(Value::as_str).unwrap_or("");
        let boundaries = g
            .get("boundaries")
            .ok_or_else(|| self.err(format!("{what}: {kind} without boundaries")))?;
        // Depth of the surface level: MultiSurface [surface], Solid [shell][surface],
        // MultiSolid [solid][shell][surface]; semantics.values has the same nesting.
        let depth = match kind {
            "MultiSurface" | "CompositeSurface" => 0,
            "Solid" => 1,
            _ => 2,
        };
        let surfaces_sem = g.pointer("/semantics/surfaces").and_then(Value::as_array);
        let values = g.pointer("/semantics/values");
        let mut stack: Vec<(&Value, Option<&Value>, usize)> = vec![(boundaries, values, depth)];
        while let Some((b, v, d)) = stack.pop() {
            let list = b
                .as_array()
                .ok_or_else(|| self.err(format!("{what}: boundaries are not arrays")))?;
            for (k, item) in list.iter().enumerate() {
                let v_item = v.and_then(|v| v.as_array()).and_then(|a| a.get(k));
                if d > 0 {
                    stack.push((item, v_item, d - 1));
                    continue;
                }
                let semantic = v_item
                    .and_then(Value::as_u64)
                    .and_then(|i| surfaces_sem?.get(i as usize))
                    .and_then(|s| s.get("type"))
                    .and_then(Value::as_str)
                    .unwrap_or(NO_SEMANTICS);
                let entry = out.entry(semantic.to_string()).or_default();
                self.surface(item, points, what, entry)?;
            }
        }
        Ok(())
    }

    /// One polygon (outer ring, then holes) triangulated on its best-fit plane.
    fn surface(
        &self,
        rings: &Value,
        points: &[DVec3],
        what: &str,
        (corners, normals): &mut (Vec<DVec3>, Vec<DVec3>),
    ) -> Result<()> {
        let rings = rings
            .as_array()
            .ok_or_else(|| self.err(format!("{what}: a surface is not a list of rings")))?;
        let mut ring_points: Vec<DVec3> = Vec::new();
        let mut holes: Vec<usize> = Vec::new();
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
        }
        if ring_points.len() < 3 {
            return Ok(());
        }
        // Newell's normal of the outer ring (robust for non-convex and slightly warped rings).
        let outer = holes.first().copied().unwrap_or(ring_points.len());
        let centre = ring_points[..outer].iter().sum::<DVec3>() / outer as f64;
        let mut normal = DVec3::ZERO;
        for k in 0..outer {
            let (a, b) = (
                ring_points[k] - centre,
                ring_points[(k + 1) % outer] - centre,
            );
            normal += DVec3::new(
                (a.y - b.y) * (a.z + b.z),
                (a.z - b.z) * (a.x + b.x),
                (a.x - b.x) * (a.y + b.y),
            );
        }
        let Some(normal) = normal.try_normalize() else {
            return Ok(()); // A degenerate polygon covers no area.
        };
        let u = normal.any_orthonormal_vector();
        let v = normal.cross(u);
        let flat: Vec<f64> = ring_points
            .iter()
            .flat_map(|p| {
                let d = *p - centre;
                [d.dot(u), d.dot(v)]
            })
            .collect();
        let triangles = earcutr::earcut(&flat, &holes, 2)
            .map_err(|e| self.err(format!("{what}: polygon not triangulated: {e:?}")))?;
        for t in triangles.chunks_exact(3) {
            let [a, b, c] = [ring_points[t[0]], ring_points[t[1]], ring_points[t[2]]];
            // earcut's winding follows the 2-D frame: keep the polygon's own orientation.
            let (b, c) = if (b - a).cross(c - a).dot(normal) < 0.0 {
                (c, b)
            } else {
                (b, c)
            };
            corners.extend([a, b, c]);
            normals.extend([normal; 3]);
        }
        Ok(())
    }

    /// Links parents and hands the scene over.
    fn finish(mut self) -> Scene {
        for (child, parent) in std::mem::take(&mut self.parents) {
            if let Some(&p) = self.node_of.get(&parent) {
                if p != child {
                    self.scene.nodes[child.index()].parent = Some(p);
                }
            }
        }
        self.scene
    }
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
        let mut r = Reader::new(path);
        r.header(&doc).unwrap();
        r.document(&doc, "CityObjects").unwrap();
        let mut scene = r.finish();
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
    fn bad_input_is_an_error_naming_the_problem() {
        let path = Path::new("bad.city.json");
        let mut r = Reader::new(path);
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
