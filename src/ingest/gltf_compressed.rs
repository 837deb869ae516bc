//! Compressed and transformed glTF data, turned back into plain accessor data for the reader:
//! `EXT_meshopt_compression` bufferViews (the `meshopt` crate's decoders and filters),
//! `KHR_draco_mesh_compression` primitives (our libdraco binding, [`crate::draco`]) and
//! `KHR_texture_transform` on base-colour textures (applied to the UVs). `KHR_mesh_quantization`
//! needs nothing here: the accessor reader dequantizes normalized integers and the node
//! transforms carry the rest.

use super::gltf_index::MeshoptView;
use crate::draco::{AttributeValues, DecodedAttribute};

/// Why an `EXT_meshopt_compression` bufferView cannot be decoded.
#[derive(Debug, thiserror::Error)]
pub enum MeshoptError {
    #[error("compressed bytes (offset {offset}, length {length}) point past the end of buffer {buffer} ({buffer_bytes} bytes)")]
    OutOfRange {
        buffer: usize,
        offset: usize,
        length: usize,
        buffer_bytes: usize,
    },
    #[error("mode {mode} with byteStride {stride} is not allowed")]
    BadStride { mode: String, stride: usize },
    #[error("unknown mode {0}")]
    UnknownMode(String),
    #[error("filter {filter} with byteStride {stride} is not allowed")]
    BadFilter { filter: String, stride: usize },
    #[error("count {count} x byteStride {stride} overflows")]
    TooLarge { count: usize, stride: usize },
    #[error("mode TRIANGLES with count {0}, which is not a multiple of 3")]
    PartialTriangle(usize),
    #[error("meshopt decoding failed")]
    Decode(#[source] meshopt::Error),
}

/// Decodes one compressed bufferView from `source` (its extension's buffer): the
/// `count * byteStride` bytes the view stands for.
pub fn decode_meshopt_view(view: &MeshoptView, source: &[u8]) -> Result<Vec<u8>, MeshoptError> {
    let (count, stride) = (view.count, view.byte_stride);
    let end = view.byte_offset.checked_add(view.byte_length);
    let encoded = match end {
        Some(end) if end <= source.len() => &source[view.byte_offset..end],
        _ => {
            return Err(MeshoptError::OutOfRange {
                buffer: view.buffer,
                offset: view.byte_offset,
                length: view.byte_length,
                buffer_bytes: source.len(),
            })
        }
    };
    let bad_stride = || MeshoptError::BadStride {
        mode: view.mode.clone(),
        stride,
    };
    // The decoders allocate count x stride bytes: refuse a count the compressed bytes cannot
    // hold before allocating (meshopt needs at least a bit per vertex byte group).
    let decoded_bytes = count
        .checked_mul(stride)
        .filter(|&n| n <= encoded.len().saturating_mul(1024).max(1 << 20))
        .ok_or(MeshoptError::TooLarge { count, stride })?;
    let bytes = match (view.mode.as_str(), stride) {
        ("ATTRIBUTES", s) if s % 4 == 0 && (4..=256).contains(&s) => {
            decode_vertices(encoded, count, s / 4)?
        }
        ("ATTRIBUTES", _) => return Err(bad_stride()),
        // The spec's rule, which meshoptimizer asserts (an abort, not an error): checked first.
        ("TRIANGLES", _) if count % 3 != 0 => return Err(MeshoptError::PartialTriangle(count)),
        ("TRIANGLES", 2) => bytes_of(
            meshopt::encoding::decode_index_buffer::<u16>(encoded, count)
                .map_err(MeshoptError::Decode)?,
        ),
        ("TRIANGLES", 4) => bytes_of(
            meshopt::encoding::decode_index_buffer::<u32>(encoded, count)
                .map_err(MeshoptError::Decode)?,
        ),
        ("INDICES", 2) => bytes_of(
            meshopt::encoding::decode_index_sequence::<u16>(encoded, count)
                .map_err(MeshoptError::Decode)?,
        ),
        ("INDICES", 4) => bytes_of(
            meshopt::encoding::decode_index_sequence::<u32>(encoded, count)
                .map_err(MeshoptError::Decode)?,
        ),
        ("TRIANGLES" | "INDICES", _) => return Err(bad_stride()),
        (other, _) => return Err(MeshoptError::UnknownMode(other.to_string())),
    };
    debug_assert_eq!(bytes.len(), decoded_bytes);
    apply_filter(view.filter.as_deref().unwrap_or("NONE"), stride, bytes)
}

fn bytes_of<T: bytemuck::Pod>(v: Vec<T>) -> Vec<u8> {
    bytemuck::cast_slice(&v).to_vec()
}

/// `decode_vertex_buffer` for a vertex of `words` 32-bit words (the stride is a type parameter
/// of the crate's decoder, so each allowed stride is one instance).
fn decode_vertices(encoded: &[u8], count: usize, words: usize) -> Result<Vec<u8>, MeshoptError> {
    /// One vertex of `N` words (std gives `Default` to arrays of up to 32 only).
    #[derive(Clone, Copy)]
    struct Vertex<const N: usize>([u32; N]);
    impl<const N: usize> Default for Vertex<N> {
        fn default() -> Self {
            Vertex([0; N])
        }
    }
    fn vertex_bytes<const N: usize>(v: Vec<Vertex<N>>) -> Vec<u8> {
        v.iter()
            .flat_map(|w| w.0)
            .flat_map(u32::to_ne_bytes)
            .collect()
    }
    macro_rules! by_words {
        ($($n:literal)*) => {
            match words {
                $($n => meshopt::encoding::decode_vertex_buffer::<Vertex<$n>>(encoded, count)
                    .map(vertex_bytes),)*
                _ => unreachable!("stride checked by the caller"),
            }
        };
    }
    by_words!(1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24 25 26 27 28 29 30
        31 32 33 34 35 36 37 38 39 40 41 42 43 44 45 46 47 48 49 50 51 52 53 54 55 56 57 58 59 60
        61 62 63 64)
    .map_err(MeshoptError::Decode)
}

/// Undoes the extension's filter on decoded vertex bytes, in place.
fn apply_filter(filter: &str, stride: usize, bytes: Vec<u8>) -> Result<Vec<u8>, MeshoptError> {
    use meshopt::encoding as enc;
    fn through<T: bytemuck::Pod>(bytes: Vec<u8>, f: impl FnOnce(&mut [T])) -> Vec<u8> {
        // Copied into typed (aligned) storage: a byte vector need not be aligned for i16/u32.
        let mut typed: Vec<T> = bytemuck::pod_collect_to_vec(&bytes);
        f(&mut typed);
        bytes_of(typed)
    }
    Ok(match (filter, stride) {
        ("NONE", _) => bytes,
        ("OCTAHEDRAL", 4) => through::<[i8; 4]>(bytes, enc::decode_filter_oct),
        ("OCTAHEDRAL", 8) => through::<[i16; 4]>(bytes, enc::decode_filter_oct),
        ("QUATERNION", 8) => through::<[i16; 4]>(bytes, enc::decode_filter_quat),
        ("EXPONENTIAL", s) if s % 4 == 0 => through::<[u32; 1]>(bytes, enc::decode_filter_exp),
        ("COLOR", 4) => through::<[u8; 4]>(bytes, enc::decode_filter_color),
        ("COLOR", 8) => through::<[u16; 4]>(bytes, enc::decode_filter_color),
        (f, s) => {
            return Err(MeshoptError::BadFilter {
                filter: f.to_string(),
                stride: s,
            })
        }
    })
}

/// A decoded Draco attribute as `N`-component f32 vectors, normalized as its glTF accessor says
/// (Draco gives integer attributes as stored; floats come back dequantized).
pub fn draco_vectors<const N: usize>(
    attribute: &DecodedAttribute,
    normalized: bool,
) -> Option<Vec<[f32; N]>> {
    let components = usize::from(attribute.components);
    if components < N {
        return None;
    }
    let scale = match (&attribute.values, normalized) {
        (_, false) | (AttributeValues::F32(_), _) => 1.0,
        (AttributeValues::U8(_), true) => 1.0 / 255.0,
        (AttributeValues::I8(_), true) => 1.0 / 127.0,
        (AttributeValues::U16(_), true) => 1.0 / 65535.0,
        (AttributeValues::I16(_), true) => 1.0 / 32767.0,
        (AttributeValues::U32(_), true) => 1.0 / u32::MAX as f64,
        (AttributeValues::I32(_), true) => 1.0 / i32::MAX as f64,
    };
    let signed = matches!(
        attribute.values,
        AttributeValues::I8(_) | AttributeValues::I16(_) | AttributeValues::I32(_)
    );
    let points = attribute.values.len() / components;
    let mut out = Vec::with_capacity(points);
    for p in 0..points {
        let mut v = [0f32; N];
        for (k, x) in v.iter_mut().enumerate() {
            let value = attribute.values.get_f64(p * components + k) * scale;
            // glTF: a signed normalized value is max(c / (2^(n-1) - 1), -1).
            *x = if normalized && signed {
                value.max(-1.0)
            } else {
                value
            } as f32;
        }
        out.push(v);
    }
    Some(out)
}

/// A `KHR_texture_transform`: UV' = offset + rotation(scale * UV), as a 2x3 matrix (rows).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UvTransform(pub [[f64; 3]; 2]);

impl UvTransform {
    /// From the extension's JSON object (`offset`, `rotation` in radians, `scale`); `None` when
    /// it is the identity.
    pub fn from_json(ext: &serde_json::Value) -> Option<UvTransform> {
        let pair = |key: &str, default: [f64; 2]| -> [f64; 2] {
            ext.get(key)
                .and_then(|v| v.as_array())
                .and_then(|a| Some([a.first()?.as_f64()?, a.get(1)?.as_f64()?]))
                .unwrap_or(default)
        };
        let [ox, oy] = pair("offset", [0.0, 0.0]);
        let [sx, sy] = pair("scale", [1.0, 1.0]);
        let r = ext.get("rotation").and_then(|v| v.as_f64()).unwrap_or(0.0);
        let (sin, cos) = r.sin_cos();
        // The extension's matrix: translation * rotation * scale, rotation [[c, s], [-s, c]].
        let m = [[cos * sx, sin * sy, ox], [-sin * sx, cos * sy, oy]];
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        (m != identity && m.iter().flatten().all(|x| x.is_finite())).then_some(UvTransform(m))
    }

    pub fn apply(&self, uv: [f32; 2]) -> [f32; 2] {
        let [a, b] = self.0;
        let (u, v) = (f64::from(uv[0]), f64::from(uv[1]));
        [
            (a[0] * u + a[1] * v + a[2]) as f32,
            (b[0] * u + b[1] * v + b[2]) as f32,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(
        mode: &str,
        stride: usize,
        count: usize,
        len: usize,
        filter: Option<&str>,
    ) -> MeshoptView {
        MeshoptView {
            filter: filter.map(str::to_string),
            ..MeshoptView::at_start(mode, stride, count, len)
        }
    }

    #[test]
    fn meshopt_vertices_and_indices_round_trip() {
        let vertices: Vec<[u16; 6]> = (0..50u16).map(|i| [i, i * 2, i * 3, 7, i, 0]).collect();
        let encoded = meshopt::encoding::encode_vertex_buffer(&vertices).unwrap();
        let decoded =
            decode_meshopt_view(&view("ATTRIBUTES", 12, 50, encoded.len(), None), &encoded)
                .unwrap();
        assert_eq!(decoded, bytemuck::cast_slice::<_, u8>(&vertices));

        let indices: Vec<u32> = vec![0, 1, 2, 2, 1, 3, 3, 1, 4];
        let encoded = meshopt::encoding::encode_index_buffer(&indices, 5).unwrap();
        let decoded =
            decode_meshopt_view(&view("TRIANGLES", 4, 9, encoded.len(), None), &encoded).unwrap();
        assert_eq!(decoded, bytemuck::cast_slice::<_, u8>(&indices));
    }

    #[test]
    fn meshopt_errors_are_typed() {
        let e = decode_meshopt_view(&view("ATTRIBUTES", 6, 1, 4, None), &[0; 4]).unwrap_err();
        assert!(matches!(e, MeshoptError::BadStride { .. }), "{e}");
        let e = decode_meshopt_view(&view("ATTRIBUTES", 4, 1, 8, None), &[0; 4]).unwrap_err();
        assert!(matches!(e, MeshoptError::OutOfRange { .. }), "{e}");
        let e = decode_meshopt_view(&view("MAGIC", 4, 1, 4, None), &[0; 4]).unwrap_err();
        assert!(matches!(e, MeshoptError::UnknownMode(_)), "{e}");
        let e = decode_meshopt_view(&view("ATTRIBUTES", 4, 3, 4, None), &[0; 4]).unwrap_err();
        assert!(matches!(e, MeshoptError::Decode(_)), "{e}");
        let e = decode_meshopt_view(&view("ATTRIBUTES", 4, 1 << 40, 4, None), &[0; 4]).unwrap_err();
        assert!(matches!(e, MeshoptError::TooLarge { .. }), "{e}");
        // Found by the fuzzer: meshoptimizer's index decoder aborts the process on this.
        let e = decode_meshopt_view(&view("TRIANGLES", 2, 4, 4, None), &[0; 4]).unwrap_err();
        assert!(matches!(e, MeshoptError::PartialTriangle(4)), "{e}");
    }

    #[test]
    fn texture_transform_follows_the_extension() {
        let t = UvTransform::from_json(&serde_json::json!({
            "offset": [0.5, 0.25], "scale": [2.0, 4.0]
        }))
        .unwrap();
        assert_eq!(t.apply([1.0, 1.0]), [2.5, 4.25]);
        // Rotation by 90 degrees: (1, 0) -> (0, -1) in the extension's convention.
        let r =
            UvTransform::from_json(&serde_json::json!({"rotation": std::f64::consts::FRAC_PI_2}))
                .unwrap();
        let p = r.apply([1.0, 0.0]);
        assert!(
            (p[0] - 0.0).abs() < 1e-6 && (p[1] + 1.0).abs() < 1e-6,
            "{p:?}"
        );
        assert_eq!(UvTransform::from_json(&serde_json::json!({})), None);
    }
}
