//! GLB containers for the tests and `make bench`, written and split by hand (not by our writer):
//! the container writer, a builder for the binary buffer with its buffer views and accessors,
//! one-mesh models, and the reverse (a GLB's JSON and BIN chunks).

use serde_json::{json, Value};

/// A GLB container from a JSON chunk and a BIN chunk (JSON padded with spaces, BIN with zeros).
pub fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |b: &[u8], fill: u8| {
        let mut v = b.to_vec();
        v.resize(b.len().div_ceil(4) * 4, fill);
        v
    };
    let (j, b) = (pad(json, b' '), pad(bin, 0));
    let mut out = Vec::with_capacity(28 + j.len() + b.len());
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((28 + j.len() + b.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    out.extend_from_slice(&(b.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&b);
    out
}

/// The JSON chunk (parsed) and the BIN chunk (empty when there is none) of a GLB.
pub fn glb_chunks(bytes: &[u8]) -> (Value, Vec<u8>) {
    let g = gltf::binary::Glb::from_slice(bytes).expect("a GLB");
    let json = serde_json::from_slice(&g.json).expect("GLB JSON");
    (json, g.bin.map(|b| b.into_owned()).unwrap_or_default())
}

/// The little-endian bytes of a slice of `f32` rows (positions, normals, UVs).
pub fn f32_bytes<const N: usize>(rows: &[[f32; N]]) -> Vec<u8> {
    rows.iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect()
}

/// Per-axis minimum and maximum of `points`: a glTF POSITION accessor's `min` and `max`.
pub fn bounds(points: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let lo = std::array::from_fn(|k| points.iter().map(|p| p[k]).fold(f32::MAX, f32::min));
    let hi = std::array::from_fn(|k| points.iter().map(|p| p[k]).fold(f32::MIN, f32::max));
    (lo, hi)
}

/// The binary buffer of a GLB being built, with its buffer views and accessors.
#[derive(Default)]
pub struct GlbBuilder {
    pub bin: Vec<u8>,
    pub views: Vec<Value>,
    pub accessors: Vec<Value>,
}

impl GlbBuilder {
    /// Appends `bytes` (at a 4-byte boundary) as a buffer view with an optional `target`; its index.
    pub fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = t.into();
        }
        self.bin.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }

    /// An accessor (`acc`: componentType, count, type, ...) over a new view of `bytes`; its index.
    pub fn accessor(&mut self, bytes: &[u8], target: Option<u32>, mut acc: Value) -> usize {
        acc["bufferView"] = self.view(bytes, target).into();
        self.accessors.push(acc);
        self.accessors.len() - 1
    }

    /// A float VEC3 POSITION accessor with its `min` and `max`; its index.
    pub fn positions(&mut self, points: &[[f32; 3]], target: Option<u32>) -> usize {
        let (lo, hi) = bounds(points);
        let acc = json!({"componentType": 5126, "count": points.len(), "type": "VEC3", "min": lo, "max": hi});
        self.accessor(&f32_bytes(points), target, acc)
    }

    /// A u32 SCALAR index accessor; its index.
    pub fn indices(&mut self, indices: &[u32], target: Option<u32>) -> usize {
        let bytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let acc = json!({"componentType": 5125, "count": indices.len(), "type": "SCALAR"});
        self.accessor(&bytes, target, acc)
    }

    /// The GLB of `doc` (asset, scenes, nodes, meshes, ...) with this buffer, its views and
    /// accessors.
    pub fn finish(self, mut doc: Value) -> Vec<u8> {
        doc["accessors"] = self.accessors.into();
        doc["bufferViews"] = self.views.into();
        doc["buffers"] = json!([{"byteLength": self.bin.len()}]);
        glb(&serde_json::to_vec(&doc).unwrap(), &self.bin)
    }
}

/// A GLB with one mesh of one primitive (POSITION, and `indices` when given) drawn by `nodes`;
/// `roots` are the scene's nodes.
pub fn one_mesh_glb(
    positions: &[[f32; 3]],
    indices: Option<&[u32]>,
    nodes: Value,
    roots: &[usize],
) -> Vec<u8> {
    let mut b = GlbBuilder::default();
    let mut primitive = json!({"attributes": {"POSITION": b.positions(positions, None)}});
    if let Some(i) = indices {
        primitive["indices"] = b.indices(i, None).into();
    }
    b.finish(json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": roots}], "nodes": nodes,
        "meshes": [{"primitives": [primitive]}],
    }))
}

/// A GLB of one textured quad whose base colour texture is `image` (declared `image/png`).
pub fn textured_quad_glb(image: &[u8]) -> Vec<u8> {
    let mut b = GlbBuilder::default();
    let quad = [
        [0.0, 0.0, 0.0],
        [4.0, 0.0, 0.0],
        [4.0, 3.0, 0.0],
        [0.0, 3.0, 0.0],
    ];
    let position = b.positions(&quad, None);
    let uv = b.accessor(
        &f32_bytes(&[[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]]),
        None,
        json!({"componentType": 5126, "count": 4, "type": "VEC2"}),
    );
    let indices = b.indices(&[0, 1, 2, 0, 2, 3], None);
    let image_view = b.view(image, None);
    b.finish(json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "wall", "mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": position, "TEXCOORD_0": uv},
            "indices": indices, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0}],
        "images": [{"name": "photo", "bufferView": image_view, "mimeType": "image/png"}],
    }))
}

/// A PNG of `w` x `h` px (RGBA, every pixel `rgba`).
pub fn png_image(w: u32, h: u32, rgba: [u8; 4]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut e = png::Encoder::new(&mut out, w, h);
    e.set_color(png::ColorType::Rgba);
    let pixels: Vec<u8> = (0..w * h).flat_map(|_| rgba).collect();
    let mut writer = e.write_header().unwrap();
    writer.write_image_data(&pixels).unwrap();
    writer.finish().unwrap();
    out
}

/// A PNG whose header claims `w` x `h` px, followed by the pixel data of a 1 x 1 image: a few
/// dozen bytes that would decode to gigabytes.
pub fn png_claiming(w: u32, h: u32) -> Vec<u8> {
    let mut head = Vec::new();
    let mut e = png::Encoder::new(&mut head, w, h);
    e.set_color(png::ColorType::Rgba);
    drop(e.write_header().unwrap());
    let mut bytes = head[..33].to_vec(); // signature, IHDR
    bytes.extend_from_slice(&png_image(1, 1, [0; 4])[33..]); // IDAT, IEND
    bytes
}
