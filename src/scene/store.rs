//! Mesh geometry kept in memory or spilled to a temporary file: how `--memory-budget` bounds the
//! geometry a conversion holds ("bounded memory": a scene larger than the machine's memory).
//!
//! Every mesh of a [`Scene`](super::Scene) lives in one slot of a [`MeshStore`]. While the
//! geometry held in memory stays under the store's resident limit, a pushed mesh stays there; past
//! it, the mesh is written to an unnamed temporary file (gone with the process, even a killed one)
//! and read back on use, through a small LRU cache bounded in bytes too. Stages get `Arc<Mesh>`
//! and drop it when done, so what a stage holds is what it works on, not the input. The figures
//! that planning needs without geometry (triangles, vertices, bytes, local box) stay in memory for
//! every slot.
//!
//! Spilled bytes are the in-memory values unchanged (native endianness: the file never leaves the
//! process), so a scene that spilled converts to exactly the same tiles as one that did not.
//! Records are read with positioned reads rather than a mapping: mapped pages count towards the
//! process's resident size until unmapped, page-cache pages read through `pread` do not, and the
//! kernel reclaims them under pressure.

use super::{Aabb, MaterialId, Mesh, MeshId, Primitive};
use glam::DVec3;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};

/// The budget a process converts under (`--memory-budget`); `None` keeps every mesh in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryBudget {
    pub bytes: u64,
    /// Where the spill file goes (a disk, not a RAM-backed /tmp); the system temp folder if `None`.
    pub spill_dir: Option<PathBuf>,
}

static BUDGET: RwLock<Option<MemoryBudget>> = RwLock::new(None);

/// Sets the budget of the stores created from now on (the CLI does this once, before reading).
/// A process-wide setting because memory is the process's; it never changes what is written.
pub fn set_memory_budget(budget: Option<MemoryBudget>) {
    *BUDGET.write().unwrap_or_else(|e| e.into_inner()) = budget;
}

pub fn memory_budget() -> Option<MemoryBudget> {
    BUDGET.read().unwrap_or_else(|e| e.into_inner()).clone()
}

/// How much geometry one store holds in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct StoreLimits {
    /// Meshes kept in memory for good, in bytes of their arrays.
    pub resident_bytes: usize,
    /// Spilled meshes read back and kept for reuse.
    pub cache_bytes: usize,
    /// What a stage may keep of data derived from geometry (dedup's prototype shapes), all threads
    /// together; past it, the stage rebuilds such data from the store when it needs it again.
    pub working_bytes: usize,
    /// Per-element metadata records kept in memory ([`super::ElementTable`]); past it they spill.
    pub metadata_bytes: usize,
    pub spill_dir: Option<PathBuf>,
}

impl StoreLimits {
    /// No limit: nothing spills.
    pub const UNLIMITED: StoreLimits = StoreLimits {
        resident_bytes: usize::MAX,
        cache_bytes: 0,
        working_bytes: usize::MAX,
        metadata_bytes: usize::MAX,
        spill_dir: None,
    };

    /// A quarter of the budget for resident geometry, a sixteenth for the read-back cache, an
    /// eighth for a stage's derived working data (dedup runs before any tile is built) and a
    /// sixteenth for per-element metadata records: the rest is for what is kept per component
    /// whatever the budget (its transform, box and ids, about 200 bytes, and the tile plan) and
    /// for the tiles being built (one gathered tile, its simplification and its encoding per
    /// thread, and each unfinished ancestor's children's content).
    pub fn from_budget(budget: Option<&MemoryBudget>) -> StoreLimits {
        match budget {
            None => StoreLimits::UNLIMITED,
            Some(b) => StoreLimits {
                resident_bytes: (b.bytes / 4) as usize,
                cache_bytes: (b.bytes / 16) as usize,
                working_bytes: (b.bytes / 8) as usize,
                metadata_bytes: (b.bytes / 16) as usize,
                spill_dir: b.spill_dir.clone(),
            },
        }
    }
}

/// What is known of a mesh without its geometry.
#[derive(Debug, Clone, Copy)]
struct Facts {
    triangles: usize,
    vertices: usize,
    heap_bytes: usize,
    estimated_bytes: usize,
    local_bounds: Aabb,
}

impl Facts {
    fn of(mesh: &Mesh) -> Facts {
        Facts {
            triangles: mesh.triangle_count(),
            vertices: mesh.vertex_count(),
            heap_bytes: mesh.heap_bytes(),
            estimated_bytes: mesh.estimated_bytes(),
            local_bounds: mesh.local_bounds.unwrap_or(Aabb::EMPTY),
        }
    }
}

#[derive(Debug, Clone)]
enum Slot {
    Resident(Arc<Mesh>, Facts),
    Spilled(Spilled, Facts),
}

/// Where a spilled mesh's record is; `material_base` is added to its material ids when read (a
/// scene appended to another keeps its records as written).
#[derive(Debug, Clone)]
struct Spilled {
    file: Arc<SpillFile>,
    offset: u64,
    len: usize,
    material_base: u32,
}

/// An unnamed temporary file, appended to under a lock and read anywhere with `pread`.
#[derive(Debug)]
pub(super) struct SpillFile {
    file: File,
    dir: PathBuf,
    end: Mutex<u64>,
}

impl SpillFile {
    pub(super) fn create(dir: Option<&Path>) -> std::io::Result<SpillFile> {
        let dir = dir.map_or_else(std::env::temp_dir, Path::to_path_buf);
        Ok(SpillFile {
            file: tempfile::tempfile_in(&dir)?,
            dir,
            end: Mutex::new(0),
        })
    }

    pub(super) fn append(&self, record: &[u8]) -> std::io::Result<u64> {
        let mut end = self.end.lock().unwrap_or_else(|e| e.into_inner());
        self.file.write_all_at(record, *end)?;
        let at = *end;
        *end += record.len() as u64;
        Ok(at)
    }

    pub(super) fn read(&self, offset: u64, len: usize) -> Vec<u8> {
        let mut buf = vec![0u8; len];
        if let Err(e) = self.file.read_exact_at(&mut buf, offset) {
            // The file is ours and was written in full: failing to read it back is a fault of the
            // machine (disk, or the folder removed under us), not of any input.
            panic!(
                "reading back spilled data from a temporary file in {} failed: {e}",
                self.dir.display()
            );
        }
        buf
    }
}

/// Figures of a store, for the report.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct StoreStats {
    pub meshes: usize,
    /// Meshes without geometry (e.g. released by dedup).
    pub empty_meshes: usize,
    pub resident_meshes: usize,
    pub resident_bytes: usize,
    pub spilled_meshes: usize,
    pub spilled_bytes: u64,
    /// Meshes kept in memory past the limit because writing the spill file failed.
    pub spill_failures: usize,
}

/// The meshes of a scene, addressed by [`MeshId`] (see the module documentation).
pub struct MeshStore {
    slots: Vec<Slot>,
    limits: StoreLimits,
    resident_bytes: usize,
    spill: Option<Arc<SpillFile>>,
    spilled_bytes: u64,
    spill_failures: usize,
    /// The first spill error, said once.
    spill_error: Option<String>,
    cache: Mutex<Lru>,
}

impl Default for MeshStore {
    /// A store under the process's budget ([`set_memory_budget`]).
    fn default() -> Self {
        MeshStore::with_limits(StoreLimits::from_budget(memory_budget().as_ref()))
    }
}

impl Clone for MeshStore {
    /// Shares the geometry (resident meshes and spill file); the copy starts with an empty cache.
    fn clone(&self) -> Self {
        MeshStore {
            slots: self.slots.clone(),
            limits: self.limits.clone(),
            resident_bytes: self.resident_bytes,
            spill: self.spill.clone(),
            spilled_bytes: self.spilled_bytes,
            spill_failures: self.spill_failures,
            spill_error: self.spill_error.clone(),
            cache: Mutex::new(Lru::new(self.limits.cache_bytes)),
        }
    }
}

impl std::fmt::Debug for MeshStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MeshStore")
            .field("stats", &self.stats())
            .field("limits", &self.limits)
            .finish()
    }
}

impl MeshStore {
    pub fn with_limits(limits: StoreLimits) -> MeshStore {
        MeshStore {
            slots: Vec::new(),
            cache: Mutex::new(Lru::new(limits.cache_bytes)),
            limits,
            resident_bytes: 0,
            spill: None,
            spilled_bytes: 0,
            spill_failures: 0,
            spill_error: None,
        }
    }

    pub fn limits(&self) -> &StoreLimits {
        &self.limits
    }

    pub fn len(&self) -> usize {
        self.slots.len()
    }
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }
    pub fn reserve(&mut self, n: usize) {
        self.slots.reserve_exact(n);
    }

    /// Adds a mesh (its `local_bounds` computed from its positions) and returns its id.
    pub fn push(&mut self, mesh: Mesh) -> MeshId {
        let id = MeshId(self.slots.len() as u32);
        let slot = self.place(mesh);
        self.slots.push(slot);
        id
    }

    /// Replaces a mesh (its `local_bounds` recomputed).
    pub fn set(&mut self, id: MeshId, mesh: Mesh) {
        self.unplace(id);
        self.slots[id.index()] = self.place(mesh);
    }

    /// Empties a mesh (name included) that nothing references any more: its slot then shares one
    /// empty mesh with every other such slot (dedup releases most meshes of a site of copies).
    pub fn release(&mut self, id: MeshId) {
        static EMPTY: std::sync::OnceLock<Arc<Mesh>> = std::sync::OnceLock::new();
        let empty = EMPTY.get_or_init(|| {
            Arc::new(Mesh {
                local_bounds: Some(Aabb::EMPTY),
                ..Mesh::default()
            })
        });
        self.unplace(id);
        self.slots[id.index()] = Slot::Resident(empty.clone(), Facts::of(empty));
    }

    /// Changes a mesh through `f` (on a copy, stored again with [`set`](Self::set)).
    pub fn update(&mut self, id: MeshId, f: impl FnOnce(&mut Mesh)) {
        let mut mesh = Arc::unwrap_or_clone(self.get(id));
        f(&mut mesh);
        self.set(id, mesh);
    }

    /// The mesh's geometry, read back from the spill file if it is there.
    pub fn get(&self, id: MeshId) -> Arc<Mesh> {
        match &self.slots[id.index()] {
            Slot::Resident(mesh, _) => mesh.clone(),
            Slot::Spilled(s, _) => self.read_back(id, s),
        }
    }

    /// [`get`](Self::get), or `None` for an id out of range.
    pub fn try_get(&self, id: MeshId) -> Option<Arc<Mesh>> {
        (id.index() < self.slots.len()).then(|| self.get(id))
    }

    /// Every mesh in id order (one at a time: a spilled one is read when reached).
    pub fn iter(&self) -> impl Iterator<Item = Arc<Mesh>> + '_ {
        (0..self.slots.len() as u32).map(|i| self.get(MeshId(i)))
    }

    /// `f` of every mesh, in parallel, results in id order (each mesh held only while `f` runs).
    pub fn par_map<T: Send>(&self, f: impl Fn(&Mesh) -> T + Sync + Send) -> Vec<T> {
        use rayon::prelude::*;
        (0..self.slots.len() as u32)
            .into_par_iter()
            .map(|i| f(&self.get(MeshId(i))))
            .collect()
    }

    pub fn triangle_count(&self, id: MeshId) -> usize {
        self.facts(id).triangles
    }
    pub fn vertex_count(&self, id: MeshId) -> usize {
        self.facts(id).vertices
    }
    /// [`Mesh::estimated_bytes`] without reading the geometry.
    pub fn estimated_bytes(&self, id: MeshId) -> usize {
        self.facts(id).estimated_bytes
    }
    /// Box of the mesh's positions in its local frame (empty for a mesh without vertices).
    pub fn local_bounds(&self, id: MeshId) -> Aabb {
        self.facts(id).local_bounds
    }

    /// Moves `other`'s meshes to the end of this store, their material ids raised by
    /// `material_base` (see [`Scene::append`](super::Scene::append)).
    pub fn append(&mut self, other: MeshStore, material_base: u32) {
        self.spill_failures += other.spill_failures;
        self.spilled_bytes += other.spilled_bytes;
        self.spill_error = self.spill_error.take().or(other.spill_error);
        self.slots.reserve(other.slots.len());
        for slot in other.slots {
            let slot = match slot {
                Slot::Resident(mut mesh, facts) => {
                    if material_base != 0 {
                        for p in &mut Arc::make_mut(&mut mesh).primitives {
                            p.material = p.material.map(|m| MaterialId(m.0 + material_base));
                        }
                    }
                    let total = self.resident_bytes.saturating_add(facts.heap_bytes);
                    if total <= self.limits.resident_bytes {
                        self.resident_bytes = total;
                        Slot::Resident(mesh, facts)
                    } else {
                        self.place(Arc::unwrap_or_clone(mesh))
                    }
                }
                Slot::Spilled(mut s, facts) => {
                    s.material_base += material_base;
                    Slot::Spilled(s, facts)
                }
            };
            self.slots.push(slot);
        }
    }

    pub fn stats(&self) -> StoreStats {
        let mut st = StoreStats {
            meshes: self.slots.len(),
            resident_bytes: self.resident_bytes,
            spilled_bytes: self.spilled_bytes,
            spill_failures: self.spill_failures,
            ..Default::default()
        };
        for s in &self.slots {
            match s {
                Slot::Resident(_, f) if f.heap_bytes == 0 => st.empty_meshes += 1,
                Slot::Resident(..) => st.resident_meshes += 1,
                Slot::Spilled(..) => st.spilled_meshes += 1,
            }
        }
        st
    }

    /// Why meshes stayed in memory past the limit, if writing the spill file failed.
    pub fn spill_error(&self) -> Option<&str> {
        self.spill_error.as_deref()
    }

    fn facts(&self, id: MeshId) -> &Facts {
        match &self.slots[id.index()] {
            Slot::Resident(_, f) | Slot::Spilled(_, f) => f,
        }
    }

    /// Keeps `mesh` in memory if it fits under the resident limit, else spills it (or, if the
    /// spill file cannot be written, keeps it anyway and says why in the stats).
    fn place(&mut self, mut mesh: Mesh) -> Slot {
        mesh.local_bounds = Some(position_bounds(&mesh));
        let facts = Facts::of(&mesh);
        if self.resident_bytes.saturating_add(facts.heap_bytes) <= self.limits.resident_bytes {
            self.resident_bytes += facts.heap_bytes;
            return Slot::Resident(Arc::new(mesh), facts);
        }
        match self.spill_mesh(&mesh) {
            Ok(s) => {
                self.spilled_bytes += s.len as u64;
                Slot::Spilled(s, facts)
            }
            Err(e) => {
                self.spill_failures += 1;
                self.spill_error.get_or_insert_with(|| e.to_string());
                self.resident_bytes += facts.heap_bytes;
                Slot::Resident(Arc::new(mesh), facts)
            }
        }
    }

    /// Forgets what slot `id` holds in memory (its bytes, its cached copy).
    fn unplace(&mut self, id: MeshId) {
        match &self.slots[id.index()] {
            Slot::Resident(_, f) => self.resident_bytes -= f.heap_bytes,
            Slot::Spilled(..) => self.cache().remove(id.0),
        }
    }

    fn spill_mesh(&mut self, mesh: &Mesh) -> std::io::Result<Spilled> {
        let file = match &self.spill {
            Some(f) => f.clone(),
            None => {
                let f = Arc::new(SpillFile::create(self.limits.spill_dir.as_deref()).map_err(
                    |e| {
                        let dir = self
                            .limits
                            .spill_dir
                            .clone()
                            .unwrap_or_else(std::env::temp_dir);
                        std::io::Error::new(
                            e.kind(),
                            format!("cannot create a spill file in {}: {e}", dir.display()),
                        )
                    },
                )?);
                self.spill = Some(f.clone());
                f
            }
        };
        let record = encode(mesh);
        let offset = file.append(&record).map_err(|e| {
            std::io::Error::new(
                e.kind(),
                format!("cannot write the spill file in {}: {e}", file.dir.display()),
            )
        })?;
        Ok(Spilled {
            file,
            offset,
            len: record.len(),
            material_base: 0,
        })
    }

    fn read_back(&self, id: MeshId, s: &Spilled) -> Arc<Mesh> {
        if let Some(m) = self.cache().get(id.0) {
            return m;
        }
        let mesh = Arc::new(decode(&s.file.read(s.offset, s.len), s.material_base));
        let bytes = mesh.heap_bytes();
        self.cache().insert(id.0, mesh.clone(), bytes);
        mesh
    }

    fn cache(&self) -> std::sync::MutexGuard<'_, Lru> {
        self.cache.lock().unwrap_or_else(|e| e.into_inner())
    }
}

fn position_bounds(mesh: &Mesh) -> Aabb {
    let mut b = Aabb::EMPTY;
    for p in &mesh.primitives {
        for v in &p.positions {
            b.extend(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64));
        }
    }
    b
}

// A record: the name, then per primitive a header (material, counts, which attributes) and then
// every primitive's arrays, each as its in-memory bytes.
const NO_MATERIAL: u32 = u32::MAX;

fn encode(mesh: &Mesh) -> Vec<u8> {
    let mut out = Vec::with_capacity(mesh.heap_bytes() + 64);
    let name = mesh.name.as_deref().map(str::as_bytes);
    out.extend_from_slice(&name.map_or(u64::MAX, |n| n.len() as u64).to_ne_bytes());
    out.extend_from_slice(name.unwrap_or_default());
    out.extend_from_slice(&(mesh.primitives.len() as u64).to_ne_bytes());
    for p in &mesh.primitives {
        out.extend_from_slice(&p.material.map_or(NO_MATERIAL, |m| m.0).to_ne_bytes());
        let flags = p.normals.is_some() as u8
            | (p.uvs.is_some() as u8) << 1
            | (p.colors.is_some() as u8) << 2;
        out.push(flags);
        out.extend_from_slice(&(p.positions.len() as u64).to_ne_bytes());
        out.extend_from_slice(&(p.indices.len() as u64).to_ne_bytes());
    }
    for p in &mesh.primitives {
        out.extend_from_slice(bytemuck::cast_slice(&p.positions));
        if let Some(n) = &p.normals {
            out.extend_from_slice(bytemuck::cast_slice(n));
        }
        if let Some(t) = &p.uvs {
            out.extend_from_slice(bytemuck::cast_slice(t));
        }
        if let Some(c) = &p.colors {
            out.extend_from_slice(bytemuck::cast_slice(c));
        }
        out.extend_from_slice(bytemuck::cast_slice(&p.indices));
    }
    out
}

/// Reads what [`encode`] wrote (the record is ours: its layout is trusted).
fn decode(record: &[u8], material_base: u32) -> Mesh {
    let mut r = Reader { record, at: 0 };
    let name_len = r.u64();
    let name = (name_len != u64::MAX)
        .then(|| String::from_utf8_lossy(r.take(name_len as usize)).into_owned());
    let count = r.u64() as usize;
    let heads: Vec<(u32, u8, usize, usize)> = (0..count)
        .map(|_| {
            let material = u32::from_ne_bytes(r.take(4).try_into().expect("4 bytes"));
            (material, r.take(1)[0], r.u64() as usize, r.u64() as usize)
        })
        .collect();
    let primitives = heads
        .into_iter()
        .map(|(material, flags, nv, ni)| Primitive {
            material: (material != NO_MATERIAL).then(|| MaterialId(material + material_base)),
            positions: r.array(nv),
            normals: (flags & 1 != 0).then(|| r.array(nv)),
            uvs: (flags & 2 != 0).then(|| r.array(nv)),
            colors: (flags & 4 != 0).then(|| r.array(nv)),
            indices: r.array(ni),
        })
        .collect();
    let mut mesh = Mesh {
        name,
        primitives,
        local_bounds: None,
    };
    mesh.local_bounds = Some(position_bounds(&mesh));
    mesh
}

struct Reader<'a> {
    record: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> &'a [u8] {
        let s = &self.record[self.at..self.at + n];
        self.at += n;
        s
    }
    fn u64(&mut self) -> u64 {
        u64::from_ne_bytes(self.take(8).try_into().expect("8 bytes"))
    }
    /// `n` values copied into a vector of their type (the record need not be aligned for it).
    fn array<T: bytemuck::Pod>(&mut self, n: usize) -> Vec<T> {
        let mut v = vec![T::zeroed(); n];
        bytemuck::cast_slice_mut::<T, u8>(&mut v).copy_from_slice(self.take(n * size_of::<T>()));
        v
    }
}

/// Least recently used meshes, bounded in bytes.
struct Lru {
    cap_bytes: usize,
    bytes: usize,
    tick: u64,
    entries: HashMap<u32, (Arc<Mesh>, usize, u64)>,
    by_use: BTreeMap<u64, u32>,
}

impl Lru {
    fn new(cap_bytes: usize) -> Lru {
        Lru {
            cap_bytes,
            bytes: 0,
            tick: 0,
            entries: HashMap::new(),
            by_use: BTreeMap::new(),
        }
    }

    fn get(&mut self, id: u32) -> Option<Arc<Mesh>> {
        let e = self.entries.get_mut(&id)?;
        self.by_use.remove(&e.2);
        self.tick += 1;
        e.2 = self.tick;
        self.by_use.insert(self.tick, id);
        Some(e.0.clone())
    }

    fn insert(&mut self, id: u32, mesh: Arc<Mesh>, bytes: usize) {
        if bytes > self.cap_bytes {
            return;
        }
        self.remove(id);
        self.tick += 1;
        self.entries.insert(id, (mesh, bytes, self.tick));
        self.by_use.insert(self.tick, id);
        self.bytes += bytes;
        while self.bytes > self.cap_bytes {
            let Some((_, old)) = self.by_use.pop_first() else {
                break;
            };
            if let Some((_, b, _)) = self.entries.remove(&old) {
                self.bytes -= b;
            }
        }
    }

    fn remove(&mut self, id: u32) {
        if let Some((_, b, t)) = self.entries.remove(&id) {
            self.bytes -= b;
            self.by_use.remove(&t);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mesh(k: u32, with_all: bool) -> Mesh {
        let positions: Vec<[f32; 3]> = (0..3 + k)
            .map(|i| [i as f32, (i * k) as f32 * 0.5, -1.25])
            .collect();
        let n = positions.len();
        Mesh {
            name: (k % 2 == 0).then(|| format!("mesh {k}")),
            primitives: vec![
                Primitive {
                    material: Some(MaterialId(k)),
                    positions: positions.clone(),
                    normals: with_all.then(|| vec![[0.0, 0.0, 1.0]; n]),
                    uvs: with_all.then(|| vec![[0.25, f32::MIN_POSITIVE]; n]),
                    colors: with_all.then(|| vec![[1.0, 0.5, 0.0, 1.0]; n]),
                    indices: (0..n as u32 - 2).flat_map(|i| [0, i + 1, i + 2]).collect(),
                },
                Primitive {
                    material: None,
                    positions,
                    indices: vec![0, 1, 2],
                    ..Default::default()
                },
            ],
            local_bounds: None,
        }
    }

    fn same(a: &Mesh, b: &Mesh) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.local_bounds, b.local_bounds);
        assert_eq!(a.primitives.len(), b.primitives.len());
        for (p, q) in a.primitives.iter().zip(&b.primitives) {
            assert_eq!(p.material, q.material);
            assert_eq!(p.positions, q.positions);
            assert_eq!(p.normals, q.normals);
            assert_eq!(p.uvs, q.uvs);
            assert_eq!(p.colors, q.colors);
            assert_eq!(p.indices, q.indices);
        }
    }

    fn tiny() -> StoreLimits {
        StoreLimits {
            resident_bytes: 200,
            cache_bytes: 400,
            working_bytes: 800,
            metadata_bytes: 0,
            spill_dir: None,
        }
    }

    #[test]
    fn spilled_meshes_read_back_as_stored() {
        let mut all = MeshStore::with_limits(StoreLimits::UNLIMITED);
        let mut spilled = MeshStore::with_limits(tiny());
        for k in 0..40 {
            assert_eq!(
                all.push(mesh(k, k % 3 == 0)),
                spilled.push(mesh(k, k % 3 == 0))
            );
        }
        let st = spilled.stats();
        assert!(st.spilled_meshes > 30 && st.resident_bytes <= 200, "{st:?}");
        assert_eq!(all.stats().spilled_meshes, 0);
        // Twice: the second pass partly from the cache.
        for _ in 0..2 {
            for (a, b) in all.iter().zip(spilled.iter()) {
                same(&a, &b);
            }
        }
        for k in 0..40 {
            let id = MeshId(k);
            assert_eq!(all.triangle_count(id), spilled.triangle_count(id));
            assert_eq!(all.vertex_count(id), spilled.vertex_count(id));
            assert_eq!(all.local_bounds(id), spilled.local_bounds(id));
            assert_eq!(Some(all.local_bounds(id)), spilled.get(id).local_bounds);
        }
        assert!(spilled.cache().bytes <= 400);
    }

    #[test]
    fn set_update_and_append_keep_ids_and_materials() {
        let mut a = MeshStore::with_limits(tiny());
        let mut b = MeshStore::with_limits(tiny());
        for k in 0..10 {
            a.push(mesh(k, true));
            b.push(mesh(k, false));
        }
        a.get(MeshId(9)); // cached, then replaced: the cache must not answer
        a.update(MeshId(9), |m| {
            m.primitives[0].positions[0] = [7.0, 7.0, 7.0]
        });
        assert_eq!(a.get(MeshId(9)).primitives[0].positions[0], [7.0, 7.0, 7.0]);
        assert_eq!(a.local_bounds(MeshId(9)).max.x, 11.0);
        a.set(MeshId(8), Mesh::default());
        assert_eq!(a.triangle_count(MeshId(8)), 0);
        assert!(a.local_bounds(MeshId(8)).is_empty());
        a.release(MeshId(7));
        a.release(MeshId(0));
        assert!(Arc::ptr_eq(&a.get(MeshId(7)), &a.get(MeshId(0))));
        assert_eq!(a.get(MeshId(7)).local_bounds, Some(Aabb::EMPTY));
        assert_eq!(a.stats().empty_meshes, 3);

        let copy = b.clone();
        a.append(b, 100);
        assert_eq!(a.len(), 20);
        for k in 0..10u32 {
            let got = a.get(MeshId(10 + k));
            let mut want = mesh(k, false);
            want.primitives[0].material = Some(MaterialId(k + 100));
            want.local_bounds = copy.get(MeshId(k)).local_bounds;
            same(&got, &want);
        }
    }

    #[test]
    fn an_unwritable_spill_folder_keeps_meshes_in_memory_and_says_why() {
        let mut s = MeshStore::with_limits(StoreLimits {
            spill_dir: Some("/nonexistent/bimtiles-spill".into()),
            ..tiny()
        });
        for k in 0..5 {
            s.push(mesh(k, true));
        }
        assert_eq!(s.stats().spilled_meshes, 0);
        assert!(s.stats().spill_failures > 0);
        assert!(s
            .spill_error()
            .unwrap()
            .contains("/nonexistent/bimtiles-spill"));
        same(&s.get(MeshId(4)), &{
            let mut m = mesh(4, true);
            m.local_bounds = Some(position_bounds(&m));
            m
        });
    }
}
