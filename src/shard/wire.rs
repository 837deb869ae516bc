//! The binary result file of one sharded job (`jobs/job-K.bin`): the figures of every tile the job
//! wrote and, for HLOD, what each of its subtree roots hands its parent (content, errors, cut
//! triangle counts), in the encoding of `crate::lod::wire`. Floats are stored as their bits, so `merge` gets exactly what the job had and
//! the merged tileset is byte-identical to `convert`'s. Little-endian; a magic at the start and an
//! end mark, so a truncated file is refused. A tile's plan path, depth and LOD level are not
//! stored: `merge` sets them from the plan. An update's job adds its part of the tile cache
//! (`crate::lod::subtree_cache::SubtreeCache::export`).

use crate::lod::wire::{Res, WireError, R, W};
use crate::tiling::JobOutput;

const MAGIC: &[u8; 8] = b"BIMTJOB4";
const END: &[u8; 4] = b"END.";

/// A job's result as stored.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct JobFile {
    pub plan_digest: String,
    pub job: usize,
    pub seconds: f64,
    pub output: JobOutput,
    /// An update's job: its part of the tile cache.
    pub cache: Option<Vec<u8>>,
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
        w.subtree(r);
    }
    w.opt(&f.cache, |w, c| {
        w.n(c.len());
        w.0.extend_from_slice(c);
    });
    w.0.extend_from_slice(END);
    w.0
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
    let roots = r.vec(8, |r| Ok((r.u64()? as usize, r.subtree()?)))?;
    let cache = match r.flag()? {
        true => {
            let n = r.n(1)?;
            Some(r.take(n)?.to_vec())
        }
        false => None,
    };
    if r.0 != END {
        return Err(WireError::NoEndMark);
    }
    Ok(JobFile {
        plan_digest,
        job,
        seconds,
        output: JobOutput { tiles, roots },
        cache,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encode::{ContentFigures, TileRecord};
    use crate::lod::hlod::BuiltSubtree;
    use crate::partition::content::{ContentPrimitive, InstancedShape, ShapeInstance, TileContent};
    use crate::scene::{Aabb, ComponentId, MaterialId, MeshId};
    use glam::{DMat4, DVec3};

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
            cache: Some(vec![1, 2, 3]),
        };
        let bytes = encode(&f);
        assert_eq!(decode(&bytes).unwrap(), f);
        for cut in [1, 9, bytes.len() / 2, bytes.len() - 1] {
            assert!(decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        assert_eq!(decode(b"BIMTJOB3"), Err(WireError::NotAJobResult));
        let mut trailing = bytes.clone();
        trailing.push(0);
        assert_eq!(decode(&trailing), Err(WireError::NoEndMark));
    }
}
