//! Adaptive loose octree over components (paper IV.A: octree spatial subdivision).
//!
//! A cell splits while its content is over the triangle or byte budget. A component goes to the
//! child octant that holds its bounding-box centre, but only if it is no larger than that child
//! cell (a loose octree with looseness 2: the child's loose bounds, twice its size, then contain
//! it). Larger components stay in the cell where they fit, so big slabs and walls sit high in the
//! tree and small windows low. Empty cells make no tile, and a tile with no content of its own and a
//! single child is replaced by that child.
//!
//! The plan is computed from bounds and counts only, and is a pure function of the scene and the
//! options (input order, no hashing, no threads): the output is the same on every run.

use crate::scene::{Aabb, ComponentId, Scene};
use glam::DVec3;

#[derive(Debug, Clone)]
pub struct OctreeOptions {
    /// A cell whose content has more triangles than this is split.
    pub max_tile_triangles: usize,
    /// A cell whose content's estimated uncompressed size is over this is split.
    pub max_tile_bytes: usize,
    /// No split below this depth (a safety net for coincident components).
    pub max_depth: u32,
}

impl Default for OctreeOptions {
    fn default() -> Self {
        OctreeOptions {
            max_tile_triangles: 40_000,
            max_tile_bytes: 4 << 20,
            max_depth: 16,
        }
    }
}

/// One tile of the plan.
#[derive(Debug, Clone)]
pub struct PlannedTile {
    /// "r" then one octant digit per level: a stable, readable name for files.
    pub path: String,
    pub depth: u32,
    /// The octree cell (cubic); not a bounding volume.
    pub cell: Aabb,
    /// Components drawn by this tile, in id order.
    pub content: Vec<ComponentId>,
    /// Indices into [`TilePlan::tiles`].
    pub children: Vec<usize>,
    /// Box of this tile's own content (empty if none).
    pub content_bounds: Aabb,
    /// Box of the content of this tile and all its descendants.
    pub bounds: Aabb,
    pub content_triangles: usize,
    /// The largest diagonal among the components of the strict descendants: what is missing from the
    /// view when this tile is drawn and its children are not (additive refinement).
    pub omitted_size_m: f64,
}

/// The partition: tiles in pre-order, `tiles[0]` the root.
#[derive(Debug, Clone, Default)]
pub struct TilePlan {
    pub tiles: Vec<PlannedTile>,
}

impl TilePlan {
    pub fn max_depth(&self) -> u32 {
        self.tiles.iter().map(|t| t.depth).max().unwrap_or(0)
    }
}

struct Item {
    id: ComponentId,
    center: DVec3,
    extent: f64,
    triangles: usize,
    bytes: usize,
    diagonal: f64,
    bounds: Aabb,
}

/// Plans the octree for every component of `scene` that has geometry.
pub fn plan_octree(scene: &Scene, opts: &OctreeOptions) -> TilePlan {
    let items: Vec<Item> = scene
        .components
        .iter()
        .filter(|c| !c.world_bounds.is_empty())
        .map(|c| {
            let mesh = scene.mesh(c.mesh);
            let s = c.world_bounds.size();
            Item {
                id: c.id,
                center: c.world_bounds.center(),
                extent: s.max_element(),
                triangles: mesh.triangle_count(),
                bytes: mesh.estimated_bytes(),
                diagonal: s.length(),
                bounds: c.world_bounds,
            }
        })
        .collect();
    let mut plan = TilePlan::default();
    if items.is_empty() {
        return plan;
    }
    let all = items.iter().fold(Aabb::EMPTY, |b, i| b.union(&i.bounds));
    let half = all.size().max_element().max(1e-6) * 0.5;
    let root_cell = Aabb {
        min: all.center() - DVec3::splat(half),
        max: all.center() + DVec3::splat(half),
    };
    let refs: Vec<&Item> = items.iter().collect();
    if let Some(root) = build(root_cell, refs, 0, "r".into(), opts) {
        flatten(root, &mut plan.tiles);
    }
    plan
}

struct Node {
    path: String,
    depth: u32,
    cell: Aabb,
    content: Vec<ComponentId>,
    content_bounds: Aabb,
    content_triangles: usize,
    content_max_diag: f64,
    children: Vec<Node>,
}

fn build(
    cell: Aabb,
    items: Vec<&Item>,
    depth: u32,
    path: String,
    opts: &OctreeOptions,
) -> Option<Node> {
    if items.is_empty() {
        return None;
    }
    let tris: usize = items.iter().map(|i| i.triangles).sum();
    let bytes: usize = items.iter().map(|i| i.bytes).sum();
    let side = cell.size().x;
    let fits_budget = tris <= opts.max_tile_triangles && bytes <= opts.max_tile_bytes;
    let (mut stay, mut down): (Vec<&Item>, Vec<&Item>) = if fits_budget || depth >= opts.max_depth {
        (items, Vec::new())
    } else {
        items.into_iter().partition(|i| i.extent > side * 0.5)
    };
    let mut children = Vec::new();
    if !down.is_empty() {
        let c = cell.center();
        let mut octants: [Vec<&Item>; 8] = Default::default();
        for it in down.drain(..) {
            let o = (it.center.x >= c.x) as usize
                | ((it.center.y >= c.y) as usize) << 1
                | ((it.center.z >= c.z) as usize) << 2;
            octants[o].push(it);
        }
        for (o, group) in octants.into_iter().enumerate() {
            let min = DVec3::new(
                if o & 1 == 0 { cell.min.x } else { c.x },
                if o & 2 == 0 { cell.min.y } else { c.y },
                if o & 4 == 0 { cell.min.z } else { c.z },
            );
            let child_cell = Aabb {
                min,
                max: min + DVec3::splat(side * 0.5),
            };
            if let Some(n) = build(child_cell, group, depth + 1, format!("{path}{o}"), opts) {
                children.push(n);
            }
        }
    }
    stay.sort_by_key(|i| i.id);
    if stay.is_empty() && children.len() == 1 {
        // An empty tile with one child adds a request and nothing else.
        let mut only = children.pop().expect("one child");
        lift(&mut only, depth);
        return Some(only);
    }
    Some(Node {
        path,
        depth,
        cell,
        content_bounds: stay.iter().fold(Aabb::EMPTY, |b, i| b.union(&i.bounds)),
        content_triangles: stay.iter().map(|i| i.triangles).sum(),
        content_max_diag: stay.iter().map(|i| i.diagonal).fold(0.0, f64::max),
        content: stay.into_iter().map(|i| i.id).collect(),
        children,
    })
}

/// Moves a subtree up so that its root sits at `depth`.
fn lift(n: &mut Node, depth: u32) {
    n.depth = depth;
    for c in &mut n.children {
        lift(c, depth + 1);
    }
}

/// Writes the subtree in pre-order; returns (bounds, largest content diagonal in the subtree).
fn flatten(n: Node, out: &mut Vec<PlannedTile>) -> (Aabb, f64) {
    let me = out.len();
    out.push(PlannedTile {
        path: n.path,
        depth: n.depth,
        cell: n.cell,
        content: n.content,
        children: Vec::new(),
        content_bounds: n.content_bounds,
        bounds: n.content_bounds,
        content_triangles: n.content_triangles,
        omitted_size_m: 0.0,
    });
    let mut bounds = n.content_bounds;
    let mut below = 0.0f64;
    for c in n.children {
        let idx = out.len();
        let (b, d) = flatten(c, out);
        bounds = bounds.union(&b);
        below = below.max(d);
        out[me].children.push(idx);
    }
    out[me].bounds = bounds;
    out[me].omitted_size_m = below;
    (bounds, below.max(n.content_max_diag))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::*;
    use glam::DMat4;

    /// A scene of unit-ish boxes (12 triangles each) at the given centres and sizes.
    fn boxes(specs: &[(DVec3, f64)]) -> Scene {
        let mut s = Scene::default();
        for (i, &(c, size)) in specs.iter().enumerate() {
            let h = (size * 0.5) as f32;
            let mut positions = Vec::new();
            for k in 0..8 {
                positions.push([
                    if k & 1 == 0 { -h } else { h },
                    if k & 2 == 0 { -h } else { h },
                    if k & 4 == 0 { -h } else { h },
                ]);
            }
            let indices = vec![
                0, 1, 3, 0, 3, 2, 4, 6, 7, 4, 7, 5, 0, 4, 5, 0, 5, 1, 2, 3, 7, 2, 7, 6, 0, 2, 6, 0,
                6, 4, 1, 5, 7, 1, 7, 3,
            ];
            s.meshes.push(Mesh {
                name: None,
                primitives: vec![Primitive {
                    positions,
                    indices,
                    ..Default::default()
                }],
                local_bounds: None,
            });
            s.components.push(Component {
                id: ComponentId(i as u32),
                key: format!("c{i}"),
                name: None,
                node: None,
                mesh: MeshId(i as u32),
                world: DMat4::from_translation(c),
                world_bounds: Aabb::EMPTY,
                source: 0,
            });
        }
        s.finish();
        s
    }

    fn check_invariants(scene: &Scene, plan: &TilePlan, opts: &OctreeOptions) {
        // Every component exactly once.
        let mut seen = vec![0; scene.components.len()];
        for t in &plan.tiles {
            for c in &t.content {
                seen[c.index()] += 1;
            }
            for &ch in &t.children {
                let child = &plan.tiles[ch];
                assert!(
                    t.bounds.contains_box(&child.bounds, 0.0),
                    "child box inside parent"
                );
                assert_eq!(child.depth, t.depth + 1);
                assert!(child.omitted_size_m <= t.omitted_size_m);
            }
            assert!(t.bounds.contains_box(&t.content_bounds, 0.0));
            if t.children.is_empty() {
                assert_eq!(t.omitted_size_m, 0.0);
                assert!(!t.content.is_empty(), "no empty leaves");
                // Over budget only where nothing could go lower: every component is larger than
                // a child cell (splitting meshes is another stage's job), or the depth cap.
                let all_too_big = t.content.iter().all(|c| {
                    scene.component(*c).world_bounds.size().max_element() > t.cell.size().x * 0.5
                });
                assert!(
                    t.content_triangles <= opts.max_tile_triangles
                        || all_too_big
                        || t.depth == opts.max_depth
                );
            }
        }
        assert!(seen.iter().all(|&n| n == 1));
    }

    #[test]
    fn small_scene_is_one_tile() {
        let s = boxes(&[(DVec3::ZERO, 1.0), (DVec3::X * 3.0, 1.0)]);
        let plan = plan_octree(&s, &OctreeOptions::default());
        assert_eq!(plan.tiles.len(), 1);
        assert_eq!(plan.tiles[0].content.len(), 2);
        assert_eq!(plan.tiles[0].omitted_size_m, 0.0);
    }

    #[test]
    fn splits_over_budget_and_keeps_large_components_high() {
        // A 100 m slab plus a 10x10 grid of 1 m boxes; budget of 10 boxes (120 triangles).
        let mut specs = vec![(DVec3::new(50.0, 50.0, 0.0), 100.0)];
        for i in 0..10 {
            for j in 0..10 {
                specs.push((
                    DVec3::new(5.0 + i as f64 * 10.0, 5.0 + j as f64 * 10.0, 1.0),
                    1.0,
                ));
            }
        }
        let s = boxes(&specs);
        let opts = OctreeOptions {
            max_tile_triangles: 120,
            ..Default::default()
        };
        let plan = plan_octree(&s, &opts);
        assert!(plan.tiles.len() > 8);
        // The slab stays at the root.
        assert!(plan.tiles[0].content.contains(&ComponentId(0)));
        assert!(plan.tiles[0].omitted_size_m >= 3f64.sqrt() - 1e-9);
        check_invariants(&s, &plan, &opts);
        // Pure function of the input.
        let again = plan_octree(&s, &opts);
        let names = |p: &TilePlan| {
            p.tiles
                .iter()
                .map(|t| (t.path.clone(), t.content.clone()))
                .collect::<Vec<_>>()
        };
        assert_eq!(names(&plan), names(&again));
    }

    #[test]
    fn coincident_components_terminate() {
        let specs: Vec<_> = (0..50).map(|_| (DVec3::splat(1.0), 0.5)).collect();
        let s = boxes(&specs);
        let opts = OctreeOptions {
            max_tile_triangles: 12,
            max_depth: 6,
            ..Default::default()
        };
        let plan = plan_octree(&s, &opts);
        check_invariants(&s, &plan, &opts);
    }

    #[test]
    fn no_tile_without_content_and_single_child() {
        let specs: Vec<_> = (0..40)
            .map(|i| (DVec3::new(i as f64 * 0.1, 0.0, 0.0), 0.05))
            .collect();
        let s = boxes(&specs);
        let opts = OctreeOptions {
            max_tile_triangles: 60,
            ..Default::default()
        };
        let plan = plan_octree(&s, &opts);
        for t in &plan.tiles {
            assert!(
                !(t.content.is_empty() && t.children.len() == 1),
                "{}",
                t.path
            );
        }
        check_invariants(&s, &plan, &opts);
    }
}
