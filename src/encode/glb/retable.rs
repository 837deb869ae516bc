//! A written tile's property table replaced (`EXT_structural_metadata`, 3D Tiles 1.1 metadata in
//! glTF), every other byte kept: when only its elements' metadata changed, an update writes the
//! same file a full encode of its content would, without that content. The encoder lays the
//! table's views out last (`GltfWriter::finish`), so the geometry's part of the BIN chunk, and
//! every view and accessor before the table's, do not move.

use super::builder::GltfBuilder;
use crate::encode::metadata::{write_property_table, PropertyTable};
use crate::glb_container::{chunks, glb_container};
use serde_json::Value;

/// `glb` (as this encoder wrote it) with `table` as its property table, and the table's bytes;
/// `None` when `glb` is not laid out as the encoder lays a tile out (another writer's file, or a
/// damaged one): the caller then encodes the content again.
pub fn replace_property_table(glb: &[u8], table: &PropertyTable) -> Option<(Vec<u8>, usize)> {
    let (json_bytes, bin) = chunks(glb)?;
    let mut root: Value = serde_json::from_slice(json_bytes).ok()?;
    // Written again from the parsed JSON: it must read back to the same bytes.
    if serde_json::to_vec(&root).ok()? != json_bytes {
        return None;
    }
    let views = root["bufferViews"].as_array()?.clone();
    let first = first_table_view(&root["extensions"]["EXT_structural_metadata"], views.len())?;
    let in_bin = |v: &Value| v["buffer"].as_u64() == Some(0);
    let end = |vs: &[Value]| -> Option<usize> {
        vs.iter().try_fold(0, |end, v| match bin_range(v) {
            Some(range) => Some(end.max(range?)),
            None => Some(end),
        })
    };
    // The table's views are in the BIN chunk, and nothing follows the last view.
    if !views[first..].iter().all(in_bin)
        || root["buffers"][0]["byteLength"].as_u64()? as usize != end(&views)?
        || bin.len() != end(&views)?.next_multiple_of(4)
    {
        return None;
    }
    let geometry_end = end(&views[..first])?;
    let mut b = GltfBuilder {
        bin: bin[..geometry_end].to_vec(),
        buffer_views: views[..first].to_vec(),
        ..Default::default()
    };
    let (ext, table_bytes) = write_property_table(table, &mut |bytes, align| {
        b.view_aligned(bytes, None, align)
    });
    root["bufferViews"] = Value::Array(b.buffer_views);
    root["buffers"][0]["byteLength"] = b.bin.len().into();
    root["extensions"]["EXT_structural_metadata"] = ext;
    let json = serde_json::to_vec(&root).ok()?;
    Some((glb_container(&json, &b.bin), table_bytes))
}

/// Where view `v`'s bytes end in the BIN chunk (buffer 0): its own range, or the range of its
/// `EXT_meshopt_compression` stream; `None` when it has none there (a fallback buffer's view),
/// `Some(None)` when its range does not read.
fn bin_range(v: &Value) -> Option<Option<usize>> {
    let stored = match &v["extensions"]["EXT_meshopt_compression"] {
        Value::Null => v,
        stream => stream,
    };
    if stored["buffer"].as_u64() != Some(0) {
        return None;
    }
    let (at, n) = (stored["byteOffset"].as_u64(), stored["byteLength"].as_u64());
    Some(at.zip(n).map(|(at, n)| (at + n) as usize))
}

/// The first of the views `ext` (the root `EXT_structural_metadata`) lays its property tables in,
/// when they are exactly the last views (of `view_count`); `view_count` for a table without any.
fn first_table_view(ext: &Value, view_count: usize) -> Option<usize> {
    let mut used: Vec<usize> = Vec::new();
    for t in ext["propertyTables"].as_array()? {
        for p in t["properties"].as_object()?.values() {
            for k in ["values", "stringOffsets", "arrayOffsets"] {
                if let Some(v) = p.get(k) {
                    used.push(v.as_u64()? as usize);
                }
            }
        }
    }
    used.sort_unstable();
    used.dedup();
    let first = used.first().copied().unwrap_or(view_count);
    (used.len() == view_count.checked_sub(first)? && used.last() < Some(&view_count))
        .then_some(first)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encode::glb::{encode_content, Compression, TileEncoding};
    use crate::encode::metadata::{ColumnData, SchemaRef};
    use crate::partition::content::{ContentPrimitive, TileContent};
    use crate::scene::{ComponentId, Scene};

    fn table(names: &[&str], heights: &[f64]) -> PropertyTable {
        PropertyTable {
            schema: SchemaRef::Uri("schema.json".into()),
            class: "element".into(),
            count: names.len(),
            columns: vec![
                (
                    "name".into(),
                    ColumnData::Text(names.iter().map(|n| Some(n.to_string())).collect()),
                ),
                ("height".into(), ColumnData::Float64(heights.to_vec())),
            ],
        }
    }

    /// Two features on two triangles, encoded with `compression` and `t` as their table.
    fn encoded(compression: Compression, t: &PropertyTable) -> Vec<u8> {
        let content = TileContent {
            features: vec![ComponentId(0), ComponentId(1)],
            primitives: vec![ContentPrimitive {
                positions: vec![
                    [0.0, 0.0, 0.0],
                    [1.0, 0.0, 0.0],
                    [0.0, 1.0, 0.0],
                    [2.0, 0.0, 0.5],
                    [3.0, 0.0, 0.5],
                    [2.0, 1.0, 0.5],
                ],
                normals: vec![[0.0, 0.0, 1.0]; 6],
                feature_ids: vec![0, 0, 0, 1, 1, 1],
                indices: vec![0, 1, 2, 3, 4, 5],
                ..Default::default()
            }],
            ..Default::default()
        };
        let enc = TileEncoding {
            compression,
            ..Default::default()
        };
        let make = |_: &[ComponentId]| t.clone();
        encode_content(&Scene::default(), &content, &enc, Some(&make))
            .unwrap()
            .glb
    }

    #[test]
    fn a_replaced_table_gives_the_file_the_encoder_writes() {
        let before = table(&["door", "wall"], &[2.1, 3.0]);
        // Longer strings and another number: the table's views grow and move.
        let after = table(&["front door of the hall", "wall"], &[2.25, 3.0]);
        for compression in [
            Compression::None,
            Compression::Quantized,
            Compression::Meshopt,
            Compression::Draco,
        ] {
            let old = encoded(compression, &before);
            let (new, _) = replace_property_table(&old, &after).expect("our own layout");
            assert_eq!(new, encoded(compression, &after), "{compression:?}");
            // And back.
            let (back, _) = replace_property_table(&new, &before).unwrap();
            assert_eq!(back, old, "{compression:?}");
        }
    }

    #[test]
    fn files_laid_out_otherwise_are_refused() {
        let t = table(&["door", "wall"], &[2.1, 3.0]);
        let glb = encoded(Compression::Meshopt, &t);
        assert!(replace_property_table(&glb, &t).is_some());
        // Cut short, or one byte more than its header says.
        assert!(replace_property_table(&glb[..glb.len() - 4], &t).is_none());
        let mut longer = glb.clone();
        longer.push(0);
        assert!(replace_property_table(&longer, &t).is_none());
        // JSON written by another writer (pretty-printed): not ours to patch.
        let (json, bin) = chunks(&glb).unwrap();
        let value: Value = serde_json::from_slice(json).unwrap();
        let pretty = glb_container(&serde_json::to_vec_pretty(&value).unwrap(), bin);
        assert!(replace_property_table(&pretty, &t).is_none());
        // A view after the table's.
        let mut moved = value.clone();
        let extra = serde_json::json!({"buffer": 0, "byteOffset": 0, "byteLength": 4});
        moved["bufferViews"].as_array_mut().unwrap().push(extra);
        let moved = glb_container(&serde_json::to_vec(&moved).unwrap(), bin);
        assert!(replace_property_table(&moved, &t).is_none());
        // No metadata at all.
        let mut bare = value;
        bare.as_object_mut().unwrap().remove("extensions");
        let bare = glb_container(&serde_json::to_vec(&bare).unwrap(), bin);
        assert!(replace_property_table(&bare, &t).is_none());
    }
}
