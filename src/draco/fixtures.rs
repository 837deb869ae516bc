//! Fixtures for the independent decoder check (DracoPy, `tests/python/test_draco_independent.py`).

use super::tests::{attrs, grid, max_extent, TestMesh, POS_BITS};
use super::*;

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
