//! Unit tests of the Draco wrapper: round trips, topology, bad input, quantization.

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

pub(super) fn max_extent(pos: &[f32]) -> f64 {
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

pub(super) const POS_BITS: u8 = 14;
const NRM_BITS: u8 = 10;
const UV_BITS: u8 = 12;

pub(super) fn attrs(m: &TestMesh) -> Vec<EncodeAttribute<'_>> {
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
