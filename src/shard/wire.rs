//! The binary result file of one sharded job (`jobs/job-K.bin`): the figures of every tile the job
//! wrote and, for HLOD, what each of its subtree roots hands its parent (content, errors, cut
//! triangle counts). Floats are stored as their bits, so `merge` gets exactly what the job had and
//! the merged tileset is byte-identical to `convert`'s. Little-endian; a magic at the start and an
//! end mark, so a truncated file is refused. A tile's plan path, depth and LOD level are not
//! stored: `merge` sets them from the plan.

use crate::encode::{ContentFigures, TileRecord};
use crate::lod::hlod::BuiltSubtree;
use crate::partition::content::{ContentPrimitive, InstancedShape, ShapeInstance, TileContent};
use crate::scene::{Aabb, ComponentId, MaterialId, MeshId};
use crate::tiling::JobOutput;
use glam::{DMat4, DVec3};

const MAGIC: &[u8; 8] = b"BIMTJOB3";
const END: &[u8; 4] = b"END.";

/// A job's result as stored.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct JobFile {
    pub plan_digest: String,
    pub job: usize,
    pub seconds: f64,
    pub output: JobOutput,
}

#[derive(Default)]
struct W(Vec<u8>);

impl W {
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn n(&mut self, v: usize) {
        self.u64(v as u64);
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn f32s(&mut self, v: &[f32]) {
        for x in v {
            self.u32(x.to_bits());
        }
    }
    fn str(&mut self, s: &str) {
        self.n(s.len());
        self.0.extend_from_slice(s.as_bytes());
    }
    fn opt<T>(&mut self, v: &Option<T>, f: impl FnOnce(&mut Self, &T)) {
        match v {
            None => self.0.push(0),
            Some(x) => {
                self.0.push(1);
                f(self, x)
            }
        }
    }
    fn dvec3(&mut self, v: DVec3) {
        v.to_array().into_iter().for_each(|x| self.f64(x));
    }
    fn aabb(&mut self, b: &Aabb) {
        self.dvec3(b.min);
        self.dvec3(b.max);
    }
    fn prim(&mut self, p: &ContentPrimitive) {
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
    fn content(&mut self, c: &TileContent) {
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
    fn record(&mut self, s: &TileRecord) {
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
}

/// Serializes a job's result.
pub(crate) fn encode(f: &JobFile) -> Vec<u8> {
    let mut w = W::default();
    w.0.extend_from_slice(MAGIC);
    w.str(&f.plan_digest);
    w.n(f.job);
    w.f64(f.seconds);
    w.n(f.output.tiles.len());
    for (i, record) in &f.output.tiles {
        w.n(*i);
        w.record(record);
    }
    w.n(f.output.roots.len());
    for (i, r) in &f.output.roots {
        w.n(*i);
        w.content(&r.content);
        w.f64(r.geometric_error_m);
        w.f64(r.coarse_to_full_m);
        w.f64(r.max_folding_edge_m);
        w.n(r.cut_triangles.len());
        for (c, n) in &r.cut_triangles {
            w.u32(c.0);
            w.n(*n);
        }
    }
    w.0.extend_from_slice(END);
    w.0
}

struct R<'a>(&'a [u8]);

/// What is wrong with the bytes of a job's result.
#[derive(Debug, thiserror::Error, PartialEq)]
pub(crate) enum WireError {
    #[error("not a bimtiles job result")]
    NotAJobResult,
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

type Res<T> = std::result::Result<T, WireError>;

impl R<'_> {
    fn take(&mut self, n: usize) -> Res<&[u8]> {
        if self.0.len() < n {
            return Err(WireError::Truncated);
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Ok(a)
    }
    fn u64(&mut self) -> Res<u64> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    fn u32(&mut self) -> Res<u32> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }
    /// A count, checked against what is left (each element at least `min_bytes`).
    fn n(&mut self, min_bytes: usize) -> Res<usize> {
        let n = self.u64()? as usize;
        if n.saturating_mul(min_bytes) > self.0.len() {
            return Err(WireError::CountBeyondEnd);
        }
        Ok(n)
    }
    fn f64(&mut self) -> Res<f64> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn f32s<const N: usize>(&mut self) -> Res<[f32; N]> {
        let mut a = [0f32; N];
        for x in &mut a {
            *x = f32::from_bits(self.u32()?);
        }
        Ok(a)
    }
    fn flag(&mut self) -> Res<bool> {
        match self.take(1)?[0] {
            0 => Ok(false),
            1 => Ok(true),
            b => Err(WireError::BadFlag(b)),
        }
    }
    fn str(&mut self) -> Res<String> {
        let n = self.n(1)?;
        Ok(String::from_utf8(self.take(n)?.to_vec())?)
    }
    fn dvec3(&mut self) -> Res<DVec3> {
        Ok(DVec3::new(self.f64()?, self.f64()?, self.f64()?))
    }
    fn aabb(&mut self) -> Res<Aabb> {
        Ok(Aabb {
            min: self.dvec3()?,
            max: self.dvec3()?,
        })
    }
    fn vec<T>(&mut self, min_bytes: usize, mut f: impl FnMut(&mut Self) -> Res<T>) -> Res<Vec<T>> {
        let n = self.n(min_bytes)?;
        (0..n).map(|_| f(self)).collect()
    }
    fn prim(&mut self) -> Res<ContentPrimitive> {
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
    fn content(&mut self) -> Res<TileContent> {
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
    fn opt_f64(&mut self) -> Res<Option<f64>> {
        Ok(if self.flag()? {
            Some(self.f64()?)
        } else {
            None
        })
    }
    fn record(&mut self) -> Res<TileRecord> {
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
}

/// Reads a job's result; `Err` says what is wrong with the bytes.
pub(crate) fn decode(bytes: &[u8]) -> Res<JobFile> {
    let mut r = R(bytes);
    if r.take(8)? != MAGIC {
        return Err(WireError::NotAJobResult);
    }
    let plan_digest = r.str()?;
    let job = r.u64()? as usize;
    let seconds = r.f64()?;
    let tiles = r.vec(57, |r| Ok((r.u64()? as usize, r.record()?)))?;
    let roots = r.vec(8, |r| {
        let i = r.u64()? as usize;
        let content = r.content()?;
        let geometric_error_m = r.f64()?;
        let coarse_to_full_m = r.f64()?;
        let max_folding_edge_m = r.f64()?;
        let cut_triangles = r
            .vec(12, |r| Ok((ComponentId(r.u32()?), r.u64()? as usize)))?
            .into_iter()
            .collect();
        Ok((
            i,
            BuiltSubtree {
                content,
                geometric_error_m,
                coarse_to_full_m,
                max_folding_edge_m,
                cut_triangles,
            },
        ))
    })?;
    if r.0 != END {
        return Err(WireError::NoEndMark);
    }
    Ok(JobFile {
        plan_digest,
        job,
        seconds,
        output: JobOutput { tiles, roots },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_is_exact_and_truncation_is_refused() {
        let prim = ContentPrimitive {
            material: Some(MaterialId(3)),
            positions: vec![[0.1, -2.5e-7, f32::MAX], [1.0, 2.0, 3.0]],
            normals: vec![[0.0, 0.0, 1.0]; 2],
            uvs: vec![[0.3, 0.7]; 2],
            colors: vec![],
            feature_ids: vec![0, 1],
            indices: vec![0, 1, 1],
        };
        let content = TileContent {
            center: DVec3::new(0.1, 1e-300, -7.25),
            features: vec![ComponentId(4), ComponentId(9)],
            primitives: vec![prim.clone(), ContentPrimitive::default()],
            instanced: vec![InstancedShape {
                mesh: MeshId(2),
                primitives: vec![prim],
                instances: vec![ShapeInstance {
                    feature: 1,
                    transform: DMat4::from_rotation_z(0.3),
                }],
            }],
        };
        let f = JobFile {
            plan_digest: "abc".into(),
            job: 3,
            seconds: 1.5,
            output: JobOutput {
                tiles: vec![(
                    7,
                    TileRecord {
                        uri: Some("tiles/r0.glb".into()),
                        geometric_error_m: 0.1 + 0.2,
                        content: ContentFigures {
                            bytes: 1234,
                            triangles: 5,
                            metadata_bytes: 77,
                            edge_bytes: 12,
                            edge_gzip_bytes: 9,
                            bounds: Aabb {
                                min: DVec3::new(-1.0, 0.25, 1e-9),
                                max: DVec3::new(2.0, 0.5, 3.0),
                            },
                            ..Default::default()
                        },
                        full_to_coarse_m: Some(1.0 / 3.0),
                        paper_error_m: Some(0.7),
                        max_position_error_m: Some(0.02),
                        ..Default::default()
                    },
                )],
                roots: vec![(
                    7,
                    BuiltSubtree {
                        content,
                        geometric_error_m: 2.0f64.sqrt(),
                        coarse_to_full_m: 0.5,
                        max_folding_edge_m: 0.25,
                        cut_triangles: [(ComponentId(4), 12)].into_iter().collect(),
                    },
                )],
            },
        };
        let bytes = encode(&f);
        assert_eq!(decode(&bytes).unwrap(), f);
        for cut in [1, 9, bytes.len() / 2, bytes.len() - 1] {
            assert!(decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        assert_eq!(decode(b"BIMTJOB2"), Err(WireError::NotAJobResult));
        let mut trailing = bytes.clone();
        trailing.push(0);
        assert_eq!(decode(&trailing), Err(WireError::NoEndMark));
    }
}
