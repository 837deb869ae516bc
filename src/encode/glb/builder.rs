//! The glTF JSON and BIN chunk of one tile as they are built: buffer views (aligned) and
//! accessors (float, normalized integer, index), with min/max where glTF requires them. With
//! `EXT_meshopt_compression`, vertex attribute and index views hold meshopt streams in the BIN
//! chunk and name a fallback buffer (no data) for their decoded bytes.

use super::*;

pub(super) const ARRAY_BUFFER: u32 = 34962;
pub(super) const ELEMENT_ARRAY_BUFFER: u32 = 34963;
pub(super) const FLOAT: u32 = 5126;
pub(super) const BYTE: u32 = 5120;
pub(super) const UNSIGNED_BYTE: u32 = 5121;
pub(super) const SHORT: u32 = 5122;
pub(super) const UNSIGNED_SHORT: u32 = 5123;
pub(super) const UNSIGNED_INT: u32 = 5125;

/// Builds the glTF JSON and BIN chunk.
#[derive(Default)]
pub(super) struct GltfBuilder {
    pub(super) bin: Vec<u8>,
    pub(super) buffer_views: Vec<Value>,
    pub(super) accessors: Vec<Value>,
    /// Vertex attributes and indices as `EXT_meshopt_compression` streams.
    pub(super) meshopt: bool,
    /// Primitives get edges: what a client draws (decoded indices) is kept for finding them.
    pub(super) edges: bool,
    /// Length of the fallback buffer (buffer 1) the compressed views decode into.
    pub(super) fallback_bytes: usize,
    /// The bytes of the edge visibility views (`EXT_mesh_primitive_edge_visibility`), for the
    /// report's figure of what edges cost.
    pub(super) edge_data: Vec<u8>,
}

impl GltfBuilder {
    /// A vertex attribute view of `bytes`, `stride` bytes per vertex (`declared_stride`: the
    /// parent view's byteStride, when it has one); with meshopt, an `ATTRIBUTES` stream.
    fn vertex_view(
        &mut self,
        bytes: &[u8],
        stride: usize,
        declared_stride: Option<usize>,
    ) -> Result<usize, EncodeError> {
        let view = if self.meshopt {
            let encoded = crate::encode::meshopt::encode_attributes(bytes, stride)?;
            self.meshopt_view(
                &encoded,
                bytes.len(),
                stride,
                "ATTRIBUTES",
                None,
                ARRAY_BUFFER,
            )
        } else {
            self.view(bytes, Some(ARRAY_BUFFER))
        };
        if let Some(s) = declared_stride {
            self.buffer_views[view]["byteStride"] = json!(s);
        }
        Ok(view)
    }

    /// A view of `encoded` (a meshopt stream of `mode`) in the BIN chunk, decoding to
    /// `decoded_len` bytes of `stride` each in the fallback buffer.
    fn meshopt_view(
        &mut self,
        encoded: &[u8],
        decoded_len: usize,
        stride: usize,
        mode: &str,
        filter: Option<&str>,
        target: u32,
    ) -> usize {
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        let fallback_offset = self.fallback_bytes.next_multiple_of(4);
        self.fallback_bytes = fallback_offset + decoded_len;
        self.buffer_views.push(json!({
            "buffer": 1, "byteOffset": fallback_offset, "byteLength": decoded_len, "target": target,
            "extensions": {"EXT_meshopt_compression": {
                "buffer": 0, "byteOffset": self.bin.len(), "byteLength": encoded.len(),
                "byteStride": stride, "count": decoded_len / stride, "mode": mode,
            }},
        }));
        if let Some(f) = filter {
            self.buffer_views.last_mut().expect("pushed")["extensions"]
                ["EXT_meshopt_compression"]["filter"] = json!(f);
        }
        self.bin.extend_from_slice(encoded);
        self.buffer_views.len() - 1
    }

    /// A float accessor stored through meshopt's `EXPONENTIAL` filter (its words in the stream,
    /// its decoded values in the accessor's min/max when `with_min_max`).
    pub(super) fn exp_accessor<const N: usize>(
        &mut self,
        exp: &crate::encode::meshopt::ExpFiltered<N>,
        with_min_max: bool,
    ) -> Result<usize, EncodeError> {
        let bytes: Vec<u8> = exp
            .words
            .iter()
            .flatten()
            .flat_map(|w| w.to_le_bytes())
            .collect();
        let encoded = crate::encode::meshopt::encode_attributes(&bytes, N * 4)?;
        let view = self.meshopt_view(
            &encoded,
            bytes.len(),
            N * 4,
            "ATTRIBUTES",
            Some("EXPONENTIAL"),
            ARRAY_BUFFER,
        );
        Ok(self.float_accessor_of(view, &exp.drawn, with_min_max))
    }

    /// A NORMAL accessor (normalized i8, stride 4) stored through meshopt's `OCTAHEDRAL` filter.
    pub(super) fn octahedral_normal_accessor(
        &mut self,
        words: &[[i8; 4]],
    ) -> Result<usize, EncodeError> {
        let bytes: Vec<u8> = words.iter().flatten().map(|&x| x as u8).collect();
        let encoded = crate::encode::meshopt::encode_attributes(&bytes, 4)?;
        let view = self.meshopt_view(
            &encoded,
            bytes.len(),
            4,
            "ATTRIBUTES",
            Some("OCTAHEDRAL"),
            ARRAY_BUFFER,
        );
        self.buffer_views[view]["byteStride"] = json!(4);
        self.accessors
            .push(json!({"bufferView": view, "componentType": BYTE,
            "normalized": true, "count": words.len(), "type": "VEC3"}));
        Ok(self.accessors.len() - 1)
    }

    pub(super) fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        self.view_aligned(bytes, target, 4)
    }

    /// A bufferView whose offset is a multiple of `align` (and of 4).
    pub(super) fn view_aligned(
        &mut self,
        bytes: &[u8],
        target: Option<u32>,
        align: usize,
    ) -> usize {
        let align = align.max(4);
        while self.bin.len() % align != 0 {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.extend_from_slice(bytes);
        self.buffer_views.push(v);
        self.buffer_views.len() - 1
    }

    pub(super) fn float_accessor<const N: usize>(
        &mut self,
        data: &[[f32; N]],
        with_min_max: bool,
    ) -> Result<usize, EncodeError> {
        self.float_accessor_in(data, with_min_max, Some(ARRAY_BUFFER))
    }

    /// A float accessor in its own bufferView (`target` None for instance attributes, which are
    /// not vertex buffers).
    pub(super) fn float_accessor_in<const N: usize>(
        &mut self,
        data: &[[f32; N]],
        with_min_max: bool,
        target: Option<u32>,
    ) -> Result<usize, EncodeError> {
        let mut bytes = Vec::with_capacity(data.len() * N * 4);
        for v in data {
            for x in v {
                bytes.write_f32::<LE>(*x).expect("vec write");
            }
        }
        let view = match target {
            Some(ARRAY_BUFFER) => self.vertex_view(&bytes, N * 4, None)?,
            _ => self.view(&bytes, target),
        };
        Ok(self.float_accessor_of(view, data, with_min_max))
    }

    /// A float accessor of `values` (as clients read them) in `view`, with their bounds when
    /// `with_min_max`.
    fn float_accessor_of<const N: usize>(
        &mut self,
        view: usize,
        values: &[[f32; N]],
        with_min_max: bool,
    ) -> usize {
        let ty = ["SCALAR", "VEC2", "VEC3", "VEC4"][N - 1];
        let mut a =
            json!({"bufferView": view, "componentType": FLOAT, "count": values.len(), "type": ty});
        if with_min_max {
            let mut lo = [f32::INFINITY; N];
            let mut hi = [f32::NEG_INFINITY; N];
            for v in values {
                for k in 0..N {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
            a["min"] = json!(lo.iter().map(|&x| x as f64).collect::<Vec<_>>());
            a["max"] = json!(hi.iter().map(|&x| x as f64).collect::<Vec<_>>());
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// A normalized integer vertex attribute: `N` components of `size` bytes each (1 or 2),
    /// padded to a 4-byte stride as glTF requires of vertex attributes; with `with_min_max`, the
    /// integer bounds.
    pub(super) fn normalized_accessor<const N: usize>(
        &mut self,
        data: &[[i32; N]],
        component_type: u32,
        with_min_max: bool,
    ) -> Result<usize, EncodeError> {
        let size = if matches!(component_type, BYTE | UNSIGNED_BYTE) {
            1
        } else {
            2
        };
        let stride = (N * size).div_ceil(4) * 4;
        let mut bytes = Vec::with_capacity(data.len() * stride);
        for v in data {
            for &x in v {
                match size {
                    1 => bytes.push(x as i8 as u8),
                    _ => bytes.extend_from_slice(&(x as u16).to_le_bytes()),
                }
            }
            bytes.resize(bytes.len() + stride - N * size, 0);
        }
        let view = self.vertex_view(&bytes, stride, (stride != N * size).then_some(stride))?;
        let ty = ["SCALAR", "VEC2", "VEC3", "VEC4"][N - 1];
        let mut a = json!({"bufferView": view, "componentType": component_type,
            "normalized": true, "count": data.len(), "type": ty});
        if with_min_max {
            let lo: Vec<i32> = (0..N)
                .map(|k| data.iter().map(|v| v[k]).min().unwrap_or(0))
                .collect();
            let hi: Vec<i32> = (0..N)
                .map(|k| data.iter().map(|v| v[k]).max().unwrap_or(0))
                .collect();
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        self.accessors.push(a);
        Ok(self.accessors.len() - 1)
    }

    /// An index accessor; also returns the indices as a client decodes them (meshopt's index
    /// codec may rotate a triangle's corners).
    pub(super) fn index_accessor(
        &mut self,
        indices: &[u32],
        vertex_count: usize,
    ) -> Result<(usize, Vec<u32>), EncodeError> {
        let (bytes, ct) = if vertex_count <= u16::MAX as usize {
            let mut b = Vec::with_capacity(indices.len() * 2);
            for &i in indices {
                b.write_u16::<LE>(i as u16).expect("vec write");
            }
            (b, UNSIGNED_SHORT)
        } else {
            let mut b = Vec::with_capacity(indices.len() * 4);
            for &i in indices {
                b.write_u32::<LE>(i).expect("vec write");
            }
            (b, UNSIGNED_INT)
        };
        let (view, drawn) = if self.meshopt {
            let encoded = crate::encode::meshopt::encode_triangles(indices, vertex_count)?;
            // Decoded back only for the edges, which follow the order a client reads.
            let drawn = if self.edges {
                crate::encode::meshopt::decode_triangles(&encoded, indices.len())?
            } else {
                Vec::new()
            };
            let stride = if ct == UNSIGNED_SHORT { 2 } else { 4 };
            let view = self.meshopt_view(
                &encoded,
                bytes.len(),
                stride,
                "TRIANGLES",
                None,
                ELEMENT_ARRAY_BUFFER,
            );
            (view, drawn)
        } else {
            let drawn = if self.edges {
                indices.to_vec()
            } else {
                Vec::new()
            };
            (self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER)), drawn)
        };
        self.accessors.push(json!({"bufferView": view, "componentType": ct, "count": indices.len(), "type": "SCALAR"}));
        Ok((self.accessors.len() - 1, drawn))
    }

    /// The `EXT_mesh_primitive_edge_visibility` object of a primitive: the bitfield as an
    /// unsigned-byte SCALAR accessor and, with silhouettes, their face normals as normalized i8
    /// VEC3 (two per silhouette edge) under [`edges::SILHOUETTE_PROPERTY`]. Plain views: the
    /// server's gzip shrinks the long runs of hidden edges.
    pub(super) fn edge_visibility(&mut self, e: &crate::encode::edges::EdgeVisibility) -> Value {
        use crate::encode::edges;
        let view = self.view(&e.visibility, None);
        self.edge_data.extend_from_slice(&e.visibility);
        self.accessors
            .push(json!({"bufferView": view, "componentType": UNSIGNED_BYTE,
            "count": e.visibility.len(), "type": "SCALAR"}));
        let mut ext = json!({"visibility": self.accessors.len() - 1});
        if !e.silhouette_normals.is_empty() {
            let bytes: Vec<u8> = e
                .silhouette_normals
                .iter()
                .flatten()
                .flat_map(|&n| edges::silhouette_normal_i8(n).map(|x| x as u8))
                .collect();
            let view = self.view(&bytes, None);
            self.edge_data.extend_from_slice(&bytes);
            self.accessors
                .push(json!({"bufferView": view, "componentType": BYTE,
                "normalized": true, "count": 2 * e.silhouette_normals.len(), "type": "VEC3"}));
            ext[edges::SILHOUETTE_PROPERTY] = json!(self.accessors.len() - 1);
        }
        ext
    }
}
