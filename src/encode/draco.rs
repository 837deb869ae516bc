//! Draco mesh compression for glTF tiles.
//!
//! Implements the encoder side of the glTF extension `KHR_draco_mesh_compression`
//! (Khronos, ratified; Draco bitstream 2.2; spec copy in
//! `shared/specs/gltf-ext/extensions/2.0/Khronos/KHR_draco_mesh_compression/`) and a decoder
//! for checking our own output. The work is done by Google's Draco C++ library (Debian
//! `libdraco-dev` 1.5.5) through our small C ABI shim `shim/draco_shim.cc`; this file is the
//! only place with `unsafe` for it, and every pointer and length is checked here.
//!
//! What a caller writing a glTF primitive needs from [`encode_mesh`]:
//! - [`Encoded::bytes`] goes into the bufferView named by the extension's `bufferView`;
//! - [`Encoded::attribute_ids`]`[i]` is the Draco unique id of input attribute `i`, the value
//!   for the extension's `attributes` map (`{"POSITION": id, "_FEATURE_ID_0": id, ...}`).
//!   Every attribute of a Draco primitive, feature ids included (as a GENERIC attribute),
//!   must be inside the Draco stream;
//! - the accessors must describe the *decoded* data (spec: "must match the decompressed
//!   data"): Draco may split or merge vertices and drop unreferenced ones, so use
//!   [`Encoded::point_count`] for every attribute accessor `count`,
//!   `3 * `[`Encoded::face_count`] for the indices accessor, and
//!   [`Encoded::attribute_min_max`] for `min`/`max` (required for POSITION). These come from
//!   decoding the stream once right after encoding, so they are exact.
//!
//! Quantization: a float attribute with `quantization_bits = b > 0` is snapped to a grid of
//! step `range / (2^b - 1)`, where `range` is the largest per-component extent of that
//! attribute's values (one range for all components); the rounding error is at most half a
//! step. See [`position_bits_for`]. Integer attributes and `b = 0` are lossless.

use std::ffi::c_void;
use std::os::raw::c_char;

use thiserror::Error;

/// Errors of the Draco binding. Decoding hostile or damaged bytes gives an error, never a
/// crash.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
pub enum DracoError {
    /// The mesh has no triangles or no vertices; Draco cannot encode it (write the primitive
    /// uncompressed or leave it out).
    #[error("empty mesh: Draco needs at least one triangle and one vertex")]
    EmptyMesh,
    /// The input arrays are inconsistent (lengths, index range, components, values).
    #[error("invalid Draco input: {0}")]
    InvalidInput(String),
    /// Draco refused to encode the mesh.
    #[error("Draco encoding failed: {0}")]
    Encode(String),
    /// The bytes are not a valid Draco mesh stream (garbage, truncated, corrupted).
    #[error("Draco decoding failed: {0}")]
    Decode(String),
    /// A valid Draco stream with something this binding does not handle (point cloud,
    /// 64-bit integer attribute, ...).
    #[error("unsupported Draco content: {0}")]
    Unsupported(String),
    #[error("out of memory in Draco: {0}")]
    OutOfMemory(String),
    #[error("internal error in the Draco shim: {0}")]
    Internal(String),
}

/// Semantic of an attribute inside the Draco stream (Draco's `GeometryAttribute::Type`).
/// glTF custom attributes such as `_FEATURE_ID_0` or `_BATCHID` are [`AttributeKind::Generic`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AttributeKind {
    Position,
    Normal,
    Color,
    TexCoord,
    Generic,
}

impl AttributeKind {
    fn to_raw(self) -> i32 {
        match self {
            AttributeKind::Position => ffi::KIND_POSITION,
            AttributeKind::Normal => ffi::KIND_NORMAL,
            AttributeKind::Color => ffi::KIND_COLOR,
            AttributeKind::TexCoord => ffi::KIND_TEX_COORD,
            AttributeKind::Generic => ffi::KIND_GENERIC,
        }
    }

    /// Draco types beyond the five above (tangent, joints, ... of newer Draco) map to
    /// `Generic`.
    fn from_raw(raw: i32) -> AttributeKind {
        match raw {
            ffi::KIND_POSITION => AttributeKind::Position,
            ffi::KIND_NORMAL => AttributeKind::Normal,
            ffi::KIND_COLOR => AttributeKind::Color,
            ffi::KIND_TEX_COORD => AttributeKind::TexCoord,
            _ => AttributeKind::Generic,
        }
    }

    /// Name used in messages and test fixtures.
    pub fn name(self) -> &'static str {
        match self {
            AttributeKind::Position => "POSITION",
            AttributeKind::Normal => "NORMAL",
            AttributeKind::Color => "COLOR",
            AttributeKind::TexCoord => "TEX_COORD",
            AttributeKind::Generic => "GENERIC",
        }
    }
}

/// Per-vertex values of an input attribute, `point_count * components` long, interleaved
/// by vertex. The component type is kept in the Draco stream and comes back on decode,
/// so pick the glTF accessor `componentType` accordingly (u8/u16 for normalized colours or
/// small feature-id ranges, f32 otherwise; glTF has no u32 vertex attributes).
#[derive(Debug, Clone, Copy)]
pub enum AttributeData<'a> {
    F32(&'a [f32]),
    U8(&'a [u8]),
    U16(&'a [u16]),
    U32(&'a [u32]),
}

impl AttributeData<'_> {
    fn len(&self) -> usize {
        match self {
            AttributeData::F32(d) => d.len(),
            AttributeData::U8(d) => d.len(),
            AttributeData::U16(d) => d.len(),
            AttributeData::U32(d) => d.len(),
        }
    }

    fn raw(&self) -> (i32, *const c_void) {
        match self {
            AttributeData::F32(d) => (ffi::DTYPE_F32, d.as_ptr().cast()),
            AttributeData::U8(d) => (ffi::DTYPE_U8, d.as_ptr().cast()),
            AttributeData::U16(d) => (ffi::DTYPE_U16, d.as_ptr().cast()),
            AttributeData::U32(d) => (ffi::DTYPE_U32, d.as_ptr().cast()),
        }
    }
}

/// One vertex attribute to encode.
#[derive(Debug, Clone, Copy)]
pub struct EncodeAttribute<'a> {
    pub kind: AttributeKind,
    /// Components per vertex: POSITION and NORMAL 3, TEX_COORD 2, COLOR 3 or 4,
    /// GENERIC 1 to 4.
    pub components: u8,
    pub data: AttributeData<'a>,
    /// Integer data meant as 0..1 (glTF `normalized: true`), e.g. u8 colours.
    pub normalized: bool,
    /// 0 = lossless; 1..=[`MAX_QUANTIZATION_BITS`] for f32 data (NORMAL needs at least 2).
    /// Must be 0 for integer data, which Draco always stores losslessly.
    pub quantization_bits: u8,
}

impl<'a> EncodeAttribute<'a> {
    /// POSITION, xyz f32. Pick `bits` with [`position_bits_for`] (14 is a common default).
    pub fn position(data: &'a [f32], bits: u8) -> Self {
        Self::float(AttributeKind::Position, 3, data, bits)
    }
    /// NORMAL, xyz f32 (10 bits is plenty for shading).
    pub fn normal(data: &'a [f32], bits: u8) -> Self {
        Self::float(AttributeKind::Normal, 3, data, bits)
    }
    /// TEXCOORD_n, uv f32 (12 bits is usual). Add one attribute per set.
    pub fn tex_coord(data: &'a [f32], bits: u8) -> Self {
        Self::float(AttributeKind::TexCoord, 2, data, bits)
    }
    /// COLOR_0 as f32 RGBA (or RGB with `components = 3` set by hand).
    pub fn color_f32(data: &'a [f32], bits: u8) -> Self {
        Self::float(AttributeKind::Color, 4, data, bits)
    }
    /// COLOR_0 as normalized u8 RGBA (lossless).
    pub fn color_u8(data: &'a [u8]) -> Self {
        EncodeAttribute {
            kind: AttributeKind::Color,
            components: 4,
            data: AttributeData::U8(data),
            normalized: true,
            quantization_bits: 0,
        }
    }
    /// `_FEATURE_ID_n` as f32 (exact for ids < 2^24); never quantized, so ids stay integers.
    pub fn feature_id_f32(data: &'a [f32]) -> Self {
        Self::float(AttributeKind::Generic, 1, data, 0)
    }
    /// `_FEATURE_ID_n` as u8 (lossless; accessor componentType UNSIGNED_BYTE).
    pub fn feature_id_u8(data: &'a [u8]) -> Self {
        Self::integer(AttributeData::U8(data))
    }
    /// `_FEATURE_ID_n` as u16 (lossless; accessor componentType UNSIGNED_SHORT).
    pub fn feature_id_u16(data: &'a [u16]) -> Self {
        Self::integer(AttributeData::U16(data))
    }
    /// A u32 scalar GENERIC attribute (lossless). glTF cannot declare u32 vertex
    /// accessors, so prefer [`Self::feature_id_u16`] or [`Self::feature_id_f32`] for tiles.
    pub fn generic_u32(data: &'a [u32]) -> Self {
        Self::integer(AttributeData::U32(data))
    }

    fn float(kind: AttributeKind, components: u8, data: &'a [f32], bits: u8) -> Self {
        EncodeAttribute {
            kind,
            components,
            data: AttributeData::F32(data),
            normalized: false,
            quantization_bits: bits,
        }
    }
    fn integer(data: AttributeData<'a>) -> Self {
        EncodeAttribute {
            kind: AttributeKind::Generic,
            components: 1,
            data,
            normalized: false,
            quantization_bits: 0,
        }
    }
}

/// How connectivity is coded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodingMethod {
    /// Best compression. Vertex and face order change; vertices may be split or merged.
    Edgebreaker,
    /// Keeps vertex and face order; much larger output. For debugging and exact tests.
    Sequential,
}

/// Encoder settings. Speeds run 0 (smallest output, slowest) to 10 (fastest, largest).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EncodeOptions {
    pub encode_speed: u8,
    pub decode_speed: u8,
    pub method: EncodingMethod,
}

impl EncodeOptions {
    /// Default speed (encoder and decoder), chosen by measurement on this machine
    /// (`measure_throughput` below; positions 14 bits, normals 10, uvs 12): against Draco's
    /// own default 5, speed 7 is within 0.2-1.1 % of the size (1M-triangle grid and five
    /// real models) while encoding 1.4-1.6x faster (2.3 Mtri/s on the grid) and decoding
    /// 1.4-1.7x faster. Speed 10 is barely faster than 7 but up to 46 % larger (grid) and
    /// 14 % larger (LoD3_Railway). Speed 0 is 3-4x slower; it shrinks the smooth grid by a
    /// third but makes the real building models 50-70 % *larger*.
    pub const DEFAULT_SPEED: u8 = 7;
}

impl Default for EncodeOptions {
    fn default() -> Self {
        EncodeOptions {
            encode_speed: Self::DEFAULT_SPEED,
            decode_speed: Self::DEFAULT_SPEED,
            method: EncodingMethod::Edgebreaker,
        }
    }
}

/// A Draco stream plus what the glTF primitive's accessors need (all of the decoded data).
#[derive(Debug, Clone, PartialEq)]
pub struct Encoded {
    /// The Draco bitstream (the extension's bufferView content).
    pub bytes: Vec<u8>,
    /// Draco unique id of each input attribute, in input order.
    pub attribute_ids: Vec<u32>,
    /// Vertex count after decoding: `count` of every attribute accessor.
    pub point_count: usize,
    /// Triangle count after decoding: the indices accessor `count` is `3 * face_count`.
    pub face_count: usize,
    /// Per input attribute, (min, max) per component of the decoded values, as f64 so that
    /// u32 values are exact. f32 data converts exactly: write them as the accessor's
    /// `min`/`max`.
    pub attribute_min_max: Vec<(Vec<f64>, Vec<f64>)>,
    /// The decoded POSITION values, xyz per point: where the client will draw the vertices
    /// (bounding volumes of instanced copies are built from them).
    pub decoded_positions: Vec<[f32; 3]>,
}

impl Encoded {
    /// Whether the indices accessor can be UNSIGNED_SHORT (all point indices < 65535).
    pub fn indices_fit_u16(&self) -> bool {
        self.point_count <= 65535
    }
}

/// Values of a decoded attribute, one entry per point, `components` values each.
#[derive(Debug, Clone, PartialEq)]
pub enum AttributeValues {
    F32(Vec<f32>),
    U8(Vec<u8>),
    U16(Vec<u16>),
    U32(Vec<u32>),
    I8(Vec<i8>),
    I16(Vec<i16>),
    I32(Vec<i32>),
}

impl AttributeValues {
    /// Number of scalar values.
    pub fn len(&self) -> usize {
        match self {
            AttributeValues::F32(v) => v.len(),
            AttributeValues::U8(v) => v.len(),
            AttributeValues::U16(v) => v.len(),
            AttributeValues::U32(v) => v.len(),
            AttributeValues::I8(v) => v.len(),
            AttributeValues::I16(v) => v.len(),
            AttributeValues::I32(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Scalar value `i` as f64 (exact for every variant). Panics if out of range.
    pub fn get_f64(&self, i: usize) -> f64 {
        match self {
            AttributeValues::F32(v) => f64::from(v[i]),
            AttributeValues::U8(v) => f64::from(v[i]),
            AttributeValues::U16(v) => f64::from(v[i]),
            AttributeValues::U32(v) => f64::from(v[i]),
            AttributeValues::I8(v) => f64::from(v[i]),
            AttributeValues::I16(v) => f64::from(v[i]),
            AttributeValues::I32(v) => f64::from(v[i]),
        }
    }

    /// The f32 values, if that is the stored type.
    pub fn as_f32(&self) -> Option<&[f32]> {
        match self {
            AttributeValues::F32(v) => Some(v),
            _ => None,
        }
    }
}

/// One decoded attribute.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedAttribute {
    pub unique_id: u32,
    pub kind: AttributeKind,
    pub components: u8,
    pub normalized: bool,
    pub values: AttributeValues,
}

impl DecodedAttribute {
    /// (min, max) per component; empty vectors for an attribute without points.
    pub fn min_max(&self) -> (Vec<f64>, Vec<f64>) {
        let nc = usize::from(self.components);
        let n = self.values.len().checked_div(nc).unwrap_or(0);
        if n == 0 {
            return (Vec::new(), Vec::new());
        }
        let mut lo = vec![f64::INFINITY; nc];
        let mut hi = vec![f64::NEG_INFINITY; nc];
        for p in 0..n {
            for c in 0..nc {
                let v = self.values.get_f64(p * nc + c);
                if v < lo[c] {
                    lo[c] = v;
                }
                if v > hi[c] {
                    hi[c] = v;
                }
            }
        }
        (lo, hi)
    }
}

/// A decoded Draco triangle mesh, de-indexed per point like a glTF primitive.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedMesh {
    pub point_count: usize,
    pub face_count: usize,
    /// `3 * face_count` point indices, each `< point_count`.
    pub indices: Vec<u32>,
    pub attributes: Vec<DecodedAttribute>,
}

impl DecodedMesh {
    /// The attribute with Draco unique id `unique_id` (the id in the glTF extension).
    pub fn attribute(&self, unique_id: u32) -> Option<&DecodedAttribute> {
        self.attributes.iter().find(|a| a.unique_id == unique_id)
    }

    /// The first attribute of a kind.
    pub fn first_of_kind(&self, kind: AttributeKind) -> Option<&DecodedAttribute> {
        self.attributes.iter().find(|a| a.kind == kind)
    }
}

/// Largest quantization accepted here. Draco itself allows 30, but an f32 has a 24-bit
/// significand, so more bits cannot add precision over the attribute's range, and Draco's
/// encoder cost grows as 2^bits (measured here on a 9-vertex mesh: 24 bits 0.14 s,
/// 27 bits 0.7 s and 0.5 GB, 30 bits 10 s and 4 GB).
pub const MAX_QUANTIZATION_BITS: u8 = 24;

/// Smallest Draco quantization (1..=[`MAX_QUANTIZATION_BITS`] bits) for positions whose largest bounding-box side
/// is `extent_m` metres, such that the rounding error stays within `max_error_m` metres.
///
/// Draco's quantization step is `extent / (2^bits - 1)` and values are rounded to the
/// nearest step, so the error is at most `step / 2`; this returns the smallest `bits` with
/// `extent / (2^bits - 1) / 2 <= max_error_m`, clamped to 1..=[`MAX_QUANTIZATION_BITS`]
/// (Draco's own limit is 30, see the constant for why we stop at 24).
/// `extent_m` must be the largest side of the box of *all* positions given to Draco (Draco
/// uses one range for the three axes). A zero extent gives 1; a non-positive or NaN
/// `max_error_m`, or an infinite extent, gives the maximum. Example: a 100 m tile with 5 mm
/// allowed error needs 14 bits (step 6.1 mm, error <= 3.05 mm).
pub fn position_bits_for(extent_m: f64, max_error_m: f64) -> u8 {
    const MIN_BITS: u8 = 1;
    const MAX_BITS: u8 = MAX_QUANTIZATION_BITS;
    // Written with is_nan() so that NaN takes the conservative branch.
    if max_error_m.is_nan() || max_error_m <= 0.0 || !extent_m.is_finite() {
        return MAX_BITS;
    }
    if extent_m <= 0.0 {
        return MIN_BITS;
    }
    (MIN_BITS..=MAX_BITS)
        .find(|&b| quantization_step(extent_m, b) / 2.0 <= max_error_m)
        .unwrap_or(MAX_BITS)
}

/// Draco's quantization step for a value range `extent` and `bits`:
/// `extent / (2^bits - 1)`. The rounding error is at most half of it.
pub fn quantization_step(extent: f64, bits: u8) -> f64 {
    let levels = (1u64 << bits.clamp(1, 62)) - 1;
    extent / levels as f64
}

/// Encodes an indexed triangle mesh into a Draco stream and reports what the glTF
/// accessors need (from one decode of the result, so counts and bounds are exact).
///
/// `indices` are triangles (3 per face) into the vertices; the vertex count is taken from
/// the POSITION attribute (exactly one is required). Errors: [`DracoError::EmptyMesh`]
/// without triangles or vertices, [`DracoError::InvalidInput`] for inconsistent input
/// (length mismatch, index out of range, non-finite floats, wrong components, quantization
/// on integer data).
pub fn encode_mesh(
    attrs: &[EncodeAttribute],
    indices: &[u32],
    opts: &EncodeOptions,
) -> Result<Encoded, DracoError> {
    let raw = encode_raw(attrs, indices, opts)?;
    let decoded = decode_mesh(&raw.bytes)
        .map_err(|e| DracoError::Internal(format!("our own Draco output did not decode: {e}")))?;
    if decoded.point_count != raw.point_count || decoded.face_count != raw.face_count {
        return Err(DracoError::Internal(format!(
            "encoder counted {} points / {} faces, decoder {} / {}",
            raw.point_count, raw.face_count, decoded.point_count, decoded.face_count
        )));
    }
    let mut attribute_min_max = Vec::with_capacity(attrs.len());
    for &id in &raw.attribute_ids {
        let att = decoded.attribute(id).ok_or_else(|| {
            DracoError::Internal(format!("attribute id {id} missing after decoding"))
        })?;
        attribute_min_max.push(att.min_max());
    }
    let decoded_positions = decoded
        .first_of_kind(AttributeKind::Position)
        .and_then(|a| a.values.as_f32())
        .map(|v| v.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect())
        .unwrap_or_default();
    Ok(Encoded {
        bytes: raw.bytes,
        attribute_ids: raw.attribute_ids,
        point_count: decoded.point_count,
        face_count: decoded.face_count,
        attribute_min_max,
        decoded_positions,
    })
}

/// Result of [`encode_mesh_fast`]: the stream and the encoder's own counts, without the
/// verification decode (so no min/max).
#[derive(Debug, Clone, PartialEq)]
pub struct EncodedRaw {
    pub bytes: Vec<u8>,
    pub attribute_ids: Vec<u32>,
    /// Points as counted by the encoder (equal to the decoded count in every test here).
    pub point_count: usize,
    pub face_count: usize,
}

/// Like [`encode_mesh`] but skips the decode: no min/max, counts from the encoder. For
/// benchmarks and for callers that decode anyway (e.g. to write an uncompressed fallback).
pub fn encode_mesh_fast(
    attrs: &[EncodeAttribute],
    indices: &[u32],
    opts: &EncodeOptions,
) -> Result<EncodedRaw, DracoError> {
    encode_raw(attrs, indices, opts)
}

fn validate(attrs: &[EncodeAttribute], indices: &[u32]) -> Result<usize, DracoError> {
    let mut positions = attrs.iter().filter(|a| a.kind == AttributeKind::Position);
    let pos = positions
        .next()
        .ok_or_else(|| DracoError::InvalidInput("a POSITION attribute is required".into()))?;
    if positions.next().is_some() {
        return Err(DracoError::InvalidInput(
            "more than one POSITION attribute".into(),
        ));
    }
    if pos.components != 3 {
        return Err(DracoError::InvalidInput(
            "POSITION must have 3 components".into(),
        ));
    }
    let point_count = pos.data.len() / 3;
    if point_count == 0 || indices.is_empty() {
        return Err(DracoError::EmptyMesh);
    }
    if indices.len() % 3 != 0 {
        return Err(DracoError::InvalidInput(format!(
            "{} indices is not a multiple of 3",
            indices.len()
        )));
    }
    if point_count > i32::MAX as usize || indices.len() / 3 > i32::MAX as usize {
        return Err(DracoError::InvalidInput("mesh too large for Draco".into()));
    }
    if attrs.len() > 255 {
        return Err(DracoError::InvalidInput("too many attributes".into()));
    }
    for (i, a) in attrs.iter().enumerate() {
        let ok_components = match a.kind {
            AttributeKind::Position | AttributeKind::Normal => a.components == 3,
            AttributeKind::TexCoord => a.components == 2,
            AttributeKind::Color => a.components == 3 || a.components == 4,
            AttributeKind::Generic => (1..=4).contains(&a.components),
        };
        if !ok_components {
            return Err(DracoError::InvalidInput(format!(
                "attribute {i} ({}): {} components not allowed",
                a.kind.name(),
                a.components
            )));
        }
        let expected = point_count
            .checked_mul(usize::from(a.components))
            .ok_or_else(|| DracoError::InvalidInput("attribute size overflows".into()))?;
        if a.data.len() != expected {
            return Err(DracoError::InvalidInput(format!(
                "attribute {i} ({}): {} values, expected {} ({} points x {})",
                a.kind.name(),
                a.data.len(),
                expected,
                point_count,
                a.components
            )));
        }
        if a.quantization_bits > MAX_QUANTIZATION_BITS {
            return Err(DracoError::InvalidInput(format!(
                "attribute {i}: quantization bits {} > {MAX_QUANTIZATION_BITS}",
                a.quantization_bits
            )));
        }
        match a.data {
            AttributeData::F32(d) => {
                if a.kind == AttributeKind::Normal && a.quantization_bits == 1 {
                    return Err(DracoError::InvalidInput(
                        "NORMAL quantization needs at least 2 bits".into(),
                    ));
                }
                if let Some(k) = d.iter().position(|v| !v.is_finite()) {
                    return Err(DracoError::InvalidInput(format!(
                        "attribute {i} ({}): non-finite value at {k}",
                        a.kind.name()
                    )));
                }
            }
            _ if a.quantization_bits != 0 => {
                return Err(DracoError::InvalidInput(format!(
                    "attribute {i} ({}): quantization applies to f32 data only",
                    a.kind.name()
                )));
            }
            _ => {}
        }
    }
    if let Some(k) = indices.iter().position(|&v| v as usize >= point_count) {
        return Err(DracoError::InvalidInput(format!(
            "index {} at {k} >= vertex count {point_count}",
            indices[k]
        )));
    }
    Ok(point_count)
}

fn encode_raw(
    attrs: &[EncodeAttribute],
    indices: &[u32],
    opts: &EncodeOptions,
) -> Result<EncodedRaw, DracoError> {
    let point_count = validate(attrs, indices)?;
    if opts.encode_speed > 10 || opts.decode_speed > 10 {
        return Err(DracoError::InvalidInput("speeds must be 0..=10".into()));
    }
    let raw_attrs: Vec<ffi::Attribute> = attrs
        .iter()
        .map(|a| {
            let (dtype, data) = a.data.raw();
            ffi::Attribute {
                kind: a.kind.to_raw(),
                dtype,
                components: u32::from(a.components),
                normalized: i32::from(a.normalized),
                quantization_bits: i32::from(a.quantization_bits),
                data,
                num_values: a.data.len() as u64,
            }
        })
        .collect();
    let raw_opts = ffi::EncodeOptions {
        encode_speed: i32::from(opts.encode_speed),
        decode_speed: i32::from(opts.decode_speed),
        method: match opts.method {
            EncodingMethod::Edgebreaker => ffi::METHOD_EDGEBREAKER,
            EncodingMethod::Sequential => ffi::METHOD_SEQUENTIAL,
        },
    };
    let mut err = ErrBuf::new();
    let mut handle: *mut ffi::Encoded = std::ptr::null_mut();
    // SAFETY: every pointer refers to live slices / locals for the duration of the call;
    // `num_values` and `num_indices` are the true lengths of those slices (validated above),
    // and the shim does not keep any of these pointers after returning.
    let status = unsafe {
        ffi::bt_draco_encode(
            raw_attrs.as_ptr(),
            raw_attrs.len() as u32,
            point_count as u64,
            indices.as_ptr(),
            indices.len() as u64,
            &raw_opts,
            &mut handle,
            err.ptr(),
            err.cap(),
        )
    };
    if status != ffi::OK || handle.is_null() {
        return Err(err.to_error(status, DracoError::Encode));
    }
    let handle = EncodedHandle(handle);
    // SAFETY: `handle.0` is a live handle from a successful encode; data/size describe the
    // buffer it owns, which lives until the handle is dropped (after the copy).
    let bytes = unsafe {
        let data = ffi::bt_draco_encoded_data(handle.0);
        let size = ffi::bt_draco_encoded_size(handle.0);
        let size = usize::try_from(size)
            .map_err(|_| DracoError::Internal("encoded size overflows usize".into()))?;
        if data.is_null() || size == 0 {
            return Err(DracoError::Internal("encoder returned no bytes".into()));
        }
        std::slice::from_raw_parts(data, size).to_vec()
    };
    let mut attribute_ids = Vec::with_capacity(attrs.len());
    for i in 0..attrs.len() {
        // SAFETY: live handle; the index is range-checked by the shim.
        let id = unsafe { ffi::bt_draco_encoded_unique_id(handle.0, i as u32) };
        if id == u32::MAX {
            return Err(DracoError::Internal(format!(
                "no unique id for attribute {i}"
            )));
        }
        attribute_ids.push(id);
    }
    // SAFETY: live handle.
    let (np, nf) = unsafe {
        (
            ffi::bt_draco_encoded_num_points(handle.0),
            ffi::bt_draco_encoded_num_faces(handle.0),
        )
    };
    Ok(EncodedRaw {
        bytes,
        attribute_ids,
        point_count: to_usize(np)?,
        face_count: to_usize(nf)?,
    })
}

/// Decodes a Draco triangle-mesh stream (e.g. the bufferView of a
/// `KHR_draco_mesh_compression` primitive). Garbage, truncated or corrupted input gives
/// [`DracoError::Decode`]; point clouds give [`DracoError::Unsupported`].
pub fn decode_mesh(bytes: &[u8]) -> Result<DecodedMesh, DracoError> {
    if bytes.is_empty() {
        return Err(DracoError::Decode("empty input".into()));
    }
    let mut err = ErrBuf::new();
    let mut handle: *mut ffi::Mesh = std::ptr::null_mut();
    // SAFETY: `bytes` is a live slice of the given length; the shim copies what it needs
    // and keeps no pointer to it (the decoded mesh owns its data).
    let status = unsafe {
        ffi::bt_draco_decode(
            bytes.as_ptr(),
            bytes.len() as u64,
            &mut handle,
            err.ptr(),
            err.cap(),
        )
    };
    if status != ffi::OK || handle.is_null() {
        return Err(err.to_error(status, DracoError::Decode));
    }
    let handle = MeshHandle(handle);
    // SAFETY (all calls below): `handle.0` is a live mesh handle until `handle` drops at the
    // end of this function; each output buffer is allocated here with the exact capacity
    // passed as `cap`, and the shim checks `cap` before writing.
    let (np, nf, na) = unsafe {
        (
            ffi::bt_draco_mesh_num_points(handle.0),
            ffi::bt_draco_mesh_num_faces(handle.0),
            ffi::bt_draco_mesh_num_attributes(handle.0),
        )
    };
    let point_count = to_usize(np)?;
    let face_count = to_usize(nf)?;
    let n_idx = face_count
        .checked_mul(3)
        .ok_or_else(|| DracoError::Decode("face count overflows".into()))?;
    let mut indices = vec![0u32; n_idx];
    let st =
        unsafe { ffi::bt_draco_mesh_copy_indices(handle.0, indices.as_mut_ptr(), n_idx as u64) };
    if st != ffi::OK {
        return Err(status_error(
            st,
            "copying indices".into(),
            DracoError::Decode,
        ));
    }
    let mut attributes = Vec::with_capacity(na as usize);
    for i in 0..na {
        let mut info = ffi::AttributeInfo::default();
        let st = unsafe { ffi::bt_draco_mesh_attribute_info(handle.0, i, &mut info) };
        if st != ffi::OK {
            return Err(status_error(
                st,
                format!("attribute {i} info"),
                DracoError::Decode,
            ));
        }
        if !(1..=4).contains(&info.components) {
            return Err(DracoError::Decode(format!(
                "attribute {i} has {} components",
                info.components
            )));
        }
        let n = point_count
            .checked_mul(info.components as usize)
            .ok_or_else(|| DracoError::Decode("attribute size overflows".into()))?;
        let values = match info.dtype {
            ffi::DTYPE_F32 => AttributeValues::F32(copy_attribute(&handle, i, n, 0f32)?),
            ffi::DTYPE_U8 => AttributeValues::U8(copy_attribute(&handle, i, n, 0u8)?),
            ffi::DTYPE_U16 => AttributeValues::U16(copy_attribute(&handle, i, n, 0u16)?),
            ffi::DTYPE_U32 => AttributeValues::U32(copy_attribute(&handle, i, n, 0u32)?),
            ffi::DTYPE_I8 => AttributeValues::I8(copy_attribute(&handle, i, n, 0i8)?),
            ffi::DTYPE_I16 => AttributeValues::I16(copy_attribute(&handle, i, n, 0i16)?),
            ffi::DTYPE_I32 => AttributeValues::I32(copy_attribute(&handle, i, n, 0i32)?),
            other => {
                return Err(DracoError::Unsupported(format!(
                    "attribute {i} has data type code {other}"
                )))
            }
        };
        attributes.push(DecodedAttribute {
            unique_id: info.unique_id,
            kind: AttributeKind::from_raw(info.kind),
            components: info.components as u8,
            normalized: info.normalized != 0,
            values,
        });
    }
    // Belt and braces: the shim already checked this.
    if indices.iter().any(|&v| v as usize >= point_count) {
        return Err(DracoError::Decode("face index out of range".into()));
    }
    Ok(DecodedMesh {
        point_count,
        face_count,
        indices,
        attributes,
    })
}

/// Copies attribute `i` (n scalar values of type T) out of a decoded mesh.
fn copy_attribute<T: Copy>(
    handle: &MeshHandle,
    i: u32,
    n: usize,
    zero: T,
) -> Result<Vec<T>, DracoError> {
    let mut out = vec![zero; n];
    let cap_bytes = std::mem::size_of_val(out.as_slice()) as u64;
    // SAFETY: live handle; `out` has exactly `cap_bytes` writable bytes, and T is the plain
    // numeric type matching the dtype the shim reported for this attribute.
    let st = unsafe {
        ffi::bt_draco_mesh_copy_attribute(handle.0, i, out.as_mut_ptr().cast(), cap_bytes)
    };
    if st != ffi::OK {
        return Err(status_error(
            st,
            format!("copying attribute {i}"),
            DracoError::Decode,
        ));
    }
    Ok(out)
}

fn to_usize(v: u64) -> Result<usize, DracoError> {
    usize::try_from(v).map_err(|_| DracoError::Internal("count overflows usize".into()))
}

fn status_error(status: i32, msg: String, default: fn(String) -> DracoError) -> DracoError {
    match status {
        ffi::ERR_INVALID_ARGUMENT => DracoError::InvalidInput(msg),
        ffi::ERR_ENCODE => DracoError::Encode(msg),
        ffi::ERR_DECODE => DracoError::Decode(msg),
        ffi::ERR_UNSUPPORTED => DracoError::Unsupported(msg),
        ffi::ERR_OUT_OF_MEMORY => DracoError::OutOfMemory(msg),
        ffi::ERR_INTERNAL => DracoError::Internal(msg),
        _ => default(format!("status {status}: {msg}")),
    }
}

/// Error-message buffer handed to the shim.
struct ErrBuf([u8; 512]);

impl ErrBuf {
    fn new() -> Self {
        ErrBuf([0; 512])
    }
    fn ptr(&mut self) -> *mut c_char {
        self.0.as_mut_ptr().cast()
    }
    fn cap(&self) -> usize {
        self.0.len()
    }
    fn message(&self) -> String {
        let end = self.0.iter().position(|&b| b == 0).unwrap_or(self.0.len());
        String::from_utf8_lossy(&self.0[..end]).into_owned()
    }
    fn to_error(&self, status: i32, default: fn(String) -> DracoError) -> DracoError {
        let mut msg = self.message();
        if msg.is_empty() {
            msg = "no message".into();
        }
        if status == ffi::OK {
            return DracoError::Internal(format!("shim returned OK without a result: {msg}"));
        }
        status_error(status, msg, default)
    }
}

/// Owns a `bt_draco_encoded` handle.
struct EncodedHandle(*mut ffi::Encoded);
impl Drop for EncodedHandle {
    fn drop(&mut self) {
        // SAFETY: the handle came from a successful bt_draco_encode and is freed only here.
        unsafe { ffi::bt_draco_encoded_free(self.0) }
    }
}

/// Owns a `bt_draco_mesh` handle.
struct MeshHandle(*mut ffi::Mesh);
impl Drop for MeshHandle {
    fn drop(&mut self) {
        // SAFETY: the handle came from a successful bt_draco_decode and is freed only here.
        unsafe { ffi::bt_draco_mesh_free(self.0) }
    }
}

/// Raw declarations matching `shim/draco_shim.h`.
mod ffi {
    use std::ffi::c_void;
    use std::os::raw::c_char;

    pub const OK: i32 = 0;
    pub const ERR_INVALID_ARGUMENT: i32 = 1;
    pub const ERR_ENCODE: i32 = 2;
    pub const ERR_DECODE: i32 = 3;
    pub const ERR_UNSUPPORTED: i32 = 4;
    pub const ERR_OUT_OF_MEMORY: i32 = 5;
    pub const ERR_INTERNAL: i32 = 6;

    pub const KIND_POSITION: i32 = 0;
    pub const KIND_NORMAL: i32 = 1;
    pub const KIND_COLOR: i32 = 2;
    pub const KIND_TEX_COORD: i32 = 3;
    pub const KIND_GENERIC: i32 = 4;

    pub const DTYPE_F32: i32 = 0;
    pub const DTYPE_U8: i32 = 1;
    pub const DTYPE_U16: i32 = 2;
    pub const DTYPE_U32: i32 = 3;
    pub const DTYPE_I8: i32 = 4;
    pub const DTYPE_I16: i32 = 5;
    pub const DTYPE_I32: i32 = 6;

    pub const METHOD_EDGEBREAKER: i32 = 0;
    pub const METHOD_SEQUENTIAL: i32 = 1;

    #[repr(C)]
    pub struct Attribute {
        pub kind: i32,
        pub dtype: i32,
        pub components: u32,
        pub normalized: i32,
        pub quantization_bits: i32,
        pub data: *const c_void,
        pub num_values: u64,
    }

    #[repr(C)]
    pub struct EncodeOptions {
        pub encode_speed: i32,
        pub decode_speed: i32,
        pub method: i32,
    }

    #[repr(C)]
    #[derive(Default)]
    pub struct AttributeInfo {
        pub unique_id: u32,
        pub kind: i32,
        pub dtype: i32,
        pub components: u32,
        pub normalized: i32,
    }

    #[repr(C)]
    pub struct Encoded {
        _private: [u8; 0],
    }
    #[repr(C)]
    pub struct Mesh {
        _private: [u8; 0],
    }

    extern "C" {
        pub fn bt_draco_encode(
            attrs: *const Attribute,
            num_attrs: u32,
            num_points: u64,
            indices: *const u32,
            num_indices: u64,
            opts: *const EncodeOptions,
            out: *mut *mut Encoded,
            err: *mut c_char,
            err_cap: usize,
        ) -> i32;
        pub fn bt_draco_encoded_data(e: *const Encoded) -> *const u8;
        pub fn bt_draco_encoded_size(e: *const Encoded) -> u64;
        pub fn bt_draco_encoded_unique_id(e: *const Encoded, i: u32) -> u32;
        pub fn bt_draco_encoded_num_points(e: *const Encoded) -> u64;
        pub fn bt_draco_encoded_num_faces(e: *const Encoded) -> u64;
        pub fn bt_draco_encoded_free(e: *mut Encoded);

        pub fn bt_draco_decode(
            data: *const u8,
            len: u64,
            out: *mut *mut Mesh,
            err: *mut c_char,
            err_cap: usize,
        ) -> i32;
        pub fn bt_draco_mesh_num_points(m: *const Mesh) -> u64;
        pub fn bt_draco_mesh_num_faces(m: *const Mesh) -> u64;
        pub fn bt_draco_mesh_num_attributes(m: *const Mesh) -> u32;
        pub fn bt_draco_mesh_attribute_info(m: *const Mesh, i: u32, out: *mut AttributeInfo)
            -> i32;
        pub fn bt_draco_mesh_copy_indices(m: *const Mesh, out: *mut u32, cap: u64) -> i32;
        pub fn bt_draco_mesh_copy_attribute(
            m: *const Mesh,
            i: u32,
            out: *mut c_void,
            cap_bytes: u64,
        ) -> i32;
        pub fn bt_draco_mesh_free(m: *mut Mesh);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// Small deterministic generator (no rand dependency).
    struct Lcg(u64);
    impl Lcg {
        fn next_u32(&mut self) -> u32 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 33) as u32
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next_u32() as usize) % n.max(1)
        }
    }

    /// Synthetic mesh: `patches` x `patches` separate wavy grid patches ("buildings") of
    /// `q` x `q` quads each, with a gap of one lattice cell between them, so every vertex has
    /// a unique lattice position `(round(x / SPACING), round(y / SPACING))`. Per-vertex
    /// normals, uvs, RGBA u8 colours, and a per-patch feature id (f32 and u16).
    pub(super) struct TestMesh {
        pub pos: Vec<f32>,
        pub nrm: Vec<f32>,
        pub uv: Vec<f32>,
        pub col: Vec<u8>,
        pub fid: Vec<f32>,
        pub fid16: Vec<u16>,
        pub idx: Vec<u32>,
    }

    const SPACING: f32 = 0.5;

    fn height(x: f32, y: f32) -> f32 {
        (x * 0.3).sin() * (y * 0.2).cos() * 2.0
    }

    pub(super) fn grid(patches: usize, q: usize) -> TestMesh {
        let mut m = TestMesh {
            pos: vec![],
            nrm: vec![],
            uv: vec![],
            col: vec![],
            fid: vec![],
            fid16: vec![],
            idx: vec![],
        };
        for pj in 0..patches {
            for pi in 0..patches {
                let feature = (pj * patches + pi) as u16;
                let base = (m.pos.len() / 3) as u32;
                for j in 0..=q {
                    for i in 0..=q {
                        let x = ((pi * (q + 2) + i) as f32) * SPACING;
                        let y = ((pj * (q + 2) + j) as f32) * SPACING;
                        let z = height(x, y);
                        m.pos.extend_from_slice(&[x, y, z]);
                        // Analytic normal of the height field.
                        let dzdx = 0.3 * (x * 0.3).cos() * (y * 0.2).cos() * 2.0;
                        let dzdy = -0.2 * (x * 0.3).sin() * (y * 0.2).sin() * 2.0;
                        let len = (dzdx * dzdx + dzdy * dzdy + 1.0).sqrt();
                        m.nrm
                            .extend_from_slice(&[-dzdx / len, -dzdy / len, 1.0 / len]);
                        m.uv.extend_from_slice(&[i as f32 / q as f32, j as f32 / q as f32]);
                        m.col.extend_from_slice(&[
                            (feature * 37 % 256) as u8,
                            (i * 255 / q) as u8,
                            (j * 255 / q) as u8,
                            255,
                        ]);
                        m.fid.push(f32::from(feature));
                        m.fid16.push(feature);
                    }
                }
                let row = (q + 1) as u32;
                for j in 0..q as u32 {
                    for i in 0..q as u32 {
                        let a = base + j * row + i;
                        let b = a + 1;
                        let c = a + row;
                        let d = c + 1;
                        m.idx.extend_from_slice(&[a, b, d, a, d, c]);
                    }
                }
            }
        }
        m
    }

    fn max_extent(pos: &[f32]) -> f64 {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in pos.chunks_exact(3) {
            for c in 0..3 {
                lo[c] = lo[c].min(f64::from(p[c]));
                hi[c] = hi[c].max(f64::from(p[c]));
            }
        }
        (0..3).map(|c| hi[c] - lo[c]).fold(0.0, f64::max)
    }

    const POS_BITS: u8 = 14;
    const NRM_BITS: u8 = 10;
    const UV_BITS: u8 = 12;

    fn attrs(m: &TestMesh) -> Vec<EncodeAttribute<'_>> {
        vec![
            EncodeAttribute::position(&m.pos, POS_BITS),
            EncodeAttribute::normal(&m.nrm, NRM_BITS),
            EncodeAttribute::tex_coord(&m.uv, UV_BITS),
            EncodeAttribute::color_u8(&m.col),
            EncodeAttribute::feature_id_f32(&m.fid),
            EncodeAttribute::feature_id_u16(&m.fid16),
        ]
    }

    /// Canonical rotation of a triangle (smallest index first, winding kept).
    fn canon(t: [u32; 3]) -> [u32; 3] {
        let k = (0..3).min_by_key(|&k| t[k]).unwrap();
        [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
    }

    /// Full check of a decoded grid against its source: every decoded point maps to its
    /// source vertex, all attributes within tolerance (ids, colours exact), same triangles.
    fn check_against_source(m: &TestMesh, enc: &Encoded, d: &DecodedMesh) {
        assert_eq!(d.face_count, m.idx.len() / 3, "face count");
        assert_eq!(d.point_count, enc.point_count);
        assert_eq!(d.face_count, enc.face_count);
        let lattice: HashMap<(i64, i64), usize> = m
            .pos
            .chunks_exact(3)
            .enumerate()
            .map(|(v, p)| {
                let key = (
                    (p[0] / SPACING).round() as i64,
                    (p[1] / SPACING).round() as i64,
                );
                (key, v)
            })
            .collect();
        assert_eq!(lattice.len(), m.pos.len() / 3, "lattice keys unique");
        let a = |k: usize| d.attribute(enc.attribute_ids[k]).expect("attribute by id");
        let (pos, nrm, uv, col, fid, fid16) = (a(0), a(1), a(2), a(3), a(4), a(5));
        assert_eq!(pos.kind, AttributeKind::Position);
        assert_eq!(nrm.kind, AttributeKind::Normal);
        assert_eq!(uv.kind, AttributeKind::TexCoord);
        assert_eq!(col.kind, AttributeKind::Color);
        assert!(col.normalized);
        assert_eq!(fid.kind, AttributeKind::Generic);
        assert_eq!(fid16.kind, AttributeKind::Generic);
        let dpos = pos.values.as_f32().unwrap();
        let dnrm = nrm.values.as_f32().unwrap();
        let duv = uv.values.as_f32().unwrap();
        let AttributeValues::U8(dcol) = &col.values else {
            panic!("colour type {:?}", col.values)
        };
        let dfid = fid.values.as_f32().unwrap();
        let AttributeValues::U16(dfid16) = &fid16.values else {
            panic!("u16 id type")
        };
        let pos_tol = quantization_step(max_extent(&m.pos), POS_BITS) / 2.0 + 1e-4;
        let uv_tol = quantization_step(1.0, UV_BITS) / 2.0 + 1e-6;
        let mut map = vec![usize::MAX; d.point_count];
        let mut max_dev = 0f64;
        for p in 0..d.point_count {
            let q = &dpos[3 * p..3 * p + 3];
            let key = (
                (q[0] / SPACING).round() as i64,
                (q[1] / SPACING).round() as i64,
            );
            let v = *lattice
                .get(&key)
                .expect("decoded point near a source vertex");
            map[p] = v;
            for (c, &qc) in q.iter().enumerate() {
                let dev = (f64::from(qc) - f64::from(m.pos[3 * v + c])).abs();
                max_dev = max_dev.max(dev);
            }
            let dot: f32 = (0..3).map(|c| dnrm[3 * p + c] * m.nrm[3 * v + c]).sum();
            assert!(dot > 0.9995, "normal deviation at {p}: dot {dot}");
            for c in 0..2 {
                let dev = (f64::from(duv[2 * p + c]) - f64::from(m.uv[2 * v + c])).abs();
                assert!(dev <= uv_tol, "uv deviation {dev} > {uv_tol}");
            }
            assert_eq!(&dcol[4 * p..4 * p + 4], &m.col[4 * v..4 * v + 4], "colour");
            assert_eq!(dfid[p], m.fid[v], "f32 feature id must be exact");
            assert_eq!(dfid16[p], m.fid16[v], "u16 feature id must be exact");
        }
        assert!(
            max_dev <= pos_tol,
            "position deviation {max_dev} > {pos_tol}"
        );
        // Same triangles (as source vertex triples, winding kept).
        let mut src: Vec<[u32; 3]> = m
            .idx
            .chunks_exact(3)
            .map(|t| canon([t[0], t[1], t[2]]))
            .collect();
        let mut dec: Vec<[u32; 3]> = d
            .indices
            .chunks_exact(3)
            .map(|t| {
                canon([
                    map[t[0] as usize] as u32,
                    map[t[1] as usize] as u32,
                    map[t[2] as usize] as u32,
                ])
            })
            .collect();
        src.sort_unstable();
        dec.sort_unstable();
        assert!(src == dec, "triangle sets differ");
        // Every source vertex survives.
        let mut seen = vec![false; m.pos.len() / 3];
        for &v in &map {
            seen[v] = true;
        }
        assert!(seen.iter().all(|&s| s), "a source vertex was lost");
        // min/max reported for the accessors are those of the decoded data, and within
        // the tolerance of the source bounds.
        for (k, att) in [pos, nrm, uv, col, fid, fid16].iter().enumerate() {
            assert_eq!(
                enc.attribute_min_max[k],
                att.min_max(),
                "min/max of attribute {k}"
            );
        }
        let (lo, hi) = &enc.attribute_min_max[0];
        for c in 0..3 {
            let slo = m
                .pos
                .iter()
                .skip(c)
                .step_by(3)
                .fold(f32::INFINITY, |a, &b| a.min(b));
            let shi = m
                .pos
                .iter()
                .skip(c)
                .step_by(3)
                .fold(f32::NEG_INFINITY, |a, &b| a.max(b));
            assert!((lo[c] - f64::from(slo)).abs() <= pos_tol);
            assert!((hi[c] - f64::from(shi)).abs() <= pos_tol);
        }
    }

    #[test]
    fn round_trip_edgebreaker_grid() {
        let m = grid(6, 12); // 36 patches x 288 = 10,368 triangles
        let enc = encode_mesh(&attrs(&m), &m.idx, &EncodeOptions::default()).unwrap();
        assert_eq!(enc.attribute_ids.len(), 6);
        let mut ids = enc.attribute_ids.clone();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids.len(), 6, "unique ids are unique");
        let d = decode_mesh(&enc.bytes).unwrap();
        check_against_source(&m, &enc, &d);
        let raw = (m.pos.len() + m.nrm.len() + m.uv.len() + m.fid.len()) * 4
            + m.col.len()
            + m.fid16.len() * 2
            + m.idx.len() * 4;
        assert!(
            enc.bytes.len() * 5 < raw,
            "{} vs raw {raw}",
            enc.bytes.len()
        );
    }

    #[test]
    fn round_trip_all_speeds_and_sequential() {
        let m = grid(3, 10);
        for speed in [0u8, 5, 7, 10] {
            let opts = EncodeOptions {
                encode_speed: speed,
                decode_speed: speed,
                method: EncodingMethod::Edgebreaker,
            };
            let enc = encode_mesh(&attrs(&m), &m.idx, &opts).unwrap();
            check_against_source(&m, &enc, &decode_mesh(&enc.bytes).unwrap());
        }
        let opts = EncodeOptions {
            method: EncodingMethod::Sequential,
            ..EncodeOptions::default()
        };
        let enc = encode_mesh(&attrs(&m), &m.idx, &opts).unwrap();
        let d = decode_mesh(&enc.bytes).unwrap();
        check_against_source(&m, &enc, &d);
        // Sequential coding keeps order: same vertex count and identical indices.
        assert_eq!(d.point_count, m.pos.len() / 3);
        assert_eq!(d.indices, m.idx);
    }

    #[test]
    fn multiple_tex_coords_and_float_colours() {
        let m = grid(2, 6);
        let uv2: Vec<f32> = m.uv.iter().map(|v| 1.0 - v).collect();
        let big_ids: Vec<u32> = m.fid16.iter().map(|&v| u32::from(v) + 100_000).collect();
        let colf: Vec<f32> = m.col.iter().map(|&c| f32::from(c) / 255.0).collect();
        let a = vec![
            EncodeAttribute::position(&m.pos, 16),
            EncodeAttribute::tex_coord(&m.uv, 12),
            EncodeAttribute::tex_coord(&uv2, 0),
            EncodeAttribute::color_f32(&colf, 10),
            EncodeAttribute::generic_u32(&big_ids),
        ];
        let enc = encode_mesh(&a, &m.idx, &EncodeOptions::default()).unwrap();
        let d = decode_mesh(&enc.bytes).unwrap();
        assert_eq!(d.face_count, m.idx.len() / 3);
        let uv2d = d.attribute(enc.attribute_ids[2]).unwrap();
        assert_eq!(uv2d.kind, AttributeKind::TexCoord);
        let ids = d.attribute(enc.attribute_ids[4]).unwrap();
        let AttributeValues::U32(v) = &ids.values else {
            panic!()
        };
        assert!(v.iter().all(|&x| (100_000..100_000 + 4).contains(&x)));
        assert_eq!(enc.attribute_min_max[4], (vec![100_000.0], vec![100_003.0]));
        // Unquantized uv2 values are bit-exact members of the source set.
        let src: std::collections::HashSet<u32> = uv2.iter().map(|v| v.to_bits()).collect();
        assert!(uv2d
            .values
            .as_f32()
            .unwrap()
            .iter()
            .all(|v| src.contains(&v.to_bits())));
    }

    /// Degenerate and non-manifold triangles, unreferenced vertices, and a hard edge
    /// (same position, different normals): the counts reported by `encode_mesh` must be
    /// those of the decoded mesh whatever Draco does with such input.
    #[test]
    fn awkward_topology_counts_match_decoded() {
        let mut m = grid(2, 4);
        let n = (m.pos.len() / 3) as u32;
        // Unreferenced vertex far away (Draco drops it: it must not widen min/max).
        m.pos.extend_from_slice(&[1000.0, 1000.0, 1000.0]);
        m.nrm.extend_from_slice(&[0.0, 0.0, 1.0]);
        m.uv.extend_from_slice(&[0.0, 0.0]);
        m.col.extend_from_slice(&[0, 0, 0, 255]);
        m.fid.push(99.0);
        m.fid16.push(99);
        // Degenerate triangle, a duplicate triangle and a fin on an existing edge.
        m.idx
            .extend_from_slice(&[0, 1, 1, 0, 1, 6, 0, 1, 6, 0, 1, 7]);
        // Hard edge: copy of vertex 2 with a flipped normal, used by one triangle.
        for c in 0..3 {
            m.pos.push(m.pos[6 + c]);
        }
        m.nrm.extend_from_slice(&[0.0, 0.0, -1.0]);
        m.uv.extend_from_slice(&[0.5, 0.5]);
        m.col.extend_from_slice(&[1, 2, 3, 4]);
        m.fid.push(0.0);
        m.fid16.push(0);
        m.idx.extend_from_slice(&[n + 1, 3, 8]);
        for opts in [
            EncodeOptions::default(),
            EncodeOptions {
                method: EncodingMethod::Sequential,
                ..EncodeOptions::default()
            },
        ] {
            let enc = encode_mesh(&attrs(&m), &m.idx, &opts).unwrap();
            let d = decode_mesh(&enc.bytes).unwrap();
            assert_eq!(
                (d.point_count, d.face_count),
                (enc.point_count, enc.face_count)
            );
            eprintln!(
                "{:?}: input {} points {} faces -> decoded {} points {} faces",
                opts.method,
                m.pos.len() / 3,
                m.idx.len() / 3,
                d.point_count,
                d.face_count
            );
            let ids = d.attribute(enc.attribute_ids[5]).unwrap();
            let AttributeValues::U16(v) = &ids.values else {
                panic!()
            };
            assert!(v.iter().all(|&x| x < 4 || x == 99));
            if opts.method == EncodingMethod::Edgebreaker {
                assert!(
                    enc.attribute_min_max[0].1[0] < 999.0,
                    "unreferenced vertex dropped"
                );
            }
        }
    }

    #[test]
    fn invalid_input_is_an_error() {
        let m = grid(1, 2);
        let opts = EncodeOptions::default();
        assert_eq!(
            encode_mesh(&attrs(&m), &[], &opts),
            Err(DracoError::EmptyMesh)
        );
        let empty: [f32; 0] = [];
        assert_eq!(
            encode_mesh(&[EncodeAttribute::position(&empty, 14)], &[0, 0, 0], &opts),
            Err(DracoError::EmptyMesh)
        );
        let no_pos = [EncodeAttribute::normal(&m.nrm, 10)];
        assert!(matches!(
            encode_mesh(&no_pos, &m.idx, &opts),
            Err(DracoError::InvalidInput(_))
        ));
        let mut bad_idx = m.idx.clone();
        bad_idx[4] = 1_000;
        assert!(matches!(
            encode_mesh(&attrs(&m), &bad_idx, &opts),
            Err(DracoError::InvalidInput(_))
        ));
        assert!(matches!(
            encode_mesh(&attrs(&m), &m.idx[..4], &opts),
            Err(DracoError::InvalidInput(_))
        ));
        let short = [
            EncodeAttribute::position(&m.pos, 14),
            EncodeAttribute::normal(&m.nrm[3..], 10),
        ];
        assert!(matches!(
            encode_mesh(&short, &m.idx, &opts),
            Err(DracoError::InvalidInput(_))
        ));
        let mut nan = m.pos.clone();
        nan[5] = f32::NAN;
        assert!(matches!(
            encode_mesh(&[EncodeAttribute::position(&nan, 14)], &m.idx, &opts),
            Err(DracoError::InvalidInput(_))
        ));
        let mut q_int = EncodeAttribute::feature_id_u16(&m.fid16);
        q_int.quantization_bits = 8;
        assert!(matches!(
            encode_mesh(
                &[EncodeAttribute::position(&m.pos, 14), q_int],
                &m.idx,
                &opts
            ),
            Err(DracoError::InvalidInput(_))
        ));
        let fast = EncodeOptions {
            encode_speed: 11,
            ..opts
        };
        assert!(matches!(
            encode_mesh(&attrs(&m), &m.idx, &fast),
            Err(DracoError::InvalidInput(_))
        ));
        // Every allowed bit count encodes (positions, normals and uvs alike).
        for bits in 1..=MAX_QUANTIZATION_BITS {
            let a = [
                EncodeAttribute::position(&m.pos, bits),
                EncodeAttribute::normal(&m.nrm, bits.max(2)),
                EncodeAttribute::tex_coord(&m.uv, bits),
            ];
            let enc = encode_mesh(&a, &m.idx, &opts).unwrap();
            assert_eq!(enc.face_count, m.idx.len() / 3);
        }
        assert!(matches!(
            encode_mesh(
                &[EncodeAttribute::position(&m.pos, MAX_QUANTIZATION_BITS + 1)],
                &m.idx,
                &opts
            ),
            Err(DracoError::InvalidInput(_))
        ));
    }

    #[test]
    fn garbage_to_decoder_is_an_error() {
        assert!(matches!(decode_mesh(&[]), Err(DracoError::Decode(_))));
        let mut rng = Lcg(42);
        for round in 0..400 {
            let len = rng.below(3000);
            let mut bytes: Vec<u8> = (0..len).map(|_| rng.next_u32() as u8).collect();
            // Half of them start with a plausible Draco header (magic, v2.2, mesh, method).
            if round % 2 == 0 && bytes.len() > 11 {
                bytes[..5].copy_from_slice(b"DRACO");
                bytes[5] = 2;
                bytes[6] = 2;
                bytes[7] = 1;
                bytes[8] = (round / 2 % 2) as u8;
            }
            match decode_mesh(&bytes) {
                Err(_) => {}
                Ok(d) => {
                    // Should not happen, but if Draco accepts it the result must be sane.
                    assert!(d.indices.iter().all(|&i| (i as usize) < d.point_count));
                }
            }
        }
    }

    #[test]
    fn truncated_and_corrupted_streams() {
        let m = grid(3, 8);
        for method in [EncodingMethod::Edgebreaker, EncodingMethod::Sequential] {
            let opts = EncodeOptions {
                method,
                ..EncodeOptions::default()
            };
            let enc = encode_mesh(&attrs(&m), &m.idx, &opts).unwrap();
            let full = enc.bytes.len();
            let step = (full / 300).max(1);
            let mut cuts: Vec<usize> = (0..full.min(64)).collect();
            cuts.extend((64..full).step_by(step));
            cuts.push(full - 1);
            for cut in cuts {
                let r = decode_mesh(&enc.bytes[..cut]);
                assert!(r.is_err(), "{method:?}: truncated to {cut}/{full} decoded");
            }
            // Random corruption: any outcome but a crash; a success must be self-consistent.
            let mut rng = Lcg(7);
            for _ in 0..300 {
                let mut b = enc.bytes.clone();
                for _ in 0..1 + rng.below(4) {
                    let at = rng.below(b.len());
                    b[at] ^= 1 << rng.below(8);
                }
                if let Ok(d) = decode_mesh(&b) {
                    assert!(d.indices.iter().all(|&i| (i as usize) < d.point_count));
                    assert!(d
                        .attributes
                        .iter()
                        .all(|a| a.values.len() == d.point_count * usize::from(a.components)));
                }
            }
        }
    }

    #[test]
    fn position_bits_helper() {
        assert_eq!(position_bits_for(100.0, 0.005), 14);
        assert!(quantization_step(100.0, 14) / 2.0 <= 0.005);
        assert!(quantization_step(100.0, 13) / 2.0 > 0.005);
        assert_eq!(position_bits_for(1.0, 1.0), 1);
        assert_eq!(position_bits_for(0.0, 0.001), 1);
        assert_eq!(position_bits_for(1e6, 1e-9), MAX_QUANTIZATION_BITS);
        assert_eq!(position_bits_for(100.0, 0.0), MAX_QUANTIZATION_BITS);
        assert_eq!(position_bits_for(100.0, f64::NAN), MAX_QUANTIZATION_BITS);
        assert_eq!(
            position_bits_for(f64::INFINITY, 0.01),
            MAX_QUANTIZATION_BITS
        );
        for (extent, err) in [(10.0, 0.001), (250.0, 0.01), (3000.0, 0.05), (1.0, 1e-4)] {
            let b = position_bits_for(extent, err);
            assert!(quantization_step(extent, b) / 2.0 <= err);
            assert!(b == 1 || quantization_step(extent, b - 1) / 2.0 > err);
        }
        // The promised bound holds through Draco: encode with the chosen bits, measure.
        let m = grid(4, 8);
        let extent = max_extent(&m.pos);
        for max_err in [0.05, 0.01, 0.002] {
            let bits = position_bits_for(extent, max_err);
            let enc = encode_mesh(
                &[EncodeAttribute::position(&m.pos, bits)],
                &m.idx,
                &EncodeOptions {
                    method: EncodingMethod::Sequential,
                    ..EncodeOptions::default()
                },
            )
            .unwrap();
            let d = decode_mesh(&enc.bytes).unwrap();
            let p = d.attributes[0].values.as_f32().unwrap();
            let dev = p
                .iter()
                .zip(&m.pos)
                .map(|(a, b)| (f64::from(*a) - f64::from(*b)).abs())
                .fold(0.0, f64::max);
            assert!(
                dev <= max_err + 1e-5,
                "bits {bits}: deviation {dev} > {max_err}"
            );
        }
    }

    /// Writes fixtures for the independent decoder check
    /// (`tests/python/test_draco_independent.py`) into `$BIMTILES_DRACO_FIXTURE_DIR`; a no-op
    /// without that variable. Layout: `manifest.json` plus, per case, `<name>.drc` (Draco
    /// stream), `<name>.pos.f32` (source positions, little-endian xyz f32) and
    /// `<name>.idx.u32` (source triangle indices, little-endian u32).
    #[test]
    fn write_independent_check_fixtures() {
        let Some(dir) = std::env::var_os("BIMTILES_DRACO_FIXTURE_DIR") else {
            eprintln!("BIMTILES_DRACO_FIXTURE_DIR not set: no fixtures written");
            return;
        };
        let dir = std::path::PathBuf::from(dir);
        std::fs::create_dir_all(&dir).unwrap();
        let big = grid(8, 16); // 32,768 triangles
        let small = grid(2, 5);
        let speed = |s: u8| EncodeOptions {
            encode_speed: s,
            decode_speed: s,
            method: EncodingMethod::Edgebreaker,
        };
        let sequential = EncodeOptions {
            method: EncodingMethod::Sequential,
            ..EncodeOptions::default()
        };
        let cases: Vec<(&str, &TestMesh, EncodeOptions)> = vec![
            ("grid_default", &big, EncodeOptions::default()),
            ("grid_speed0", &big, speed(0)),
            ("grid_speed10", &big, speed(10)),
            ("grid_sequential", &big, sequential),
            ("small_default", &small, EncodeOptions::default()),
        ];
        let mut entries = Vec::new();
        for (name, m, opts) in cases {
            let a = attrs(m);
            let enc = encode_mesh(&a, &m.idx, &opts).unwrap();
            std::fs::write(dir.join(format!("{name}.drc")), &enc.bytes).unwrap();
            let pos: Vec<u8> = m.pos.iter().flat_map(|v| v.to_le_bytes()).collect();
            std::fs::write(dir.join(format!("{name}.pos.f32")), pos).unwrap();
            let idx: Vec<u8> = m.idx.iter().flat_map(|v| v.to_le_bytes()).collect();
            std::fs::write(dir.join(format!("{name}.idx.u32")), idx).unwrap();
            let extent = max_extent(&m.pos);
            let attributes: Vec<serde_json::Value> = a
                .iter()
                .enumerate()
                .map(|(k, at)| {
                    let dtype = match at.data {
                        AttributeData::F32(_) => "f32",
                        AttributeData::U8(_) => "u8",
                        AttributeData::U16(_) => "u16",
                        AttributeData::U32(_) => "u32",
                    };
                    serde_json::json!({
                        "unique_id": enc.attribute_ids[k],
                        "kind": at.kind.name(),
                        "components": at.components,
                        "dtype": dtype,
                        "normalized": at.normalized,
                        "quantization_bits": at.quantization_bits,
                        "min": enc.attribute_min_max[k].0,
                        "max": enc.attribute_min_max[k].1,
                    })
                })
                .collect();
            entries.push(serde_json::json!({
                "name": name,
                "drc": format!("{name}.drc"),
                "encode_speed": opts.encode_speed,
                "decode_speed": opts.decode_speed,
                "method": format!("{:?}", opts.method),
                "point_count": enc.point_count,
                "face_count": enc.face_count,
                "attributes": attributes,
                "feature_id_unique_ids": [enc.attribute_ids[4], enc.attribute_ids[5]],
                "source": {
                    "positions": format!("{name}.pos.f32"),
                    "indices": format!("{name}.idx.u32"),
                    "vertex_count": m.pos.len() / 3,
                    "face_count": m.idx.len() / 3,
                    "feature_ids": m.fid16.iter().copied().collect::<std::collections::BTreeSet<_>>(),
                },
                // Max allowed |decoded - source| per position component: half a step plus
                // f32 rounding.
                "position_tolerance": quantization_step(extent, POS_BITS) / 2.0 + 1e-4,
            }));
        }
        let manifest = serde_json::json!({ "version": 1, "cases": entries });
        std::fs::write(
            dir.join("manifest.json"),
            serde_json::to_string_pretty(&manifest).unwrap(),
        )
        .unwrap();
        eprintln!("wrote Draco fixtures to {}", dir.display());
    }

    /// Loads every mesh primitive of a GLB, merged into one mesh (node transforms ignored,
    /// which is right for these files: world coordinates are baked in). Missing normals
    /// or uvs are filled with constants when another primitive has them. Returns
    /// (positions, normals, uvs or empty, per-vertex node id, indices).
    #[allow(clippy::type_complexity)]
    fn load_glb(path: &std::path::Path) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<u16>, Vec<u32>) {
        let bytes = std::fs::read(path).unwrap();
        let g = gltf::Gltf::from_slice_without_validation(&bytes).unwrap();
        let blob = g.blob.as_deref();
        let (mut pos, mut nrm, mut uv, mut fid, mut idx) = (vec![], vec![], vec![], vec![], vec![]);
        let mut any_uv = false;
        for (mi, mesh) in g.meshes().enumerate() {
            for prim in mesh.primitives() {
                let r = prim.reader(|_| blob);
                let Some(p) = r.read_positions() else {
                    continue;
                };
                let base = (pos.len() / 3) as u32;
                let p: Vec<[f32; 3]> = p.collect();
                let n = p.len();
                pos.extend(p.iter().flatten());
                match r.read_normals() {
                    Some(ns) => nrm.extend(ns.flatten()),
                    None => nrm.extend(std::iter::repeat_n([0.0f32, 0.0, 1.0], n).flatten()),
                }
                match r.read_tex_coords(0) {
                    Some(t) => {
                        any_uv = true;
                        uv.extend(t.into_f32().flatten())
                    }
                    None => uv.extend(std::iter::repeat_n(0.0f32, 2 * n)),
                }
                fid.extend(std::iter::repeat_n((mi % 65536) as u16, n));
                match r.read_indices() {
                    Some(i) => idx.extend(i.into_u32().map(|v| v + base)),
                    None => idx.extend(base..base + n as u32),
                }
            }
        }
        if !any_uv {
            uv.clear();
        }
        (pos, nrm, uv, fid, idx)
    }

    /// Throughput and ratio table. Run with
    /// `cargo test --release --lib measure_throughput -- --ignored --nocapture`
    /// (`BIMTILES_DATA_DIR` = folder of the real `.glb` models, default `../shared/data`).
    #[test]
    #[ignore]
    fn measure_throughput() {
        use std::time::Instant;
        let data_dir = std::env::var_os("BIMTILES_DATA_DIR")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| {
                std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
            });
        type Model = (String, Vec<f32>, Vec<f32>, Vec<f32>, Vec<u16>, Vec<u32>);
        let mut models: Vec<Model> = vec![];
        let g = grid(1, 708);
        let fid = vec![0u16; g.pos.len() / 3];
        models.push(("grid 708x708".into(), g.pos, g.nrm, g.uv, fid, g.idx));
        let mut files: Vec<_> = std::fs::read_dir(&data_dir)
            .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default();
        files.retain(|p| p.extension().is_some_and(|e| e == "glb"));
        files.sort();
        for f in files {
            let (p, n, u, i, x) = load_glb(&f);
            models.push((
                f.file_stem().unwrap().to_string_lossy().into(),
                p,
                n,
                u,
                i,
                x,
            ));
        }
        println!("| model | tris | verts in->out | speed | encode s | Mtri/s | decode s | encode_mesh s | bytes | ratio | B/tri | +fid bytes |");
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
        for (name, pos, nrm, uv, fid, idx) in &models {
            let tris = idx.len() / 3;
            let mut a = vec![
                EncodeAttribute::position(pos, 14),
                EncodeAttribute::normal(nrm, 10),
            ];
            if !uv.is_empty() {
                a.push(EncodeAttribute::tex_coord(uv, 12));
            }
            let raw = (pos.len() + nrm.len() + uv.len() + idx.len()) * 4;
            for speed in [0u8, 5, 7, 10] {
                let opts = EncodeOptions {
                    encode_speed: speed,
                    decode_speed: speed,
                    method: EncodingMethod::Edgebreaker,
                };
                let reps = if tris < 100_000 { 5 } else { 1 };
                let t = Instant::now();
                let mut r = None;
                for _ in 0..reps {
                    r = Some(encode_mesh_fast(&a, idx, &opts).unwrap());
                }
                let enc_s = t.elapsed().as_secs_f64() / reps as f64;
                let r = r.unwrap();
                let t = Instant::now();
                for _ in 0..reps {
                    decode_mesh(&r.bytes).unwrap();
                }
                let dec_s = t.elapsed().as_secs_f64() / reps as f64;
                let t = Instant::now();
                let full = encode_mesh(&a, idx, &opts).unwrap();
                let full_s = t.elapsed().as_secs_f64();
                assert_eq!(full.bytes, r.bytes);
                let mut af = a.clone();
                af.push(EncodeAttribute::feature_id_u16(fid));
                let with_fid = encode_mesh_fast(&af, idx, &opts).unwrap().bytes.len();
                println!(
                    "| {name} | {tris} | {}->{} | {speed} | {enc_s:.3} | {:.2} | {dec_s:.3} | {full_s:.3} | {} | {:.4} ({:.1}x) | {:.2} | {with_fid} |",
                    pos.len() / 3,
                    r.point_count,
                    tris as f64 / enc_s / 1e6,
                    r.bytes.len(),
                    r.bytes.len() as f64 / raw as f64,
                    raw as f64 / r.bytes.len() as f64,
                    r.bytes.len() as f64 / tris as f64,
                );
            }
        }
    }
}
