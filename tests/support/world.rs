//! World expansion of a glTF read with the `gltf` crate, shared by the tests and `make bench`:
//! the node hierarchy walked with world matrices (f32 or f64), and every primitive of a file
//! merged in world coordinates.

use glam::{DMat4, Mat4, Vec3};

/// A 4x4 matrix a node hierarchy can be walked in: `Mat4` (f32 products) or `DMat4` (each local
/// matrix read as f32, as glTF stores it, then multiplied in f64).
pub trait WorldMatrix: Copy + std::ops::Mul<Output = Self> {
    fn from_gltf(m: [[f32; 4]; 4]) -> Self;
}

impl WorldMatrix for Mat4 {
    fn from_gltf(m: [[f32; 4]; 4]) -> Self {
        Mat4::from_cols_array_2d(&m)
    }
}

impl WorldMatrix for DMat4 {
    fn from_gltf(m: [[f32; 4]; 4]) -> Self {
        DMat4::from_cols_array(
            &Mat4::from_cols_array_2d(&m)
                .to_cols_array()
                .map(|x| x as f64),
        )
    }
}

/// The root nodes of the default scene (else the first scene; none without scenes).
pub fn scene_roots(doc: &gltf::Document) -> Vec<gltf::Node<'_>> {
    doc.default_scene()
        .or_else(|| doc.scenes().next())
        .map(|s| s.nodes().collect())
        .unwrap_or_default()
}

/// Every node below `roots` with its world matrix (`root` times the node matrices down to it),
/// depth first in reading order (roots and children in glTF order).
pub fn world_nodes<'a, M: WorldMatrix>(
    roots: impl IntoIterator<Item = gltf::Node<'a>>,
    root: M,
) -> Vec<(gltf::Node<'a>, M)> {
    let mut out = Vec::new();
    let mut stack: Vec<(gltf::Node<'a>, M)> = roots.into_iter().map(|n| (n, root)).collect();
    stack.reverse();
    while let Some((node, parent)) = stack.pop() {
        let world = parent * M::from_gltf(node.transform().matrix());
        let first = stack.len();
        stack.extend(node.children().map(|c| (c, world)));
        stack[first..].reverse();
        out.push((node, world));
    }
    out
}

/// Every triangle primitive of a glTF merged in world coordinates (glTF y-up, f32), normals by
/// the inverse transpose (+z where missing), group id = node index.
#[derive(Default)]
pub struct WorldMesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub groups: Vec<u32>,
    pub indices: Vec<u32>,
}

/// [`WorldMesh`] of the GLB at `path` (every scene), or `None` when it does not read.
pub fn world_mesh(path: &std::path::Path) -> Option<WorldMesh> {
    let bytes = std::fs::read(path).ok()?;
    let g = gltf::Gltf::from_slice_without_validation(&bytes).ok()?;
    let blob = g.blob.as_deref();
    let mut m = WorldMesh::default();
    for (node, world) in world_nodes(g.scenes().flat_map(|s| s.nodes()), Mat4::IDENTITY) {
        let Some(mesh) = node.mesh() else { continue };
        let nmat = world.inverse().transpose();
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let r = prim.reader(|_| blob);
            let Some(pos) = r.read_positions() else {
                continue;
            };
            let pos: Vec<[f32; 3]> = pos.collect();
            let nrm: Vec<[f32; 3]> = match r.read_normals() {
                Some(n) => n.collect(),
                None => vec![[0.0, 0.0, 1.0]; pos.len()],
            };
            let base = m.positions.len() as u32;
            let idx: Vec<u32> = match r.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..pos.len() as u32).collect(),
            };
            for (p, n) in pos.iter().zip(&nrm) {
                m.positions
                    .push(world.transform_point3(Vec3::from(*p)).to_array());
                m.normals.push(
                    nmat.transform_vector3(Vec3::from(*n))
                        .normalize_or_zero()
                        .to_array(),
                );
                m.groups.push(node.index() as u32);
            }
            m.indices.extend(idx.iter().map(|i| i + base));
        }
    }
    Some(m)
}
