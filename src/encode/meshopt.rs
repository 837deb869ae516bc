//! `EXT_meshopt_compression` streams for tile geometry (the extension's README, "Compression
//! modes"): vertex attributes in `ATTRIBUTES` mode (bitstream version 0, the one the extension
//! defines) and triangle lists in `TRIANGLES` mode, encoded with meshoptimizer (the `meshopt`
//! crate). Unlike Draco, clients decode these on the main thread as the data arrives (CesiumJS:
//! `GltfBufferViewLoader`), with no worker task per primitive, and the streams are laid out for
//! the server's gzip to shrink further.
//!
//! The codecs work best on vertices in the order the triangles first use them, triangles in
//! vertex-cache order: [`optimize_order`] reorders a primitive so.

use crate::partition::content::ContentPrimitive;

/// The vertex codec version `EXT_meshopt_compression` defines (header byte `0xa0`); later
/// meshoptimizer versions default to version 1, which only `KHR_meshopt_compression` allows.
const VERTEX_CODEC_VERSION: i32 = 0;

/// Why a stream could not be encoded (the callers' layouts make these unreachable; they are
/// errors rather than panics all the same).
#[derive(Debug, thiserror::Error)]
pub enum MeshoptEncodeError {
    #[error("a meshopt vertex stride of {0} bytes is not a multiple of 4 up to 256")]
    Stride(usize),
    #[error("meshopt encoding failed")]
    Encode(#[source] meshopt::Error),
}

/// Encodes `count` elements of `stride` bytes (`bytes.len() == count * stride`) as one
/// `ATTRIBUTES` stream.
pub fn encode_attributes(bytes: &[u8], stride: usize) -> Result<Vec<u8>, MeshoptEncodeError> {
    if stride == 0 || stride % 4 != 0 || stride > 256 || bytes.len() % stride != 0 {
        return Err(MeshoptEncodeError::Stride(stride));
    }
    /// One element of `N` bytes: the crate takes the stride from the element type.
    #[derive(Clone, Copy)]
    #[repr(C)]
    struct Element<const N: usize>([u8; N]);
    fn encode<const N: usize>(bytes: &[u8]) -> Result<Vec<u8>, meshopt::Error> {
        let elements: Vec<Element<N>> = bytes
            .chunks_exact(N)
            .map(|c| Element(c.try_into().expect("chunks of N")))
            .collect();
        meshopt::encoding::encode_vertex_buffer_level(&elements, 2, Some(VERTEX_CODEC_VERSION))
    }
    // Tile attributes are 4 (octahedral normals, u16 UVs, u8 colours, f32 feature IDs), 8 (i16
    // positions padded, f32 UVs), 12 (f32 positions) or 16 bytes (f32 colours) per vertex.
    match stride {
        4 => encode::<4>(bytes),
        8 => encode::<8>(bytes),
        12 => encode::<12>(bytes),
        16 => encode::<16>(bytes),
        _ => return Err(MeshoptEncodeError::Stride(stride)),
    }
    .map_err(MeshoptEncodeError::Encode)
}

/// Encodes a triangle list over `vertex_count` vertices as one `TRIANGLES` stream (index codec
/// version 1, header `0xe1`; decoded to 2- or 4-byte indices as the bufferView's stride says).
pub fn encode_triangles(
    indices: &[u32],
    vertex_count: usize,
) -> Result<Vec<u8>, MeshoptEncodeError> {
    meshopt::encoding::encode_index_buffer(indices, vertex_count)
        .map_err(MeshoptEncodeError::Encode)
}

/// The triangle list a client decodes from a `TRIANGLES` stream of `index_count` indices: the
/// same triangles in the same order, each possibly rotated (the codec may start a triangle at
/// another corner, keeping its winding). What is written per triangle corner or edge must
/// follow this order, not the encoder's input.
pub fn decode_triangles(
    encoded: &[u8],
    index_count: usize,
) -> Result<Vec<u32>, MeshoptEncodeError> {
    meshopt::encoding::decode_index_buffer::<u32>(encoded, index_count)
        .map_err(MeshoptEncodeError::Encode)
}

/// Float vectors through the `EXPONENTIAL` filter.
pub struct ExpFiltered<const N: usize> {
    /// The filter's words (the stream's elements before the attribute codec).
    pub words: Vec<[u32; N]>,
    /// What they decode to: what clients draw.
    pub drawn: Vec<[f32; N]>,
}

/// Mantissa bits the `EXPONENTIAL` filter may use (its README: 1 to 24).
const EXP_BITS: std::ops::RangeInclusive<i32> = 1..=24;

/// Float vectors (positions of a tile too wide for 16-bit positions within the error bound,
/// UVs that tile beyond [0, 1]) through the `EXPONENTIAL` filter: each component a mantissa over
/// one exponent per component, the fewest mantissa bits that keep every decoded component within
/// `max_error` of its value; `None` when even 24 bits miss the bound.
pub fn exp_filtered<const N: usize>(values: &[[f32; N]], max_error: f64) -> Option<ExpFiltered<N>> {
    use meshopt::encoding::{decode_filter_exp, encode_filter_exp, EncodeExpMode};
    let try_bits = |bits: i32| {
        let words = encode_filter_exp(values, bits, EncodeExpMode::SharedComponent);
        let mut decoded = words.clone();
        decode_filter_exp(&mut decoded);
        let drawn: Vec<[f32; N]> = decoded.iter().map(|w| w.map(f32::from_bits)).collect();
        let within = values
            .iter()
            .zip(&drawn)
            .all(|(v, d)| (0..N).all(|k| ((v[k] as f64) - (d[k] as f64)).abs() <= max_error));
        within.then_some(ExpFiltered { words, drawn })
    };
    // The error falls as bits grow: the fewest that meet the bound, by bisection.
    let (mut lo, mut hi) = (*EXP_BITS.start(), *EXP_BITS.end());
    let mut best = try_bits(hi)?;
    while lo < hi {
        let mid = (lo + hi) / 2;
        match try_bits(mid) {
            Some(found) => {
                best = found;
                hi = mid;
            }
            None => lo = mid + 1,
        }
    }
    Some(best)
}

/// Bits per component of octahedral normals: 8, the i8 normals' precision (about a degree).
const NORMAL_OCT_BITS: i32 = 8;

/// Unit normals through the `OCTAHEDRAL` filter: four i8 per normal (the stream's elements;
/// clients decode them to a normalized i8 vector and a fourth byte they ignore). Two meaningful
/// components instead of three compress better than i8 x, y, z.
pub fn octahedral_normals(normals: &[[f32; 3]]) -> Vec<[i8; 4]> {
    let padded: Vec<[f32; 4]> = normals.iter().map(|n| [n[0], n[1], n[2], 0.0]).collect();
    meshopt::encoding::encode_filter_oct::<i8>(&padded, NORMAL_OCT_BITS)
}

/// `p` with its triangles in vertex-cache order and its vertices in first-use order (vertices
/// no triangle uses are dropped): what the codecs compress best. The same triangles and vertices.
pub fn optimize_order(p: &ContentPrimitive) -> ContentPrimitive {
    let n = p.positions.len();
    let cache_ordered = meshopt::optimize::optimize_vertex_cache(&p.indices, n);
    // First-use order (meshoptimizer's vertex fetch remap; the crate's wrapper truncates its
    // table when some vertex is unused, so it is written out here): u32::MAX for unused ones.
    let mut remap = vec![u32::MAX; n];
    let mut kept = 0;
    for &i in &cache_ordered {
        if remap[i as usize] == u32::MAX {
            remap[i as usize] = kept as u32;
            kept += 1;
        }
    }
    fn permute<T: Copy>(values: &[T], remap: &[u32], kept: usize) -> Vec<T> {
        if values.is_empty() {
            return Vec::new();
        }
        let mut out: Vec<Option<T>> = vec![None; kept];
        for (old, &new) in remap.iter().enumerate() {
            if new != u32::MAX {
                out[new as usize] = Some(values[old]);
            }
        }
        out.into_iter()
            .map(|v| v.expect("remap is a bijection onto 0..kept"))
            .collect()
    }
    ContentPrimitive {
        material: p.material,
        positions: permute(&p.positions, &remap, kept),
        normals: permute(&p.normals, &remap, kept),
        uvs: permute(&p.uvs, &remap, kept),
        colors: permute(&p.colors, &remap, kept),
        feature_ids: permute(&p.feature_ids, &remap, kept),
        indices: cache_ordered.iter().map(|&i| remap[i as usize]).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::{decode_meshopt_view, MeshoptView};

    fn view(mode: &str, stride: usize, count: usize, len: usize) -> MeshoptView {
        MeshoptView::at_start(mode, stride, count, len)
    }

    fn grid(side: u32) -> ContentPrimitive {
        let mut p = ContentPrimitive {
            material: None,
            positions: Vec::new(),
            normals: Vec::new(),
            uvs: Vec::new(),
            colors: Vec::new(),
            feature_ids: Vec::new(),
            indices: Vec::new(),
        };
        for y in 0..=side {
            for x in 0..=side {
                p.positions
                    .push([x as f32, y as f32, (x * y) as f32 * 0.01]);
                p.uvs.push([x as f32 / side as f32, y as f32 / side as f32]);
                p.feature_ids.push(x / 4);
            }
        }
        // Triangles in a scattered order, and two vertices nobody uses: the first and the last.
        p.positions.insert(0, [-99.0; 3]);
        p.uvs.insert(0, [1.0; 2]);
        p.feature_ids.insert(0, 7);
        let at = |x: u32, y: u32| 1 + y * (side + 1) + x;
        for k in 0..side * side {
            let c = (k * 7919) % (side * side);
            let (x, y) = (c % side, c / side);
            p.indices.extend([at(x, y), at(x + 1, y), at(x + 1, y + 1)]);
            p.indices.extend([at(x, y), at(x + 1, y + 1), at(x, y + 1)]);
        }
        p.positions.push([99.0; 3]);
        p.uvs.push([0.0; 2]);
        p.feature_ids.push(0);
        p
    }

    /// A vertex's position and UV bits and its feature.
    type Corner = (u32, u32, u32, u32, u32, u32);

    /// The triangles of `p` as vertex triples, in a canonical order.
    fn triangles(p: &ContentPrimitive) -> Vec<[Corner; 3]> {
        let v = |i: u32| {
            let i = i as usize;
            let [x, y, z] = p.positions[i].map(f32::to_bits);
            let [s, t] = p.uvs[i].map(f32::to_bits);
            (x, y, z, s, t, p.feature_ids[i])
        };
        let mut out: Vec<_> = p
            .indices
            .chunks_exact(3)
            .map(|t| {
                // Rotate so the smallest vertex comes first (keeps the winding).
                let mut tri = [v(t[0]), v(t[1]), v(t[2])];
                let m = (0..3).min_by_key(|&k| tri[k]).unwrap();
                tri.rotate_left(m);
                tri
            })
            .collect();
        out.sort();
        out
    }

    #[test]
    fn reordering_keeps_every_triangle_and_drops_unused_vertices() {
        let p = grid(12);
        let q = optimize_order(&p);
        assert_eq!(triangles(&p), triangles(&q));
        assert_eq!(q.positions.len(), p.positions.len() - 2);
        assert_eq!(q.uvs.len(), q.positions.len());
        assert_eq!(q.feature_ids.len(), q.positions.len());
        // First-use order: vertex k first appears after vertices 0..k.
        let mut next = 0;
        for &i in &q.indices {
            assert!(i <= next);
            next = next.max(i + 1);
        }
    }

    #[test]
    fn streams_decode_back_with_the_reader() {
        let q = optimize_order(&grid(12));
        let bytes: Vec<u8> = q
            .positions
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let encoded = encode_attributes(&bytes, 12).unwrap();
        assert_eq!(encoded[0], 0xa0, "vertex codec version 0");
        let v = view("ATTRIBUTES", 12, q.positions.len(), encoded.len());
        assert_eq!(decode_meshopt_view(&v, &encoded).unwrap(), bytes);

        let encoded = encode_triangles(&q.indices, q.positions.len()).unwrap();
        assert_eq!(encoded[0], 0xe1, "index codec version 1");
        let v = view("TRIANGLES", 4, q.indices.len(), encoded.len());
        let decoded = decode_meshopt_view(&v, &encoded).unwrap();
        let indices: Vec<u32> = decoded
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        // The codec may rotate a triangle's corners (the winding stays).
        let rotated = |ix: &[u32]| -> Vec<[u32; 3]> {
            ix.chunks_exact(3)
                .map(|t| {
                    let mut t = [t[0], t[1], t[2]];
                    let m = (0..3).min_by_key(|&k| t[k]).unwrap();
                    t.rotate_left(m);
                    t
                })
                .collect()
        };
        assert_eq!(rotated(&indices), rotated(&q.indices));
        assert!(matches!(
            encode_attributes(&bytes, 6),
            Err(MeshoptEncodeError::Stride(6))
        ));
    }

    #[test]
    fn octahedral_normals_decode_within_a_degree() {
        let normals: Vec<[f32; 3]> = (0..200)
            .map(|i| {
                let (a, b) = (i as f32 * 0.37, i as f32 * 0.11);
                [a.cos() * b.sin(), a.sin() * b.sin(), b.cos()]
            })
            .collect();
        let mut words = octahedral_normals(&normals);
        meshopt::encoding::decode_filter_oct(&mut words);
        for (n, w) in normals.iter().zip(&words) {
            let d = [w[0], w[1], w[2]].map(|x| x as f32 / 127.0);
            let len = d.iter().map(|x| x * x).sum::<f32>().sqrt();
            let cos = (0..3).map(|k| n[k] * d[k]).sum::<f32>() / len;
            assert!(cos > 1.0f32.to_radians().cos(), "{n:?} -> {d:?}");
        }
    }

    #[test]
    fn exponential_positions_stay_within_the_bound_with_few_bits() {
        // A 400 m wide tile: too wide for 16-bit positions within 1 mm.
        let positions: Vec<[f32; 3]> = (0..500)
            .map(|i| {
                let t = i as f32 * 0.7919;
                [200.0 * t.sin(), 12.5 * t.cos(), -180.0 + 0.73 * i as f32]
            })
            .collect();
        let ExpFiltered {
            words,
            drawn: decoded,
        } = exp_filtered(&positions, 0.001).unwrap();
        let worst = positions
            .iter()
            .zip(&decoded)
            .flat_map(|(p, d)| (0..3).map(move |k| (p[k] - d[k]).abs()))
            .fold(0.0, f32::max);
        assert!(worst <= 0.001 && worst > 0.0001, "{worst}");
        // The reader's filter gives the same floats.
        let bytes: Vec<u8> = words
            .iter()
            .flatten()
            .flat_map(|w| w.to_le_bytes())
            .collect();
        let encoded = encode_attributes(&bytes, 12).unwrap();
        let mut v = view("ATTRIBUTES", 12, words.len(), encoded.len());
        v.filter = Some("EXPONENTIAL".into());
        let back = decode_meshopt_view(&v, &encoded).unwrap();
        let back: Vec<f32> = back
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(back, decoded.concat());
    }
}
