//! HLOD in an update (`convert --update`, book: guide/updating.md): what changed is built, the
//! rest is taken from the tile cache ([`super::subtree_cache`]).
//!
//! Two passes. First every leaf is built (gathering and encoding a leaf is cheap, and its key
//! needs what it makes) and every tile's subtree key computed, bottom-up. Then, from the root
//! down, a tile whose key is in the cache, and whose file the live tileset still has, is taken
//! from it with its whole subtree; any other tile is built, from its children's hand-overs. A
//! taken tile's hand-over is needed only when its parent is built: it is read from the cache
//! (upper levels), or made again from its recipe, from its own children's hand-overs, down to
//! tiles whose hand-over is kept, or leaves. A tile whose geometry key alone is in the cache (an
//! element's metadata changed below it) gets its content the same way and is only written again.

use super::hlod::{continuing, cut_triangles, BuiltSubtree, HlodBuilder};
use super::subtree_cache::{Found, HandOver, SubtreeCache, TileKeys};
use crate::error::Result;
use crate::scene::ComponentId;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::sync::Mutex;

impl HlodBuilder<'_> {
    /// Brings the subtree of tile `i` up to date with `cache`; what it hands up when its parent
    /// needs it (a single-leaf plan's root: the coarse root simplifies it).
    pub(super) fn build_updated(
        &self,
        cache: &SubtreeCache,
        i: usize,
    ) -> Result<Option<BuiltSubtree>> {
        let keys: Vec<Mutex<Option<TileKeys>>> =
            self.plan.tiles.iter().map(|_| Mutex::default()).collect();
        self.key_subtree(cache, i, &keys)?;
        let keys: Vec<Option<TileKeys>> = keys
            .into_iter()
            .map(|k| k.into_inner().expect("no poisoned key"))
            .collect();
        let need = self.plan.tiles[i].children.is_empty();
        self.build_changed(cache, &keys, i, need)
    }

    /// Builds the leaves of the subtree of tile `i` and keys all its tiles into `keys`; returns
    /// the key of tile `i` and the triangles of the cut components below it.
    fn key_subtree(
        &self,
        cache: &SubtreeCache,
        i: usize,
        keys: &[Mutex<Option<TileKeys>>],
    ) -> Result<(TileKeys, BTreeMap<ComponentId, usize>)> {
        let tile = &self.plan.tiles[i];
        let (key, cut) = if tile.children.is_empty() {
            let (built, record) = self.build_leaf(i)?;
            let key = cache.leaf_keys(self.scene, tile, &built, &record)?;
            (key, built.cut_triangles)
        } else {
            let kids: Vec<(TileKeys, BTreeMap<ComponentId, usize>)> = tile
                .children
                .par_iter()
                .map(|&c| self.key_subtree(cache, c, keys))
                .collect::<Result<_>>()?;
            let cut = cut_triangles(kids.iter().map(|(_, cut)| cut));
            let child_keys: Vec<TileKeys> = kids.iter().map(|(key, _)| *key).collect();
            let allowed_m = self.allowed_m.get(i).copied().flatten();
            let locked = continuing(self.scene, &cut);
            (cache.node_keys(tile, allowed_m, &child_keys, &locked), cut)
        };
        *keys[i].lock().expect("key") = Some(key);
        Ok((key, cut))
    }

    /// Takes or builds tile `i` and its subtree; its hand-over when `need` (its parent is built).
    fn build_changed(
        &self,
        cache: &SubtreeCache,
        keys: &[Option<TileKeys>],
        i: usize,
        need: bool,
    ) -> Result<Option<BuiltSubtree>> {
        let tile = &self.plan.tiles[i];
        if tile.children.is_empty() {
            // Written with the keys: only its hand-over is made again.
            return Ok(need.then(|| self.leaf_handover(i)));
        }
        let key = keys[i].expect("every tile of the subtree is keyed");
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
        if let Some(found) = cache.reuse(i, tile, &key, need) {
            let Found {
                record,
                recipe,
                file_taken,
                handover,
            } = found;
            // Its children are the cached ones: they are taken too, and hand it their content if
            // it is made again.
            let built = match handover {
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
                    cache.store(i, tile, &key, (&written, built, &recipe), true)?;
                    written
                }
                _ => record,
            };
            *self.slots[i].lock().expect("slot") = Some(record);
            return Ok(built.filter(|_| need));
        }
        let (built, record, recipe) = self.build_internal(i, all(handed(true)?))?;
        cache.store(i, tile, &key, (&record, &built, &recipe), false)?;
        *self.slots[i].lock().expect("slot") = Some(record);
        Ok(Some(built))
    }
}
