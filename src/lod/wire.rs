//! The bit-exact binary encoding of what the HLOD stage hands on: tile records, tile contents
//! and what a subtree hands its parent ([`BuiltSubtree`]). Floats are stored as their bits, so a
//! reader gets exactly what the writer had. Little-endian; counts are checked against the bytes
//! left, so truncated bytes are refused. Used by the sharded jobs' result files
//! (`crate::shard`) and by the update's tile cache ([`super::subtree_cache`]).

use crate::encode::{ContentFigures, TileRecord};
use crate::lod::hlod::BuiltSubtree;
use crate::partition::content::{ContentPrimitive, InstancedShape, ShapeInstance, TileContent};
use crate::scene::{Aabb, ComponentId, MaterialId, MeshId};
use glam::{DMat4, DVec3};

/// How a primitive's arrays are written: `Raw`, element by element (what the sharded jobs hand
/// on, and what keys hash), or `Packed` through meshopt's lossless codecs (the vertex codec, and
/// the index sequence codec, which keeps every triangle's corners in their order): the update's
/// tile cache keeps more hand-overs in its share of the tileset's bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Streams {
    Raw,
    Packed,
}

/// meshopt's vertex codec packs an array into no less than this share of its bytes (twice the
/// share an array of zeros, its best case, packs into), and a packed array carries up to
/// [`PACKED_SLACK_BYTES`] of its own framing: counts past that are refused before anything is
/// allocated. (The cache's zlib checksum already refuses bytes spoiled by accident.)
const PACKED_VERTEX_RATIO: usize = 2048;
const PACKED_SLACK_BYTES: usize = 64;

/// A writer of the encoding.
#[derive(Default)]
pub(crate) struct W(pub(crate) Vec<u8>);

impl W {
    pub(crate) fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn n(&mut self, v: usize) {
        self.u64(v as u64);
    }
    pub(crate) fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    pub(crate) fn f32s(&mut self, v: &[f32]) {
        for x in v {
            self.u32(x.to_bits());
        }
    }
    pub(crate) fn str(&mut self, s: &str) {
        self.n(s.len());
        self.0.extend_from_slice(s.as_bytes());
    }
    pub(crate) fn opt<T>(&mut self, v: &Option<T>, f: impl FnOnce(&mut Self, &T)) {
        match v {
            None => self.0.push(0),
            Some(x) => {
                self.0.push(1);
                f(self, x)
            }
        }
    }
    pub(crate) fn dvec3(&mut self, v: DVec3) {
        v.to_array().into_iter().for_each(|x| self.f64(x));
    }
    pub(crate) fn aabb(&mut self, b: &Aabb) {
        self.dvec3(b.min);
        self.dvec3(b.max);
    }
    /// A primitive, its arrays as they are or [`Streams::Packed`].
    fn prim(&mut self, p: &ContentPrimitive, streams: Streams) {
        self.opt(&p.material, |w, m| w.u32(m.0));
        self.stream(&p.positions, streams, |w, v| w.f32s(v));
        self.stream(&p.normals, streams, |w, v| w.f32s(v));
        self.stream(&p.uvs, streams, |w, v| w.f32s(v));
        self.stream(&p.colors, streams, |w, v| w.f32s(v));
        self.stream(&p.feature_ids, streams, |w, &v| w.u32(v));
        self.n(p.indices.len());
        match streams {
            Streams::Raw => p.indices.iter().for_each(|&v| self.u32(v)),
            Streams::Packed if p.indices.is_empty() => {}
            Streams::Packed => {
                let vertices = p.indices.iter().max().map_or(0, |&m| m as usize + 1);
                let packed = meshopt::encode_index_sequence(&p.indices, vertices)
                    .expect("an index sequence always encodes");
                self.n(packed.len());
                self.0.extend_from_slice(&packed);
            }
        }
    }
    /// A vertex array: its count, then each element by `raw`, or the array through meshopt's
    /// lossless vertex codec (its bytes' count, then its bytes).
    fn stream<T>(&mut self, v: &[T], streams: Streams, raw: impl Fn(&mut Self, &T)) {
        self.n(v.len());
        match streams {
            Streams::Raw => v.iter().for_each(|x| raw(self, x)),
            Streams::Packed if v.is_empty() => {}
            Streams::Packed => {
                let packed =
                    meshopt::encode_vertex_buffer(v).expect("a vertex array always encodes");
                self.n(packed.len());
                self.0.extend_from_slice(&packed);
            }
        }
    }
    fn content_with(&mut self, c: &TileContent, streams: Streams) {
        self.dvec3(c.center);
        self.n(c.features.len());
        c.features.iter().for_each(|f| self.u32(f.0));
        self.n(c.primitives.len());
        c.primitives.iter().for_each(|p| self.prim(p, streams));
        self.n(c.instanced.len());
        for s in &c.instanced {
            self.u32(s.mesh.0);
            self.n(s.primitives.len());
            s.primitives.iter().for_each(|p| self.prim(p, streams));
            self.n(s.instances.len());
            for i in &s.instances {
                self.u32(i.feature);
                i.transform
                    .to_cols_array()
                    .into_iter()
                    .for_each(|x| self.f64(x));
            }
        }
    }
    pub(crate) fn record(&mut self, s: &TileRecord) {
        let c = &s.content;
        self.aabb(&c.bounds);
        self.opt(&s.uri, |w, u| w.str(u));
        self.f64(s.geometric_error_m);
        self.u64(c.bytes);
        for v in [
            c.triangles,
            c.vertices,
            c.stored_triangles,
            c.instanced_shapes,
            c.instances,
            c.features,
        ] {
            self.n(v);
        }
        self.u64(c.metadata_bytes);
        self.u64(c.edge_bytes);
        self.u64(c.edge_gzip_bytes);
        self.opt(&s.simplified_from_triangles, |w, &v| w.n(v));
        self.opt(&s.full_to_coarse_m, |w, &v| w.f64(v));
        self.opt(&s.coarse_to_full_bound_m, |w, &v| w.f64(v));
        self.opt(&s.measured_error_m, |w, &v| w.f64(v));
        self.opt(&s.max_folding_edge_m, |w, &v| w.f64(v));
        self.opt(&s.paper_error_m, |w, &v| w.f64(v));
        self.opt(&s.max_position_error_m, |w, &v| w.f64(v));
    }
    pub(crate) fn subtree(&mut self, r: &BuiltSubtree) {
        self.subtree_with(r, Streams::Raw);
    }
    /// [`Self::subtree`] with its arrays [`Streams::Packed`].
    pub(crate) fn packed_subtree(&mut self, r: &BuiltSubtree) {
        self.subtree_with(r, Streams::Packed);
    }
    fn subtree_with(&mut self, r: &BuiltSubtree, streams: Streams) {
        self.content_with(&r.content, streams);
        self.f64(r.geometric_error_m);
        self.f64(r.coarse_to_full_m);
        self.f64(r.max_folding_edge_m);
        self.n(r.cut_triangles.len());
        for (c, n) in &r.cut_triangles {
            self.u32(c.0);
            self.n(*n);
        }
    }
}

/// A reader of the encoding.
pub(crate) struct R<'a>(pub(crate) &'a [u8]);

/// What is wrong with the bytes of a job's result.
#[derive(Debug, thiserror::Error, PartialEq)]
pub(crate) enum WireError {
    #[error("not a bimtiles job result")]
    NotAJobResult,
    #[error("not a bimtiles tile cache")]
    NotATileCache,
    #[error("truncated")]
    Truncated,
    #[error("truncated (count beyond the end)")]
    CountBeyondEnd,
    #[error("truncated or trailing bytes")]
    NoEndMark,
    #[error("bad option flag {0}")]
    BadFlag(u8),
    #[error("a packed array does not decode")]
    BadStream,
    #[error("a string is not UTF-8")]
    NotUtf8(#[from] std::string::FromUtf8Error),
}

pub(crate) type Res<T> = std::result::Result<T, WireError>;

impl R<'_> {
    pub(crate) fn take(&mut self, n: usize) -> Res<&[u8]> {
        if self.0.len() < n {
            return Err(WireError::Truncated);
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Ok(a)
    }
    pub(crate) fn u64(&mut self) -> Res<u64> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    pub(crate) fn u32(&mut self) -> Res<u32> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }
    /// A count, checked against what is left (each element at least `min_bytes`).
    pub(crate) fn n(&mut self, min_bytes: usize) -> Res<usize> {
        let n = self.u64()? as usize;
        if n.saturating_mul(min_bytes) > self.0.len() {
            return Err(WireError::CountBeyondEnd);
        }
        Ok(n)
    }
    pub(crate) fn f64(&mut self) -> Res<f64> {
        Ok(f64::from_bits(self.u64()?))
    }
    pub(crate) fn f32s<const N: usize>(&mut self) -> Res<[f32; N]> {
        let mut a = [0f32; N];
        for x in &mut a {
            *x = f32::from_bits(self.u32()?);
        }
        Ok(a)
    }
    pub(crate) fn flag(&mut self) -> Res<bool> {
        match self.take(1)?[0] {
            0 => Ok(false),
            1 => Ok(true),
            b => Err(WireError::BadFlag(b)),
        }
    }
    pub(crate) fn str(&mut self) -> Res<String> {
        let n = self.n(1)?;
        Ok(String::from_utf8(self.take(n)?.to_vec())?)
    }
    pub(crate) fn dvec3(&mut self) -> Res<DVec3> {
        Ok(DVec3::new(self.f64()?, self.f64()?, self.f64()?))
    }
    pub(crate) fn aabb(&mut self) -> Res<Aabb> {
        Ok(Aabb {
            min: self.dvec3()?,
            max: self.dvec3()?,
        })
    }
    pub(crate) fn vec<T>(
        &mut self,
        min_bytes: usize,
        mut f: impl FnMut(&mut Self) -> Res<T>,
    ) -> Res<Vec<T>> {
        let n = self.n(min_bytes)?;
        (0..n).map(|_| f(self)).collect()
    }
    fn prim(&mut self, streams: Streams) -> Res<ContentPrimitive> {
        Ok(ContentPrimitive {
            material: if self.flag()? {
                Some(MaterialId(self.u32()?))
            } else {
                None
            },
            positions: self.stream(12, streams, |r| r.f32s())?,
            normals: self.stream(12, streams, |r| r.f32s())?,
            uvs: self.stream(8, streams, |r| r.f32s())?,
            colors: self.stream(16, streams, |r| r.f32s())?,
            feature_ids: self.stream(4, streams, |r| r.u32())?,
            indices: match streams {
                Streams::Raw => self.vec(4, |r| r.u32())?,
                Streams::Packed => {
                    // An index takes at least a byte of the sequence.
                    let count = self.u64()? as usize;
                    let bytes = self.packed(count, count)?;
                    if count == 0 {
                        Vec::new()
                    } else {
                        meshopt::decode_index_sequence::<u32>(bytes, count)
                            .map_err(|_| WireError::BadStream)?
                    }
                }
            },
        })
    }
    /// What [`W::stream`] wrote; `size_bytes` is an element's.
    fn stream<T: Clone + Default>(
        &mut self,
        size_bytes: usize,
        streams: Streams,
        raw: impl FnMut(&mut Self) -> Res<T>,
    ) -> Res<Vec<T>> {
        match streams {
            Streams::Raw => self.vec(size_bytes, raw),
            Streams::Packed => {
                let count = self.u64()? as usize;
                let least = count.saturating_mul(size_bytes) / PACKED_VERTEX_RATIO;
                let bytes = self.packed(count, least)?;
                if count == 0 {
                    return Ok(Vec::new());
                }
                meshopt::decode_vertex_buffer(bytes, count).map_err(|_| WireError::BadStream)
            }
        }
    }
    /// The bytes of a packed array of `count` elements, which take at least `min_bytes` (none for
    /// an empty array).
    fn packed(&mut self, count: usize, min_bytes: usize) -> Res<&[u8]> {
        if count == 0 {
            return Ok(&[]);
        }
        let n = self.n(1)?;
        if min_bytes > n.saturating_add(PACKED_SLACK_BYTES) {
            return Err(WireError::CountBeyondEnd);
        }
        self.take(n)
    }
    fn content_with(&mut self, streams: Streams) -> Res<TileContent> {
        Ok(TileContent {
            center: self.dvec3()?,
            features: self.vec(4, |r| Ok(ComponentId(r.u32()?)))?,
            primitives: self.vec(1, |r| r.prim(streams))?,
            instanced: self.vec(1, |r| {
                Ok(InstancedShape {
                    mesh: MeshId(r.u32()?),
                    primitives: r.vec(1, |r| r.prim(streams))?,
                    instances: r.vec(132, |r| {
                        let feature = r.u32()?;
                        let mut m = [0f64; 16];
                        for x in &mut m {
                            *x = r.f64()?;
                        }
                        Ok(ShapeInstance {
                            feature,
                            transform: DMat4::from_cols_array(&m),
                        })
                    })?,
                })
            })?,
        })
    }
    pub(crate) fn opt_f64(&mut self) -> Res<Option<f64>> {
        Ok(if self.flag()? {
            Some(self.f64()?)
        } else {
            None
        })
    }
    pub(crate) fn record(&mut self) -> Res<TileRecord> {
        let bounds = self.aabb()?;
        let uri = if self.flag()? {
            Some(self.str()?)
        } else {
            None
        };
        let geometric_error_m = self.f64()?;
        let bytes = self.u64()?;
        let mut counts = [0usize; 6];
        for c in &mut counts {
            *c = self.u64()? as usize;
        }
        let [triangles, vertices, stored_triangles, instanced_shapes, instances, features] = counts;
        let content = ContentFigures {
            bytes,
            features,
            triangles,
            vertices,
            stored_triangles,
            instanced_shapes,
            instances,
            metadata_bytes: self.u64()?,
            edge_bytes: self.u64()?,
            edge_gzip_bytes: self.u64()?,
            bounds,
        };
        Ok(TileRecord {
            uri,
            geometric_error_m,
            content,
            simplified_from_triangles: if self.flag()? {
                Some(self.u64()? as usize)
            } else {
                None
            },
            full_to_coarse_m: self.opt_f64()?,
            coarse_to_full_bound_m: self.opt_f64()?,
            measured_error_m: self.opt_f64()?,
            max_folding_edge_m: self.opt_f64()?,
            paper_error_m: self.opt_f64()?,
            max_position_error_m: self.opt_f64()?,
            ..Default::default()
        })
    }
    pub(crate) fn subtree(&mut self) -> Res<BuiltSubtree> {
        self.subtree_with(Streams::Raw)
    }
    /// What [`W::packed_subtree`] wrote.
    pub(crate) fn packed_subtree(&mut self) -> Res<BuiltSubtree> {
        self.subtree_with(Streams::Packed)
    }
    fn subtree_with(&mut self, streams: Streams) -> Res<BuiltSubtree> {
        let content = self.content_with(streams)?;
        let geometric_error_m = self.f64()?;
        let coarse_to_full_m = self.f64()?;
        let max_folding_edge_m = self.f64()?;
        let cut_triangles = self
            .vec(12, |r| Ok((ComponentId(r.u32()?), r.u64()? as usize)))?
            .into_iter()
            .collect();
        Ok(BuiltSubtree {
            content,
            geometric_error_m,
            coarse_to_full_m,
            max_folding_edge_m,
            cut_triangles,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// A hand-over with arrays of every kind: long ones of equal values (which pack far below
    /// their size), short ones, empty ones, and bits no arithmetic makes (NaN payloads, -0).
    fn handover() -> BuiltSubtree {
        let n = 5000u32;
        let big = ContentPrimitive {
            material: Some(MaterialId(3)),
            positions: (0..n).map(|i| [i as f32 * 0.25, -0.0, 1e-30]).collect(),
            normals: vec![[0.0, 0.0, 1.0]; n as usize],
            uvs: (0..n)
                .map(|i| [f32::from_bits(0x7fc0_0001 + i), 0.5])
                .collect(),
            colors: Vec::new(),
            feature_ids: vec![7; n as usize],
            indices: (0..n - 2).flat_map(|i| [i + 2, i, i + 1]).collect(),
        };
        let small = ContentPrimitive {
            material: None,
            positions: vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.5]],
            normals: vec![[0.0, 1.0, 0.0]; 3],
            uvs: Vec::new(),
            colors: vec![[1.0, 0.5, 0.25, 1.0]; 3],
            feature_ids: vec![0, 1, 0],
            indices: vec![2, 0, 1],
        };
        BuiltSubtree {
            content: TileContent {
                center: DVec3::new(1.5, -2.0, 1e6),
                features: vec![ComponentId(4), ComponentId(9)],
                primitives: vec![big, small, ContentPrimitive::default()],
                instanced: Vec::new(),
            },
            geometric_error_m: 0.25,
            coarse_to_full_m: 0.125,
            max_folding_edge_m: 2.0,
            cut_triangles: BTreeMap::from([(ComponentId(9), 12)]),
        }
    }

    fn bits(b: &BuiltSubtree) -> Vec<u8> {
        let mut w = W::default();
        w.subtree(b);
        w.0
    }

    #[test]
    fn a_packed_handover_reads_back_bit_for_bit_and_smaller() {
        let b = handover();
        let mut w = W::default();
        w.packed_subtree(&b);
        let raw = bits(&b);
        assert!(w.0.len() * 3 < raw.len(), "{} of {}", w.0.len(), raw.len());
        let mut r = R(&w.0);
        let back = r.packed_subtree().expect("reads back");
        assert!(r.0.is_empty());
        assert_eq!(bits(&back), raw);
    }

    #[test]
    fn a_cut_or_spoiled_packed_handover_is_refused() {
        let mut w = W::default();
        w.packed_subtree(&handover());
        for cut in [1, 100, w.0.len() / 2, w.0.len() - 1] {
            let mut r = R(&w.0[..cut]);
            assert!(r.packed_subtree().is_err(), "cut at {cut}");
        }
        // A vertex count far beyond what the packed bytes can hold is refused before decoding.
        let (center, features) = (24, 8 + 2 * 4);
        let count_at = center + features + 8 + 1 + 4;
        let mut spoiled = w.0.clone();
        spoiled[count_at..count_at + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
        assert_eq!(
            R(&spoiled).packed_subtree().err(),
            Some(WireError::CountBeyondEnd)
        );
    }
}
