//! Writes a tile's content as one GLB (glTF 2.0 binary container).
//!
//! The components of a tile are merged per material into one primitive each, so a tile costs a
//! few draw calls however many elements it holds. Identity survives the merge: every vertex gets
//! `_FEATURE_ID_0` = the component's index in the tile, declared with `EXT_mesh_features` (3D Tiles
//! 1.1 metadata), so picking still names the element.
//!
//! Vertices are transformed in f64 from their mesh frame to the scene frame, made relative to the
//! tile's centre, turned to glTF's y-up, and only then stored as f32; the centre goes into the
//! root node's translation. Precision is thus bounded by the tile's size, not the model's.

use super::metadata::{write_property_table, PropertyTable};
use crate::error::{Error, Result};
use crate::glb_container::glb_container;
use crate::partition::content::{ContentPrimitive, TileContent};
use crate::partition::ContentItem;
use crate::scene::*;
use crate::texture::{ImageSource, TileImage};
use byteorder::{WriteBytesExt, LE};
use glam::{DMat4, DVec3};
use serde_json::{json, Map, Value};
use std::collections::BTreeMap;

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const BYTE: u32 = 5120;
const SHORT: u32 = 5122;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;

/// What a written tile holds, for the tileset and the report.
#[derive(Debug, Clone)]
pub struct EncodedTile {
    pub glb: Vec<u8>,
    /// Triangles and vertices drawn (an instanced shape once per instance).
    pub triangles: usize,
    pub vertices: usize,
    /// Triangles stored (an instanced shape once).
    pub stored_triangles: usize,
    /// Instanced shapes and the components drawn through them.
    pub instanced_shapes: usize,
    pub instances: usize,
    /// Exact box of the written vertices, in the scene frame.
    pub bounds: Aabb,
    /// The component of each feature ID (`_FEATURE_ID_0` value = index here).
    pub features: Vec<ComponentId>,
    /// Bytes of the property table (buffers and its JSON), 0 without metadata.
    pub metadata_bytes: usize,
}

/// Geometry compression of tile content.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Compression {
    /// Plain float attributes and integer indices.
    None,
    /// `KHR_mesh_quantization`: positions as normalized i16 in a frame per mesh (dequantized by
    /// the node transform; float when the mesh is too large for the position error bound),
    /// normals as normalized i8, UVs in [0, 1] as normalized u16 (float when they tile).
    Quantized,
    /// `KHR_draco_mesh_compression` on every primitive (every attribute inside Draco).
    #[default]
    Draco,
}

/// How a tile is written.
#[derive(Debug, Clone)]
pub struct TileEncoding {
    pub compression: Compression,
    /// Largest position error quantization may add (metres): Draco's position bits are derived
    /// from it and the primitive's extent.
    pub max_position_error_m: f64,
    /// Shading normals from the faces as Draco's quantization leaves them (simplified content,
    /// whose normals come from its faces anyway: `simplify::normals`). Coarse quantization turns
    /// small faces; normals that follow them shade what is drawn, and Draco predicts them from
    /// those faces (Mini_Project's root: 61.9 -> 55.9 KB).
    pub normals_from_drawn_faces: bool,
    pub generator: String,
}

impl Default for TileEncoding {
    fn default() -> Self {
        TileEncoding {
            compression: Compression::Draco,
            max_position_error_m: DEFAULT_MAX_POSITION_ERROR_M,
            normals_from_drawn_faces: false,
            generator: concat!("bimtiles ", env!("CARGO_PKG_VERSION")).into(),
        }
    }
}

/// Quantization error allowed on full-detail content: at most 1 mm per axis, below what a viewer
/// can show of a building and what BIM exports are accurate to.
pub const DEFAULT_MAX_POSITION_ERROR_M: f64 = 0.001;
/// Draco bits for normals (octahedral): 8 bits (Draco's default) keeps normals within about a
/// degree, below visible shading error.
const NORMAL_BITS: u8 = 8;
/// Draco bits for colours: 8 bits per channel, as images have.
const COLOR_BITS: u8 = 8;

/// Texels per texture repeat assumed when the image's size is unknown (no texture, unreadable
/// header): a step of 1/1024 is half a texel of a 512-pixel texture.
const DEFAULT_UV_TEXELS: u32 = 512;

/// Draco bits for texture coordinates: a step of at most half a texel of the bound image
/// (`texels` along its longer side, full resolution) over the primitive's UV range (tiling UVs
/// span many repeats), so a texel lookup moves by at most half a texel. Measured on
/// LoD3_Railway (64-512 px textures): UVs are 46 % of its Draco bytes and each bit 3.5 %.
fn uv_bits(uvs: &[[f32; 2]], texels: u32) -> u8 {
    let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
    for t in uvs {
        for k in 0..2 {
            lo[k] = lo[k].min(t[k]);
            hi[k] = hi[k].max(t[k]);
        }
    }
    let range = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1.0) as f64;
    // step = range / (2^bits - 1) <= 1 / (2 texels), to within a factor 2^bits / (2^bits - 1).
    ((range * 2.0 * texels.max(1) as f64).log2().ceil() as u8).clamp(6, 20)
}

/// Texels along the longer side of the base colour image of `material` at full resolution, or
/// of the atlas the tile samples it from (`sampled_px`) when that is larger.
fn texture_texels(
    scene: &Scene,
    material: Option<MaterialId>,
    sampled_px: &BTreeMap<ImageId, u32>,
) -> u32 {
    let t = material.and_then(|m| scene.materials[m.index()].base_color_texture.as_ref());
    let own = t
        .and_then(|t| crate::texture::codec::dimensions(&scene.images[t.image.index()].bytes).ok())
        .map_or(DEFAULT_UV_TEXELS, |(w, h)| w.max(h));
    own.max(
        t.and_then(|t| sampled_px.get(&t.image))
            .copied()
            .unwrap_or(0),
    )
}

/// Makes the property table of a tile's features (in feature-ID order).
pub type TableMaker<'a> = &'a (dyn Fn(&[ComponentId]) -> PropertyTable + Sync);

/// Encodes `content` of `scene` (whole components or parts) as one GLB whose origin is `center`
/// (scene frame); with `metadata`, the features get a property table (`EXT_structural_metadata`).
pub fn encode_tile(
    scene: &Scene,
    content: &[ContentItem],
    center: DVec3,
    enc: &TileEncoding,
    metadata: Option<TableMaker>,
) -> Result<EncodedTile> {
    encode_content(
        scene,
        &TileContent::gather(scene, content, center),
        enc,
        metadata,
    )
}

/// Encodes merged tile content (full detail or simplified) as one GLB.
pub fn encode_content(
    scene: &Scene,
    content: &TileContent,
    enc: &TileEncoding,
    metadata: Option<TableMaker>,
) -> Result<EncodedTile> {
    encode_content_from(scene, content, enc, metadata, None, &BTreeMap::new())
}

/// [`encode_content`], with the images taken from `images` instead of the scene;
/// `sampled_px`: the longer side of the image the tile samples instead of a scene image (a
/// texture atlas, `crate::texture::atlas`), which Draco's UV precision must resolve.
pub fn encode_content_with_images(
    scene: &Scene,
    content: &TileContent,
    enc: &TileEncoding,
    metadata: Option<TableMaker>,
    images: ImageSource,
    sampled_px: &BTreeMap<ImageId, u32>,
) -> Result<EncodedTile> {
    encode_content_from(scene, content, enc, metadata, Some(images), sampled_px)
}

fn encode_content_from(
    scene: &Scene,
    content: &TileContent,
    enc: &TileEncoding,
    metadata: Option<TableMaker>,
    images: Option<ImageSource>,
    sampled_px: &BTreeMap<ImageId, u32>,
) -> Result<EncodedTile> {
    let mut bounds = content.bounds();
    let table = metadata.map(|make| make(&content.features));
    let mats = MaterialTable {
        image_source: images,
        sampled_px: sampled_px.clone(),
        ..MaterialTable::default()
    };
    let (glb, metadata_bytes) =
        write_glb(scene, content, enc, table.as_ref(), &mut bounds, mats)
            .map_err(|e| Error::output("tile", format!("GLB encoding failed: {e}")))?;
    Ok(EncodedTile {
        glb,
        triangles: content.triangle_count(),
        vertices: content.vertex_count(),
        stored_triangles: content.stored_triangle_count(),
        instanced_shapes: content.instanced.len(),
        instances: content.instance_count(),
        bounds,
        features: content.features.clone(),
        metadata_bytes,
    })
}

/// Scene z-up → glTF y-up: (x, y, z) ↦ (x, z, -y), as `Z_UP_TO_Y_UP`.
fn y_up(v: &[[f32; 3]]) -> Vec<[f32; 3]> {
    v.iter().map(|p| [p[0], p[2], -p[1]]).collect()
}

/// Builds the glTF JSON and BIN chunk.
struct GltfBuilder {
    bin: Vec<u8>,
    buffer_views: Vec<Value>,
    accessors: Vec<Value>,
}

impl GltfBuilder {
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        self.view_aligned(bytes, target, 4)
    }

    /// A bufferView whose offset is a multiple of `align` (and of 4).
    fn view_aligned(&mut self, bytes: &[u8], target: Option<u32>, align: usize) -> usize {
        let align = align.max(4);
        while self.bin.len() % align != 0 {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.extend_from_slice(bytes);
        self.buffer_views.push(v);
        self.buffer_views.len() - 1
    }

    fn float_accessor<const N: usize>(&mut self, data: &[[f32; N]], with_min_max: bool) -> usize {
        self.float_accessor_in(data, with_min_max, Some(ARRAY_BUFFER))
    }

    /// A float accessor in its own bufferView (`target` None for instance attributes, which are
    /// not vertex buffers).
    fn float_accessor_in<const N: usize>(
        &mut self,
        data: &[[f32; N]],
        with_min_max: bool,
        target: Option<u32>,
    ) -> usize {
        let mut bytes = Vec::with_capacity(data.len() * N * 4);
        for v in data {
            for x in v {
                bytes.write_f32::<LE>(*x).expect("vec write");
            }
        }
        let view = self.view(&bytes, target);
        let ty = match N {
            1 => "SCALAR",
            2 => "VEC2",
            3 => "VEC3",
            _ => "VEC4",
        };
        let mut a =
            json!({"bufferView": view, "componentType": FLOAT, "count": data.len(), "type": ty});
        if with_min_max {
            let mut lo = [f32::INFINITY; N];
            let mut hi = [f32::NEG_INFINITY; N];
            for v in data {
                for k in 0..N {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
            a["min"] = json!(lo.iter().map(|&x| x as f64).collect::<Vec<_>>());
            a["max"] = json!(hi.iter().map(|&x| x as f64).collect::<Vec<_>>());
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// A normalized integer vertex attribute: `N` components of `size` bytes each (1 or 2),
    /// padded to a 4-byte stride as glTF requires of vertex attributes; with `with_min_max`, the
    /// integer bounds.
    fn normalized_accessor<const N: usize>(
        &mut self,
        data: &[[i32; N]],
        component_type: u32,
        with_min_max: bool,
    ) -> usize {
        let size = if component_type == BYTE { 1 } else { 2 };
        let stride = (N * size).div_ceil(4) * 4;
        let mut bytes = Vec::with_capacity(data.len() * stride);
        for v in data {
            for &x in v {
                match size {
                    1 => bytes.push(x as i8 as u8),
                    _ => bytes.extend_from_slice(&(x as u16).to_le_bytes()),
                }
            }
            bytes.resize(bytes.len() + stride - N * size, 0);
        }
        let view = self.view(&bytes, Some(ARRAY_BUFFER));
        if stride != N * size {
            self.buffer_views[view]["byteStride"] = json!(stride);
        }
        let ty = ["SCALAR", "VEC2", "VEC3", "VEC4"][N - 1];
        let mut a = json!({"bufferView": view, "componentType": component_type,
            "normalized": true, "count": data.len(), "type": ty});
        if with_min_max {
            let lo: Vec<i32> = (0..N)
                .map(|k| data.iter().map(|v| v[k]).min().unwrap_or(0))
                .collect();
            let hi: Vec<i32> = (0..N)
                .map(|k| data.iter().map(|v| v[k]).max().unwrap_or(0))
                .collect();
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    fn index_accessor(&mut self, indices: &[u32], vertex_count: usize) -> usize {
        let (bytes, ct) = if vertex_count <= u16::MAX as usize {
            let mut b = Vec::with_capacity(indices.len() * 2);
            for &i in indices {
                b.write_u16::<LE>(i as u16).expect("vec write");
            }
            (b, UNSIGNED_SHORT)
        } else {
            let mut b = Vec::with_capacity(indices.len() * 4);
            for &i in indices {
                b.write_u32::<LE>(i).expect("vec write");
            }
            (b, UNSIGNED_INT)
        };
        let view = self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER));
        self.accessors.push(json!({"bufferView": view, "componentType": ct, "count": indices.len(), "type": "SCALAR"}));
        self.accessors.len() - 1
    }
}

/// The materials, textures, images and samplers of one GLB, each written once.
#[derive(Default)]
struct MaterialTable<'a> {
    /// Where image bytes come from (default: the scene's own).
    image_source: Option<ImageSource<'a>>,
    materials: Vec<Value>,
    material_map: BTreeMap<u32, usize>,
    images: Vec<Value>,
    image_map: BTreeMap<u32, usize>,
    /// Shared files written, by URI, and embedded atlases, by their bytes' address: two scene
    /// images packed into one atlas are one glTF image.
    uri_map: BTreeMap<String, usize>,
    embedded: Vec<(std::sync::Arc<Vec<u8>>, usize)>,
    /// See [`encode_content_with_images`].
    sampled_px: BTreeMap<ImageId, u32>,
    samplers: Vec<Sampler>,
    textures: Vec<(usize, usize)>,
}

impl MaterialTable<'_> {
    /// The glTF index of scene material `mid`, written (with its image) on first use.
    fn index(
        &mut self,
        scene: &Scene,
        b: &mut GltfBuilder,
        mid: MaterialId,
    ) -> std::result::Result<usize, String> {
        if let Some(&i) = self.material_map.get(&mid.0) {
            return Ok(i);
        }
        let mat = &scene.materials[mid.index()];
        let mut tex = None;
        if let Some(t) = mat.base_color_texture.as_ref() {
            let img = match self.image_map.get(&t.image.0) {
                Some(&i) => i,
                None => {
                    let im = &scene.images[t.image.index()];
                    let image = match self.image_source {
                        Some(source) => source(t.image)?,
                        None => TileImage::Embedded {
                            bytes: im.bytes.clone(),
                            mime: im.mime_type.clone(),
                        },
                    };
                    let k = self.push_image(b, image);
                    self.image_map.insert(t.image.0, k);
                    k
                }
            };
            let sampler = self
                .samplers
                .iter()
                .position(|s| *s == t.sampler)
                .unwrap_or_else(|| {
                    self.samplers.push(t.sampler);
                    self.samplers.len() - 1
                });
            tex = Some(
                self.textures
                    .iter()
                    .position(|&x| x == (img, sampler))
                    .unwrap_or_else(|| {
                        self.textures.push((img, sampler));
                        self.textures.len() - 1
                    }),
            );
        }
        self.materials.push(material_json(mat, tex));
        self.material_map.insert(mid.0, self.materials.len() - 1);
        Ok(self.materials.len() - 1)
    }

    /// The glTF index of `image`, written unless the same shared file or the same embedded
    /// bytes (one `Arc`: an atlas) already are.
    fn push_image(&mut self, b: &mut GltfBuilder, image: TileImage) -> usize {
        let n = self.images.len();
        match image {
            TileImage::Embedded { bytes, mime } => {
                if let Some(&(_, k)) = self
                    .embedded
                    .iter()
                    .find(|(a, _)| std::sync::Arc::ptr_eq(a, &bytes))
                {
                    return k;
                }
                self.images
                    .push(json!({"bufferView": b.view(&bytes, None), "mimeType": mime}));
                self.embedded.push((bytes, n));
            }
            TileImage::External { uri, mime } => {
                if let Some(&k) = self.uri_map.get(&uri) {
                    return k;
                }
                self.images.push(json!({"uri": uri, "mimeType": mime}));
                self.uri_map.insert(uri, n);
            }
        }
        n
    }

    fn write_into(self, root: &mut Value) {
        if !self.materials.is_empty() {
            root["materials"] = json!(self.materials);
        }
        if !self.images.is_empty() {
            root["images"] = json!(self.images);
            root["textures"] = json!(self
                .textures
                .iter()
                .map(|&(source, sampler)| json!({"source": source, "sampler": sampler}))
                .collect::<Vec<_>>());
            root["samplers"] = json!(self.samplers.iter().map(sampler_json).collect::<Vec<_>>());
        }
    }
}

/// Writes one primitive (plain or Draco) with its material; with `feature_count`, per-vertex
/// feature IDs (`EXT_mesh_features`). Returns the primitive and, when compressed, the decoded
/// positions (glTF y-up, primitive frame): where the client draws the vertices.
#[allow(clippy::too_many_arguments)]
fn write_primitive(
    scene: &Scene,
    b: &mut GltfBuilder,
    mats: &mut MaterialTable,
    m: &ContentPrimitive,
    feature_count: Option<usize>,
    property_table: bool,
    enc: &TileEncoding,
    frame: Option<&QuantFrame>,
) -> std::result::Result<(Value, Option<Vec<DVec3>>), String> {
    let (mut prim, decoded) = match enc.compression {
        Compression::None => (plain_primitive(b, m, feature_count.is_some(), None), None),
        Compression::Quantized => {
            let p = plain_primitive(b, m, feature_count.is_some(), Some(frame));
            (p, frame.map(|f| f.decoded_positions(&m.positions)))
        }
        Compression::Draco => {
            let texels = texture_texels(scene, m.material, &mats.sampled_px);
            let (p, bx) = draco_primitive(b, m, feature_count, enc, texels)?;
            (p, Some(bx))
        }
    };
    prim["mode"] = json!(4);
    if let Some(n) = feature_count {
        let mut feature_ids = json!({"featureCount": n, "attribute": 0});
        if property_table {
            feature_ids["propertyTable"] = json!(0);
        }
        prim["extensions"]["EXT_mesh_features"] = json!({"featureIds": [feature_ids]});
    }
    if let Some(mid) = m.material {
        prim["material"] = json!(mats.index(scene, b, mid)?);
    }
    Ok((prim, decoded))
}

/// A point of glTF (y-up) back in the scene frame (z-up).
fn z_up(v: DVec3) -> DVec3 {
    DVec3::new(v.x, -v.z, v.y)
}

/// Writes the GLB. With Draco, `bounds` grows to hold the *decoded* (quantized) positions too, so
/// the tile's bounding volume contains what clients draw.
fn write_glb(
    scene: &Scene,
    content: &TileContent,
    enc: &TileEncoding,
    table: Option<&PropertyTable>,
    bounds: &mut Aabb,
    mut mats: MaterialTable,
) -> std::result::Result<(Vec<u8>, usize), String> {
    let mut b = GltfBuilder {
        bin: Vec::new(),
        buffer_views: Vec::new(),
        accessors: Vec::new(),
    };
    let (center, feature_count) = (content.center, content.features.len());
    let mut meshes: Vec<Value> = Vec::new();
    let mut root_node = json!({"translation": [center.x, center.z, -center.y]});
    let mut nodes: Vec<Value> = Vec::new();
    let mut used: Vec<&str> = Vec::new();
    let mut required: Vec<&str> = Vec::new();

    // The merged geometry: one mesh on the root node, a feature ID per vertex.
    // With quantization, a frame per mesh (None: the mesh keeps float positions).
    let frame_of = |prims: &[ContentPrimitive]| match enc.compression {
        Compression::Quantized => QuantFrame::of(prims, enc.max_position_error_m),
        _ => None,
    };
    if !content.primitives.is_empty() {
        let frame = frame_of(&content.primitives);
        let mut primitives = Vec::new();
        for m in &content.primitives {
            let (prim, decoded) = write_primitive(
                scene,
                &mut b,
                &mut mats,
                m,
                Some(feature_count),
                table.is_some(),
                enc,
                frame.as_ref(),
            )?;
            for p in decoded.iter().flatten() {
                bounds.extend(center + z_up(*p));
            }
            primitives.push(prim);
        }
        meshes.push(json!({"primitives": primitives}));
        match frame {
            // Dequantized by a child node of the root.
            Some(f) => nodes.push(json!({
                "mesh": 0,
                "translation": f.center,
                "scale": vec![f.scale; 3],
            })),
            None => root_node["mesh"] = json!(0),
        }
        used.push("EXT_mesh_features");
    }

    // Each instanced shape: a mesh written once, on a child node placing it per instance
    // (EXT_mesh_gpu_instancing) with a feature ID per instance (EXT_instance_features).
    for shape in &content.instanced {
        let frame = frame_of(&shape.primitives);
        let mut primitives = Vec::new();
        // Decoded vertices of the shape (scene frame, z-up): every instance's copy of them
        // goes into the tile's box, so a rotated copy is bounded exactly, not by a turned box.
        let mut decoded_points: Vec<DVec3> = Vec::new();
        for m in &shape.primitives {
            let (prim, decoded) = write_primitive(
                scene,
                &mut b,
                &mut mats,
                m,
                None,
                false,
                enc,
                frame.as_ref(),
            )?;
            decoded_points.extend(decoded.iter().flatten().map(|p| z_up(*p)));
            primitives.push(prim);
        }
        meshes.push(json!({"primitives": primitives}));
        let mut translations = Vec::with_capacity(shape.instances.len());
        let mut rotations = Vec::with_capacity(shape.instances.len());
        let mut scales = Vec::with_capacity(shape.instances.len());
        let mut fids = Vec::with_capacity(shape.instances.len());
        for inst in &shape.instances {
            // The instance transform in glTF's y-up frame.
            let mut y_up_transform = Z_UP_TO_Y_UP * inst.transform * Y_UP_TO_Z_UP;
            // Quantized positions: the dequantization (uniform scale, then translation) goes
            // first; it stays a TRS since the scale is uniform.
            if let Some(f) = &frame {
                y_up_transform *= f.matrix();
            }
            let (t, r, s) = crate::geometry::instance_trs(&y_up_transform)
                .ok_or("an instance transform is not translation-rotation-scale")?;
            translations.push(t.as_vec3().to_array());
            rotations.push(r.normalize().as_quat().to_array());
            scales.push(s.as_vec3().to_array());
            fids.push([inst.feature as f32]);
            for p in &decoded_points {
                bounds.extend(center + inst.transform.transform_point3(*p));
            }
        }
        let mut attributes = Map::new();
        attributes.insert(
            "TRANSLATION".into(),
            json!(b.float_accessor_in(&translations, false, None)),
        );
        attributes.insert(
            "ROTATION".into(),
            json!(b.float_accessor_in(&rotations, false, None)),
        );
        // Rigid copies (the usual case) need no SCALE.
        if scales
            .iter()
            .any(|s| s.iter().any(|&x| (x - 1.0).abs() > 1e-6))
        {
            attributes.insert(
                "SCALE".into(),
                json!(b.float_accessor_in(&scales, false, None)),
            );
        }
        attributes.insert(
            "_FEATURE_ID_0".into(),
            json!(b.float_accessor_in(&fids, false, None)),
        );
        let mut feature_ids = json!({"featureCount": feature_count, "attribute": 0});
        if table.is_some() {
            feature_ids["propertyTable"] = json!(0);
        }
        nodes.push(json!({
            "mesh": meshes.len() - 1,
            "extensions": {
                "EXT_mesh_gpu_instancing": {"attributes": attributes},
                "EXT_instance_features": {"featureIds": [feature_ids]},
            }
        }));
    }
    if !nodes.is_empty() {
        root_node["children"] = json!((1..=nodes.len()).collect::<Vec<_>>());
    }
    if !content.instanced.is_empty() {
        used.extend(["EXT_mesh_gpu_instancing", "EXT_instance_features"]);
        // No fallback exists for viewers without instancing (they use --no-instancing output).
        required.push("EXT_mesh_gpu_instancing");
    }
    nodes.insert(0, root_node);

    let (metadata_ext, metadata_bytes) = match table {
        Some(t) => {
            used.push("EXT_structural_metadata");
            let (ext, n) =
                write_property_table(t, &mut |bytes, align| b.view_aligned(bytes, None, align));
            (Some(ext), n)
        }
        None => (None, 0),
    };
    match enc.compression {
        Compression::Draco => {
            used.push("KHR_draco_mesh_compression");
            required.push("KHR_draco_mesh_compression");
        }
        Compression::Quantized if !meshes.is_empty() => {
            used.push("KHR_mesh_quantization");
            required.push("KHR_mesh_quantization");
        }
        _ => {}
    }
    let mut root = json!({
        "asset": {"version": "2.0", "generator": enc.generator},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "meshes": meshes,
        "accessors": b.accessors,
        "bufferViews": b.buffer_views,
        "buffers": [{"byteLength": b.bin.len()}],
        "extensionsUsed": used,
    });
    if !required.is_empty() {
        root["extensionsRequired"] = json!(required);
    }
    if let Some(ext) = metadata_ext {
        root["extensions"] = json!({"EXT_structural_metadata": ext});
    }
    mats.write_into(&mut root);
    let json_bytes = serde_json::to_vec(&root).map_err(|e| e.to_string())?;
    Ok((glb_container(&json_bytes, &b.bin), metadata_bytes))
}

/// The dequantization of a mesh's normalized i16 positions (glTF y-up, mesh frame): the node
/// transform `center + scale * (q / 32767)`, one uniform scale so normals need no change.
#[derive(Debug, Clone, Copy)]
struct QuantFrame {
    center: [f64; 3],
    scale: f64,
}

/// Largest normalized i16 value.
const I16_MAX: f64 = 32767.0;

impl QuantFrame {
    /// The frame of all positions of `prims` (scene frame), or `None` when the quantization step
    /// would move a vertex by more than `max_error_m` on an axis (the mesh stays float) or the
    /// mesh is empty.
    fn of(prims: &[ContentPrimitive], max_error_m: f64) -> Option<QuantFrame> {
        let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
        for p in prims.iter().flat_map(|m| y_up(&m.positions)) {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k] as f64);
                hi[k] = hi[k].max(p[k] as f64);
            }
        }
        if lo[0] > hi[0] {
            return None;
        }
        let center = [0, 1, 2].map(|k| (lo[k] + hi[k]) / 2.0);
        let half = (0..3).map(|k| (hi[k] - lo[k]) / 2.0).fold(0.0, f64::max);
        // Rounding to the nearest step moves a vertex by at most half a step.
        let scale = half.max(1e-9);
        (scale / I16_MAX / 2.0 <= max_error_m).then_some(QuantFrame { center, scale })
    }

    fn quantize(&self, p: [f32; 3]) -> [i32; 3] {
        [0, 1, 2].map(|k| {
            ((p[k] as f64 - self.center[k]) / self.scale * I16_MAX)
                .round()
                .clamp(-I16_MAX, I16_MAX) as i32
        })
    }

    fn dequantize(&self, q: [i32; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| self.center[k] + self.scale * q[k] as f64 / I16_MAX)
    }

    /// The dequantized positions (glTF y-up, mesh frame).
    fn decoded_positions(&self, positions: &[[f32; 3]]) -> Vec<DVec3> {
        y_up(positions)
            .into_iter()
            .map(|p| DVec3::from(self.dequantize(self.quantize(p))))
            .collect()
    }

    /// The node (or instance) transform that dequantizes (clients read a normalized i16 `q` as
    /// `q / 32767`).
    fn matrix(&self) -> DMat4 {
        DMat4::from_scale_rotation_translation(
            DVec3::splat(self.scale),
            glam::DQuat::IDENTITY,
            DVec3::from(self.center),
        )
    }
}

/// A unit vector as normalized i8 (`round(x * 127)`).
fn normal_i8(n: [f32; 3]) -> [i32; 3] {
    n.map(|x| (x.clamp(-1.0, 1.0) * 127.0).round() as i32)
}

/// UVs inside [0, 1] as normalized u16, or `None` when they tile beyond it.
fn uvs_u16(uvs: &[[f32; 2]]) -> Option<Vec<[i32; 2]>> {
    uvs.iter()
        .all(|t| t.iter().all(|x| (0.0..=1.0).contains(x)))
        .then(|| {
            uvs.iter()
                .map(|t| t.map(|x| (x as f64 * 65535.0).round() as i32))
                .collect()
        })
}

/// Attributes and indices as plain accessors; with `quantized` (`KHR_mesh_quantization`),
/// normals as i8, UVs in [0, 1] as u16, and positions as i16 in the mesh's frame if it has one.
fn plain_primitive(
    b: &mut GltfBuilder,
    m: &ContentPrimitive,
    with_features: bool,
    quantized: Option<Option<&QuantFrame>>,
) -> Value {
    let mut attributes = Map::new();
    let positions = match quantized.flatten() {
        Some(f) => {
            let q: Vec<[i32; 3]> = y_up(&m.positions)
                .into_iter()
                .map(|p| f.quantize(p))
                .collect();
            b.normalized_accessor(&q, SHORT, true)
        }
        None => b.float_accessor(&y_up(&m.positions), true),
    };
    attributes.insert("POSITION".into(), json!(positions));
    if !m.normals.is_empty() {
        let n = y_up(&m.normals);
        let normals = match quantized {
            Some(_) => {
                let q: Vec<[i32; 3]> = n.into_iter().map(normal_i8).collect();
                b.normalized_accessor(&q, BYTE, false)
            }
            None => b.float_accessor(&n, false),
        };
        attributes.insert("NORMAL".into(), json!(normals));
    }
    if !m.uvs.is_empty() {
        let uvs = match quantized.and_then(|_| uvs_u16(&m.uvs)) {
            Some(q) => b.normalized_accessor(&q, UNSIGNED_SHORT, false),
            None => b.float_accessor(&m.uvs, false),
        };
        attributes.insert("TEXCOORD_0".into(), json!(uvs));
    }
    if !m.colors.is_empty() {
        attributes.insert("COLOR_0".into(), json!(b.float_accessor(&m.colors, false)));
    }
    if with_features {
        let fids: Vec<[f32; 1]> = m.feature_ids.iter().map(|&f| [f as f32]).collect();
        attributes.insert(
            "_FEATURE_ID_0".into(),
            json!(b.float_accessor(&fids, false)),
        );
    }
    let indices = b.index_accessor(&m.indices, m.positions.len());
    json!({"attributes": attributes, "indices": indices})
}

/// One Draco stream in a bufferView, and accessors (without bufferViews) that describe the
/// decoded data, as KHR_draco_mesh_compression requires; with `feature_count`, the per-vertex
/// feature IDs go in too. Also returns the decoded positions.
fn draco_primitive(
    b: &mut GltfBuilder,
    m: &ContentPrimitive,
    feature_count: Option<usize>,
    enc: &TileEncoding,
    uv_texels: u32,
) -> std::result::Result<(Value, Vec<DVec3>), String> {
    use super::draco::{
        encode_mesh, position_bits_for, quantization_step, EncodeAttribute, EncodeOptions,
    };
    let positions_y_up = y_up(&m.positions);
    let mut normals_y_up = y_up(&m.normals);
    let positions = positions_y_up.as_flattened();
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in &positions_y_up {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let extent = (0..3).map(|k| (hi[k] - lo[k]) as f64).fold(0.0, f64::max);
    let position_bits = position_bits_for(extent, enc.max_position_error_m);
    if enc.normals_from_drawn_faces && !normals_y_up.is_empty() {
        // Draco's grid: one step for all axes from the box's low corner, values rounded.
        let step = quantization_step(extent, position_bits);
        let drawn: Vec<[f32; 3]> = if step > 0.0 {
            positions_y_up
                .iter()
                .map(|p| {
                    std::array::from_fn(|k| {
                        let q = ((p[k] - lo[k]) as f64 / step).round();
                        (lo[k] as f64 + q * step) as f32
                    })
                })
                .collect()
        } else {
            positions_y_up.clone()
        };
        crate::geometry::normals_from_faces(&drawn, &m.indices, &mut normals_y_up);
    }
    let mut attrs = vec![EncodeAttribute::position(positions, position_bits)];
    let mut names = vec![("POSITION", FLOAT, "VEC3")];
    if !m.normals.is_empty() {
        attrs.push(EncodeAttribute::normal(
            normals_y_up.as_flattened(),
            NORMAL_BITS,
        ));
        names.push(("NORMAL", FLOAT, "VEC3"));
    }
    if !m.uvs.is_empty() {
        attrs.push(EncodeAttribute::tex_coord(
            m.uvs.as_flattened(),
            uv_bits(&m.uvs, uv_texels),
        ));
        names.push(("TEXCOORD_0", FLOAT, "VEC2"));
    }
    if !m.colors.is_empty() {
        attrs.push(EncodeAttribute::color_f32(
            m.colors.as_flattened(),
            COLOR_BITS,
        ));
        names.push(("COLOR_0", FLOAT, "VEC4"));
    }
    // Feature IDs are exact integers: u16 while they fit (lossless in Draco), f32 beyond.
    let fid_u16: Vec<u16>;
    let fid_f32: Vec<f32>;
    match feature_count {
        None => {}
        Some(n) if n <= u16::MAX as usize => {
            fid_u16 = m.feature_ids.iter().map(|&f| f as u16).collect();
            attrs.push(EncodeAttribute::feature_id_u16(&fid_u16));
            names.push(("_FEATURE_ID_0", UNSIGNED_SHORT, "SCALAR"));
        }
        Some(_) => {
            fid_f32 = m.feature_ids.iter().map(|&f| f as f32).collect();
            attrs.push(EncodeAttribute::feature_id_f32(&fid_f32));
            names.push(("_FEATURE_ID_0", FLOAT, "SCALAR"));
        }
    }
    let encoded =
        encode_mesh(&attrs, &m.indices, &EncodeOptions::default()).map_err(|e| e.to_string())?;
    let view = b.view(&encoded.bytes, None);
    let mut attributes = Map::new();
    let mut draco_ids = Map::new();
    for (k, &(name, ct, ty)) in names.iter().enumerate() {
        let mut a = json!({"componentType": ct, "count": encoded.point_count, "type": ty});
        if name == "POSITION" {
            let (min, max) = &encoded.attribute_min_max[k];
            a["min"] = json!(min);
            a["max"] = json!(max);
        }
        b.accessors.push(a);
        attributes.insert(name.into(), json!(b.accessors.len() - 1));
        draco_ids.insert(name.into(), json!(encoded.attribute_ids[k]));
    }
    let index_type = if encoded.indices_fit_u16() {
        UNSIGNED_SHORT
    } else {
        UNSIGNED_INT
    };
    b.accessors.push(
        json!({"componentType": index_type, "count": encoded.face_count * 3, "type": "SCALAR"}),
    );
    let indices = b.accessors.len() - 1;
    Ok((
        json!({
            "attributes": attributes,
            "indices": indices,
            "extensions": {"KHR_draco_mesh_compression": {"bufferView": view, "attributes": draco_ids}}
        }),
        encoded
            .decoded_positions
            .iter()
            .map(|p| DVec3::from(p.map(f64::from)))
            .collect(),
    ))
}

fn material_json(m: &Material, texture: Option<usize>) -> Value {
    let mut pbr = json!({
        "baseColorFactor": m.base_color,
        "metallicFactor": m.metallic,
        "roughnessFactor": m.roughness,
    });
    if let Some(t) = texture {
        pbr["baseColorTexture"] = json!({"index": t});
    }
    let mut v = json!({"pbrMetallicRoughness": pbr});
    if let Some(n) = &m.name {
        v["name"] = json!(n);
    }
    if m.emissive != [0.0; 3] {
        v["emissiveFactor"] = json!(m.emissive);
    }
    match m.alpha_mode {
        AlphaMode::Opaque => {}
        AlphaMode::Mask => {
            v["alphaMode"] = json!("MASK");
            v["alphaCutoff"] = json!(m.alpha_cutoff);
        }
        AlphaMode::Blend => v["alphaMode"] = json!("BLEND"),
    }
    if m.double_sided {
        v["doubleSided"] = json!(true);
    }
    v
}

fn sampler_json(s: &Sampler) -> Value {
    let mut v = json!({});
    if s.mag_filter != 0 {
        v["magFilter"] = json!(s.mag_filter);
    }
    if s.min_filter != 0 {
        v["minFilter"] = json!(s.min_filter);
    }
    if s.wrap_s != 0 {
        v["wrapS"] = json!(s.wrap_s);
    }
    if s.wrap_t != 0 {
        v["wrapT"] = json!(s.wrap_t);
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat4;

    fn whole(c: u32) -> Vec<ContentItem> {
        vec![ContentItem {
            component: ComponentId(c),
            triangles: None,
        }]
    }

    fn plain() -> TileEncoding {
        TileEncoding {
            compression: Compression::None,
            ..Default::default()
        }
    }

    fn one_triangle_scene(world: DMat4) -> Scene {
        let mut s = Scene::default();
        s.materials.push(Material::default());
        s.meshes.push(Mesh {
            name: None,
            primitives: vec![Primitive {
                material: Some(MaterialId(0)),
                positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]],
                indices: vec![0, 1, 2],
                ..Default::default()
            }],
            local_bounds: None,
        });
        s.push_component(Component::new(MeshId(0), world), &ElementInfo::keyed("a"));
        s.finish();
        s
    }

    #[test]
    fn writes_a_readable_glb_relative_to_center() {
        // A glTF (y-up) triangle placed through the y-up → z-up transform, far from the origin.
        let far = DVec3::new(500_000.25, 5_400_000.5, 100.0);
        let s = one_triangle_scene(DMat4::from_translation(far) * Y_UP_TO_Z_UP);
        let center = s.components[0].world_bounds.center();
        let t = encode_tile(&s, &whole(0), center, &plain(), None).unwrap();
        assert_eq!(t.triangles, 1);
        let g = gltf::Gltf::from_slice_without_validation(&t.glb).unwrap();
        let node = g.document.nodes().next().unwrap();
        let tr = node.transform().decomposed().0;
        // The node translation carries the centre (in y-up); vertices are small.
        assert!((tr[0] as f64 - center.x).abs() < 1.0);
        assert!((tr[2] as f64 + center.y).abs() < 1.0);
        let blob = g.blob.as_deref().unwrap();
        let prim = node.mesh().unwrap().primitives().next().unwrap();
        let reader = prim.reader(|_| Some(blob));
        let pos: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
        assert!(pos.iter().all(|p| p.iter().all(|c| c.abs() <= 1.0)));
        // glTF local (1,0,0) → scene (far + (1,0,0)): x stays x.
        let max_x = pos.iter().map(|p| p[0]).fold(f32::MIN, f32::max) as f64 + center.x;
        assert!((max_x - (far.x + 1.0)).abs() < 1e-6);
        // glTF (0,0,-1) is north (+y) in the scene frame.
        assert!((t.bounds.max.y - (far.y + 1.0)).abs() < 1e-9);
        assert!(g
            .document
            .extensions_used()
            .any(|e| e == "EXT_mesh_features"));
    }

    #[test]
    fn mirrored_transforms_keep_front_faces() {
        let s = one_triangle_scene(DMat4::from_scale(DVec3::new(-1.0, 1.0, 1.0)));
        let t = encode_tile(&s, &whole(0), DVec3::ZERO, &plain(), None).unwrap();
        let g = gltf::Gltf::from_slice_without_validation(&t.glb).unwrap();
        let blob = g.blob.as_deref().unwrap();
        let prim = g
            .document
            .meshes()
            .next()
            .unwrap()
            .primitives()
            .next()
            .unwrap();
        let r = prim.reader(|_| Some(blob));
        let idx: Vec<u32> = r.read_indices().unwrap().into_u32().collect();
        assert_eq!(idx, vec![0, 2, 1]);
    }
}
