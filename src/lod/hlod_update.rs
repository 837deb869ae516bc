//! HLOD in an update (`convert --update`, book: guide/updating.md): what changed is built, the
//! rest is taken from the tile cache ([`super::subtree_cache`]).
//!
//! Two passes. First every leaf is gathered and keyed (its key covers its features' metadata as
//! its file holds it), and taken from the live tileset or written, and every tile's subtree key
//! computed, bottom-up. Then, from the root
//! down, a tile whose key is in the cache, and whose file the live tileset still has, is taken
//! from it with its whole subtree; any other tile is built, from its children's hand-overs. A
//! taken tile's hand-over is needed only when its parent is built: it is read from the cache
//! (upper levels), or made again from its recipe, from its own children's hand-overs, down to
//! tiles whose hand-over is kept, or leaves. A tile whose geometry key alone is in the cache (an
//! element's metadata changed below it) is written again: its live file with the new property
//! table in place of the old (the encoder writes the table last), or, when its parent is built
//! or that file is not as written, from its content made the same way.
//!
//! A sharded update (`crate::shard`) runs the same passes in pieces: a job brings its subtrees
//! up to date and hands up each root's content and keys; `merge` keys and takes or builds the
//! rest of the tree, with the jobs' subtree roots as given (the builder's `stop` tiles).

use super::hlod::{continuing, cut_triangles, leaf_built, BuiltSubtree, HlodBuilder};
use super::subtree_cache::{Found, HandOver, Labels, SubtreeCache, TileKeys};
use crate::encode::TileRecord;
use crate::error::{Error, Result};
use crate::scene::ComponentId;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::sync::Mutex;

impl HlodBuilder<'_> {
    /// Brings the subtree of tile `i` up to date with `cache`; what it hands up when its parent
    /// needs it: a single-leaf plan's root (the coarse root simplifies it), and the root of a
    /// sharded job's subtree (its parent is built by `merge`, whose cache gets the root's keys).
    pub(super) fn build_updated(
        &self,
        cache: &SubtreeCache,
        i: usize,
    ) -> Result<Option<BuiltSubtree>> {
        let keys = self.keyed(cache, i)?;
        let root = keys[i].as_ref().expect("the subtree's root is keyed");
        cache.set_subtree_key(i, root.0);
        let need = i != 0 || self.plan.tiles[i].children.is_empty();
        self.build_changed(cache, &keys, i, need)
    }

    /// Builds the leaves of the subtree of tile `i` and keys all its tiles (by plan index; `None`
    /// outside the subtree).
    pub(crate) fn tile_keys(
        &self,
        cache: &SubtreeCache,
        i: usize,
    ) -> Result<Vec<Option<TileKeys>>> {
        Ok(self
            .keyed(cache, i)?
            .into_iter()
            .map(|k| k.map(|(keys, _)| keys))
            .collect())
    }

    /// [`Self::tile_keys`], with each tile's labels.
    fn keyed(&self, cache: &SubtreeCache, i: usize) -> Result<Vec<Option<(TileKeys, Labels)>>> {
        let keys: Vec<Mutex<Option<(TileKeys, Labels)>>> =
            self.plan.tiles.iter().map(|_| Mutex::default()).collect();
        self.key_subtree(cache, i, &keys)?;
        Ok(keys
            .into_iter()
            .map(|k| k.into_inner().expect("no poisoned key"))
            .collect())
    }

    /// Builds the leaves of the subtree of tile `i` and keys all its tiles into `keys`; returns
    /// the key of tile `i`, the triangles of the cut components below it and its labels.
    fn key_subtree(
        &self,
        cache: &SubtreeCache,
        i: usize,
        keys: &[Mutex<Option<(TileKeys, Labels)>>],
    ) -> Result<(TileKeys, BTreeMap<ComponentId, usize>, Labels)> {
        let tile = &self.plan.tiles[i];
        let (key, cut, labels) = if self.stop.contains(&i) {
            // A sharded job's subtree: its keys and what it hands up come from the job.
            let given = self.provided.lock().expect("provided");
            let cut = given.get(&i).map(|b| b.cut_triangles.clone());
            match (cache.subtree_key(i), cut) {
                (Some(key), Some(cut)) => {
                    let leaves = self.leaves_below(i);
                    let labels = Labels::of(self.scene, leaves.iter().flat_map(|l| l.iter()));
                    (key, cut, labels)
                }
                _ => {
                    let uri = format!("tiles/{}.glb", tile.path);
                    return Err(Error::output(uri, "no job built this subtree"));
                }
            }
        } else if tile.children.is_empty() {
            let labels = Labels::of(self.scene, tile.content.iter());
            let (content, cut_triangles) = self.leaf_content(i);
            let leaf_file = self
                .leaf_file
                .expect("a tile cache comes with what leaves' files hold");
            let file_inputs = leaf_file(&content);
            // The hand-over is the content itself unless instances are expanded for it: only
            // then is the content kept apart to be written.
            let instanced = (!content.instanced.is_empty()).then(|| content.clone());
            let built = leaf_built(content, cut_triangles);
            let key = cache.leaf_keys(self.scene, tile, &labels, &built, &file_inputs);
            let record = match cache.reuse_leaf(i, tile, &key) {
                Some(record) => record,
                None => {
                    let as_written = instanced.as_ref().unwrap_or(&built.content);
                    let record = (self.write)(i, as_written, TileRecord::default())?;
                    cache.store_leaf(i, tile, &key, &record)?;
                    record
                }
            };
            *self.slots[i].lock().expect("slot") = Some(record);
            (key, built.cut_triangles, labels)
        } else {
            type Keyed = (TileKeys, BTreeMap<ComponentId, usize>, Labels);
            let kids: Vec<Keyed> = tile
                .children
                .par_iter()
                .map(|&c| self.key_subtree(cache, c, keys))
                .collect::<Result<_>>()?;
            let cut = cut_triangles(kids.iter().map(|(_, cut, _)| cut));
            let labels = Labels::union(kids.iter().map(|(_, _, l)| l));
            let child_keys: Vec<(TileKeys, &Labels)> =
                kids.iter().map(|(key, _, l)| (*key, l)).collect();
            let allowed_m = self.allowed_m.get(i).copied().flatten();
            let locked = continuing(self.scene, &cut);
            let key = cache.node_keys(tile, allowed_m, &labels, &child_keys, &locked);
            (key, cut, labels)
        };
        *keys[i].lock().expect("key") = Some((key, labels.clone()));
        Ok((key, cut, labels))
    }

    /// Takes or builds tile `i` and its subtree; its hand-over when `need` (its parent is built).
    fn build_changed(
        &self,
        cache: &SubtreeCache,
        keys: &[Option<(TileKeys, Labels)>],
        i: usize,
        need: bool,
    ) -> Result<Option<BuiltSubtree>> {
        let tile = &self.plan.tiles[i];
        if self.stop.contains(&i) {
            // Built by a sharded job, which handed its content up.
            let given = self.provided.lock().expect("provided").remove(&i);
            return Ok(given.filter(|_| need));
        }
        if tile.children.is_empty() {
            // Written with the keys: only its hand-over is made again.
            return Ok(need.then(|| self.leaf_handover(i)));
        }
        let (key, labels) = keys[i]
            .as_ref()
            .expect("every tile of the subtree is keyed");
        let key = *key;
        let handed = |need: bool| -> Result<Vec<Option<BuiltSubtree>>> {
            tile.children
                .par_iter()
                .map(|&c| self.build_changed(cache, keys, c, need))
                .collect()
        };
        let all = |kids: Vec<Option<BuiltSubtree>>| -> Vec<BuiltSubtree> {
            kids.into_iter()
                .map(|k| k.expect("a hand-over asked for is made"))
                .collect()
        };
        if let Some(found) = cache.reuse(i, tile, &key, labels, need) {
            let Found {
                record,
                recipe,
                file_taken,
                handover,
                retable,
            } = found;
            // Only its elements' metadata changed, and its parent needs no content: its file
            // with another property table.
            let retabled = match (retable, self.retable) {
                (Some(r), Some(write)) => write(i, &r.file, &r.features, record.clone())?
                    .map(|written| (written, r.features)),
                _ => None,
            };
            if let Some((written, features)) = retabled {
                handed(false)?;
                cache.store_retabled(i, tile, &key, labels, (&written, &recipe, &features))?;
                *self.slots[i].lock().expect("slot") = Some(written);
                return Ok(None);
            }
            // Its children are the cached ones: they are taken too, and hand it their content if
            // it is made again.
            let built = match handover {
                // A file to write again, whose table could not be replaced.
                None if !file_taken => Some(self.replay(i, all(handed(true)?), &recipe)?),
                None => handed(false).map(|_| None)?,
                Some(HandOver::Kept(built)) => handed(false).map(|_| Some(built))?,
                Some(HandOver::Remade) => Some(self.replay(i, all(handed(true)?), &recipe)?),
            };
            let record = match (&built, file_taken) {
                (Some(built), false) => {
                    // Only its elements' metadata changed: the same content, written again.
                    let written = match record.uri {
                        Some(_) => (self.write)(i, &built.content, record)?,
                        None => record,
                    };
                    cache.store(i, tile, &key, labels, (&written, built, &recipe), true)?;
                    written
                }
                _ => record,
            };
            *self.slots[i].lock().expect("slot") = Some(record);
            return Ok(built.filter(|_| need));
        }
        let (built, record, recipe) = self.build_internal(i, all(handed(true)?))?;
        cache.store(i, tile, &key, labels, (&record, &built, &recipe), false)?;
        *self.slots[i].lock().expect("slot") = Some(record);
        Ok(Some(built))
    }
}
