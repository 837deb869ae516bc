//! What a conversion is asked to do: [`ConvertOptions`] and its choices (levels of detail, error
//! metric, coarse-tile properties), with the defaults chosen by measurement. Read by every phase of
//! `convert` and by sharded builds.

use crate::dedup::DedupOptions;
use crate::encode::edges::EdgeOptions;
use crate::encode::Compression;
use crate::geodesy::GeoOrigin;
use crate::partition::OctreeOptions;
use serde::Serialize;
use std::path::PathBuf;

#[derive(Debug, Clone)]
pub struct ConvertOptions {
    pub out_dir: PathBuf,
    /// Replace an existing output folder (only one that holds a tileset, or an empty one).
    pub force: bool,
    /// Where the model's anchor goes on Earth; `None` = [`GeoOrigin::DEFAULT`].
    pub origin: Option<GeoOrigin>,
    /// The projected CRS of the inputs' map coordinates (`--crs EPSG:CODE`): glTF/GLB positions
    /// and IFC map conversions that name no CRS.
    pub crs: Option<String>,
    /// The CityJSON LoD to read ("2.2"; `--cityjson-lod`); `None`: each object's highest.
    pub cityjson_lod: Option<String>,
    /// The up axis and unit of OBJ inputs (`--up`, `--unit`); `None`: y up, metres.
    pub mesh_frame: crate::ingest::interchange::MeshFrame,
    /// The CityGML LoD to read ("2"; `--citygml-lod`); `None`: each object's highest.
    pub citygml_lod: Option<String>,
    /// The CityGML appearance theme to draw (`--citygml-theme`); `None`: the file's first.
    pub citygml_theme: Option<String>,
    /// A georeference that cannot be used is an error instead of a warning (`--strict-georef`).
    pub strict_georef: bool,
    pub octree: OctreeOptions,
    /// Geometry compression of the tiles.
    pub compression: Compression,
    /// Which edges the tiles carry (`EXT_mesh_primitive_edge_visibility`) and the crease angle
    /// that makes an edge hard.
    pub edges: EdgeOptions,
    /// Levels of detail: HLOD (default), none, or the paper's discrete chains.
    pub lod: LodMode,
    /// Which error the simplified tiles declare as geometricError (both are reported).
    pub error_metric: ErrorMetric,
    /// Options of the QEM simplifier for LOD content (targets are set per tile).
    pub simplify: crate::simplify::SimplifyOptions,
    /// HLOD tiles are made coarser (up to `lod::hlod::HLOD_COARSEN_TRIES` smaller triangle targets, each
    /// measured) while their measured error stays under this fraction of their framed error
    /// ([`crate::tileset::view::framed_error_m`] of the tile's bounding sphere: the error at which
    /// a viewer that sees the whole tile draws it). 0: the tile budget and
    /// `lod::hlod::HLOD_CHILDREN_DIVISOR` alone set how coarse they are. See [`DEFAULT_HLOD_ERROR_FRACTION`].
    pub hlod_error_fraction: f64,
    /// Which properties simplified (HLOD, LOD chain) tiles carry; full-detail tiles carry all.
    pub coarse_tile_properties: CoarseTileProperties,
    /// A model the budgets keep to one heavy tile gets a coarse HLOD root above it when that
    /// saves its first view a request's worth of bytes (`lod::coarse_root`).
    pub coarse_root: bool,
    /// The root tile's GLB goes into tileset.json as a data URI when it names no other file, and
    /// base64's growth and CesiumJS's cache keys cost less than the request (`tileset::inline`).
    pub inline_root: bool,
    /// Redundant and repeated components (paper III.A); `None` leaves the scene as read.
    pub dedup: Option<DedupOptions>,
    /// Write a shape drawn several times in a tile once, placed per instance
    /// (`EXT_mesh_gpu_instancing`); off, every copy is written as plain geometry.
    pub instancing: bool,
    /// Instance a shape in a tile only when that stores at least this many fewer triangles;
    /// `None`: [`default_min_instanced_triangles_saved`] of the compression.
    pub min_instanced_triangles_saved: Option<usize>,
    /// Write a tile's plain-coloured materials that differ only in base colour as one primitive,
    /// the colours in `COLOR_0` ([`AppearanceClasses`]); off, one primitive per material;
    /// `None`: [`default_merge_plain_materials`] of the compression.
    pub merge_plain_materials: Option<bool>,
    /// The 3D Tiles client the packaging is chosen for (`--client`; [`Client::apply`]).
    pub client: Client,
    /// Every tile carries the schema of its own property table inline (only the properties and
    /// enums it uses) instead of sharing one `schema.json`, for clients that never fetch
    /// `schemaUri`. Off: the tileset decides by cost (`tileset::metadata::SchemaPlacement`).
    pub schema_in_every_tile: bool,
    /// Show progress bars on stderr.
    pub progress: bool,
    /// Texture elimination, pyramids and level matching (paper III.D–III.F).
    pub texture: crate::texture::TextureOptions,
    /// Bring the tileset at `out_dir` up to date (`crate::update`) instead of building it anew.
    pub update: bool,
    /// With `update`: keep the files the new tileset no longer has, for clients that still hold
    /// the old tileset.json.
    pub keep_stale: bool,
}

impl ConvertOptions {
    pub fn new(out_dir: impl Into<PathBuf>) -> Self {
        ConvertOptions {
            out_dir: out_dir.into(),
            force: false,
            origin: None,
            crs: None,
            cityjson_lod: None,
            mesh_frame: Default::default(),
            citygml_lod: None,
            citygml_theme: None,
            strict_georef: false,
            octree: OctreeOptions::default(),
            compression: Compression::default(),
            edges: EdgeOptions::default(),
            lod: LodMode::default(),
            error_metric: ErrorMetric::default(),
            simplify: crate::simplify::SimplifyOptions::default(),
            hlod_error_fraction: DEFAULT_HLOD_ERROR_FRACTION,
            coarse_tile_properties: CoarseTileProperties::default(),
            coarse_root: true,
            inline_root: true,
            dedup: Some(DedupOptions::default()),
            instancing: true,
            min_instanced_triangles_saved: None,
            merge_plain_materials: None,
            client: Client::default(),
            schema_in_every_tile: false,
            progress: false,
            texture: Default::default(),
            update: false,
            keep_stale: false,
        }
    }
}

/// The options every stage reads: [`ConvertOptions`] as asked, with each default that depends on
/// another option decided once ([`ConvertOptions::resolve`]), so that the stages and the report
/// cannot decide it twice, or differently. The options as asked are read through it (`Deref`).
#[derive(Debug, Clone)]
pub struct Settings {
    /// The options as asked (also what a sharded plan's digest covers).
    pub asked: ConvertOptions,
    /// [`ConvertOptions::min_instanced_triangles_saved`], decided.
    pub min_instanced_triangles_saved: usize,
    /// [`ConvertOptions::merge_plain_materials`], decided.
    pub merge_plain_materials: bool,
}

impl ConvertOptions {
    /// The settings the stages read: every default left to another option decided.
    pub fn resolve(&self) -> Settings {
        Settings {
            asked: self.clone(),
            min_instanced_triangles_saved: self
                .min_instanced_triangles_saved
                .unwrap_or_else(|| default_min_instanced_triangles_saved(self.compression)),
            merge_plain_materials: self
                .merge_plain_materials
                .unwrap_or_else(|| default_merge_plain_materials(self.compression)),
        }
    }
}

impl std::ops::Deref for Settings {
    type Target = ConvertOptions;
    fn deref(&self) -> &ConvertOptions {
        &self.asked
    }
}

/// Default of [`ConvertOptions::min_instanced_triangles_saved`], chosen by measurement on the
/// sample and the shared models (docs/benchmarks.md). Draco already compresses a repeated
/// shape to a few bytes per triangle, so an instanced shape's own node, mesh, accessors and
/// instance attributes (about 1 KB) only pay off for larger savings; plain geometry costs tens of
/// bytes per triangle. With meshopt, what decides is the first view: CesiumJS sets up every mesh
/// and instanced node of a tile (small models with many instanced shapes load slower than one
/// primitive), so it follows Draco.
pub fn default_min_instanced_triangles_saved(compression: Compression) -> usize {
    match compression {
        Compression::Draco | Compression::Meshopt => 1000,
        Compression::None | Compression::Quantized => 100,
    }
}

/// Default of [`ConvertOptions::merge_plain_materials`], chosen by measurement
/// (docs/benchmarks.md): with Draco, merging cuts primitives and bytes (one Draco stream per
/// class instead of per material, 8-bit colours); meshopt stores 8-bit colours too, which its
/// codec shrinks to almost nothing along a run of one colour; plain float `COLOR_0` costs 16
/// bytes a vertex, more than merging saves, so without compression materials stay apart.
pub fn default_merge_plain_materials(compression: Compression) -> bool {
    matches!(compression, Compression::Draco | Compression::Meshopt)
}

/// The 3D Tiles client a tileset is packaged for. A profile chooses only how geometry and
/// metadata are packaged (inlined root, materials, instancing, compression, schema placement),
/// never what they are: every profile gives the same elements, triangles and properties.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Client {
    /// CesiumJS (and the default output): every packaging that makes its first view fastest.
    #[default]
    Cesium,
    /// three.js with 3DTilesRendererJS, which picks elements through per-vertex feature ids and
    /// reads no `EXT_instance_features`: no GPU instancing.
    Three,
    /// deck.gl / loaders.gl `Tile3DLayer`: no root inlined as a data URI (it takes the content
    /// type from the text after the URI's last '.'), materials kept apart (its shader ignores
    /// `COLOR_0`), no GPU instancing (it draws one copy), the schema inline in every tile (it
    /// never fetches `schemaUri`), never Draco (feature ids come back under another name).
    Deckgl,
    /// Every client above loads and picks it completely: deck.gl's choices, which include three's.
    Portable,
}

/// An option asked for on the command line that the chosen client cannot load.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "--client {client} cannot load {option}: {why}; leave it out, or use --client cesium or three"
)]
pub struct ClientConflict {
    pub client: &'static str,
    pub option: &'static str,
    pub why: &'static str,
}

impl Client {
    /// Every profile, in the order the documentation lists them.
    pub const ALL: [Client; 4] = [
        Client::Cesium,
        Client::Three,
        Client::Deckgl,
        Client::Portable,
    ];

    /// The one spelling of this profile: the CLI's value and the report's.
    pub fn name(&self) -> &'static str {
        match self {
            Client::Cesium => "cesium",
            Client::Three => "three",
            Client::Deckgl => "deckgl",
            Client::Portable => "portable",
        }
    }

    /// Sets `opts` to what this client loads: the profile's choices override the defaults and
    /// agree with every flag that only turns a packaging off (`--no-inline-root`,
    /// `--keep-materials`, `--no-instancing`). `compression_asked`: the compression given
    /// explicitly, if any (`None`: the profile keeps `opts.compression`, the default meshopt); an
    /// explicit Draco with a profile that cannot read its feature ids is an error, not silently
    /// changed.
    pub fn apply(
        self,
        opts: &mut ConvertOptions,
        compression_asked: Option<Compression>,
    ) -> Result<(), ClientConflict> {
        opts.client = self;
        if let Some(c) = compression_asked {
            opts.compression = c;
        }
        if self == Client::Cesium {
            return Ok(());
        }
        opts.instancing = false;
        if self == Client::Three {
            return Ok(());
        }
        if opts.compression == Compression::Draco {
            if compression_asked.is_some() {
                return Err(ClientConflict {
                    client: self.name(),
                    option: "--compression draco",
                    why: "loaders.gl decodes the feature ids of Draco tiles as a custom attribute",
                });
            }
            opts.compression = Compression::Meshopt;
        }
        opts.inline_root = false;
        opts.merge_plain_materials = Some(false);
        opts.schema_in_every_tile = true;
        Ok(())
    }
}

impl Serialize for Client {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

/// Which properties the tables of simplified tiles carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CoarseTileProperties {
    /// What names an element (id, name, class, storey, building, site, material, source,
    /// aliases): picking a coarse tile names the element; its property sets and hierarchy path
    /// come with full detail ([`TableScope::Identity`]).
    #[default]
    Identity,
    /// Every property in every tile.
    All,
}

/// How levels of detail are made.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum LodMode {
    /// Hierarchical LOD (paper III.C(3)): every internal tile carries its subtree's content merged
    /// and simplified to the tile budget; `refine: "REPLACE"`; leaves hold full detail.
    #[default]
    Hlod,
    /// No simplified content: internal tiles hold the components too large for their children and
    /// refine by adding (`refine: "ADD"`), with a size-bound geometric error.
    None,
    /// The paper's discrete LODs (III.C, Table IV): every leaf becomes a chain of tiles with its
    /// bounds, coarsest first, simplified to these ratios of its triangles (finest first, as
    /// [`crate::lod::chain_levels::chain_ratios`] gives them), full detail last;
    /// `refine: "REPLACE"`; internal tiles are empty, with a size-bound error.
    Ratios(Vec<f32>),
}

impl LodMode {
    /// The one spelling of this mode (the report's `lod`; the ratios themselves are reported
    /// apart).
    pub fn name(&self) -> &'static str {
        match self {
            LodMode::Hlod => "hlod",
            LodMode::None => "none",
            LodMode::Ratios(_) => "ratios",
        }
    }
}

/// Which error simplified tiles declare as `geometricError`. The report shows both per level
/// (`lod_levels`, as the paper's Table I). Its name, as the CLI spells it, comes from
/// [`ErrorMetric::name`] alone: serializing writes that name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ErrorMetric {
    /// The measured distance between a tile's content and the full detail it stands for (honest:
    /// checked by an independent measurement in the tests).
    #[default]
    Measured,
    /// The paper's screen-space error (III.C(3), formulas (1), (2)): the geometricError that makes
    /// a client switch where Δ(mesh) of the longest collapsed edge reaches
    /// `tileset::view::PAPER_MAX_DELTA_PX` at 1920x1080 and 60° (`paper_geometric_error_m`). Not a distance
    /// bound: it can be smaller than the real deviation (not honest in general).
    PaperSse,
}

impl ErrorMetric {
    /// The one spelling of this metric: the CLI's value, the report's and the serialized form.
    pub fn name(&self) -> &'static str {
        match self {
            ErrorMetric::Measured => "measured",
            ErrorMetric::PaperSse => "paper-sse",
        }
    }
}

impl Serialize for ErrorMetric {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

/// Default of [`ConvertOptions::hlod_error_fraction`]. A client measures the distance to the
/// bounding box, which from a corner is nearer than the sphere `framed_error_m` assumes; 0.8
/// leaves room for that, so a first view of the whole model keeps to the root alone (chosen by
/// measurement: docs/benchmarks.md).
pub const DEFAULT_HLOD_ERROR_FRACTION: f64 = 0.8;

#[cfg(test)]
mod tests {
    use super::*;

    /// Each profile turns off what its client cannot load and leaves the rest as asked.
    #[test]
    fn client_profiles_choose_packaging_only() {
        let packaging = |client: Client, asked: Option<Compression>| {
            let mut o = ConvertOptions::new("out");
            client.apply(&mut o, asked).map(|()| {
                (
                    o.inline_root,
                    o.merge_plain_materials,
                    o.instancing,
                    o.compression,
                    o.schema_in_every_tile,
                    o.client,
                )
            })
        };
        let default = ConvertOptions::new("out");
        assert_eq!(
            packaging(Client::Cesium, None),
            Ok((
                default.inline_root,
                default.merge_plain_materials,
                default.instancing,
                default.compression,
                default.schema_in_every_tile,
                Client::Cesium
            ))
        );
        let draco = Some(Compression::Draco);
        assert_eq!(
            packaging(Client::Cesium, draco).unwrap().3,
            Compression::Draco
        );
        let three = packaging(Client::Three, draco).unwrap();
        assert_eq!(three.3, Compression::Draco);
        assert!(!three.2 && three.0 == default.inline_root && !three.4);
        for client in [Client::Deckgl, Client::Portable] {
            assert_eq!(
                packaging(client, None),
                Ok((
                    false,
                    Some(false),
                    false,
                    Compression::Meshopt,
                    true,
                    client
                ))
            );
            let quantized = packaging(client, Some(Compression::Quantized)).unwrap();
            assert_eq!(quantized.3, Compression::Quantized);
            let err = packaging(client, draco).unwrap_err().to_string();
            assert!(
                err.contains(client.name()) && err.contains("--compression draco"),
                "{err}"
            );
        }
        // A Draco default (library callers) becomes meshopt rather than an error.
        let mut o = ConvertOptions::new("out");
        o.compression = Compression::Draco;
        Client::Portable.apply(&mut o, None).unwrap();
        assert_eq!(o.compression, Compression::Meshopt);
    }

    /// Serializing an error metric writes its one name.
    #[test]
    fn error_metric_serializes_as_its_name() {
        for m in [ErrorMetric::Measured, ErrorMetric::PaperSse] {
            assert_eq!(serde_json::to_value(m).unwrap(), m.name());
        }
    }
}
