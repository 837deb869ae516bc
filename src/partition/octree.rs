//! Adaptive loose octree over components (paper IV.A: octree spatial subdivision).
//!
//! A cell splits while its content is over the triangle or byte budget. A component goes to the
//! child octant that holds its bounding-box centre, but only if it is no larger than that child
//! cell (a loose octree with looseness 2: the child's loose bounds, twice its size, then contain
//! it). Larger components stay in the cell where they fit, so big slabs and walls sit high in the
//! tree and small windows low. Empty cells make no tile, and a tile with no content of its own and a
//! single child is replaced by that child.
//!
//! Cutting big meshes: when what stays in an over-budget cell is itself over the budget (one
//! merged-by-material mesh, a city in one node, a scanned surface), the largest of those meshes are
//! cut, largest first, until the rest fits: their triangles go to the child octants by centroid
//! (whole triangles, no clipping), as parts that keep their component's identity and descend like
//! components, to be cut again if needed. So no content exceeds the budget unless a single
//! triangle does (or the depth cap is hit), every input triangle is in exactly one tile, and
//! per-element models keep their elements whole: only what overflows a tile is cut.
//!
//! Extent (the bottom rung of the error ladder): a cell whose content spans more than
//! `max_leaf_extent_m` also splits, even within the budgets, and what is that wide and cannot
//! descend whole is cut like an over-budget mesh. The HLOD tiles above then form a ladder: each
//! level's cells are half its parent's, and so is the error a viewer accepts of them (their framed
//! error, which caps their simplification); the leaf level's rung is absolute, so that full detail
//! is only fetched near it. A wide, sparse scene (kilometres across in few triangles, which the
//! budgets alone would make a root over a few kilometre-wide leaves) gets the levels between;
//! compact models, smaller than a leaf, keep the tree their budgets give.
//!
//! A campus's grid is anchored ([`Scene::stable_layout`]: a manifest of placed models): every
//! cell below the root is a cell of one fixed power-of-two grid (a cell of side `s` spans
//! `[i s, (i + 1) s]` on each axis of the tileset frame), and the root is the grid-aligned cube
//! of twice the smallest power of two that spans the content ([`grid_root_cell`]). So the cells do not move when the content's bounds do: a building
//! removed, moved or replaced changes the cells it was or is in and their ancestors, and the
//! rest of the tree, cells and content, stays as it was (`convert --update`). Only content that
//! reaches past the root's cube, or shrinks to half of it, changes the root. A cell that holds
//! nearly all of its parent's content (a campus across a line of the grid) is no level of its own:
//! it is spliced out, and the cells in its place grouped by octant ([`without_repeated_levels`]);
//! the grid's cells below keep their places. A single model's
//! root is the cube around its bounds (cells that fit it tightly: a grid anchored at the origin
//! would cut a model centred there along its middle planes first).
//!
//! The plan is computed from bounds and counts only, and is a pure function of the scene and the
//! options (input order, no hashing, no threads): the output is the same on every run.

use crate::scene::{Aabb, ComponentId, Scene};
use glam::DVec3;
use std::sync::Arc;

/// A triangle of a component's mesh: (primitive index, triangle index in that primitive).
pub type TriRef = (u32, u32);

/// What a tile draws of one component: all of it, or a part of a cut mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct ContentItem {
    pub component: ComponentId,
    /// `None`: the whole component; `Some`: only these triangles, sorted.
    pub triangles: Option<Arc<Vec<TriRef>>>,
}

#[derive(Debug, Clone)]
pub struct OctreeOptions {
    /// A cell whose content has more triangles than this is split.
    pub max_tile_triangles: usize,
    /// A cell whose content's estimated uncompressed size is over this is split.
    pub max_tile_bytes: usize,
    /// A cell whose content spans more than this (largest side of its box, metres) is split, and
    /// meshes wider than this that stay in it are cut: the ladder's bottom rung (module docs).
    pub max_leaf_extent_m: f64,
    /// No split below this depth (a safety net for coincident components).
    pub max_depth: u32,
}

/// Default [`OctreeOptions::max_leaf_extent_m`]. A leaf's parent spans at most about twice this,
/// so its error is capped at about 0.8 of its framed error (`lod::hlod`), some 4 m: full detail
/// is fetched within about 300 m of it. City blocks and airfield aprons are tiled; a building (or a
/// site of them) is not split for its extent.
pub const MAX_LEAF_EXTENT_M: f64 = 128.0;

impl Default for OctreeOptions {
    fn default() -> Self {
        OctreeOptions {
            max_tile_triangles: 40_000,
            max_tile_bytes: 4 << 20,
            max_leaf_extent_m: MAX_LEAF_EXTENT_M,
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
    /// What this tile draws, ordered by component id (parts of one component together).
    pub content: Vec<ContentItem>,
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

    /// The plan for replacement refinement (HLOD): all full-detail content in leaves. A tile that
    /// has both content of its own and children hands its content to a new leaf child named
    /// `<path>8` (octants are 0-7), which is drawn beside the other children once the tile
    /// refines; the tile itself then carries only what the HLOD builder makes of its subtree.
    pub fn with_content_in_leaves(self) -> TilePlan {
        fn visit(old: &[PlannedTile], i: usize, depth: u32, out: &mut Vec<PlannedTile>) {
            let t = &old[i];
            let me = out.len();
            out.push(PlannedTile {
                depth,
                children: Vec::new(),
                ..t.clone()
            });
            if t.children.is_empty() {
                return;
            }
            if !t.content.is_empty() {
                let leaf = out.len();
                out.push(PlannedTile {
                    path: format!("{}8", t.path),
                    depth: depth + 1,
                    children: Vec::new(),
                    bounds: t.content_bounds,
                    omitted_size_m: 0.0,
                    ..t.clone()
                });
                out[me].children.push(leaf);
                let own = &mut out[me];
                own.content = Vec::new();
                own.content_bounds = Aabb::EMPTY;
                own.content_triangles = 0;
            }
            for &c in &t.children {
                let ci = out.len();
                out[me].children.push(ci);
                visit(old, c, depth + 1, out);
            }
        }
        let mut out = Vec::with_capacity(self.tiles.len() * 9 / 8 + 1);
        if !self.tiles.is_empty() {
            visit(&self.tiles, 0, 0, &mut out);
        }
        TilePlan { tiles: out }
    }

    /// A one-tile plan with a coarse root above its tile: the new root (named `<path>-lod1`, as
    /// the first coarser level of a discrete LOD chain) has no content items of its own and the
    /// old tile, one level down and named as before, as its only child. `None` unless the plan
    /// is one tile.
    pub fn under_coarse_root(&self) -> Option<TilePlan> {
        let [leaf] = &self.tiles[..] else {
            return None;
        };
        let root = PlannedTile {
            path: format!("{}-lod1", leaf.path),
            depth: 0,
            content: Vec::new(),
            children: vec![1],
            content_bounds: Aabb::EMPTY,
            content_triangles: 0,
            ..leaf.clone()
        };
        let leaf = PlannedTile {
            depth: 1,
            ..leaf.clone()
        };
        Some(TilePlan {
            tiles: vec![root, leaf],
        })
    }
}

struct Item {
    id: ComponentId,
    part: Option<Arc<Vec<TriRef>>>,
    center: DVec3,
    extent: f64,
    triangles: usize,
    bytes: usize,
    diagonal: f64,
    bounds: Aabb,
}

/// Plans the octree for every drawn component of `scene` that has geometry (aliases of exact
/// duplicates are left out: their geometry is the kept component's).
pub fn plan_octree(scene: &Scene, opts: &OctreeOptions) -> TilePlan {
    let plan = plan_cells(scene, opts);
    match scene.stable_layout {
        true => TilePlan {
            tiles: without_repeated_levels(plan.tiles),
        },
        false => plan,
    }
}

/// The octree of [`plan_octree`], every non-empty cell a tile but those with one child and no
/// content of their own.
fn plan_cells(scene: &Scene, opts: &OctreeOptions) -> TilePlan {
    let items: Vec<Item> = scene
        .drawn_components()
        .filter(|c| !c.world_bounds.is_empty())
        .map(|c| {
            let s = c.world_bounds.size();
            Item {
                id: c.id,
                part: None,
                center: c.world_bounds.center(),
                extent: s.max_element(),
                triangles: scene.meshes.triangle_count(c.mesh),
                bytes: scene.meshes.estimated_bytes(c.mesh),
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
    let root_cell = match scene.stable_layout {
        true => grid_root_cell(&all),
        false => bounds_root_cell(&all),
    };
    if let Some(root) = build(scene, root_cell, items, 0, "r".into(), opts) {
        flatten(root, &mut plan.tiles);
    }
    plan
}

/// A child whose box's largest side is over this share of its parent's halves nothing (see
/// [`without_repeated_levels`]).
const REPEATED_LEVEL_SIDE_RATIO: f64 = 0.75;

/// The plan with every tile that repeats its parent's level spliced out, and the tiles that
/// splicing leaves with more than eight children grouped by octant.
///
/// On the anchored grid, content that straddles a line of a large cell leaves one child holding
/// nearly all of it beside slivers: the ladder (`lod::hlod`) would still halve each such level's
/// error, holding every level below to more detail than its size asks, and each would be one more
/// simplification and measurement of nearly all the content. A tile with no content of its own
/// whose box's largest side is over [`REPEATED_LEVEL_SIDE_RATIO`] of its parent's is replaced by
/// its children (again if they repeat it too). The cells that then take its place are smaller
/// than half their new parent, and can be many: they are grouped by the octant of the parent's box
/// their centre is in, each group of two or more a tile of its own (`<parent>g<octant>`, no
/// content), so that the first levels below a tile halve it, as a plain octree's do. Grid tiles keep
/// their paths and cells (an update's tiles keep their names); only the tree above them changes.
fn without_repeated_levels(tiles: Vec<PlannedTile>) -> Vec<PlannedTile> {
    fn side_m(b: &Aabb) -> f64 {
        b.size().max_element()
    }
    /// A tile to write: one of the plan's, or a group of some of its tiles.
    enum Next<'a> {
        Tile(usize),
        Group(Box<PlannedTile>, &'a [usize]),
    }
    fn visit(old: &[PlannedTile], next: Next, depth: u32, out: &mut Vec<PlannedTile>) {
        let (tile, children) = match next {
            Next::Tile(i) => (old[i].clone(), &old[i].children[..]),
            Next::Group(tile, children) => (*tile, children),
        };
        let limit_m = REPEATED_LEVEL_SIDE_RATIO * side_m(&tile.bounds);
        // In order: a spliced child's children take its place.
        let mut kids = Vec::new();
        let mut pending: Vec<usize> = children.iter().rev().copied().collect();
        while let Some(c) = pending.pop() {
            let t = &old[c];
            if t.content.is_empty() && !t.children.is_empty() && side_m(&t.bounds) > limit_m {
                pending.extend(t.children.iter().rev());
            } else {
                kids.push(c);
            }
        }
        let mut octants: [Vec<usize>; 8] = Default::default();
        for &k in &kids {
            octants[octant_of(old[k].bounds.center(), tile.bounds.center())].push(k);
        }
        let grouped = kids.len() > 8 && octants.iter().all(|o| o.len() < kids.len());
        let me = out.len();
        out.push(PlannedTile {
            depth,
            children: Vec::new(),
            ..tile
        });
        let nexts: Vec<Next> = match grouped {
            false => kids.into_iter().map(Next::Tile).collect(),
            true => octants
                .iter()
                .enumerate()
                .filter(|(_, o)| !o.is_empty())
                .map(|(o, group)| match group[..] {
                    [only] => Next::Tile(only),
                    _ => {
                        let bounds = group
                            .iter()
                            .fold(Aabb::EMPTY, |b, &k| b.union(&old[k].bounds));
                        let parent = &out[me];
                        let tile = PlannedTile {
                            path: format!("{}g{o}", parent.path),
                            depth: depth + 1,
                            cell: bounds_root_cell(&bounds),
                            content: Vec::new(),
                            children: Vec::new(),
                            content_bounds: Aabb::EMPTY,
                            bounds,
                            content_triangles: 0,
                            // The parent's: no smaller than what its descendants in the group
                            // hold.
                            omitted_size_m: parent.omitted_size_m,
                        };
                        Next::Group(Box::new(tile), group)
                    }
                })
                .collect(),
        };
        for next in nexts {
            let at = out.len();
            out[me].children.push(at);
            visit(old, next, depth + 1, out);
        }
    }
    let mut out = Vec::with_capacity(tiles.len());
    if !tiles.is_empty() {
        visit(&tiles, Next::Tile(0), 0, &mut out);
    }
    out
}

/// The root cell of a single model: the cube around its bounds' centre whose side is their
/// largest (the tightest cells for a model whose bounds an update seldom moves).
fn bounds_root_cell(bounds: &Aabb) -> Aabb {
    let half = bounds.size().max_element().max(1e-6) * 0.5;
    Aabb {
        min: bounds.center() - DVec3::splat(half),
        max: bounds.center() + DVec3::splat(half),
    }
}

/// The root cell of a campus (a scene with [`Scene::stable_layout`]) within `bounds`: a cube of side `2 s`, `s` the smallest power of two
/// (metres) no smaller than the content's largest side, its corner on the grid of side `s`. It
/// holds the content (which starts in its lower half on each axis), and its children, and theirs,
/// are cells of the fixed power-of-two grid whatever the bounds: the content's bounds choose only
/// how far up the grid the root sits.
pub fn grid_root_cell(bounds: &Aabb) -> Aabb {
    let extent_m = bounds.size().max_element().max(1e-6);
    // An exact power of two, so that the corners below are exact multiples of it.
    let mut side_m = 2f64.powi(extent_m.log2().ceil() as i32);
    while side_m < extent_m {
        side_m *= 2.0;
    }
    let min = (bounds.min / side_m).floor() * side_m;
    Aabb {
        min,
        max: min + DVec3::splat(2.0 * side_m),
    }
}

struct Node {
    path: String,
    depth: u32,
    cell: Aabb,
    content: Vec<ContentItem>,
    content_bounds: Aabb,
    content_triangles: usize,
    content_max_diag: f64,
    children: Vec<Node>,
}

fn octant_of(p: DVec3, c: DVec3) -> usize {
    (p.x >= c.x) as usize | ((p.y >= c.y) as usize) << 1 | ((p.z >= c.z) as usize) << 2
}

fn child_cell(cell: &Aabb, o: usize) -> Aabb {
    let c = cell.center();
    let half = cell.size().x * 0.5;
    let min = DVec3::new(
        if o & 1 == 0 { cell.min.x } else { c.x },
        if o & 2 == 0 { cell.min.y } else { c.y },
        if o & 4 == 0 { cell.min.z } else { c.z },
    );
    Aabb {
        min,
        max: min + DVec3::splat(half),
    }
}

/// Cuts an item into up to 8 parts by triangle centroid against the cell's centre; returns
/// (octant, part) in octant order.
fn cut(scene: &Scene, item: &Item, cell: &Aabb) -> Vec<(usize, Item)> {
    let comp = scene.component(item.id);
    let mesh = scene.mesh(comp.mesh);
    let c = cell.center();
    let all: Vec<TriRef>;
    let tris: &[TriRef] = match &item.part {
        Some(p) => p,
        None => {
            all = mesh
                .primitives
                .iter()
                .enumerate()
                .flat_map(|(pi, p)| (0..p.triangle_count() as u32).map(move |t| (pi as u32, t)))
                .collect();
            &all
        }
    };
    let bytes_per_tri = item.bytes as f64 / item.triangles.max(1) as f64;
    let mut groups: [(Vec<TriRef>, Aabb); 8] = Default::default();
    for &(pi, t) in tris {
        let prim = &mesh.primitives[pi as usize];
        let k = t as usize * 3;
        let idx = [prim.indices[k], prim.indices[k + 1], prim.indices[k + 2]];
        let v = idx.map(|i| {
            let p = prim.positions[i as usize];
            comp.world
                .transform_point3(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        });
        let g = &mut groups[octant_of((v[0] + v[1] + v[2]) / 3.0, c)];
        g.0.push((pi, t));
        for p in v {
            g.1.extend(p);
        }
    }
    groups
        .into_iter()
        .enumerate()
        .filter(|(_, g)| !g.0.is_empty())
        .map(|(o, (tris, bounds))| {
            let s = bounds.size();
            (
                o,
                Item {
                    id: item.id,
                    center: bounds.center(),
                    extent: s.max_element(),
                    triangles: tris.len(),
                    bytes: (tris.len() as f64 * bytes_per_tri).ceil() as usize,
                    diagonal: s.length(),
                    bounds,
                    part: Some(Arc::new(tris)),
                },
            )
        })
        .collect()
}

fn build(
    scene: &Scene,
    cell: Aabb,
    items: Vec<Item>,
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
    let too_wide = |i: &Item| {
        i.extent > opts.max_leaf_extent_m && i.triangles > 1 && side > opts.max_leaf_extent_m
    };
    let extent_m = items
        .iter()
        .fold(Aabb::EMPTY, |b, i| b.union(&i.bounds))
        .size()
        .max_element();
    // A cell no larger than a leaf may span is not split for its extent (its content may stick
    // out of it: whole triangles, loose octree).
    let fits_extent = extent_m <= opts.max_leaf_extent_m || side <= opts.max_leaf_extent_m;
    let mut octants: [Vec<Item>; 8] = Default::default();
    let mut stay: Vec<Item> = Vec::new();
    if (fits_budget && fits_extent) || depth >= opts.max_depth {
        stay = items;
    } else {
        let c = cell.center();
        for it in items {
            if it.extent > side * 0.5 {
                stay.push(it);
            } else {
                octants[octant_of(it.center, c)].push(it);
            }
        }
        // What stays but spans more than a leaf may is cut (one triangle cannot be: it stays).
        if stay.iter().any(too_wide) {
            let mut kept = Vec::new();
            for it in stay {
                if too_wide(&it) {
                    for (o, part) in cut(scene, &it, &cell) {
                        octants[o].push(part);
                    }
                } else {
                    kept.push(it);
                }
            }
            stay = kept;
        }
        // What cannot descend whole is still too much: cut the largest meshes until it fits.
        let (mut stay_tris, mut stay_bytes) = (
            stay.iter().map(|i| i.triangles).sum::<usize>(),
            stay.iter().map(|i| i.bytes).sum::<usize>(),
        );
        if stay_tris > opts.max_tile_triangles || stay_bytes > opts.max_tile_bytes {
            stay.sort_by(|a, b| b.triangles.cmp(&a.triangles).then(a.id.cmp(&b.id)));
            let mut kept = Vec::new();
            for it in stay {
                let over = stay_tris > opts.max_tile_triangles || stay_bytes > opts.max_tile_bytes;
                if !over {
                    kept.push(it);
                    continue;
                }
                stay_tris -= it.triangles;
                stay_bytes -= it.bytes;
                if it.triangles > 1 {
                    for (o, part) in cut(scene, &it, &cell) {
                        octants[o].push(part);
                    }
                } else {
                    // One triangle cannot be cut: it descends by its centre (its tile's volume
                    // comes from the content, so it stays correct), until the depth cap.
                    octants[octant_of(it.center, c)].push(it);
                }
            }
            stay = kept;
        }
    }
    let mut children = Vec::new();
    for (o, group) in octants.into_iter().enumerate() {
        if let Some(n) = build(
            scene,
            child_cell(&cell, o),
            group,
            depth + 1,
            format!("{path}{o}"),
            opts,
        ) {
            children.push(n);
        }
    }
    stay.sort_by(|a, b| {
        a.id.cmp(&b.id).then_with(|| {
            a.part
                .as_ref()
                .map(|p| p[0])
                .cmp(&b.part.as_ref().map(|p| p[0]))
        })
    });
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
        content: stay
            .into_iter()
            .map(|i| ContentItem {
                component: i.id,
                triangles: i.part,
            })
            .collect(),
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

    /// Adds a one-primitive mesh and the component that draws it.
    fn push_mesh_component(
        s: &mut Scene,
        positions: Vec<[f32; 3]>,
        indices: Vec<u32>,
        key: String,
        world: DMat4,
    ) {
        let mesh = MeshId(s.meshes.len() as u32);
        s.meshes.push(Mesh {
            name: None,
            primitives: vec![Primitive {
                positions,
                indices,
                ..Default::default()
            }],
            local_bounds: None,
        });
        s.push_component(Component::new(mesh, world), &ElementInfo::keyed(key));
    }

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
            push_mesh_component(
                &mut s,
                positions,
                indices,
                format!("c{i}"),
                DMat4::from_translation(c),
            );
        }
        s.finish();
        s
    }

    fn check_invariants(scene: &Scene, plan: &TilePlan, opts: &OctreeOptions) {
        // The depth cap counts grid levels from the root cell, some of which an empty tile with a
        // single child may have left out: a capped cell is this small.
        let bounds = scene
            .components
            .iter()
            .fold(Aabb::EMPTY, |b, c| b.union(&c.world_bounds));
        let root = match scene.stable_layout {
            true => grid_root_cell(&bounds),
            false => bounds_root_cell(&bounds),
        };
        let capped_side_m = root.size().x / 2f64.powi(opts.max_depth as i32);
        // Every triangle exactly once.
        let mut seen: Vec<Vec<u32>> = scene
            .components
            .iter()
            .map(|c| vec![0; scene.meshes.triangle_count(c.mesh)])
            .collect();
        for t in &plan.tiles {
            for c in &t.content {
                let mesh = scene.mesh(scene.component(c.component).mesh);
                let first_tri = |pi: u32| -> usize {
                    mesh.primitives[..pi as usize]
                        .iter()
                        .map(|p| p.triangle_count())
                        .sum()
                };
                match &c.triangles {
                    None => seen[c.component.index()].iter_mut().for_each(|n| *n += 1),
                    Some(tris) => {
                        assert!(tris.windows(2).all(|w| w[0] < w[1]), "sorted, unique");
                        for &(pi, ti) in tris.iter() {
                            seen[c.component.index()][first_tri(pi) + ti as usize] += 1;
                        }
                    }
                }
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
            }
            // The budget holds for every tile, unless one triangle exceeds it or the depth cap
            // was hit.
            assert!(
                t.content_triangles <= opts.max_tile_triangles
                    || t.cell.size().x <= capped_side_m * (1.0 + 1e-9),
                "{} holds {} triangles",
                t.path,
                t.content_triangles
            );
        }
        assert!(
            seen.iter().flatten().all(|&n| n == 1),
            "every triangle exactly once"
        );
    }

    #[test]
    fn the_root_cell_holds_the_content_on_the_power_of_two_grid() {
        for (min, max) in [
            (DVec3::new(0.0, 0.0, 0.0), DVec3::new(40.0, 10.0, 5.0)),
            (DVec3::new(-7.5, 3.0, -2.0), DVec3::new(25.0, 9.0, 12.0)),
            (
                DVec3::new(1000.3, -20.0, 0.0),
                DVec3::new(1003.1, -19.0, 0.5),
            ),
            (DVec3::splat(64.0), DVec3::splat(64.0)),
        ] {
            let b = Aabb { min, max };
            let cell = grid_root_cell(&b);
            assert!(cell.contains_box(&b, 0.0), "{b:?} in {cell:?}");
            let side = cell.size().x;
            assert_eq!(cell.size(), DVec3::splat(side));
            let half = side / 2.0;
            assert_eq!(half.log2().fract(), 0.0, "a power of two: {half}");
            assert!(
                half >= b.size().max_element() && half < 2.0 * b.size().max_element().max(1e-6)
            );
            // Its children are grid cells: corners on multiples of their side.
            assert_eq!((cell.min / half).fract(), DVec3::ZERO);
        }
    }

    #[test]
    fn a_removed_box_leaves_the_other_cells_where_they_were() {
        // A row of boxes over 300 m, split by a small budget; the last box (which sets the
        // bounds) removed: the tiles that hold none of it keep their cells and content.
        let specs: Vec<(DVec3, f64)> = (0..30)
            .map(|i| (DVec3::new(i as f64 * 10.0, (i % 3) as f64 * 4.0, 0.0), 2.0))
            .collect();
        let opts = OctreeOptions {
            max_tile_triangles: 36,
            ..Default::default()
        };
        let campus = |specs: &[(DVec3, f64)]| {
            let mut s = boxes(specs);
            s.stable_layout = true;
            s
        };
        let before = plan_octree(&campus(&specs), &opts);
        let after = plan_octree(&campus(&specs[..29]), &opts);
        check_invariants(&campus(&specs[..29]), &after, &opts);
        let gone = ComponentId(29);
        // The tiles that held the box, and so their ancestors (path prefixes), may change; every
        // other leaf of the new plan is a leaf of the old one, with the same content.
        let held: Vec<&str> = before
            .tiles
            .iter()
            .filter(|t| t.content.iter().any(|c| c.component == gone))
            .map(|t| t.path.as_str())
            .collect();
        let leaves = |p: &TilePlan| -> Vec<(String, Vec<ContentItem>)> {
            p.tiles
                .iter()
                .filter(|t| t.children.is_empty() && !held.iter().any(|h| h.starts_with(&t.path)))
                .map(|t| (t.path.clone(), t.content.clone()))
                .collect()
        };
        let (kept_before, kept_after) = (leaves(&before), leaves(&after));
        assert!(kept_after.len() >= 8, "{} leaves", kept_after.len());
        for leaf in &kept_after {
            assert!(kept_before.contains(leaf), "{} as it was", leaf.0);
        }
        // A single model's cells follow its bounds: the same change moves them.
        let single = plan_octree(&boxes(&specs[..29]), &opts);
        let moved = leaves(&single)
            .iter()
            .filter(|l| !kept_before.contains(l))
            .count();
        assert!(moved > 0, "a single model's grid is not anchored");
    }

    #[test]
    fn a_campus_across_the_grid_lines_has_no_level_that_repeats_its_parent() {
        // Ten rows of ten boxes 60 m apart, from 20 m west and south of the origin: the grid's
        // lines through the origin leave one cell of each large level holding nearly all of them,
        // beside slivers.
        let specs: Vec<(DVec3, f64)> = (0..100)
            .map(|i| {
                let (x, y) = ((i % 10) as f64, (i / 10) as f64);
                (DVec3::new(x * 60.0 - 20.0, y * 60.0 - 20.0, 4.0), 8.0)
            })
            .collect();
        let mut s = boxes(&specs);
        s.stable_layout = true;
        let opts = OctreeOptions {
            max_tile_triangles: 48,
            ..Default::default()
        };
        let side_m = |t: &PlannedTile| t.bounds.size().max_element();
        let repeats = |p: &TilePlan| {
            p.tiles.iter().any(|t| {
                t.children.iter().any(|&c| {
                    let child = &p.tiles[c];
                    child.content.is_empty()
                        && !child.children.is_empty()
                        && side_m(child) > REPEATED_LEVEL_SIDE_RATIO * side_m(t)
                })
            })
        };
        let cells = plan_cells(&s, &opts);
        assert!(repeats(&cells), "the grid's own tree repeats a level");
        let plan = plan_octree(&s, &opts);
        check_invariants(&s, &plan, &opts);
        assert!(!repeats(&plan));
        // The cells that took a spliced level's place are grouped, eight groups at most.
        assert!(plan.tiles.iter().any(|t| t.path.contains('g')));
        assert!(plan.tiles.iter().all(|t| t.children.len() <= 8));
        for t in plan.tiles.iter().filter(|t| t.path.contains('g')) {
            assert!(t.content.is_empty() && t.children.len() >= 2, "{}", t.path);
        }
        // The same leaves, under the same names.
        let leaves = |p: &TilePlan| -> Vec<(String, Vec<ContentItem>)> {
            let mut l: Vec<_> = p
                .tiles
                .iter()
                .filter(|t| t.children.is_empty())
                .map(|t| (t.path.clone(), t.content.clone()))
                .collect();
            l.sort_by(|a, b| a.0.cmp(&b.0));
            l
        };
        assert_eq!(leaves(&plan), leaves(&cells));
    }

    #[test]
    fn small_scene_is_one_tile() {
        let s = boxes(&[(DVec3::ZERO, 1.0), (DVec3::X * 3.0, 1.0)]);
        let plan = plan_octree(&s, &OctreeOptions::default());
        assert_eq!(plan.tiles.len(), 1);
        assert_eq!(plan.tiles[0].content.len(), 2);
        assert_eq!(plan.tiles[0].omitted_size_m, 0.0);
    }

    /// A 100 m slab plus a 10x10 grid of 1 m boxes; budget of 10 boxes (120 triangles).
    fn slab_and_boxes() -> (Scene, OctreeOptions) {
        let mut specs = vec![(DVec3::new(50.0, 50.0, 0.0), 100.0)];
        for i in 0..10 {
            for j in 0..10 {
                specs.push((
                    DVec3::new(5.0 + i as f64 * 10.0, 5.0 + j as f64 * 10.0, 1.0),
                    1.0,
                ));
            }
        }
        let opts = OctreeOptions {
            max_tile_triangles: 120,
            ..Default::default()
        };
        (boxes(&specs), opts)
    }

    #[test]
    fn splits_over_budget_and_keeps_large_components_high() {
        let (s, opts) = slab_and_boxes();
        let plan = plan_octree(&s, &opts);
        assert!(plan.tiles.len() > 8);
        // The slab stays at the root.
        assert!(plan.tiles[0]
            .content
            .iter()
            .any(|c| c.component == ComponentId(0) && c.triangles.is_none()));
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
    fn replacement_plan_has_all_content_in_leaves() {
        let (s, opts) = slab_and_boxes();
        let plan = plan_octree(&s, &opts);
        let leaves = plan.clone().with_content_in_leaves();
        check_invariants(&s, &leaves, &opts);
        assert!(leaves.tiles.len() > plan.tiles.len());
        for t in &leaves.tiles {
            assert_eq!(t.content.is_empty(), !t.children.is_empty(), "{}", t.path);
        }
        // The slab went from the root to the root's new leaf, named after it.
        let root = &leaves.tiles[0].path;
        let leaf = leaves
            .tiles
            .iter()
            .find(|t| t.path == format!("{root}8"))
            .unwrap();
        assert!(leaf.content.iter().any(|c| c.component == ComponentId(0)));
        assert_eq!(leaf.depth, 1);
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

    /// One mesh: an n x n grid of quads (2 n^2 triangles) on the ground, `size` metres wide.
    fn grid_scene(n: usize, size: f32) -> Scene {
        let mut positions = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 / n as f32 * size, j as f32 / n as f32 * size);
                positions.push([x, y, (x * 0.3).sin()]);
            }
        }
        let mut indices = Vec::new();
        for j in 0..n as u32 {
            for i in 0..n as u32 {
                let a = j * (n as u32 + 1) + i;
                let b = a + n as u32 + 1;
                indices.extend_from_slice(&[a, a + 1, b + 1, a, b + 1, b]);
            }
        }
        let mut s = Scene::default();
        push_mesh_component(&mut s, positions, indices, "grid".into(), DMat4::IDENTITY);
        s.finish();
        s
    }

    #[test]
    fn big_meshes_are_cut_to_the_budget() {
        let s = grid_scene(100, 100.0); // 20,000 triangles in one mesh
        let opts = OctreeOptions {
            max_tile_triangles: 1000,
            ..Default::default()
        };
        let plan = plan_octree(&s, &opts);
        check_invariants(&s, &plan, &opts);
        let with_content = plan.tiles.iter().filter(|t| !t.content.is_empty()).count();
        assert!(with_content >= 20, "{with_content} tiles");
        // Parts are tight: a leaf's box is far smaller than the mesh.
        let leaf = plan.tiles.iter().find(|t| t.children.is_empty()).unwrap();
        assert!(leaf.content_bounds.size().x < 60.0);
    }

    #[test]
    fn wide_content_is_split_to_the_leaf_extent_within_the_budget() {
        // 1 km of ground in 3,200 triangles of 25 m: far under the budget, far over a leaf's span.
        let s = grid_scene(40, 1000.0);
        let opts = OctreeOptions::default();
        let plan = plan_octree(&s, &opts);
        check_invariants(&s, &plan, &opts);
        assert!(plan.tiles.len() > 16, "{} tiles", plan.tiles.len());
        for t in plan.tiles.iter().filter(|t| t.children.is_empty()) {
            // A leaf's cell is at most 128 m; its parts reach across its parent's cell at most,
            // plus a triangle.
            let span = t.content_bounds.size().max_element();
            assert!(
                span <= 2.0 * MAX_LEAF_EXTENT_M + 2.0 * 25.0 * 2f64.sqrt(),
                "{span}"
            );
        }
        // Without the extent rule, the budget alone keeps it one tile.
        let one = plan_octree(
            &s,
            &OctreeOptions {
                max_leaf_extent_m: f64::INFINITY,
                ..opts
            },
        );
        assert_eq!(one.tiles.len(), 1);
    }

    #[test]
    fn whole_elements_stay_whole_when_they_fit() {
        // A big mesh plus small boxes: only the big mesh is cut.
        let mut s = grid_scene(60, 100.0);
        let boxes_scene = boxes(
            &(0..20)
                .map(|i| (DVec3::new(5.0 * i as f64, 50.0, 2.0), 1.0))
                .collect::<Vec<_>>(),
        );
        s.append(boxes_scene);
        s.finish();
        let opts = OctreeOptions {
            max_tile_triangles: 800,
            ..Default::default()
        };
        let plan = plan_octree(&s, &opts);
        check_invariants(&s, &plan, &opts);
        for t in &plan.tiles {
            for c in &t.content {
                if c.component != ComponentId(0) {
                    assert!(c.triangles.is_none(), "box {:?} was cut", c.component);
                }
            }
        }
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

    #[test]
    fn a_coarse_root_goes_above_a_one_tile_plan_only() {
        let s = boxes(&[(DVec3::ZERO, 1.0), (DVec3::new(3.0, 0.0, 0.0), 1.0)]);
        let plan = plan_octree(&s, &OctreeOptions::default());
        assert_eq!(plan.tiles.len(), 1);
        let two = plan.under_coarse_root().expect("one tile");
        let [root, leaf] = &two.tiles[..] else {
            panic!("two tiles")
        };
        assert_eq!((root.path.as_str(), root.depth), ("r-lod1", 0));
        assert_eq!((leaf.path.as_str(), leaf.depth), ("r", 1));
        assert_eq!(root.children, [1]);
        assert!(root.content.is_empty() && leaf.children.is_empty());
        assert_eq!(leaf.content.len(), plan.tiles[0].content.len());
        assert_eq!(root.bounds, leaf.bounds);
        assert!(two.under_coarse_root().is_none());
        let split = plan_octree(
            &s,
            &OctreeOptions {
                max_tile_triangles: 12,
                ..Default::default()
            },
        );
        assert!(split.tiles.len() > 1 && split.under_coarse_root().is_none());
    }
}
