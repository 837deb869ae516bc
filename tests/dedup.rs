//! Dedup on real inputs: the bundled sample (every baked copy and exact duplicate listed in its
//! expect.json must be found, nothing else) and every model of the shared data folder
//! (`$BIMTILES_SHARED/data`, else `../shared/data` beside the crate; skipped with a message when
//! absent, a failure under `BIMTILES_REQUIRE_TOOLS`). After dedup, every component is expanded back to world geometry and compared with
//! the input, and identities are counted. Run with `-- --nocapture` to see the per-model table.

use bimtiles::dedup::{deduplicate, shape_groups, DedupOptions, DedupReport};
use bimtiles::ingest::read_input;
use bimtiles::scene::{Component, ComponentId, ElementInfo, Scene};
use glam::{DMat3, DVec3};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

const TOL: f64 = 0.001;

/// One drawn corner: position, unit normal, UV.
type Corner = (DVec3, Option<DVec3>, Option<[f32; 2]>);

/// A component's drawn triangles per primitive in the scene frame (winding in drawn order:
/// flipped when the world mirrors), with each primitive's material.
fn expand(scene: &Scene, c: &Component) -> Vec<(Option<u32>, Vec<[Corner; 3]>)> {
    let l = DMat3::from_mat4(c.world);
    let nm = l.inverse().transpose();
    let flip = l.determinant() < 0.0;
    scene
        .mesh(c.mesh)
        .primitives
        .iter()
        .map(|p| {
            let corner = |i: usize| -> Corner {
                (
                    c.world
                        .transform_point3(DVec3::from_array(p.positions[i].map(f64::from))),
                    p.normals
                        .as_ref()
                        .map(|n| (nm * DVec3::from_array(n[i].map(f64::from))).normalize_or_zero()),
                    p.uvs.as_ref().map(|u| u[i]),
                )
            };
            let tris = p
                .indices
                .chunks_exact(3)
                .map(|t| {
                    let (a, b, c) = (t[0] as usize, t[1] as usize, t[2] as usize);
                    if flip {
                        [corner(a), corner(c), corner(b)]
                    } else {
                        [corner(a), corner(b), corner(c)]
                    }
                })
                .collect();
            (p.material.map(|m| m.0), tris)
        })
        .collect()
}

fn corner_eq(x: &Corner, y: &Corner, tol: f64) -> bool {
    x.0.distance(y.0) <= tol
        && match (x.1, y.1) {
            // 2° (the default normal tolerance), and zero normals only with zero normals.
            (Some(m), Some(n)) => (m == n) || m.dot(n) >= 2f64.to_radians().cos() - 1e-12,
            (None, None) => true,
            _ => false,
        }
        && match (x.2, y.2) {
            (Some(m), Some(n)) => (0..2).all(|i| (m[i] - n[i]).abs() <= 1e-4 * m[i].abs().max(1.0)),
            (None, None) => true,
            _ => false,
        }
}

/// Whether `a` (a component after dedup) draws what `b` (the input component) drew: same
/// materials (by value) per primitive, and the same oriented triangles corner by corner within
/// `tol`. Vertex by vertex in index order when the triangle lists line up; otherwise each
/// triangle must find its own distinct partner (through a grid of centroids).
fn same_geometry(
    sa: &Scene,
    a: &Component,
    sb: &Scene,
    b: &Component,
    tol: f64,
) -> Result<(), String> {
    let (ea, eb) = (expand(sa, a), expand(sb, b));
    if ea.len() != eb.len() {
        return Err(format!("{} primitives instead of {}", ea.len(), eb.len()));
    }
    for (k, ((ma, ta), (mb, tb))) in ea.iter().zip(&eb).enumerate() {
        let mat = |s: &Scene, m: &Option<u32>| m.map(|m| s.materials[m as usize].clone());
        if mat(sa, ma) != mat(sb, mb) {
            return Err(format!("primitive {k}: other material"));
        }
        if ta.len() != tb.len() {
            return Err(format!(
                "primitive {k}: {} triangles instead of {}",
                ta.len(),
                tb.len()
            ));
        }
        // Same order: corner i against corner i.
        if ta
            .iter()
            .zip(tb)
            .all(|(x, y)| (0..3).all(|i| corner_eq(&x[i], &y[i], tol)))
        {
            continue;
        }
        let cell = 4.0 * tol;
        let key = |t: &[Corner; 3]| {
            let c = (t[0].0 + t[1].0 + t[2].0) / 3.0;
            [
                (c.x / cell).floor() as i64,
                (c.y / cell).floor() as i64,
                (c.z / cell).floor() as i64,
            ]
        };
        let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
        for (i, t) in tb.iter().enumerate() {
            grid.entry(key(t)).or_default().push(i);
        }
        // Candidates of each output triangle, then a perfect matching (greedy, then augmenting
        // paths): slivers can make one triangle fit several.
        let mut cands: Vec<Vec<usize>> = Vec::with_capacity(ta.len());
        for t in ta {
            let q = key(t);
            let mut list = Vec::new();
            for d in 0..27i64 {
                let n = [q[0] + d % 3 - 1, q[1] + (d / 3) % 3 - 1, q[2] + d / 9 - 1];
                for &j in grid.get(&n).into_iter().flatten() {
                    if (0..3).any(|r| (0..3).all(|i| corner_eq(&t[i], &tb[j][(i + r) % 3], tol))) {
                        list.push(j);
                    }
                }
            }
            if list.is_empty() {
                return Err(format!(
                    "primitive {k}: triangle at {:?} not in the input",
                    t.map(|c| c.0)
                ));
            }
            cands.push(list);
        }
        let mut owner: Vec<Option<usize>> = vec![None; tb.len()];
        fn augment(
            l: usize,
            cands: &[Vec<usize>],
            owner: &mut [Option<usize>],
            seen: &mut [bool],
        ) -> bool {
            for &r in &cands[l] {
                if !seen[r] {
                    seen[r] = true;
                    let free = match owner[r] {
                        None => true,
                        Some(o) => augment(o, cands, owner, seen),
                    };
                    if free {
                        owner[r] = Some(l);
                        return true;
                    }
                }
            }
            false
        }
        for l in 0..ta.len() {
            if let Some(&r) = cands[l].iter().find(|&&r| owner[r].is_none()) {
                owner[r] = Some(l);
                continue;
            }
            if !augment(l, &cands, &mut owner, &mut vec![false; tb.len()]) {
                return Err(format!(
                    "primitive {k}: triangles do not pair up one to one"
                ));
            }
        }
    }
    Ok(())
}

/// Every component keeps its id, key, node and info; none lost or duplicated; every drawn
/// component expands to its input geometry within the tolerance; every alias points at a drawn
/// component whose geometry is its own within the tolerance (checked against the input of both).
fn assert_correct(name: &str, before: &Scene, after: &Scene) {
    assert_eq!(
        before.components.len(),
        after.components.len(),
        "{name}: component count"
    );
    let infos_b: Vec<ElementInfo> = before.elements.iter().collect();
    let infos_a: Vec<ElementInfo> = after.elements.iter().collect();
    assert!(infos_b == infos_a, "{name}: element info");
    let keys_b: BTreeMap<&str, usize> = count_keys(&infos_b);
    let keys_a: BTreeMap<&str, usize> = count_keys(&infos_a);
    assert_eq!(keys_b, keys_a, "{name}: identities");
    let key = |c: &Component| infos_a[c.id.index()].key.as_str();
    let failures: Vec<String> = after
        .components
        .iter()
        .zip(&before.components)
        .filter_map(|(a, b)| {
            assert_eq!((a.id, a.node), (b.id, b.node));
            if let Some(kept) = a.alias_of {
                let k = &after.components[kept.index()];
                if k.alias_of.is_some() {
                    return Some(format!("{}: alias of an alias", key(a)));
                }
                // The alias is drawn by `kept` as `kept` was in the input.
                let kb = &before.components[kept.index()];
                if let Err(e) = same_geometry(before, kb, before, b, TOL) {
                    return Some(format!("{} alias of {}: {e}", key(a), key(k)));
                }
            }
            same_geometry(after, a, before, b, TOL)
                .err()
                .map(|e| format!("{} ({}): {e}", key(a), a.id.0))
        })
        .collect();
    assert!(
        failures.is_empty(),
        "{name}: {} components differ from the input, first: {:?}",
        failures.len(),
        &failures[..failures.len().min(5)]
    );
    // Every mesh a component uses still holds its geometry (released meshes are unreferenced).
    for c in &after.components {
        let m = after.mesh(c.mesh);
        assert_eq!(
            m.triangle_count(),
            before
                .meshes
                .triangle_count(before.components[c.id.index()].mesh)
        );
    }
}

fn count_keys(infos: &[ElementInfo]) -> BTreeMap<&str, usize> {
    let mut m = BTreeMap::new();
    for i in infos {
        *m.entry(i.key.as_str()).or_insert(0) += 1;
    }
    m
}

fn by_key(s: &Scene, key: &str) -> ComponentId {
    let hits: Vec<usize> = (s.elements.iter().enumerate())
        .filter(|(_, e)| e.key == key)
        .map(|(i, _)| i)
        .collect();
    assert_eq!(hits.len(), 1, "component {key}");
    s.components[hits[0]].id
}

#[test]
fn sample_building_every_baked_copy_and_duplicate() {
    let path = crate::common::sample();
    let expect: Value = serde_json::from_str(
        &std::fs::read_to_string(crate::common::repo().join("samples/sample_building.expect.json"))
            .unwrap(),
    )
    .unwrap();
    let before = read_input(&path).unwrap();
    let mut after = before.clone();
    let r = deduplicate(&mut after, &DedupOptions::default());
    eprintln!("{}", serde_json::to_string_pretty(&r).unwrap());
    assert_correct("sample", &before, &after);

    // Exact duplicates: exactly the listed pairs.
    let pairs = expect["exact_duplicate_pairs"].as_array().unwrap();
    let mut want: BTreeSet<(ComponentId, ComponentId)> = BTreeSet::new();
    for p in pairs {
        want.insert((
            by_key(&after, p["duplicate"].as_str().unwrap()),
            by_key(&after, p["kept"].as_str().unwrap()),
        ));
    }
    let got: BTreeSet<(ComponentId, ComponentId)> = after
        .components
        .iter()
        .filter_map(|c| c.alias_of.map(|k| (c.id, k)))
        .collect();
    assert_eq!(got, want);
    assert_eq!(
        r.redundant_removed,
        expect["exact_duplicates"].as_u64().unwrap() as usize
    );

    // Every rigid copy group ends on one mesh, each group on its own.
    let mut group_mesh = BTreeSet::new();
    for g in expect["rigid_copy_groups"].as_array().unwrap() {
        let meshes: BTreeSet<u32> = g["guids"]
            .as_array()
            .unwrap()
            .iter()
            .map(|k| {
                after.components[by_key(&after, k.as_str().unwrap()).index()]
                    .mesh
                    .0
            })
            .collect();
        assert_eq!(
            meshes.len(),
            1,
            "group {} split over {meshes:?}",
            g["shape"]
        );
        assert!(
            group_mesh.insert(*meshes.first().unwrap()),
            "two groups share a mesh"
        );
    }
    assert_eq!(
        r.congruent_rewritten,
        expect["baked_copies"].as_u64().unwrap() as usize
    );
    assert_eq!(
        r.unique_shapes,
        expect["unique_shapes_incl_instanced"].as_u64().unwrap() as usize
    );
    // glTF-level instances stay instanced: one group per instanced mesh, of the listed size.
    let mut sizes: Vec<usize> = shape_groups(&after)
        .iter()
        .filter(|g| !group_mesh.contains(&g.mesh.0) && g.components.len() > 1)
        .map(|g| g.components.len())
        .collect();
    sizes.sort_unstable();
    let mut want_sizes: Vec<usize> = expect["gltf_instanced_meshes"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    want_sizes.sort_unstable();
    assert_eq!(sizes, want_sizes);
    let copies: usize = expect["rigid_copy_groups"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g["count"].as_u64().unwrap() as usize)
        .sum();
    assert_eq!(
        r.instanced_components,
        copies + want_sizes.iter().sum::<usize>()
    );
    assert_eq!(
        r.components,
        expect["components"].as_u64().unwrap() as usize
    );
    assert_eq!(
        r.triangles_before,
        expect["triangles"].as_u64().unwrap() as usize
    );
    assert!(r.bytes_after < r.bytes_before);
}

fn row(name: &str, r: &DedupReport, read_s: f64) -> String {
    format!(
        "| {name} | {} | {} | {} | {} | {} | {} ({} / {}) | {:.1} % | {} | {} | {:.3} | {:.2} |",
        r.components,
        r.unique_shapes_before,
        r.unique_shapes,
        r.instanced_components,
        r.redundant_removed,
        r.congruent_rewritten,
        r.matched_same_order,
        r.matched_by_search,
        100.0 * (1.0 - r.bytes_after as f64 / r.bytes_before.max(1) as f64),
        r.bytes_before,
        r.bytes_after,
        r.seconds,
        read_s,
    )
}

#[test]
fn shared_models_table_and_correctness() {
    let Some(files) = crate::common::shared_files(&["glb", "ifc"]) else {
        return;
    };
    assert!(!files.is_empty(), "no .glb/.ifc in the shared data");
    let mut table = vec![
        "| model | components | shapes before | shapes after | instanced | removed (exact) | rewritten (congruent: same order / search) | bytes saved | bytes before | bytes after | dedup s | read s |".to_string(),
        "|---|---|---|---|---|---|---|---|---|---|---|---|".to_string(),
    ];
    for f in &files {
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        let t = std::time::Instant::now();
        let before = match read_input(Path::new(f)) {
            Ok(s) => s,
            Err(e) => {
                // Readers have their own tests; a model this build cannot read is reported.
                eprintln!("{name}: not read ({e})");
                table.push(format!("| {name} | not read: {e} |"));
                continue;
            }
        };
        let read_s = t.elapsed().as_secs_f64();
        let mut after = before.clone();
        let r = deduplicate(&mut after, &DedupOptions::default());
        assert_correct(&name, &before, &after);
        assert!(r.bytes_after <= r.bytes_before, "{name}");
        assert!(r.triangles_after <= r.triangles_before, "{name}");
        table.push(row(&name, &r, read_s));
        eprintln!("{}", table.last().unwrap());
    }
    println!("\n{}\n", table.join("\n"));
}
