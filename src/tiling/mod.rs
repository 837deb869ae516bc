//! Tiling: the tiles of a plan made and written. Content gathered per tile, its levels made by the
//! LOD stage (HLOD bottom-up, [`crate::lod::hlod`], or discrete chains, [`crate::lod::chains`]),
//! each tile encoded and written as soon as it is made, then the texture files of one tile moved
//! into it, schema.json (when the tiles share it) and tileset.json. One code path for `convert`
//! (a single job over the whole tree) and for sharded builds (`crate::shard`: jobs build
//! subtrees, `merge` the top).

use crate::encode::glb::encode_content_with_images;
use crate::encode::{TileEncoding, TileRecord};
use crate::error::{Error, Result};
use crate::geodesy::GeoOrigin;
use crate::lod::chains::build_chains;
use crate::lod::coarse_root::{coarse_root, RootInputs};
use crate::lod::gather;
use crate::lod::hlod::{self, BuiltSubtree, HlodBuilder};
use crate::lod::subtree_cache::{global_digest, SubtreeCache, SubtreeKey, TileKeys};
use crate::options::{CoarseTileProperties, LodMode, Settings};
use crate::output_dir::write_renamed;
use crate::partition::content::{AppearanceClasses, TileContent};
use crate::partition::{PlannedTile, TilePlan};
use crate::prepare::Prepared;
use crate::scene::Scene;
use crate::texture::single_use::embed_files_cheaper_than_a_request;
use crate::tileset::element_index::{ElementIndex, ELEMENT_INDEX_FILE};
use crate::tileset::metadata::{MetadataSchema, SchemaPlacement, TableScope};
use crate::tileset::{tileset_json, Refine};
use glam::DVec3;
use rayon::prelude::*;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::Path;

pub(crate) fn progress_bar(show: bool, len: usize, what: &'static str) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(len as u64);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{prefix:>10} [{bar:30}] {pos}/{len} {elapsed}")
            .expect("static template")
            .progress_chars("=> "),
    );
    pb.set_prefix(what);
    pb
}

/// The metadata schema file, in the tileset's folder, and how a tile (in `tiles/`) reaches it.
pub const SCHEMA_FILE: &str = "schema.json";
const SCHEMA_URI: &str = "../schema.json";

/// Where tile `tile`'s file goes, relative to tileset.json.
fn tile_uri(tile: &PlannedTile) -> String {
    format!("tiles/{}.glb", tile.path)
}

/// Tiles of the plan that may get content: those holding items without LOD; every tile with
/// HLOD or chains (a parent holds its children's simplified content).
fn content_tiles_at_most(prep: &Prepared, opts: &Settings) -> usize {
    match opts.lod {
        LodMode::None => prep
            .plan
            .tiles
            .iter()
            .filter(|t| !t.content.is_empty())
            .count(),
        LodMode::Hlod | LodMode::Ratios(_) => prep.plan.tiles.len(),
    }
}

/// Encodes and writes the tiles of one build under `dir/tiles/` (each to a temporary name, then
/// renamed, so a killed process leaves no tile under its final name half-written), and assembles
/// the tileset from the tiles' figures. Used by `convert` (one job over the whole tree) and by the
/// sharded build (`crate::shard`: each job builds its subtrees, `merge` the levels above them).
pub(crate) struct TileWriter<'a> {
    scene: &'a Scene,
    plan: &'a TilePlan,
    opts: &'a Settings,
    dir: &'a Path,
    textures: &'a crate::texture::TextureLevels<'a>,
    appearance: &'a AppearanceClasses,
    /// Per plan tile, its level in a discrete LOD chain (`--lod-ratios`; empty otherwise).
    chain_level: &'a [Option<usize>],
    schema: MetadataSchema,
    /// In every tile, or one file (`schema.json`) they share.
    schema_placement: SchemaPlacement,
    encoding: TileEncoding,
    pb: indicatif::ProgressBar,
    /// The update's tile cache (HLOD only; `None` for a plain build).
    cache: Option<&'a SubtreeCache>,
}

/// What building some subtrees gave: the record of every tile written (with its plan index), and
/// (HLOD) what each subtree root hands its parent.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct JobOutput {
    pub tiles: Vec<(usize, TileRecord)>,
    pub roots: Vec<(usize, BuiltSubtree)>,
}

impl<'a> TileWriter<'a> {
    /// `progress_len`: tiles this process will write (for the progress bar).
    pub(crate) fn new(
        scene: &'a Scene,
        prep: &'a Prepared,
        opts: &'a Settings,
        dir: &'a Path,
        textures: &'a crate::texture::TextureLevels<'a>,
        progress_len: usize,
    ) -> Result<Self> {
        let (plan, appearance, chain_level) = (&prep.plan, &prep.appearance, &prep.chain_level);
        let tiles_dir = dir.join("tiles");
        // The metadata schema, in every tile or once for the tileset (schema.json).
        let schema = MetadataSchema::from_scene(scene);
        let schema_bytes = serde_json::to_vec(&schema.to_json(None)).map_or(0, |v| v.len());
        let schema_placement = match opts.schema_in_every_tile {
            true => SchemaPlacement::Inline,
            false => {
                SchemaPlacement::choose(content_tiles_at_most(prep, opts), schema_bytes, SCHEMA_URI)
            }
        };
        std::fs::create_dir_all(&tiles_dir)
            .map_err(|e| Error::output_from(&tiles_dir, "cannot create the folder", e))?;
        Ok(TileWriter {
            scene,
            plan,
            opts,
            dir,
            textures,
            appearance,
            chain_level,
            schema,
            schema_placement,
            encoding: TileEncoding {
                compression: opts.compression,
                edges: opts.edges,
                ..TileEncoding::default()
            },
            pb: progress_bar(opts.progress, progress_len, "tiles"),
            cache: None,
        })
    }

    /// The scene's appearance classes.
    pub(crate) fn appearance(&self) -> &AppearanceClasses {
        self.appearance
    }

    /// Builds HLOD tiles through the update's tile cache.
    pub(crate) fn with_cache(mut self, cache: &'a SubtreeCache) -> Self {
        self.cache = Some(cache);
        self
    }

    /// What every tile's output depends on beside its own inputs (the tile cache's global
    /// digest): the tool, the options that shape the output, the tileset's frame, the metadata
    /// schema's properties and its placement (the appearance classes are in the leaves' keys). `None` when tiles may not be taken
    /// from the cache: the tiles use textures, whose files and levels are chosen over all tiles.
    pub(crate) fn cache_digest(&self, origin: &GeoOrigin, anchor: DVec3) -> Option<SubtreeKey> {
        let textured = !self.scene.images.is_empty()
            || self
                .scene
                .materials
                .iter()
                .any(|m| m.base_color_texture.is_some());
        if textured || self.opts.lod != LodMode::Hlod {
            return None;
        }
        Some(global_digest(&[
            crate::update::tool_version().as_bytes(),
            crate::update::options_fingerprint(self.opts).as_bytes(),
            format!("{origin:?} {anchor:?}").as_bytes(),
            // The schema's properties (a tile's table has a column per property it fills) and
            // its placement. Not its enums' values: a feature's codes are written in its leaf's
            // table, in every leaf's key (a value added or removed elsewhere changes no code).
            format!(
                "{:?} {:?} {:?}",
                self.schema.properties, self.schema.pset_keys, self.schema_placement
            )
            .as_bytes(),
        ]))
    }

    pub(crate) fn finish_progress(&self) {
        self.pb.finish_and_clear();
    }

    fn write(&self, i: usize, content: &TileContent, record: TileRecord) -> Result<TileRecord> {
        self.write_tile(&self.plan.tiles[i], content, record)
    }

    /// What a leaf's file holds beside its geometry and materials ([`hlod::LeafFile`]): the
    /// property table [`Self::write_tile`] gives it.
    fn leaf_file(&self, content: &TileContent) -> Vec<u8> {
        // Merging primitives by appearance, as writing does, keeps the features and their order.
        self.property_table(&content.features, &TileRecord::default())
            .key_bytes()
    }

    /// The property table of a tile's `features` (its rows), for the tile `record` describes:
    /// simplified tiles may carry identities alone (`--coarse-tile-properties`).
    fn property_table(
        &self,
        features: &[crate::scene::ComponentId],
        record: &TileRecord,
    ) -> crate::encode::metadata::PropertyTable {
        let scope = match (
            record.simplified_from_triangles,
            self.opts.coarse_tile_properties,
        ) {
            (Some(_), CoarseTileProperties::Identity) => TableScope::Identity,
            _ => TableScope::All,
        };
        self.schema
            .property_table(self.scene, features, &self.schema_placement, scope)
    }

    /// Tile `i`'s live `file` with the property table of `features` in place of its own, written
    /// as `tiles/<path>.glb` ([`hlod::Retable`]): what encoding its content again would write.
    fn retable(
        &self,
        i: usize,
        file: &[u8],
        features: &[crate::scene::ComponentId],
        mut record: TileRecord,
    ) -> Result<Option<TileRecord>> {
        let table = self.property_table(features, &record);
        let Some((glb, table_bytes)) = crate::encode::glb::replace_property_table(file, &table)
        else {
            return Ok(None);
        };
        let uri = tile_uri(&self.plan.tiles[i]);
        write_renamed(&self.dir.join(&uri), &glb)?;
        self.pb.inc(1);
        record.content.bytes = glb.len() as u64;
        record.content.metadata_bytes = table_bytes as u64;
        record.uri = Some(uri);
        Ok(Some(record))
    }

    /// Encodes `content` as the GLB of `tile` and writes it (`tiles/<path>.glb`).
    fn write_tile(
        &self,
        tile: &PlannedTile,
        content: &TileContent,
        mut record: TileRecord,
    ) -> Result<TileRecord> {
        let (scene, opts, textures) = (self.scene, self.opts, self.textures);
        let uri = tile_uri(tile);
        let path = self.dir.join(&uri);
        // The texture level matched to the tile's error (REPLACE content; ADD content is full).
        let texture_error = if opts.lod != LodMode::None {
            record.geometric_error_m
        } else {
            0.0
        };
        let merged = self.appearance.merge(scene, content);
        let content = merged.as_ref().unwrap_or(content);
        let chosen = textures.for_tile(content, texture_error);
        // Small non-repeating images packed into an atlas: UVs remapped in a copy of the content.
        let atlas = textures
            .atlas_for_tile(content, &chosen)
            .map_err(|e| Error::encode(&path, e))?;
        let content = atlas.as_ref().map_or(content, |a| &a.content);
        let image = |id| textures.image_for(id, &chosen, atlas.as_ref());
        let sampled_px = atlas.as_ref().map(|a| a.texels_px()).unwrap_or_default();
        let make_table =
            |features: &[crate::scene::ComponentId]| self.property_table(features, &record);
        let coarse_encoding;
        // Simplified content: its own position grid, its normals from the faces as drawn.
        let encoding = match record.max_position_error_m {
            Some(e) => {
                coarse_encoding = TileEncoding {
                    max_position_error_m: e,
                    normals_from_drawn_faces: true,
                    ..self.encoding.clone()
                };
                &coarse_encoding
            }
            _ => &self.encoding,
        };
        let enc = encode_content_with_images(
            scene,
            content,
            encoding,
            Some(&make_table),
            &image,
            &sampled_px,
        )
        .map_err(|e| Error::encode(&path, e))?;
        write_renamed(&path, &enc.glb)?;
        self.pb.inc(1);
        record.uri = Some(uri);
        record.content = enc.figures;
        Ok(record)
    }

    /// Every tile's keys in the update's tile cache, its leaves built and written (a sharded
    /// update's plan finds with them the jobs that have work). HLOD through a cache only.
    pub(crate) fn tile_keys(&self) -> Result<Vec<Option<TileKeys>>> {
        let (Some(cache), LodMode::Hlod) = (self.cache, &self.opts.lod) else {
            return Ok(vec![None; self.plan.tiles.len()]);
        };
        let write =
            |i: usize, content: &TileContent, record: TileRecord| self.write(i, content, record);
        let leaf_file = |content: &TileContent| self.leaf_file(content);
        let retable = |i: usize, file: &[u8], features: &[crate::scene::ComponentId], record| {
            self.retable(i, file, features, record)
        };
        let slots: Vec<std::sync::Mutex<Option<TileRecord>>> =
            self.plan.tiles.iter().map(|_| Default::default()).collect();
        let hlod = HlodBuilder {
            scene: self.scene,
            plan: self.plan,
            opts: self.opts,
            write: &write,
            slots: &slots,
            stop: &Default::default(),
            provided: Default::default(),
            allowed_m: hlod::allowed_errors_m(self.plan, self.opts),
            cache: Some(cache),
            leaf_file: Some(&leaf_file),
            retable: Some(&retable),
        };
        match self.plan.tiles.is_empty() {
            true => Ok(Vec::new()),
            false => hlod.tile_keys(cache, 0),
        }
    }

    /// Builds and writes the subtrees under `roots`, not descending into tiles of `stop`, whose
    /// results are `provided` (HLOD: what those subtree roots hand up).
    pub(crate) fn build_subtrees(
        &self,
        roots: &[usize],
        stop: &std::collections::BTreeSet<usize>,
        provided: BTreeMap<usize, BuiltSubtree>,
    ) -> Result<JobOutput> {
        let (scene, plan, opts) = (self.scene, self.plan, self.opts);
        let write =
            |i: usize, content: &TileContent, record: TileRecord| self.write(i, content, record);
        let leaf_file = |content: &TileContent| self.leaf_file(content);
        let retable = |i: usize, file: &[u8], features: &[crate::scene::ComponentId], record| {
            self.retable(i, file, features, record)
        };
        match &opts.lod {
            LodMode::None => {
                let mut owned = Vec::new();
                let mut stack: Vec<usize> = roots.iter().rev().copied().collect();
                while let Some(j) = stack.pop() {
                    if !stop.contains(&j) {
                        owned.push(j);
                        stack.extend(plan.tiles[j].children.iter().rev());
                    }
                }
                let tiles = owned
                    .par_iter()
                    .map(|&i| {
                        let tile = &plan.tiles[i];
                        let record = TileRecord::with_error(tile.omitted_size_m);
                        if tile.content.is_empty() {
                            self.pb.inc(1);
                            return Ok((i, record));
                        }
                        let content =
                            gather(scene, opts, &tile.content, tile.content_bounds.center());
                        Ok((i, write(i, &content, record)?))
                    })
                    .collect::<Result<Vec<_>>>()?;
                Ok(JobOutput {
                    tiles,
                    roots: Vec::new(),
                })
            }
            LodMode::Hlod => {
                let slots: Vec<std::sync::Mutex<Option<TileRecord>>> =
                    plan.tiles.iter().map(|_| Default::default()).collect();
                let hlod = HlodBuilder {
                    scene,
                    plan,
                    opts,
                    write: &write,
                    slots: &slots,
                    stop,
                    provided: std::sync::Mutex::new(provided),
                    allowed_m: hlod::allowed_errors_m(plan, opts),
                    cache: self.cache,
                    leaf_file: Some(&leaf_file),
                    retable: Some(&retable),
                };
                let built = roots
                    .par_iter()
                    .map(|&r| hlod.build(r))
                    .collect::<Result<Vec<_>>>()?;
                let tiles = slots
                    .into_iter()
                    .enumerate()
                    .filter_map(|(i, m)| {
                        m.into_inner()
                            .expect("no poisoned slot")
                            .map(|record| (i, record))
                    })
                    .collect();
                Ok(JobOutput {
                    tiles,
                    roots: roots
                        .iter()
                        .zip(built)
                        .filter_map(|(&r, built)| Some((r, built?)))
                        .collect(),
                })
            }
            LodMode::Ratios(ratios) => {
                // Chains sit below whole leaves: a job builds them over the whole tree, or none.
                if stop.contains(&0) {
                    return Ok(JobOutput::default());
                }
                if roots != [0] || !stop.is_empty() {
                    return Err(Error::output(
                        self.dir,
                        "--lod-ratios chains are built by convert, not by sharded jobs",
                    ));
                }
                let tiles = build_chains(scene, plan, self.chain_level, ratios, opts, &write)?;
                Ok(JobOutput {
                    tiles,
                    roots: Vec::new(),
                })
            }
        }
    }

    /// Builds the tiles above the subtree `roots` from the jobs' outputs, moves each texture file
    /// whose copies cost less than a request into the tiles using it, then writes schema.json
    /// (when the tiles share it) and tileset.json; returns every tile's figures, in plan order.
    pub(crate) fn merge(
        &self,
        jobs: Vec<JobOutput>,
        roots: &[usize],
        origin: GeoOrigin,
        anchor: DVec3,
    ) -> Result<Vec<TileRecord>> {
        let (plan, opts, tmp) = (self.plan, self.opts, self.dir);
        let mut slots: Vec<Option<TileRecord>> = vec![None; plan.tiles.len()];
        let mut provided = BTreeMap::new();
        for job in jobs {
            for (i, record) in job.tiles {
                slots[i] = Some(record);
            }
            provided.extend(job.roots);
        }
        let stop: std::collections::BTreeSet<usize> = roots.iter().copied().collect();
        let top = self.build_subtrees(&[0], &stop, provided)?;
        for (i, record) in top.tiles {
            slots[i] = Some(record);
        }
        let mut records = Vec::with_capacity(slots.len());
        for (s, tile) in slots.into_iter().zip(&plan.tiles) {
            let mut record = s.ok_or_else(|| {
                Error::output(tmp, format!("tile {} was built by no job", tile.path))
            })?;
            record.path = tile.path.clone();
            record.depth = tile.depth;
            record.lod_level = self.chain_level.get(records.len()).copied().flatten();
            records.push(record);
        }
        // A compact model's one heavy tile gets a coarse root above it.
        let mut plan = std::borrow::Cow::Borrowed(plan);
        let whole_model = top.roots.into_iter().find(|(i, _)| *i == 0);
        if let Some((_, full)) = whole_model {
            let write_tile = |tile: &PlannedTile, content: &TileContent, record: TileRecord| {
                self.write_tile(tile, content, record)
            };
            let inputs = RootInputs {
                scene: self.scene,
                plan: self.plan,
                opts,
                dir: tmp,
                textures: self.textures,
                write_tile: &write_tile,
            };
            if let Some((with_root, with_root_records)) = coarse_root(&inputs, &records, full)? {
                (plan, records) = (std::borrow::Cow::Owned(with_root), with_root_records);
            }
        }
        if let SchemaPlacement::File(_) = self.schema_placement {
            let schema_json = serde_json::to_vec_pretty(&self.schema.to_json(None))
                .map_err(|e| Error::output_from(tmp, "cannot serialize schema.json", e))?;
            write_renamed(&tmp.join(SCHEMA_FILE), &schema_json)?;
        }
        // The element index, for a viewer's model tree and search (fetched after the first view).
        let index = ElementIndex::from_scene(self.scene);
        write_renamed(&tmp.join(ELEMENT_INDEX_FILE), &index.to_bytes())?;
        let mut extras = json!({"bimtiles": {
            "origin": {"longitude_deg": origin.longitude_deg, "latitude_deg": origin.latitude_deg, "height_m": origin.height_m},
            "anchor_m": anchor.to_array(),
            "frame": "root transform maps local east-north-up metres to ECEF; glTF content is y-up",
            "elementIndex": ELEMENT_INDEX_FILE,
        }});
        if let Some(edges) = crate::tileset::edges_extras(opts.edges.mode, self.scene) {
            extras["bimtiles"]["edges"] = edges;
        }
        let refine = match opts.lod {
            LodMode::Hlod | LodMode::Ratios(_) => Refine::Replace,
            LodMode::None => Refine::Add,
        };
        if !opts.texture.embed {
            let uris: Vec<&str> = records.iter().filter_map(|r| r.uri.as_deref()).collect();
            let moved = embed_files_cheaper_than_a_request(tmp, &uris)?;
            for r in &mut records {
                if let Some(&bytes) = r.uri.as_ref().and_then(|u| moved.tile_bytes.get(u)) {
                    r.content.bytes = bytes;
                }
            }
        }
        // No schema in tileset.json: no tileset, tile or group metadata uses one, and CesiumJS
        // fetches a tileset's `schemaUri` before the tileset is ready, then drops it (the tiles
        // fetch theirs again): a round trip before the first tile, for nothing.
        let mut ts = tileset_json(&plan, &records, refine, &origin.enu_to_ecef(), extras);
        crate::tileset::check_numbers(&ts).map_err(|e| Error::Internal {
            path: (self.scene.sources.first()).map_or_else(Default::default, |s| s.path.clone()),
            message: e.to_string(),
        })?;
        if opts.inline_root {
            crate::tileset::inline::inline_root_content(tmp, &mut ts, &mut records[0])?;
        }
        let bytes = serde_json::to_vec_pretty(&ts)
            .map_err(|e| Error::output_from(tmp, "cannot serialize tileset.json", e))?;
        write_renamed(&tmp.join("tileset.json"), &bytes)?;
        Ok(records)
    }
}
