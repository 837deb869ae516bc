//! Assembly of the engine's plain data into the scene: spatial structure as nodes, elements with
//! their semantics and typed properties, one material per colour, skipped classes.

use super::*;

pub(super) fn skip_reason(class: &str) -> Option<&'static str> {
    SKIPPED_CLASSES
        .iter()
        .find(|(c, _)| c.eq_ignore_ascii_case(class))
        .map(|(_, r)| *r)
}

pub(super) fn is_storey(c: &str) -> bool {
    c.eq_ignore_ascii_case("IfcBuildingStorey")
}
pub(super) fn is_building(c: &str) -> bool {
    [
        "IfcBuilding",
        "IfcFacility",
        "IfcBridge",
        "IfcRoad",
        "IfcRailway",
        "IfcMarineFacility",
        "IfcTunnel",
    ]
    .iter()
    .any(|k| k.eq_ignore_ascii_case(c))
}
pub(super) fn is_site(c: &str) -> bool {
    c.eq_ignore_ascii_case("IfcSite")
}
pub(super) fn is_project(c: &str) -> bool {
    c.eq_ignore_ascii_case("IfcProject")
}

/// Types a property value the IFC library gave as text.
pub(super) fn typed_value(v: &engine::RawValue) -> Option<PropertyValue> {
    use engine::ValueKind as K;
    let t = v.text.trim();
    Some(match v.kind {
        K::Null => return None,
        K::Bool | K::Logical => match t.to_ascii_lowercase().as_str() {
            "true" | ".t." | "t" => PropertyValue::Bool(true),
            "false" | ".f." | "f" => PropertyValue::Bool(false),
            "" | "unknown" | ".u." => PropertyValue::Text("UNKNOWN".into()),
            _ => PropertyValue::Text(t.to_string()),
        },
        K::Integer => t
            .parse::<i64>()
            .map(PropertyValue::Integer)
            .or_else(|_| t.parse::<f64>().map(PropertyValue::Number))
            .unwrap_or_else(|_| PropertyValue::Text(t.to_string())),
        K::Real => t
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .map(PropertyValue::Number)
            .unwrap_or_else(|| PropertyValue::Text(t.to_string())),
        K::Text => PropertyValue::Text(v.text.clone()),
        K::Unknown => parse_loose(t),
    })
}

/// Types text whose IFC type is not known: ".T."/"TRUE" → Bool, "12" → Integer, "1.5" → Number,
/// anything else (including enumerations) → Text.
pub fn parse_loose(t: &str) -> PropertyValue {
    let t = t.trim();
    match t.to_ascii_uppercase().as_str() {
        "TRUE" | ".T." => return PropertyValue::Bool(true),
        "FALSE" | ".F." => return PropertyValue::Bool(false),
        _ => {}
    }
    if let Ok(i) = t.parse::<i64>() {
        return PropertyValue::Integer(i);
    }
    if t.chars().any(|c| c.is_ascii_digit()) {
        if let Ok(x) = t.parse::<f64>() {
            if x.is_finite() {
                return PropertyValue::Number(x);
            }
        }
    }
    PropertyValue::Text(t.to_string())
}

pub(super) struct Builder<'a> {
    scene: Scene,
    data: &'a engine::RawData,
    parent: HashMap<u32, u32>,
    node_of: HashMap<u32, NodeId>,
    materials: HashMap<([u32; 4], Option<String>), MaterialId>,
    /// element → its type object.
    type_of: HashMap<u32, u32>,
    /// set id → (set name, properties) and object → set ids.
    sets_of: HashMap<u32, Vec<u32>>,
    materials_of: HashMap<u32, Vec<String>>,
    /// Repeated metadata text (classes, storeys, property names), one copy each.
    texts: std::cell::RefCell<TextInterner>,
}

impl<'a> Builder<'a> {
    fn shared(&self, s: &str) -> SharedText {
        self.texts.borrow_mut().get(s)
    }

    fn entity(&self, id: u32) -> Option<&engine::RawEntity> {
        self.data.entities.get(&id)
    }

    /// The node of `id` (a spatial structure element or an aggregate parent), creating it and its
    /// ancestors; `None` for the project and for unknown ids.
    fn node(&mut self, id: u32, depth: usize) -> Option<NodeId> {
        if let Some(n) = self.node_of.get(&id) {
            return Some(*n);
        }
        let e = self.entity(id)?;
        if is_project(&e.class) || depth > 64 {
            return None;
        }
        let name = e
            .name
            .clone()
            .filter(|s| !s.is_empty())
            .or_else(|| e.guid.clone())
            .unwrap_or_else(|| format!("{}#{id}", e.class));
        let extras = serde_json::value::to_raw_value(
            &serde_json::json!({"ifc_class": e.class, "guid": e.guid}),
        )
        .ok();
        let parent = self.parent.get(&id).copied();
        let parent_node = parent.and_then(|p| self.node(p, depth + 1));
        let nid = NodeId(self.scene.nodes.len() as u32);
        self.scene.nodes.push(Node {
            name: Some(name),
            parent: parent_node,
            extras,
            name_repeat: 0,
        });
        self.node_of.insert(id, nid);
        Some(nid)
    }

    /// (storey, building, site) names above `id`.
    fn containers(&self, id: u32) -> (Option<String>, Option<String>, Option<String>) {
        let (mut st, mut b, mut s) = (None, None, None);
        let mut cur = self.parent.get(&id).copied();
        let mut steps = 0;
        while let Some(p) = cur {
            steps += 1;
            if steps > 64 {
                break;
            }
            if let Some(e) = self.entity(p) {
                let name = || e.name.clone().filter(|n| !n.is_empty());
                if st.is_none() && is_storey(&e.class) {
                    st = name();
                } else if b.is_none() && is_building(&e.class) {
                    b = name();
                } else if s.is_none() && is_site(&e.class) {
                    s = name();
                }
            }
            cur = self.parent.get(&p).copied();
        }
        (st, b, s)
    }

    fn properties(&self, id: u32) -> Vec<Property> {
        let mut out: Vec<Property> = Vec::new();
        let mut seen: HashSet<(String, String)> = HashSet::new();
        let mut owners = vec![id];
        if let Some(t) = self.type_of.get(&id) {
            owners.push(*t); // the element's own values first: they win
        }
        for owner in owners {
            for sid in self.sets_of.get(&owner).into_iter().flatten() {
                let Some(set) = self.data.sets.get(sid) else {
                    continue;
                };
                for (name, v) in &set.values {
                    let Some(value) = typed_value(v) else {
                        continue;
                    };
                    if seen.insert((set.name.clone(), name.clone())) {
                        out.push(Property {
                            set: self.shared(&set.name),
                            name: self.shared(name),
                            value,
                        });
                    }
                }
            }
        }
        out
    }

    fn material_name(&self, id: u32) -> Option<String> {
        let names = self
            .materials_of
            .get(&id)
            .or_else(|| self.type_of.get(&id).and_then(|t| self.materials_of.get(t)))?;
        let mut uniq: Vec<&str> = Vec::new();
        for n in names {
            if !n.is_empty() && !uniq.contains(&n.as_str()) {
                uniq.push(n);
            }
        }
        (!uniq.is_empty()).then(|| uniq.join(", "))
    }

    fn material(&mut self, color: [f32; 4], name: Option<String>) -> MaterialId {
        let c = color.map(|x| {
            if x.is_finite() {
                x.clamp(0.0, 1.0)
            } else {
                1.0
            }
        });
        let key = (c.map(f32::to_bits), name.clone());
        if let Some(m) = self.materials.get(&key) {
            return *m;
        }
        let id = MaterialId(self.scene.materials.len() as u32);
        self.scene.materials.push(Material {
            name,
            base_color: c,
            metallic: 0.0,
            roughness: IFC_ROUGHNESS,
            alpha_mode: if c[3] < 1.0 {
                AlphaMode::Blend
            } else {
                AlphaMode::Opaque
            },
            double_sided: c[3] < 1.0,
            ..Material::default()
        });
        self.materials.insert(key, id);
        id
    }
}

/// Area-weighted vertex normals for a triangle list.
pub(super) fn vertex_normals(pos: &[[f32; 3]], idx: &[u32]) -> Vec<[f32; 3]> {
    let mut acc = vec![glam::Vec3::ZERO; pos.len()];
    for t in idx.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| glam::Vec3::from(pos[i as usize]));
        let n = (b - a).cross(c - a);
        for &i in t {
            acc[i as usize] += n;
        }
    }
    acc.into_iter()
        .map(|n| n.try_normalize().unwrap_or(glam::Vec3::Z).to_array())
        .collect()
}

pub(super) fn assemble(
    path: &Path,
    file_bytes: u64,
    geom: engine::RawGeometry,
    data: engine::RawData,
    report: &mut IfcReadReport,
) -> Result<Scene> {
    let mut b = Builder {
        scene: Scene::default(),
        data: &data,
        parent: HashMap::new(),
        node_of: HashMap::new(),
        materials: HashMap::new(),
        type_of: HashMap::new(),
        sets_of: HashMap::new(),
        materials_of: HashMap::new(),
        texts: Default::default(),
    };
    b.scene.sources.push(SourceFile {
        path: path.to_path_buf(),
        bytes: file_bytes,
    });
    b.read_relationships();
    let frame = geom.frame_to_world;
    for el in geom.elements {
        let class = el.class.clone();
        let guid = el
            .guid
            .clone()
            .unwrap_or_else(|| format!("#{}", el.express_id));
        if let Some(_r) = skip_reason(&class) {
            *report.excluded_by_class.entry(class).or_default() += 1;
            continue;
        }
        let bx = match element_box(&el) {
            Ok(bx) => bx,
            Err(problem) => {
                report.skipped.push(SkippedElement {
                    guid,
                    class,
                    reason: problem.to_string(),
                });
                continue;
            }
        };
        b.add_element(&el, guid, &class, bx.center(), frame);
    }
    for m in geom.missing {
        if skip_reason(&m.class).is_some() {
            continue;
        }
        report.skipped.push(SkippedElement {
            guid: m.guid.unwrap_or_else(|| format!("#{}", m.express_id)),
            class: m.class,
            reason: m.reason,
        });
    }
    if b.scene.components.is_empty() {
        return Err(Error::input(
            path,
            format!(
                "no element with geometry in this IFC file ({} skipped)",
                report.skipped.len()
            ),
        ));
    }
    Ok(b.scene)
}

/// Why an element's geometry is not used (the element is skipped and reported).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum ElementGeometryProblem {
    #[error("malformed triangle data")]
    Malformed,
    #[error("index {index} out of range ({vertices} vertices)")]
    IndexOutOfRange { index: u32, vertices: u32 },
    #[error("non-finite vertex coordinates")]
    NonFinite,
    #[error("no triangles")]
    NoTriangles,
}

/// Frame-space box of an element (f64), or why it is skipped.
fn element_box(el: &engine::RawElement) -> std::result::Result<Aabb, ElementGeometryProblem> {
    let mut bx = Aabb::EMPTY;
    for p in &el.pieces {
        if p.positions.len() % 3 != 0 || p.indices.len() % 3 != 0 {
            return Err(ElementGeometryProblem::Malformed);
        }
        let vertices = (p.positions.len() / 3) as u32;
        if let Some(&index) = p.indices.iter().find(|&&i| i >= vertices) {
            return Err(ElementGeometryProblem::IndexOutOfRange { index, vertices });
        }
        for v in p.positions.chunks_exact(3) {
            if !v.iter().all(|x| x.is_finite()) || !p.origin.iter().all(|x| x.is_finite()) {
                return Err(ElementGeometryProblem::NonFinite);
            }
            bx.extend(DVec3::new(
                p.origin[0] + v[0] as f64,
                p.origin[1] + v[1] as f64,
                p.origin[2] + v[2] as f64,
            ));
        }
    }
    let tris: usize = el.pieces.iter().map(|p| p.indices.len() / 3).sum();
    if tris == 0 || bx.is_empty() {
        return Err(ElementGeometryProblem::NoTriangles);
    }
    Ok(bx)
}

/// A piece's vertex normals: its own when complete and finite (normalized), else area-weighted
/// ones from its triangles.
fn piece_normals(p: &engine::RawPiece, positions: &[[f32; 3]]) -> Vec<[f32; 3]> {
    if p.normals.len() == p.positions.len() && p.normals.iter().all(|x| x.is_finite()) {
        p.normals
            .chunks_exact(3)
            .map(|n| {
                glam::Vec3::new(n[0], n[1], n[2])
                    .try_normalize()
                    .unwrap_or(glam::Vec3::Z)
                    .to_array()
            })
            .collect()
    } else {
        vertex_normals(positions, &p.indices)
    }
}

impl Builder<'_> {
    /// Relationships: the parent of each object (aggregation > containment > nesting), types,
    /// property sets, materials.
    fn read_relationships(&mut self) {
        let data = self.data;
        let mut rank: HashMap<u32, u8> = HashMap::new();
        for r in &data.rels {
            use engine::RelKind as R;
            let prio = match r.kind {
                R::Aggregates => 3,
                R::Contains => 2,
                R::Nests => 1,
                R::DefinesByType => {
                    self.type_of.entry(r.related).or_insert(r.relating);
                    continue;
                }
                R::DefinesByProperties | R::TypeHasSet => {
                    self.sets_of.entry(r.related).or_default().push(r.relating);
                    continue;
                }
            };
            if r.related == r.relating {
                continue;
            }
            let cur = rank.get(&r.related).copied().unwrap_or(0);
            if prio > cur {
                rank.insert(r.related, prio);
                self.parent.insert(r.related, r.relating);
            }
        }
        for (el, name) in &data.materials {
            self.materials_of.entry(*el).or_default().push(name.clone());
        }
    }

    /// The element's primitives, one per (colour, material name), vertices relative to `local`
    /// (frame space).
    fn primitives(&mut self, el: &engine::RawElement, local: DVec3) -> Vec<Primitive> {
        let mut prims: Vec<Primitive> = Vec::new();
        let mut prim_of: HashMap<MaterialId, usize> = HashMap::new();
        for p in &el.pieces {
            if p.indices.is_empty() {
                continue;
            }
            let mat = self.material(p.color, p.material_name.clone());
            let k = *prim_of.entry(mat).or_insert_with(|| {
                prims.push(Primitive {
                    material: Some(mat),
                    normals: Some(Vec::new()),
                    ..Default::default()
                });
                prims.len() - 1
            });
            let prim = &mut prims[k];
            let base = prim.positions.len() as u32;
            let off = DVec3::from(p.origin) - local;
            let positions: Vec<[f32; 3]> = p
                .positions
                .chunks_exact(3)
                .map(|v| {
                    [
                        (off.x + v[0] as f64) as f32,
                        (off.y + v[1] as f64) as f32,
                        (off.z + v[2] as f64) as f32,
                    ]
                })
                .collect();
            let normals = piece_normals(p, &positions);
            prim.positions.extend(positions);
            prim.normals.as_mut().unwrap().extend(normals);
            prim.indices.extend(p.indices.iter().map(|i| i + base));
        }
        prims
    }

    /// Adds a valid element: its node (under its spatial parent), its mesh (centred on `local`,
    /// placed by `frame`) and its component with its semantics and properties.
    fn add_element(
        &mut self,
        el: &engine::RawElement,
        guid: String,
        class: &str,
        local: DVec3,
        frame: DMat4,
    ) {
        let prims = self.primitives(el, local);
        let (storey, building, site) = self.containers(el.express_id);
        let parent_node = self
            .parent
            .get(&el.express_id)
            .copied()
            .and_then(|p| self.node(p, 0));
        let node = NodeId(self.scene.nodes.len() as u32);
        self.scene.nodes.push(Node {
            name: Some(
                el.name
                    .clone()
                    .filter(|s| !s.is_empty())
                    .unwrap_or_else(|| guid.clone()),
            ),
            parent: parent_node,
            extras: None,
            name_repeat: 0,
        });
        self.node_of.insert(el.express_id, node);
        let mesh = MeshId(self.scene.meshes.len() as u32);
        self.scene.meshes.push(Mesh {
            name: el.name.clone(),
            primitives: prims,
            local_bounds: None,
        });
        let info = ElementInfo {
            key: guid,
            name: el.name.clone(),
            guid: el.guid.clone(),
            class: Some(self.shared(class)),
            storey: storey.map(|t| self.shared(&t)),
            building: building.map(|t| self.shared(&t)),
            site: site.map(|t| self.shared(&t)),
            material: self.material_name(el.express_id).map(|t| self.shared(&t)),
            properties: self.properties(el.express_id),
        };
        self.scene.push_component(
            Component {
                node: Some(node),
                ..Component::new(mesh, frame * DMat4::from_translation(local))
            },
            &info,
        );
    }
}

// ------------------------------------------------------------------------------------------------
// The IFC library adapter: the only place that names ifc-lite types.
// ------------------------------------------------------------------------------------------------
