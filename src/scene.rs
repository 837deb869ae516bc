//! The in-memory building model that every stage shares.
//!
//! Readers (`ingest`) produce a [`Scene`]; dedup, partition, simplification, textures and the
//! encoders read it. Everything is held in `Vec`s addressed by small typed ids in input order, so
//! the pipeline is deterministic and a component's identity ([`ComponentId`]) survives from input to
//! the feature IDs written in the tiles.
//!
//! Coordinate convention: mesh data stays in its source's local frame (f32, as read); each
//! component carries a `world` transform (f64) that maps it into the *scene frame*: metres,
//! right-handed, **z-up**, x east, y north once georeferenced. The glTF y-up → z-up change lives in
//! the glTF reader's transform ([`Y_UP_TO_Z_UP`]), and back again in the encoder ([`Z_UP_TO_Y_UP`]):
//! both are defined here, once.

use glam::{DMat4, DVec3};
use serde_json::value::RawValue;
use serde_json::Value;
use std::sync::Arc;

mod elements;
pub mod ids;
pub mod placement;
mod store;
pub use elements::{ElementStats, ElementTable};
pub use store::{
    memory_budget, set_memory_budget, MemoryBudget, MeshStore, StoreLimits, StoreStats,
};

/// glTF (y-up) → scene frame (z-up): (x, y, z) ↦ (x, -z, y), a +90° turn about x. This is the
/// same rotation 3D Tiles clients apply to glTF content (3D Tiles 1.1, "glTF transforms").
pub const Y_UP_TO_Z_UP: DMat4 = DMat4::from_cols_array(&[
    1.0, 0.0, 0.0, 0.0, //
    0.0, 0.0, 1.0, 0.0, //
    0.0, -1.0, 0.0, 0.0, //
    0.0, 0.0, 0.0, 1.0,
]);
/// Scene frame (z-up) → glTF (y-up): the inverse of [`Y_UP_TO_Z_UP`], (x, y, z) ↦ (x, z, -y).
pub const Z_UP_TO_Y_UP: DMat4 = DMat4::from_cols_array(&[
    1.0, 0.0, 0.0, 0.0, //
    0.0, 0.0, -1.0, 0.0, //
    0.0, 1.0, 0.0, 0.0, //
    0.0, 0.0, 0.0, 1.0,
]);

macro_rules! typed_id {
    ($name:ident, $what:literal) => {
        #[doc = concat!("Index of a ", $what, " in its `Scene` vector.")]
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub struct $name(pub u32);
        impl $name {
            pub fn index(self) -> usize {
                self.0 as usize
            }
        }
    };
}
typed_id!(ComponentId, "component");
typed_id!(MeshId, "mesh");
typed_id!(MaterialId, "material");
typed_id!(ImageId, "image");
typed_id!(NodeId, "hierarchy node");

/// Axis-aligned box in f64 (scene frame unless said otherwise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Aabb::EMPTY
    }
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb {
        min: DVec3::splat(f64::INFINITY),
        max: DVec3::splat(f64::NEG_INFINITY),
    };
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }
    pub fn extend(&mut self, p: DVec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }
    pub fn center(&self) -> DVec3 {
        (self.min + self.max) * 0.5
    }
    pub fn size(&self) -> DVec3 {
        if self.is_empty() {
            DVec3::ZERO
        } else {
            self.max - self.min
        }
    }
    pub fn diagonal(&self) -> f64 {
        self.size().length()
    }
    pub fn contains_box(&self, o: &Aabb, tol: f64) -> bool {
        o.min.cmpge(self.min - DVec3::splat(tol)).all()
            && o.max.cmple(self.max + DVec3::splat(tol)).all()
    }
    /// The box of this box's 8 corners after an affine transform.
    pub fn transformed(&self, m: &DMat4) -> Aabb {
        let mut out = Aabb::EMPTY;
        if self.is_empty() {
            return out;
        }
        for i in 0..8 {
            let c = DVec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            );
            out.extend(m.transform_point3(c));
        }
        out
    }
}

/// One triangle list with one material, in its mesh's local frame.
#[derive(Debug, Clone, Default)]
pub struct Primitive {
    pub material: Option<MaterialId>,
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    /// TEXCOORD_0; may leave [0,1] (tiling textures).
    pub uvs: Option<Vec<[f32; 2]>>,
    /// COLOR_0 as linear RGBA.
    pub colors: Option<Vec<[f32; 4]>>,
    /// Triangle list, every index < positions.len() (checked by the readers).
    pub indices: Vec<u32>,
}

impl Primitive {
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }
    /// Bytes this primitive takes as uncompressed glTF attributes + u32 indices: the unit of the
    /// partitioner's byte budget.
    pub fn estimated_bytes(&self) -> usize {
        let per_vertex = 12
            + self.normals.as_ref().map_or(0, |_| 12)
            + self.uvs.as_ref().map_or(0, |_| 8)
            + self.colors.as_ref().map_or(0, |_| 16)
            + 4; // feature id
        self.positions.len() * per_vertex + self.indices.len() * 4
    }
}

#[derive(Debug, Clone, Default)]
pub struct Mesh {
    pub name: Option<String>,
    pub primitives: Vec<Primitive>,
    /// Box of all positions in the mesh's local frame (filled by [`MeshStore`] when stored).
    pub local_bounds: Option<Aabb>,
}

impl Mesh {
    pub fn triangle_count(&self) -> usize {
        self.primitives.iter().map(Primitive::triangle_count).sum()
    }
    pub fn vertex_count(&self) -> usize {
        self.primitives.iter().map(|p| p.positions.len()).sum()
    }
    pub fn estimated_bytes(&self) -> usize {
        self.primitives.iter().map(Primitive::estimated_bytes).sum()
    }
    /// Bytes of its arrays in memory (what [`MeshStore`] counts against its limit).
    pub fn heap_bytes(&self) -> usize {
        self.primitives
            .iter()
            .map(|p| {
                size_of_val(&p.positions[..])
                    + p.normals.as_ref().map_or(0, |v| size_of_val(&v[..]))
                    + p.uvs.as_ref().map_or(0, |v| size_of_val(&v[..]))
                    + p.colors.as_ref().map_or(0, |v| size_of_val(&v[..]))
                    + size_of_val(&p.indices[..])
            })
            .sum()
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum AlphaMode {
    Opaque,
    Mask,
    Blend,
}

/// glTF sampler settings, kept as the raw glTF enums (0 = unset).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Sampler {
    pub mag_filter: u32,
    pub min_filter: u32,
    pub wrap_s: u32,
    pub wrap_t: u32,
}

impl Sampler {
    /// glTF `wrapS`/`wrapT` values (WebGL enums).
    pub const REPEAT: u32 = 10497;
    pub const MIRRORED_REPEAT: u32 = 33648;
    pub const CLAMP_TO_EDGE: u32 = 33071;

    /// Filters unset, `wrap_s` and `wrap_t` as given.
    pub fn wrapping(wrap_s: u32, wrap_t: u32) -> Sampler {
        Sampler {
            wrap_s,
            wrap_t,
            ..Sampler::default()
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct TextureRef {
    pub image: ImageId,
    pub sampler: Sampler,
    pub tex_coord: u32,
}

impl TextureRef {
    /// An image on the first UV set, wrapped `wrap` in both directions.
    pub fn on_first_uvs(image: ImageId, wrap: u32) -> TextureRef {
        TextureRef {
            image,
            sampler: Sampler::wrapping(wrap, wrap),
            tex_coord: 0,
        }
    }
}

/// A metallic-roughness material (the subset building models use).
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    pub name: Option<String>,
    pub base_color: [f32; 4],
    pub metallic: f32,
    pub roughness: f32,
    pub emissive: [f32; 3],
    pub base_color_texture: Option<TextureRef>,
    pub alpha_mode: AlphaMode,
    pub alpha_cutoff: f32,
    pub double_sided: bool,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            name: None,
            base_color: [1.0; 4],
            metallic: 1.0,
            roughness: 1.0,
            emissive: [0.0; 3],
            base_color_texture: None,
            alpha_mode: AlphaMode::Opaque,
            alpha_cutoff: 0.5,
            double_sided: false,
        }
    }
}

/// An encoded image as it came in (PNG/JPEG/WebP bytes); shared, never copied per tile.
#[derive(Debug, Clone)]
pub struct Image {
    pub name: Option<String>,
    pub mime_type: String,
    pub bytes: Arc<Vec<u8>>,
}

/// A node of the source hierarchy (building → storey → element, or a glTF node tree).
#[derive(Debug, Clone, Default)]
pub struct Node {
    pub name: Option<String>,
    pub parent: Option<NodeId>,
    /// 0, or n for the n-th repeat of its name among its siblings: its path segment is then
    /// `name#n` ([`ids`]).
    pub name_repeat: u32,
    /// The source's `extras` as written (JSON text), for nodes without a mesh: kept compact,
    /// since a parsed map costs ~0.8 KB a node. A node with a mesh has its extras parsed into its
    /// element's [`ElementInfo`] at ingest, and the text is dropped then (a million elements on
    /// a 100M-triangle site). [`Node::extras_value`] parses it.
    pub extras: Option<Box<RawValue>>,
}

impl Node {
    /// The extras, parsed (`None` when there are none or they are not valid JSON).
    pub fn extras_value(&self) -> Option<Value> {
        serde_json::from_str(self.extras.as_ref()?.get()).ok()
    }
}

/// One BIM element or one glTF node with a mesh: what geometry work needs (its identity and
/// semantics are its [`ElementInfo`], in [`Scene::elements`]).
#[derive(Debug, Clone)]
pub struct Component {
    pub id: ComponentId,
    /// Where it sits in the hierarchy (`nodes`), when the source has one.
    pub node: Option<NodeId>,
    pub mesh: MeshId,
    /// Mesh-local → scene frame (metres, z-up).
    pub world: DMat4,
    /// Box of the mesh's vertices in the scene frame (filled by [`Scene::finish`]).
    pub world_bounds: Aabb,
    /// Which input file it came from (index into `Scene::sources`).
    pub source: u32,
    /// Set by `dedup` when this component is a redundant exact copy of another (same geometry at
    /// the same place): it stays in the scene for its identity and metadata, but stages that
    /// write geometry skip it (the kept component draws it).
    pub alias_of: Option<ComponentId>,
}

/// A typed property value (IFC property sets arrive as text; readers type what is clearly typed).
#[derive(Debug, Clone, PartialEq)]
pub enum PropertyValue {
    Text(String),
    Number(f64),
    Integer(i64),
    Bool(bool),
}

impl PropertyValue {
    /// A JSON scalar as a typed value (glTF extras, CityJSON attributes); `None` for null, arrays
    /// and objects, which each reader treats in its own way.
    pub fn from_json_scalar(v: &Value) -> Option<PropertyValue> {
        Some(match v {
            Value::String(s) => PropertyValue::Text(s.clone()),
            Value::Bool(b) => PropertyValue::Bool(*b),
            Value::Number(n) => match n.as_i64() {
                Some(i) => PropertyValue::Integer(i),
                None => PropertyValue::Number(n.as_f64().unwrap_or(f64::NAN)),
            },
            _ => return None,
        })
    }
}

/// One named property of an element, in a named set (IFC property set or quantity set; "extras"
/// for glTF node extras).
#[derive(Debug, Clone, PartialEq)]
pub struct Property {
    pub set: SharedText,
    pub name: SharedText,
    pub value: PropertyValue,
}

/// Text that repeats across elements (IFC classes, storeys, materials, property-set and property
/// names), stored once and shared: a site of a million elements has a few hundred distinct
/// values, and a `String` each would cost about 50 bytes per element per field (per-element
/// metadata is what `--memory-budget` does not bound).
pub type SharedText = Arc<str>;

/// Hands out one [`SharedText`] per distinct value (readers keep one while they read a file).
#[derive(Debug, Default)]
pub struct TextInterner {
    values: std::collections::HashSet<SharedText>,
}

impl TextInterner {
    pub fn get(&mut self, s: &str) -> SharedText {
        if let Some(t) = self.values.get(s) {
            return t.clone();
        }
        let t: SharedText = Arc::from(s);
        self.values.insert(t.clone());
        t
    }
}

/// What a component *is*: its identity and BIM semantics, kept beside the geometry (in
/// [`Scene::elements`], one per component, as compact records) so geometry work never copies
/// strings. Every field but the key is optional: a plain glTF node has none of them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ElementInfo {
    /// Stable identity: IFC GlobalId, or the glTF node path.
    pub key: String,
    pub name: Option<String>,
    /// IFC GlobalId (22 characters), when known.
    pub guid: Option<String>,
    /// IFC class, e.g. "IfcWindow".
    pub class: Option<SharedText>,
    /// Containing spatial structure, by name.
    pub storey: Option<SharedText>,
    pub building: Option<SharedText>,
    pub site: Option<SharedText>,
    /// Material name, when the source names one.
    pub material: Option<SharedText>,
    pub properties: Vec<Property>,
}

impl ElementInfo {
    /// An element known only by its key.
    pub fn keyed(key: impl Into<String>) -> ElementInfo {
        ElementInfo {
            key: key.into(),
            ..ElementInfo::default()
        }
    }
}

impl Component {
    /// A component with no hierarchy node or source index (id and bounds are filled in by
    /// [`Scene::push_component`] and [`Scene::finish`]).
    pub fn new(mesh: MeshId, world: DMat4) -> Component {
        Component {
            id: ComponentId(0),
            node: None,
            mesh,
            world,
            world_bounds: Aabb::EMPTY,
            source: 0,
            alias_of: None,
        }
    }

    /// The matrix that carries normals through `world` (inverse transpose of its linear part).
    pub fn normal_matrix(&self) -> glam::DMat3 {
        glam::DMat3::from_mat4(self.world).inverse().transpose()
    }

    /// Whether `world` mirrors (negative determinant): triangle winding must then be flipped to
    /// keep front faces in front.
    pub fn mirrors(&self) -> bool {
        glam::DMat3::from_mat4(self.world).determinant() < 0.0
    }
}

/// A number no building model holds, in an element's geometry or placement ([`Scene::first_implausible`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "element '{element}': {what} {value:e} m is not plausible (not finite, or beyond ±{bound:e} m, the Earth's circumference)",
    bound = crate::geodesy::PLAUSIBLE_COORDINATE_M
)]
pub struct ImplausibleNumber {
    /// The element's id (IFC GlobalId, glTF node path).
    pub element: String,
    /// "transform entry" or "vertex coordinate" (in the scene frame, after its transforms).
    pub what: &'static str,
    pub value: f64,
}

/// A source file that was read into the scene.
#[derive(Debug, Clone)]
pub struct SourceFile {
    pub path: std::path::PathBuf,
    pub bytes: u64,
}

/// A georeference found in an input (IFC site reference): where the model's `anchor` (a point in
/// the scene frame) lies on Earth, and how far the model is turned from true north.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SourceGeoreference {
    pub longitude_deg: f64,
    pub latitude_deg: f64,
    pub height_m: f64,
    /// Angle of true north from the model's +y axis, counter-clockwise positive (IFC TrueNorth).
    pub true_north_deg: Option<f64>,
    pub anchor: DVec3,
    /// Map coordinates (an IfcMapConversion, or `--crs`): model metres around the anchor → local
    /// east-north-up metres (the map's rotation and scales, the grid's convergence and scale
    /// factor); replaces the true-north turn.
    pub map_linear: Option<glam::DMat3>,
}

/// A georeference an input asked for but that could not be used (unknown CRS, a unit that is not
/// a length, a point far outside the CRS's area of use): the input falls back to the default
/// placement, with this warning; `--strict-georef` makes it an error.
#[derive(Debug, Clone, PartialEq)]
pub struct GeorefWarning {
    pub file: std::path::PathBuf,
    pub message: String,
}

#[derive(Debug, Clone, Default)]
pub struct Scene {
    pub sources: Vec<SourceFile>,
    /// The first georeference an input carried, if any.
    pub georeference: Option<SourceGeoreference>,
    /// The projected CRSs that placed inputs (report.json `georeference.crs`).
    pub crs_used: Vec<crate::geodesy::crs::CrsUse>,
    /// Georeferences that could not be used.
    pub georef_warnings: Vec<GeorefWarning>,
    /// What the readers left out or could not use (an IFC element skipped...), one line each
    /// naming the file: the report's `warnings`, printed by the CLI unless `--quiet`.
    pub reader_warnings: Vec<String>,
    /// Elements a reader skipped (broken geometry), counted for the report.
    pub skipped_elements: usize,
    /// Products left out because their only geometry is a curve (IFC alignments, footprints).
    pub curve_only_elements: usize,
    pub nodes: Vec<Node>,
    pub components: Vec<Component>,
    /// `elements.get(i)` describes `components[i]` (same length; see [`Scene::push_component`]).
    pub elements: ElementTable,
    /// Mesh geometry, in memory or spilled to disk under `--memory-budget`.
    pub meshes: MeshStore,
    pub materials: Vec<Material>,
    pub images: Vec<Image>,
    /// Primitives the readers could not use (points, lines), counted for the report.
    pub skipped_primitives: usize,
    /// Elements whose id is not their plain GlobalId or node path, because it repeated ([`ids`]).
    pub renamed_ids: usize,
    /// The scene is a campus of separately placed models (a manifest) built to be updated
    /// (`--update`), a building at a time: its octree sits on the fixed power-of-two grid and its
    /// enum codes come from the values' names, so that a change stays in the tiles it touches
    /// (`partition::octree`, `tileset::metadata`). Otherwise the octree fits the bounds and the
    /// enum codes are dense.
    pub stable_layout: bool,
}

impl Scene {
    /// Adds a component and its semantics, keeping `components` and `elements` aligned; the
    /// component's id is set to its index.
    pub fn push_component(&mut self, mut c: Component, info: &ElementInfo) -> ComponentId {
        let id = ComponentId(self.components.len() as u32);
        c.id = id;
        self.components.push(c);
        self.elements.push(info);
        id
    }

    /// The identity and semantics of component `id` (decoded from its record).
    pub fn element(&self, id: ComponentId) -> ElementInfo {
        self.elements.get(id.index())
    }

    pub fn component(&self, id: ComponentId) -> &Component {
        &self.components[id.index()]
    }
    pub fn mesh(&self, id: MeshId) -> Arc<Mesh> {
        self.meshes.get(id)
    }

    /// Components whose geometry is drawn (aliases of exact duplicates are not).
    pub fn drawn_components(&self) -> impl Iterator<Item = &Component> {
        self.components.iter().filter(|c| c.alias_of.is_none())
    }

    /// Total triangles drawn (a mesh used by several components counts once per use; aliases
    /// are not drawn).
    pub fn triangle_count(&self) -> usize {
        self.drawn_components()
            .map(|c| self.meshes.triangle_count(c.mesh))
            .sum()
    }
    pub fn vertex_count(&self) -> usize {
        self.drawn_components()
            .map(|c| self.meshes.vertex_count(c.mesh))
            .sum()
    }

    pub fn bounds(&self) -> Aabb {
        self.components
            .iter()
            .fold(Aabb::EMPTY, |b, c| b.union(&c.world_bounds))
    }

    /// Path of names from the hierarchy root to `node` ("Building/Level 1/Window-07"), a
    /// repeated sibling name numbered ("world/object#2", see [`ids`]).
    pub fn node_path(&self, node: NodeId) -> String {
        let mut parts = Vec::new();
        let mut cur = Some(node);
        while let Some(n) = cur {
            let nd = &self.nodes[n.index()];
            parts.push(ids::path_segment(nd.name.as_deref(), n.0, nd.name_repeat));
            cur = nd.parent;
        }
        parts.reverse();
        parts.join("/")
    }

    /// Whether `node`'s path holds a repeat number (`#n`) in any of its segments.
    pub fn path_is_numbered(&self, node: NodeId) -> bool {
        std::iter::successors(Some(node), |n| self.nodes[n.index()].parent)
            .any(|n| self.nodes[n.index()].name_repeat != 0)
    }

    /// Appends another scene (a second input file), renumbering its ids.
    pub fn append(&mut self, other: Scene) {
        let (n0, m0, mat0, img0, c0, s0) = (
            self.nodes.len() as u32,
            self.meshes.len() as u32,
            self.materials.len() as u32,
            self.images.len() as u32,
            self.components.len() as u32,
            self.sources.len() as u32,
        );
        self.sources.extend(other.sources);
        self.nodes.extend(other.nodes.into_iter().map(|mut n| {
            n.parent = n.parent.map(|p| NodeId(p.0 + n0));
            n
        }));
        self.images.extend(other.images);
        self.materials
            .extend(other.materials.into_iter().map(|mut m| {
                if let Some(t) = m.base_color_texture.as_mut() {
                    t.image = ImageId(t.image.0 + img0);
                }
                m
            }));
        self.meshes.append(other.meshes, mat0);
        self.elements.append(other.elements);
        self.components
            .extend(other.components.into_iter().map(|mut c| {
                c.id = ComponentId(c.id.0 + c0);
                c.node = c.node.map(|x| NodeId(x.0 + n0));
                c.mesh = MeshId(c.mesh.0 + m0);
                c.source += s0;
                c.alias_of = c.alias_of.map(|a| ComponentId(a.0 + c0));
                c
            }));
        self.skipped_primitives += other.skipped_primitives;
        self.skipped_elements += other.skipped_elements;
        self.curve_only_elements += other.curve_only_elements;
        self.renamed_ids += other.renamed_ids;
        self.georeference = self.georeference.or(other.georeference);
        self.crs_used.extend(other.crs_used);
        self.georef_warnings.extend(other.georef_warnings);
        self.reader_warnings.extend(other.reader_warnings);
    }

    /// Pre-multiplies every component's world transform (e.g. to move the anchor to the origin).
    pub fn apply_transform(&mut self, m: &DMat4) {
        for c in &mut self.components {
            c.world = *m * c.world;
        }
        self.compute_bounds();
    }

    /// The first component whose transform or placed vertices hold a number that is not
    /// plausible (`geodesy::plausible_m`: a 1e30 extrusion, a position at f32::MAX, a NaN), with
    /// the input file it came from. Checks the components' world boxes, not every vertex.
    pub fn first_implausible(&self) -> Option<(std::path::PathBuf, ImplausibleNumber)> {
        use crate::geodesy::first_implausible_m;
        self.components.iter().enumerate().find_map(|(i, c)| {
            let b = &c.world_bounds;
            let corners = || b.min.to_array().into_iter().chain(b.max.to_array());
            let (what, value) = first_implausible_m(c.world.to_cols_array())
                .map(|v| ("transform entry", v))
                .or_else(|| match b.is_empty() {
                    true => None,
                    false => first_implausible_m(corners()).map(|v| ("vertex coordinate", v)),
                })?;
            let file = self.sources.get(c.source as usize).map(|s| s.path.clone());
            let number = ImplausibleNumber {
                element: self.elements.get(i).key,
                what,
                value,
            };
            Some((file.unwrap_or_default(), number))
        })
    }

    /// Fills the derived fields (component world bounds; mesh local bounds are the store's).
    /// Called by readers once a scene is complete and after any geometry change.
    pub fn finish(&mut self) {
        debug_assert_eq!(self.elements.len(), self.components.len(), "push_component");
        self.compute_bounds();
    }

    /// Exact world boxes: every vertex transformed in f64 (a box of transformed local-box
    /// corners would be loose for rotated components, and tile volumes must be tight).
    fn compute_bounds(&mut self) {
        use rayon::prelude::*;
        let meshes = &self.meshes;
        self.components.par_iter_mut().for_each(|c| {
            let mut b = Aabb::EMPTY;
            let mut finite = true;
            for p in &meshes.get(c.mesh).primitives {
                for v in &p.positions {
                    let q =
                        c.world
                            .transform_point3(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64));
                    finite &= q.is_finite();
                    b.extend(q);
                }
            }
            // `extend` passes over NaN: a box of NaN keeps it for `first_implausible`.
            c.world_bounds = match finite {
                true => b,
                false => Aabb {
                    min: DVec3::NAN,
                    max: DVec3::NAN,
                },
            };
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_change_round_trips_and_maps_up() {
        let up_gltf = DVec3::new(0.0, 1.0, 0.0);
        assert_eq!(Y_UP_TO_Z_UP.transform_point3(up_gltf), DVec3::Z);
        // glTF +z (towards the viewer) is south: -y in the scene frame.
        assert_eq!(Y_UP_TO_Z_UP.transform_point3(DVec3::Z), -DVec3::Y);
        assert_eq!(Z_UP_TO_Y_UP * Y_UP_TO_Z_UP, DMat4::IDENTITY);
    }

    #[test]
    fn aabb_union_contains_and_transform() {
        let mut a = Aabb::EMPTY;
        assert!(a.is_empty());
        a.extend(DVec3::new(0.0, 0.0, 0.0));
        a.extend(DVec3::new(1.0, 2.0, 3.0));
        let b = Aabb {
            min: DVec3::splat(0.5),
            max: DVec3::splat(0.9),
        };
        assert!(a.contains_box(&b, 0.0));
        assert!(!b.contains_box(&a, 0.0));
        let t = DMat4::from_translation(DVec3::new(10.0, 0.0, 0.0));
        let m = a.transformed(&t);
        assert_eq!(m.min, DVec3::new(10.0, 0.0, 0.0));
        assert_eq!(m.max, DVec3::new(11.0, 2.0, 3.0));
        assert!((a.diagonal() - 14f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn interned_text_is_one_allocation_per_value() {
        let mut t = TextInterner::default();
        let (a, b, c) = (t.get("IfcWall"), t.get("IfcWall"), t.get("IfcSlab"));
        assert!(Arc::ptr_eq(&a, &b));
        assert!(!Arc::ptr_eq(&a, &c));
        assert_eq!((&*a, &*c), ("IfcWall", "IfcSlab"));
    }

    #[test]
    fn append_renumbers_ids() {
        let mk = || {
            let mut s = Scene::default();
            s.sources.push(SourceFile {
                path: "a".into(),
                bytes: 1,
            });
            s.nodes.push(Node::default());
            s.materials.push(Material::default());
            s.meshes.push(Mesh {
                name: None,
                primitives: vec![Primitive {
                    material: Some(MaterialId(0)),
                    positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                    indices: vec![0, 1, 2],
                    ..Default::default()
                }],
                local_bounds: None,
            });
            s.push_component(
                Component {
                    node: Some(NodeId(0)),
                    ..Component::new(MeshId(0), DMat4::IDENTITY)
                },
                &ElementInfo::keyed("k"),
            );
            s
        };
        let mut a = mk();
        a.append(mk());
        a.finish();
        assert_eq!(a.components[1].id, ComponentId(1));
        assert_eq!(a.components[1].mesh, MeshId(1));
        assert_eq!(a.components[1].node, Some(NodeId(1)));
        assert_eq!(a.components[1].source, 1);
        assert_eq!(
            a.mesh(MeshId(1)).primitives[0].material,
            Some(MaterialId(1))
        );
        assert_eq!(a.triangle_count(), 2);
        assert_eq!(a.bounds().max, DVec3::new(1.0, 1.0, 0.0));
    }
}
