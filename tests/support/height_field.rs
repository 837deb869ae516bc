//! Synthetic inputs shared by the tests and `make bench`: a GLB container writer and a height
//! field (a terrain or scanned-facade stand-in: one mesh, millions of triangles).

/// A GLB container from a JSON chunk and a BIN chunk (both padded here).
pub fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let mut j = json.to_vec();
    while j.len() % 4 != 0 {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while b.len() % 4 != 0 {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    out.extend_from_slice(&(b.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&b);
    out
}

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
    let (pl, il) = (pos.len(), idx.len());
    let mut bin = pos;
    bin.extend_from_slice(&idx);
    let json = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": "terrain"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": (n + 1) * (n + 1), "type": "VEC3", "min": [0.0, -3.0, -size], "max": [size, 3.0, 0.0]},
            {"bufferView": 1, "componentType": 5125, "count": n * n * 6, "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteLength": pl}, {"buffer": 0, "byteOffset": pl, "byteLength": il}],
        "buffers": [{"byteLength": pl + il}]
    });
    glb(&serde_json::to_vec(&json).unwrap(), &bin)
}
