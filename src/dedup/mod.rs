//! Redundant and repeated components (paper, section III.A).
//!
//! BIM exporters bake every window, door and column into its own mesh in world coordinates, and
//! sometimes write the same element twice. This stage finds both in a [`Scene`] and rewrites it:
//! * **exact duplicates** (same geometry at the same place, same materials, within a tolerance):
//!   all but the lowest id become aliases ([`Component::alias_of`]); they stay in the scene with
//!   their identity and metadata, and later stages skip their geometry;
//! * **congruent components** (same shape up to a rigid motion, optionally a uniform scale): they
//!   are rewritten to share one prototype mesh, each with its own `world`, so the GLB writer can
//!   store the shape once and place it per instance (`EXT_mesh_gpu_instancing`), keeping each
//!   instance's feature ID. glTF-level reuse (nodes already sharing a mesh) is kept as it is.
//!
//! Candidates are bucketed by an exact signature (per primitive: material, vertex and index
//! counts, attributes) and by motion-invariant moments, so the work is near-linear in the number of
//! components; matching itself is in [`matcher`](self::matcher). Every rewrite is verified vertex by
//! vertex (or triangle by triangle) against the input within the tolerance, so expanding the
//! output reproduces the input.

pub mod geom;
mod matcher;

use crate::scene::{ComponentId, MaterialId, MeshId, MeshStore, Scene};
use geom::Similarity;
use glam::{DMat3, DMat4, DVec3};
use matcher::{
    find_motion_same_order, find_motion_search, InvariantKey, Invariants, MatchKind, SameOrder,
    Shape, Tol, ICP_RUNS_PER_CANDIDATE,
};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};

/// What to look for, and how close is the same.
#[derive(Debug, Clone, PartialEq)]
pub struct DedupOptions {
    /// Largest distance, in metres, between corresponding vertices of two components that are
    /// still the same geometry. Default 1 mm.
    pub tolerance_m: f64,
    /// Largest angle between corresponding normals, in degrees. Default 2°.
    pub normal_tolerance_deg: f64,
    /// Also match copies that are uniformly scaled (off by default: a scaled window is a
    /// different product).
    pub allow_uniform_scale: bool,
    /// Mark exact duplicates as aliases.
    pub exact: bool,
    /// Rewrite congruent components to share a mesh.
    pub congruent: bool,
    /// Empty (in place, so every `MeshId` stays valid) the meshes that no component references
    /// any more, to free their memory.
    pub release_unused_meshes: bool,
}

impl Default for DedupOptions {
    fn default() -> Self {
        DedupOptions {
            tolerance_m: 0.001,
            normal_tolerance_deg: 2.0,
            allow_uniform_scale: false,
            exact: true,
            congruent: true,
            release_unused_meshes: true,
        }
    }
}

/// What dedup found and what it saves. "Drawn" counts every component the writer draws (aliases
/// are not drawn); "stored" counts each mesh once.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct DedupReport {
    pub components: usize,
    /// Distinct meshes drawn before (glTF-level reuse already shares some).
    pub unique_shapes_before: usize,
    /// Distinct meshes drawn after.
    pub unique_shapes: usize,
    /// Components drawn through a mesh that at least one other drawn component also uses, before
    /// (glTF-level reuse) and after.
    pub instanced_components_before: usize,
    pub instanced_components: usize,
    /// Components moved onto another component's mesh (baked copies found).
    pub congruent_rewritten: usize,
    /// Of those, how many were matched vertex by vertex in input order, and how many needed the
    /// frame search.
    pub matched_same_order: usize,
    pub matched_by_search: usize,
    /// Meshes left unshared because they are noisy copies of another: the same vertex order,
    /// every vertex within a few tolerances, some beyond one (a larger `--dedup-tolerance-m`
    /// would share them).
    pub near_twins: usize,
    /// Exact duplicates marked as aliases.
    pub redundant_removed: usize,
    /// Meshes no longer referenced by any component, emptied in place.
    pub meshes_released: usize,
    pub triangles_before: usize,
    pub triangles_after: usize,
    pub triangles_stored_before: usize,
    pub triangles_stored_after: usize,
    /// Estimated uncompressed geometry bytes: before, every component's mesh written expanded (what
    /// a writer without instancing does); after, each drawn mesh once, plus per-instance
    /// transforms and feature IDs for shared meshes.
    pub bytes_before: usize,
    pub bytes_after: usize,
    pub tolerance_m: f64,
    pub seconds: f64,
}

/// One mesh and the drawn components that use it (in id order): the unit the instanced writer
/// stores once and places per component with `world`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShapeGroup {
    pub mesh: MeshId,
    pub components: Vec<ComponentId>,
}

/// Per-instance bytes in instanced output: TRANSLATION, ROTATION, SCALE as f32 (40) and a feature
/// ID (4).
const INSTANCE_BYTES: usize = 44;

/// Every mesh drawn by at least one component (aliases are not drawn), with its drawn users, in
/// `MeshId` order. Groups with more than one component are what `EXT_mesh_gpu_instancing` writes.
pub fn shape_groups(scene: &Scene) -> Vec<ShapeGroup> {
    let mut users: BTreeMap<MeshId, Vec<ComponentId>> = BTreeMap::new();
    for c in scene.components.iter().filter(|c| c.alias_of.is_none()) {
        users.entry(c.mesh).or_default().push(c.id);
    }
    users
        .into_iter()
        .map(|(mesh, components)| ShapeGroup { mesh, components })
        .collect()
}

/// Finds exact duplicates and congruent components in `scene` and rewrites it in place (see the
/// module doc): aliases get `alias_of`, congruent components get the prototype's `mesh` and an
/// adjusted `world`. Component ids, keys, nodes and `info` are untouched; mesh ids stay valid
/// (unreferenced meshes are emptied, not removed, when `release_unused_meshes`). Deterministic:
/// the result does not depend on thread count.
pub fn deduplicate(scene: &mut Scene, opts: &DedupOptions) -> DedupReport {
    let started = std::time::Instant::now();
    let tol = Tol {
        pos: if opts.tolerance_m.is_finite() && opts.tolerance_m >= 0.0 {
            opts.tolerance_m
        } else {
            DedupOptions::default().tolerance_m
        },
        cos_normal: opts
            .normal_tolerance_deg
            .clamp(0.0, 180.0)
            .to_radians()
            .cos(),
        allow_scale: opts.allow_uniform_scale,
    };
    let before = Counts::of(scene);
    let referenced_before: Vec<bool> = referenced(scene);

    let canon = canonical_materials(scene);
    let mesh_sig: Vec<Option<u32>> = signature_ids(&scene.meshes, &canon);

    let mut report = DedupReport {
        components: scene.components.len(),
        tolerance_m: tol.pos,
        ..Default::default()
    };
    if opts.exact {
        let aliases = exact_duplicates(scene, &mesh_sig, &tol);
        report.redundant_removed = aliases.len();
        for (alias, kept) in aliases {
            scene.components[alias.index()].alias_of = Some(kept);
        }
    }
    let mut changed = false;
    if opts.congruent {
        let (moves, near_twins) = congruent_moves(scene, &mesh_sig, &tol);
        report.near_twins = near_twins;
        for &(c, mesh, world, kind) in &moves {
            let comp = &mut scene.components[c.index()];
            comp.mesh = mesh;
            comp.world = world;
            match kind {
                MatchKind::SameOrder => report.matched_same_order += 1,
                MatchKind::Triangles => report.matched_by_search += 1,
            }
        }
        report.congruent_rewritten = moves.len();
        changed = !moves.is_empty();
    }
    if opts.release_unused_meshes {
        let now = referenced(scene);
        for i in 0..scene.meshes.len() {
            if referenced_before[i] && !now[i] {
                scene.meshes.release(MeshId(i as u32));
                report.meshes_released += 1;
            }
        }
    }
    if changed || report.meshes_released > 0 {
        // Boxes of moved components change by up to the tolerance; recompute them exactly.
        scene.finish();
    }
    let after = Counts::of(scene);
    report.unique_shapes_before = before.unique_shapes;
    report.unique_shapes = after.unique_shapes;
    report.instanced_components_before = before.instanced;
    report.instanced_components = after.instanced;
    report.triangles_before = before.drawn_triangles;
    report.triangles_after = after.drawn_triangles;
    report.triangles_stored_before = before.expanded_triangles;
    report.triangles_stored_after = after.stored_triangles;
    report.bytes_before = before.expanded_bytes;
    report.bytes_after = after.instanced_bytes;
    report.seconds = started.elapsed().as_secs_f64();
    report
}

fn referenced(scene: &Scene) -> Vec<bool> {
    let mut r = vec![false; scene.meshes.len()];
    for c in &scene.components {
        if let Some(x) = r.get_mut(c.mesh.index()) {
            *x = true;
        }
    }
    r
}

/// Size figures of a scene as the writers would store it.
struct Counts {
    unique_shapes: usize,
    instanced: usize,
    drawn_triangles: usize,
    /// Every component written expanded, aliases included (a writer that knows nothing of dedup).
    expanded_triangles: usize,
    expanded_bytes: usize,
    stored_triangles: usize,
    instanced_bytes: usize,
}

impl Counts {
    fn of(scene: &Scene) -> Counts {
        let meshes = &scene.meshes;
        let known = |m: MeshId| m.index() < meshes.len();
        let groups = shape_groups(scene);
        let mut k = Counts {
            unique_shapes: groups.len(),
            instanced: 0,
            drawn_triangles: 0,
            expanded_triangles: 0,
            expanded_bytes: 0,
            stored_triangles: 0,
            instanced_bytes: 0,
        };
        for c in scene.components.iter().filter(|c| known(c.mesh)) {
            k.expanded_triangles += meshes.triangle_count(c.mesh);
            k.expanded_bytes += meshes.estimated_bytes(c.mesh);
        }
        for g in groups.iter().filter(|g| known(g.mesh)) {
            let triangles = meshes.triangle_count(g.mesh);
            k.drawn_triangles += triangles * g.components.len();
            k.stored_triangles += triangles;
            k.instanced_bytes += meshes.estimated_bytes(g.mesh);
            if g.components.len() > 1 {
                k.instanced += g.components.len();
                k.instanced_bytes += INSTANCE_BYTES * g.components.len();
            }
        }
        k
    }
}

/// Each material's lowest-id equal material: two materials that render the same do not make two
/// shapes different (readers may create one per element).
fn canonical_materials(scene: &Scene) -> Vec<u32> {
    let mut first: BTreeMap<String, u32> = BTreeMap::new();
    scene
        .materials
        .iter()
        .enumerate()
        .map(|(i, m)| *first.entry(format!("{m:?}")).or_insert(i as u32))
        .collect()
}

/// The exact part of a mesh's signature, per primitive: canonical material, vertex count, index
/// count, attributes present. Continuous invariants are bucketed separately (with neighbouring
/// cells), because quantising them into this key would split true copies that straddle a cell
/// boundary.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct PrimSig {
    material: u32,
    vertices: usize,
    indices: usize,
    attrs: u8,
}

/// Signature id per mesh (equal ids: equal exact signatures); None for meshes without triangles,
/// which have no shape to share.
fn signature_ids(meshes: &MeshStore, canon: &[u32]) -> Vec<Option<u32>> {
    let sigs: Vec<Option<Vec<PrimSig>>> = meshes.par_map(|m| {
        if m.triangle_count() == 0 {
            return None;
        }
        Some(
            m.primitives
                .iter()
                .map(|p| PrimSig {
                    material: p.material.map_or(u32::MAX, |MaterialId(x)| {
                        canon.get(x as usize).copied().unwrap_or(x)
                    }),
                    vertices: p.positions.len(),
                    indices: p.indices.len(),
                    attrs: u8::from(p.normals.is_some())
                        | u8::from(p.uvs.is_some()) << 1
                        | u8::from(p.colors.is_some()) << 2,
                })
                .collect(),
        )
    });
    let mut ids: BTreeMap<Vec<PrimSig>, u32> = BTreeMap::new();
    sigs.into_iter()
        .map(|s| {
            let next = ids.len() as u32;
            s.map(|s| *ids.entry(s).or_insert(next))
        })
        .collect()
}

/// Integer cell of `x` on a grid of `size`.
fn cell(x: f64, size: f64) -> i64 {
    (x / size).floor().clamp(-1e15, 1e15) as i64
}

fn neighbours(k: [i64; 3]) -> impl Iterator<Item = [i64; 3]> {
    (0..27).map(move |i| [k[0] + i % 3 - 1, k[1] + (i / 3) % 3 - 1, k[2] + i / 9 - 1])
}

/// (alias, kept) pairs: components whose world geometry equals that of a lower-id component at
/// the same place. Candidates share the exact signature and a world-centroid cell (or a
/// neighbouring one); each is then verified vertex by vertex. Kept components are never aliases,
/// so every alias points at a drawn component.
fn exact_duplicates(
    scene: &Scene,
    mesh_sig: &[Option<u32>],
    tol: &Tol,
) -> Vec<(ComponentId, ComponentId)> {
    let size = (4.0 * tol.pos).max(1e-9);
    let centroids: Vec<Option<DVec3>> = scene.meshes.par_map(|m| {
        let n = m.vertex_count();
        (n > 0).then(|| {
            m.primitives
                .iter()
                .flat_map(|p| p.positions.iter())
                .map(|v| DVec3::from_array(v.map(f64::from)))
                .sum::<DVec3>()
                / n as f64
        })
    });
    // The vertex centroid is affine-equivariant: world centroid = world · local centroid.
    let keys: Vec<Option<(u32, DVec3)>> = scene
        .components
        .par_iter()
        .map(|c| {
            if c.alias_of.is_some() {
                return None;
            }
            let sig = (*mesh_sig.get(c.mesh.index())?)?;
            let w = c.world.transform_point3((*centroids.get(c.mesh.index())?)?);
            w.is_finite().then_some((sig, w))
        })
        .collect();
    let mut grid: HashMap<(u32, [i64; 3]), Vec<u32>> = HashMap::new();
    let mut out = Vec::new();
    for (i, key) in keys.iter().enumerate() {
        let Some((sig, w)) = *key else { continue };
        let k = [cell(w.x, size), cell(w.y, size), cell(w.z, size)];
        let mut cands: Vec<u32> = neighbours(k)
            .filter_map(|n| grid.get(&(sig, n)))
            .flatten()
            .copied()
            .filter(|&j| keys[j as usize].is_some_and(|(_, wj)| wj.distance(w) <= tol.pos))
            .collect();
        cands.sort_unstable();
        let c = &scene.components[i];
        let mut shape_c: Option<Shape> = None;
        let kept = cands.into_iter().find(|&j| {
            let p = &scene.components[j as usize];
            let sc = shape_c.get_or_insert_with(|| Shape::new(scene.mesh(c.mesh), &c.world));
            let sp = Shape::new(scene.mesh(p.mesh), &p.world);
            // Identity motion: the alias would be drawn by the kept component as it is.
            MatchKind::SameOrder.verify(sc, &sp, &DMat4::IDENTITY, sp.mirrored, tol)
                || MatchKind::Triangles.verify(sc, &sp, &DMat4::IDENTITY, sp.mirrored, tol)
        });
        match kept {
            Some(j) => out.push((ComponentId(i as u32), ComponentId(j))),
            None => grid.entry((sig, k)).or_default().push(i as u32),
        }
    }
    out
}

/// A mesh (through its lowest-id drawn user, `rep`) found congruent to a prototype mesh.
struct Found {
    mesh: MeshId,
    rep: ComponentId,
    proto_rep: ComponentId,
    /// Scene-frame motion carrying the prototype rep's world geometry onto `rep`'s.
    motion: Similarity,
    kind: MatchKind,
}

/// Bucket key of the motion-invariant moments: cells of 4δ in each principal extent (true copies
/// differ by at most 2δ, so they fall in the same or a neighbouring cell). With scale allowed,
/// the extents' ratios instead.
fn moment_cell(inv: &Invariants, tol: &Tol) -> [i64; 3] {
    let s = inv.moments.sigma;
    if tol.allow_scale {
        // Shapes smaller than ~200·δ may straddle more than one ratio cell and be missed when
        // scaled; exact-size copies of them are still found by the same cell.
        let r = |x: f64| if s[0] > 0.0 { x / s[0] } else { 0.0 };
        [cell(r(s[1]), 0.02), cell(r(s[2]), 0.02), 0]
    } else {
        let size = (4.0 * tol.pos).max(1e-9);
        s.map(|x| cell(x, size))
    }
}

/// Prototypes a component is compared with, nearest invariants first: by the same-order fit
/// (cheap), then by the frame search (ICP, costly; it also stops once `ICP_RUNS_PER_CANDIDATE`
/// are spent). A true copy is within the tolerance, so its invariants are about as close as they
/// can be; on the shared models, one search try loses matches, two find all that an unbounded
/// search finds (four are allowed, for margin). Without a bound, a bucket of n near-twins that
/// never match (noisy copies of one part) costs n²/2 comparisons (docs/benchmarks.md).
const SAME_ORDER_TRIES: usize = 8;
const SEARCH_TRIES: usize = 4;

/// A prototype of [`cluster`]: the first member of a group, which later members are compared with.
struct Proto {
    rep: ComponentId,
    mesh: MeshId,
    /// Kept while the bucket's kept shapes stay within its share of the working memory, else
    /// rebuilt on use: a bucket of near-twins (noisy copies, all prototypes) would otherwise hold
    /// every copy's geometry in f64 at once, whatever the memory budget.
    shape: Option<Shape>,
    inv: Invariants,
}

impl Proto {
    /// Its shape: the kept one, or one rebuilt from the store into `rebuilt`.
    fn shape<'p>(&'p self, scene: &Scene, rebuilt: &'p mut Option<Shape>) -> &'p Shape {
        match &self.shape {
            Some(s) => s,
            None => rebuilt.insert(Shape::new(
                scene.mesh(self.mesh),
                &scene.components[self.rep.index()].world,
            )),
        }
    }
}

/// Greedy clustering of one signature bucket, in rep-id order: each mesh is compared with the
/// nearest prototypes found so far whose invariants are compatible; the first verified match
/// wins, else it becomes a prototype. Comparing with prototypes only (never with other members)
/// keeps every member within the tolerance of the geometry it will be drawn with.
/// Also returns how many meshes stayed prototypes as near-twins of one (see `SameOrder::NearTwin`).
fn cluster(
    scene: &Scene,
    meshes: &[(MeshId, ComponentId)],
    tol: &Tol,
    shape_bytes: usize,
) -> (Vec<Found>, usize) {
    let mut kept_bytes = 0usize;
    let mut protos: Vec<Proto> = Vec::new();
    // Per cell: prototype index and its comparison key, side by side for the scan.
    let mut grid: HashMap<[i64; 3], Vec<(usize, InvariantKey)>> = HashMap::new();
    let mut out = Vec::new();
    let mut near_twins = 0;
    for &(mesh, rep) in meshes {
        let c = &scene.components[rep.index()];
        // Loaded one at a time: a member that matches is dropped at once.
        let geometry = scene.mesh(mesh);
        let geometry_bytes = geometry.heap_bytes();
        let shape = Shape::new(geometry, &c.world);
        let Some(inv) = Invariants::of(&shape) else {
            continue;
        };
        let key = moment_cell(&inv, tol);
        let inv_key = inv.key();
        let mut cands: Vec<(f64, usize)> = neighbours(key)
            .filter_map(|k| grid.get(&k))
            .flatten()
            .map(|(pi, k)| (inv_key.mismatch(k, tol), *pi))
            .filter(|&(d, _)| d <= 1.0)
            .collect();
        // Nearest first, then input order (deterministic). Only the first few are tried: those
        // are selected, then sorted (sorting every compatible prototype dominates the dedup of
        // noisy copies, whose buckets hold many near-twins).
        let order = |a: &(f64, usize), b: &(f64, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
        let tried = SAME_ORDER_TRIES.max(SEARCH_TRIES);
        if cands.len() > tried {
            cands.select_nth_unstable_by(tried - 1, order);
            cands.truncate(tried);
        }
        cands.sort_unstable_by(order);
        // The same-order fit (one fit and one pass each) first, the frame search only when none
        // matches that way.
        let mut near_twin = false;
        let hit = cands
            .iter()
            .take(SAME_ORDER_TRIES)
            .find_map(|&(_, pi)| {
                let mut rebuilt = None;
                let ps = protos[pi].shape(scene, &mut rebuilt);
                match find_motion_same_order(&shape, ps, tol) {
                    SameOrder::Match(m) => Some((pi, (m, MatchKind::SameOrder))),
                    SameOrder::NearTwin => {
                        near_twin = true;
                        None
                    }
                    SameOrder::No => None,
                }
            })
            .or_else(|| {
                // A noisy copy of a prototype: the search would not find a motion either.
                if near_twin {
                    return None;
                }
                let mut icp_budget = ICP_RUNS_PER_CANDIDATE;
                cands.iter().take(SEARCH_TRIES).find_map(|&(_, pi)| {
                    let p = &protos[pi];
                    let mut rebuilt = None;
                    let ps = p.shape(scene, &mut rebuilt);
                    find_motion_search(&shape, &inv, ps, &p.inv, tol, &mut icp_budget)
                        .map(|m| (pi, (m, MatchKind::Triangles)))
                })
            });
        match hit {
            Some((pi, (motion, kind))) => out.push(Found {
                mesh,
                rep,
                proto_rep: protos[pi].rep,
                motion,
                kind,
            }),
            None => {
                near_twins += usize::from(near_twin);
                grid.entry(key).or_default().push((protos.len(), inv_key));
                let bytes = shape.heap_bytes() + geometry_bytes;
                let keep = kept_bytes.saturating_add(bytes) <= shape_bytes;
                kept_bytes += if keep { bytes } else { 0 };
                protos.push(Proto {
                    rep,
                    mesh,
                    shape: keep.then_some(shape),
                    inv,
                });
            }
        }
    }
    (out, near_twins)
}

/// Components to move onto a prototype mesh: (component, new mesh, new world, how it was
/// matched) in component-id order; and the number of near-twins left as they were.
fn congruent_moves(
    scene: &Scene,
    mesh_sig: &[Option<u32>],
    tol: &Tol,
) -> (Vec<(ComponentId, MeshId, DMat4, MatchKind)>, usize) {
    // Drawn users of each mesh, in id order; the first is the mesh's representative.
    let mut users: Vec<Vec<ComponentId>> = vec![Vec::new(); scene.meshes.len()];
    for c in &scene.components {
        if c.alias_of.is_none() && mesh_sig.get(c.mesh.index()).is_some_and(|s| s.is_some()) {
            users[c.mesh.index()].push(c.id);
        }
    }
    let mut buckets: BTreeMap<u32, Vec<(MeshId, ComponentId)>> = BTreeMap::new();
    let mut reps: Vec<(ComponentId, MeshId)> = users
        .iter()
        .enumerate()
        .filter_map(|(m, u)| u.first().map(|&r| (r, MeshId(m as u32))))
        .collect();
    reps.sort_unstable();
    for (rep, mesh) in reps {
        if let Some(sig) = mesh_sig[mesh.index()] {
            buckets.entry(sig).or_default().push((mesh, rep));
        }
    }
    // Buckets are independent: cluster them in parallel, collect in bucket order. Each running
    // bucket may keep its share of the store's working memory in prototype shapes.
    let buckets: Vec<Vec<(MeshId, ComponentId)>> = buckets.into_values().collect();
    let shape_bytes = scene.meshes.limits().working_bytes / rayon::current_num_threads().max(1);
    let clustered: Vec<(Vec<Found>, usize)> = buckets
        .par_iter()
        .map(|b| cluster(scene, b, tol, shape_bytes))
        .collect();
    let near_twins = clustered.iter().map(|c| c.1).sum();
    let found: Vec<Found> = clustered.into_iter().flat_map(|c| c.0).collect();
    // Every drawn user of a matched mesh moves with its representative; users other than the
    // representative are verified on their own (their world may scale differently).
    let jobs: Vec<(ComponentId, &Found)> = found
        .iter()
        .flat_map(|f| users[f.mesh.index()].iter().map(move |&d| (d, f)))
        .collect();
    let results: Vec<Option<(ComponentId, MeshId, DMat4, MatchKind)>> = jobs
        .par_iter()
        .map(|&(d, f)| {
            let proto = &scene.components[f.proto_rep.index()];
            let motion = f.motion.to_mat4();
            let m = if d == f.rep {
                motion
            } else {
                let rep_world = scene.components[f.rep.index()].world;
                let inv = rep_world.inverse();
                let comp = &scene.components[d.index()];
                let m = comp.world * inv * motion;
                if !m.is_finite() {
                    return None;
                }
                let sd = Shape::new(scene.mesh(comp.mesh), &comp.world);
                let sp = Shape::new(scene.mesh(proto.mesh), &proto.world);
                let mirrored = DMat3::from_mat4(m * proto.world).determinant() < 0.0;
                if !f.kind.verify(&sd, &sp, &m, mirrored, tol) {
                    return None;
                }
                m
            };
            Some((d, proto.mesh, m * proto.world, f.kind))
        })
        .collect();
    let mut moves: Vec<(ComponentId, MeshId, DMat4, MatchKind)> =
        results.into_iter().flatten().collect();
    moves.sort_unstable_by_key(|m| m.0);
    (moves, near_twins)
}

#[cfg(test)]
mod tests;
