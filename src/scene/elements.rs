//! Per-element metadata (identity, BIM semantics, property sets) kept as compact records, in memory
//! or spilled to a temporary file: how `--memory-budget` bounds the metadata a conversion holds
//! ("bounded memory"; the geometry's counterpart is [`super::store`]).
//!
//! As Rust values an element costs about a kilobyte (its `ElementInfo`, key, name and GlobalId
//! strings, property vectors), gigabytes for a site of a million elements once the allocator's
//! fragmentation is counted, at any budget (docs/benchmarks.md). Here each element is one byte
//! record: strings as length and bytes, repeated texts (classes, storeys, property names) as
//! indices into one table of distinct values, numbers as varints. Records fill fixed-size chunks;
//! past the store's metadata share of the budget, a full chunk goes to an unnamed temporary file
//! and records are read back from it with positioned reads (as geometry is). Stages ask for an
//! element's [`ElementInfo`] when they need it (the metadata encoder, per tile) or walk all of them
//! in order (the schema).
//!
//! Records hold exactly what was pushed, so a spilled table gives the same tiles as one that did
//! not spill.

use super::store::SpillFile;
use super::{ElementInfo, Property, PropertyValue, SharedText};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

/// Records are packed into chunks of a sixteenth of the table's resident limit, between
/// [`MIN_CHUNK_BYTES`] and [`CHUNK_BYTES`] (a record longer than a chunk gets one of its own), so
/// the chunk being filled stays small against the limit. Spilled chunks are read whole when the
/// table is walked in order, and a record at a time for single lookups.
const CHUNK_BYTES: usize = 256 * 1024;
const MIN_CHUNK_BYTES: usize = 4096;

/// Where one element's record is.
#[derive(Debug, Clone, Copy)]
struct RecordPos {
    chunk: u32,
    offset: u32,
    len: u32,
}

#[derive(Debug, Clone)]
enum Chunk {
    Resident(Arc<[u8]>),
    Spilled {
        file: Arc<SpillFile>,
        offset: u64,
        len: usize,
    },
}

/// Figures of a table, for the report.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ElementStats {
    pub elements: usize,
    /// Distinct shared texts (classes, storeys, property names...).
    pub shared_texts: usize,
    pub resident_bytes: usize,
    pub spilled_bytes: u64,
}

/// The elements of a scene, `get(i)` describing component `i` (see the module documentation).
#[derive(Debug, Clone)]
pub struct ElementTable {
    texts: Vec<SharedText>,
    text_ids: HashMap<SharedText, u32>,
    records: Vec<RecordPos>,
    chunks: Vec<Chunk>,
    /// The chunk being filled (not yet in `chunks`), sealed at `chunk_bytes`.
    open: Vec<u8>,
    chunk_bytes: usize,
    /// Sealed chunk bytes kept in memory, and the limit past which they spill.
    resident_bytes: usize,
    resident_limit: usize,
    spill_dir: Option<PathBuf>,
    spill: Option<Arc<SpillFile>>,
    spilled_bytes: u64,
    /// The first spill error (the table then keeps its chunks in memory); said in the report.
    spill_error: Option<String>,
}

impl Default for ElementTable {
    /// A table under the process's budget ([`super::set_memory_budget`]).
    fn default() -> Self {
        let limits = super::StoreLimits::from_budget(super::memory_budget().as_ref());
        ElementTable::with_limit(limits.metadata_bytes, limits.spill_dir)
    }
}

impl ElementTable {
    /// A table that keeps up to `resident_limit` bytes of records in memory.
    pub fn with_limit(resident_limit: usize, spill_dir: Option<PathBuf>) -> ElementTable {
        ElementTable {
            texts: Vec::new(),
            text_ids: HashMap::new(),
            records: Vec::new(),
            chunks: Vec::new(),
            open: Vec::new(),
            chunk_bytes: (resident_limit / 16).clamp(MIN_CHUNK_BYTES, CHUNK_BYTES),
            resident_bytes: 0,
            resident_limit,
            spill_dir,
            spill: None,
            spilled_bytes: 0,
            spill_error: None,
        }
    }

    pub fn len(&self) -> usize {
        self.records.len()
    }
    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    pub fn reserve(&mut self, n: usize) {
        self.records.reserve_exact(n);
    }

    /// Appends an element's record.
    pub fn push(&mut self, info: &ElementInfo) {
        let mut rec = std::mem::take(&mut self.open);
        let start = rec.len();
        self.encode(info, &mut rec);
        let len = rec.len() - start;
        self.open = rec;
        if start > 0 && self.open.len() > self.chunk_bytes {
            // The record does not fit the open chunk: seal what was there, start anew with it.
            let tail = self.open.split_off(start);
            self.seal();
            self.open = tail;
        }
        let offset = self.open.len() - len;
        self.records.push(RecordPos {
            chunk: self.chunks.len() as u32,
            offset: offset as u32,
            len: len as u32,
        });
        if self.open.len() >= self.chunk_bytes {
            self.seal();
        }
    }

    /// Element `i` (panics past the end, as indexing does).
    pub fn get(&self, i: usize) -> ElementInfo {
        let r = self.records[i];
        let (s, e) = (r.offset as usize, (r.offset + r.len) as usize);
        match self.chunks.get(r.chunk as usize) {
            None => self.decode(&self.open[s..e]),
            Some(Chunk::Resident(b)) => self.decode(&b[s..e]),
            Some(Chunk::Spilled { file, offset, .. }) => {
                self.decode(&file.read(offset + r.offset as u64, r.len as usize))
            }
        }
    }

    /// Every element in order, a spilled chunk read once.
    pub fn iter(&self) -> impl Iterator<Item = ElementInfo> + '_ {
        let mut chunk: Option<(u32, Arc<[u8]>)> = None;
        self.records.iter().map(move |r| {
            let (s, e) = (r.offset as usize, (r.offset + r.len) as usize);
            let bytes: &[u8] = match self.chunks.get(r.chunk as usize) {
                None => &self.open[s..e],
                Some(Chunk::Resident(b)) => &b[s..e],
                Some(Chunk::Spilled { file, offset, len }) => {
                    if chunk.as_ref().is_none_or(|(k, _)| *k != r.chunk) {
                        chunk = Some((r.chunk, file.read(*offset, *len).into()));
                    }
                    &chunk.as_ref().expect("just read").1[s..e]
                }
            };
            self.decode(bytes)
        })
    }

    /// Rewrites every element with `f` (a manifest prefixes clashing keys and sets the building).
    pub fn map(self, mut f: impl FnMut(&mut ElementInfo)) -> ElementTable {
        let mut out = ElementTable::with_limit(self.resident_limit, self.spill_dir.clone());
        out.reserve(self.len());
        for mut info in self.iter() {
            f(&mut info);
            out.push(&info);
        }
        out
    }

    /// Appends another scene's elements (re-encoded: the two tables number their texts apart).
    pub fn append(&mut self, other: ElementTable) {
        if self.is_empty() && self.spill.is_none() && other.resident_limit == self.resident_limit {
            *self = other;
            return;
        }
        self.reserve(other.len());
        for info in other.iter() {
            self.push(&info);
        }
    }

    pub fn stats(&self) -> ElementStats {
        ElementStats {
            elements: self.len(),
            shared_texts: self.texts.len(),
            resident_bytes: self.resident_bytes + self.open.capacity(),
            spilled_bytes: self.spilled_bytes,
        }
    }

    /// Why records stayed in memory past the budget (the spill file could not be written).
    pub fn spill_error(&self) -> Option<&str> {
        self.spill_error.as_deref()
    }

    /// Moves the open chunk into `chunks`: kept in memory under the limit, else spilled.
    fn seal(&mut self) {
        let bytes = std::mem::take(&mut self.open);
        if bytes.is_empty() {
            return;
        }
        if self.resident_bytes + bytes.len() > self.resident_limit && self.spill_error.is_none() {
            match self.spill_chunk(&bytes) {
                Ok(chunk) => {
                    self.spilled_bytes += bytes.len() as u64;
                    self.chunks.push(chunk);
                    return;
                }
                Err(e) => self.spill_error = Some(e.to_string()),
            }
        }
        self.resident_bytes += bytes.len();
        self.chunks.push(Chunk::Resident(bytes.into()));
    }

    fn spill_chunk(&mut self, bytes: &[u8]) -> std::io::Result<Chunk> {
        let file = match &self.spill {
            Some(f) => f.clone(),
            None => {
                let f = Arc::new(SpillFile::create(self.spill_dir.as_deref())?);
                self.spill = Some(f.clone());
                f
            }
        };
        let offset = file.append(bytes)?;
        Ok(Chunk::Spilled {
            file,
            offset,
            len: bytes.len(),
        })
    }

    fn text_id(&mut self, t: &SharedText) -> u32 {
        if let Some(&id) = self.text_ids.get(t) {
            return id;
        }
        let id = self.texts.len() as u32;
        self.texts.push(t.clone());
        self.text_ids.insert(t.clone(), id);
        id
    }

    fn encode(&mut self, info: &ElementInfo, out: &mut Vec<u8>) {
        put_str(out, &info.key);
        let name_is_key = info.name.as_deref() == Some(info.key.as_str());
        let guid_is_key = info.guid.as_deref() == Some(info.key.as_str());
        let flags = u8::from(info.name.is_some())
            | u8::from(name_is_key) << 1
            | u8::from(info.guid.is_some()) << 2
            | u8::from(guid_is_key) << 3;
        out.push(flags);
        if let (Some(n), false) = (&info.name, name_is_key) {
            put_str(out, n);
        }
        if let (Some(g), false) = (&info.guid, guid_is_key) {
            put_str(out, g);
        }
        for t in [
            &info.class,
            &info.storey,
            &info.building,
            &info.site,
            &info.material,
        ] {
            let id = t.as_ref().map_or(0, |t| self.text_id(t) as u64 + 1);
            put_varint(out, id);
        }
        put_varint(out, info.properties.len() as u64);
        for p in &info.properties {
            let (set, name) = (self.text_id(&p.set), self.text_id(&p.name));
            put_varint(out, set as u64);
            put_varint(out, name as u64);
            match &p.value {
                PropertyValue::Text(t) => {
                    out.push(0);
                    put_str(out, t);
                }
                PropertyValue::Number(x) => {
                    out.push(1);
                    out.extend_from_slice(&x.to_le_bytes());
                }
                PropertyValue::Integer(i) => {
                    out.push(2);
                    put_varint(out, ((i << 1) ^ (i >> 63)) as u64);
                }
                PropertyValue::Bool(b) => out.push(3 + u8::from(*b)),
            }
        }
    }

    fn decode(&self, bytes: &[u8]) -> ElementInfo {
        let mut r = Cursor { bytes, at: 0 };
        let key = r.string();
        let flags = r.byte();
        let name = match (flags & 1 != 0, flags & 2 != 0) {
            (false, _) => None,
            (true, true) => Some(key.clone()),
            (true, false) => Some(r.string()),
        };
        let guid = match (flags & 4 != 0, flags & 8 != 0) {
            (false, _) => None,
            (true, true) => Some(key.clone()),
            (true, false) => Some(r.string()),
        };
        let mut shared = || match r.varint() {
            0 => None,
            id => Some(self.texts[id as usize - 1].clone()),
        };
        let (class, storey, building, site, material) =
            (shared(), shared(), shared(), shared(), shared());
        let count = r.varint() as usize;
        let mut properties = Vec::with_capacity(count);
        for _ in 0..count {
            let set = self.texts[r.varint() as usize].clone();
            let name = self.texts[r.varint() as usize].clone();
            let value = match r.byte() {
                0 => PropertyValue::Text(r.string()),
                1 => PropertyValue::Number(f64::from_le_bytes(
                    r.take(8).try_into().expect("8 bytes"),
                )),
                2 => {
                    let z = r.varint();
                    PropertyValue::Integer((z >> 1) as i64 ^ -((z & 1) as i64))
                }
                tag => PropertyValue::Bool(tag == 4),
            };
            properties.push(Property { set, name, value });
        }
        ElementInfo {
            key,
            name,
            guid,
            class,
            storey,
            building,
            site,
            material,
            properties,
        }
    }
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push(v as u8 | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    put_varint(out, s.len() as u64);
    out.extend_from_slice(s.as_bytes());
}

/// Reads a record the table wrote itself (so its bounds and UTF-8 are trusted: a failure is a bug).
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> &'a [u8] {
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        s
    }
    fn byte(&mut self) -> u8 {
        self.take(1)[0]
    }
    fn varint(&mut self) -> u64 {
        let (mut v, mut shift) = (0u64, 0);
        loop {
            let b = self.byte();
            v |= ((b & 0x7f) as u64) << shift;
            if b < 0x80 {
                return v;
            }
            shift += 7;
        }
    }
    fn string(&mut self) -> String {
        let n = self.varint() as usize;
        String::from_utf8(self.take(n).to_vec()).expect("a record holds the UTF-8 it was given")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn element(i: usize) -> ElementInfo {
        let t = |s: &str| -> SharedText { Arc::from(s) };
        let guid = format!("{i:022}");
        ElementInfo {
            key: if i % 3 == 0 {
                guid.clone()
            } else {
                format!("site/b/{i}")
            },
            name: match i % 4 {
                0 => None,
                1 => Some(guid.clone()),
                _ => Some(format!("Wall {i} é")),
            },
            guid: (i % 5 != 0).then_some(guid),
            class: Some(t(["IfcWall", "IfcSlab", "IfcDoor"][i % 3])),
            storey: (i % 2 == 0).then(|| t("Level 1")),
            building: Some(t("B")),
            site: None,
            material: (i % 7 == 0).then(|| t("Concrete")),
            properties: (0..i % 4)
                .map(|k| Property {
                    set: t("Pset_WallCommon"),
                    name: t(["Width", "Count", "IsExternal", "Reference"][k]),
                    value: match k {
                        0 => PropertyValue::Number(i as f64 * -0.25),
                        1 => PropertyValue::Integer(i as i64 - 500),
                        2 => PropertyValue::Bool(i % 2 == 0),
                        _ => PropertyValue::Text(format!("ref {i}")),
                    },
                })
                .collect(),
        }
    }

    #[test]
    fn records_read_back_as_pushed_resident_and_spilled() {
        let all: Vec<ElementInfo> = (0..20_000).map(element).collect();
        for limit in [usize::MAX, 0, 300_000] {
            let mut t = ElementTable::with_limit(limit, None);
            for e in &all {
                t.push(e);
            }
            let stats = t.stats();
            assert_eq!(stats.elements, all.len());
            if limit == 0 {
                assert!(stats.spilled_bytes > 0, "{stats:?}");
            }
            assert_eq!(t.spill_error(), None);
            for i in [0, 1, 7, 9_999, 19_999] {
                assert_eq!(t.get(i), all[i], "element {i} at limit {limit}");
            }
            assert!(
                t.iter().eq(all.iter().cloned()),
                "in order at limit {limit}"
            );
        }
    }

    #[test]
    fn a_record_longer_than_a_chunk_gets_its_own() {
        let mut big = element(1);
        big.properties[0].value = PropertyValue::Text("x".repeat(3 * CHUNK_BYTES));
        let mut t = ElementTable::with_limit(0, None);
        t.push(&element(2));
        t.push(&big);
        t.push(&element(3));
        assert_eq!(t.get(1), big);
        assert!(t.iter().eq([element(2), big, element(3)]));
    }

    #[test]
    fn map_and_append_keep_order_and_texts() {
        let mut a = ElementTable::with_limit(0, None);
        let mut b = ElementTable::with_limit(usize::MAX, None);
        for i in 0..100 {
            a.push(&element(i));
            b.push(&element(1000 + i));
        }
        let b = b.map(|e| e.building = Some(Arc::from("Other")));
        a.append(b);
        assert_eq!(a.len(), 200);
        assert_eq!(a.get(5), element(5));
        let mut want = element(1042);
        want.building = Some(Arc::from("Other"));
        assert_eq!(a.get(142), want);
        // Repeated texts are stored once.
        assert!(a.stats().shared_texts < 16, "{:?}", a.stats());
    }

    #[test]
    fn an_unwritable_spill_folder_keeps_records_in_memory_and_says_why() {
        let mut t = ElementTable::with_limit(0, Some("/nonexistent/bimtiles-spill".into()));
        for i in 0..5_000 {
            t.push(&element(i));
        }
        assert!(t.spill_error().is_some());
        assert_eq!(t.get(4_321), element(4_321));
    }
}
