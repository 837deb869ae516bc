//! The update's tile cache (`.bimtiles/tile-cache.bin`): an HLOD tile whose whole subtree is
//! what it was at the last `--update` build is not simplified, measured and encoded again, and a
//! leaf that is what it was is not encoded again; the written file is taken from the live tileset
//! and the record (and an HLOD tile's hand-over) from the cache.
//!
//! Every tile gets a subtree key, a SHA-256 of everything its file and its hand-over depend on.
//! A leaf's key covers its plan data (path, boxes), the scene data of its content (each
//! component's placement, the raw geometry of its mesh, the materials it uses and their appearance
//! classes, the triangles kept), the bit-exact hand-over it makes, and the property table its file
//! carries (its features' metadata, as written). An internal
//! tile's key covers its plan data, its allowed error, the components its simplification keeps
//! locked, its children's keys in order, and where each child's ids stand among its own; so it
//! changes whenever anything below it changes, and two equal subtrees at different places get
//! different keys (their paths differ). Every key also covers a global digest: the tool's version,
//! the options that shape the output, the tileset's frame, and the metadata schema's properties
//! and placement.
//!
//! Global ids (component, mesh and material indices) move whenever an entry before them in the
//! manifest is replaced or removed, while the tiles' output depends on them only through their
//! order: merging sorts features and primitives by id, instancing orders shapes by mesh, and
//! nothing else reads their values (features and groups are local per tile; files carry
//! materials and metadata by value). So a key names each id by its rank among the tile's
//! [`Labels`] (the components of the leaves below it and the materials of their meshes; a leaf's
//! meshes among its own), and an internal tile's key covers how its children's labels interleave
//! in its own. Equal keys then mean equal output up to an order-keeping renaming of the ids. The
//! cache keeps hand-overs by ranks too, and a tile taken from it gets today's ids back from its
//! labels; a hand-over with an id outside them is not kept (it is made again from its recipe),
//! and a leaf whose hand-over has one is keyed by its global ids.
//!
//! Every leaf is gathered (its key needs its hand-over); only a changed one is encoded. The cache
//! keeps, per tile, its key, then, compressed on their own, its path, the SHA-256 of its file, its
//! record and, for an HLOD tile, its hand-over's recipe, and its hand-over, in the encoding of
//! [`super::wire`] (the hand-over's arrays packed by meshopt's lossless codecs). A tile is reused
//! only when the live file still has the bytes the cache recorded. A missing, corrupt or foreign
//! cache reuses nothing: every tile is built.
//!
//! A hand-over is the tile's content at full precision, several times its file's size, and it is
//! read only when the tile's parent is built ([`super::hlod_update`]). So the cache keeps the
//! hand-overs of the upper levels only, from the root down, as many as fit in
//! [`HANDOVER_SHARE`] of the tiles' bytes: an upper tile stands for a large subtree, which its
//! hand-over spares making again, and the levels below hold most of the bytes. Any other
//! hand-over is made again from its recipe ([`Recipe`]): the same simplifications from its
//! children's hand-overs, without the measurements, which cost most of a tile.

use crate::encode::TileRecord;
use crate::error::{Error, Result};
use crate::lod::hlod::{BuiltSubtree, Recipe};
use crate::lod::wire::{WireError, R, W};
use crate::partition::content::AppearanceClasses;
use crate::partition::{ContentItem, PlannedTile};
use crate::scene::{ComponentId, MaterialId, Scene};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The tile cache, relative to the output folder (beside the update state).
pub const TILE_CACHE_FILE: &str = ".bimtiles/tile-cache.bin";
const MAGIC: &[u8; 8] = b"BIMTCAC6";
/// What every version of the cache file starts with.
const MAGIC_STEM: &[u8; 7] = b"BIMTCAC";
/// The hand-overs the cache keeps, at most, as a share of the bytes of the tileset's tiles.
pub const HANDOVER_SHARE: f64 = 0.08;
const END: &[u8; 4] = b"END.";

/// A SHA-256 of everything a subtree's output depends on.
pub(crate) type SubtreeKey = [u8; 32];

/// A tile's two keys: `geometry` covers what its content, figures and hand-over depend on (all
/// but the elements' metadata), `whole` covers its file too.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct TileKeys {
    pub geometry: SubtreeKey,
    pub whole: SubtreeKey,
}

/// What the cache saved and cost in one build.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct CacheTally {
    /// Tiles built (every leaf, the internal tiles not found in the cache, and those written
    /// again), their files' bytes.
    pub tiles_built: usize,
    pub tile_bytes_built: u64,
    /// Internal tiles built, and internal tiles in the plan.
    pub internal_tiles_built: usize,
    pub internal_tiles: usize,
    /// Internal tiles reused from the cache, their files' bytes.
    pub tiles_reused: usize,
    pub tile_bytes_reused: u64,
    /// Internal tiles whose file was written again from their cached geometry (only their
    /// elements' metadata changed).
    pub tiles_rewritten: usize,
    /// Internal tiles found in the cache whose hand-over was made again from its recipe.
    pub tiles_remade: usize,
    /// Leaves whose file was taken from the live tileset (not encoded), their files' bytes.
    pub leaves_reused: usize,
    pub leaf_bytes_reused: u64,
}

/// What a tile found in the cache hands its parent: kept in the cache, or to be made again from
/// its recipe.
#[derive(Debug, PartialEq)]
pub(crate) enum HandOver {
    Kept(BuiltSubtree),
    Remade,
}

/// A tile found in the cache.
#[derive(Debug, PartialEq)]
pub(crate) struct Found {
    /// Its record as the previous build wrote it.
    pub record: TileRecord,
    pub recipe: Recipe,
    /// Whether its file was taken: when not, only its geometry is the same (an element's
    /// metadata changed), and the file is to be written again from its hand-over's content.
    pub file_taken: bool,
    /// Its hand-over, when asked for or when its file is to be written again.
    pub handover: Option<HandOver>,
    /// When its file is to be written again and its parent needs no hand-over: the live file and
    /// the features its property table has a row for, to replace the table in the file (the
    /// hand-over then comes only if that fails).
    pub retable: Option<Retable>,
}

/// A live tile file whose property table is to be replaced, and the features of its rows.
#[derive(Debug, PartialEq)]
pub(crate) struct Retable {
    pub file: Vec<u8>,
    pub features: Vec<ComponentId>,
}

/// An entry's head: what taking its tile needs.
struct Head {
    path: String,
    /// The SHA-256 of its file as written (`None`: no content).
    file: Option<SubtreeKey>,
    record: TileRecord,
    recipe: Recipe,
    /// Internal tiles with content: the features of its property table's rows, as ranks among
    /// its labels' components.
    feature_ranks: Option<Vec<u32>>,
}

/// One tile in the cache, each part compressed: what taking it needs (its path, its file's
/// SHA-256, its record, its hand-over's recipe), and what it hands its parent, if kept; with its
/// geometry key.
#[derive(Clone)]
struct Entry {
    geometry: SubtreeKey,
    head: Vec<u8>,
    handover: Option<Vec<u8>>,
}

/// The previous build's tile cache, and the entries of the one being built.
pub(crate) struct SubtreeCache {
    global: SubtreeKey,
    /// The scene's appearance classes (a parent merges its primitives by class).
    appearance: AppearanceClasses,
    /// Entries of the previous build, by whole key, and their whole keys by geometry key.
    previous: HashMap<SubtreeKey, Entry>,
    by_geometry: HashMap<SubtreeKey, SubtreeKey>,
    live: PathBuf,
    staging: PathBuf,
    /// Entries of this build, by plan index, with their keys and tile paths.
    fresh: Mutex<BTreeMap<usize, (SubtreeKey, String, Entry)>>,
    tally: Mutex<CacheTally>,
    /// Keys of subtree roots built in another process (a sharded update): set by a job for each
    /// root it built, and in `merge` from the jobs' results.
    subtree_keys: Mutex<BTreeMap<usize, TileKeys>>,
    /// Why the previous cache could not be used (`None`: it was, or there was no tileset).
    pub(crate) note: Option<String>,
}

/// The global ids a tile's subtree uses, sorted: the components of the leaves below it and the
/// materials of their meshes. Its key and its cached hand-over name an id by its rank here, so
/// that a renumbering that keeps their order (an entry earlier in the manifest replaced or
/// removed) changes neither.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Labels {
    pub components: Vec<ComponentId>,
    pub materials: Vec<MaterialId>,
}

impl Labels {
    /// The labels of the content `items` (a leaf's, or every leaf's below a tile).
    pub(crate) fn of<'a>(scene: &Scene, items: impl Iterator<Item = &'a ContentItem>) -> Labels {
        let mut components: Vec<ComponentId> = items.map(|item| item.component).collect();
        components.sort_unstable();
        components.dedup();
        let mut meshes: Vec<_> = components
            .iter()
            .map(|&c| scene.component(c).mesh)
            .collect();
        meshes.sort_unstable();
        meshes.dedup();
        let mut materials: Vec<MaterialId> = meshes
            .into_iter()
            .flat_map(|m| {
                let mesh = scene.mesh(m);
                let used: Vec<MaterialId> =
                    mesh.primitives.iter().filter_map(|p| p.material).collect();
                used
            })
            .collect();
        materials.sort_unstable();
        materials.dedup();
        Labels {
            components,
            materials,
        }
    }

    /// The labels of a tile over its children's.
    pub(crate) fn union<'a>(kids: impl Iterator<Item = &'a Labels> + Clone) -> Labels {
        fn all<'b, T: Ord + Copy + 'b>(lists: impl Iterator<Item = &'b [T]>) -> Vec<T> {
            let mut v: Vec<T> = lists.flat_map(|l| l.iter().copied()).collect();
            v.sort_unstable();
            v.dedup();
            v
        }
        Labels {
            components: all(kids.clone().map(|k| &k.components[..])),
            materials: all(kids.map(|k| &k.materials[..])),
        }
    }

    /// The ranks of `components` among the labels' (`None` if one is not there).
    fn ranks(&self, components: &[ComponentId]) -> Option<Vec<u32>> {
        components.iter().map(|&c| self.component_rank(c)).collect()
    }

    fn component_rank(&self, c: ComponentId) -> Option<u32> {
        self.components.binary_search(&c).ok().map(|r| r as u32)
    }

    fn material_rank(&self, m: MaterialId) -> Option<u32> {
        self.materials.binary_search(&m).ok().map(|r| r as u32)
    }

    /// `built` with its ids given as their ranks (`to_ranks`), or its ranks as the ids they
    /// stand for; `None` when one is not among the labels (instanced shapes, which hand-overs
    /// never have, are not relabelled either).
    pub(crate) fn relabel(&self, built: &BuiltSubtree, to_ranks: bool) -> Option<BuiltSubtree> {
        if !built.content.instanced.is_empty() {
            return None;
        }
        let component = |c: ComponentId| match to_ranks {
            true => self.component_rank(c).map(ComponentId),
            false => self.components.get(c.index()).copied(),
        };
        let material = |m: MaterialId| match to_ranks {
            true => self.material_rank(m).map(MaterialId),
            false => self.materials.get(m.index()).copied(),
        };
        let mut out = built.clone();
        for f in &mut out.content.features {
            *f = component(*f)?;
        }
        for p in &mut out.content.primitives {
            p.material = match p.material {
                Some(m) => Some(material(m)?),
                None => None,
            };
        }
        out.cut_triangles = built
            .cut_triangles
            .iter()
            .map(|(&c, &n)| Some((component(c)?, n)))
            .collect::<Option<_>>()?;
        Some(out)
    }
}

/// Where each of `sub` (sorted) stands in `sup` (sorted, holding them all); `u32::MAX` for one
/// it does not hold.
fn positions<T: Ord>(sub: &[T], sup: &[T]) -> Vec<u32> {
    let mut at = 0;
    sub.iter()
        .map(|x| {
            while at < sup.len() && sup[at] < *x {
                at += 1;
            }
            match sup.get(at) == Some(x) {
                true => at as u32,
                false => u32::MAX,
            }
        })
        .collect()
}

/// The hasher of keys.
struct KeyHasher(Sha256);

impl KeyHasher {
    fn new(kind: &str, global: &SubtreeKey) -> Self {
        let mut h = KeyHasher(Sha256::new());
        h.bytes(kind.as_bytes());
        h.0.update(global);
        h
    }
    /// Length-prefixed, so that consecutive fields cannot run into each other.
    fn bytes(&mut self, b: &[u8]) {
        self.0.update((b.len() as u64).to_le_bytes());
        self.0.update(b);
    }
    fn debug(&mut self, v: &impl std::fmt::Debug) {
        // Debug prints floats in the shortest form that reads back to the same bits: exact.
        self.bytes(format!("{v:?}").as_bytes());
    }
    /// A tile's plan data but its content: path, boxes, counts. Not its depth: levels with one
    /// child are folded into their parent, so a change elsewhere can move a tile's depth, and
    /// only tileset.json, always written again, reads it.
    fn plan(&mut self, t: &PlannedTile) {
        self.bytes(t.path.as_bytes());
        self.debug(&(
            &t.cell,
            &t.content_bounds,
            &t.bounds,
            t.content_triangles,
            t.omitted_size_m.to_bits(),
        ));
    }
    fn finish(self) -> SubtreeKey {
        self.0.finalize().into()
    }
}

fn sha256_file(path: &Path) -> std::io::Result<SubtreeKey> {
    let mut h = Sha256::new();
    std::io::copy(&mut std::fs::File::open(path)?, &mut h)?;
    Ok(h.finalize().into())
}

/// The global digest: what every tile's output depends on beside its own inputs, given as its
/// parts' text (each part exact: floats in Debug form).
pub(crate) fn global_digest(parts: &[&[u8]]) -> SubtreeKey {
    let mut h = KeyHasher(Sha256::new());
    h.bytes(MAGIC);
    for p in parts {
        h.bytes(p);
    }
    h.finish()
}

impl SubtreeCache {
    /// The cache of the live tileset `live` (if any), for a build in `staging` whose global digest
    /// is `global`.
    pub(crate) fn open(
        live: &Path,
        staging: &Path,
        global: SubtreeKey,
        appearance: &AppearanceClasses,
    ) -> SubtreeCache {
        let path = live.join(TILE_CACHE_FILE);
        let (previous, note) = match std::fs::read(&path) {
            Ok(bytes) => match decode_file(&bytes) {
                Ok((g, entries)) if g == global => (entries, None),
                Ok(_) => (
                    HashMap::new(),
                    Some(
                        "the tile cache is of another tool version, options, frame or schema"
                            .to_string(),
                    ),
                ),
                Err(WireError::NotATileCache) if bytes.starts_with(MAGIC_STEM) => (
                    HashMap::new(),
                    Some("the tile cache is of another format".to_string()),
                ),
                Err(e) => (
                    HashMap::new(),
                    Some(format!("the tile cache is corrupt ({e})")),
                ),
            },
            Err(_) if !live.join("tileset.json").is_file() => (HashMap::new(), None),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => (
                HashMap::new(),
                Some(format!("no tile cache ({TILE_CACHE_FILE}) in the output")),
            ),
            Err(e) => (
                HashMap::new(),
                Some(format!("the tile cache cannot be read ({e})")),
            ),
        };
        SubtreeCache {
            global,
            appearance: appearance.clone(),
            by_geometry: previous.iter().map(|(k, e)| (e.geometry, *k)).collect(),
            previous,
            live: live.to_path_buf(),
            staging: staging.to_path_buf(),
            fresh: Mutex::default(),
            tally: Mutex::default(),
            subtree_keys: Mutex::default(),
            note,
        }
    }

    /// Records the keys of subtree root `i` (built here for a parent built elsewhere, or built
    /// elsewhere for a parent built here).
    pub(crate) fn set_subtree_key(&self, i: usize, keys: TileKeys) {
        self.subtree_keys.lock().expect("keys").insert(i, keys);
    }

    /// The keys of subtree root `i`, if recorded.
    pub(crate) fn subtree_key(&self, i: usize) -> Option<TileKeys> {
        self.subtree_keys.lock().expect("keys").get(&i).copied()
    }

    /// Whether internal tile `tile` with `keys` would be taken from the cache as it is: its whole
    /// key is there, for its path, and the live tileset still holds its file as written. Changes
    /// nothing (a sharded update's plan asks it to find the jobs with work).
    pub(crate) fn would_take(&self, tile: &PlannedTile, keys: &TileKeys) -> bool {
        let Some(entry) = self.previous.get(&keys.whole) else {
            return false;
        };
        let Ok(Head {
            path, file, record, ..
        }) = decode_head(&entry.head)
        else {
            return false;
        };
        path == tile.path
            && match (file, &record.uri) {
                (Some(sha), Some(uri)) => sha256_file(&self.live.join(uri)).ok() == Some(sha),
                (None, None) => true,
                _ => false,
            }
    }

    /// What this process added to the cache (its entries, the subtree roots' keys it recorded,
    /// its tally), to be [`Self::absorb`]ed by the process that writes the cache.
    pub(crate) fn export(&self) -> Vec<u8> {
        let mut w = W::default();
        let fresh = self.fresh.lock().expect("fresh");
        w.n(fresh.len());
        for (&i, (key, path, entry)) in fresh.iter() {
            w.n(i);
            w.0.extend_from_slice(key);
            w.str(path);
            w.0.extend_from_slice(&entry.geometry);
            w.n(entry.head.len());
            w.0.extend_from_slice(&entry.head);
            w.opt(&entry.handover, |w, h| {
                w.n(h.len());
                w.0.extend_from_slice(h);
            });
        }
        let keys = self.subtree_keys.lock().expect("keys");
        w.n(keys.len());
        for (&i, k) in keys.iter() {
            w.n(i);
            w.0.extend_from_slice(&k.geometry);
            w.0.extend_from_slice(&k.whole);
        }
        let t = self.tally();
        for n in [
            t.tiles_built,
            t.tile_bytes_built as usize,
            t.internal_tiles_built,
            t.internal_tiles,
            t.tiles_reused,
            t.tile_bytes_reused as usize,
            t.tiles_rewritten,
            t.tiles_remade,
            t.leaves_reused,
            t.leaf_bytes_reused as usize,
        ] {
            w.n(n);
        }
        w.0
    }

    /// Adds what another process [`Self::export`]ed.
    pub(crate) fn absorb(&self, bytes: &[u8]) -> std::result::Result<(), WireError> {
        let mut r = R(bytes);
        let entries = r.vec(81, |r| {
            let i = r.u64()? as usize;
            let key = key_from(r)?;
            let path = r.str()?;
            Ok((i, (key, path, entry_from(r)?)))
        })?;
        let keys = r.vec(72, |r| {
            let i = r.u64()? as usize;
            let geometry = key_from(r)?;
            let whole = key_from(r)?;
            Ok((i, TileKeys { geometry, whole }))
        })?;
        let mut n = [0usize; 10];
        for x in &mut n {
            *x = r.u64()? as usize;
        }
        if !r.0.is_empty() {
            return Err(WireError::NoEndMark);
        }
        self.fresh.lock().expect("fresh").extend(entries);
        self.subtree_keys.lock().expect("keys").extend(keys);
        let mut t = self.tally.lock().expect("tally");
        t.tiles_built += n[0];
        t.tile_bytes_built += n[1] as u64;
        t.internal_tiles_built += n[2];
        t.internal_tiles += n[3];
        t.tiles_reused += n[4];
        t.tile_bytes_reused += n[5] as u64;
        t.tiles_rewritten += n[6];
        t.tiles_remade += n[7];
        t.leaves_reused += n[8];
        t.leaf_bytes_reused += n[9] as u64;
        Ok(())
    }

    /// A cache that reuses nothing and stores what it is given (unit tests).
    #[cfg(test)]
    pub(crate) fn empty(global: SubtreeKey) -> SubtreeCache {
        let none = Path::new("/nonexistent");
        SubtreeCache::open(none, none, global, &AppearanceClasses::default())
    }

    /// The keys of leaf `tile`, whose ids are `labels`, which hands up `built` and whose file
    /// holds, beside its geometry, `file_inputs` (its features' metadata as written).
    pub(crate) fn leaf_keys(
        &self,
        scene: &Scene,
        tile: &PlannedTile,
        labels: &Labels,
        built: &BuiltSubtree,
        file_inputs: &[u8],
    ) -> TileKeys {
        let mut h = KeyHasher::new("leaf", &self.global);
        h.plan(tile);
        // Ids by their ranks among the leaf's (its meshes' too: the instanced shapes follow
        // their order), everything else by value.
        let mut meshes: Vec<_> = tile
            .content
            .iter()
            .map(|item| scene.component(item.component).mesh)
            .collect();
        meshes.sort_unstable();
        meshes.dedup();
        for item in &tile.content {
            let comp = scene.component(item.component);
            // As bits, not printed: a leaf has thousands of elements.
            let mut fields: Vec<u64> = vec![
                labels.component_rank(comp.id).map_or(u64::MAX, u64::from),
                meshes
                    .binary_search(&comp.mesh)
                    .map_or(u64::MAX, |r| r as u64),
                comp.alias_of.is_some() as u64,
            ];
            fields.extend(comp.world.to_cols_array().map(f64::to_bits));
            let b = &comp.world_bounds;
            fields.extend(
                b.min
                    .to_array()
                    .into_iter()
                    .chain(b.max.to_array())
                    .map(f64::to_bits),
            );
            h.bytes(bytemuck::cast_slice(&fields));
            match &item.triangles {
                Some(t) => {
                    let flat: Vec<u32> = t.iter().flat_map(|&(p, i)| [p, i]).collect();
                    h.bytes(bytemuck::cast_slice(&flat))
                }
                None => h.bytes(b"whole"),
            }
            let mesh = scene.mesh(comp.mesh);
            h.0.update((mesh.primitives.len() as u64).to_le_bytes());
            for p in &mesh.primitives {
                h.debug(&p.material.map(|m| labels.material_rank(m)));
                h.bytes(bytemuck::cast_slice(&p.positions));
                h.bytes(bytemuck::cast_slice(
                    p.normals.as_deref().unwrap_or_default(),
                ));
                h.bytes(bytemuck::cast_slice(p.uvs.as_deref().unwrap_or_default()));
                h.bytes(bytemuck::cast_slice(
                    p.colors.as_deref().unwrap_or_default(),
                ));
                h.bytes(bytemuck::cast_slice(&p.indices));
                h.debug(&(p.normals.is_some(), p.uvs.is_some(), p.colors.is_some()));
            }
        }
        // A material by value, and its appearance class by its rank among the classes (the
        // twins' ids all move when a material is added or removed; their order does not).
        for &m in &labels.materials {
            let class = self.appearance.class_of(m);
            h.debug(&(
                scene.materials.get(m.index()),
                class.map(|(rank, twin)| (rank, scene.materials.get(twin.index()))),
            ));
        }
        // The hand-over by ranks; by global ids (as a tile keyed so is never taken after a
        // renumbering) if one is not among the labels.
        let mut w = W::default();
        match labels.relabel(built, true) {
            Some(ranked) => w.subtree(&ranked),
            None => {
                w.str("global ids");
                w.subtree(built)
            }
        }
        h.bytes(&w.0);
        let geometry = h.finish();
        let mut h = KeyHasher::new("leaf file", &geometry);
        h.bytes(file_inputs);
        TileKeys {
            geometry,
            whole: h.finish(),
        }
    }

    /// The record of leaf `i` (`tile`) as the previous build wrote it, when its whole key is in
    /// the cache and the live tileset still holds its file as written: the file is put in the
    /// staging folder (a hard link, or a copy), not encoded again.
    pub(crate) fn reuse_leaf(
        &self,
        i: usize,
        tile: &PlannedTile,
        keys: &TileKeys,
    ) -> Option<TileRecord> {
        let entry = self.previous.get(&keys.whole)?;
        let Head {
            path, file, record, ..
        } = decode_head(&entry.head).ok()?;
        if path != tile.path {
            return None;
        }
        self.take_file(file, &record)?;
        self.fresh
            .lock()
            .expect("fresh")
            .insert(i, (keys.whole, path, entry.clone()));
        let mut t = self.tally.lock().expect("tally");
        t.leaves_reused += 1;
        t.leaf_bytes_reused += record.content.bytes;
        Some(record)
    }

    /// Records leaf `i` (`tile`), just written, for the next build.
    pub(crate) fn store_leaf(
        &self,
        i: usize,
        tile: &PlannedTile,
        keys: &TileKeys,
        record: &TileRecord,
    ) -> Result<()> {
        let entry = Entry {
            geometry: keys.geometry,
            head: self.head(tile, record, &Recipe::default(), None)?,
            handover: None,
        };
        self.fresh
            .lock()
            .expect("fresh")
            .insert(i, (keys.whole, tile.path.clone(), entry));
        self.tally_built(record, false);
        Ok(())
    }

    /// An entry's head, compressed: what taking tile `tile` needs.
    fn head(
        &self,
        tile: &PlannedTile,
        record: &TileRecord,
        recipe: &Recipe,
        feature_ranks: Option<&[u32]>,
    ) -> Result<Vec<u8>> {
        let file = self.file_digest(record)?;
        let mut head = W::default();
        head.str(&tile.path);
        head.opt(&file, |w, sha| w.0.extend_from_slice(sha));
        head.record(record);
        head.n(recipe.steps.len());
        for &(from_children, target) in &recipe.steps {
            head.0.push(from_children as u8);
            head.n(target);
        }
        head.opt(&recipe.flattened_grid_m, |w, &g| w.f64(g));
        head.f64(recipe.geometric_error_m);
        head.f64(recipe.coarse_to_full_m);
        head.f64(recipe.max_folding_edge_m);
        head.opt(&feature_ranks, |w, ranks| {
            w.n(ranks.len());
            ranks.iter().for_each(|&r| w.u32(r));
        });
        self.compressed(head)
    }

    fn compressed(&self, w: W) -> Result<Vec<u8>> {
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
        z.write_all(&w.0)
            .and_then(|()| z.finish())
            .map_err(|e| Error::output_from(&self.staging, "cannot compress the tile cache", e))
    }

    /// The keys of internal tile `tile`, whose ids are `labels`, over its children's keys and
    /// labels (in plan order): `allowed_m` is its allowed error and `continuing` the components
    /// its simplification keeps locked. Where each child's ids stand among the tile's is
    /// covered: merging orders features and primitives by id.
    pub(crate) fn node_keys(
        &self,
        tile: &PlannedTile,
        allowed_m: Option<f64>,
        labels: &Labels,
        children: &[(TileKeys, &Labels)],
        continuing: &[ComponentId],
    ) -> TileKeys {
        let mut h = KeyHasher::new("node", &self.global);
        h.plan(tile);
        h.debug(&allowed_m.map(f64::to_bits));
        h.debug(&positions(continuing, &labels.components));
        h.0.update((children.len() as u64).to_le_bytes());
        for (k, kid) in children {
            h.0.update(k.geometry);
            h.bytes(bytemuck::cast_slice(&positions(
                &kid.components,
                &labels.components,
            )));
            h.bytes(bytemuck::cast_slice(&positions(
                &kid.materials,
                &labels.materials,
            )));
        }
        let geometry = h.finish();
        let mut h = KeyHasher::new("node file", &geometry);
        for (k, _) in children {
            h.0.update(k.whole);
        }
        TileKeys {
            geometry,
            whole: h.finish(),
        }
    }

    /// The SHA-256 of the file `record` names in the staging folder (`None`: no file).
    fn file_digest(&self, record: &TileRecord) -> Result<Option<SubtreeKey>> {
        let Some(uri) = &record.uri else {
            return Ok(None);
        };
        let path = self.staging.join(uri);
        sha256_file(&path)
            .map(Some)
            .map_err(|e| Error::output_from(&path, "cannot read the written tile", e))
    }

    fn tally_built(&self, record: &TileRecord, internal: bool) {
        let mut t = self.tally.lock().expect("tally");
        t.tiles_built += 1;
        t.tile_bytes_built += record.content.bytes;
        if internal {
            t.internal_tiles_built += 1;
            t.internal_tiles += 1;
        }
    }

    /// Internal tile `i` (`tile`, whose ids are `labels`) as the previous build made it, when
    /// its whole key, or only its geometry key, is in the cache. With the whole key, and the live
    /// tileset still holding its file as written, the file is put in the staging folder (a hard
    /// link, or a copy) and the tile counted as reused; the hand-over comes if `need`. Otherwise
    /// the file is to be written again: with its live file and features to replace its property
    /// table when its parent needs no hand-over (then [`Self::store_retabled`]), or else with its
    /// hand-over, whose content is written again (then [`Self::store`]).
    pub(crate) fn reuse(
        &self,
        i: usize,
        tile: &PlannedTile,
        keys: &TileKeys,
        labels: &Labels,
        need: bool,
    ) -> Option<Found> {
        let (entry, same_file) = match self.previous.get(&keys.whole) {
            Some(entry) => (entry, true),
            None => (
                self.previous.get(self.by_geometry.get(&keys.geometry)?)?,
                false,
            ),
        };
        let Head {
            path,
            file,
            record,
            recipe,
            feature_ranks,
        } = decode_head(&entry.head).ok()?;
        if path != tile.path {
            return None;
        }
        let file_taken = same_file && self.take_file(file, &record).is_some();
        let retable = match (file_taken || need, feature_ranks) {
            (false, Some(ranks)) => self.live_file(file, &record).and_then(|file| {
                let features = ranks
                    .iter()
                    .map(|&r| labels.components.get(r as usize).copied())
                    .collect::<Option<_>>()?;
                Some(Retable { file, features })
            }),
            _ => None,
        };
        let handover = match (need || (!file_taken && retable.is_none()), &entry.handover) {
            (false, _) => None,
            (true, Some(packed)) => Some(HandOver::Kept(
                labels.relabel(&decode_handover(packed).ok()?, false)?,
            )),
            (true, None) => Some(HandOver::Remade),
        };
        let mut t = self.tally.lock().expect("tally");
        t.tiles_remade += (handover == Some(HandOver::Remade)) as usize;
        if file_taken {
            self.fresh
                .lock()
                .expect("fresh")
                .insert(i, (keys.whole, path, entry.clone()));
            t.tiles_reused += 1;
            t.tile_bytes_reused += record.content.bytes;
            t.internal_tiles += 1;
        }
        Some(Found {
            record,
            recipe,
            file_taken,
            handover,
            retable,
        })
    }

    /// The bytes of the live file `record` names, if it still has the SHA-256 `file`.
    fn live_file(&self, file: Option<SubtreeKey>, record: &TileRecord) -> Option<Vec<u8>> {
        let bytes = std::fs::read(self.live.join(record.uri.as_ref()?)).ok()?;
        let sha: SubtreeKey = Sha256::digest(&bytes).into();
        (Some(sha) == file).then_some(bytes)
    }

    /// Puts the live file `record` names, if it still has the SHA-256 `file`, in the staging
    /// folder (a hard link, or a copy).
    fn take_file(&self, file: Option<SubtreeKey>, record: &TileRecord) -> Option<()> {
        match (file, &record.uri) {
            (Some(sha), Some(uri)) => {
                let (from, at) = (self.live.join(uri), self.staging.join(uri));
                if sha256_file(&from).ok()? != sha {
                    return None;
                }
                std::fs::create_dir_all(at.parent()?).ok()?;
                let _ = std::fs::remove_file(&at);
                if std::fs::hard_link(&from, &at).is_err() {
                    std::fs::copy(&from, &at).ok()?;
                }
                Some(())
            }
            (None, None) => Some(()),
            _ => None,
        }
    }

    /// Records internal tile `i` (`tile`, whose ids are `labels`), just built as `recipe` says
    /// (or its file written again, when `rewritten`), for the next build. Its hand-over is kept
    /// by ranks; one that cannot be (an id not among the labels) is left to its recipe.
    pub(crate) fn store(
        &self,
        i: usize,
        tile: &PlannedTile,
        keys: &TileKeys,
        labels: &Labels,
        (record, built, recipe): (&TileRecord, &BuiltSubtree, &Recipe),
        rewritten: bool,
    ) -> Result<()> {
        let ranked = labels.relabel(built, true);
        let handover = ranked.as_ref().map(|r| {
            let mut w = W::default();
            w.packed_subtree(r);
            w
        });
        let feature_ranks = match record.uri {
            Some(_) => labels.ranks(&built.content.features),
            None => None,
        };
        let entry = Entry {
            geometry: keys.geometry,
            head: self.head(tile, record, recipe, feature_ranks.as_deref())?,
            handover: handover.map(|w| self.compressed(w)).transpose()?,
        };
        self.fresh
            .lock()
            .expect("fresh")
            .insert(i, (keys.whole, tile.path.clone(), entry));
        match rewritten {
            true => self.tally_rewritten(record),
            false => self.tally_built(record, true),
        }
        Ok(())
    }

    /// Records internal tile `i` (`tile`), whose file was written again with another property
    /// table for the same `features` ([`Found::retable`]), for the next build: its hand-over, if
    /// kept, is the previous build's.
    pub(crate) fn store_retabled(
        &self,
        i: usize,
        tile: &PlannedTile,
        keys: &TileKeys,
        labels: &Labels,
        (record, recipe, features): (&TileRecord, &Recipe, &[ComponentId]),
    ) -> Result<()> {
        let feature_ranks = labels.ranks(features);
        let previous = self
            .by_geometry
            .get(&keys.geometry)
            .and_then(|k| self.previous.get(k));
        let entry = Entry {
            geometry: keys.geometry,
            head: self.head(tile, record, recipe, feature_ranks.as_deref())?,
            handover: previous.and_then(|e| e.handover.clone()),
        };
        self.fresh
            .lock()
            .expect("fresh")
            .insert(i, (keys.whole, tile.path.clone(), entry));
        self.tally_rewritten(record);
        Ok(())
    }

    fn tally_rewritten(&self, record: &TileRecord) {
        let mut t = self.tally.lock().expect("tally");
        t.tiles_rewritten += 1;
        t.tiles_built += 1;
        t.internal_tiles += 1;
        t.tile_bytes_built += record.content.bytes;
    }

    /// What this build saved.
    pub(crate) fn tally(&self) -> CacheTally {
        self.tally.lock().expect("tally").clone()
    }

    /// Writes this build's cache into `dir` (the staging folder), with the hand-overs of the
    /// upper levels that fit in [`HANDOVER_SHARE`] of the tiles' bytes; returns its size.
    pub(crate) fn write_into(&self, dir: &Path) -> Result<u64> {
        let fresh = self.fresh.lock().expect("fresh");
        let tile_bytes = {
            let t = self.tally.lock().expect("tally");
            t.tile_bytes_built + t.tile_bytes_reused + t.leaf_bytes_reused
        };
        let kept = kept_handovers(
            fresh
                .values()
                .map(|(_, path, e)| (path.as_str(), e.handover.as_ref().map(Vec::len))),
            (tile_bytes as f64 * HANDOVER_SHARE) as usize,
        );
        let mut w = W::default();
        w.0.extend_from_slice(MAGIC);
        w.0.extend_from_slice(&self.global);
        w.n(fresh.len());
        for (key, path, entry) in fresh.values() {
            w.0.extend_from_slice(key);
            w.0.extend_from_slice(&entry.geometry);
            w.n(entry.head.len());
            w.0.extend_from_slice(&entry.head);
            let handover = entry
                .handover
                .as_ref()
                .filter(|_| kept.contains(path.as_str()));
            w.opt(&handover, |w, h| {
                w.n(h.len());
                w.0.extend_from_slice(h);
            });
        }
        w.0.extend_from_slice(END);
        let path = dir.join(TILE_CACHE_FILE);
        if let Some(folder) = path.parent() {
            std::fs::create_dir_all(folder)
                .map_err(|e| Error::output_from(folder, "cannot create the folder", e))?;
        }
        crate::output_dir::write_renamed(&path, &w.0)?;
        Ok(w.0.len() as u64)
    }
}

/// The tiles (by path) whose hand-overs are kept: from the root down, level by level and in path
/// order within a level, until the next one would pass `budget_bytes`. `tiles` gives each
/// tile's hand-over size, if it has one.
fn kept_handovers<'a>(
    tiles: impl Iterator<Item = (&'a str, Option<usize>)>,
    budget_bytes: usize,
) -> std::collections::HashSet<&'a str> {
    let mut order: Vec<(&str, usize)> = tiles.filter_map(|(p, h)| Some((p, h?))).collect();
    order.sort_by_key(|&(path, _)| (path.len(), path));
    let mut used_bytes = 0;
    order
        .into_iter()
        .take_while(|&(_, bytes)| {
            used_bytes += bytes;
            used_bytes <= budget_bytes
        })
        .map(|(path, _)| path)
        .collect()
}

fn key_from(r: &mut R) -> std::result::Result<SubtreeKey, WireError> {
    Ok(r.take(32)?.try_into().expect("32 bytes"))
}

/// An entry as a cache file and a job's part of the cache both write it after its key: its
/// geometry key, head and hand-over.
fn entry_from(r: &mut R) -> std::result::Result<Entry, WireError> {
    let geometry = key_from(r)?;
    let n = r.n(1)?;
    let head = r.take(n)?.to_vec();
    let handover = match r.flag()? {
        true => {
            let n = r.n(1)?;
            Some(r.take(n)?.to_vec())
        }
        false => None,
    };
    Ok(Entry {
        geometry,
        head,
        handover,
    })
}

/// The global digest and the entries of a cache file.
#[allow(clippy::type_complexity)]
fn decode_file(
    bytes: &[u8],
) -> std::result::Result<(SubtreeKey, HashMap<SubtreeKey, Entry>), WireError> {
    let mut r = R(bytes);
    if r.take(8)? != MAGIC {
        return Err(WireError::NotATileCache);
    }
    let global = key_from(&mut r)?;
    let entries = r.vec(73, |r| {
        let key = key_from(r)?;
        Ok((key, entry_from(r)?))
    })?;
    if r.0 != END {
        return Err(WireError::NoEndMark);
    }
    Ok((global, entries.into_iter().collect()))
}

fn inflate(packed: &[u8]) -> std::result::Result<Vec<u8>, WireError> {
    let mut bytes = Vec::new();
    flate2::read::ZlibDecoder::new(packed)
        .read_to_end(&mut bytes)
        .map_err(|_| WireError::Truncated)?;
    Ok(bytes)
}

/// An entry's head.
fn decode_head(packed: &[u8]) -> std::result::Result<Head, WireError> {
    let bytes = inflate(packed)?;
    let mut r = R(&bytes);
    let path = r.str()?;
    let file = match r.flag()? {
        true => Some(key_from(&mut r)?),
        false => None,
    };
    let record = r.record()?;
    let steps = r.vec(9, |r| Ok((r.flag()?, r.u64()? as usize)))?;
    let recipe = Recipe {
        steps,
        flattened_grid_m: r.opt_f64()?,
        geometric_error_m: r.f64()?,
        coarse_to_full_m: r.f64()?,
        max_folding_edge_m: r.f64()?,
    };
    let feature_ranks = match r.flag()? {
        true => Some(r.vec(4, |r| r.u32())?),
        false => None,
    };
    if !r.0.is_empty() {
        return Err(WireError::NoEndMark);
    }
    Ok(Head {
        path,
        file,
        record,
        recipe,
        feature_ranks,
    })
}

/// An entry's hand-over.
fn decode_handover(packed: &[u8]) -> std::result::Result<BuiltSubtree, WireError> {
    let bytes = inflate(packed)?;
    let mut r = R(&bytes);
    let built = r.packed_subtree()?;
    if !r.0.is_empty() {
        return Err(WireError::NoEndMark);
    }
    Ok(built)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::partition::content::{ContentPrimitive, TileContent};

    fn planned(path: &str) -> PlannedTile {
        PlannedTile {
            path: path.into(),
            depth: path.len() as u32 - 1,
            cell: Default::default(),
            content: Vec::new(),
            children: Vec::new(),
            content_bounds: Default::default(),
            bounds: Default::default(),
            content_triangles: 0,
            omitted_size_m: 0.0,
        }
    }

    fn subtree(x: f32) -> BuiltSubtree {
        BuiltSubtree {
            content: TileContent {
                primitives: vec![ContentPrimitive {
                    positions: vec![[0.0, 0.0, 0.0], [x, 0.0, 0.0], [0.0, 1.0, 0.0]],
                    feature_ids: vec![0; 3],
                    indices: vec![0, 1, 2],
                    ..Default::default()
                }],
                features: vec![ComponentId(0)],
                ..Default::default()
            },
            geometric_error_m: 0.0,
            coarse_to_full_m: 0.0,
            max_folding_edge_m: 0.0,
            cut_triangles: BTreeMap::new(),
        }
    }

    /// The labels of a tile of one component, `c`, without materials.
    fn labels(c: u32) -> Labels {
        Labels {
            components: vec![ComponentId(c)],
            materials: Vec::new(),
        }
    }

    #[test]
    fn a_parent_key_follows_its_childrens_content_and_its_own_path() {
        let cache = SubtreeCache::empty(global_digest(&[b"options"]));
        let scene = Scene::default();
        let none = Labels::default();
        let leaf_with = |path: &str, x: f32, file_inputs: &[u8]| {
            cache.leaf_keys(&scene, &planned(path), &none, &subtree(x), file_inputs)
        };
        let leaf = |path: &str, x: f32| leaf_with(path, x, b"metadata");
        let node = |cache: &SubtreeCache, path: &str, allowed, kids: &[TileKeys], locked| {
            let kids: Vec<(TileKeys, &Labels)> = kids.iter().map(|&k| (k, &none)).collect();
            cache.node_keys(&planned(path), allowed, &none, &kids, locked)
        };
        let parent = |path: &str, kids: &[TileKeys]| node(&cache, path, None, kids, &[]);
        let a = parent("r0", &[leaf("r00", 1.0), leaf("r01", 1.0)]);
        assert_eq!(a, parent("r0", &[leaf("r00", 1.0), leaf("r01", 1.0)]));
        // One child's content moved by one float step: another key.
        let moved = parent("r0", &[leaf("r00", 1.0), leaf("r01", 1.0 + f32::EPSILON)]);
        assert_ne!(a.geometry, moved.geometry);
        assert_ne!(a.whole, moved.whole);
        // One child's file changed, not its content (its elements' metadata): the same geometry.
        let renamed = parent(
            "r0",
            &[leaf("r00", 1.0), leaf_with("r01", 1.0, b"other metadata")],
        );
        assert_eq!(a.geometry, renamed.geometry);
        assert_ne!(a.whole, renamed.whole);
        // The same subtree elsewhere in the tree: another key (its path).
        assert_ne!(a, parent("r1", &[leaf("r10", 1.0), leaf("r11", 1.0)]));
        assert_ne!(a, parent("r1", &[leaf("r00", 1.0), leaf("r01", 1.0)]));
        // Children order, allowed error and locked components count.
        assert_ne!(a, parent("r0", &[leaf("r01", 1.0), leaf("r00", 1.0)]));
        let kids = [leaf("r00", 1.0), leaf("r01", 1.0)];
        assert_ne!(a, node(&cache, "r0", Some(0.5), &kids, &[]));
        assert_ne!(a, node(&cache, "r0", None, &kids, &[ComponentId(0)]));
        // Other options, tool or schema: another key.
        let other = SubtreeCache::empty(global_digest(&[b"other options"]));
        let other_leaf =
            |path: &str| other.leaf_keys(&scene, &planned(path), &none, &subtree(1.0), b"metadata");
        let b = node(
            &other,
            "r0",
            None,
            &[other_leaf("r00"), other_leaf("r01")],
            &[],
        );
        assert_ne!(a.geometry, b.geometry);
    }

    /// A campus of one-triangle buildings, one per `colours` entry (its material's red), in
    /// manifest order.
    fn campus(colours: &[f32]) -> Scene {
        use crate::scene::{Component, ElementInfo, Material, Mesh, MeshId, Primitive};
        let mut scene = Scene::default();
        for &red in colours {
            let mut b = Scene::default();
            b.materials.push(Material {
                base_color: [red, 0.0, 0.0, 1.0],
                ..Default::default()
            });
            let x = 10.0 * red;
            b.meshes.push(Mesh {
                name: None,
                primitives: vec![crate::scene::Primitive {
                    material: Some(MaterialId(0)),
                    positions: vec![[x, 0.0, 0.0], [x + 1.0, 0.0, 0.0], [x, 1.0, 0.0]],
                    indices: vec![0, 1, 2],
                    ..Primitive::default()
                }],
                local_bounds: None,
            });
            let world = glam::DMat4::IDENTITY;
            b.push_component(Component::new(MeshId(0), world), &ElementInfo::keyed("k"));
            scene.append(b);
        }
        scene.finish();
        scene
    }

    /// A leaf of the building drawn in `red`, and its labels and keys.
    fn leaf_of(
        cache: &SubtreeCache,
        scene: &Scene,
        path: &str,
        red: f32,
    ) -> (PlannedTile, Labels, TileKeys) {
        let c = scene
            .components
            .iter()
            .find(|c| scene.mesh(c.mesh).primitives[0].positions[0][0] == 10.0 * red)
            .expect("the building")
            .id;
        let mut tile = planned(path);
        tile.content = vec![ContentItem {
            component: c,
            triangles: None,
        }];
        let labels = Labels::of(scene, tile.content.iter());
        let content = TileContent::gather(scene, &tile.content, Default::default());
        let built = crate::lod::hlod::leaf_built(content, BTreeMap::new());
        let keys = cache.leaf_keys(scene, &tile, &labels, &built, b"metadata");
        (tile, labels, keys)
    }

    /// A tile's keys follow the order of its ids, not their values: buildings renumbered by an
    /// entry removed before them keep their keys; the same buildings in another order do not.
    #[test]
    fn keys_survive_a_renumbering_that_keeps_the_order() {
        let cache = SubtreeCache::empty(global_digest(&[b"options"]));
        let parent_keys = |scene: &Scene| {
            let (_, la, a) = leaf_of(&cache, scene, "r00", 0.5);
            let (_, lb, b) = leaf_of(&cache, scene, "r01", 0.75);
            let labels = Labels::union([&la, &lb].into_iter());
            let kids = [(a, &la), (b, &lb)];
            (
                a,
                b,
                cache.node_keys(&planned("r0"), None, &labels, &kids, &[]),
            )
        };
        let (a, b, parent) = parent_keys(&campus(&[0.5, 0.75]));
        let (a2, b2, renumbered) = parent_keys(&campus(&[0.25, 0.5, 0.75]));
        assert_eq!((a, b, parent), (a2, b2, renumbered));
        let (a3, b3, reordered) = parent_keys(&campus(&[0.75, 0.5]));
        assert_eq!((a, b), (a3, b3), "each leaf alone is the same");
        assert_ne!(parent, reordered, "merging orders features by id");
        // A hand-over by ranks reads back as the ids of the tile it is given to.
        let scene = campus(&[0.25, 0.5, 0.75]);
        let (tile, labels, _) = leaf_of(&cache, &scene, "r00", 0.75);
        let content = TileContent::gather(&scene, &tile.content, Default::default());
        let built = crate::lod::hlod::leaf_built(content, BTreeMap::new());
        let ranked = labels.relabel(&built, true).unwrap();
        assert_eq!(ranked.content.features, vec![ComponentId(0)]);
        assert_eq!(ranked.content.primitives[0].material, Some(MaterialId(0)));
        assert_eq!(labels.relabel(&ranked, false), Some(built.clone()));
        assert_eq!(Labels::default().relabel(&built, true), None);
    }

    /// What a sharded job adds to the cache reaches the merging process whole: its entries (read
    /// back as the same tiles), its roots' keys and its tally; and the plan's check sees which
    /// tiles would be taken.
    #[test]
    fn a_jobs_part_of_the_cache_is_absorbed_whole() {
        let dir = std::env::temp_dir().join(format!("bimtiles-cache-part-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("tiles")).unwrap();
        let global = global_digest(&[b"x"]);
        let keys = |g: u8, w: u8| TileKeys {
            geometry: [g; 32],
            whole: [w; 32],
        };
        let record = TileRecord {
            uri: Some("tiles/r0.glb".into()),
            ..Default::default()
        };
        std::fs::write(dir.join("tiles/r0.glb"), b"tile").unwrap();
        let recipe = Recipe::default();
        let job = SubtreeCache::open(&dir, &dir, global, &Default::default());
        job.store(
            2,
            &planned("r0"),
            &keys(1, 2),
            &labels(0),
            (&record, &subtree(0.5), &recipe),
            false,
        )
        .unwrap();
        job.set_subtree_key(2, keys(1, 2));
        let part = job.export();
        let merging = SubtreeCache::open(&dir, &dir, global, &Default::default());
        merging.absorb(&part).unwrap();
        assert_eq!(merging.subtree_key(2), Some(keys(1, 2)));
        assert_eq!(merging.tally(), job.tally());
        assert!(merging.absorb(&part[..part.len() - 1]).is_err());
        merging.write_into(&dir).unwrap();
        std::fs::write(dir.join("tileset.json"), b"{}").unwrap();
        let next = SubtreeCache::open(&dir, &dir, global, &Default::default());
        assert!(next.would_take(&planned("r0"), &keys(1, 2)));
        assert!(
            !next.would_take(&planned("r1"), &keys(1, 2)),
            "another path"
        );
        assert!(!next.would_take(&planned("r0"), &keys(1, 3)), "another key");
        assert_eq!(
            next.tally(),
            CacheTally::default(),
            "asking changes nothing"
        );
        std::fs::write(dir.join("tiles/r0.glb"), b"edited").unwrap();
        assert!(
            !next.would_take(&planned("r0"), &keys(1, 2)),
            "the live file changed"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn hand_overs_are_kept_from_the_root_down_within_the_budget() {
        let tiles = [
            ("r010", Some(10)),
            ("r0", Some(10)),
            ("r1", None),
            ("r00", Some(30)),
            ("r01", Some(10)),
        ];
        let kept = |budget| {
            let mut k: Vec<&str> = kept_handovers(tiles.iter().copied(), budget)
                .into_iter()
                .collect();
            k.sort();
            k
        };
        assert_eq!(kept(9), Vec::<&str>::new());
        assert_eq!(kept(10), ["r0"]);
        // A level is taken in path order, and the first tile over the budget ends it.
        assert_eq!(kept(45), ["r0", "r00"]);
        assert_eq!(kept(50), ["r0", "r00", "r01"]);
        assert_eq!(kept(60), ["r0", "r00", "r01", "r010"]);
    }

    #[test]
    fn an_entry_reads_back_exactly_and_a_spoiled_file_is_refused() {
        let dir = std::env::temp_dir().join(format!("bimtiles-tile-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let global = global_digest(&[b"x"]);
        let cache = SubtreeCache::open(&dir, &dir, global, &Default::default());
        let mut record = TileRecord {
            geometric_error_m: 0.1 + 0.2,
            ..Default::default()
        };
        // The tileset's bytes, of which the hand-overs may take a share.
        record.content.bytes = 1 << 20;
        let built = subtree(0.3);
        let recipe = Recipe {
            steps: vec![(true, 20), (false, 10)],
            flattened_grid_m: Some(0.1 + 0.2),
            geometric_error_m: 1.0 / 3.0,
            ..Default::default()
        };
        let keys = |g: u8, w: u8| TileKeys {
            geometry: [g; 32],
            whole: [w; 32],
        };
        cache
            .store(
                2,
                &planned("r0"),
                &keys(6, 7),
                &labels(0),
                (&record, &built, &recipe),
                false,
            )
            .unwrap();
        cache.write_into(&dir).unwrap();
        std::fs::write(dir.join("tileset.json"), b"{}").unwrap();
        let again = SubtreeCache::open(&dir, &dir, global, &Default::default());
        assert_eq!(again.note, None);
        let found = |file_taken, handover| Found {
            record: record.clone(),
            recipe: recipe.clone(),
            file_taken,
            handover,
            retable: None,
        };
        let kept = || Some(HandOver::Kept(built.clone()));
        assert_eq!(
            again.reuse(2, &planned("r1"), &keys(6, 7), &labels(0), true),
            None,
            "path"
        );
        assert_eq!(
            again.reuse(2, &planned("r0"), &keys(5, 8), &labels(0), true),
            None,
            "keys"
        );
        assert_eq!(
            again.reuse(2, &planned("r0"), &keys(6, 7), &labels(0), true),
            Some(found(true, kept()))
        );
        assert_eq!(
            again.reuse(2, &planned("r0"), &keys(6, 7), &labels(0), false),
            Some(found(true, None))
        );
        // The same tile after its ids were renumbered: its hand-over names today's.
        let mut renumbered = built.clone();
        renumbered.content.features = vec![ComponentId(5)];
        let handover = again
            .reuse(2, &planned("r0"), &keys(6, 7), &labels(5), true)
            .and_then(|f| f.handover);
        assert_eq!(handover, Some(HandOver::Kept(renumbered)));
        // The same geometry in another file: its hand-over, to write the file again.
        assert_eq!(
            again.reuse(2, &planned("r0"), &keys(6, 8), &labels(0), false),
            Some(found(false, kept()))
        );
        // A hand-over over the budget (a tileset of no bytes) is not kept.
        let small = TileRecord::default();
        let lean = SubtreeCache::open(&dir, &dir, global, &Default::default());
        lean.store(
            2,
            &planned("r0"),
            &keys(6, 7),
            &labels(0),
            (&small, &built, &recipe),
            false,
        )
        .unwrap();
        lean.write_into(&dir).unwrap();
        let lean = SubtreeCache::open(&dir, &dir, global, &Default::default());
        let found = |handover| Found {
            record: small.clone(),
            recipe: recipe.clone(),
            file_taken: true,
            handover,
            retable: None,
        };
        assert_eq!(
            lean.reuse(2, &planned("r0"), &keys(6, 7), &labels(0), true),
            Some(found(Some(HandOver::Remade)))
        );
        assert_eq!(
            lean.reuse(2, &planned("r0"), &keys(6, 7), &labels(0), false),
            Some(found(None))
        );
        let other = SubtreeCache::open(&dir, &dir, global_digest(&[b"y"]), &Default::default());
        assert!(other.note.unwrap().contains("another tool version"));
        let bytes = std::fs::read(dir.join(TILE_CACHE_FILE)).unwrap();
        std::fs::write(dir.join(TILE_CACHE_FILE), &bytes[..bytes.len() - 3]).unwrap();
        let cut = SubtreeCache::open(&dir, &dir, global, &Default::default());
        assert!(cut.note.unwrap().contains("corrupt"));
        let mut older = bytes.clone();
        older[7] = b'1';
        std::fs::write(dir.join(TILE_CACHE_FILE), &older).unwrap();
        let older = SubtreeCache::open(&dir, &dir, global, &Default::default());
        assert!(older.note.unwrap().contains("another format"));
        std::fs::remove_file(dir.join(TILE_CACHE_FILE)).unwrap();
        let none = SubtreeCache::open(&dir, &dir, global, &Default::default());
        assert!(none.note.unwrap().contains("no tile cache"));
        let _ = std::fs::remove_dir_all(&dir);
    }
    #[test]
    fn a_file_whose_metadata_changed_is_offered_with_its_rows_when_unchanged_on_disk() {
        let dir = std::env::temp_dir().join(format!("bimtiles-retable-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("tiles")).unwrap();
        std::fs::write(dir.join("tiles/r0.glb"), b"the file as written").unwrap();
        std::fs::write(dir.join("tileset.json"), b"{}").unwrap();
        let global = global_digest(&[b"x"]);
        let cache = SubtreeCache::open(&dir, &dir, global, &Default::default());
        let record = TileRecord {
            uri: Some("tiles/r0.glb".into()),
            ..Default::default()
        };
        let keys = |w: u8| TileKeys {
            geometry: [6; 32],
            whole: [w; 32],
        };
        let (built, recipe) = (subtree(0.3), Recipe::default());
        let stored = (&record, &built, &recipe);
        cache
            .store(2, &planned("r0"), &keys(7), &labels(0), stored, false)
            .unwrap();
        cache.write_into(&dir).unwrap();
        let again = SubtreeCache::open(&dir, &dir, global, &Default::default());
        // Another whole key (an element's metadata changed), its ids renumbered since.
        let found = |need| {
            again
                .reuse(2, &planned("r0"), &keys(8), &labels(4), need)
                .unwrap()
        };
        let offered = found(false);
        assert_eq!(
            offered.retable,
            Some(Retable {
                file: b"the file as written".to_vec(),
                features: vec![ComponentId(4)],
            })
        );
        assert_eq!((offered.file_taken, offered.handover), (false, None));
        // Its parent is built: the hand-over comes, and the content is written again.
        let needed = found(true);
        assert_eq!(needed.retable, None);
        assert!(needed.handover.is_some());
        // A live file that is not as written is not patched.
        std::fs::write(dir.join("tiles/r0.glb"), b"the file, altered").unwrap();
        let altered = found(false);
        assert_eq!(altered.retable, None);
        assert!(altered.handover.is_some());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
