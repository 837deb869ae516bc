//! Welding: merges input vertices that share a group id and lie within a
//! position tolerance into one *position vertex*, and input vertices that
//! also share all attributes into one *wedge* (attribute vertex). Attribute
//! seams (split normals at hard edges, UV seams) thus stay connected by
//! position but keep their distinct wedges. Degenerate and zero-area
//! triangles are dropped.

use std::collections::HashMap as StdHashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// FxHash-style hasher (the maps are only probed, never iterated, so the
/// hash function does not affect the result, and SipHash's strength buys nothing here
/// for a noticeable share of a run).
#[derive(Default)]
pub(crate) struct FxHasher(u64);
impl Hasher for FxHasher {
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for c in bytes.chunks(8) {
            let mut b = [0u8; 8];
            b[..c.len()].copy_from_slice(c);
            self.write_u64(u64::from_le_bytes(b));
        }
    }
    #[inline]
    fn write_u32(&mut self, i: u32) {
        self.write_u64(i as u64);
    }
    #[inline]
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    #[inline]
    fn write_i64(&mut self, i: i64) {
        self.write_u64(i as u64);
    }
    #[inline]
    fn write_usize(&mut self, i: usize) {
        self.write_u64(i as u64);
    }
    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }
}
type HashMap<K, V> = StdHashMap<K, V, BuildHasherDefault<FxHasher>>;

use glam::DVec3;

/// Result of welding.
pub(crate) struct Welded {
    /// Position of every position vertex.
    pub pos: Vec<DVec3>,
    /// Position vertex is locked (one of its input vertices was locked).
    pub locked: Vec<bool>,
    /// Position vertex of every wedge.
    pub wedge_pos: Vec<u32>,
    /// Input vertex a wedge was taken from (its attributes and group).
    pub wedge_src: Vec<u32>,
    /// Triangles as wedge indices (valid, non-degenerate).
    pub tris: Vec<[u32; 3]>,
}

const NONE: u32 = u32::MAX;

/// Welds. `attr_key(i)` returns the attribute bits of input vertex `i`
/// (normal, uv, colour), `groups[i]` its group. Inputs must already be
/// validated (indices in range, finite positions).
pub(crate) fn weld(
    positions: &[[f32; 3]],
    groups: &dyn Fn(usize) -> u32,
    locked: &dyn Fn(usize) -> bool,
    attr_key: &dyn Fn(usize) -> [u32; 9],
    indices: &[u32],
    tolerance: f64,
) -> Welded {
    // Only weld vertices that are referenced.
    let mut used = vec![false; positions.len()];
    for &i in indices {
        used[i as usize] = true;
    }
    // 1. Position vertices: first representative in input order.
    let pv = if tolerance > 0.0 {
        position_vertices_within(positions, &used, groups, locked, tolerance)
    } else {
        position_vertices_exact(positions, &used, groups, locked)
    };
    // 2. Wedges.
    let (wedge_of, wedge_pos, wedge_src) = wedges(&used, &pv.rep, pv.pos.len(), attr_key);
    // 3. Triangles.
    let tris = valid_triangles(indices, &wedge_of, &wedge_pos, &pv.pos);
    Welded {
        pos: pv.pos,
        locked: pv.locked,
        wedge_pos,
        wedge_src,
        tris,
    }
}

/// Position vertices of the referenced input vertices.
struct PositionVertices {
    /// Input vertex -> position vertex (`NONE` if unreferenced).
    rep: Vec<u32>,
    pos: Vec<DVec3>,
    locked: Vec<bool>,
}

fn p64(p: [f32; 3]) -> DVec3 {
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// Position vertices within `tolerance` (> 0) of each other, same group,
/// found on a grid hash: each input vertex takes the first earlier position
/// vertex of its group within the tolerance (a locked one: at exactly its
/// position), else becomes one.
fn position_vertices_within(
    positions: &[[f32; 3]],
    used: &[bool],
    groups: &dyn Fn(usize) -> u32,
    locked: &dyn Fn(usize) -> bool,
    tolerance: f64,
) -> PositionVertices {
    let n = positions.len();
    let mut rep = vec![NONE; n];
    let mut pos: Vec<DVec3> = Vec::new();
    let mut plocked = Vec::new();
    // Cells of four times the tolerance: per axis a point within the
    // tolerance is in the point's own cell, or in the neighbour on the
    // side where the point is within the tolerance of the cell's edge
    // (a quarter of the cell). Most points need one probe (cells of twice
    // the tolerance took 8, of the tolerance 27); the result, the first
    // representative within the tolerance, does not depend on the cells.
    let inv = 0.25 / tolerance;
    let cell = |p: DVec3| {
        (
            (p.x * inv).floor() as i64,
            (p.y * inv).floor() as i64,
            (p.z * inv).floor() as i64,
        )
    };
    // Cells to probe along one axis: the own one, and a neighbour when
    // the point is within the tolerance of that side (with a margin for
    // rounding).
    let span = |x: f64, c: i64| -> (i64, i64) {
        let f = x * inv - c as f64;
        (
            if f < 0.25 + 1e-6 { -1 } else { 0 },
            if f > 0.75 - 1e-6 { 1 } else { 0 },
        )
    };
    let n_used = used.iter().filter(|&&u| u).count();
    // Compact cell table: a bucket per hash of (group, cell) holding
    // the head of a list of position vertices (`next_in_cell`). Cells
    // sharing a bucket share its list: the extra entries are farther
    // than the tolerance (every point within it lies in a probed
    // cell) or of another group (checked), so the result is the same
    // as with one list per cell; an empty bucket is one load (a map
    // probe was a cache miss and most probes are of empty cells).
    let bits = (2 * n_used).next_power_of_two().max(64);
    let shift = 64 - bits.trailing_zeros();
    let mut heads = vec![NONE; bits];
    let bucket = |g: u32, cx: i64, cy: i64, cz: i64| {
        let mut h = FxHasher::default();
        h.write_u32(g);
        h.write_i64(cx);
        h.write_i64(cy);
        h.write_i64(cz);
        (h.finish() >> shift) as usize
    };
    let mut next_in_cell: Vec<u32> = Vec::new(); // per position vertex
    let mut rep_group: Vec<u32> = Vec::new(); // per position vertex
    let tol2 = tolerance * tolerance;
    for i in 0..n {
        if !used[i] {
            continue;
        }
        let g = groups(i);
        let lk = locked(i);
        let p = p64(positions[i]);
        let (cx, cy, cz) = cell(p);
        let (sx, sy, sz) = (span(p.x, cx), span(p.y, cy), span(p.z, cz));
        let mut best = NONE;
        for dx in sx.0..=sx.1 {
            for dy in sy.0..=sy.1 {
                for dz in sz.0..=sz.1 {
                    let mut r = heads[bucket(g, cx + dx, cy + dy, cz + dz)];
                    while r != NONE {
                        let q = pos[r as usize];
                        let ok = if lk {
                            q == p
                        } else {
                            (q - p).length_squared() <= tol2
                        };
                        if ok && r < best && rep_group[r as usize] == g {
                            best = r;
                        }
                        r = next_in_cell[r as usize];
                    }
                }
            }
        }
        if best == NONE {
            best = pos.len() as u32;
            pos.push(p);
            plocked.push(false);
            rep_group.push(g);
            let h = &mut heads[bucket(g, cx, cy, cz)];
            next_in_cell.push(*h);
            *h = best;
        }
        if lk {
            plocked[best as usize] = true;
        }
        rep[i] = best;
    }
    PositionVertices {
        rep,
        pos,
        locked: plocked,
    }
}

/// Position vertices at exactly the same position (bits), same group.
fn position_vertices_exact(
    positions: &[[f32; 3]],
    used: &[bool],
    groups: &dyn Fn(usize) -> u32,
    locked: &dyn Fn(usize) -> bool,
) -> PositionVertices {
    let n = positions.len();
    let mut rep = vec![NONE; n];
    let mut pos: Vec<DVec3> = Vec::new();
    let mut plocked = Vec::new();
    let mut map: HashMap<(u32, [u32; 3]), u32> = HashMap::default();
    for i in 0..n {
        if !used[i] {
            continue;
        }
        let p = positions[i];
        let key = (groups(i), [p[0].to_bits(), p[1].to_bits(), p[2].to_bits()]);
        let id = *map.entry(key).or_insert_with(|| {
            pos.push(p64(p));
            plocked.push(false);
            (pos.len() - 1) as u32
        });
        if locked(i) {
            plocked[id as usize] = true;
        }
        rep[i] = id;
    }
    PositionVertices {
        rep,
        pos,
        locked: plocked,
    }
}

/// Wedges: (position vertex, attributes), in input order. Returns the wedge
/// of every input vertex, and the position vertex and source input vertex
/// of every wedge. A position vertex has a few wedges: they are found on a
/// per-vertex list (a map keyed by the attributes was a cache miss per
/// input vertex).
fn wedges(
    used: &[bool],
    rep: &[u32],
    n_pos: usize,
    attr_key: &dyn Fn(usize) -> [u32; 9],
) -> (Vec<u32>, Vec<u32>, Vec<u32>) {
    let n = used.len();
    let mut wedge_of = vec![NONE; n];
    let mut first_wedge = vec![NONE; n_pos];
    let mut next_wedge: Vec<u32> = Vec::new();
    let mut wedge_key: Vec<[u32; 9]> = Vec::new();
    let mut wedge_pos = Vec::new();
    let mut wedge_src = Vec::new();
    for i in 0..n {
        if !used[i] {
            continue;
        }
        let r = rep[i];
        let key = attr_key(i);
        let mut w = first_wedge[r as usize];
        while w != NONE && wedge_key[w as usize] != key {
            w = next_wedge[w as usize];
        }
        if w == NONE {
            w = wedge_pos.len() as u32;
            wedge_pos.push(r);
            wedge_src.push(i as u32);
            wedge_key.push(key);
            next_wedge.push(first_wedge[r as usize]);
            first_wedge[r as usize] = w;
        }
        wedge_of[i] = w;
    }
    (wedge_of, wedge_pos, wedge_src)
}

/// Triangles as wedge triples, without those with a repeated position
/// vertex or zero area (relative to their size).
fn valid_triangles(
    indices: &[u32],
    wedge_of: &[u32],
    wedge_pos: &[u32],
    pos: &[DVec3],
) -> Vec<[u32; 3]> {
    let mut tris = Vec::with_capacity(indices.len() / 3);
    for t in indices.chunks_exact(3) {
        let w = [
            wedge_of[t[0] as usize],
            wedge_of[t[1] as usize],
            wedge_of[t[2] as usize],
        ];
        let (a, b, c) = (
            wedge_pos[w[0] as usize],
            wedge_pos[w[1] as usize],
            wedge_pos[w[2] as usize],
        );
        if a == b || b == c || a == c {
            continue;
        }
        let (pa, pb, pc) = (pos[a as usize], pos[b as usize], pos[c as usize]);
        let cr = (pb - pa).cross(pc - pa);
        let scale = (pb - pa)
            .length_squared()
            .max((pc - pa).length_squared())
            .max((pc - pb).length_squared());
        let a2 = cr.length_squared();
        if a2.is_nan() || a2 <= 1e-24 * scale * scale {
            continue;
        }
        tris.push(w);
    }
    tris
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(pos: &[[f32; 3]], groups: &[u32], idx: &[u32], tol: f64) -> Welded {
        weld(
            pos,
            &|i| groups[i],
            &|_| false,
            &|i| [i as u32 % 2, 0, 0, 0, 0, 0, 0, 0, 0],
            idx,
            tol,
        )
    }

    #[test]
    fn welds_within_tolerance_and_group_only() {
        let pos = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.00001, 0.0, 0.0], // near 0, same group, other attributes
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 0.0], // same position as 0 but other group
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 1.0],
        ];
        let groups = [0, 0, 0, 0, 0, 0, 1, 1, 1];
        let w = run(&pos, &groups, &[0, 1, 2, 3, 4, 5, 6, 7, 8], 1e-4);
        assert_eq!(w.pos.len(), 3 + 1 + 3);
        assert_eq!(w.wedge_pos[0], w.wedge_pos[3]);
        assert_ne!(w.wedge_pos[0], w.wedge_pos[6]);
        assert_eq!(w.tris.len(), 3);
    }

    /// Points crowded around cell edges (multiples of the tolerance, jittered by less than it)
    /// weld exactly as a brute-force search would: each takes the first earlier position vertex
    /// of its group within the tolerance, else becomes one.
    #[test]
    fn cells_find_every_point_within_tolerance() {
        let tol = 1e-3;
        let mut rnd = crate::geometry::test_uniform(12345);
        let mut pos = Vec::new();
        let mut groups = Vec::new();
        for _ in 0..3000 {
            let mut axis = || ((rnd() * 6.0).floor() - 3.0) * tol + (rnd() - 0.5) * 1.5 * tol;
            pos.push([axis() as f32, axis() as f32, axis() as f32]);
            groups.push((rnd() * 2.0) as u32);
        }
        let idx: Vec<u32> = (0..pos.len() as u32).collect();
        let w = run(&pos, &groups, &idx, tol);
        let mut expect: Vec<(DVec3, u32)> = Vec::new();
        for (p, &g) in pos.iter().zip(&groups) {
            let p = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let near = expect
                .iter()
                .any(|&(q, h)| h == g && (q - p).length_squared() <= tol * tol);
            if !near {
                expect.push((p, g));
            }
        }
        let got: Vec<DVec3> = w.pos.clone();
        assert_eq!(got, expect.iter().map(|e| e.0).collect::<Vec<_>>());
    }

    #[test]
    fn drops_degenerate() {
        let pos = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
        ];
        let w = run(&pos, &[0; 4], &[0, 1, 2, 0, 3, 1, 0, 0, 1], 0.0);
        assert!(w.tris.is_empty());
    }
}
