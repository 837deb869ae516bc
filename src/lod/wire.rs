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
    pub(crate) fn prim(&mut self, p: &ContentPrimitive) {
        self.opt(&p.material, |w, m| w.u32(m.0));
        self.n(p.positions.len());
        p.positions.iter().for_each(|v| self.f32s(v));
        self.n(p.normals.len());
        p.normals.iter().for_each(|v| self.f32s(v));
        self.n(p.uvs.len());
        p.uvs.iter().for_each(|v| self.f32s(v));
        self.n(p.colors.len());
        p.colors.iter().for_each(|v| self.f32s(v));
        self.n(p.feature_ids.len());
        p.feature_ids.iter().for_each(|&v| self.u32(v));
        self.n(p.indices.len());
        p.indices.iter().for_each(|&v| self.u32(v));
    }
    pub(crate) fn content(&mut self, c: &TileContent) {
        self.dvec3(c.center);
        self.n(c.features.len());
        c.features.iter().for_each(|f| self.u32(f.0));
        self.n(c.primitives.len());
        c.primitives.iter().for_each(|p| self.prim(p));
        self.n(c.instanced.len());
        for s in &c.instanced {
            self.u32(s.mesh.0);
            self.n(s.primitives.len());
            s.primitives.iter().for_each(|p| self.prim(p));
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
        self.content(&r.content);
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
    pub(crate) fn prim(&mut self) -> Res<ContentPrimitive> {
        Ok(ContentPrimitive {
            material: if self.flag()? {
                Some(MaterialId(self.u32()?))
            } else {
                None
            },
            positions: self.vec(12, |r| r.f32s())?,
            normals: self.vec(12, |r| r.f32s())?,
            uvs: self.vec(8, |r| r.f32s())?,
            colors: self.vec(16, |r| r.f32s())?,
            feature_ids: self.vec(4, |r| r.u32())?,
            indices: self.vec(4, |r| r.u32())?,
        })
    }
    pub(crate) fn content(&mut self) -> Res<TileContent> {
        Ok(TileContent {
            center: self.dvec3()?,
            features: self.vec(4, |r| Ok(ComponentId(r.u32()?)))?,
            primitives: self.vec(1, |r| r.prim())?,
            instanced: self.vec(1, |r| {
                Ok(InstancedShape {
                    mesh: MeshId(r.u32()?),
                    primitives: r.vec(1, |r| r.prim())?,
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
        let content = self.content()?;
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
