//! Draco mesh compression, for glTF tiles and glTF input.
//!
//! Implements both sides of the glTF extension `KHR_draco_mesh_compression`
//! (Khronos, ratified; Draco bitstream 2.2; spec copy in
//! `shared/specs/gltf-ext/extensions/2.0/Khronos/KHR_draco_mesh_compression/`): the encoder
//! writes tiles, the decoder reads compressed input (`ingest::gltf`) and checks our own output. The work is done by Google's Draco C++ library (Debian
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

use thiserror::Error;

mod ffi;
#[cfg(test)]
mod fixtures;
#[cfg(test)]
mod tests;

use ffi::{EncodedHandle, ErrBuf, MeshHandle};

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
    /// Default speed (encoder and decoder): nearly the size of Draco's own default 5, and
    /// faster to encode and decode; faster speeds cost much size, slower ones time (and, on
    /// building models, size too). Chosen by measurement (`cargo bench --bench draco`):
    /// docs/benchmarks.md.
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
    /// The whole decoded mesh: the triangle and point order a client draws.
    pub decoded_mesh: DecodedMesh,
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
/// encoder's time and memory grow as 2^bits (docs/benchmarks.md).
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
        decoded_mesh: decoded,
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
