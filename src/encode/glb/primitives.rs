//! One tile primitive written plain (floats or `KHR_mesh_quantization`, optionally as
//! `EXT_meshopt_compression` streams) or as a Draco stream (`KHR_draco_mesh_compression`), with
//! its feature IDs (`EXT_mesh_features`).

use super::*;

/// Draco bits for normals (octahedral): 8 bits (Draco's default) keeps normals within about a
/// degree, below visible shading error.
pub(super) const NORMAL_BITS: u8 = 8;
/// Draco bits for colours: 8 bits per channel, as images have.
pub(super) const COLOR_BITS: u8 = 8;

/// Writes one primitive (plain or Draco) with its material; with `feature_count`, per-vertex
/// feature IDs (`EXT_mesh_features`). Returns the primitive and, when compressed, the decoded
/// positions (glTF y-up, primitive frame): where the client draws the vertices.
#[allow(clippy::too_many_arguments)]
pub(super) fn write_primitive(
    scene: &Scene,
    b: &mut GltfBuilder,
    mats: &mut MaterialTable,
    m: &ContentPrimitive,
    drawn_by: Option<&DrawnBy>,
    feature_count: Option<usize>,
    property_table: bool,
    enc: &TileEncoding,
    frame: Option<&QuantFrame>,
) -> std::result::Result<(Value, Option<Vec<DVec3>>), EncodeError> {
    let (mut prim, decoded, drawn) = match enc.compression {
        Compression::None => {
            let (p, indices) = plain_primitive(b, m, feature_count.is_some(), None)?;
            (p, None, Drawn::of(b.edges, m, None, indices))
        }
        Compression::Quantized => {
            let (p, indices) = plain_primitive(b, m, feature_count.is_some(), Some(frame))?;
            let decoded = frame.map(|f| f.decoded_positions(&m.positions));
            let drawn = Drawn::of(b.edges, m, decoded.as_deref(), indices);
            (p, decoded, drawn)
        }
        Compression::Meshopt => {
            let texels = texture_texels(scene, m.material, &mats.sampled_px);
            meshopt_primitive(b, m, feature_count.is_some(), enc, frame, texels)?
        }
        Compression::Draco => {
            let texels = texture_texels(scene, m.material, &mats.sampled_px);
            let (p, bx, drawn) = draco_primitive(b, m, feature_count, enc, texels)?;
            (p, Some(bx), drawn)
        }
    };
    // A drawn vertex lies within √3 per-axis position errors of its source; twice that is searched,
    // so a seam's ends are found however the grid rounded them (too short an edge is not judged).
    let grid_m = match enc.compression {
        Compression::None => 0.0,
        _ => 2.0 * enc.max_position_error_m * 3f64.sqrt(),
    };
    let whole = |feature: u32| drawn_by?.whole_surface(scene, feature);
    let seams = crate::encode::edges::Seams {
        whole_surface: &whole,
        tolerance_m: crate::encode::edges::weld_tolerance_m() + grid_m,
    };
    if let Some(edges) = crate::encode::edges::edge_visibility(
        &drawn.positions_y_up,
        &drawn.groups,
        &drawn.indices,
        &enc.edges,
        drawn_by.is_some().then_some(&seams),
    ) {
        let mut ext = b.edge_visibility(&edges);
        ext["material"] = json!(mats.edge_index());
        prim["extensions"][crate::encode::edges::EXTENSION] = ext;
    }
    prim["mode"] = json!(4);
    if feature_count.is_some() {
        // What the written attribute holds: every vertex, or only those a triangle uses (the
        // meshopt and Draco encodings drop the others).
        let distinct = match enc.compression {
            Compression::Meshopt | Compression::Draco => {
                super::distinct_feature_count(m.indices.iter().map(|&i| m.feature_ids[i as usize]))
            }
            Compression::None | Compression::Quantized => {
                super::distinct_feature_count(m.feature_ids.iter().copied())
            }
        };
        let mut feature_ids = json!({"featureCount": distinct, "attribute": 0});
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

/// What a client draws of a primitive, in the order it decodes it: the triangles (a codec may
/// reorder or rotate them), the vertices where they are drawn (y-up, quantization included: two
/// corners the grid puts on one point are one corner), and the element (feature ID) of each
/// vertex. Edge visibility is found on it and written against it.
#[derive(Default)]
struct Drawn {
    positions_y_up: Vec<[f32; 3]>,
    groups: Vec<u32>,
    indices: Vec<u32>,
}

impl Drawn {
    /// `m`'s vertices (drawn at `decoded` when quantized), with triangles `indices` as the
    /// client reads them; nothing when the primitives get no edges (`wanted` false).
    fn of(
        wanted: bool,
        m: &ContentPrimitive,
        decoded: Option<&[DVec3]>,
        indices: Vec<u32>,
    ) -> Drawn {
        if !wanted {
            return Drawn::default();
        }
        Drawn {
            positions_y_up: match decoded {
                Some(d) => d.iter().map(|p| p.as_vec3().to_array()).collect(),
                None => y_up(&m.positions),
            },
            groups: m.feature_ids.clone(),
            indices,
        }
    }
}

/// Attributes and indices as plain accessors; with `quantized` (`KHR_mesh_quantization`),
/// normals as i8, UVs in [0, 1] as u16, and positions as i16 in the mesh's frame if it has one.
/// Also returns the indices as a client reads them.
pub(super) fn plain_primitive(
    b: &mut GltfBuilder,
    m: &ContentPrimitive,
    with_features: bool,
    quantized: Option<Option<&QuantFrame>>,
) -> std::result::Result<(Value, Vec<u32>), EncodeError> {
    plain_primitive_at(b, m, with_features, quantized, WrittenAttributes::default())
}

/// `m` as `EXT_meshopt_compression` streams: quantized as [`plain_primitive`] writes it, its
/// vertices reordered for the codecs, normals through the `OCTAHEDRAL` filter, and what 16 bits
/// cannot hold within the bounds through the `EXPONENTIAL` filter: positions of a mesh without a
/// frame (within `enc.max_position_error_m`), UVs that tile beyond [0, 1] (within a quarter texel
/// of the `uv_texels` image, as Draco's UV bits); colours as 8-bit. Also returns the decoded
/// positions and what is drawn (triangles as the index codec's decoder gives them back).
fn meshopt_primitive(
    b: &mut GltfBuilder,
    m: &ContentPrimitive,
    with_features: bool,
    enc: &TileEncoding,
    frame: Option<&QuantFrame>,
    uv_texels: u32,
) -> std::result::Result<(Value, Option<Vec<DVec3>>, Drawn), EncodeError> {
    use crate::encode::meshopt::{exp_filtered, octahedral_normals, optimize_order};
    let m = optimize_order(m);
    let mut written = WrittenAttributes::default();
    let mut decoded = frame.map(|f| f.decoded_positions(&m.positions));
    if frame.is_none() {
        if let Some(exp) = exp_filtered(&y_up(&m.positions), enc.max_position_error_m) {
            written.position = Some(b.exp_accessor(&exp, true)?);
            decoded = Some(
                exp.drawn
                    .iter()
                    .map(|v| DVec3::from(v.map(f64::from)))
                    .collect(),
            );
        }
    }
    if !m.normals.is_empty() {
        written.normal =
            Some(b.octahedral_normal_accessor(&octahedral_normals(&y_up(&m.normals)))?);
    }
    if !m.uvs.is_empty() && !uvs_in_unit_square(&m.uvs) {
        let quarter_texel = 0.25 / uv_texels.max(1) as f64;
        if let Some(exp) = exp_filtered(&m.uvs, quarter_texel) {
            written.uv = Some(b.exp_accessor(&exp, false)?);
        }
    }
    if !m.colors.is_empty() {
        // 8 bits per channel, as Draco's colours (COLOR_BITS) and images have.
        let q: Vec<[i32; 4]> = m
            .colors
            .iter()
            .map(|c| c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as i32))
            .collect();
        written.color = Some(b.normalized_accessor(&q, UNSIGNED_BYTE, false)?);
    }
    let (p, indices) = plain_primitive_at(b, &m, with_features, Some(frame), written)?;
    let drawn = Drawn::of(b.edges, &m, decoded.as_deref(), indices);
    Ok((p, decoded, drawn))
}

/// Accessors a primitive's writer made itself (meshopt filters), used instead of the plain ones.
#[derive(Default)]
struct WrittenAttributes {
    position: Option<usize>,
    normal: Option<usize>,
    uv: Option<usize>,
    color: Option<usize>,
}

/// [`plain_primitive`], with the accessors in `written` used as they are.
fn plain_primitive_at(
    b: &mut GltfBuilder,
    m: &ContentPrimitive,
    with_features: bool,
    quantized: Option<Option<&QuantFrame>>,
    written: WrittenAttributes,
) -> std::result::Result<(Value, Vec<u32>), EncodeError> {
    let mut attributes = Map::new();
    let positions = match (written.position, quantized.flatten()) {
        (Some(accessor), _) => accessor,
        (None, Some(f)) => {
            let q: Vec<[i32; 3]> = y_up(&m.positions)
                .into_iter()
                .map(|p| f.quantize(p))
                .collect();
            b.normalized_accessor(&q, SHORT, true)?
        }
        (None, None) => b.float_accessor(&y_up(&m.positions), true)?,
    };
    attributes.insert("POSITION".into(), json!(positions));
    if !m.normals.is_empty() {
        let normals = match (written.normal, quantized) {
            (Some(accessor), _) => accessor,
            (None, Some(_)) => {
                let q: Vec<[i32; 3]> = y_up(&m.normals).into_iter().map(normal_i8).collect();
                b.normalized_accessor(&q, BYTE, false)?
            }
            (None, None) => b.float_accessor(&y_up(&m.normals), false)?,
        };
        attributes.insert("NORMAL".into(), json!(normals));
    }
    if !m.uvs.is_empty() {
        let uvs = match (written.uv, quantized.and_then(|_| uvs_u16(&m.uvs))) {
            (Some(accessor), _) => accessor,
            (None, Some(q)) => b.normalized_accessor(&q, UNSIGNED_SHORT, false)?,
            (None, None) => b.float_accessor(&m.uvs, false)?,
        };
        attributes.insert("TEXCOORD_0".into(), json!(uvs));
    }
    if !m.colors.is_empty() {
        let colors = match written.color {
            Some(accessor) => accessor,
            None => b.float_accessor(&m.colors, false)?,
        };
        attributes.insert("COLOR_0".into(), json!(colors));
    }
    if with_features {
        let fids: Vec<[f32; 1]> = m.feature_ids.iter().map(|&f| [f as f32]).collect();
        attributes.insert(
            "_FEATURE_ID_0".into(),
            json!(b.float_accessor(&fids, false)?),
        );
    }
    let (indices, drawn_indices) = b.index_accessor(&m.indices, m.positions.len())?;
    Ok((
        json!({"attributes": attributes, "indices": indices}),
        drawn_indices,
    ))
}

/// One Draco stream in a bufferView, and accessors (without bufferViews) that describe the
/// decoded data, as KHR_draco_mesh_compression requires; with `feature_count`, the per-vertex
/// feature IDs go in too. Also returns the decoded positions and what is drawn (Draco's own
/// triangle and point order, read back from the stream).
fn draco_primitive(
    b: &mut GltfBuilder,
    m: &ContentPrimitive,
    feature_count: Option<usize>,
    enc: &TileEncoding,
    uv_texels: u32,
) -> std::result::Result<(Value, Vec<DVec3>, Drawn), EncodeError> {
    use crate::encode::draco::{encode_mesh, position_bits_for, EncodeAttribute, EncodeOptions};
    let positions_y_up = y_up(&m.positions);
    let mut normals_y_up = y_up(&m.normals);
    let positions = positions_y_up.as_flattened();
    let extent = super::draco_box(&positions_y_up).1;
    let position_bits = position_bits_for(extent, enc.max_position_error_m);
    if enc.normals_from_drawn_faces && !normals_y_up.is_empty() {
        let drawn = super::draco_grid_positions(&positions_y_up, enc.max_position_error_m);
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
    let encoded = encode_mesh(&attrs, &m.indices, &EncodeOptions::default())?;
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
    // What is drawn, for the edges only.
    let drawn = if !b.edges {
        Drawn::default()
    } else {
        // The element of each decoded point: its decoded feature ID (all one element
        // without them).
        let decoded_groups: Vec<u32> = match names.iter().position(|n| n.0 == "_FEATURE_ID_0") {
            Some(k) => encoded
                .decoded_mesh
                .attribute(encoded.attribute_ids[k])
                .map(|a| {
                    (0..encoded.point_count)
                        .map(|i| a.values.get_f64(i) as u32)
                        .collect()
                })
                .unwrap_or_else(|| vec![0; encoded.point_count]),
            None => vec![0; encoded.point_count],
        };
        Drawn {
            positions_y_up: encoded.decoded_positions.clone(),
            groups: decoded_groups,
            indices: encoded.decoded_mesh.indices.clone(),
        }
    };
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
        drawn,
    ))
}
