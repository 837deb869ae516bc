//! A glTF JSON read in one streaming pass into compact tables, without a whole
//! `gltf_json::Root`.
//!
//! A BIM export's JSON is mostly four arrays that grow with the model: nodes, meshes, accessors and
//! bufferViews. `gltf_json` holds them as a tree several times the JSON text (every accessor's
//! min/max as a `serde_json::Value`; docs/benchmarks.md), which set the reader's peak memory. Here
//! each element of those arrays is parsed through its `gltf_json` type (same field rules and enum
//! checks) and at once reduced to what the reader uses. Everything else (asset, materials,
//! textures, images, samplers, buffers, extensions) stays a small `gltf_json::Root`, for the `gltf`
//! crate's document API and its reference checks; the reduced tables get the same checks here
//! ([`GltfIndex::check_references`]).

use gltf::accessor::{DataType, Dimensions};
use gltf::json::validation::Checked;
use serde::de::{DeserializeSeed, Deserializer, Error as _, MapAccess, SeqAccess, Visitor};
use serde::Deserialize;
use serde_json::value::RawValue;
use serde_json::{Map, Value};
use std::fmt;
use std::marker::PhantomData;

/// A glTF JSON that parses but does not hold together: each names the JSON path of the problem
/// (`accessors[3].componentType`). Inside the streaming parse it reaches the reader through
/// serde's error (which keeps only its text); the reference checks return it whole.
#[derive(Debug, thiserror::Error)]
pub enum GltfIndexError {
    /// An enum field holds a value glTF does not define.
    #[error("{path}: invalid value")]
    InvalidValue { path: String },
    /// A sparse accessor's indices are not of an index type (u8, u16, u32).
    #[error("{path}: {found} is not an index type")]
    NotIndexType { path: String, found: String },
    /// A primitive's attribute name is not a glTF semantic.
    #[error("{path}: invalid semantic")]
    InvalidSemantic { path: String },
    /// A problem the `gltf` crate's validator found in the rest of the JSON.
    #[error("{path}")]
    Validation {
        path: String,
        source: gltf::json::validation::Error,
    },
    /// Something the glTF 2.0 specification forbids that the reader would otherwise pass over
    /// (a mesh with no primitives, a byteStride that cuts elements, a version it does not read).
    #[error("{path}: {problem}")]
    Forbidden { path: String, problem: String },
    /// An index into another array that is past its end.
    #[error("{path}: index {index} out of bounds (of {len})")]
    OutOfBounds {
        path: String,
        index: usize,
        len: usize,
    },
}

/// The reduced glTF JSON.
pub struct GltfIndex {
    /// The rest of the JSON: no nodes, scenes, meshes, accessors or bufferViews, and images
    /// without their bufferView (kept in `image_views`, since the views live here).
    pub root: gltf::json::Root,
    pub image_views: Vec<Option<u32>>,
    pub nodes: Vec<IndexNode>,
    /// Each scene's root nodes, and the default scene.
    pub scenes: Vec<Vec<u32>>,
    pub scene: Option<u32>,
    pub meshes: Vec<MeshDesc>,
    pub accessors: Vec<AccessorDesc>,
    pub views: Vec<ViewDesc>,
}

/// A node: hierarchy, mesh, name, extras as written, and its transform in f64 (`gltf_json` keeps
/// f32, which loses millimetres on projected coordinates). The transform is boxed and absent when
/// the node has none (exports of many elements rarely give one): a quarter of the bytes a node,
/// on a site of a million nodes.
#[derive(Deserialize)]
#[serde(from = "NodeJson")]
pub struct IndexNode {
    pub name: Option<String>,
    pub mesh: Option<u32>,
    pub children: Vec<u32>,
    pub extras: Option<Box<RawValue>>,
    pub transform: Option<Box<NodeTransform>>,
}

/// A node's transform as written: a matrix, or translation, rotation and scale.
pub struct NodeTransform {
    pub matrix: Option<[f64; 16]>,
    pub translation: Option<[f64; 3]>,
    pub rotation: Option<[f64; 4]>,
    pub scale: Option<[f64; 3]>,
}

/// A node as the JSON has it, turned into an [`IndexNode`] as soon as it is read.
#[derive(Deserialize)]
struct NodeJson {
    name: Option<String>,
    mesh: Option<u32>,
    #[serde(default)]
    children: Vec<u32>,
    extras: Option<Box<RawValue>>,
    matrix: Option<[f64; 16]>,
    translation: Option<[f64; 3]>,
    rotation: Option<[f64; 4]>,
    scale: Option<[f64; 3]>,
}

impl From<NodeJson> for IndexNode {
    fn from(n: NodeJson) -> IndexNode {
        let given = n.matrix.is_some()
            || n.translation.is_some()
            || n.rotation.is_some()
            || n.scale.is_some();
        IndexNode {
            name: n.name,
            mesh: n.mesh,
            children: n.children,
            extras: n.extras,
            transform: given.then(|| {
                Box::new(NodeTransform {
                    matrix: n.matrix,
                    translation: n.translation,
                    rotation: n.rotation,
                    scale: n.scale,
                })
            }),
        }
    }
}

#[derive(Deserialize)]
struct SceneJson {
    #[serde(default)]
    nodes: Vec<u32>,
}

/// A bufferView reduced to what decoding needs.
#[derive(Clone)]
pub struct ViewDesc {
    pub buffer: usize,
    pub offset: usize,
    pub length: usize,
    pub stride: Option<usize>,
    /// `EXT_meshopt_compression`: where the compressed bytes are (boxed: rare). The reader
    /// decodes them before any accessor is read and points the view at the decoded bytes.
    pub meshopt: Option<Box<MeshoptView>>,
}

/// A bufferView's `EXT_meshopt_compression` object.
#[derive(Clone, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct MeshoptView {
    pub buffer: usize,
    #[serde(default)]
    pub byte_offset: usize,
    pub byte_length: usize,
    pub byte_stride: usize,
    pub count: usize,
    pub mode: String,
    #[serde(default)]
    pub filter: Option<String>,
}

#[cfg(test)]
impl MeshoptView {
    /// A stream of `mode` at the start of buffer 0 (the codec tests' views).
    pub(crate) fn at_start(mode: &str, stride: usize, count: usize, byte_length: usize) -> Self {
        MeshoptView {
            buffer: 0,
            byte_offset: 0,
            byte_length,
            byte_stride: stride,
            count,
            mode: mode.into(),
            filter: None,
        }
    }
}

/// A primitive's `KHR_draco_mesh_compression` object: the bufferView of the Draco stream and the
/// Draco unique id of each attribute we read.
#[derive(Default)]
pub struct DracoDesc {
    pub view: u32,
    pub positions: Option<u32>,
    pub normals: Option<u32>,
    pub uvs: Option<u32>,
    pub colors: Option<u32>,
}

/// An accessor's sparse substitution: `count` indices and values, each in its bufferView.
pub struct SparseDesc {
    pub count: usize,
    pub index_view: u32,
    pub index_offset: usize,
    pub index_size: usize,
    pub value_view: u32,
    pub value_offset: usize,
}

/// An accessor reduced to what decoding needs (sparse data boxed: it is rare).
pub struct AccessorDesc {
    pub view: Option<u32>,
    pub offset: usize,
    pub count: usize,
    pub data_type: DataType,
    pub dimensions: Dimensions,
    pub normalized: bool,
    pub sparse: Option<Box<SparseDesc>>,
}

impl AccessorDesc {
    /// The bufferViews this accessor reads (its own and its sparse data's).
    pub fn views(&self) -> impl Iterator<Item = u32> + '_ {
        let sparse = self
            .sparse
            .iter()
            .flat_map(|s| [s.index_view, s.value_view]);
        self.view.into_iter().chain(sparse)
    }
}

/// A primitive reduced to what decoding needs: accessor indices; checks of the data run when it
/// is decoded.
pub struct PrimitiveDesc {
    pub mode: gltf::mesh::Mode,
    pub draco: Option<Box<DracoDesc>>,
    pub material: Option<u32>,
    pub positions: Option<u32>,
    pub normals: Option<u32>,
    pub uvs: Option<u32>,
    pub colors: Option<u32>,
    pub indices: Option<u32>,
}

impl PrimitiveDesc {
    pub fn accessors(&self) -> impl Iterator<Item = u32> {
        [
            self.positions,
            self.normals,
            self.uvs,
            self.colors,
            self.indices,
        ]
        .into_iter()
        .flatten()
    }
}

/// A mesh reduced to what decoding needs.
pub struct MeshDesc {
    pub name: Option<String>,
    pub primitives: Vec<PrimitiveDesc>,
}

fn usize_of(v: gltf::json::validation::USize64) -> usize {
    usize::try_from(v.0).unwrap_or(usize::MAX)
}

fn checked<T: Copy>(c: &Checked<T>, what: impl FnOnce() -> String) -> Result<T, GltfIndexError> {
    match c {
        Checked::Valid(v) => Ok(*v),
        Checked::Invalid => Err(GltfIndexError::InvalidValue { path: what() }),
    }
}

fn view_of(i: usize, v: gltf::json::buffer::View) -> Result<ViewDesc, GltfIndexError> {
    let meshopt = match v
        .extensions
        .as_ref()
        .and_then(|e| e.others.get("EXT_meshopt_compression"))
    {
        None => None,
        Some(ext) => Some(Box::new(MeshoptView::deserialize(ext).map_err(|_| {
            GltfIndexError::InvalidValue {
                path: format!("bufferViews[{i}].extensions.EXT_meshopt_compression"),
            }
        })?)),
    };
    Ok(ViewDesc {
        buffer: v.buffer.value(),
        offset: v.byte_offset.map_or(0, usize_of),
        length: usize_of(v.byte_length),
        stride: v.byte_stride.map(|s| s.0),
        meshopt,
    })
}

/// A primitive's `KHR_draco_mesh_compression`, if it has one.
fn draco_of(
    path: impl Fn() -> String,
    ext: Option<&gltf::json::extensions::mesh::Primitive>,
) -> Result<Option<Box<DracoDesc>>, GltfIndexError> {
    let Some(value) = ext.and_then(|e| e.others.get("KHR_draco_mesh_compression")) else {
        return Ok(None);
    };
    let invalid = || GltfIndexError::InvalidValue {
        path: format!("{}.extensions.KHR_draco_mesh_compression", path()),
    };
    let view = value
        .get("bufferView")
        .and_then(Value::as_u64)
        .and_then(|v| u32::try_from(v).ok())
        .ok_or_else(invalid)?;
    let attributes = value
        .get("attributes")
        .and_then(Value::as_object)
        .ok_or_else(invalid)?;
    let id = |name: &str| -> Result<Option<u32>, GltfIndexError> {
        match attributes.get(name) {
            None => Ok(None),
            Some(v) => v
                .as_u64()
                .and_then(|v| u32::try_from(v).ok())
                .map(Some)
                .ok_or_else(invalid),
        }
    };
    Ok(Some(Box::new(DracoDesc {
        view,
        positions: id("POSITION")?,
        normals: id("NORMAL")?,
        uvs: id("TEXCOORD_0")?,
        colors: id("COLOR_0")?,
    })))
}

fn accessor_of(i: usize, a: gltf::json::Accessor) -> Result<AccessorDesc, GltfIndexError> {
    use gltf::json::accessor::IndexComponentType as I;
    let sparse = match &a.sparse {
        None => None,
        Some(s) => Some(Box::new(SparseDesc {
            count: usize_of(s.count),
            index_view: s.indices.buffer_view.value() as u32,
            index_offset: usize_of(s.indices.byte_offset),
            index_size: match checked(&s.indices.component_type, || {
                format!("accessors[{i}].sparse.indices.componentType")
            })? {
                I(DataType::U8) => 1,
                I(DataType::U16) => 2,
                I(DataType::U32) => 4,
                I(other) => {
                    return Err(GltfIndexError::NotIndexType {
                        path: format!("accessors[{i}].sparse.indices.componentType"),
                        found: format!("{other:?}"),
                    })
                }
            },
            value_view: s.values.buffer_view.value() as u32,
            value_offset: usize_of(s.values.byte_offset),
        })),
    };
    Ok(AccessorDesc {
        view: a.buffer_view.map(|v| v.value() as u32),
        offset: a.byte_offset.map_or(0, usize_of),
        count: usize_of(a.count),
        data_type: checked(&a.component_type, || {
            format!("accessors[{i}].componentType")
        })?
        .0,
        dimensions: checked(&a.type_, || format!("accessors[{i}].type"))?,
        normalized: a.normalized,
        sparse,
    })
}

fn mesh_of(i: usize, m: gltf::json::Mesh) -> Result<MeshDesc, GltfIndexError> {
    use gltf::json::mesh::Semantic;
    let mut primitives = Vec::with_capacity(m.primitives.len());
    for (pi, p) in m.primitives.iter().enumerate() {
        let attr = |s: Semantic| {
            p.attributes
                .get(&Checked::Valid(s))
                .map(|a| a.value() as u32)
        };
        if p.attributes.keys().any(|k| matches!(k, Checked::Invalid)) {
            return Err(GltfIndexError::InvalidSemantic {
                path: format!("meshes[{i}].primitives[{pi}].attributes"),
            });
        }
        primitives.push(PrimitiveDesc {
            mode: checked(&p.mode, || format!("meshes[{i}].primitives[{pi}].mode"))?,
            draco: draco_of(
                || format!("meshes[{i}].primitives[{pi}]"),
                p.extensions.as_ref(),
            )?,
            material: p.material.map(|m| m.value() as u32),
            positions: attr(Semantic::Positions),
            normals: attr(Semantic::Normals),
            uvs: attr(Semantic::TexCoords(0)),
            colors: attr(Semantic::Colors(0)),
            indices: p.indices.map(|a| a.value() as u32),
        });
    }
    Ok(MeshDesc {
        name: m.name,
        primitives,
    })
}

/// Deserializes a JSON array element by element as `T`, reducing each with `F` at once.
struct Reduce<T, O, F>(F, PhantomData<fn(T) -> O>);

impl<'de, T, O, F> DeserializeSeed<'de> for Reduce<T, O, F>
where
    T: Deserialize<'de>,
    F: FnMut(usize, T) -> Result<O, GltfIndexError>,
{
    type Value = Vec<O>;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Vec<O>, D::Error> {
        d.deserialize_seq(self)
    }
}

impl<'de, T, O, F> Visitor<'de> for Reduce<T, O, F>
where
    T: Deserialize<'de>,
    F: FnMut(usize, T) -> Result<O, GltfIndexError>,
{
    type Value = Vec<O>;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("an array")
    }
    fn visit_seq<A: SeqAccess<'de>>(mut self, mut seq: A) -> Result<Vec<O>, A::Error> {
        let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0));
        while let Some(e) = seq.next_element::<T>()? {
            out.push((self.0)(out.len(), e).map_err(A::Error::custom)?);
        }
        Ok(out)
    }
}

fn reduce<'de, T, O, F>(f: F) -> Reduce<T, O, F>
where
    T: Deserialize<'de>,
    F: FnMut(usize, T) -> Result<O, GltfIndexError>,
{
    Reduce(f, PhantomData)
}

impl<'de> Deserialize<'de> for GltfIndex {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_map(IndexVisitor)
    }
}

struct IndexVisitor;

impl<'de> Visitor<'de> for IndexVisitor {
    type Value = GltfIndex;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a glTF JSON object")
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<GltfIndex, A::Error> {
        let (mut nodes, mut scenes, mut scene) = (Vec::new(), Vec::new(), None);
        let (mut meshes, mut accessors, mut views) = (Vec::new(), Vec::new(), Vec::new());
        let mut rest = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            match key.as_str() {
                "nodes" => nodes = map.next_value()?,
                "scenes" => scenes = map.next_value_seed(reduce(|_, s: SceneJson| Ok(s.nodes)))?,
                "scene" => scene = map.next_value()?,
                "meshes" => meshes = map.next_value_seed(reduce(mesh_of))?,
                "accessors" => accessors = map.next_value_seed(reduce(accessor_of))?,
                "bufferViews" => views = map.next_value_seed(reduce(view_of))?,
                _ => {
                    rest.insert(key, map.next_value::<Value>()?);
                }
            }
        }
        let mut root: gltf::json::Root =
            serde_json::from_value(Value::Object(rest)).map_err(A::Error::custom)?;
        let image_views = root
            .images
            .iter_mut()
            .map(|i| i.buffer_view.take().map(|v| v.value() as u32))
            .collect();
        Ok(GltfIndex {
            root,
            image_views,
            nodes,
            scenes,
            scene,
            meshes,
            accessors,
            views,
        })
    }
}

impl GltfIndex {
    /// Broken indices in the reduced tables, as the `gltf` crate's validator reports them for the
    /// rest: the first one.
    pub fn check_references(&self) -> Result<(), GltfIndexError> {
        let bad = |path: String, i: u32, len: usize| match (i as usize) < len {
            true => Ok(()),
            false => Err(GltfIndexError::OutOfBounds {
                path,
                index: i as usize,
                len,
            }),
        };
        let n = self.nodes.len();
        for (i, node) in self.nodes.iter().enumerate() {
            if let Some(m) = node.mesh {
                bad(format!("nodes[{i}].mesh"), m, self.meshes.len())?;
            }
            for (k, &c) in node.children.iter().enumerate() {
                bad(format!("nodes[{i}].children[{k}]"), c, n)?;
            }
        }
        for (i, s) in self.scenes.iter().enumerate() {
            for (k, &c) in s.iter().enumerate() {
                bad(format!("scenes[{i}].nodes[{k}]"), c, n)?;
            }
        }
        if let Some(s) = self.scene {
            bad("scene".into(), s, self.scenes.len())?;
        }
        for (i, m) in self.meshes.iter().enumerate() {
            for (pi, p) in m.primitives.iter().enumerate() {
                for a in p.accessors() {
                    bad(
                        format!("meshes[{i}].primitives[{pi}]"),
                        a,
                        self.accessors.len(),
                    )?;
                }
                if let Some(mat) = p.material {
                    bad(
                        format!("meshes[{i}].primitives[{pi}].material"),
                        mat,
                        self.root.materials.len(),
                    )?;
                }
            }
        }
        for (i, m) in self.meshes.iter().enumerate() {
            for (pi, p) in m.primitives.iter().enumerate() {
                if let Some(d) = &p.draco {
                    bad(
                        format!("meshes[{i}].primitives[{pi}].extensions.KHR_draco_mesh_compression.bufferView"),
                        d.view,
                        self.views.len(),
                    )?;
                }
            }
        }
        for (i, a) in self.accessors.iter().enumerate() {
            for v in a.views() {
                bad(format!("accessors[{i}].bufferView"), v, self.views.len())?;
            }
        }
        for (i, v) in self.views.iter().enumerate() {
            if v.buffer >= self.root.buffers.len() {
                return Err(GltfIndexError::OutOfBounds {
                    path: format!("bufferViews[{i}].buffer"),
                    index: v.buffer,
                    len: self.root.buffers.len(),
                });
            }
            if let Some(m) = &v.meshopt {
                if m.buffer >= self.root.buffers.len() {
                    return Err(GltfIndexError::OutOfBounds {
                        path: format!("bufferViews[{i}].extensions.EXT_meshopt_compression.buffer"),
                        index: m.buffer,
                        len: self.root.buffers.len(),
                    });
                }
            }
        }
        for (i, v) in self.image_views.iter().enumerate() {
            if let Some(v) = *v {
                bad(format!("images[{i}].bufferView"), v, self.views.len())?;
            }
        }
        self.check_spec_rules()
    }

    /// The glTF 2.0 rules (section 3 and 5 of the specification) a reader could pass over
    /// without noticing: the asset's version, meshes with primitives, byte strides that hold
    /// their elements.
    fn check_spec_rules(&self) -> Result<(), GltfIndexError> {
        let forbidden = |path: String, problem: String| GltfIndexError::Forbidden { path, problem };
        check_version(&self.root.asset).map_err(|(field, problem)| forbidden(field, problem))?;
        if let Some(i) = self.meshes.iter().position(|m| m.primitives.is_empty()) {
            let problem = "a mesh with no primitives (glTF 2.0 requires at least one)";
            return Err(forbidden(format!("meshes[{i}]"), problem.into()));
        }
        for (i, v) in self.views.iter().enumerate() {
            let Some(stride) = v.stride else { continue };
            if !(4..=252).contains(&stride) || stride % 4 != 0 {
                let problem =
                    format!("byteStride {stride} is not a multiple of 4 from 4 to 252 (glTF 2.0)");
                return Err(forbidden(format!("bufferViews[{i}]"), problem));
            }
        }
        for (i, a) in self.accessors.iter().enumerate() {
            let Some(view) = a.view else { continue };
            let Some(stride) = self.views[view as usize].stride else {
                continue;
            };
            let element_bytes = a.data_type.size() * a.dimensions.multiplicity();
            if stride < element_bytes {
                let problem = format!(
                    "its {element_bytes}-byte elements overlap: bufferViews[{view}].byteStride is {stride}"
                );
                return Err(forbidden(format!("accessors[{i}]"), problem));
            }
        }
        Ok(())
    }
}

/// glTF 2.0 `asset.version` and `asset.minVersion` (section 5.2): "MAJOR.MINOR", major 2, and
/// no minVersion above 2.0 (this reader implements 2.0). `Err`: the field and the problem.
fn check_version(asset: &gltf::json::Asset) -> Result<(), (String, String)> {
    let parse = |v: &str| -> Option<(u32, u32)> {
        let (major, minor) = v.split_once('.')?;
        let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
        (digits(major) && digits(minor))
            .then(|| Some((major.parse().ok()?, minor.parse().ok()?)))?
    };
    match parse(&asset.version) {
        Some((2, _)) => {}
        _ => {
            let problem = format!("version '{}' is not a glTF 2.x version", asset.version);
            return Err(("asset.version".into(), problem));
        }
    }
    match asset.min_version.as_deref().map(|v| (v, parse(v))) {
        None | Some((_, Some((2, 0)))) => Ok(()),
        Some((v, _)) => Err((
            "asset.minVersion".into(),
            format!("'{v}' asks for more than glTF 2.0, which bimtiles reads"),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn index(json: serde_json::Value) -> GltfIndex {
        serde_json::from_value(json).unwrap()
    }

    fn base() -> serde_json::Value {
        serde_json::json!({
            "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0, "name": "n", "translation": [512345.678, 0, 1],
                       "extras": {"ifc_class": "IfcWall"}}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1},
                        "indices": 2, "material": 0}]}],
            "materials": [{}],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                 "min": [0, 0, 0], "max": [1, 1, 0]},
                {"bufferView": 0, "byteOffset": 36, "componentType": 5123, "normalized": true,
                 "count": 3, "type": "VEC2"},
                {"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR",
                 "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5121},
                            "values": {"bufferView": 1, "byteOffset": 4}}}],
            "bufferViews": [{"buffer": 0, "byteLength": 48, "byteStride": 12},
                            {"buffer": 0, "byteOffset": 48, "byteLength": 12}],
            "buffers": [{"byteLength": 60}],
            "images": [{"bufferView": 1, "mimeType": "image/png"}]
        })
    }

    #[test]
    fn reduces_the_large_arrays_and_keeps_the_rest() {
        let ix = index(base());
        assert!(ix.check_references().is_ok());
        assert_eq!(ix.scenes, vec![vec![0]]);
        assert_eq!(ix.scene, Some(0));
        let n = &ix.nodes[0];
        assert_eq!((n.mesh, n.name.as_deref()), (Some(0), Some("n")));
        // f64 transforms, extras as written.
        let t = n.transform.as_deref().unwrap();
        assert_eq!(t.translation.unwrap()[0], 512345.678);
        assert!(t.matrix.is_none() && t.rotation.is_none() && t.scale.is_none());
        assert_eq!(
            n.extras.as_ref().unwrap().get(),
            r#"{"ifc_class":"IfcWall"}"#
        );
        let p = &ix.meshes[0].primitives[0];
        assert_eq!(
            (p.positions, p.uvs, p.indices, p.normals, p.material),
            (Some(0), Some(1), Some(2), None, Some(0))
        );
        assert_eq!(p.mode, gltf::mesh::Mode::Triangles);
        let uv = &ix.accessors[1];
        assert_eq!(
            (uv.offset, uv.data_type, uv.normalized),
            (36, DataType::U16, true)
        );
        assert_eq!(uv.dimensions, Dimensions::Vec2);
        let sparse = ix.accessors[2].sparse.as_ref().unwrap();
        assert_eq!((sparse.index_size, sparse.value_offset), (1, 4));
        assert_eq!(ix.accessors[2].views().collect::<Vec<_>>(), vec![1, 1, 1]);
        assert_eq!((ix.views[0].stride, ix.views[1].offset), (Some(12), 48));
        // The rest is a gltf_json Root; the image's view moved beside it.
        assert_eq!(ix.root.materials.len(), 1);
        assert_eq!(ix.image_views, vec![Some(1)]);
        assert!(ix.root.images[0].buffer_view.is_none());
        assert!(ix.root.accessors.is_empty() && ix.root.nodes.is_empty());
    }

    #[test]
    fn broken_references_are_reported_with_their_path() {
        type Break = fn(&mut serde_json::Value);
        let cases: [(&str, Break); 6] = [
            ("nodes[0].mesh", |j| j["nodes"][0]["mesh"] = 3.into()),
            ("scenes[0].nodes[0]", |j| {
                j["scenes"][0]["nodes"][0] = 9.into()
            }),
            ("meshes[0].primitives[0]", |j| {
                j["meshes"][0]["primitives"][0]["indices"] = 7.into()
            }),
            ("meshes[0].primitives[0].material", |j| {
                j["materials"] = serde_json::json!([])
            }),
            ("accessors[2].bufferView", |j| {
                j["accessors"][2]["sparse"]["values"]["bufferView"] = 5.into()
            }),
            ("images[0].bufferView", |j| {
                j["images"][0]["bufferView"] = 2.into()
            }),
        ];
        for (path, edit) in cases {
            let mut j = base();
            edit(&mut j);
            let e = index(j).check_references().unwrap_err();
            assert!(
                matches!(&e, GltfIndexError::OutOfBounds { path: p, .. } if p == path),
                "{path}: {e}"
            );
            assert!(e.to_string().starts_with(path), "{path}: {e}");
        }
    }

    #[test]
    fn invalid_enums_fail_the_parse() {
        let mut j = base();
        j["accessors"][0]["componentType"] = 1234.into();
        let e = serde_json::from_value::<GltfIndex>(j)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("accessors[0].componentType"), "{e}");
        let mut j = base();
        j["meshes"][0]["primitives"][0]["mode"] = 9.into();
        let e = serde_json::from_value::<GltfIndex>(j)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("meshes[0].primitives[0].mode"), "{e}");
        let mut j = base();
        j["accessors"][2]["sparse"]["indices"]["componentType"] = 5126.into();
        let e = serde_json::from_value::<GltfIndex>(j)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("accessors[2].sparse.indices.componentType: invalid value"),
            "{e}"
        );
    }

    #[test]
    fn a_bad_semantic_is_typed() {
        let m: gltf::json::Mesh = serde_json::from_value(serde_json::json!(
            {"primitives": [{"attributes": {"POSITION": 0, "NOT_A_SEMANTIC": 1}}]}
        ))
        .unwrap();
        let e = mesh_of(4, m).err().unwrap();
        assert!(
            matches!(&e, GltfIndexError::InvalidSemantic { path } if path == "meshes[4].primitives[0].attributes"),
            "{e}"
        );
    }
}
