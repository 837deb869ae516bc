//! The element index (`element-index.json`, schema `schemas/element-index.schema.json`): every
//! element of the tileset with its id, name, IFC class, site, building, storey, hierarchy path and
//! bounding box, so that a viewer can list, group and find elements without loading any tile
//! (the paper's section IV, the web BIM system: model tree and search).
//!
//! A column table, rows sorted by site, building, storey, class and id (a model tree's groups are
//! contiguous runs): repeated texts (site, building, storey, class, the path's parent) are written
//! once in dictionaries and referenced by code, code 0 standing for "no value"; boxes are whole
//! millimetres in the tileset frame (the frame of tileset.json's bounding volumes, before the root
//! transform), rounded outwards so that each box contains its element's triangles. Written from the
//! scene alone, so `convert` and a sharded build's `merge` write the same bytes.

use crate::scene::{Aabb, ComponentId, Scene};
use serde::Serialize;
use std::collections::BTreeMap;

/// The index file, in the tileset's folder (named in tileset.json's `asset.extras.bimtiles`).
pub const ELEMENT_INDEX_FILE: &str = "element-index.json";
/// The `format` field: a reader refuses a version it does not know.
pub const ELEMENT_INDEX_FORMAT: &str = "bimtiles-element-index/2";

/// Texts written once, referenced by code (index; 0 is `null`, no value).
#[derive(Debug, Default, Serialize, PartialEq)]
pub struct Dictionaries {
    pub site: Vec<Option<String>>,
    pub building: Vec<Option<String>>,
    pub storey: Vec<Option<String>>,
    pub class: Vec<Option<String>>,
    /// The hierarchy path without its last segment.
    #[serde(rename = "pathParent")]
    pub path_parent: Vec<Option<String>>,
}

/// One value per element and column, rows in the same order in every column.
#[derive(Debug, Default, Serialize, PartialEq)]
pub struct Columns {
    pub id: Vec<String>,
    pub name: Vec<Option<String>>,
    pub site: Vec<u32>,
    pub building: Vec<u32>,
    pub storey: Vec<u32>,
    pub class: Vec<u32>,
    #[serde(rename = "pathParent")]
    pub path_parent: Vec<u32>,
    /// The path's last segment; `null` when it is the element's label (its name, else its id:
    /// the usual case), `""` when the element has no path (then `pathParent` is 0 too).
    #[serde(rename = "pathLeaf")]
    pub path_leaf: Vec<Option<String>>,
    /// Six integers a row: the box's minimum corner x, y, z and its size x, y, z (millimetres).
    pub box_mm: Vec<i64>,
    /// Row of the element drawn in this one's place (an exact duplicate not drawn), else -1.
    #[serde(rename = "drawnBy")]
    pub drawn_by: Vec<i64>,
}

/// The whole file.
#[derive(Debug, Serialize, PartialEq)]
pub struct ElementIndex {
    pub format: &'static str,
    pub frame: &'static str,
    pub count: usize,
    pub dictionaries: Dictionaries,
    pub columns: Columns,
}

/// One element before sorting.
struct Row {
    key: (u32, u32, u32, u32),
    id: String,
    name: Option<String>,
    path: Option<String>,
    bounds: Aabb,
    component: ComponentId,
    alias_of: Option<ComponentId>,
}

/// Sorted distinct values (plus `null` first) and each one's code.
fn dictionary<'a>(values: impl Iterator<Item = Option<&'a str>>) -> Vec<Option<String>> {
    let distinct: std::collections::BTreeSet<&str> = values.flatten().collect();
    std::iter::once(None)
        .chain(distinct.into_iter().map(|s| Some(s.to_string())))
        .collect()
}

fn code_of(dict: &[Option<String>], v: Option<&str>) -> u32 {
    v.map_or(0, |v| {
        dict.binary_search_by(|d| d.as_deref().cmp(&Some(v)))
            .map_or(0, |i| i as u32)
    })
}

/// Whole millimetres around `b`, rounded outwards after the same tolerance the tile boxes get
/// (the f32 rounding of vertices written relative to a tile centre): min corner and size.
pub fn box_mm(b: &Aabb) -> [i64; 6] {
    let p = super::padded(b);
    let lo = (p.min * 1000.0).floor();
    let hi = (p.max * 1000.0).ceil();
    [
        lo.x as i64,
        lo.y as i64,
        lo.z as i64,
        (hi.x - lo.x) as i64,
        (hi.y - lo.y) as i64,
        (hi.z - lo.z) as i64,
    ]
}

fn split_path(path: &str) -> (Option<&str>, &str) {
    match path.rsplit_once('/') {
        Some((parent, leaf)) => (Some(parent), leaf),
        None => (None, path),
    }
}

impl ElementIndex {
    /// The index of every component of `scene` that has geometry (exact duplicates included, with
    /// the row drawn for them).
    pub fn from_scene(scene: &Scene) -> ElementIndex {
        let infos: Vec<_> = scene
            .components
            .iter()
            .filter(|c| !c.world_bounds.is_empty())
            .map(|c| (c, scene.element(c.id)))
            .collect();
        let paths: Vec<Option<String>> = infos
            .iter()
            .map(|(c, _)| c.node.map(|n| scene.node_path(n)))
            .collect();
        let dictionaries = Dictionaries {
            site: dictionary(infos.iter().map(|(_, i)| i.site.as_deref())),
            building: dictionary(infos.iter().map(|(_, i)| i.building.as_deref())),
            storey: dictionary(infos.iter().map(|(_, i)| i.storey.as_deref())),
            class: dictionary(infos.iter().map(|(_, i)| i.class.as_deref())),
            path_parent: dictionary(
                paths
                    .iter()
                    .map(|p| p.as_deref().and_then(|p| split_path(p).0)),
            ),
        };
        let d = &dictionaries;
        let mut rows: Vec<Row> = infos
            .into_iter()
            .zip(paths)
            .map(|((c, info), path)| Row {
                key: (
                    code_of(&d.site, info.site.as_deref()),
                    code_of(&d.building, info.building.as_deref()),
                    code_of(&d.storey, info.storey.as_deref()),
                    code_of(&d.class, info.class.as_deref()),
                ),
                id: info.key,
                name: info.name.filter(|n| !n.is_empty()),
                path,
                bounds: c.world_bounds,
                component: c.id,
                alias_of: c.alias_of,
            })
            .collect();
        // Ids are unique in a scene: the order is total, whatever the input order.
        rows.sort_by(|a, b| (a.key, &a.id).cmp(&(b.key, &b.id)));
        let row_of: BTreeMap<ComponentId, usize> = rows
            .iter()
            .enumerate()
            .map(|(i, r)| (r.component, i))
            .collect();
        let mut columns = Columns::default();
        for r in &rows {
            let (parent, leaf) = match r.path.as_deref().map(split_path) {
                Some((parent, leaf)) => (parent, Some(leaf)),
                None => (None, None),
            };
            columns.id.push(r.id.clone());
            columns.site.push(r.key.0);
            columns.building.push(r.key.1);
            columns.storey.push(r.key.2);
            columns.class.push(r.key.3);
            columns.path_parent.push(code_of(&d.path_parent, parent));
            // Left out when it is the label a reader already has (the name, else the id); a
            // missing path is an empty leaf under no parent, so that it stays apart.
            let label = r.name.as_deref().unwrap_or(&r.id);
            columns.path_leaf.push(match leaf {
                Some(leaf) if leaf == label => None,
                Some(leaf) => Some(leaf.to_string()),
                None => Some(String::new()),
            });
            columns.name.push(r.name.clone());
            columns.box_mm.extend(box_mm(&r.bounds));
            columns.drawn_by.push(
                r.alias_of
                    .and_then(|k| row_of.get(&k))
                    .map_or(-1, |&i| i as i64),
            );
        }
        ElementIndex {
            format: ELEMENT_INDEX_FORMAT,
            frame:
                "tileset frame (east-north-up metres, z-up, before the root transform), millimetres",
            count: rows.len(),
            dictionaries,
            columns,
        }
    }

    /// The file's bytes: compact JSON (one line).
    pub fn to_bytes(&self) -> Vec<u8> {
        serde_json::to_vec(self).expect("the element index serializes")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Component, ElementInfo, Mesh, Node, NodeId, Primitive};
    use glam::{DMat4, DVec3};

    /// Id, storey, class and offset of a test element.
    type Placed<'a> = (&'a str, Option<&'a str>, Option<&'a str>, [f64; 3]);

    /// A scene of unit triangles at the given offsets, each an element with these semantics,
    /// named `n<i>` under a site node.
    fn scene(elements: &[Placed]) -> Scene {
        scene_with(elements, |i, _| {
            (Some(format!("n{i}")), Some(format!("n{i}")))
        })
    }

    /// The same, each element's name and node name (no node: no path) chosen by `names`.
    fn scene_with(
        elements: &[Placed],
        names: impl Fn(usize, &str) -> (Option<String>, Option<String>),
    ) -> Scene {
        let mut s = Scene::default();
        let mesh = s.meshes.push(Mesh {
            name: None,
            primitives: vec![Primitive {
                material: None,
                positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.5]],
                normals: None,
                uvs: None,
                colors: None,
                indices: vec![0, 1, 2],
            }],
            local_bounds: None,
        });
        s.nodes.push(Node {
            name: Some("Site".into()),
            ..Node::default()
        });
        for (i, (key, storey, class, at)) in elements.iter().enumerate() {
            let (name, node_name) = names(i, key);
            let mut c = Component::new(mesh, DMat4::from_translation(DVec3::from_array(*at)));
            if let Some(node_name) = node_name {
                c.node = Some(NodeId(s.nodes.len() as u32));
                s.nodes.push(Node {
                    name: Some(node_name),
                    parent: Some(NodeId(0)),
                    ..Node::default()
                });
            }
            let info = ElementInfo {
                key: key.to_string(),
                name,
                storey: storey.map(Into::into),
                class: class.map(Into::into),
                ..ElementInfo::default()
            };
            s.push_component(c, &info);
        }
        s.finish();
        s
    }

    #[test]
    fn rows_are_grouped_by_storey_and_class_and_boxes_hold_the_geometry() {
        let s = scene(&[
            ("c", Some("OG"), Some("IfcWall"), [10.0, 0.0, 3.0]),
            ("a", Some("EG"), Some("IfcSlab"), [0.0, 0.0, 0.0]),
            ("b", Some("EG"), Some("IfcWall"), [-5.25, 1.0, 0.0]),
            ("d", None, None, [0.0, 0.0, 0.0]),
        ]);
        let ix = ElementIndex::from_scene(&s);
        assert_eq!(ix.count, 4);
        // No storey sorts first (code 0), then EG before OG; within EG the slab before the wall.
        assert_eq!(ix.columns.id, ["d", "a", "b", "c"]);
        assert_eq!(
            ix.dictionaries.storey,
            [None, Some("EG".into()), Some("OG".into())]
        );
        assert_eq!(ix.columns.storey, [0, 1, 1, 2]);
        let b = &ix.columns.box_mm[18..24];
        // The element at (10, 0, 3): its triangle spans 1 x 2 x 0.5 m.
        assert!(
            b[0] <= 10_000 && b[0] >= 9_999 && b[2] <= 3_000 && b[2] >= 2_999,
            "{b:?}"
        );
        assert!(b[0] + b[3] >= 11_000 && b[1] + b[4] >= 2_000 && b[2] + b[5] >= 3_500);
        assert!(b[3] <= 1_002 && b[4] <= 2_002 && b[5] <= 502, "{b:?}");
        // The path's leaf is the label (the name, else the id): not repeated; its parent is in
        // the dictionary.
        assert_eq!(ix.columns.path_leaf, [None, None, None, None]);
        assert_eq!(ix.dictionaries.path_parent, [None, Some("Site".into())]);
        assert!(ix.columns.path_parent.iter().all(|&p| p == 1));
        assert_eq!(ix.columns.drawn_by, [-1, -1, -1, -1]);
    }

    #[test]
    fn a_leaf_that_is_the_label_is_left_out_and_no_path_is_an_empty_leaf() {
        let s = scene_with(
            &[
                ("guid-a", None, None, [0.0, 0.0, 0.0]),
                ("guid-b", None, None, [1.0, 0.0, 0.0]),
                ("guid-c", None, None, [2.0, 0.0, 0.0]),
                ("guid-d", None, None, [3.0, 0.0, 0.0]),
            ],
            |i, key| match i {
                // No name: the id is the label.
                0 => (None, Some(key.to_string())),
                // A name the node does not carry.
                1 => (Some("Wall".into()), Some(key.to_string())),
                // No node, so no path.
                2 => (Some("Door".into()), None),
                _ => (Some("Slab".into()), Some("Slab".into())),
            },
        );
        let ix = ElementIndex::from_scene(&s);
        assert_eq!(ix.columns.id, ["guid-a", "guid-b", "guid-c", "guid-d"]);
        assert_eq!(
            ix.columns.path_leaf,
            [None, Some("guid-b".into()), Some(String::new()), None]
        );
        assert_eq!(ix.columns.path_parent, [1, 1, 0, 1]);
    }

    #[test]
    fn the_bytes_depend_on_the_scene_not_on_its_order() {
        let a = scene(&[
            ("x", Some("1"), None, [0.0, 0.0, 0.0]),
            ("y", Some("2"), None, [1.0, 0.0, 0.0]),
        ]);
        let b = scene(&[
            ("y", Some("2"), None, [1.0, 0.0, 0.0]),
            ("x", Some("1"), None, [0.0, 0.0, 0.0]),
        ]);
        let (ia, ib) = (ElementIndex::from_scene(&a), ElementIndex::from_scene(&b));
        assert_eq!(ia.columns.id, ib.columns.id);
        assert_eq!(ia.columns.box_mm, ib.columns.box_mm);
        assert_eq!(ia.dictionaries, ib.dictionaries);
        let v: serde_json::Value = serde_json::from_slice(&ia.to_bytes()).unwrap();
        assert_eq!(v["format"], ELEMENT_INDEX_FORMAT);
        assert_eq!(v["columns"]["box_mm"].as_array().unwrap().len(), 12);
    }

    #[test]
    fn duplicates_not_drawn_name_the_row_drawn_for_them() {
        let mut s = scene(&[
            ("kept", None, None, [0.0, 0.0, 0.0]),
            ("copy", None, None, [0.0, 0.0, 0.0]),
        ]);
        s.components[1].alias_of = Some(ComponentId(0));
        let ix = ElementIndex::from_scene(&s);
        assert_eq!(ix.columns.id, ["copy", "kept"]);
        assert_eq!(ix.columns.drawn_by, [1, -1]);
    }

    #[test]
    fn boxes_round_outwards_to_millimetres() {
        let b = Aabb {
            min: DVec3::new(-0.0004, 1.2341, 0.0),
            max: DVec3::new(0.0004, 1.2349, 2.0),
        };
        let [x, y, z, sx, sy, sz] = box_mm(&b);
        assert!(
            x as f64 / 1000.0 <= b.min.x
                && y as f64 / 1000.0 <= b.min.y
                && z as f64 / 1000.0 <= b.min.z
        );
        assert!((x + sx) as f64 / 1000.0 >= b.max.x && (y + sy) as f64 / 1000.0 >= b.max.y);
        assert!((z + sz) as f64 / 1000.0 >= b.max.z);
        assert_eq!((x, y, sy), (-1, 1233, 3));
    }
}
