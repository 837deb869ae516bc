//! Edge visibility of a triangle primitive, as `EXT_mesh_primitive_edge_visibility` (Khronos
//! glTF, `extensions/2.0/Vendor/EXT_mesh_primitive_edge_visibility`, "Edge Visibility") stores
//! it: 2 bits per triangle edge, `(v0:v1, v1:v2, v2:v0)` per triangle in index order, 4 edges a
//! byte from the low bits up; `0` hidden, `1` silhouette, `2` hard, `3` a hard edge already
//! encoded as `2` on an adjoining triangle.
//!
//! Edges are found on the element's shape, not on its triangle soup: vertices of one element
//! (one feature ID) within the weld step's tolerance (`simplify::SimplifyOptions::weld_tolerance_m`)
//! are one corner, so the edge between two faces an exporter split for flat shading is seen as
//! shared; vertices of different elements are never welded, so touching elements keep their
//! outlines. Then, per welded edge:
//! - used by one triangle (a boundary), or by three or more: hard;
//! - used by two whose dihedral angle is above the crease angle: hard;
//! - at or below [`COPLANAR_MAX_DEG`]: hidden (the diagonal of a flat face);
//! - in between, a smooth edge of a curved surface: a silhouette ([`EdgeMode::All`]) or hidden.
//!
//! An edge used by one triangle of the primitive is not always the element's boundary: where the
//! octree cut a large element between tiles, its surface goes on in the next tile. Given the rest
//! of the element's surface ([`Seams`]), such an edge is judged as the whole surface would have
//! it: a seam across a flat or smoothly curved face is hidden, so a cut draws no line; a crease
//! that the cut follows stays hard.
//!
//! The spec's once-only rules hold by construction: of the occurrences of a welded edge, the
//! first in index order carries `2` (or `1`) and the others `3` (or `0`).
//!
//! Silhouettes need companion data. The spec's latest draft names it `silhouetteMates`; the
//! CesiumJS this project pins reads the earlier `silhouetteNormals` (the two faces' normals per
//! silhouette edge, in the order the `1`s are met, read as VEC3 and normalized). What is written
//! is chosen here alone: [`SILHOUETTE_PROPERTY`] and [`EdgeVisibility::silhouette_normals`].

use glam::DVec3;
use std::collections::HashMap;

/// Which edges tiles carry (`--edges`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EdgeMode {
    /// No `EXT_mesh_primitive_edge_visibility` (the default until edges cost less).
    #[default]
    None,
    /// Hard edges only (outlines and creases).
    Hard,
    /// Hard edges and the silhouettes of curved surfaces.
    All,
}

impl EdgeMode {
    /// The one spelling of this mode (the CLI's value and the report's).
    pub fn name(self) -> &'static str {
        match self {
            EdgeMode::None => "none",
            EdgeMode::Hard => "hard",
            EdgeMode::All => "all",
        }
    }
}

/// How edges are found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeOptions {
    pub mode: EdgeMode,
    /// Two faces meeting at more than this dihedral angle (degrees) make a hard edge.
    pub crease_angle_deg: f64,
}

impl Default for EdgeOptions {
    fn default() -> Self {
        EdgeOptions {
            mode: EdgeMode::default(),
            crease_angle_deg: DEFAULT_CREASE_ANGLE_DEG,
        }
    }
}

/// Default crease angle: above the facet angle of the round profiles building models are
/// tessellated with (pipes, columns and ducts in 16 to 36 segments turn 10° to 22.5° a facet,
/// so they draw as silhouettes, not as a cage of lines), and below the mitres and chamfers that
/// read as edges. Chosen by measurement (the edges page of the book).
pub const DEFAULT_CREASE_ANGLE_DEG: f64 = 20.0;

/// Two faces of one element that meet at this dihedral angle or less (degrees) are one plane:
/// the edge between them is hidden. The position grid turns small faces by a degree or so (a
/// millimetre over a few centimetres), and what it turns are not surfaces to outline; round
/// profiles turn 10° and more a facet.
pub const COPLANAR_MAX_DEG: f64 = 2.0;

/// Steps of a silhouette normal's components as written (normalized i8): 8, so 31 values a
/// component, within about 2° of the face. A silhouette is drawn where one face turns to the
/// viewer and the other away; 2° moves that by 2° of view, and the coarser values cost gzip
/// half the bytes of full i8.
const SILHOUETTE_NORMAL_STEP: f64 = 8.0;

/// A silhouette normal as written: a normalized i8 VEC3 on [`SILHOUETTE_NORMAL_STEP`].
pub fn silhouette_normal_i8(n: [f32; 3]) -> [i8; 3] {
    n.map(|x| {
        let q = (x.clamp(-1.0, 1.0) as f64 * 127.0 / SILHOUETTE_NORMAL_STEP).round();
        (q * SILHOUETTE_NORMAL_STEP).clamp(-127.0, 127.0) as i8
    })
}

/// Whether a silhouette whose faces have these normals can ever be drawn: a client draws it
/// where one face turns to the viewer and the other away, which two faces written with one
/// normal never do. Where a curve's faces are finer than the normals' steps, the outline is drawn
/// on the edges where the written normal changes, so no view loses its outline; the edges in
/// between would cost their normals and draw nothing.
pub fn silhouette_can_draw(normals: [[f32; 3]; 2]) -> bool {
    silhouette_normal_i8(normals[0]) != silhouette_normal_i8(normals[1])
}

/// Twice the area (m²) below which a triangle has no direction: a sliver whose normal is noise.
const MIN_DOUBLE_AREA_M2: f64 = 1e-12;

/// The name of the silhouette companion data in the extension's JSON: what the pinned CesiumJS
/// reads (`GltfLoader.loadEdgeVisibility`), not the newer draft's `silhouetteMates`.
pub const SILHOUETTE_PROPERTY: &str = "silhouetteNormals";

/// The extension's name.
pub const EXTENSION: &str = "EXT_mesh_primitive_edge_visibility";

/// The colour of the edges (linear RGBA), as the base colour of the material the extension's
/// `material` names: without one, CesiumJS draws an edge in its surface's own unlit colour, which
/// is lighter than a lit face and hard to see; drawings show edges as dark lines.
pub const EDGE_COLOR: [f32; 4] = [0.02, 0.02, 0.02, 1.0];

/// An element's whole surface (every triangle of it in the scene, not only those in the tile), in
/// the frame of the drawn positions, with each face's material.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WholeSurface {
    pub positions: Vec<[f32; 3]>,
    pub indices: Vec<u32>,
    /// Per triangle, its material (any number that tells materials apart): a seam runs between
    /// faces of one material; where the material changes the element has an edge of its own.
    pub face_materials: Vec<u32>,
}

/// Where the rest of each element's surface is (by group) and how far a drawn vertex may lie from
/// its place on that surface (the position grid and the weld), to tell seams from boundaries.
pub struct Seams<'a> {
    pub whole_surface: &'a dyn Fn(u32) -> Option<WholeSurface>,
    pub tolerance_m: f64,
}

/// Visibility values (the spec's "Edge Visibility").
pub const HIDDEN: u8 = 0;
pub const SILHOUETTE: u8 = 1;
pub const HARD: u8 = 2;
pub const REPEATED_HARD: u8 = 3;

/// One primitive's edges, ready to write.
#[derive(Debug, Clone, PartialEq)]
pub struct EdgeVisibility {
    /// The bitfield: `ceil(6 N / 8)` bytes for N triangles, unused bits zero.
    pub visibility: Vec<u8>,
    /// Per edge encoded `1`, in the order they are met, the normals of the face that encodes it
    /// and of the face across it, turned to the first's side where the two are wound against
    /// each other (unit vectors, the positions' frame).
    pub silhouette_normals: Vec<[[f32; 3]; 2]>,
    /// Edges (welded) that are hard and silhouettes.
    pub hard_edges: usize,
    pub silhouette_edges: usize,
}

/// The visibility value of edge `k` (triangle `k / 3`, edge `k % 3`) in a bitfield.
pub fn value_at(visibility: &[u8], k: usize) -> u8 {
    (visibility[k / 4] >> ((k % 4) * 2)) & 3
}

/// Packs one value per triangle edge into the bitfield (4 a byte, low bits first).
pub fn pack(values: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; (values.len() * 2).div_ceil(8)];
    for (k, &v) in values.iter().enumerate() {
        out[k / 4] |= (v & 3) << ((k % 4) * 2);
    }
    out
}

/// What `bytes` cost gzipped (the deflate stream, default level, as web servers send tiles);
/// 0 for none.
pub fn gzip_bytes(bytes: &[u8]) -> u64 {
    use std::io::Write;
    if bytes.is_empty() {
        return 0;
    }
    let mut z = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::default());
    z.write_all(bytes).expect("writes to a Vec");
    z.finish().expect("writes to a Vec").len() as u64
}

/// Position tolerance of the weld (metres): the simplifier's, so an element's faces are joined
/// as the weld step joins them.
pub fn weld_tolerance_m() -> f64 {
    crate::simplify::SimplifyOptions::default().weld_tolerance_m as f64
}

/// Corner of every vertex: the first earlier vertex of its group within `tolerance`, else itself
/// (input order decides, so the result is the same on every run).
fn welded_corners(positions: &[[f32; 3]], groups: &[u32], tolerance: f64) -> Vec<u32> {
    let p64 = |p: [f32; 3]| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    let mut cells: HashMap<(u32, [i64; 3]), Vec<u32>> = HashMap::new();
    let mut corner = vec![0u32; positions.len()];
    let tol2 = tolerance * tolerance;
    for (i, &p) in positions.iter().enumerate() {
        let (g, q) = (groups[i], p64(p));
        let c = cell_of(q, tolerance);
        let mut best = u32::MAX;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = (g, [c[0] + dx, c[1] + dy, c[2] + dz]);
                    for &r in cells.get(&key).into_iter().flatten() {
                        if r < best && (p64(positions[r as usize]) - q).length_squared() <= tol2 {
                            best = r;
                        }
                    }
                }
            }
        }
        if best == u32::MAX {
            best = i as u32;
            cells.entry((g, c)).or_default().push(best);
        }
        corner[i] = best;
    }
    corner
}

/// The edges of one triangle list (`indices` into `positions`, `groups` the element of each
/// vertex), classified and encoded; `None` when `opts` asks for none or no edge is visible (the
/// spec wants at least one non-zero value).
pub fn edge_visibility(
    positions: &[[f32; 3]],
    groups: &[u32],
    indices: &[u32],
    opts: &EdgeOptions,
    seams: Option<&Seams>,
) -> Option<EdgeVisibility> {
    if opts.mode == EdgeMode::None || indices.len() < 3 {
        return None;
    }
    let corner = welded_corners(positions, groups, weld_tolerance_m());
    let p64 = |i: u32| {
        let p = positions[i as usize];
        DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
    };
    let tri_count = indices.len() / 3;
    // Welded corners per triangle; a triangle two of whose corners are one is a line, and has
    // no edges of its own (all hidden).
    let corners: Vec<Option<[u32; 3]>> = indices
        .chunks_exact(3)
        .map(|t| {
            let c = [t[0], t[1], t[2]].map(|i| corner[i as usize]);
            (c[0] != c[1] && c[1] != c[2] && c[2] != c[0]).then_some(c)
        })
        .collect();
    // Unit normal per triangle; None for one without area (a sliver: no direction to compare).
    let normals: Vec<Option<DVec3>> = indices
        .chunks_exact(3)
        .map(|t| {
            let n = (p64(t[1]) - p64(t[0])).cross(p64(t[2]) - p64(t[0]));
            let len = n.length();
            (len > MIN_DOUBLE_AREA_M2).then(|| n / len)
        })
        .collect();
    // Every edge of every triangle by its welded corners (low, high), and whether it runs low to
    // high.
    let mut edges: Vec<(u32, u32, u32, bool)> = Vec::with_capacity(tri_count * 3);
    for (t, c) in corners.iter().enumerate() {
        let Some(c) = c else { continue };
        for e in 0..3 {
            let (a, b) = (c[e], c[(e + 1) % 3]);
            edges.push((a.min(b), a.max(b), (t * 3 + e) as u32, a < b));
        }
    }
    edges.sort_unstable();
    let cos_crease = opts.crease_angle_deg.to_radians().cos();
    let cos_coplanar = COPLANAR_MAX_DEG.to_radians().cos();
    let mut values = vec![HIDDEN; tri_count * 3];
    let mut silhouettes: Vec<(u32, [[f32; 3]; 2])> = Vec::new();
    let (mut hard_edges, mut silhouette_edges) = (0, 0);
    let mut boundary: Vec<u32> = Vec::new();
    for run in edges.chunk_by(|x, y| (x.0, x.1) == (y.0, y.1)) {
        let hard = match run {
            [(_, _, k, _)] => {
                boundary.push(*k);
                continue;
            }
            [(_, _, k0, dir0), (_, _, k1, dir1)] => {
                let (Some(n0), Some(n1)) = (normals[*k0 as usize / 3], normals[*k1 as usize / 3])
                else {
                    // Beside a sliver (a crack filler, mostly inside flat faces): hidden.
                    continue;
                };
                // Consistently wound neighbours run the edge in opposite directions; one wound
                // the other way has its normal turned.
                let cos = if dir0 != dir1 {
                    n0.dot(n1)
                } else {
                    -n0.dot(n1)
                };
                // The face across, turned as the encoding face's surface runs.
                let across = if dir0 != dir1 { n1 } else { -n1 };
                let pair = [n0, across].map(|n| n.as_vec3().to_array());
                if cos < cos_crease {
                    true
                } else if cos >= cos_coplanar
                    || opts.mode != EdgeMode::All
                    || !silhouette_can_draw(pair)
                {
                    false
                } else {
                    values[*k0 as usize] = SILHOUETTE;
                    silhouettes.push((*k0, pair));
                    silhouette_edges += 1;
                    false
                }
            }
            _ => true,
        };
        if hard {
            hard_edges += 1;
            values[run[0].2 as usize] = HARD;
            for other in &run[1..] {
                values[other.2 as usize] = REPEATED_HARD;
            }
        }
    }
    let seam = seams.map_or_else(
        || vec![false; boundary.len()],
        |s| soft_seams(positions, groups, indices, &boundary, s, cos_crease),
    );
    for (&k, seam) in boundary.iter().zip(seam) {
        if !seam {
            values[k as usize] = HARD;
            hard_edges += 1;
        }
    }
    if hard_edges + silhouette_edges == 0 {
        return None;
    }
    silhouettes.sort_unstable_by_key(|s| s.0);
    Some(EdgeVisibility {
        visibility: pack(&values),
        silhouette_normals: silhouettes.into_iter().map(|s| s.1).collect(),
        hard_edges,
        silhouette_edges,
    })
}

/// Per boundary edge (`k`: triangle `k / 3`, edge `k % 3`), whether it is a seam: the element's
/// whole surface has an edge there between two faces that meet at no more than the crease angle.
fn soft_seams(
    positions: &[[f32; 3]],
    groups: &[u32],
    indices: &[u32],
    boundary: &[u32],
    seams: &Seams,
    cos_crease: f64,
) -> Vec<bool> {
    let ends = |k: u32| {
        let (t, e) = (k as usize / 3, k as usize % 3);
        let a = indices[3 * t + e] as usize;
        let b = indices[3 * t + (e + 1) % 3] as usize;
        (groups[a], positions[a], positions[b])
    };
    let mut by_group: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
    for (j, &k) in boundary.iter().enumerate() {
        by_group.entry(ends(k).0).or_default().push(j);
    }
    let mut seam = vec![false; boundary.len()];
    for (group, list) in by_group {
        let Some(whole) = (seams.whole_surface)(group) else {
            continue;
        };
        let rest = SoftEdges::new(&whole, cos_crease, seams.tolerance_m);
        for j in list {
            let (_, a, b) = ends(boundary[j]);
            seam[j] = rest.near(a, b);
        }
    }
    seam
}

/// The edges of a whole surface between two faces that meet at no more than the crease angle,
/// found by position within a tolerance.
struct SoftEdges {
    soft: std::collections::HashSet<(u32, u32)>,
    /// Welded corners by grid cell (the tolerance a cell).
    cells: HashMap<[i64; 3], Vec<u32>>,
    positions: Vec<DVec3>,
    tolerance_m: f64,
}

impl SoftEdges {
    fn new(whole: &WholeSurface, cos_crease: f64, tolerance_m: f64) -> SoftEdges {
        let n = whole.positions.len();
        let corner = welded_corners(&whole.positions, &vec![0; n], weld_tolerance_m());
        let positions: Vec<DVec3> = (whole.positions.iter())
            .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        let mut edges: Vec<(u32, u32, DVec3, bool, u32)> = Vec::new();
        for (t, &material) in whole.indices.chunks_exact(3).zip(&whole.face_materials) {
            let c = [t[0], t[1], t[2]].map(|i| corner[i as usize]);
            if c[0] == c[1] || c[1] == c[2] || c[2] == c[0] {
                continue;
            }
            let [p0, p1, p2] = [t[0], t[1], t[2]].map(|i| positions[i as usize]);
            let normal = (p1 - p0).cross(p2 - p0).normalize_or_zero();
            for e in 0..3 {
                let (a, b) = (c[e], c[(e + 1) % 3]);
                edges.push((a.min(b), a.max(b), normal, a < b, material));
            }
        }
        edges.sort_unstable_by_key(|e| (e.0, e.1));
        let soft = edges
            .chunk_by(|x, y| (x.0, x.1) == (y.0, y.1))
            .filter_map(|run| match run {
                [(a, b, n0, d0, m0), (_, _, n1, d1, m1)] => {
                    let cos = if d0 != d1 { n0.dot(*n1) } else { -n0.dot(*n1) };
                    // Beside a sliver (no normal) the seam is not judged: it stays hard.
                    let sliver = *n0 == DVec3::ZERO || *n1 == DVec3::ZERO;
                    (!sliver && m0 == m1 && cos >= cos_crease).then_some((*a, *b))
                }
                _ => None,
            })
            .collect();
        let tolerance_m = tolerance_m.max(weld_tolerance_m());
        let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (i, &c) in corner.iter().enumerate() {
            if c == i as u32 {
                cells
                    .entry(cell_of(positions[i], tolerance_m))
                    .or_default()
                    .push(c);
            }
        }
        SoftEdges {
            soft,
            cells,
            positions,
            tolerance_m,
        }
    }

    /// Corners within the tolerance of `p`.
    fn corners_near(&self, p: [f32; 3]) -> Vec<u32> {
        let q = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let c = cell_of(q, self.tolerance_m);
        let mut out = Vec::new();
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = [c[0] + dx, c[1] + dy, c[2] + dz];
                    for &r in self.cells.get(&key).into_iter().flatten() {
                        if self.positions[r as usize].distance(q) <= self.tolerance_m {
                            out.push(r);
                        }
                    }
                }
            }
        }
        out
    }

    /// Whether a soft edge of the whole surface runs between `a` and `b` (never for an edge too
    /// short to tell its ends apart within the tolerance).
    fn near(&self, a: [f32; 3], b: [f32; 3]) -> bool {
        let length_m = DVec3::from(a.map(f64::from)).distance(DVec3::from(b.map(f64::from)));
        if length_m <= 2.0 * self.tolerance_m {
            return false;
        }
        let (near_a, near_b) = (self.corners_near(a), self.corners_near(b));
        near_a.iter().any(|&x| {
            near_b
                .iter()
                .any(|&y| x != y && self.soft.contains(&(x.min(y), x.max(y))))
        })
    }
}

/// The grid cell of `p` for cells of `size_m`.
fn cell_of(p: DVec3, size_m: f64) -> [i64; 3] {
    let inv = 1.0 / size_m;
    [
        (p.x * inv).floor() as i64,
        (p.y * inv).floor() as i64,
        (p.z * inv).floor() as i64,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::{FRAC_PI_2, TAU};

    /// Hard edges and silhouettes (`--edges all`), the default crease angle.
    fn every_edge() -> EdgeOptions {
        EdgeOptions {
            mode: EdgeMode::All,
            ..EdgeOptions::default()
        }
    }

    fn all(values: &EdgeVisibility, triangles: usize) -> Vec<u8> {
        (0..triangles * 3)
            .map(|k| value_at(&values.visibility, k))
            .collect()
    }

    fn count(v: &[u8], x: u8) -> usize {
        v.iter().filter(|&&y| y == x).count()
    }

    #[test]
    fn packs_four_edges_a_byte_low_bits_first() {
        // The spec's example: [2,0,1, 0,2,0] is [18, 2].
        assert_eq!(pack(&[2, 0, 1, 0, 2, 0]), vec![18, 2]);
        // ceil(6 N / 8) bytes, unused bits zero.
        for n in 1..9 {
            let p = pack(&vec![3; n * 3]);
            assert_eq!(p.len(), (6 * n).div_ceil(8));
            let used_bits = 6 * n;
            if used_bits % 8 != 0 {
                assert_eq!(p.last().unwrap() >> (used_bits % 8), 0);
            }
        }
    }

    #[test]
    fn a_flat_quad_has_four_hard_edges_and_a_hidden_diagonal() {
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let e = edge_visibility(
            &positions,
            &[0; 4],
            &[0, 1, 2, 0, 2, 3],
            &every_edge(),
            None,
        )
        .unwrap();
        let v = all(&e, 2);
        assert_eq!(count(&v, HARD), 4);
        assert_eq!(count(&v, HIDDEN), 2);
        assert_eq!((e.hard_edges, e.silhouette_edges), (4, 0));
        // The diagonal (0:2 in the first, 2:0 in the second) is the hidden one.
        assert_eq!((v[2], v[3]), (HIDDEN, HIDDEN));
    }

    /// A unit cube with its vertices split per face (4 each, flat-shaded as exporters write it).
    fn split_cube() -> (Vec<[f32; 3]>, Vec<u32>) {
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for axis in 0..3 {
            for side in [0.0f32, 1.0] {
                let base = positions.len() as u32;
                let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
                for (a, b) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
                    let mut p = [0.0f32; 3];
                    p[axis] = side;
                    p[u] = a;
                    p[w] = b;
                    positions.push(p);
                }
                // Outward winding.
                if side == 1.0 {
                    indices.extend([base, base + 1, base + 2, base, base + 2, base + 3]);
                } else {
                    indices.extend([base, base + 2, base + 1, base, base + 3, base + 2]);
                }
            }
        }
        (positions, indices)
    }

    #[test]
    fn a_cube_with_split_vertices_has_twelve_hard_edges() {
        let (positions, indices) = split_cube();
        let e = edge_visibility(&positions, &[0; 24], &indices, &every_edge(), None).unwrap();
        let v = all(&e, 12);
        assert_eq!(e.hard_edges, 12);
        assert_eq!(count(&v, HARD), 12);
        assert_eq!(count(&v, REPEATED_HARD), 12);
        assert_eq!(count(&v, HIDDEN), 12);
        assert_eq!(count(&v, SILHOUETTE), 0);
        // Without the weld, every face would be a boundary: 24 edges drawn twice.
        let corners = welded_corners(&positions, &[0; 24], weld_tolerance_m());
        let mut distinct = corners.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(distinct.len(), 8);
    }

    /// An open cylinder of `segments` facets (radius 1, height 2), smooth-shaded (shared vertices).
    fn cylinder(segments: u32) -> (Vec<[f32; 3]>, Vec<u32>) {
        let mut positions = Vec::new();
        for i in 0..segments {
            let a = i as f32 / segments as f32 * std::f32::consts::TAU;
            positions.push([a.cos(), a.sin(), 0.0]);
            positions.push([a.cos(), a.sin(), 2.0]);
        }
        let mut indices = Vec::new();
        for i in 0..segments {
            let (b0, t0) = (2 * i, 2 * i + 1);
            let (b1, t1) = (2 * ((i + 1) % segments), 2 * ((i + 1) % segments) + 1);
            indices.extend([b0, b1, t1, b0, t1, t0]);
        }
        (positions, indices)
    }

    #[test]
    fn a_cylinder_draws_silhouettes_along_its_side_and_hard_rims() {
        let (positions, indices) = cylinder(24);
        let groups = vec![0; positions.len()];
        let e = edge_visibility(&positions, &groups, &indices, &every_edge(), None).unwrap();
        // 15° a facet: below the crease angle. The vertical edges are silhouettes (24), the
        // diagonals coplanar (hidden), the two rims hard (48 edges).
        assert_eq!(e.silhouette_edges, 24);
        assert_eq!(e.hard_edges, 48);
        assert_eq!(e.silhouette_normals.len(), 24);
        let v = all(&e, 48);
        assert_eq!(count(&v, SILHOUETTE), 24);
        // Each normal pair: the two faces across the edge, 15° apart.
        for [a, b] in &e.silhouette_normals {
            let (a, b) = (glam::Vec3::from(*a), glam::Vec3::from(*b));
            assert!((a.dot(b) - 15f32.to_radians().cos()).abs() < 1e-4);
        }
        // `hard` drops the silhouettes; `none` writes nothing.
        let hard = EdgeOptions {
            mode: EdgeMode::Hard,
            ..every_edge()
        };
        let h = edge_visibility(&positions, &groups, &indices, &hard, None).unwrap();
        assert_eq!((h.hard_edges, h.silhouette_edges), (48, 0));
        assert!(h.silhouette_normals.is_empty());
        let none = EdgeOptions {
            mode: EdgeMode::None,
            ..every_edge()
        };
        assert!(edge_visibility(&positions, &groups, &indices, &none, None).is_none());
        // A crease angle below the facet angle makes the facets hard.
        let sharp = EdgeOptions {
            crease_angle_deg: 10.0,
            ..every_edge()
        };
        let s = edge_visibility(&positions, &groups, &indices, &sharp, None).unwrap();
        assert_eq!((s.hard_edges, s.silhouette_edges), (72, 0));
    }

    #[test]
    fn a_finely_faceted_cylinder_keeps_its_outlines_with_fewer_silhouettes() {
        // 3° a facet: finer than the written normals' steps, so neighbouring faces often share
        // a written normal, and an edge between two such faces is never drawn.
        let segments = 120;
        let (positions, indices) = cylinder(segments);
        let groups = vec![0; positions.len()];
        let e = edge_visibility(&positions, &groups, &indices, &every_edge(), None).unwrap();
        assert!(e.silhouette_edges > 0 && e.silhouette_edges < segments as usize);
        // From every side, the written normals still draw an edge within a few facets of each
        // of the cylinder's two outlines (where the view grazes the surface).
        let written: Vec<[glam::Vec3; 2]> = (e.silhouette_normals.iter())
            .map(|p| p.map(|n| glam::Vec3::from(silhouette_normal_i8(n).map(|x| x as f32))))
            .collect();
        for step in 0..500 {
            let azimuth = step as f32 * 0.72f32.to_radians();
            let view = glam::Vec3::new(azimuth.cos(), azimuth.sin(), 0.3);
            let drawn: Vec<f32> = (written.iter())
                .filter(|[a, b]| (view.dot(*a) > 0.0) != (view.dot(*b) > 0.0))
                .map(|[a, b]| (*a + *b).y.atan2((*a + *b).x))
                .collect();
            for outline in [azimuth + FRAC_PI_2, azimuth - FRAC_PI_2] {
                let near = |d: &f32| {
                    let off = (d - outline).rem_euclid(TAU);
                    off.min(TAU - off) < 8f32.to_radians()
                };
                assert!(
                    drawn.iter().any(near),
                    "no outline near {outline} ({drawn:?})"
                );
            }
        }
    }

    #[test]
    fn a_silhouette_across_a_face_wound_the_other_way_turns_its_normal() {
        // Two facets of a curve 15° apart, the second wound against the first.
        let a = 7.5f32.to_radians();
        let positions = [
            [0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [a.cos(), 0.0, a.sin()],
            [-a.cos(), 0.0, a.sin()],
        ];
        let e = edge_visibility(
            &positions,
            &[0; 4],
            &[0, 1, 2, 0, 1, 3],
            &every_edge(),
            None,
        )
        .unwrap();
        assert_eq!(e.silhouette_edges, 1);
        let [n0, n1] = e.silhouette_normals[0].map(glam::Vec3::from);
        // Both on one side of the surface, 15° apart.
        assert!((n0.dot(n1) - 15f32.to_radians().cos()).abs() < 1e-4);
    }

    #[test]
    fn two_touching_elements_keep_their_own_outlines() {
        // Two flat quads side by side sharing the edge x = 1, as two elements: 8 hard edges, the
        // shared one drawn by both. As one element, the shared edge is an inner one (hidden).
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [2.0, 1.0, 0.0],
            [1.0, 1.0, 0.0],
        ];
        let indices = [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7];
        let two = edge_visibility(
            &positions,
            &[0, 0, 0, 0, 1, 1, 1, 1],
            &indices,
            &every_edge(),
            None,
        )
        .unwrap();
        assert_eq!(two.hard_edges, 8);
        assert_eq!(count(&all(&two, 4), REPEATED_HARD), 0);
        let one = edge_visibility(&positions, &[0; 8], &indices, &every_edge(), None).unwrap();
        assert_eq!(one.hard_edges, 6);
    }

    #[test]
    fn vertices_within_the_weld_tolerance_are_one_corner() {
        let t = weld_tolerance_m() as f32;
        let positions = [[0.0, 0.0, 0.0], [0.5 * t, 0.0, 0.0], [3.0 * t, 0.0, 0.0]];
        assert_eq!(welded_corners(&positions, &[0; 3], t as f64), vec![0, 0, 2]);
        // Another group never welds.
        assert_eq!(
            welded_corners(&positions, &[0, 1, 0], t as f64),
            vec![0, 1, 2]
        );
    }

    #[test]
    fn faces_without_area_and_back_to_back_faces() {
        // A zero-area triangle on the quad's edge: no angle to judge across the edge it shares
        // (hidden); its two halves of that edge are boundaries, so the outline is still drawn.
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.5, 0.0, 0.0],
        ];
        let e = edge_visibility(
            &positions,
            &[0; 5],
            &[0, 1, 2, 0, 2, 3, 0, 4, 1],
            &every_edge(),
            None,
        )
        .unwrap();
        let v = all(&e, 3);
        assert_eq!(&v[6..], &[HARD, HARD, HIDDEN]);
        assert_eq!(e.hard_edges, 5);
        // A triangle with two corners welded into one is a line: its edges are all hidden.
        let e = edge_visibility(
            &[
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1e-6],
            ],
            &[0; 4],
            &[0, 1, 2, 0, 3, 1],
            &every_edge(),
            None,
        )
        .unwrap();
        assert_eq!(&all(&e, 2)[3..], &[HIDDEN; 3]);
        // A one-sided sheet written twice, back to back: its outline is hard (180°), once.
        let e = edge_visibility(
            &positions[..3],
            &[0; 3],
            &[0, 1, 2, 0, 2, 1],
            &every_edge(),
            None,
        )
        .unwrap();
        let v = all(&e, 2);
        assert_eq!((count(&v, HARD), count(&v, REPEATED_HARD)), (3, 3));
    }

    #[test]
    fn a_cut_across_a_flat_face_draws_no_line_and_a_crease_or_new_material_does() {
        // One element: flat quad A (in the tile), flat quad B beside it, and wall C folded up at
        // 90 degrees from A's far side. The tile draws A alone.
        let p = |x: f32, y: f32, z: f32| [x, y, z];
        let whole_positions = vec![
            p(0., 0., 0.),
            p(1., 0., 0.),
            p(1., 1., 0.),
            p(0., 1., 0.),
            p(2., 0., 0.),
            p(2., 1., 0.),
            p(1., 1., 1.),
            p(0., 1., 1.),
        ];
        let whole_indices = vec![0, 1, 2, 0, 2, 3, 1, 4, 5, 1, 5, 2, 3, 2, 6, 3, 6, 7];
        let tile_positions = whole_positions[..4].to_vec();
        let tile_indices = [0, 1, 2, 0, 2, 3];
        let run = |face_materials: Vec<u32>| {
            let whole = WholeSurface {
                positions: whole_positions.clone(),
                indices: whole_indices.clone(),
                face_materials,
            };
            let find = |_: u32| Some(whole.clone());
            let seams = Seams {
                whole_surface: &find,
                tolerance_m: 1e-4,
            };
            let e = edge_visibility(
                &tile_positions,
                &[0; 4],
                &tile_indices,
                &every_edge(),
                Some(&seams),
            )
            .unwrap();
            (all(&e, 2), e.hard_edges)
        };
        // Edges: k = 0 (p0-p1, a boundary), 1 (p1-p2, the cut towards B), 2 and 3 (the
        // diagonal), 4 (p2-p3, the crease towards C), 5 (p3-p0, a boundary).
        let (values, hard) = run(vec![7; 6]);
        assert_eq!(values, vec![HARD, HIDDEN, HIDDEN, HIDDEN, HARD, HARD]);
        assert_eq!(hard, 3);
        // B of another material: the element has an edge there of its own.
        let (values, _) = run(vec![7, 7, 8, 8, 7, 7]);
        assert_eq!(values[1], HARD);
        // Without the rest of the surface every boundary is hard.
        let e = edge_visibility(&tile_positions, &[0; 4], &tile_indices, &every_edge(), None);
        assert_eq!(e.unwrap().hard_edges, 4);
    }
}
