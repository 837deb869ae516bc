//! Parallel simplification of one large mesh (rayon): "parallel over
//! independent meshes" inside one mesh.
//!
//! * **Many connected parts** (a BIM model: thousands of separate members):
//!   the parts are dealt by size into a few groups of about equal size, each
//!   group is simplified on its own ([`qem::run`]) to its share of the
//!   triangle goal, and the results are put back in the input's numbering.
//!   Collapses never cross parts, so a group depends on its own parts only.
//!   The goal is shared in proportion to each group's triangles instead of by
//!   one global cost order; with many parts dealt by size every group is a
//!   similar mix of the model (BIM models repeat their members), so the
//!   error matches one run's (docs/benchmarks.md).
//! * **One large surface** (a terrain, a scanned building), or parts too
//!   unequal to deal: the surface is cut into cells (median cuts). The
//!   quadrics of the whole are computed first (a cell alone would take its
//!   cut for a border) and carried through. The cells are simplified in
//!   parallel, with the vertices of the triangles across a cut pinned
//!   (locked and numbered so that no collapse removes them: no crack), to
//!   a quarter of the removal short of the goal; then one run over the whole
//!   surface takes the cuts and the last collapses, in one cost order (cells
//!   are not alike: one may be flat, another curved).
//!
//! Small meshes (under twice [`GROUP_TRIANGLES`]; they come by the thousand
//! from the tiler, already in parallel) run as one. The grouping depends on
//! the mesh only (not on the thread count), so the output is the same on
//! every machine.

use glam::DVec3;
use rayon::prelude::*;

use super::qem::{self, QemInput, QemOutput, QemParams};
use super::quadric::Quadric;

/// Triangles per group: below twice this a mesh runs as one group (small
/// meshes come by the thousand from the tiler, already in parallel).
const GROUP_TRIANGLES: usize = 100_000;
/// At most this many groups, whatever the size.
const MAX_GROUPS: usize = 8;
/// At least this many parts per group: a group of a few parts would not be
/// a fair sample of the model, and its share of the goal would be off.
const PARTS_PER_GROUP: usize = 32;

/// [`qem::run`] over groups of connected parts, or cells of one large
/// surface, in parallel (see the module documentation); the output is
/// numbered as the input.
pub(crate) fn run(input: QemInput, params: &QemParams) -> QemOutput {
    run_in_groups(GROUP_TRIANGLES, input, params)
}

/// Cells of one surface stop this far from the goal (a fraction of the
/// triangles to remove); one run over the whole surface does the rest.
/// Too close to the goal and the cells' borders cost error that one run
/// would not; this leaves the whole-surface run enough collapses to match
/// one run's error, faster (chosen by measurement: docs/benchmarks.md).
const CELL_SLACK: f64 = 0.25;
/// A vertex in no piece.
const NO_PIECE: u32 = u32::MAX;

/// [`run`] with groups of about `group_triangles` triangles.
fn run_in_groups(group_triangles: usize, input: QemInput, params: &QemParams) -> QemOutput {
    if let Some((part, group_of_part)) =
        deal_parts(group_triangles, &input.pos, &input.wedge_pos, &input.tris)
    {
        let group: Vec<u32> = part.iter().map(|&c| group_of_part[c as usize]).collect();
        let (mut whole, tris) = Whole::new(input);
        let c = whole.run_groups(&group, tris, params.target_tris, params);
        return whole.output(c);
    }
    let Some(cell) = cut_cells(group_triangles, &input.pos, &input.wedge_pos, &input.tris) else {
        return qem::run(input, params);
    };
    // One surface. Its quadrics first, as one run has them (a cell alone
    // would take its cut for a border), carried through both steps: the
    // cells (the cut pinned) to near the goal, then the whole to the goal,
    // so that the last collapses, which set the error, are taken in one
    // cost order (cells of a surface are not alike: one may be flat,
    // another curved).
    let (stride, normal_offset) = (input.stride, input.normal_offset);
    let start = qem::run(input, &params.with_target(usize::MAX));
    let (mut whole, tris) = Whole::carry(start, stride, normal_offset);
    let to_remove = tris.len().saturating_sub(params.target_tris);
    let cells_goal = params.target_tris + (CELL_SLACK * to_remove as f64) as usize;
    let cells = whole.run_groups(&cell, tris, cells_goal, params);
    let mut in_use = vec![NO_PIECE; whole.pos.len()];
    for t in &cells.tris {
        for &w in t {
            in_use[whole.wedge_pos[w as usize] as usize] = 0;
        }
    }
    let mut last = whole.run_groups(&in_use, cells.tris, params.target_tris, params);
    last.max_qem_distance = last.max_qem_distance.max(cells.max_qem_distance);
    last.max_collapsed_edge = last.max_collapsed_edge.max(cells.max_collapsed_edge);
    whole.output(last)
}

/// Triangles after a step (input wedge numbers) and its largest errors.
struct Collapsed {
    tris: Vec<[u32; 3]>,
    max_qem_distance: f64,
    max_collapsed_edge: f64,
}

/// The mesh in the input's numbering: what the pieces are cut from and
/// written back to.
struct Whole {
    pos: Vec<DVec3>,
    locked: Vec<bool>,
    curv: Vec<f32>,
    wedge_pos: Vec<u32>,
    attr: Vec<f32>,
    stride: usize,
    normal_offset: Option<usize>,
    /// Carried quadrics (else each piece computes its own).
    quad: Option<Vec<Quadric>>,
}

/// A piece of the mesh: its vertices (input numbers; the pinned ones last),
/// the wedges of those vertices, and its triangle goal.
struct Piece {
    vertices: Vec<u32>,
    wedges: Vec<u32>,
    target: usize,
}

impl Whole {
    fn new(input: QemInput) -> (Whole, Vec<[u32; 3]>) {
        let whole = Whole {
            pos: input.pos,
            locked: input.locked,
            curv: input.curv,
            wedge_pos: input.wedge_pos,
            attr: input.attr,
            stride: input.stride,
            normal_offset: input.normal_offset,
            quad: input.quadrics,
        };
        (whole, input.tris)
    }

    /// The state after a run, its quadrics carried.
    fn carry(
        out: QemOutput,
        stride: usize,
        normal_offset: Option<usize>,
    ) -> (Whole, Vec<[u32; 3]>) {
        let whole = Whole {
            pos: out.pos,
            locked: out.locked,
            curv: out.curv,
            wedge_pos: out.wedge_pos,
            attr: out.attr,
            stride,
            normal_offset,
            quad: Some(out.quad),
        };
        (whole, out.tris)
    }

    /// Runs every group (`group` of each position vertex, or [`NO_PIECE`])
    /// on its own triangles, in parallel, to its share of `goal`, and takes
    /// the results back. Triangles across groups are kept as they are, and
    /// their vertices pinned.
    fn run_groups(
        &mut self,
        group: &[u32],
        tris: Vec<[u32; 3]>,
        goal: usize,
        params: &QemParams,
    ) -> Collapsed {
        let n_groups = group
            .iter()
            .filter(|&&g| g != NO_PIECE)
            .max()
            .map_or(0, |&g| g as usize + 1);
        let group_of = |t: &[u32; 3]| {
            let g = group[self.wedge_pos[t[0] as usize] as usize];
            t.iter()
                .all(|&w| group[self.wedge_pos[w as usize] as usize] == g)
                .then_some(g as usize)
        };
        let mut group_tris: Vec<Vec<[u32; 3]>> = vec![Vec::new(); n_groups];
        let mut across = Vec::new();
        for t in tris {
            match group_of(&t) {
                Some(g) => group_tris[g].push(t),
                None => across.push(t),
            }
        }
        let mut pinned = vec![false; self.pos.len()];
        for t in &across {
            for &w in t {
                pinned[self.wedge_pos[w as usize] as usize] = true;
            }
        }
        let sizes: Vec<usize> = group_tris.iter().map(Vec::len).collect();
        let goal = goal.saturating_sub(across.len());
        let targets = share(goal, &sizes);
        let pieces = self.pieces(group, &pinned, group_tris, &targets);
        let outputs: Vec<(Piece, QemOutput)> = pieces
            .into_par_iter()
            .map(|(piece, input)| {
                let out = qem::run(input, &params.with_target(piece.target));
                (piece, out)
            })
            .collect();
        let mut tris = Vec::new();
        let (mut max_qem_distance, mut max_collapsed_edge) = (0.0f64, 0.0f64);
        for (piece, out) in outputs {
            max_qem_distance = max_qem_distance.max(out.max_qem_distance);
            max_collapsed_edge = max_collapsed_edge.max(out.max_collapsed_edge);
            tris.extend(self.absorb(&piece, &pinned, out));
        }
        tris.extend(across);
        Collapsed {
            tris,
            max_qem_distance,
            max_collapsed_edge,
        }
    }

    /// The whole as a run's output, with the triangles and errors of `c`.
    fn output(self, c: Collapsed) -> QemOutput {
        QemOutput {
            pos: self.pos,
            locked: self.locked,
            wedge_pos: self.wedge_pos,
            attr: self.attr,
            tris: c.tris,
            max_qem_distance: c.max_qem_distance,
            max_collapsed_edge: c.max_collapsed_edge,
            quad: self.quad.unwrap_or_default(),
            curv: self.curv,
        }
    }

    /// The pieces (`piece_of` each vertex, or [`NO_PIECE`]; `tris[i]`: piece
    /// `i`'s triangles, input wedge numbers) as inputs of their own. Pinned
    /// vertices are locked and numbered last: a collapse removes the lower
    /// numbered of its two vertices (the other takes the new position), so
    /// a pinned vertex, and the wedges that triangles outside the piece
    /// use, are never removed.
    fn pieces(
        &self,
        piece_of: &[u32],
        pinned: &[bool],
        tris: Vec<Vec<[u32; 3]>>,
        targets: &[usize],
    ) -> Vec<(Piece, QemInput)> {
        let n = tris.len();
        let mut local = vec![0u32; self.pos.len()];
        let mut vertices: Vec<Vec<u32>> = vec![Vec::new(); n];
        for last in [false, true] {
            for (x, &g) in piece_of.iter().enumerate() {
                if g != NO_PIECE && pinned[x] == last {
                    local[x] = vertices[g as usize].len() as u32;
                    vertices[g as usize].push(x as u32);
                }
            }
        }
        let mut local_wedge = vec![0u32; self.wedge_pos.len()];
        let mut wedges: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (w, &x) in self.wedge_pos.iter().enumerate() {
            let g = piece_of[x as usize];
            if g != NO_PIECE {
                local_wedge[w] = wedges[g as usize].len() as u32;
                wedges[g as usize].push(w as u32);
            }
        }
        let s = self.stride;
        tris.into_iter()
            .zip(vertices.into_iter().zip(wedges))
            .zip(targets)
            .map(|((t, (vs, ws)), &target)| {
                let input = QemInput {
                    pos: vs.iter().map(|&x| self.pos[x as usize]).collect(),
                    locked: vs
                        .iter()
                        .map(|&x| self.locked[x as usize] || pinned[x as usize])
                        .collect(),
                    curv: vs.iter().map(|&x| self.curv[x as usize]).collect(),
                    wedge_pos: ws
                        .iter()
                        .map(|&w| local[self.wedge_pos[w as usize] as usize])
                        .collect(),
                    tris: t
                        .iter()
                        .map(|t| t.map(|w| local_wedge[w as usize]))
                        .collect(),
                    attr: ws
                        .iter()
                        .flat_map(|&w| &self.attr[w as usize * s..(w as usize + 1) * s])
                        .copied()
                        .collect(),
                    stride: s,
                    normal_offset: self.normal_offset,
                    quadrics: self
                        .quad
                        .as_ref()
                        .map(|q| vs.iter().map(|&x| q[x as usize]).collect()),
                };
                let piece = Piece {
                    vertices: vs,
                    wedges: ws,
                    target,
                };
                (piece, input)
            })
            .collect()
    }

    /// Writes a piece's result back; its triangles in input wedge numbers.
    /// (A pinned vertex keeps its own lock flag: pinning was for the piece.)
    fn absorb(&mut self, piece: &Piece, pinned: &[bool], out: QemOutput) -> Vec<[u32; 3]> {
        let (vs, ws, s) = (&piece.vertices, &piece.wedges, self.stride);
        for (l, &x) in vs.iter().enumerate() {
            let x = x as usize;
            self.pos[x] = out.pos[l];
            self.curv[x] = out.curv[l];
            if let Some(q) = self.quad.as_mut() {
                q[x] = out.quad[l];
            }
            if !pinned[x] {
                self.locked[x] = out.locked[l];
            }
        }
        for (l, &w) in ws.iter().enumerate() {
            let w = w as usize;
            self.wedge_pos[w] = vs[out.wedge_pos[l] as usize];
            self.attr[w * s..(w + 1) * s].copy_from_slice(&out.attr[l * s..(l + 1) * s]);
        }
        out.tris.iter().map(|t| t.map(|l| ws[l as usize])).collect()
    }
}

/// One large surface (or a mesh whose parts cannot be dealt evenly) cut
/// into cells of about equal vertex count: each time the cell with most
/// vertices is halved at the median along its longest side. The cell of
/// every position vertex, or `None` when too small or when more than 5 % of
/// the triangles would cross cells.
fn cut_cells(
    group_triangles: usize,
    pos: &[DVec3],
    wedge_pos: &[u32],
    tris: &[[u32; 3]],
) -> Option<Vec<u32>> {
    let n_cells = (tris.len() / group_triangles).min(MAX_GROUPS);
    if n_cells < 2 {
        return None;
    }
    let mut used = vec![false; pos.len()];
    for t in tris {
        for &w in t {
            used[wedge_pos[w as usize] as usize] = true;
        }
    }
    let mut order: Vec<u32> = (0..pos.len() as u32)
        .filter(|&x| used[x as usize])
        .collect();
    let mut cells = vec![(0, order.len())];
    while cells.len() < n_cells {
        let (i, &(a, b)) = cells
            .iter()
            .enumerate()
            .max_by_key(|(i, (a, b))| (b - a, std::cmp::Reverse(*i)))?;
        let slice = &mut order[a..b];
        let (lo, hi) = slice.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &x| (lo.min(pos[x as usize]), hi.max(pos[x as usize])),
        );
        let size = hi - lo;
        let axis = if size.x >= size.y && size.x >= size.z {
            0
        } else if size.y >= size.z {
            1
        } else {
            2
        };
        let mid = slice.len() / 2;
        slice.select_nth_unstable_by(mid, |&x, &y| {
            pos[x as usize][axis]
                .total_cmp(&pos[y as usize][axis])
                .then(x.cmp(&y))
        });
        cells[i] = (a, a + mid);
        cells.push((a + mid, b));
    }
    let mut cell = vec![0u32; pos.len()];
    for (c, &(a, b)) in cells.iter().enumerate() {
        for &x in &order[a..b] {
            cell[x as usize] = c as u32;
        }
    }
    let crossing = tris
        .iter()
        .filter(|t| {
            let c = cell[wedge_pos[t[0] as usize] as usize];
            t.iter().any(|&w| cell[wedge_pos[w as usize] as usize] != c)
        })
        .count();
    (crossing * 20 <= tris.len()).then_some(cell)
}

/// The connected part of every position vertex and the group of every
/// part ([`qem::components`]), or `None` when the mesh should run as one group: too small, or no way
/// to deal its parts into groups of about equal size.
fn deal_parts(
    group_triangles: usize,
    pos: &[DVec3],
    wedge_pos: &[u32],
    tris: &[[u32; 3]],
) -> Option<(Vec<u32>, Vec<u32>)> {
    if tris.len() / group_triangles < 2 {
        return None;
    }
    let (part, radius2) = qem::components(pos, wedge_pos, tris);
    let mut size = vec![0usize; radius2.len()];
    for t in tris {
        size[part[wedge_pos[t[0] as usize] as usize] as usize] += 1;
    }
    let n_parts = size.iter().filter(|&&s| s > 0).count();
    let n_groups = (tris.len() / group_triangles)
        .min(n_parts / PARTS_PER_GROUP)
        .min(MAX_GROUPS);
    if n_groups < 2 {
        return None;
    }
    // Largest first, each to the group with the fewest triangles so far
    // (ties: the first); the order is total, so the dealing is reproducible.
    let mut order: Vec<u32> = (0..size.len() as u32).collect();
    order.sort_unstable_by_key(|&c| (std::cmp::Reverse(size[c as usize]), c));
    let mut load = vec![0usize; n_groups];
    let mut group = vec![0u32; size.len()];
    for c in order {
        let g = (0..n_groups).min_by_key(|&g| (load[g], g)).unwrap_or(0);
        group[c as usize] = g as u32;
        load[g] += size[c as usize];
    }
    // A group more than a quarter above the mean (one part dominates):
    // the parallel run would mostly wait for it, and its share of the goal
    // would be decided by one part.
    let mean = tris.len() as f64 / n_groups as f64;
    let largest = load.iter().copied().max().unwrap_or(0) as f64;
    (largest <= 1.25 * mean).then_some((part, group))
}

/// `total` split in proportion to `sizes` (largest remainders first; ties
/// to the earlier group), summing to `total`.
fn share(total: usize, sizes: &[usize]) -> Vec<usize> {
    let all: usize = sizes.iter().sum();
    if all == 0 {
        return vec![0; sizes.len()];
    }
    let total = total.min(all);
    let exact: Vec<u128> = sizes.iter().map(|&s| total as u128 * s as u128).collect();
    let mut out: Vec<usize> = exact.iter().map(|&e| (e / all as u128) as usize).collect();
    let mut rest = total - out.iter().sum::<usize>();
    let mut by_remainder: Vec<usize> = (0..sizes.len()).collect();
    by_remainder.sort_by_key(|&i| (std::cmp::Reverse(exact[i] % all as u128), i));
    for i in by_remainder {
        if rest == 0 {
            break;
        }
        out[i] += 1;
        rest -= 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` separate wavy patches of `q x q` quads side by side (patch `i`
    /// with bump amplitude `amp(i)`), as welded QEM input.
    fn patches(n: usize, q: usize, amp: impl Fn(usize) -> f64) -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let (mut pos, mut tris) = (Vec::new(), Vec::new());
        for i in 0..n {
            let base = pos.len() as u32;
            for y in 0..=q {
                for x in 0..=q {
                    let (fx, fy) = (x as f64 / q as f64, y as f64 / q as f64);
                    let z = amp(i) * (fx * 6.0).sin() * (fy * 4.0).cos();
                    pos.push(DVec3::new(fx + 1.5 * i as f64, fy, z));
                }
            }
            let w = q as u32 + 1;
            for y in 0..q as u32 {
                for x in 0..q as u32 {
                    let c = base + y * w + x;
                    tris.push([c, c + 1, c + w + 1]);
                    tris.push([c, c + w + 1, c + w]);
                }
            }
        }
        (pos, tris)
    }

    fn params(target_tris: usize) -> QemParams {
        QemParams {
            target_tris,
            target_error2: f64::INFINITY,
            curvature_weight: 1.0,
            cos_max_angle: 60f64.to_radians().cos(),
            max_edge_len2: f64::INFINITY,
            lock_borders: false,
            boundary_weight: 1.0,
            strict_wedges: false,
            keep_apart_m: f64::INFINITY,
        }
    }

    fn run_with(
        group_triangles: usize,
        pos: &[DVec3],
        tris: &[[u32; 3]],
        target: usize,
    ) -> QemOutput {
        let nv = pos.len();
        let input = QemInput {
            pos: pos.to_vec(),
            locked: vec![false; nv],
            curv: vec![0.0; nv],
            wedge_pos: (0..nv as u32).collect(),
            tris: tris.to_vec(),
            attr: Vec::new(),
            stride: 0,
            normal_offset: None,
            quadrics: None,
        };
        run_in_groups(group_triangles, input, &params(target))
    }

    #[test]
    fn parts_are_dealt_evenly_and_unequal_or_small_meshes_run_whole() {
        let (pos, tris) = patches(128, 4, |_| 0.1);
        let ids: Vec<u32> = (0..pos.len() as u32).collect();
        // 4096 triangles in groups of 1024: 4 groups of 32 patches.
        let (part, group) = deal_parts(1024, &pos, &ids, &tris).expect("dealt");
        let mut load = [0usize; 4];
        for t in &tris {
            load[group[part[t[0] as usize] as usize] as usize] += 1;
        }
        assert_eq!(load, [1024; 4]);
        assert!(deal_parts(4096, &pos, &ids, &tris).is_none(), "too small");
        // Groups of 512 triangles would hold 16 parts each: 4 groups still.
        let (_, group) = deal_parts(512, &pos, &ids, &tris).expect("dealt");
        assert_eq!(group.iter().max(), Some(&3));
        // One patch of 4608 triangles and 96 of 32: one group would hold 60 %.
        let (big, big_tris) = patches(1, 48, |_| 0.1);
        let (small, small_tris) = patches(96, 4, |_| 0.1);
        let n = big.len() as u32;
        let pos: Vec<DVec3> = big
            .into_iter()
            .chain(small.into_iter().map(|p| p + DVec3::Y * 3.0))
            .collect();
        let tris: Vec<[u32; 3]> = big_tris
            .into_iter()
            .chain(small_tris.into_iter().map(|t| t.map(|x| x + n)))
            .collect();
        let ids: Vec<u32> = (0..pos.len() as u32).collect();
        assert!(
            deal_parts(2000, &pos, &ids, &tris).is_none(),
            "one part dominates"
        );
    }

    #[test]
    fn groups_reach_the_goal_keep_each_part_and_stay_close_to_one_run() {
        // 96 patches, four kinds of relief dealt over 3 groups.
        let (pos, tris) = patches(96, 8, |i| [0.02, 0.1, 0.3, 0.05][i % 4]);
        let target = tris.len() / 5;
        let whole = run_with(usize::MAX, &pos, &tris, target);
        let grouped = run_with(2400, &pos, &tris, target);
        let ids: Vec<u32> = (0..pos.len() as u32).collect();
        let (_, group) = deal_parts(2400, &pos, &ids, &tris).expect("dealt");
        let groups = 3;
        assert_eq!(group.iter().max(), Some(&(groups as u32 - 1)));
        assert!(grouped.tris.len() <= target && grouped.tris.len() + 2 * groups >= target);
        // Input numbering: a wedge stays on a vertex of its own patch, and
        // every patch keeps triangles.
        let patch_of = |x: u32| x as usize / (9 * 9);
        let mut kept = [0usize; 96];
        for t in &grouped.tris {
            for &w in t {
                let x = grouped.wedge_pos[w as usize];
                assert_eq!(patch_of(x), patch_of(w), "wedge {w} moved to another part");
                assert!(grouped.pos[x as usize].is_finite());
            }
            kept[patch_of(t[0])] += 1;
        }
        assert!(kept.iter().all(|&k| k > 0), "{kept:?}");
        // Every group is a similar mix: the error stays near one run's.
        close_to_one_run_and_same_on_one_thread(&grouped, &whole, || {
            run_with(2400, &pos, &tris, target)
        });
    }

    /// `out`'s error is within 1.5x of one run's (`whole`), and `again` on
    /// one thread gives the same output.
    fn close_to_one_run_and_same_on_one_thread(
        out: &QemOutput,
        whole: &QemOutput,
        again: impl Fn() -> QemOutput + Send + Sync,
    ) {
        assert!(
            out.max_qem_distance <= 1.5 * whole.max_qem_distance,
            "{} vs one run's {}",
            out.max_qem_distance,
            whole.max_qem_distance
        );
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(again);
        assert_eq!(one.tris, out.tris);
        assert_eq!(one.pos, out.pos);
    }

    #[test]
    fn one_surface_is_cut_into_cells_without_cracks() {
        // One wavy 120 x 120 surface, no parts to deal: cut into 5 cells.
        let (pos, tris) = patches(1, 120, |_| 0.2);
        let target = tris.len() / 10;
        let ids: Vec<u32> = (0..pos.len() as u32).collect();
        assert!(deal_parts(5000, &pos, &ids, &tris).is_none());
        let cell = cut_cells(5000, &pos, &ids, &tris).expect("cut");
        assert_eq!(cell.iter().max(), Some(&4));
        let whole = run_with(usize::MAX, &pos, &tris, target);
        let cells = run_with(5000, &pos, &tris, target);
        assert!(cells.tris.len() <= target && cells.tris.len() + 2 >= target);
        // No crack along a cut: every open edge of the output is on the
        // surface's own border.
        let mut edges = std::collections::HashMap::new();
        for t in &cells.tris {
            let v = t.map(|w| cells.wedge_pos[w as usize]);
            for k in 0..3 {
                let e = (v[k].min(v[(k + 1) % 3]), v[k].max(v[(k + 1) % 3]));
                *edges.entry(e).or_insert(0) += 1;
            }
        }
        let on_border = |x: u32| {
            let p = cells.pos[x as usize];
            [p.x, p.y]
                .iter()
                .any(|&c| c.abs() < 1e-3 || (c - 1.0).abs() < 1e-3)
        };
        for (&(a, b), &n) in &edges {
            assert!(
                n == 2 || (n == 1 && on_border(a) && on_border(b)),
                "edge {a}-{b} x{n}: a crack"
            );
        }
        close_to_one_run_and_same_on_one_thread(&cells, &whole, || {
            run_with(5000, &pos, &tris, target)
        });
    }

    #[test]
    fn shares_sum_to_the_total_in_proportion() {
        assert_eq!(share(10, &[50, 50]), vec![5, 5]);
        assert_eq!(share(10, &[10, 10, 10]), vec![4, 3, 3]);
        assert_eq!(
            share(10, &[1, 1, 1]),
            vec![1, 1, 1],
            "no more than there is"
        );
        assert_eq!(share(7, &[30, 10]), vec![5, 2]);
        assert_eq!(share(100, &[3, 4]), vec![3, 4]);
        assert_eq!(share(5, &[0, 0]), vec![0, 0]);
        let s = share(24_102, &[120_509, 120_507]);
        assert_eq!(s.iter().sum::<usize>(), 24_102);
    }
}
