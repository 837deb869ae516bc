//! HLOD, checked from the outside: every internal tile's declared geometricError against an
//! independent measurement of how far its content really is from the full detail it stands for
//! (honest: not larger than declared; tight: declared not more than 2x the measurement), and no
//! cracks along tile borders at any level.
//!
//! The measurement is ours only in the sense of living in this file: a bounding-volume hierarchy
//! over triangles and exact point-to-triangle distances (Ericson), sampling every vertex, edge
//! midpoint and centroid plus area-weighted points of both surfaces (past a bounded number of
//! points, every centroid and points by area); it shares no code with the simplifier's
//! measurement.

use crate::common::height_field::height_field_glb;
use crate::common::*;
use glam::DVec3;
use std::collections::HashMap;

type Tri = [DVec3; 3];

/// How far a decoded full-detail vertex (Draco, meshopt or quantized) may lie from the input: 1 mm
/// per axis.
const LEAF_GRID_M: f64 = 1.7321e-3;

/// The ladder's bound: a child declares at most this share of its parent's geometricError.
const LADDER_CHILD_RATIO: f64 = 0.5;

/// Triangles of a decoded tile.
fn triangles(t: &DecodedTile) -> Vec<Tri> {
    t.indices
        .chunks_exact(3)
        .map(|c| [0, 1, 2].map(|k| t.positions[c[k] as usize]))
        .collect()
}

fn closest_on_triangle(p: DVec3, [a, b, c]: &Tri) -> DVec3 {
    let (ab, ac, ap) = (*b - *a, *c - *a, p - *a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - *b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return *a + ab * (d1 / (d1 - d3));
    }
    let cp = p - *c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return *a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return *b + (*c - *b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    *a + ab * (vb * denom) + ac * (vc * denom)
}

/// Uniform grid of triangles for closest-point queries.
/// A triangle set for exact nearest-distance queries: a bounding-volume hierarchy (median splits
/// on the longest axis), searched nearest box first. A grid's cells cannot suit a 7 km scene and a
/// detailed hangar at once; the hierarchy adapts to both.
struct Surface {
    tris: Vec<Tri>,
    nodes: Vec<BoxNode>,
}

/// A box over `tris[start..start + count]` (a leaf), or over its two children `first_child` and
/// `first_child + 1`.
struct BoxNode {
    lo: DVec3,
    hi: DVec3,
    start: u32,
    count: u32,
    first_child: u32,
}

const LEAF_TRIANGLES: usize = 8;

impl Surface {
    fn new(mut tris: Vec<Tri>) -> Surface {
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF_TRIANGLES + 1);
        nodes.push(BoxNode {
            lo: DVec3::ZERO,
            hi: DVec3::ZERO,
            start: 0,
            count: tris.len() as u32,
            first_child: 0,
        });
        let mut todo = vec![0usize];
        while let Some(n) = todo.pop() {
            let (start, count) = (nodes[n].start as usize, nodes[n].count as usize);
            let part = &mut tris[start..start + count];
            let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
            for p in part.iter().flatten() {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
            (nodes[n].lo, nodes[n].hi) = (lo, hi);
            if count <= LEAF_TRIANGLES {
                continue;
            }
            let axis = (hi - lo).max_position();
            let centre = |t: &Tri| t[0][axis] + t[1][axis] + t[2][axis];
            let half = count / 2;
            part.select_nth_unstable_by(half, |a, b| centre(a).total_cmp(&centre(b)));
            let first_child = nodes.len();
            for (s, c) in [(start, half), (start + half, count - half)] {
                nodes.push(BoxNode {
                    lo,
                    hi,
                    start: s as u32,
                    count: c as u32,
                    first_child: 0,
                });
                todo.push(nodes.len() - 1);
            }
            nodes[n].first_child = first_child as u32;
            nodes[n].count = 0;
        }
        Surface { tris, nodes }
    }

    /// Distance from `p` to the surface.
    fn distance(&self, p: DVec3) -> f64 {
        let box_d2 = |n: &BoxNode| (n.lo - p).max(p - n.hi).max(DVec3::ZERO).length_squared();
        let mut best2 = f64::INFINITY;
        let mut stack = vec![(0u32, box_d2(&self.nodes[0]))];
        while let Some((n, d2)) = stack.pop() {
            if d2 >= best2 {
                continue;
            }
            let node = &self.nodes[n as usize];
            if node.count > 0 {
                let (s, c) = (node.start as usize, node.count as usize);
                for t in &self.tris[s..s + c] {
                    best2 = best2.min((closest_on_triangle(p, t) - p).length_squared());
                }
                continue;
            }
            let (a, b) = (node.first_child, node.first_child + 1);
            let (da, db) = (
                box_d2(&self.nodes[a as usize]),
                box_d2(&self.nodes[b as usize]),
            );
            // The nearer child is searched first (pushed last).
            if da < db {
                stack.extend([(b, db), (a, da)]);
            } else {
                stack.extend([(a, da), (b, db)]);
            }
        }
        best2.sqrt()
    }
}

/// Points measured on one surface at most. Below it: every vertex, edge quarter point and
/// centroid (where simplification errors peak), plus `extra` points by area. Past it (the root of a wide
/// scene stands for every triangle): the centroids, a stride of them if need be, and the rest of
/// the budget by area, so a small part far off is still sampled.
const MAX_SAMPLES: usize = 2_000_000;

/// Sample points of a surface (deterministic; see [`MAX_SAMPLES`]).
fn samples(tris: &[Tri], extra: usize) -> Vec<DVec3> {
    let every_corner = 13 * tris.len() + extra <= MAX_SAMPLES;
    let centroid_step = tris.len().div_ceil(MAX_SAMPLES / 2).max(1);
    let extra = if every_corner {
        extra
    } else {
        MAX_SAMPLES - tris.len().div_ceil(centroid_step)
    };
    let mut out = Vec::with_capacity(MAX_SAMPLES.min(tris.len() * 13 + extra));
    let mut area_total = 0.0;
    for (i, t) in tris.iter().enumerate() {
        if every_corner {
            out.extend_from_slice(t);
            // Every edge at its quarter points too: along an edge the distance to a coarser
            // surface peaks between corners (a tile of LoD3_Railway at 1,000 triangles declared
            // 0.0428 m while an edge of its full detail lay 0.0487 m away).
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                out.extend([a * 0.75 + b * 0.25, (a + b) * 0.5, a * 0.25 + b * 0.75]);
            }
        }
        if every_corner || i % centroid_step == 0 {
            out.push((t[0] + t[1] + t[2]) / 3.0);
        }
        area_total += (t[1] - t[0]).cross(t[2] - t[0]).length() * 0.5;
    }
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for t in tris {
        let a = (t[1] - t[0]).cross(t[2] - t[0]).length() * 0.5;
        let n = (a / area_total.max(1e-12) * extra as f64).round() as usize;
        for _ in 0..n {
            let (mut u, mut v) = (rnd(), rnd());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            out.push(t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v);
        }
    }
    out
}

fn one_sided(from: &[DVec3], to: &Surface) -> f64 {
    use rayon::prelude::*;
    from.par_iter()
        .map(|&p| to.distance(p))
        .reduce(|| 0.0, f64::max)
}

/// Children lists of decoded tiles.
fn children(tiles: &[DecodedTile]) -> Vec<Vec<usize>> {
    let mut ch = vec![Vec::new(); tiles.len()];
    for (i, t) in tiles.iter().enumerate() {
        if let Some(p) = t.parent {
            ch[p].push(i);
        }
    }
    ch
}

/// For each internal tile: (index, measured symmetric Hausdorff distance to the full detail below
/// it, declared geometricError, largest child's error, the two one-sided distances).
fn measure_hlod(dir: &std::path::Path) -> Vec<(usize, f64, f64, f64, f64, f64)> {
    let (ts, tiles) = decode_tileset(dir);
    assert_eq!(ts["root"]["refine"], "REPLACE");
    let ch = children(&tiles);
    let mut leaves_below: Vec<Vec<usize>> = vec![Vec::new(); tiles.len()];
    for i in (0..tiles.len()).rev() {
        if ch[i].is_empty() {
            leaves_below[i].push(i);
        }
        let mine = leaves_below[i].clone();
        if let Some(p) = tiles[i].parent {
            leaves_below[p].extend(mine);
        }
    }
    let mut out = Vec::new();
    for (i, t) in tiles.iter().enumerate() {
        // Leaves are full detail; empty tiles (above discrete LOD chains) stand for nothing.
        if ch[i].is_empty() || t.triangles == 0 {
            continue;
        }
        let full: Vec<Tri> = leaves_below[i]
            .iter()
            .flat_map(|&l| triangles(&tiles[l]))
            .collect();
        let coarse = triangles(t);
        let d_full_to_coarse = one_sided(&samples(&full, 20_000), &Surface::new(coarse.clone()));
        let d_coarse_to_full = one_sided(&samples(&coarse, 20_000), &Surface::new(full));
        let children_max = ch[i]
            .iter()
            .map(|&c| tiles[c].geometric_error)
            .fold(0.0, f64::max);
        out.push((
            i,
            d_full_to_coarse.max(d_coarse_to_full),
            t.geometric_error,
            children_max,
            d_full_to_coarse,
            d_coarse_to_full,
        ));
    }
    out
}

/// Asserts honest and tight on every internal tile; returns (min, median, max) of
/// measured/declared.
///
/// `leaf_grid_m`: how far the drawn full detail itself may lie from the input (√3 mm with Draco
/// or KHR_mesh_quantization, 0 without compression): the declared error bounds the distance to
/// the input, and this test measures against the decoded leaves.
fn check_honest_and_tight(name: &str, dir: &std::path::Path, leaf_grid_m: f64) -> (f64, f64, f64) {
    let m = measure_hlod(dir);
    let (_, tiles) = decode_tileset(dir);
    assert!(!m.is_empty(), "{name}: no internal tiles");
    let mut ratios = Vec::new();
    let verbose = std::env::var_os("BIMTILES_HLOD_VERBOSE").is_some();
    let mut forced = 0;
    for &(i, measured, declared, children_max, f2c, c2f) in &m {
        if verbose {
            eprintln!("{name}: tile {i}: measured {measured:.4} m, declared {declared:.4} m");
        }
        // 20 µm of slack, and f32 rounding on a wide scene: vertices are f32 relative to each
        // tile's own centre (and were f32 in the input, kilometres from its origin on the
        // airport), so the same point decodes apart in two tiles (0.2 mm on the 7 km airport,
        // where tiles that simplify nothing declare the 0.1 mm floor).
        let f32_m = 3e-7 * (tiles[0].box_max - tiles[0].box_min).length();
        assert!(
            measured <= declared * 1.0001 + 2e-5 + f32_m + leaf_grid_m,
            "{name}: tile {i} is dishonest: real deviation {measured} m > declared {declared} m \
             (full to coarse {f2c} m, coarse to full {c2f} m)"
        );
        // Tight, with 1 mm of absolute slack: declared errors at the simplifier's 0.1 mm floor
        // stand for deviations too small to measure. The one exception is forced by the ladder
        // (a parent declares at least twice its children's error): a child measured against its
        // own full detail can lack something a sibling draws, or the parent simplifies little;
        // then the parent declares twice its largest child's error.
        let monotonic_floor = children_max / LADDER_CHILD_RATIO * (1.0 + 1e-5) + 1e-5;
        // (With compression, the declared error carries the quantization grid, √3 mm.)
        if declared > 2.0 * measured + 1e-3 + leaf_grid_m {
            assert!(
                declared <= monotonic_floor,
                "{name}: tile {i} is loose: declared {declared} m > 2 x real deviation {measured} m"
            );
            forced += 1;
        }
        ratios.push(measured / declared);
    }
    ratios.sort_by(f64::total_cmp);
    let r = (
        ratios[0],
        ratios[ratios.len() / 2],
        ratios[ratios.len() - 1],
    );
    eprintln!(
        "{name}: {} internal tiles ({forced} held above a child's error), measured/declared min {:.2} median {:.2} max {:.2}",
        m.len(),
        r.0,
        r.1,
        r.2
    );
    r
}

#[test]
fn sample_hlod_is_honest_and_tight() {
    let out = tmpdir("hlod-sample").join("tiles");
    let report = convert(
        &sample(),
        &out,
        &["--max-tile-triangles", "2000", "--compression", "none"],
    );
    assert_eq!(report["options"]["lod"], "hlod");
    assert!(report["geometric_error_metric"]
        .as_str()
        .unwrap()
        .starts_with("measured"));
    let tiles = check_tileset(
        &out,
        report["input"]["triangles"].as_u64().unwrap() as usize,
    );
    // The root is a coarse but whole building: within the budget, and it still spans the model.
    let root = &tiles[0];
    assert!(root.triangles <= 2000 && root.triangles > 200);
    let leaves_area: f64 = {
        let ch = children(&tiles);
        (0..tiles.len())
            .filter(|&i| ch[i].is_empty())
            .map(|i| tiles[i].area)
            .sum()
    };
    assert!(
        root.area > 0.3 * leaves_area,
        "root keeps the building's surface ({} of {} m2)",
        root.area,
        leaves_area
    );
    check_honest_and_tight("sample", &out, 0.0);
}

#[test]
fn shared_models_hlod_is_honest_and_tight() {
    let mut table = Vec::new();
    let only = std::env::var("BIMTILES_HLOD_ONLY").unwrap_or_default();
    for model in shared_models() {
        let name = model.file_stem().unwrap().to_string_lossy().to_string();
        if !name.contains(&only) {
            continue;
        }
        let out = tmpdir(&format!("hlod-{name}")).join("tiles");
        let report = convert(
            &model,
            &out,
            &["--max-tile-triangles", "5000", "--compression", "none"],
        );
        check_tileset(
            &out,
            report["input"]["triangles"].as_u64().unwrap() as usize,
        );
        if report["output"]["tiles"].as_u64().unwrap() == 1 {
            eprintln!("{name}: one tile, no HLOD to check");
            continue;
        }
        let r = check_honest_and_tight(&name, &out, 0.0);
        table.push((name, report["levels"].as_array().unwrap().len(), r));
    }
    for (name, levels, r) in &table {
        eprintln!(
            "| {name} | {levels} levels | measured/declared {:.2} / {:.2} / {:.2} |",
            r.0, r.1, r.2
        );
    }
}

/// Open-border edges (used by one triangle), by exact decoded positions.
fn border_points(tris: &[Tri]) -> Vec<DVec3> {
    let key = |p: DVec3| {
        let q = (p * 1e5).round();
        (q.x as i64, q.y as i64, q.z as i64)
    };
    let mut edges: HashMap<_, (u32, DVec3, DVec3)> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let (ka, kb) = (key(a), key(b));
            let e = edges
                .entry(if ka < kb { (ka, kb) } else { (kb, ka) })
                .or_insert((0, a, b));
            e.0 += 1;
        }
    }
    edges
        .values()
        .filter(|e| e.0 == 1)
        .flat_map(|&(_, a, b)| [a, (a + b) * 0.5, a * 0.75 + b * 0.25])
        .collect()
}

#[test]
fn no_cracks_between_tiles_at_any_level() {
    // One cut mesh (a 2 km height field of 80,000 triangles) over many tiles.
    let dir = tmpdir("hlod-cracks");
    let input = dir.join("terrain.glb");
    std::fs::write(&input, height_field_glb(200, 2000.0)).unwrap();
    let out = dir.join("tiles");
    convert(
        &input,
        &out,
        &["--max-tile-triangles", "3000", "--compression", "none"],
    );
    let (_, tiles) = decode_tileset(&out);
    let ch = children(&tiles);
    let max_depth = tiles.iter().map(|t| t.depth).max().unwrap();
    assert!(max_depth >= 2, "a real tree");
    // The terrain's own outer border is not a crack.
    let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
    for t in &tiles {
        for p in &t.positions {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let outer = |p: DVec3| {
        (p.x - lo.x).abs() < 1e-3
            || (p.x - hi.x).abs() < 1e-3
            || (p.y - lo.y).abs() < 1e-3
            || (p.y - hi.y).abs() < 1e-3
    };
    // Cracks open where tiles meet: along the borders of the full-detail leaves (the cut lines).
    let leaf_borders: Vec<(usize, Vec<DVec3>)> = (0..tiles.len())
        .filter(|&i| ch[i].is_empty())
        .map(|i| {
            let pts = border_points(&triangles(&tiles[i]));
            (i, pts.into_iter().filter(|&p| !outer(p)).collect())
        })
        .collect();
    for depth in 0..=max_depth {
        // What a viewer draws when it refines every tile down to `depth`.
        let front: Vec<usize> = (0..tiles.len())
            .filter(|&i| tiles[i].depth == depth || (tiles[i].depth < depth && ch[i].is_empty()))
            .collect();
        if front.len() < 2 {
            continue;
        }
        let drawn = Surface::new(front.iter().flat_map(|&j| triangles(&tiles[j])).collect());
        // The front tile that stands for each leaf.
        let owner = |leaf: usize| {
            let mut o = leaf;
            while !front.contains(&o) {
                o = tiles[o].parent.unwrap();
            }
            o
        };
        // Border points shared by leaves of two different front tiles: where two drawn tiles meet.
        let key = |p: DVec3| ((p.x * 1e3).round() as i64, (p.y * 1e3).round() as i64);
        let mut owners: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
        for (leaf, pts) in &leaf_borders {
            for &p in pts {
                let o = owners.entry(key(p)).or_default();
                if !o.contains(&owner(*leaf)) {
                    o.push(owner(*leaf));
                }
            }
        }
        let mut worst: f64 = 0.0;
        let mut checked = 0;
        for (leaf, pts) in &leaf_borders {
            let o = owner(*leaf);
            for &p in pts {
                if owners[&key(p)].len() < 2 {
                    continue;
                }
                checked += 1;
                let gap = drawn.distance(p);
                worst = worst.max(gap);
                // Stricter than the tile's error: the seam is closed exactly (f32 rounding).
                assert!(
                    gap <= 1e-3_f64.min(tiles[o].geometric_error + 1e-4),
                    "depth {depth}: a {gap} m gap at {p} where {:?} meets a neighbour (error {})",
                    tiles[o].name,
                    tiles[o].geometric_error,
                );
            }
        }
        assert!(checked > 0, "depth {depth}: no shared tile border found");
        eprintln!(
            "depth {depth}: {} tiles, {checked} points where tiles meet, largest gap {worst:.2e} m",
            front.len()
        );
    }
}

/// The paper's Δ(mesh) criterion as a geometricError, computed here from the formulas (1), (2)
/// written out: e = L · 16 px · sqrt(1920 / (2 · 1080 · 16)) (1920x1080, Δ = 16, 60°).
fn paper_error_by_hand(edge_m: f64) -> f64 {
    edge_m * 16.0 * (1920.0f64 / (2.0 * 1080.0 * 16.0)).sqrt()
}

/// The sample converted in `name` with 2000-triangle tiles, no compression and `extra` options.
fn sample_with(name: &str, extra: &[&str]) -> (std::path::PathBuf, serde_json::Value) {
    let out = tmpdir(name).join("tiles");
    let mut args = vec!["--max-tile-triangles", "2000", "--compression", "none"];
    args.extend_from_slice(extra);
    let report = convert(&sample(), &out, &args);
    (out, report)
}

#[test]
fn sample_paper_sse_metric_declares_the_papers_error_and_reports_both() {
    let (out, report) = sample_with("hlod-paper-sse", &["--error-metric", "paper-sse"]);
    assert_eq!(report["options"]["error_metric"], "paper-sse");
    assert!(report["geometric_error_metric"]
        .as_str()
        .unwrap()
        .starts_with("paper-sse"));
    check_tileset(
        &out,
        report["input"]["triangles"].as_u64().unwrap() as usize,
    );
    let (_, tiles) = decode_tileset(&out);
    let by_uri: HashMap<&str, &DecodedTile> = tiles
        .iter()
        .filter_map(|t| Some((t.name.as_deref()?, t)))
        .collect();
    let mut simplified = 0;
    for t in report["tiles"].as_array().unwrap() {
        let Some(edge) = t["max_folding_edge_m"].as_f64() else {
            assert_eq!(t["geometric_error_m"], 0.0, "full detail");
            continue;
        };
        simplified += 1;
        let declared = by_uri[t["content"].as_str().unwrap()].geometric_error;
        let paper = paper_error_by_hand(edge);
        assert!((t["paper_error_m"].as_f64().unwrap() - paper).abs() < 1e-9 * paper.max(1.0));
        // The paper's value, unless held above a child's (3D Tiles: errors decrease downwards).
        assert!(declared >= paper - 1e-9, "{declared} < {paper}");
        assert!(edge > 0.0, "an internal tile collapsed edges");
        // Both metrics are in the report: the measured one is the honest distance.
        assert!(t["measured_error_m"].as_f64().unwrap() > 0.0);
    }
    assert!(simplified > 0);
    // Table I: the HLOD rows switch where Δ(mesh) = 16 px (or later, when held by a child).
    let rows = report["lod_levels"].as_array().unwrap();
    assert_eq!(rows[0]["level"], "LOD0 (full detail)");
    assert_eq!(rows[0]["max_folding_edge_m"], 0.0);
    for r in &rows[1..] {
        let d = r["delta_mesh_px"].as_f64().unwrap();
        assert!(d <= 16.0 + 1e-6 && d > 0.0, "{r}");
        let range = r["range_of_visibility_m"].as_f64().unwrap();
        let ge = r["geometric_error_max_m"].as_f64().unwrap();
        // 3D Tiles SSE of the declared error at that range is 16 px.
        let sse = ge * 1080.0 / (2.0 * range * (30f64).to_radians().tan());
        assert!((sse - 16.0).abs() < 1e-6, "{sse}");
    }
    // inspect shows the same table, as JSON and for people.
    let o = run(&["inspect", out.to_str().unwrap(), "--json"]);
    assert!(o.status.success());
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(s["lod_levels"], report["lod_levels"]);
    let o = run(&["inspect", out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("Table I") && text.contains("HLOD depth 0"),
        "{text}"
    );
}

#[test]
fn measured_metric_reports_the_papers_delta_beside_it() {
    let (_, report) = sample_with("hlod-measured-table", &[]);
    let (mut simplified, mut held) = (0, 0);
    for t in report["tiles"].as_array().unwrap() {
        if let Some(m) = t["measured_error_m"].as_f64() {
            // The measured error is declared, unless held above a child's.
            let declared = t["geometric_error_m"].as_f64().unwrap();
            assert!(declared >= m, "{t}");
            simplified += 1;
            held += usize::from(declared > m);
            let edge = t["max_folding_edge_m"].as_f64().unwrap();
            let paper = paper_error_by_hand(edge);
            assert!((t["paper_error_m"].as_f64().unwrap() - paper).abs() < 1e-9 * paper.max(1.0));
        }
    }
    assert!(simplified > 0 && held < simplified);
    // Under the measured metric the real error on screen is 16 px where the level switches.
    for r in &report["lod_levels"].as_array().unwrap()[1..] {
        let px = r["measured_sse_px"].as_f64().unwrap();
        assert!(px <= 16.0 + 1e-6 && px > 1.0, "{r}");
    }
}

/// Discrete LOD chains: structure, triangle ratios and honest, tight errors.
fn check_chains(name: &str, out: &std::path::Path, report: &serde_json::Value, ratios: &[f64]) {
    let tiles = check_tileset(out, report["input"]["triangles"].as_u64().unwrap() as usize);
    assert_eq!(report["options"]["lod"], "ratios");
    let ch = children(&tiles);
    // Per level: triangles over the chains, and every chain tile's only child is the next level,
    // with the same bounds (up to where simplified vertices moved) and a smaller error.
    let mut per_level = vec![0usize; ratios.len() + 1];
    let rep: HashMap<&str, &serde_json::Value> = report["tiles"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|t| Some((t["content"].as_str()?, t)))
        .collect();
    for (i, t) in tiles.iter().enumerate() {
        let Some(name) = &t.name else {
            continue;
        };
        let k = rep[name.as_str()]["lod_level"].as_u64().unwrap() as usize;
        per_level[k] += t.triangles;
        if k > 0 {
            assert_eq!(ch[i].len(), 1, "{name}: a chain tile has one child");
            let c = &tiles[ch[i][0]];
            assert_eq!(rep[c.name.as_deref().unwrap()]["lod_level"], k as u64 - 1);
            assert!(c.geometric_error < t.geometric_error);
            assert!((c.box_min - t.box_min).abs().max_element() < 0.5);
        } else {
            assert!(ch[i].is_empty() && t.geometric_error == 0.0);
        }
    }
    for (k, r) in ratios.iter().enumerate() {
        let got = per_level[k + 1] as f64 / per_level[0] as f64;
        eprintln!(
            "{name}: LOD{} keeps {got:.3} of the triangles (ratio {r})",
            k + 1
        );
        assert!(
            (got - r).abs() < 0.05,
            "{name}: LOD{} has {got} of full, not {r}",
            k + 1
        );
    }
    let rows = report["lod_levels"].as_array().unwrap();
    assert_eq!(rows.len(), ratios.len() + 1);
    check_honest_and_tight(name, out, 0.0);
}

#[test]
fn sample_lod_chains_are_honest_and_keep_their_ratios() {
    let (out, report) = sample_with("chains-sample", &["--lod-ratios", "0.85,0.7,0.5"]);
    check_chains("sample", &out, &report, &[0.85, 0.7, 0.5]);
    if let Some((_, errors, _)) = gltf_validator(&out) {
        assert_eq!(errors, 0);
    }
    // Bad ratios are a one-line error, nothing written.
    let bad = tmpdir("chains-bad").join("tiles");
    let o = run(&[
        "convert",
        "--out",
        bad.to_str().unwrap(),
        "--lod-ratios",
        "0.5,1.5",
    ]);
    assert!(!o.status.success() && !bad.exists());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--lod-ratios"));
}

#[test]
fn shared_model_lod_chains_are_honest_and_keep_their_ratios() {
    let Some(model) = shared_file("AC20-FZK-Haus.glb") else {
        return;
    };
    let out = tmpdir("chains-fzk").join("tiles");
    let report = convert(
        &model,
        &out,
        &[
            "--max-tile-triangles",
            "5000",
            "--compression",
            "none",
            "--lod-ratios",
            "0.85,0.7,0.5",
        ],
    );
    check_chains("AC20-FZK-Haus", &out, &report, &[0.85, 0.7, 0.5]);
    if let Some((_, errors, _)) = gltf_validator(&out) {
        assert_eq!(errors, 0);
    }
}

#[test]
fn railway_root_is_within_the_budget() {
    // LoD3_Railway's many small closed parts stalled the simplifier above the budget (the root
    // kept 2,170 triangles for 2,000). At the root no part continues outside, so nothing is
    // locked and the budget holds. Below it, parts cut across tiles keep their borders locked (no
    // cracks), and tiles made mostly of such borders can still overshoot (r0: 2,453).
    let Some(model) = shared_file("LoD3_Railway.glb") else {
        return;
    };
    let out = tmpdir("hlod-railway-budget").join("tiles");
    let report = convert(&model, &out, &["--max-tile-triangles", "2000"]);
    let tiles = report["tiles"].as_array().unwrap();
    assert_eq!(tiles[0]["path"], "r");
    assert!(tiles[0]["simplified_from_triangles"].as_u64().unwrap() > 2000);
    assert!(
        tiles[0]["stored_triangles"].as_u64().unwrap() <= 2000,
        "{}",
        tiles[0]
    );
    for t in tiles {
        if t["simplified_from_triangles"].is_u64() && t["stored_triangles"].as_u64() > Some(2000) {
            eprintln!(
                "over budget (locked borders): {} {}",
                t["path"], t["stored_triangles"]
            );
        }
    }
}

/// The framed error of a bounding sphere of radius `r`, by hand: the error that a viewer whose
/// screen the sphere fills (1080 px, 60°, eye at 2r from the centre) sees as 16 px.
fn framed_error_by_hand(r: f64) -> f64 {
    16.0 * 2.0 * r * (30f64).to_radians().tan() / 1080.0
}

/// The ladder of levels (issue 28), from the tileset as written: every tile's geometricError is
/// strictly below its parent's and at most [`LADDER_CHILD_RATIO`] of it, no tile has content
/// that draws nothing, and (`within_framed`, default budgets) every internal tile's error is
/// within its framed error, so a viewer never needs a level before the tile is about a screen
/// across. Returns (tiles, depth, largest internal error / framed error).
fn check_ladder(name: &str, dir: &std::path::Path, within_framed: bool) -> (usize, u32, f64) {
    let (_, tiles) = decode_tileset(dir);
    let ch = children(&tiles);
    let mut worst_framed: f64 = 0.0;
    for (i, t) in tiles.iter().enumerate() {
        if let Some(content) = &t.name {
            assert!(t.triangles > 0, "{name}: {content} draws nothing");
        }
        if let Some(p) = t.parent {
            let parent = tiles[p].geometric_error;
            assert!(
                t.geometric_error < parent && t.geometric_error <= LADDER_CHILD_RATIO * parent,
                "{name}: tile {i} ({:?}) declares {} m under a parent of {parent} m",
                t.name,
                t.geometric_error
            );
        }
        if !ch[i].is_empty() {
            let r = (t.box_max - t.box_min).length() / 2.0;
            let f = t.geometric_error / framed_error_by_hand(r);
            worst_framed = worst_framed.max(f);
            if within_framed {
                assert!(
                    f <= 1.0,
                    "{name}: tile {i} ({:?}) declares {} m, {f:.2} x its framed error",
                    t.name,
                    t.geometric_error
                );
            }
        }
    }
    let depth = tiles.iter().map(|t| t.depth).max().unwrap_or(0);
    eprintln!(
        "{name}: {} tiles, depth {depth}, largest internal error {worst_framed:.2} x framed",
        tiles.len()
    );
    (tiles.len(), depth, worst_framed)
}

#[test]
fn wide_sparse_airport_gets_a_ladder_of_honest_levels() {
    let Some(model) = shared_file("phnl_honolulu_airport.glb") else {
        return;
    };
    let out = tmpdir("ladder-airport").join("tiles");
    let report = convert(&model, &out, &[]);
    check_tileset(
        &out,
        report["input"]["triangles"].as_u64().unwrap() as usize,
    );
    // 6.8 x 3.2 km: the budgets alone gave a root (255 m) over five kilometre-wide leaves (0 m).
    let (tiles, depth, _) = check_ladder("airport", &out, true);
    assert!(depth >= 4 && tiles > 50, "{tiles} tiles, depth {depth}");
    // No leaf spans more than the octree's extent rung (128 m) unless one triangle does.
    let (_, decoded) = decode_tileset(&out);
    let ch = children(&decoded);
    for (i, t) in decoded.iter().enumerate() {
        // Whole triangles: a leaf (in a cell of at most 128 m) may hold parts cut in its parent,
        // which reach across half of that cell and stick out of it by their largest triangle.
        let largest = triangles(t)
            .iter()
            .map(|[a, b, c]| (a.max(*b).max(*c) - a.min(*b).min(*c)).max_element())
            .fold(0.0, f64::max);
        if ch[i].is_empty() {
            let span = (t.box_max - t.box_min).max_element();
            assert!(
                span <= 2.0 * 128.0 + 2.0 * largest + 1.0,
                "{:?} spans {span} m (largest triangle {largest} m)",
                t.name
            );
        }
    }
    check_honest_and_tight("airport", &out, LEAF_GRID_M);
    // The root quantizes on a share of its error, far coarser than full detail's 1 mm, and the
    // honesty above holds with that grid.
    let root_grid_m = report["tiles"][0]["max_position_error_m"].as_f64().unwrap();
    assert!(root_grid_m > 0.05, "root grid {root_grid_m} m");
    // At 1,000 triangles a tile one tile used to be written with nothing to draw.
    let small = tmpdir("ladder-airport-1k").join("tiles");
    convert(&model, &small, &["--max-tile-triangles", "1000"]);
    check_ladder("airport at 1000", &small, false);
}

#[test]
fn railway_and_mini_keep_a_ladder_of_honest_levels() {
    if let Some(model) = shared_file("LoD3_Railway.glb") {
        // The tile that declared 0.0428 m for a 0.0487 m deviation (edges of full detail).
        let out = tmpdir("ladder-railway-1k").join("tiles");
        convert(&model, &out, &["--max-tile-triangles", "1000"]);
        check_ladder("LoD3_Railway at 1000", &out, false);
        check_honest_and_tight("LoD3_Railway at 1000", &out, LEAF_GRID_M);
    }
    if let Some(model) = shared_file("ISSUE_021_Mini_Project.glb") {
        let out = tmpdir("ladder-mini").join("tiles");
        convert(&model, &out, &[]);
        check_ladder("ISSUE_021_Mini_Project", &out, true);
        check_honest_and_tight("ISSUE_021_Mini_Project", &out, LEAF_GRID_M);
    }
}

/// What a client fetches for the tile report.json names `name` (its GLB and the texture files it
/// references), and the texels of its images.
fn fetched_and_texels(dir: &std::path::Path, name: &str) -> (u64, u64) {
    let uri = content_uri(dir, name);
    let fetched_glb = content_bytes(dir, &uri);
    let glb = plain_glb(fetched_glb.clone());
    let g = gltf::Gltf::from_slice_without_validation(&glb).unwrap();
    let blob = g.blob.as_deref().unwrap_or_default();
    let mut fetched = fetched_glb.len() as u64;
    let mut texels = 0;
    for image in g.images() {
        let bytes = image_bytes(dir, &uri, blob, &image);
        if let gltf::image::Source::Uri { .. } = image.source() {
            fetched += bytes.len() as u64;
        }
        let im = image::load_from_memory(&bytes).expect("the image decodes");
        texels += im.width() as u64 * im.height() as u64;
    }
    (fetched, texels)
}

/// Every tile of the default (meshopt) tileset in `dir` is honest: the full detail below it lies
/// within its declared error, up to the leaves' quantization grid.
fn assert_within_declared_errors(dir: &std::path::Path) {
    for (i, measured, declared, ..) in measure_hlod(dir) {
        assert!(
            measured <= declared * 1.0001 + 2e-5 + LEAF_GRID_M,
            "tile {i}: {measured} m > declared {declared} m"
        );
    }
}

#[test]
fn compact_textured_model_gets_a_coarse_root_with_coarser_textures() {
    // LoD3_Railway is one tile by the budgets: its first view was every texel at full detail.
    let Some(model) = shared_file("LoD3_Railway.glb") else {
        return;
    };
    let out = tmpdir("coarse-root-railway").join("tiles");
    let report = convert(&model, &out, &[]);
    check_tileset(
        &out,
        report["input"]["triangles"].as_u64().unwrap() as usize,
    );
    let tiles = report["tiles"].as_array().unwrap();
    let paths: Vec<&str> = tiles.iter().map(|t| t["path"].as_str().unwrap()).collect();
    assert_eq!(paths, ["r-lod1", "r"]);
    assert_eq!(report["output"]["tiles"], 2);
    assert_eq!(report["output"]["max_depth"], 1);
    // A rung below the framed error, over full detail.
    check_ladder("LoD3_Railway", &out, true);
    // Honest: the full detail lies within the root's error. (Not tight: the root declares the
    // error its texture levels are chosen for, above its geometry's.)
    assert_within_declared_errors(&out);
    let (root_fetched, root_texels) = fetched_and_texels(&out, "tiles/r-lod1.glb");
    let (leaf_fetched, leaf_texels) = fetched_and_texels(&out, "tiles/r.glb");
    eprintln!(
        "LoD3_Railway: first view {root_fetched} B, {root_texels} texels; full detail {leaf_fetched} B, {leaf_texels} texels"
    );
    assert!(
        leaf_fetched >= root_fetched + bimtiles::transfer::SEQUENTIAL_REQUEST_WORTH_BYTES as u64,
        "{root_fetched} vs {leaf_fetched}"
    );
    assert!(
        16 * root_texels <= leaf_texels,
        "{root_texels} vs {leaf_texels}"
    );
    gltf_validator(&out);
    if let Some(views) = decode_meshopt(&out, &tmpdir("coarse-root-railway-decoded")) {
        assert!(views > 0);
    }

    // Asked not to, or too light to pay for the request: one tile as before.
    let one = convert(
        &model,
        &tmpdir("coarse-root-railway-off").join("tiles"),
        &["--no-coarse-root"],
    );
    assert_eq!(one["output"]["tiles"], 1);
    let sample_out = tmpdir("coarse-root-sample").join("tiles");
    assert_eq!(convert(&sample(), &sample_out, &[])["output"]["tiles"], 1);
}

#[test]
fn ifc_building_gets_a_simplified_coarse_root_inlined_in_the_tileset() {
    // The IFC duplex is one tile by the budgets, most of its bytes property sets. Its first
    // coarser try is far off while half of its triangles are close: finer tries that jumped to
    // every triangle left it no coarse root.
    let Some(model) = shared_file("duplex.ifc") else {
        return;
    };
    let out = tmpdir("coarse-root-duplex-ifc").join("tiles");
    let report = convert(&model, &out, &[]);
    let full_triangles = report["input"]["triangles"].as_u64().unwrap() as usize;
    check_tileset(&out, full_triangles);
    let tiles = report["tiles"].as_array().unwrap();
    let paths: Vec<&str> = tiles.iter().map(|t| t["path"].as_str().unwrap()).collect();
    assert_eq!(paths, ["r-lod1", "r"]);
    let (root, leaf) = (&tiles[0], &tiles[1]);
    let root_triangles = root["triangles"].as_u64().unwrap();
    let leaf_triangles = leaf["triangles"].as_u64().unwrap();
    assert!(
        root_triangles * 10 <= leaf_triangles * 6,
        "the root is simplified: {root_triangles} of {leaf_triangles} triangles"
    );
    // The first view is the root alone, one request: it is in tileset.json.
    assert_eq!(root["inlined_in_tileset"], true);
    let root_uri = &content_uri(&out, root["content"].as_str().unwrap());
    assert!(
        root_uri.starts_with("data:"),
        "{}",
        &root_uri[..40.min(root_uri.len())]
    );
    // Its elements stay clickable by name and class; property sets come with full detail.
    let root_glb = glb_json(&content_bytes(&out, root_uri));
    let leaf_glb = glb_json(&content_bytes(&out, &content_uri(&out, "tiles/r.glb")));
    let columns = |doc: &serde_json::Value| -> Vec<String> {
        let table = &doc["extensions"]["EXT_structural_metadata"]["propertyTables"][0];
        table["properties"]
            .as_object()
            .unwrap()
            .keys()
            .cloned()
            .collect()
    };
    let (root_columns, leaf_columns) = (columns(&root_glb), columns(&leaf_glb));
    for name in ["id", "name", "class"] {
        assert!(
            root_columns.iter().any(|c| c == name),
            "{name} in {root_columns:?}"
        );
    }
    assert!(
        root_columns.len() * 10 < leaf_columns.len(),
        "{} root columns, {} full-detail",
        root_columns.len(),
        leaf_columns.len()
    );
    // Honest: the full detail lies within the root's declared error.
    assert_within_declared_errors(&out);
    gltf_validator(&out);
}
