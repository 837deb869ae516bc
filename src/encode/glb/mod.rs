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
use super::{ContentFigures, EncodeError};
use crate::glb_container::glb_container;
use crate::partition::content::{ContentPrimitive, InstancedShape, TileContent};
use crate::partition::ContentItem;
use crate::scene::*;
use crate::texture::{ImageSource, TileImage};
use byteorder::{WriteBytesExt, LE};
use glam::{DMat4, DVec3};
use serde_json::{json, Map, Value};
use std::collections::BTreeMap;

mod builder;
mod materials;
mod primitives;
mod quantization;
mod retable;

use builder::*;
use materials::*;
use primitives::*;
use quantization::*;
pub use retable::replace_property_table;

/// An encoded tile: the GLB and what it holds.
#[derive(Debug, Clone)]
pub struct EncodedTile {
    pub glb: Vec<u8>,
    /// The component of each feature ID (`_FEATURE_ID_0` value = index here).
    pub features: Vec<ComponentId>,
    pub figures: ContentFigures,
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
    /// `KHR_draco_mesh_compression` on every primitive (every attribute inside Draco): the
    /// smallest files, but CesiumJS decodes one primitive per frame per spare core.
    Draco,
    /// `Quantized`'s attributes as `EXT_meshopt_compression` streams, vertices reordered for
    /// its codecs: decoded on the client's main thread, without Draco's worker task per
    /// primitive. The default, by measurement (book: guide/compression.md).
    #[default]
    Meshopt,
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
    /// those faces, so they cost fewer bytes too (docs/benchmarks.md).
    pub normals_from_drawn_faces: bool,
    /// Which edges every primitive carries (`EXT_mesh_primitive_edge_visibility`).
    pub edges: crate::encode::edges::EdgeOptions,
    pub generator: String,
}

impl Default for TileEncoding {
    fn default() -> Self {
        TileEncoding {
            compression: Compression::default(),
            max_position_error_m: DEFAULT_MAX_POSITION_ERROR_M,
            normals_from_drawn_faces: false,
            edges: Default::default(),
            generator: concat!("bimtiles ", env!("CARGO_PKG_VERSION")).into(),
        }
    }
}

/// Quantization error allowed on full-detail content: at most 1 mm per axis, below what a viewer
/// can show of a building and what BIM exports are accurate to.
pub const DEFAULT_MAX_POSITION_ERROR_M: f64 = 0.001;
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
) -> std::result::Result<EncodedTile, EncodeError> {
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
) -> std::result::Result<EncodedTile, EncodeError> {
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
) -> std::result::Result<EncodedTile, EncodeError> {
    encode_content_from(scene, content, enc, metadata, Some(images), sampled_px)
}

fn encode_content_from(
    scene: &Scene,
    content: &TileContent,
    enc: &TileEncoding,
    metadata: Option<TableMaker>,
    images: Option<ImageSource>,
    sampled_px: &BTreeMap<ImageId, u32>,
) -> std::result::Result<EncodedTile, EncodeError> {
    let mut bounds = content.bounds();
    let table = metadata.map(|make| make(&content.features));
    let mats = MaterialTable {
        image_source: images,
        sampled_px: sampled_px.clone(),
        ..MaterialTable::default()
    };
    let (glb, metadata_bytes, edge_data) =
        write_glb(scene, content, enc, table.as_ref(), &mut bounds, mats)?;
    let figures = ContentFigures {
        bytes: glb.len() as u64,
        features: content.features.len(),
        triangles: content.triangle_count(),
        vertices: content.vertex_count(),
        stored_triangles: content.stored_triangle_count(),
        instanced_shapes: content.instanced.len(),
        instances: content.instance_count(),
        metadata_bytes: metadata_bytes as u64,
        edge_bytes: edge_data.len() as u64,
        edge_gzip_bytes: crate::encode::edges::gzip_bytes(&edge_data),
        bounds,
    };
    Ok(EncodedTile {
        glb,
        features: content.features.clone(),
        figures,
    })
}

/// Where Draco draws `positions_y_up` (one primitive's, glTF frame) when they are written with at
/// most `max_position_error_m` per axis: one step for all axes from the box's low corner (the
/// largest extent over `2^bits - 1`), values rounded, as Draco's quantization transform does.
pub(crate) fn draco_grid_positions(
    positions_y_up: &[[f32; 3]],
    max_position_error_m: f64,
) -> Vec<[f32; 3]> {
    use crate::encode::draco::{position_bits_for, quantization_step};
    let (lo, extent) = draco_box(positions_y_up);
    let step = quantization_step(extent, position_bits_for(extent, max_position_error_m));
    if step <= 0.0 {
        return positions_y_up.to_vec();
    }
    positions_y_up
        .iter()
        .map(|p| {
            std::array::from_fn(|k| {
                let q = ((p[k] - lo[k]) as f64 / step).round();
                (lo[k] as f64 + q * step) as f32
            })
        })
        .collect()
}

/// The low corner of the box of `positions` and its largest extent (Draco's quantization range).
fn draco_box(positions: &[[f32; 3]]) -> ([f32; 3], f64) {
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let extent = (0..3).map(|k| (hi[k] - lo[k]) as f64).fold(0.0, f64::max);
    (lo, extent)
}

/// Per triangle of each of `prims` (one mesh, scene frame as content holds it), whether the grid
/// that `compression` writes positions on within `max_position_error_m` flattens it: drawn with
/// no area, it shows nothing of what it stood for. Draco quantizes each primitive in its own box
/// ([`draco_grid_positions`]); quantized and meshopt tiles put the whole mesh on one frame
/// ([`QuantFrame`], judged on its integers, so exactly), or meshopt's exponent filter when the
/// mesh is too wide for the frame.
pub fn grid_flattens(
    compression: Compression,
    prims: &[ContentPrimitive],
    max_position_error_m: f64,
) -> Vec<Vec<bool>> {
    let flat_where = |p: &ContentPrimitive, flat: &dyn Fn([u32; 3]) -> bool| -> Vec<bool> {
        p.indices
            .chunks_exact(3)
            .map(|t| flat([t[0], t[1], t[2]]))
            .collect()
    };
    let flat_f32 = |p: &ContentPrimitive, drawn: &[[f32; 3]]| {
        let at = |i: u32| DVec3::from(drawn[i as usize].map(f64::from));
        flat_where(p, &|[a, b, c]| {
            let [a, b, c] = [at(a), at(b), at(c)];
            (b - a).cross(c - a).length_squared() == 0.0
        })
    };
    let frame = match compression {
        Compression::Quantized | Compression::Meshopt => {
            QuantFrame::of(prims, max_position_error_m)
        }
        Compression::Draco | Compression::None => None,
    };
    prims
        .iter()
        .map(|p| {
            let positions_y_up = y_up(&p.positions);
            match (compression, &frame) {
                (Compression::Draco, _) => flat_f32(
                    p,
                    &draco_grid_positions(&positions_y_up, max_position_error_m),
                ),
                (_, Some(f)) => {
                    let q: Vec<[i64; 3]> = positions_y_up
                        .iter()
                        .map(|&v| f.quantize(v).map(i64::from))
                        .collect();
                    flat_where(p, &|[a, b, c]| {
                        let [a, b, c] = [q[a as usize], q[b as usize], q[c as usize]];
                        let (u, v) = (
                            [0, 1, 2].map(|k| b[k] - a[k]),
                            [0, 1, 2].map(|k| c[k] - a[k]),
                        );
                        u[1] * v[2] == u[2] * v[1]
                            && u[2] * v[0] == u[0] * v[2]
                            && u[0] * v[1] == u[1] * v[0]
                    })
                }
                (Compression::Meshopt, None) => {
                    match crate::encode::meshopt::exp_filtered(
                        &positions_y_up,
                        max_position_error_m,
                    ) {
                        Some(exp) => flat_f32(p, &exp.drawn),
                        None => flat_f32(p, &positions_y_up),
                    }
                }
                _ => flat_f32(p, &positions_y_up),
            }
        })
        .collect()
}

/// Scene z-up → glTF y-up: (x, y, z) ↦ (x, z, -y), as `Z_UP_TO_Y_UP`.
fn y_up(v: &[[f32; 3]]) -> Vec<[f32; 3]> {
    v.iter().map(|p| [p[0], p[2], -p[1]]).collect()
}

/// A point of glTF (y-up) back in the scene frame (z-up).
fn z_up(v: DVec3) -> DVec3 {
    DVec3::new(v.x, -v.z, v.y)
}

/// Writes the GLB. With Draco, `bounds` grows to hold the *decoded* (quantized) positions too, so
/// the tile's bounding volume contains what clients draw. Returns it with the property table's
/// bytes and the edge visibility data.
fn write_glb(
    scene: &Scene,
    content: &TileContent,
    enc: &TileEncoding,
    table: Option<&PropertyTable>,
    bounds: &mut Aabb,
    mats: MaterialTable,
) -> std::result::Result<(Vec<u8>, usize, Vec<u8>), EncodeError> {
    let mut w = GlbWriter {
        scene,
        enc,
        b: GltfBuilder {
            meshopt: enc.compression == Compression::Meshopt,
            edges: enc.edges.mode != crate::encode::edges::EdgeMode::None,
            ..GltfBuilder::default()
        },
        mats,
        meshes: Vec::new(),
        nodes: Vec::new(),
    };
    let (center, feature_count) = (content.center, content.features.len());
    let mut root_node = json!({"translation": [center.x, center.z, -center.y]});
    let mut used: Vec<&str> = Vec::new();
    let mut required: Vec<&str> = Vec::new();

    // The merged geometry: one mesh on the root node, a feature ID per vertex.
    if !content.primitives.is_empty() {
        let frame = w.frame_of(&content.primitives);
        let drawn_by = DrawnBy {
            features: &content.features,
            center,
        };
        w.write_mesh(
            &content.primitives,
            Some(&drawn_by),
            Some(feature_count),
            table.is_some(),
            frame.as_ref(),
            |p| bounds.extend(center + z_up(p)),
        )?;
        match frame {
            // Dequantized by a child node of the root.
            Some(f) => w.nodes.push(json!({
                "mesh": 0,
                "translation": f.center,
                "scale": vec![f.scale; 3],
            })),
            None => root_node["mesh"] = json!(0),
        }
        used.push("EXT_mesh_features");
    }
    for shape in &content.instanced {
        w.write_instanced_shape(shape, center, table.is_some(), bounds)?;
    }
    if !w.nodes.is_empty() {
        root_node["children"] = json!((1..=w.nodes.len()).collect::<Vec<_>>());
    }
    if !content.instanced.is_empty() {
        used.extend(["EXT_mesh_gpu_instancing", "EXT_instance_features"]);
        // No fallback exists for viewers without instancing (they use --no-instancing output).
        required.push("EXT_mesh_gpu_instancing");
    }
    w.nodes.insert(0, root_node);
    w.finish(table, used, required)
}

/// The components a tile's merged geometry draws (by feature ID) and the origin of its positions:
/// where the edge finder looks for the rest of an element cut between tiles.
pub(super) struct DrawnBy<'a> {
    features: &'a [crate::scene::ComponentId],
    center: DVec3,
}

impl DrawnBy<'_> {
    /// The whole surface of the component of feature `feature`, in the frame the tile draws it
    /// in (glTF y-up, from the tile's origin).
    pub(super) fn whole_surface(
        &self,
        scene: &Scene,
        feature: u32,
    ) -> Option<crate::encode::edges::WholeSurface> {
        let component = scene.component(*self.features.get(feature as usize)?);
        let mesh = scene.mesh(component.mesh);
        let mut out = crate::encode::edges::WholeSurface::default();
        for p in &mesh.primitives {
            let material = p.material.map_or(u32::MAX, |m| m.0);
            (out.face_materials).extend(std::iter::repeat_n(material, p.indices.len() / 3));
            let base = out.positions.len() as u32;
            out.positions.extend(p.positions.iter().map(|v| {
                let at = DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
                let w = component.world.transform_point3(at) - self.center;
                [w.x as f32, w.z as f32, -w.y as f32]
            }));
            out.indices.extend(p.indices.iter().map(|&i| base + i));
        }
        (!out.indices.is_empty()).then_some(out)
    }
}

/// A tile's glTF while it is written: the binary buffer with its views and accessors, the
/// materials, the meshes and the nodes.
struct GlbWriter<'a> {
    scene: &'a Scene,
    enc: &'a TileEncoding,
    b: GltfBuilder,
    mats: MaterialTable<'a>,
    meshes: Vec<Value>,
    /// The root's children while they are written; the root is inserted first at the end.
    nodes: Vec<Value>,
}

impl GlbWriter<'_> {
    /// With quantization, a frame per mesh (None: the mesh keeps float positions).
    fn frame_of(&self, prims: &[ContentPrimitive]) -> Option<QuantFrame> {
        match self.enc.compression {
            Compression::Quantized | Compression::Meshopt => {
                QuantFrame::of(prims, self.enc.max_position_error_m)
            }
            _ => None,
        }
    }

    /// Writes `prims` as one mesh; `decoded_point` gets every decoded (quantized) vertex, y-up,
    /// in order.
    fn write_mesh(
        &mut self,
        prims: &[ContentPrimitive],
        drawn_by: Option<&DrawnBy>,
        feature_count: Option<usize>,
        property_table: bool,
        frame: Option<&QuantFrame>,
        mut decoded_point: impl FnMut(DVec3),
    ) -> std::result::Result<(), EncodeError> {
        let mut primitives = Vec::new();
        for m in prims {
            let (prim, decoded) = write_primitive(
                self.scene,
                &mut self.b,
                &mut self.mats,
                m,
                drawn_by,
                feature_count,
                property_table,
                self.enc,
                frame,
            )?;
            for p in decoded.iter().flatten() {
                decoded_point(*p);
            }
            primitives.push(prim);
        }
        self.meshes.push(json!({"primitives": primitives}));
        Ok(())
    }

    /// An instanced shape: a mesh written once, on a child node placing it per instance
    /// (EXT_mesh_gpu_instancing) with a feature ID per instance (EXT_instance_features).
    fn write_instanced_shape(
        &mut self,
        shape: &InstancedShape,
        center: DVec3,
        property_table: bool,
        bounds: &mut Aabb,
    ) -> std::result::Result<(), EncodeError> {
        let frame = self.frame_of(&shape.primitives);
        // Decoded vertices of the shape (scene frame, z-up): every instance's copy of them
        // goes into the tile's box, so a rotated copy is bounded exactly, not by a turned box.
        let mut decoded_points: Vec<DVec3> = Vec::new();
        self.write_mesh(&shape.primitives, None, None, false, frame.as_ref(), |p| {
            decoded_points.push(z_up(p))
        })?;
        let attributes =
            self.instance_attributes(shape, frame.as_ref(), &decoded_points, center, bounds)?;
        let distinct = distinct_feature_count(shape.instances.iter().map(|i| i.feature));
        let mut feature_ids = json!({"featureCount": distinct, "attribute": 0});
        if property_table {
            feature_ids["propertyTable"] = json!(0);
        }
        self.nodes.push(json!({
            "mesh": self.meshes.len() - 1,
            "extensions": {
                "EXT_mesh_gpu_instancing": {"attributes": attributes},
                "EXT_instance_features": {"featureIds": [feature_ids]},
            }
        }));
        Ok(())
    }

    /// The per-instance attributes of a shape (TRS and feature ID accessors); `bounds` grows to
    /// hold every instance's copy of the shape's decoded vertices.
    fn instance_attributes(
        &mut self,
        shape: &InstancedShape,
        frame: Option<&QuantFrame>,
        decoded_points: &[DVec3],
        center: DVec3,
        bounds: &mut Aabb,
    ) -> std::result::Result<Map<String, Value>, EncodeError> {
        let mut translations = Vec::with_capacity(shape.instances.len());
        let mut rotations = Vec::with_capacity(shape.instances.len());
        let mut scales = Vec::with_capacity(shape.instances.len());
        let mut fids = Vec::with_capacity(shape.instances.len());
        for inst in &shape.instances {
            // The instance transform in glTF's y-up frame.
            let mut y_up_transform = Z_UP_TO_Y_UP * inst.transform * Y_UP_TO_Z_UP;
            // Quantized positions: the dequantization (uniform scale, then translation) goes
            // first; it stays a TRS since the scale is uniform.
            if let Some(f) = frame {
                y_up_transform *= f.matrix();
            }
            let (t, r, s) = crate::geometry::instance_trs(&y_up_transform)
                .ok_or(EncodeError::InstanceTransform)?;
            translations.push(t.as_vec3().to_array());
            rotations.push(r.normalize().as_quat().to_array());
            scales.push(s.as_vec3().to_array());
            fids.push([inst.feature as f32]);
            for p in decoded_points {
                bounds.extend(center + inst.transform.transform_point3(*p));
            }
        }
        let b = &mut self.b;
        let mut attributes = Map::new();
        attributes.insert(
            "TRANSLATION".into(),
            json!(b.float_accessor_in(&translations, false, None)?),
        );
        attributes.insert(
            "ROTATION".into(),
            json!(b.float_accessor_in(&rotations, false, None)?),
        );
        // Rigid copies (the usual case) need no SCALE.
        if scales
            .iter()
            .any(|s| s.iter().any(|&x| (x - 1.0).abs() > 1e-6))
        {
            attributes.insert(
                "SCALE".into(),
                json!(b.float_accessor_in(&scales, false, None)?),
            );
        }
        attributes.insert(
            "_FEATURE_ID_0".into(),
            json!(b.float_accessor_in(&fids, false, None)?),
        );
        Ok(attributes)
    }

    /// The property table, the compression extensions and the glTF JSON, in the GLB container;
    /// returns it with the property table's bytes and the edge visibility data.
    fn finish(
        mut self,
        table: Option<&PropertyTable>,
        mut used: Vec<&str>,
        mut required: Vec<&str>,
    ) -> std::result::Result<(Vec<u8>, usize, Vec<u8>), EncodeError> {
        let b = &mut self.b;
        let (metadata_ext, metadata_bytes) = match table {
            Some(t) => {
                used.push("EXT_structural_metadata");
                let (ext, n) =
                    write_property_table(t, &mut |bytes, align| b.view_aligned(bytes, None, align));
                (Some(ext), n)
            }
            None => (None, 0),
        };
        match self.enc.compression {
            Compression::Draco => {
                used.push("KHR_draco_mesh_compression");
                required.push("KHR_draco_mesh_compression");
            }
            Compression::Quantized | Compression::Meshopt if !self.meshes.is_empty() => {
                used.push("KHR_mesh_quantization");
                required.push("KHR_mesh_quantization");
            }
            _ => {}
        }
        let b = self.b;
        if !b.edge_data.is_empty() {
            // Optional: a client without it draws the surfaces alone.
            used.push(crate::encode::edges::EXTENSION);
        }
        let mut buffers = vec![json!({"byteLength": b.bin.len()})];
        if b.fallback_bytes > 0 {
            // The decoded views' buffer: no data, so the extension is required (its README,
            // "Fallback buffers").
            buffers.push(json!({"byteLength": b.fallback_bytes,
                "extensions": {"EXT_meshopt_compression": {"fallback": true}}}));
            used.push("EXT_meshopt_compression");
            required.push("EXT_meshopt_compression");
        }
        let mut root = json!({
            "asset": {"version": "2.0", "generator": self.enc.generator},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": self.nodes,
            "meshes": self.meshes,
            "accessors": b.accessors,
            "bufferViews": b.buffer_views,
            "buffers": buffers,
            "extensionsUsed": used,
        });
        if !required.is_empty() {
            root["extensionsRequired"] = json!(required);
        }
        if let Some(ext) = metadata_ext {
            root["extensions"] = json!({"EXT_structural_metadata": ext});
        }
        self.mats.write_into(&mut root);
        let json_bytes = serde_json::to_vec(&root)?;
        Ok((
            glb_container(&json_bytes, &b.bin),
            metadata_bytes,
            b.edge_data,
        ))
    }
}

/// `featureCount` of an `EXT_mesh_features` / `EXT_instance_features` feature ID set: the number
/// of distinct features its IDs name (the spec's definition), not the property table's rows.
fn distinct_feature_count(ids: impl Iterator<Item = u32>) -> usize {
    let mut ids: Vec<u32> = ids.collect();
    ids.sort_unstable();
    ids.dedup();
    ids.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat4;

    #[test]
    fn each_grid_flattens_the_triangles_it_puts_on_a_line() {
        // 1 m extent, 1 mm: 9 bits, a step of 1/511 m (1.96 mm). An apex 0.4 mm above the base
        // rounds onto it; 1.5 mm above, onto the next grid line; 0.5 m above stays a triangle.
        let step = crate::encode::draco::quantization_step(1.0, 9);
        assert!(step / 2.0 <= 0.001 && step > 0.0015);
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.5, 0.0, 0.0004],
            [0.5, 0.0, 0.0015],
            [0.5, 0.0, 0.5],
        ];
        let indices = [0, 1, 2, 0, 1, 3, 0, 1, 4];
        let flattens = |c, e| grid_flattens(c, &[primitive(&positions, &indices)], e).remove(0);
        assert_eq!(
            flattens(Compression::Draco, 0.001),
            vec![true, false, false]
        );
        // A finer grid keeps the thin one.
        assert_eq!(
            flattens(Compression::Draco, 0.0001),
            vec![false, false, false]
        );
        // The meshopt frame's step is twice the bound whatever the extent (2 mm): the 0.4 mm apex
        // rounds onto the base, the 1.5 mm one a step above it; a 0.1 mm bound keeps both.
        for c in [Compression::Meshopt, Compression::Quantized] {
            assert_eq!(flattens(c, 0.001), vec![true, false, false]);
            assert_eq!(flattens(c, 0.0001), vec![false, false, false]);
        }
        assert_eq!(flattens(Compression::None, 0.001), vec![false; 3]);
    }

    fn primitive(positions: &[[f32; 3]], indices: &[u32]) -> ContentPrimitive {
        ContentPrimitive {
            positions: positions.to_vec(),
            feature_ids: vec![0; positions.len()],
            indices: indices.to_vec(),
            ..Default::default()
        }
    }

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
        assert_eq!(t.figures.triangles, 1);
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
        assert!((t.figures.bounds.max.y - (far.y + 1.0)).abs() < 1e-9);
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
