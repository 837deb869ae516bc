//! A synthetic input shared by the tests and `make bench`: a height field (a terrain or
//! scanned-facade stand-in: one mesh, millions of triangles). Needs `glb.rs` beside it as the
//! includer's module `glb`.

use super::glb::GlbBuilder;

/// A height field of n x n quads (2 n^2 triangles), `size` metres wide, as a GLB (y-up).
pub fn height_field_glb(n: usize, size: f32) -> Vec<u8> {
    let mut pos = Vec::with_capacity((n + 1) * (n + 1) * 12);
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (i as f32 / n as f32 * size, j as f32 / n as f32 * size);
            let y = 3.0 * (x * 0.05).sin() * (z * 0.07).cos();
            for c in [x, y, -z] {
                pos.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    let mut idx = Vec::with_capacity(n * n * 24);
    for j in 0..n as u32 {
        for i in 0..n as u32 {
            let a = j * (n as u32 + 1) + i;
            let b = a + n as u32 + 1;
            for k in [a, a + 1, b + 1, a, b + 1, b] {
                idx.extend_from_slice(&k.to_le_bytes());
            }
        }
    }
    // The accessor bounds are the surface's envelope (not the sampled extremes).
    let mut b = GlbBuilder::default();
    let p = b.accessor(
        &pos,
        None,
        serde_json::json!({"componentType": 5126, "count": (n + 1) * (n + 1), "type": "VEC3", "min": [0.0, -3.0, -size], "max": [size, 3.0, 0.0]}),
    );
    let i = b.accessor(
        &idx,
        None,
        serde_json::json!({"componentType": 5125, "count": n * n * 6, "type": "SCALAR"}),
    );
    b.finish(serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": "terrain"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": p}, "indices": i}]}],
    }))
}
