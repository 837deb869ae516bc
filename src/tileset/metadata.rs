//! The metadata schema of a tileset (3D Tiles 1.1 metadata, as used by `EXT_structural_metadata`):
//! the fixed class of `schemas/bimtiles.schema.json` (id, name, path, source, IFC class, storey,
//! building, site, material), its enums filled with the values this scene uses, and one typed
//! property per property-set entry found in the input.
//!
//! Repeated strings (classes, storeys, materials, source files) are enums: a tile stores a 2-byte
//! code per element and the names once, in the schema. Property-set values are typed when every
//! value of a property has one type (numbers → FLOAT64, booleans → an enum), else text.
//!
//! In a campus ([`Scene::stable_layout`]), an enum value's code comes from its name (a fixed hash into the codes the enum's width
//! allows, the next free code on a collision, names taken in sorted order), not from its rank
//! among the values: a building added to or removed from a campus takes its own values with it
//! and leaves every other value's code, and so every tile that does not hold it, as it was
//! (`convert --update`). A single model's codes are dense, in first-use order: columns whose
//! values agree (one building, one site, one source file) are the same bytes and share one
//! bufferView.

use crate::encode::metadata::{ColumnData, PropertyTable, SchemaRef};
use crate::scene::{Component, ComponentId, ElementInfo, PropertyValue, Scene, SharedText};
use crate::transfer::copies_cost_less_than_a_request;
use serde_json::{json, Map, Value};
use std::collections::{BTreeMap, HashMap};

/// The base schema, written once, kept in `schemas/`.
pub const BASE_SCHEMA: &str = include_str!("../../schemas/bimtiles.schema.json");
pub const CLASS_ID: &str = "element";
/// The enum name that stands for "no value" (enum value 0 of every enum).
pub const NO_VALUE: &str = "(none)";

/// A text property-set entry becomes an enum when it has at most this many distinct values...
const ENUM_MAX_VALUES: usize = 4096;
/// ...and each is used at least this often on average (else the names in schema.json, fetched
/// once, would outweigh the 2-byte codes saved in the tiles).
const ENUM_MIN_USES_PER_VALUE: usize = 4;
/// `noData` of FLOAT64 properties: no real property value is this.
pub const NO_NUMBER: f64 = f64::MIN;

/// Where the tiles of a tileset find the metadata schema.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SchemaPlacement {
    /// One file, at this URI relative to a tile, fetched once and shared by every tile.
    File(String),
    /// In each tile, only the properties and enums its property table uses.
    Inline,
}

impl SchemaPlacement {
    /// Inline when every tile repeating the schema (`schema_bytes`, an upper bound of each tile's
    /// part of it) costs no more than the request the file would
    /// ([`copies_cost_less_than_a_request`]: always for a one-tile tileset, the same bytes and
    /// one round trip fewer). `content_tiles`: tiles that may have content, at most.
    /// (The file is a sequential request: CesiumJS reads a tile's `EXT_structural_metadata`
    /// schema before the tile can show, so `schemaUri` costs the first tile one more round trip
    /// after its GLB.)
    pub fn choose(content_tiles: usize, schema_bytes: usize, file_uri: &str) -> SchemaPlacement {
        match copies_cost_less_than_a_request(content_tiles as u64, schema_bytes as u64) {
            true => SchemaPlacement::Inline,
            false => SchemaPlacement::File(file_uri.into()),
        }
    }
}

/// Whether a table that shares the tileset's schema file writes a property of this type even when
/// none of its features has a value (all `noData`). The spec lets a table leave out any property
/// that is not `required`, but the official 3d-tiles-validator (0.6.1) stops with an internal
/// error on a table that leaves out an ENUM or numeric property of its class (it reads their
/// values to check enum codes and ranges), which teams that run it in CI read as an invalid
/// tileset. Tables are cheap to fill: columns of only `noData` are the same bytes and share one
/// buffer view per type. STRING properties stay out: it does not read them, and an all-empty
/// column would need a zero-length buffer view, which glTF forbids. An inline schema only
/// defines what its table holds, so there is nothing to fill.
fn fills_absent(placement: &SchemaPlacement, value_type: &ValueType) -> bool {
    matches!(placement, SchemaPlacement::File(_)) && *value_type != ValueType::Text
}

/// Where a property's values come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Column {
    Id,
    Name,
    Path,
    Source,
    Class,
    Storey,
    Building,
    Site,
    Material,
    /// Ids of the exact duplicates this element stands for.
    Aliases,
    /// The n-th property-set entry (`MetadataSchema::pset_keys`).
    Pset(usize),
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ValueType {
    Text,
    Float64,
    /// An enum of the schema, by id.
    Enum(String),
}

#[derive(Debug, Clone)]
pub struct PropertyDef {
    /// Property id in the schema (`^[a-zA-Z_][a-zA-Z0-9_]*$`).
    pub id: String,
    pub column: Column,
    pub value_type: ValueType,
}

/// One element's value of one property.
#[derive(Debug, Clone, PartialEq)]
pub enum MetaValue {
    Text(String),
    Number(f64),
    /// Enum code (index into the enum's values; 0 = none).
    Code(u16),
}

/// Which properties a tile's table carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TableScope {
    /// Every property (full-detail tiles).
    All,
    /// What names an element: simplified tiles, which a first view loads for the whole model at
    /// once. Left out, as the largest shares of such a table (docs/benchmarks.md): property sets,
    /// the hierarchy path (storey, building and site already place the element), and the name where
    /// the id is the glTF node path, which ends with it. Clicking an element there names it; its
    /// full-detail tile has the rest.
    Identity,
}

/// The schema of one tileset.
#[derive(Debug, Clone)]
pub struct MetadataSchema {
    pub properties: Vec<PropertyDef>,
    /// (property set, property name) of each `Column::Pset`.
    pub pset_keys: Vec<(String, String)>,
    /// Enum id → value names in first-use order ([`NO_VALUE`] first, code 0); their codes are
    /// [`MetadataSchema::enum_code`].
    pub enums: BTreeMap<String, Vec<String>>,
    enum_codes: HashMap<String, HashMap<String, u16>>,
    /// Kept component → ids of its aliases (exact duplicates not drawn), as a JSON array.
    aliases: HashMap<ComponentId, String>,
    base: Value,
}

/// Whether a component's id is its glTF node path (no GlobalId) and ends with its name (not
/// with a repeat number: `object#1`).
fn id_is_node_path(scene: &Scene, comp: &Component, info: &ElementInfo) -> bool {
    comp.node
        .is_some_and(|n| scene.nodes[n.index()].name_repeat == 0 && info.key == scene.node_path(n))
}

/// 64-bit FNV-1a of `s`: a hash fixed by its definition (the same on every platform and in every
/// version), unlike the standard library's.
fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Enum value name → code, dense: its index in `names`.
fn dense_codes_of(names: &[String]) -> HashMap<String, u16> {
    names
        .iter()
        .enumerate()
        .map(|(i, n)| (n.clone(), i as u16))
        .collect()
}

/// Enum value name → code, from the name. The first `fixed` names (the base schema's values) keep their index;
/// every other name takes the code its hash points at among those the enum's width allows
/// (1-255 for an enum of at most 256 values, else 1-65535), or the next free one, names taken in
/// sorted order: a pure function of the set of names in which one name more or less moves no
/// other code unless it took that code's place first.
fn codes_of(names: &[String], fixed: usize) -> HashMap<String, u16> {
    let mut codes: HashMap<String, u16> = names
        .iter()
        .take(fixed)
        .enumerate()
        .map(|(i, n)| (n.clone(), i as u16))
        .collect();
    let top: u64 = if names.len() <= 256 { 255 } else { 65_535 };
    let mut taken = vec![false; top as usize + 1];
    taken[0] = true;
    for &c in codes.values() {
        taken[c as usize] = true;
    }
    let mut free: Vec<&String> = names
        .iter()
        .skip(fixed)
        .filter(|n| !codes.contains_key(*n))
        .collect();
    free.sort();
    for n in free {
        let mut c = 1 + fnv1a(n) % top;
        while taken[c as usize] {
            c = c % top + 1;
        }
        taken[c as usize] = true;
        codes.insert(n.clone(), c as u16);
    }
    codes
}

/// A schema identifier from any text: non-alphanumerics become '_', no leading digit.
pub fn identifier(s: &str) -> String {
    let mut id: String = s
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    if id.is_empty() || id.starts_with(|c: char| c.is_ascii_digit()) {
        id.insert(0, '_');
    }
    id
}

/// The enums of a schema while it is built: value names in first-use order, and how many of
/// them are the base schema's (codes fixed by their index).
struct EnumTable {
    names: BTreeMap<String, Vec<String>>,
    seen: HashMap<String, std::collections::HashSet<String>>,
    fixed: HashMap<String, usize>,
}

impl EnumTable {
    /// The enums of the base schema, with their fixed values.
    fn from_base(base: &Value) -> EnumTable {
        let mut table = EnumTable {
            names: BTreeMap::new(),
            seen: HashMap::new(),
            fixed: HashMap::new(),
        };
        for (id, e) in base["enums"].as_object().expect("base enums") {
            let names: Vec<String> = e["values"]
                .as_array()
                .expect("enum values")
                .iter()
                .map(|v| v["name"].as_str().expect("enum value name").to_string())
                .collect();
            let fixed = names.len();
            table.insert(id.clone(), names);
            table.fixed.insert(id.clone(), fixed);
        }
        table
    }

    /// Adds enum `enum_id` with these value names, the first ([`NO_VALUE`]) fixed at code 0.
    fn insert(&mut self, enum_id: String, names: Vec<String>) {
        self.fixed.insert(enum_id.clone(), names.len().min(1));
        self.seen
            .insert(enum_id.clone(), names.iter().cloned().collect());
        self.names.insert(enum_id, names);
    }

    /// Adds value `v` (if any and new, while codes last) to enum `enum_id` of the base schema.
    fn add(&mut self, enum_id: &str, v: Option<&str>) {
        if let Some(v) = v {
            let seen = self.seen.get_mut(enum_id).expect("known enum");
            if !seen.contains(v) && seen.len() < u16::MAX as usize {
                seen.insert(v.to_string());
                let list = self.names.get_mut(enum_id).expect("known enum");
                list.push(v.to_string());
            }
        }
    }

    /// The code of every value of every enum: from its name ([`codes_of`]) when `by_name`, else
    /// its index ([`dense_codes_of`]).
    fn codes(&self, by_name: bool) -> HashMap<String, HashMap<String, u16>> {
        self.names
            .iter()
            .map(|(id, names)| {
                let codes = match by_name {
                    true => codes_of(names, self.fixed[id]),
                    false => dense_codes_of(names),
                };
                (id.clone(), codes)
            })
            .collect()
    }

    /// The values the scene uses of the fixed enums (source files, then each element's IFC
    /// class, storey, building, site and material), in first-use order.
    fn add_fixed_values(&mut self, scene: &Scene) {
        for s in &scene.sources {
            self.add(
                "sourceFile",
                s.path
                    .file_name()
                    .map(|n| n.to_string_lossy().to_string())
                    .as_deref(),
            );
        }
        for info in scene.elements.iter() {
            self.add("ifcClass", info.class.as_deref());
            self.add("storey", info.storey.as_deref());
            self.add("building", info.building.as_deref());
            self.add("site", info.site.as_deref());
            self.add("material", info.material.as_deref());
        }
    }
}

/// Which value types each property-set entry (set, name) has: (text, number, bool).
type PsetKinds = BTreeMap<(SharedText, SharedText), (bool, bool, bool)>;

/// The property-set entries of the scene and their value types.
fn pset_kinds(scene: &Scene) -> PsetKinds {
    let mut kinds = PsetKinds::new();
    for info in scene.elements.iter() {
        for p in &info.properties {
            let k = kinds.entry((p.set.clone(), p.name.clone())).or_default();
            match p.value {
                PropertyValue::Text(_) => k.0 = true,
                PropertyValue::Number(_) | PropertyValue::Integer(_) => k.1 = true,
                PropertyValue::Bool(_) => k.2 = true,
            }
        }
    }
    kinds
}

/// The properties of the fixed class (`schemas/bimtiles.schema.json`).
fn fixed_properties() -> Vec<PropertyDef> {
    [
        ("id", Column::Id, ValueType::Text),
        ("name", Column::Name, ValueType::Text),
        ("path", Column::Path, ValueType::Text),
        (
            "source",
            Column::Source,
            ValueType::Enum("sourceFile".into()),
        ),
        ("class", Column::Class, ValueType::Enum("ifcClass".into())),
        ("storey", Column::Storey, ValueType::Enum("storey".into())),
        (
            "building",
            Column::Building,
            ValueType::Enum("building".into()),
        ),
        ("site", Column::Site, ValueType::Enum("site".into())),
        (
            "material",
            Column::Material,
            ValueType::Enum("material".into()),
        ),
        ("aliases", Column::Aliases, ValueType::Text),
    ]
    .into_iter()
    .map(|(id, column, value_type)| PropertyDef {
        id: id.into(),
        column,
        value_type,
    })
    .collect()
}

/// Distinct values of a text-only property-set entry, in first-use order (collected up to one
/// more than [`ENUM_MAX_VALUES`]), with its use count.
#[derive(Default)]
struct Distinct {
    values: Vec<String>,
    seen: std::collections::HashSet<String>,
    uses: usize,
}

/// The distinct non-empty values of the text-only property-set entries.
fn distinct_text_values(
    scene: &Scene,
    kinds: &PsetKinds,
) -> HashMap<(SharedText, SharedText), Distinct> {
    let mut text_values: HashMap<(SharedText, SharedText), Distinct> = HashMap::new();
    for info in scene.elements.iter() {
        for p in &info.properties {
            if let PropertyValue::Text(t) = &p.value {
                if kinds[&(p.set.clone(), p.name.clone())] == (true, false, false) && !t.is_empty()
                {
                    let d = text_values
                        .entry((p.set.clone(), p.name.clone()))
                        .or_default();
                    d.uses += 1;
                    if d.values.len() <= ENUM_MAX_VALUES && d.seen.insert(t.clone()) {
                        d.values.push(t.clone());
                    }
                }
            }
        }
    }
    text_values
}

/// One property per property-set entry (ordered by set, then name), typed by its values, added
/// to `properties` (and an enum per text entry with few, often used values to `enums`);
/// returns the (set, name) of each.
fn add_pset_properties(
    kinds: PsetKinds,
    text_values: &HashMap<(SharedText, SharedText), Distinct>,
    properties: &mut Vec<PropertyDef>,
    enums: &mut EnumTable,
) -> Vec<(String, String)> {
    let mut pset_keys = Vec::new();
    for ((set, name), (text, number, boolean)) in kinds {
        let mut id = identifier(&format!("{set}_{name}"));
        while properties.iter().any(|p| p.id == id) {
            id.push('_');
        }
        let value_type = match (text, number, boolean) {
            (false, true, false) => ValueType::Float64,
            (false, false, true) => ValueType::Enum("boolean".into()),
            _ => match text_values.get(&(set.clone(), name.clone())) {
                // A text entry with few values, each used often ("Material: Concrete"): an
                // enum, 2 bytes a row and the names once in schema.json, instead of the
                // string and its 4-byte offset in every tile.
                Some(Distinct { values, uses, .. })
                    if values.len() <= ENUM_MAX_VALUES
                        && *uses >= ENUM_MIN_USES_PER_VALUE * values.len()
                        && !values.iter().any(|v| v == NO_VALUE) =>
                {
                    let mut enum_id = format!("pset_{id}");
                    while enums.names.contains_key(&enum_id) {
                        enum_id.push('_');
                    }
                    let names: Vec<String> = std::iter::once(NO_VALUE.to_string())
                        .chain(values.iter().cloned())
                        .collect();
                    enums.insert(enum_id.clone(), names);
                    ValueType::Enum(enum_id)
                }
                _ => ValueType::Text,
            },
        };
        properties.push(PropertyDef {
            id,
            column: Column::Pset(pset_keys.len()),
            value_type,
        });
        pset_keys.push((set.to_string(), name.to_string()));
    }
    pset_keys
}

/// Kept component -> ids of its aliases, as a JSON array: any id (node names hold spaces) reads
/// back unchanged.
fn alias_lists(scene: &Scene) -> HashMap<ComponentId, String> {
    let mut alias_ids: HashMap<ComponentId, Vec<String>> = HashMap::new();
    for c in &scene.components {
        if let Some(kept) = c.alias_of {
            alias_ids
                .entry(kept)
                .or_default()
                .push(scene.element(c.id).key);
        }
    }
    alias_ids
        .into_iter()
        .map(|(kept, ids)| (kept, Value::from(ids).to_string()))
        .collect()
}

impl MetadataSchema {
    /// Builds the schema for `scene`: enum values in first-use order, one property per
    /// property-set entry (ordered by set, then name).
    pub fn from_scene(scene: &Scene) -> MetadataSchema {
        let base: Value =
            serde_json::from_str(BASE_SCHEMA).expect("schemas/bimtiles.schema.json is valid JSON");
        let mut enums = EnumTable::from_base(&base);
        enums.add_fixed_values(scene);
        let kinds = pset_kinds(scene);
        let mut properties = fixed_properties();
        let text_values = distinct_text_values(scene, &kinds);
        let pset_keys = add_pset_properties(kinds, &text_values, &mut properties, &mut enums);
        debug_assert!(pset_keys.windows(2).all(|w| w[0] < w[1]));
        MetadataSchema {
            properties,
            pset_keys,
            enum_codes: enums.codes(scene.stable_layout),
            enums: enums.names,
            aliases: alias_lists(scene),
            base,
        }
    }

    /// The code of value `name` of enum `enum_id`, if the enum has it.
    pub fn enum_code(&self, enum_id: &str, name: &str) -> Option<u16> {
        self.enum_codes.get(enum_id)?.get(name).copied()
    }

    fn code(&self, enum_id: &str, v: Option<&str>) -> Option<MetaValue> {
        Some(MetaValue::Code(self.enum_code(enum_id, v?)?))
    }

    /// The value of property `p` for a component and its element (None: no value).
    pub fn value(
        &self,
        scene: &Scene,
        comp: &Component,
        info: &ElementInfo,
        p: usize,
    ) -> Option<MetaValue> {
        let text = |s: Option<String>| s.filter(|s| !s.is_empty()).map(MetaValue::Text);
        match self.properties[p].column {
            Column::Id => Some(MetaValue::Text(info.key.clone())),
            Column::Name => text(info.name.clone()),
            Column::Path => text(comp.node.map(|n| scene.node_path(n))),
            Column::Source => self.code(
                "sourceFile",
                scene
                    .sources
                    .get(comp.source as usize)
                    .and_then(|s| s.path.file_name())
                    .and_then(|n| n.to_str()),
            ),
            Column::Class => self.code("ifcClass", info.class.as_deref()),
            Column::Storey => self.code("storey", info.storey.as_deref()),
            Column::Building => self.code("building", info.building.as_deref()),
            Column::Site => self.code("site", info.site.as_deref()),
            Column::Material => self.code("material", info.material.as_deref()),
            Column::Aliases => text(self.aliases.get(&comp.id).cloned()),
            Column::Pset(k) => self.pset_value(&self.pset_entries(info), p, k),
        }
    }

    /// The value of property-set property `p` (column `k`) for an element whose entries are
    /// `entries` ([`Self::pset_entries`]).
    fn pset_value(
        &self,
        entries: &[(usize, &PropertyValue)],
        p: usize,
        k: usize,
    ) -> Option<MetaValue> {
        let at = entries.binary_search_by_key(&k, |&(j, _)| j).ok()?;
        match (&self.properties[p].value_type, entries[at].1) {
            (ValueType::Float64, PropertyValue::Number(x)) => Some(MetaValue::Number(*x)),
            (ValueType::Float64, PropertyValue::Integer(i)) => Some(MetaValue::Number(*i as f64)),
            (ValueType::Enum(_), PropertyValue::Bool(b)) => {
                self.code("boolean", Some(if *b { "true" } else { "false" }))
            }
            (ValueType::Enum(e), PropertyValue::Text(s)) => {
                self.code(e, Some(s.as_str()).filter(|s| !s.is_empty()))
            }
            (_, PropertyValue::Text(s)) if s.is_empty() => None,
            (_, PropertyValue::Text(s)) => Some(MetaValue::Text(s.clone())),
            (_, PropertyValue::Number(x)) => Some(MetaValue::Text(x.to_string())),
            (_, PropertyValue::Integer(i)) => Some(MetaValue::Text(i.to_string())),
            (_, PropertyValue::Bool(b)) => Some(MetaValue::Text(b.to_string())),
        }
    }

    /// An element's property-set entries by their column (`Column::Pset`), sorted, the first of
    /// a repeated entry kept: a table indexes each element once instead of scanning its entries
    /// for every column.
    fn pset_entries<'e>(&self, info: &'e ElementInfo) -> Vec<(usize, &'e PropertyValue)> {
        let mut entries: Vec<(usize, &PropertyValue)> = info
            .properties
            .iter()
            .filter_map(|q| {
                // `pset_keys` is sorted: the schema makes it from an ordered map.
                let k = self
                    .pset_keys
                    .binary_search_by(|(set, name)| {
                        (set.as_str(), name.as_str()).cmp(&(&*q.set, &*q.name))
                    })
                    .ok()?;
                Some((k, &q.value))
            })
            .collect();
        entries.sort_by_key(|&(k, _)| k);
        entries.dedup_by_key(|&mut (k, _)| k);
        entries
    }

    /// The property table of one tile's features: the properties some feature has a value for;
    /// the schema as `placement` says (the tileset's file, or inline with just the properties and
    /// enums of this table). With [`TableScope::Identity`] only what names an element (id, name
    /// unless the id ends with it, class, storey, building, site, material, source, and the
    /// duplicates it stands for).
    ///
    /// With the shared file, every ENUM and FLOAT64 property of the schema is in every table,
    /// with its `noData` where no feature has a value ([`fills_absent`]).
    pub fn property_table(
        &self,
        scene: &Scene,
        features: &[ComponentId],
        placement: &SchemaPlacement,
        scope: TableScope,
    ) -> PropertyTable {
        let elements: Vec<(&Component, ElementInfo)> = features
            .iter()
            .map(|&c| (scene.component(c), scene.element(c)))
            .collect();
        // An identity table leaves the property sets out: nothing to index.
        let entries: Vec<Vec<(usize, &PropertyValue)>> = elements
            .iter()
            .map(|(_, info)| match scope {
                TableScope::All => self.pset_entries(info),
                TableScope::Identity => Vec::new(),
            })
            .collect();
        let mut columns = Vec::new();
        let mut present = Vec::new();
        for (p, def) in self.properties.iter().enumerate() {
            let identity = scope == TableScope::Identity;
            let fill = fills_absent(placement, &def.value_type);
            let left_out = identity && matches!(def.column, Column::Pset(_) | Column::Path);
            if left_out && !fill {
                continue;
            }
            let values: Vec<Option<MetaValue>> = elements
                .iter()
                .zip(&entries)
                .map(|((comp, info), entries)| match def.column {
                    _ if left_out => None,
                    Column::Name if identity && id_is_node_path(scene, comp, info) => None,
                    Column::Pset(k) => self.pset_value(entries, p, k),
                    _ => self.value(scene, comp, info, p),
                })
                .collect();
            if values.iter().all(Option::is_none) && !fill {
                continue;
            }
            let col = match &def.value_type {
                ValueType::Text => ColumnData::Text(
                    values
                        .into_iter()
                        .map(|v| match v {
                            Some(MetaValue::Text(t)) => Some(t),
                            _ => None,
                        })
                        .collect(),
                ),
                ValueType::Float64 => ColumnData::Float64(
                    values
                        .into_iter()
                        .map(|v| match v {
                            Some(MetaValue::Number(x)) => x,
                            _ => NO_NUMBER,
                        })
                        .collect(),
                ),
                ValueType::Enum(e) => ColumnData::Enum {
                    codes: values
                        .into_iter()
                        .map(|v| match v {
                            Some(MetaValue::Code(c)) => c,
                            _ => 0,
                        })
                        .collect(),
                    one_byte: self.enum_is_one_byte(e),
                },
            };
            columns.push((def.id.clone(), col));
            present.push(p);
        }
        PropertyTable {
            schema: match placement {
                SchemaPlacement::File(uri) => SchemaRef::Uri(uri.to_string()),
                SchemaPlacement::Inline => SchemaRef::Inline(self.to_json(Some(&present))),
            },
            class: CLASS_ID.into(),
            count: features.len(),
            columns,
        }
    }

    /// Whether enum `id`'s codes fit in one byte (`valueType` UINT8; else the default UINT16): a
    /// byte per element and enum property saved in every tile.
    fn enum_is_one_byte(&self, id: &str) -> bool {
        self.enums.get(id).is_some_and(|v| v.len() <= 256)
    }

    /// The schema as JSON; with `only`, just those properties (by index) and the enums they use
    /// (what one tile needs inline).
    pub fn to_json(&self, only: Option<&[usize]>) -> Value {
        let mut schema = self.base.clone();
        let base_props = self.base["classes"][CLASS_ID]["properties"].clone();
        let mut props = Map::new();
        let mut used_enums = Vec::new();
        for (i, p) in self.properties.iter().enumerate() {
            if only.is_some_and(|o| !o.contains(&i)) {
                continue;
            }
            let def = match p.column {
                Column::Pset(k) => {
                    let (set, name) = &self.pset_keys[k];
                    let mut d = json!({"name": format!("{set}.{name}"), "description": format!("Property {name} of {set}")});
                    match &p.value_type {
                        ValueType::Text => {
                            d["type"] = json!("STRING");
                            d["noData"] = json!("");
                        }
                        ValueType::Float64 => {
                            d["type"] = json!("SCALAR");
                            d["componentType"] = json!("FLOAT64");
                            d["noData"] = json!(NO_NUMBER);
                        }
                        ValueType::Enum(e) => {
                            d["type"] = json!("ENUM");
                            d["enumType"] = json!(e);
                            d["noData"] = json!(NO_VALUE);
                        }
                    }
                    d
                }
                _ => base_props[&p.id].clone(),
            };
            if let ValueType::Enum(e) = &p.value_type {
                used_enums.push(e.clone());
            }
            props.insert(p.id.clone(), def);
        }
        schema["classes"][CLASS_ID]["properties"] = Value::Object(props);
        let mut enums = Map::new();
        for (id, names) in &self.enums {
            if only.is_some() && !used_enums.contains(id) {
                continue;
            }
            let mut e = self.base["enums"][id].clone();
            if self.enum_is_one_byte(id) {
                e["valueType"] = json!("UINT8");
            }
            let codes = &self.enum_codes[id];
            e["values"] = json!(names
                .iter()
                .map(|n| json!({"name": n, "value": codes[n]}))
                .collect::<Vec<_>>());
            enums.insert(id.clone(), e);
        }
        if enums.is_empty() {
            schema.as_object_mut().expect("object").remove("enums");
        } else {
            schema["enums"] = Value::Object(enums);
        }
        schema
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::*;
    use crate::transfer::SEQUENTIAL_REQUEST_WORTH_BYTES;

    fn scene_with(infos: Vec<ElementInfo>) -> Scene {
        let mut s = Scene::default();
        s.sources.push(SourceFile {
            path: "dir/model.glb".into(),
            bytes: 0,
        });
        s.meshes.push(Mesh::default());
        for (i, mut info) in infos.into_iter().enumerate() {
            if info.key.is_empty() {
                info.key = format!("k{i}");
                info.name = Some(format!("n{i}"));
            }
            s.push_component(Component::new(MeshId(0), glam::DMat4::IDENTITY), &info);
        }
        s
    }

    fn value_of(m: &MetadataSchema, s: &Scene, c: ComponentId, p: usize) -> Option<MetaValue> {
        m.value(s, s.component(c), &s.element(c), p)
    }

    fn prop(set: &str, name: &str, value: PropertyValue) -> Property {
        Property {
            set: set.into(),
            name: name.into(),
            value,
        }
    }

    #[test]
    fn table_columns_read_each_entry_as_value_finds_it() {
        let s = scene_with(vec![
            ElementInfo {
                properties: vec![
                    prop("B", "z", PropertyValue::Text("first".into())),
                    prop("A", "y", PropertyValue::Number(2.5)),
                    // A repeated entry: the first one is the element's value.
                    prop("B", "z", PropertyValue::Text("second".into())),
                    prop("A", "empty", PropertyValue::Text(String::new())),
                ],
                ..Default::default()
            },
            ElementInfo {
                properties: vec![prop("A", "y", PropertyValue::Integer(4))],
                ..Default::default()
            },
            ElementInfo::default(),
        ]);
        let m = MetadataSchema::from_scene(&s);
        let ids = [ComponentId(0), ComponentId(1), ComponentId(2)];
        let table = m.property_table(&s, &ids, &SchemaPlacement::Inline, TableScope::All);
        let column = |id: &str| {
            let p = m.properties.iter().position(|p| p.id == id).unwrap();
            let values: Vec<_> = ids.iter().map(|&c| value_of(&m, &s, c, p)).collect();
            let col = table.columns.iter().find(|c| c.0 == id).map(|c| &c.1);
            (values, col.cloned())
        };
        let (values, col) = column("B_z");
        assert_eq!(values[0], Some(MetaValue::Text("first".into())));
        assert_eq!(
            col,
            Some(ColumnData::Text(vec![Some("first".into()), None, None]))
        );
        let (values, col) = column("A_y");
        assert_eq!(values[1], Some(MetaValue::Number(4.0)));
        assert_eq!(col, Some(ColumnData::Float64(vec![2.5, 4.0, NO_NUMBER])));
        // An empty text is no value: no feature has one, so the table leaves the column out.
        assert_eq!(column("A_empty"), (vec![None, None, None], None));
    }

    #[test]
    fn enums_types_and_values() {
        let s = scene_with(vec![
            ElementInfo {
                class: Some("IfcWall".into()),
                storey: Some("L1".into()),
                properties: vec![
                    prop("Pset_WallCommon", "IsExternal", PropertyValue::Bool(true)),
                    prop("Qto", "Width", PropertyValue::Number(0.3)),
                    prop(
                        "Pset_WallCommon",
                        "Reference",
                        PropertyValue::Text("W-01".into()),
                    ),
                    prop("Mixed", "x", PropertyValue::Integer(3)),
                ],
                ..Default::default()
            },
            ElementInfo {
                class: Some("IfcWindow".into()),
                properties: vec![
                    prop("Qto", "Width", PropertyValue::Integer(1)),
                    prop("Mixed", "x", PropertyValue::Text("a".into())),
                ],
                ..Default::default()
            },
        ]);
        let m = MetadataSchema::from_scene(&s);
        assert_eq!(m.enums["ifcClass"], vec!["(none)", "IfcWall", "IfcWindow"]);
        let idx = |id: &str| m.properties.iter().position(|p| p.id == id).unwrap();
        assert_eq!(
            m.properties[idx("Qto_Width")].value_type,
            ValueType::Float64
        );
        assert_eq!(
            m.properties[idx("Pset_WallCommon_IsExternal")].value_type,
            ValueType::Enum("boolean".into())
        );
        assert_eq!(m.properties[idx("Mixed_x")].value_type, ValueType::Text);
        assert_eq!(
            value_of(&m, &s, ComponentId(1), idx("class")),
            m.enum_code("ifcClass", "IfcWindow").map(MetaValue::Code)
        );
        assert_eq!(value_of(&m, &s, ComponentId(1), idx("storey")), None);
        assert_eq!(
            value_of(&m, &s, ComponentId(1), idx("Qto_Width")),
            Some(MetaValue::Number(1.0))
        );
        assert_eq!(
            value_of(&m, &s, ComponentId(0), idx("Pset_WallCommon_IsExternal")),
            Some(MetaValue::Code(2))
        );
        assert_eq!(
            value_of(&m, &s, ComponentId(1), idx("Mixed_x")),
            Some(MetaValue::Text("a".into()))
        );
        assert_eq!(
            value_of(&m, &s, ComponentId(0), idx("source")),
            m.enum_code("sourceFile", "model.glb").map(MetaValue::Code)
        );
        let ids = [ComponentId(0), ComponentId(1)];
        let names = |t: PropertyTable| t.columns.into_iter().map(|c| c.0).collect::<Vec<_>>();
        let all = names(m.property_table(
            &s,
            &ids,
            &SchemaPlacement::File("s.json".into()),
            TableScope::All,
        ));
        assert!(all.contains(&"Qto_Width".to_string()) && all.contains(&"class".to_string()));
        let identity = names(m.property_table(
            &s,
            &ids,
            &SchemaPlacement::File("s.json".into()),
            TableScope::Identity,
        ));
        // Sharing schema.json, every ENUM and FLOAT64 property of the class is in the table
        // (the identity scope's property sets too, as noData); text ones only with values.
        assert_eq!(
            identity,
            [
                "id",
                "name",
                "source",
                "class",
                "storey",
                "building",
                "site",
                "material",
                "Pset_WallCommon_IsExternal",
                "Qto_Width"
            ]
        );
        let absent = |t: PropertyTable, id: &str| t.columns.into_iter().find(|c| c.0 == id);
        let file = SchemaPlacement::File("s.json".into());
        assert_eq!(
            absent(
                m.property_table(&s, &ids, &file, TableScope::Identity),
                "Qto_Width"
            ),
            Some((
                "Qto_Width".into(),
                ColumnData::Float64(vec![NO_NUMBER, NO_NUMBER])
            ))
        );
        assert_eq!(
            absent(
                m.property_table(&s, &ids, &file, TableScope::All),
                "building"
            ),
            Some((
                "building".into(),
                ColumnData::Enum {
                    codes: vec![0, 0],
                    one_byte: true
                }
            ))
        );
        let inline_identity =
            names(m.property_table(&s, &ids, &SchemaPlacement::Inline, TableScope::Identity));
        assert_eq!(inline_identity, ["id", "name", "source", "class", "storey"]);
        let full = m.to_json(None);
        assert_eq!(full["id"], "bimtiles");
        assert_eq!(
            full["classes"]["element"]["properties"]["Qto_Width"]["componentType"],
            "FLOAT64"
        );
        let sub = m.to_json(Some(&[idx("id"), idx("class")]));
        assert_eq!(
            sub["classes"]["element"]["properties"]
                .as_object()
                .unwrap()
                .len(),
            2
        );
        assert_eq!(sub["enums"].as_object().unwrap().len(), 1);
        // Inline: the table's own properties and the enums they use, nothing else.
        let inline = m.property_table(&s, &ids, &SchemaPlacement::Inline, TableScope::Identity);
        let SchemaRef::Inline(schema) = &inline.schema else {
            panic!("not inline: {:?}", inline.schema);
        };
        let props = schema["classes"]["element"]["properties"]
            .as_object()
            .unwrap();
        assert_eq!(props.keys().collect::<Vec<_>>().len(), inline.columns.len());
        for (id, _) in &inline.columns {
            assert_eq!(
                props[id], full["classes"]["element"]["properties"][id],
                "{id}"
            );
        }
        assert!(schema["enums"]
            .as_object()
            .unwrap()
            .contains_key("ifcClass"));
    }

    #[test]
    fn the_schema_goes_inline_when_its_copies_cost_less_than_a_round_trip() {
        let file = SchemaPlacement::File("../schema.json".into());
        let choose = |tiles, bytes| SchemaPlacement::choose(tiles, bytes, "../schema.json");
        // One tile: the same bytes either way, one request fewer inline.
        assert_eq!(choose(1, 10_000_000), SchemaPlacement::Inline);
        assert_eq!(choose(0, 10_000_000), SchemaPlacement::Inline);
        let worth = SEQUENTIAL_REQUEST_WORTH_BYTES;
        assert_eq!(choose(5, worth / 4), SchemaPlacement::Inline);
        assert_eq!(choose(6, worth / 4), file);
        assert_eq!(choose(usize::MAX, usize::MAX), file);
    }

    #[test]
    fn repeated_text_values_become_an_enum_and_unique_ones_stay_text() {
        let infos = (0..12)
            .map(|i| ElementInfo {
                properties: vec![
                    prop(
                        "Pset",
                        "Finish",
                        PropertyValue::Text(["Paint", "Tile", ""][i % 3].into()),
                    ),
                    prop("Pset", "Tag", PropertyValue::Text(format!("T-{i}"))),
                ],
                ..Default::default()
            })
            .collect();
        let s = scene_with(infos);
        let m = MetadataSchema::from_scene(&s);
        let idx = |id: &str| m.properties.iter().position(|p| p.id == id).unwrap();
        let finish = idx("Pset_Finish");
        let ValueType::Enum(e) = &m.properties[finish].value_type else {
            panic!(
                "Finish should be an enum: {:?}",
                m.properties[finish].value_type
            );
        };
        assert_eq!(m.enums[e], vec!["(none)", "Paint", "Tile"]);
        assert_eq!(
            value_of(&m, &s, ComponentId(1), finish),
            m.enum_code(e, "Tile").map(MetaValue::Code)
        );
        assert_eq!(
            value_of(&m, &s, ComponentId(2), finish),
            None,
            "empty text is no value"
        );
        assert_eq!(m.properties[idx("Pset_Tag")].value_type, ValueType::Text);
        let json = m.to_json(None);
        assert_eq!(
            json["classes"]["element"]["properties"]["Pset_Finish"]["enumType"],
            json!(e)
        );
        assert_eq!(json["enums"][e]["values"][2]["name"], "Tile");
        assert_eq!(
            json["enums"][e]["values"][2]["value"],
            m.enum_code(e, "Tile").unwrap()
        );
    }

    #[test]
    fn enum_codes_stay_when_a_value_goes() {
        let names = |n: &[&str]| -> Vec<String> {
            std::iter::once(NO_VALUE)
                .chain(n.iter().copied())
                .map(String::from)
                .collect()
        };
        let all: Vec<String> = (0..60).map(|i| format!("b{i:03}.glb")).collect();
        let refs: Vec<&str> = all.iter().map(String::as_str).collect();
        let before = codes_of(&names(&refs), 1);
        assert_eq!(before[NO_VALUE], 0);
        let distinct: std::collections::HashSet<u16> = before.values().copied().collect();
        assert_eq!(distinct.len(), before.len(), "codes are unique");
        assert!(before.values().all(|&c| c <= 255), "one byte");
        // One value gone (one campus building removed), another added at the end: the others keep
        // their codes, whatever their rank, unless they had collided with the one that went.
        let mut fewer: Vec<&str> = refs.clone();
        let gone = fewer.remove(30);
        fewer.push("z.glb");
        let after = codes_of(&names(&fewer), 1);
        let moved = refs
            .iter()
            .filter(|n| **n != gone && before[**n] != after[**n])
            .count();
        assert!(moved <= 2, "{moved} codes moved");
        // First-use order does not matter: the codes are a function of the set.
        let mut reversed = fewer.clone();
        reversed.reverse();
        assert_eq!(codes_of(&names(&reversed), 1), after);
        // Over 256 values: two-byte codes, all distinct.
        let many: Vec<String> = (0..1000).map(|i| format!("v{i}")).collect();
        let many_codes = codes_of(
            &names(&many.iter().map(String::as_str).collect::<Vec<_>>()),
            1,
        );
        let distinct: std::collections::HashSet<u16> = many_codes.values().copied().collect();
        assert_eq!(distinct.len(), 1001);
    }

    #[test]
    fn identifiers_are_valid() {
        assert_eq!(
            identifier("Pset_WallCommon.FireRating"),
            "Pset_WallCommon_FireRating"
        );
        assert_eq!(identifier("3D Höhe"), "_3D_H_he");
        assert_eq!(identifier(""), "_");
    }

    #[test]
    fn identity_tables_leave_out_paths_and_names_that_the_id_ends_with() {
        // Component 0: no GlobalId, its id is its node path; component 1: a GlobalId.
        let mut s = scene_with(vec![
            ElementInfo {
                name: Some("wall#0".into()),
                ..ElementInfo::keyed("building-0/wall#0")
            },
            ElementInfo {
                name: Some("Door".into()),
                ..ElementInfo::keyed("1CBNfY0004DZ4oDpWmD3am")
            },
        ]);
        s.nodes = vec![
            Node {
                name: Some("building-0".into()),
                parent: None,
                extras: None,
                name_repeat: 0,
            },
            Node {
                name: Some("wall#0".into()),
                parent: Some(NodeId(0)),
                extras: None,
                name_repeat: 0,
            },
            Node {
                name: Some("1CBNfY0004DZ4oDpWmD3am".into()),
                parent: Some(NodeId(0)),
                extras: None,
                name_repeat: 0,
            },
        ];
        s.components[0].node = Some(NodeId(1));
        s.components[1].node = Some(NodeId(2));
        let m = MetadataSchema::from_scene(&s);
        let ids = [ComponentId(0), ComponentId(1)];
        let column = |scope, id: &str| {
            m.property_table(&s, &ids, &SchemaPlacement::File("s.json".into()), scope)
                .columns
                .into_iter()
                .find(|c| c.0 == id)
                .map(|c| c.1)
        };
        let text = |v: &[Option<&str>]| {
            Some(ColumnData::Text(
                v.iter().map(|x| x.map(String::from)).collect(),
            ))
        };
        assert_eq!(
            column(TableScope::All, "path"),
            text(&[
                Some("building-0/wall#0"),
                Some("building-0/1CBNfY0004DZ4oDpWmD3am")
            ])
        );
        assert_eq!(column(TableScope::Identity, "path"), None);
        assert_eq!(
            column(TableScope::All, "name"),
            text(&[Some("wall#0"), Some("Door")])
        );
        assert_eq!(
            column(TableScope::Identity, "name"),
            text(&[None, Some("Door")])
        );
        assert_eq!(
            column(TableScope::Identity, "id"),
            text(&[Some("building-0/wall#0"), Some("1CBNfY0004DZ4oDpWmD3am")])
        );
    }
}
