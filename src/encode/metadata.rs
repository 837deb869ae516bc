//! Writes a property table into a tile's glTF (`EXT_structural_metadata`, glTF extension of 3D
//! Tiles 1.1): one row per feature, one column per property, in the binary layout the extension
//! defines (strings as UTF-8 bytes plus offsets, FLOAT64, and enum codes, each aligned to its
//! size). String offsets take the smallest type that holds the column's byte length (UINT8, UINT16
//! or UINT32: coarse tiles' columns are short, so most take 1 or 2 bytes a row), enum codes the
//! width their schema enum declares. The schema itself is built by `tileset::metadata`; this module
//! only lays out bytes.

use serde_json::{json, Map, Value};

/// One column of a property table.
#[derive(Debug, Clone, PartialEq)]
pub enum ColumnData {
    /// STRING; `None` is written as the empty string (the property's `noData`).
    Text(Vec<Option<String>>),
    /// SCALAR FLOAT64 (missing values already replaced by the property's `noData`).
    Float64(Vec<f64>),
    /// ENUM codes, written as UINT8 when `one_byte` (the schema enum's `valueType`), else UINT16.
    Enum { codes: Vec<u16>, one_byte: bool },
}

/// Where a glTF finds its metadata schema.
#[derive(Debug, Clone, PartialEq)]
pub enum SchemaRef {
    /// The schema object itself, in the glTF.
    Inline(Value),
    /// A URI relative to the glTF (one schema file shared by every tile of a tileset; viewers
    /// fetch and cache it once).
    Uri(String),
}

/// A property table for one tile: its schema reference and one column per present property.
#[derive(Debug, Clone, PartialEq)]
pub struct PropertyTable {
    pub schema: SchemaRef,
    pub class: String,
    pub count: usize,
    pub columns: Vec<(String, ColumnData)>,
}

impl PropertyTable {
    /// Every part of the table as bytes, each length-prefixed (what a tile's key covers of its
    /// metadata): equal bytes, equal tables.
    pub fn key_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let mut put = |b: &[u8]| {
            out.extend_from_slice(&(b.len() as u64).to_le_bytes());
            out.extend_from_slice(b);
        };
        match &self.schema {
            SchemaRef::Inline(s) => put(&serde_json::to_vec(s).unwrap_or_default()),
            SchemaRef::Uri(u) => put(format!("uri {u}").as_bytes()),
        }
        put(self.class.as_bytes());
        put(&(self.count as u64).to_le_bytes());
        for (id, column) in &self.columns {
            put(id.as_bytes());
            match column {
                ColumnData::Text(values) => {
                    put(b"text");
                    for v in values {
                        match v {
                            Some(t) => put(t.as_bytes()),
                            None => put(&[0xff]),
                        }
                    }
                }
                ColumnData::Float64(values) => {
                    put(b"float64");
                    let bits: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
                    put(&bits);
                }
                ColumnData::Enum { codes, one_byte } => {
                    put(if *one_byte { b"enum8" } else { b"enum16" });
                    let bytes: Vec<u8> = codes.iter().flat_map(|c| c.to_le_bytes()).collect();
                    put(&bytes);
                }
            }
        }
        out
    }
}

/// Lays the table out with `view(bytes, alignment) -> bufferView index`; returns the root
/// extension object and the number of bytes written.
///
/// Columns with the same data share their bufferViews (the extension points a property at
/// bufferViews by index; nothing asks for one per property): in glTF exports whose node names
/// are the element ids, `id`, `name` and `path` are the same strings, a large share of a tile's
/// metadata (docs/benchmarks.md).
pub fn write_property_table(
    table: &PropertyTable,
    view: &mut dyn FnMut(&[u8], usize) -> usize,
) -> (Value, usize) {
    let mut props = Map::new();
    let mut bytes = 0;
    let mut written: Vec<(&ColumnData, Value)> = Vec::new();
    for (id, col) in &table.columns {
        if let Some((_, entry)) = written.iter().find(|(c, _)| same_bytes(c, col)) {
            props.insert(id.clone(), entry.clone());
            continue;
        }
        let entry = match col {
            ColumnData::Text(values) => {
                let mut data = Vec::new();
                let mut ends = Vec::with_capacity(values.len() + 1);
                ends.push(0);
                for v in values {
                    data.extend_from_slice(v.as_deref().unwrap_or("").as_bytes());
                    ends.push(data.len());
                }
                let (offsets, size, name) = offsets_of(&ends);
                bytes += data.len() + offsets.len();
                let values = view(&data, 1);
                let offs = view(&offsets, size);
                json!({"values": values, "stringOffsets": offs, "stringOffsetType": name})
            }
            ColumnData::Float64(values) => {
                let data: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
                bytes += data.len();
                json!({"values": view(&data, 8)})
            }
            ColumnData::Enum { codes, one_byte } => {
                let size = if *one_byte { 1 } else { 2 };
                let data = little_endian(codes.iter().map(|&c| u64::from(c)), size);
                bytes += data.len();
                json!({"values": view(&data, size)})
            }
        };
        written.push((col, entry.clone()));
        props.insert(id.clone(), entry);
    }
    let mut ext = json!({
        "propertyTables": [{"class": table.class, "count": table.count, "properties": props}],
    });
    match &table.schema {
        SchemaRef::Inline(s) => ext["schema"] = s.clone(),
        SchemaRef::Uri(u) => ext["schemaUri"] = json!(u),
    }
    bytes += serde_json::to_vec(&ext).map_or(0, |v| v.len());
    (ext, bytes)
}

/// String offsets (`ends`: 0, then the end of each string) in the smallest type that holds the
/// last: bytes, the type's size and its name.
fn offsets_of(ends: &[usize]) -> (Vec<u8>, usize, &'static str) {
    let last = ends.last().copied().unwrap_or(0);
    let (size, name) = if last <= u8::MAX as usize {
        (1, "UINT8")
    } else if last <= u16::MAX as usize {
        (2, "UINT16")
    } else {
        (4, "UINT32")
    };
    (
        little_endian(ends.iter().map(|&e| e as u64), size),
        size,
        name,
    )
}

/// Unsigned integers as `size`-byte little-endian values (each fits).
fn little_endian(values: impl Iterator<Item = u64>, size: usize) -> Vec<u8> {
    values
        .flat_map(|v| v.to_le_bytes().into_iter().take(size))
        .collect()
}

/// Whether two columns are laid out as the same bytes (a missing string is written as "").
fn same_bytes(a: &ColumnData, b: &ColumnData) -> bool {
    match (a, b) {
        (ColumnData::Text(x), ColumnData::Text(y)) => {
            x.len() == y.len()
                && x.iter()
                    .zip(y)
                    .all(|(p, q)| p.as_deref().unwrap_or("") == q.as_deref().unwrap_or(""))
        }
        (ColumnData::Float64(x), ColumnData::Float64(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits())
        }
        (
            ColumnData::Enum {
                codes: x,
                one_byte: a,
            },
            ColumnData::Enum {
                codes: y,
                one_byte: b,
            },
        ) => x == y && a == b,
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn enum_codes(codes: Vec<u16>) -> ColumnData {
        ColumnData::Enum {
            codes,
            one_byte: false,
        }
    }

    #[test]
    fn key_bytes_tell_every_value_apart() {
        let table = |name: &str, height: f64, code: u16| PropertyTable {
            schema: SchemaRef::Uri("schema.json".into()),
            class: "element".into(),
            count: 2,
            columns: vec![
                (
                    "name".into(),
                    ColumnData::Text(vec![Some(name.into()), None]),
                ),
                ("height".into(), ColumnData::Float64(vec![height, 2.0])),
                ("class".into(), enum_codes(vec![code, 2])),
            ],
        };
        let a = table("Wall", 1.0, 1).key_bytes();
        assert_eq!(a, table("Wall", 1.0, 1).key_bytes());
        for other in [
            table("Wall ", 1.0, 1),
            table("Wall", 1.0 + f64::EPSILON, 1),
            table("Wall", 1.0, 3),
        ] {
            assert_ne!(a, other.key_bytes());
        }
        // Fields cannot run into each other.
        let mut t = table("Wall", 1.0, 1);
        t.columns[0].1 = ColumnData::Text(vec![Some("Wa".into()), Some("ll".into())]);
        assert_ne!(a, t.key_bytes());
    }

    #[test]
    fn identical_columns_share_their_buffer_views() {
        let ids = ColumnData::Text(vec![Some("a1".into()), Some("b2".into())]);
        let table = PropertyTable {
            schema: SchemaRef::Uri("schema.json".into()),
            class: "element".into(),
            count: 2,
            columns: vec![
                ("id".into(), ids.clone()),
                ("name".into(), ids),
                (
                    "path".into(),
                    ColumnData::Text(vec![Some("a1".into()), None]),
                ),
                ("class".into(), enum_codes(vec![1, 2])),
                ("storey".into(), enum_codes(vec![1, 2])),
                ("height".into(), ColumnData::Float64(vec![1.0, 2.0])),
            ],
        };
        let mut views: Vec<Vec<u8>> = Vec::new();
        let (ext, _) = write_property_table(&table, &mut |b, _| {
            views.push(b.to_vec());
            views.len() - 1
        });
        let p = &ext["propertyTables"][0]["properties"];
        assert_eq!(p["id"], p["name"]);
        assert_ne!(p["id"]["values"], p["path"]["values"]);
        assert_eq!(p["class"], p["storey"]);
        // id/name: 2 views, path: 2, class/storey: 1, height: 1.
        assert_eq!(views.len(), 6);
        let v = p["path"]["values"].as_u64().unwrap() as usize;
        assert_eq!(views[v], b"a1");
    }

    #[test]
    fn offsets_and_enum_codes_take_the_smallest_declared_width() {
        let lay_out = |columns: Vec<(String, ColumnData)>| {
            let table = PropertyTable {
                schema: SchemaRef::Uri("schema.json".into()),
                class: "element".into(),
                count: 2,
                columns,
            };
            let mut views: Vec<Vec<u8>> = Vec::new();
            let (ext, _) = write_property_table(&table, &mut |b, _| {
                views.push(b.to_vec());
                views.len() - 1
            });
            (ext["propertyTables"][0]["properties"].clone(), views)
        };
        let text = |n: usize| ColumnData::Text(vec![Some("x".repeat(n)), Some("yz".into())]);
        for (n, ty, offsets) in [
            (253, "UINT8", vec![0, 253, 255]),
            (254, "UINT16", vec![0, 0, 254, 0, 0, 1]),
            (
                65_534,
                "UINT32",
                vec![0, 0, 0, 0, 254, 255, 0, 0, 0, 0, 1, 0],
            ),
        ] {
            let (p, views) = lay_out(vec![("id".into(), text(n))]);
            assert_eq!(p["id"]["stringOffsetType"], ty, "{n}");
            let o = p["id"]["stringOffsets"].as_u64().unwrap() as usize;
            assert_eq!(views[o], offsets, "{n}");
        }
        let (p, views) = lay_out(vec![
            (
                "a".into(),
                ColumnData::Enum {
                    codes: vec![3, 200],
                    one_byte: true,
                },
            ),
            ("b".into(), enum_codes(vec![3, 200])),
        ]);
        let at = |k: &str| views[p[k]["values"].as_u64().unwrap() as usize].clone();
        assert_eq!(at("a"), vec![3, 200]);
        assert_eq!(
            at("b"),
            vec![3, 0, 200, 0],
            "a different width is not shared"
        );
    }
}
