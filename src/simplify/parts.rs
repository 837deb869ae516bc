//! Parallel simplification of a large mesh made of many connected parts
//! (a BIM model: thousands of separate members): the parts are dealt into a
//! few groups of about equal size, each group is simplified on its own
//! ([`qem::run`], in parallel with rayon) to its share of the triangle
//! goal, and the results are put back in the input's numbering: "parallel
//! over independent meshes" (issue 3) inside one mesh. Collapses never
//! cross parts, so a group's result depends on its own parts only.
//!
//! What changes against one run over everything: the goal is shared in
//! proportion to each group's triangles instead of by one global cost
//! order. With many parts dealt by size, every group is a similar mix of
//! the model, so the groups end at similar costs (checked by the quality
//! test: `tests/simplify_quality.rs`). Meshes with few or very unequal parts
//! (a terrain, one big shell), and small meshes, run as one group.
//!
//! The grouping depends on the input only (not on the thread count), so the
//! output is the same on every machine.

use glam::DVec3;
use rayon::prelude::*;

use super::qem::{self, QemInput, QemOutput, QemParams};

/// Triangles per group: below twice this a mesh runs as one group (small
/// meshes come by the thousand from the tiler, already in parallel).
const GROUP_TRIANGLES: usize = 100_000;
/// At most this many groups, whatever the size.
const MAX_GROUPS: usize = 8;
/// At least this many parts per group: a group of a few parts would not be
/// a fair sample of the model, and its share of the goal would be off.
const PARTS_PER_GROUP: usize = 32;

/// [`qem::run`] over groups of connected parts, in parallel (see the module
/// documentation); the output is numbered as the input.
pub(crate) fn run(input: QemInput, params: &QemParams) -> QemOutput {
    run_in_groups(GROUP_TRIANGLES, input, params)
}

/// [`run`] with groups of about `group_triangles` triangles.
fn run_in_groups(group_triangles: usize, input: QemInput, params: &QemParams) -> QemOutput {
    let Some((part, group_of_part)) =
        deal_parts(group_triangles, &input.pos, &input.wedge_pos, &input.tris)
    else {
        return qem::run(input, params);
    };
    let group_of_vertex = |x: u32| group_of_part[part[x as usize] as usize];
    let n_groups = group_of_part.iter().max().map_or(0, |&g| g as usize + 1);

    // Each group's vertices, wedges and triangles, renumbered in input
    // order (`local`: input index -> index in its group).
    let mut local_vertex = vec![0u32; input.pos.len()];
    let mut vertices: Vec<Vec<u32>> = vec![Vec::new(); n_groups];
    for x in 0..input.pos.len() as u32 {
        let g = group_of_vertex(x) as usize;
        local_vertex[x as usize] = vertices[g].len() as u32;
        vertices[g].push(x);
    }
    let mut local_wedge = vec![0u32; input.wedge_pos.len()];
    let mut wedges: Vec<Vec<u32>> = vec![Vec::new(); n_groups];
    for (w, &x) in input.wedge_pos.iter().enumerate() {
        let g = group_of_vertex(x) as usize;
        local_wedge[w] = wedges[g].len() as u32;
        wedges[g].push(w as u32);
    }
    let mut group_tris: Vec<Vec<[u32; 3]>> = vec![Vec::new(); n_groups];
    for t in &input.tris {
        let g = group_of_vertex(input.wedge_pos[t[0] as usize]) as usize;
        group_tris[g].push(t.map(|w| local_wedge[w as usize]));
    }
    let targets = share(
        params.target_tris,
        &group_tris.iter().map(Vec::len).collect::<Vec<_>>(),
    );

    let outputs: Vec<QemOutput> = (0..n_groups)
        .into_par_iter()
        .zip(group_tris.into_par_iter())
        .map(|(g, gt)| {
            let vs = &vertices[g];
            let ws = &wedges[g];
            let group_params = QemParams {
                target_tris: targets[g],
                ..params.clone()
            };
            qem::run(
                QemInput {
                    pos: vs.iter().map(|&x| input.pos[x as usize]).collect(),
                    locked: vs.iter().map(|&x| input.locked[x as usize]).collect(),
                    curv: vs.iter().map(|&x| input.curv[x as usize]).collect(),
                    wedge_pos: ws
                        .iter()
                        .map(|&w| local_vertex[input.wedge_pos[w as usize] as usize])
                        .collect(),
                    tris: gt,
                    attr: ws
                        .iter()
                        .flat_map(|&w| {
                            &input.attr[w as usize * input.stride..(w as usize + 1) * input.stride]
                        })
                        .copied()
                        .collect(),
                    stride: input.stride,
                    normal_offset: input.normal_offset,
                },
                &group_params,
            )
        })
        .collect();

    // Back to the input's numbering.
    let stride = input.stride;
    let (mut pos, mut wedge_pos, mut attr) = (input.pos, input.wedge_pos, input.attr);
    let mut out_tris = Vec::new();
    let (mut max_qem_distance, mut max_collapsed_edge) = (0.0f64, 0.0f64);
    for (g, o) in outputs.into_iter().enumerate() {
        let (vs, ws) = (&vertices[g], &wedges[g]);
        for (l, &x) in vs.iter().enumerate() {
            pos[x as usize] = o.pos[l];
        }
        for (l, &w) in ws.iter().enumerate() {
            let w = w as usize;
            wedge_pos[w] = vs[o.wedge_pos[l] as usize];
            attr[w * stride..(w + 1) * stride]
                .copy_from_slice(&o.attr[l * stride..(l + 1) * stride]);
        }
        out_tris.extend(o.tris.iter().map(|t| t.map(|l| ws[l as usize])));
        max_qem_distance = max_qem_distance.max(o.max_qem_distance);
        max_collapsed_edge = max_collapsed_edge.max(o.max_collapsed_edge);
    }
    QemOutput {
        pos,
        wedge_pos,
        attr,
        tris: out_tris,
        max_qem_distance,
        max_collapsed_edge,
    }
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
        assert!(
            grouped.max_qem_distance <= 1.5 * whole.max_qem_distance,
            "grouped {} vs whole {}",
            grouped.max_qem_distance,
            whole.max_qem_distance
        );
        // The same on any thread count.
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| run_with(2400, &pos, &tris, target));
        assert_eq!(one.tris, grouped.tris);
        assert_eq!(one.pos, grouped.pos);
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
