//! Command-line interface: parses arguments, calls the library, prints. Nothing else lives here.

use anyhow::{Context, Result};
use bimtiles::convert::{
    Client, CoarseTileProperties, ConvertOptions, ErrorMetric, LodMode, Updated,
};
use bimtiles::dedup::DedupOptions;
use bimtiles::encode::Compression;
use bimtiles::geodesy::GeoOrigin;
use bimtiles::ingest::InputSet;
use bimtiles::inspect::{human_bytes, inspect};
use bimtiles::partition::OctreeOptions;
use bimtiles::simplify::SimplifyOptions;
use bimtiles::texture::{TextureFormat, TextureOptions};
use clap::{Args, CommandFactory, Parser, Subcommand};
use std::path::PathBuf;

/// The version `--version` prints: the crate's, and the commit it was built from (build.rs).
const VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (",
    env!("BIMTILES_COMMIT"),
    ")"
);

#[derive(Parser)]
#[command(
    name = "bimtiles",
    version = VERSION,
    about = "Building models (glTF/GLB, IFC) to OGC 3D Tiles 1.1"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert models into a 3D Tiles 1.1 tileset.
    #[command(after_help = "Examples:
  bimtiles convert duplex.ifc --out tiles/duplex
  bimtiles convert --manifest campus.json --out tiles/campus --force
  bimtiles convert site.city.json --crs EPSG:7415 --out tiles/site --quiet")]
    Convert(ConvertArgs),
    /// Sharded build, step 1: plan the octree and split it into N subtree jobs (DIR/plan.json).
    /// Takes the options of `convert`; `--out` is the build folder DIR. With --update, DIR is a
    /// tileset to bring up to date: the build goes to DIR/.bimtiles/shard/, plan.json marks the
    /// jobs whose subtrees did not change ("changed": false; they need no run), and merge
    /// publishes the result over the live tileset as `convert --update` does.
    #[command(after_help = "Examples:
  bimtiles plan --manifest campus.json --out build --jobs 8
  bimtiles plan a.ifc b.glb --out build --jobs 2 --max-tile-triangles 20000
  bimtiles plan --manifest campus.json --out site/tiles --jobs 8 --update")]
    Plan(PlanArgs),
    /// Sharded build, step 2: build one job's subtrees into DIR (any order, any machine that sees
    /// DIR and the inputs). A job an update's plan marks unchanged does nothing.
    #[command(after_help = "Examples:
  bimtiles build-job build --job 0
  for j in 0 1 2; do bimtiles build-job build --job $j --quiet; done")]
    BuildJob {
        /// The build folder written by `bimtiles plan`.
        dir: PathBuf,
        /// Which job (0 to N-1).
        #[arg(long)]
        job: usize,
        /// Worker threads (default: all cores; at most 1024). The output does not depend on it.
        #[arg(long, value_parser = parse_threads)]
        threads: Option<usize>,
        /// No progress bar and no summary.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Sharded build, step 3: check every job's result, build the top levels and write
    /// tileset.json, schema.json and report.json (byte-identical to `convert`'s tileset). An
    /// update also takes the unchanged jobs' tiles from the tile cache and puts the new tileset in
    /// place of the live one (switched last, atomically; stale files removed unless
    /// --keep-stale).
    #[command(after_help = "Examples:
  bimtiles merge build
  bimtiles merge build --threads 4 --quiet")]
    Merge {
        /// The build folder written by `bimtiles plan`.
        dir: PathBuf,
        /// Worker threads (default: all cores; at most 1024). The output does not depend on it.
        #[arg(long, value_parser = parse_threads)]
        threads: Option<usize>,
        /// No progress bar and no summary.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Simplify a model with our QEM and write it as one GLB (to compare simplifiers).
    #[command(after_help = "Examples:
  bimtiles simplify duplex.glb --out duplex-half.glb
  bimtiles simplify duplex.ifc --out coarse.glb --ratio 0.1 --max-error 0.05 --json")]
    Simplify {
        /// Input model (.glb, .gltf, .ifc).
        input: PathBuf,
        /// Output GLB.
        #[arg(long, short)]
        out: PathBuf,
        /// Fraction of triangles to keep.
        #[arg(long, default_value_t = 0.5)]
        ratio: f32,
        /// Stop once the error would exceed this (metres).
        #[arg(long)]
        max_error: Option<f64>,
        /// Print JSON for scripts.
        #[arg(long)]
        json: bool,
    },
    /// Serve a tileset and the CesiumJS viewer over HTTP (loopback by default).
    #[command(after_help = "Examples:
  bimtiles serve tiles/duplex            # then open http://127.0.0.1:8080/
  bimtiles serve tiles/campus --port 9000 --log")]
    Serve {
        /// The tileset folder (holding tileset.json).
        dir: PathBuf,
        #[arg(long, default_value_t = 8080)]
        port: u16,
        #[arg(long, default_value = "127.0.0.1")]
        host: String,
        /// The viewer page's folder (default: the repository's viewer/).
        #[arg(long, env = "BIMTILES_VIEWER_DIR")]
        viewer_dir: Option<PathBuf>,
        /// CesiumJS's Build/Cesium folder (default: tools/node_modules/cesium/Build/Cesium).
        #[arg(long, env = "BIMTILES_CESIUM_DIR")]
        cesium_dir: Option<PathBuf>,
        /// Log every request on stderr.
        #[arg(long)]
        log: bool,
    },
    /// Summarise a tileset per level (tiles, triangles, bytes, geometric error).
    #[command(after_help = "Examples:
  bimtiles inspect tiles/duplex
  bimtiles inspect tiles/duplex --json > levels.json
  bimtiles inspect tiles/duplex --feature GLOBAL_ID")]
    Inspect {
        /// The tileset folder (holding tileset.json).
        dir: PathBuf,
        /// Print JSON for scripts.
        #[arg(long)]
        json: bool,
        /// Show one element instead: its properties and the tiles that draw it (id = GlobalId
        /// or node path).
        #[arg(long)]
        feature: Option<String>,
    },
    /// Print a shell completion script (bash, zsh, fish, elvish, powershell) on stdout.
    #[command(after_help = "Examples:
  bimtiles completions bash > /etc/bash_completion.d/bimtiles
  bimtiles completions zsh > ~/.zfunc/_bimtiles")]
    Completions {
        /// The shell to complete for.
        shell: clap_complete::Shell,
    },
    /// Print the manual page (roff) on stdout, or write one page per subcommand into a folder.
    #[command(after_help = "Examples:
  bimtiles man > bimtiles.1 && man ./bimtiles.1
  bimtiles man --out-dir /usr/local/share/man/man1")]
    Man {
        /// Write bimtiles.1 and bimtiles-SUBCOMMAND.1 here instead.
        #[arg(long)]
        out_dir: Option<PathBuf>,
    },
}

#[derive(Args)]
struct ConvertArgs {
    /// Input models (.ifc, .glb, .gltf, .city.json, .jsonl, .gml, .xml, .gml.gz, .obj, .fbx).
    /// Without any, the bundled sample building is converted.
    inputs: Vec<PathBuf>,
    /// A manifest of many models (JSON): models placed by longitude/latitude/height/heading or
    /// by an east/north/up offset, converted into one tileset (the book's "Campus manifests").
    #[arg(long, conflicts_with = "inputs")]
    manifest: Option<PathBuf>,
    /// Output folder (must not exist, unless --force).
    #[arg(long, short)]
    out: PathBuf,
    /// Replace an existing output folder that holds a tileset.
    #[arg(long)]
    force: bool,
    /// Bring the tileset in --out up to date with the inputs and options: nothing is built when
    /// they, and the tool, are those it was built from (no model is read); otherwise it is built
    /// again and published over the old one, whose unchanged files stay as they are (the book's
    /// "Updating a tileset"). The old tileset stays complete until the switch.
    #[arg(long)]
    update: bool,
    /// With --update: keep the files the new tileset no longer has, for clients that still hold
    /// the old tileset.json.
    #[arg(long, requires = "update")]
    keep_stale: bool,
    /// Geographic place of the model's anchor: LON,LAT[,HEIGHT] (degrees, degrees, metres on WGS84).
    #[arg(long, value_parser = GeoOrigin::parse, allow_hyphen_values = true)]
    origin: Option<GeoOrigin>,
    /// Projected CRS of the inputs' map coordinates (EPSG:CODE, a bare code, or a name PROJ
    /// knows): glTF/GLB positions are easting (+x), northing (-z), height (+y); an IFC
    /// IfcMapConversion that names no usable CRS is in it.
    #[arg(long)]
    crs: Option<String>,
    /// CityJSON: the level of detail to read ("2.2", "1.3"...); an object without it is left
    /// out. Default: each object's highest.
    #[arg(long)]
    cityjson_lod: Option<String>,
    /// OBJ: the model's up axis, y or z. Default: y.
    #[arg(long, value_name = "AXIS")]
    up: Option<bimtiles::ingest::interchange::UpAxis>,
    /// OBJ: the length one model unit stands for: m, cm, mm, ft or in. Default: m (cm when the
    /// file's header says "uses centimeters as units").
    #[arg(long, value_name = "UNIT")]
    unit: Option<bimtiles::ingest::interchange::LengthUnit>,
    /// CityGML: the level of detail to read (0 to 4); an object without it is left out.
    /// Default: each object's highest.
    #[arg(long)]
    citygml_lod: Option<String>,
    /// CityGML: the appearance theme to draw (textures and materials). Default: the file's
    /// first.
    #[arg(long)]
    citygml_theme: Option<String>,
    /// A georeference that cannot be used (unknown CRS, unit not a length, far outside the CRS's
    /// area of use) is an error and nothing is written, instead of a warning and the default
    /// placement.
    #[arg(long)]
    strict_georef: bool,
    /// Split an octree cell while its content has more triangles than this.
    #[arg(long, default_value_t = OctreeOptions::default().max_tile_triangles, value_parser = parse_at_least_one)]
    max_tile_triangles: usize,
    /// Split an octree cell while its content is larger than this many (uncompressed) bytes.
    #[arg(long, default_value_t = OctreeOptions::default().max_tile_bytes, value_parser = parse_at_least_one)]
    max_tile_bytes: usize,
    /// Development option (hidden): split an octree cell whose content spans more than this many
    /// metres, even within the budgets. `inf` lifts the rule, so that a wide model within the
    /// budgets can be one tile (the browser benchmark's single-tile raw variant).
    #[arg(long, hide = true, default_value_t = OctreeOptions::default().max_leaf_extent_m, value_parser = parse_leaf_extent)]
    max_leaf_extent_m: f64,
    /// Geometry compression of the tiles: meshopt (KHR_mesh_quantization attributes as
    /// EXT_meshopt_compression streams: decoded on the client's main thread, the fastest first
    /// view), draco (KHR_draco_mesh_compression: the smallest files, decoded in a worker one
    /// primitive at a time), quantized (KHR_mesh_quantization: 16-bit positions within 1 mm, 8-bit
    /// normals, 16-bit UVs) or none (32-bit floats).
    /// Default: meshopt.
    #[arg(long, value_enum)]
    compression: Option<CompressionArg>,
    /// The 3D Tiles client the tileset is packaged for: cesium (CesiumJS; the default, every
    /// packaging that makes its first view fastest), three (three.js with 3DTilesRendererJS: no
    /// GPU instancing, so every element is pickable), deckgl (deck.gl / loaders.gl Tile3DLayer:
    /// no root inlined in tileset.json, materials kept apart instead of merged into vertex
    /// colours, no GPU instancing, the schema inline in every tile, meshopt) or portable (what
    /// every one of these clients loads and picks in: deckgl's choices). A profile never changes
    /// geometry or metadata, only how they are packaged. Flags that turn a packaging off agree
    /// with any profile; --compression draco with deckgl or portable is an error.
    #[arg(long, value_enum, default_value = "cesium")]
    client: ClientArg,
    /// Edges drawn the way CAD and BIM tools draw them (EXT_mesh_primitive_edge_visibility on
    /// every primitive, shown by CesiumJS's edgeDisplayMode): all (outlines and creases, and the
    /// silhouettes of curved surfaces), hard (outlines and creases only) or none.
    /// Off by default: on some BIM models even hard adds more bytes to the gzipped tiles than a
    /// default may (book: guide/edges.md, "What edges cost").
    #[arg(long, value_enum, default_value = "none")]
    edges: EdgesArg,
    /// Two faces of one element that meet at more than this angle (degrees) draw a hard edge;
    /// below it, a curved surface draws only its silhouette.
    #[arg(long, default_value_t = bimtiles::encode::edges::DEFAULT_CREASE_ANGLE_DEG, value_parser = parse_edge_angle)]
    edge_angle_deg: f64,
    /// Levels of detail: hlod (internal tiles carry their subtree simplified with our QEM,
    /// refine REPLACE) or none (internal tiles hold only what is too big for their children,
    /// refine ADD).
    #[arg(long, value_enum, default_value = "hlod")]
    lod: LodArg,
    /// Discrete LOD chains instead of HLOD (the paper's LOD1..LOD3): every leaf tile becomes a
    /// chain of tiles with its bounds, simplified to these fractions of its triangles, coarsest
    /// first, full detail last (refine REPLACE). E.g. 0.85,0.7,0.5.
    #[arg(long, value_delimiter = ',', conflicts_with = "lod")]
    lod_ratios: Option<Vec<f32>>,
    /// How coarse HLOD tiles get: up to two smaller triangle targets are tried, each measured,
    /// while their error stays under this fraction of the error at which a viewer that frames the
    /// tile draws it (16 px SSE at 1080 px, 60° field of view). 0: no coarser than the tile
    /// budget and a quarter of what the children draw.
    #[arg(long, default_value_t = bimtiles::convert::DEFAULT_HLOD_ERROR_FRACTION)]
    hlod_error_fraction: f64,
    /// Properties in the tables of simplified (coarse) tiles: identity (id, name, class, storey,
    /// building, site, material, source, aliases; property sets and hierarchy paths only in
    /// full-detail tiles, so a first view stays small) or all.
    #[arg(long, value_enum, default_value = "identity")]
    coarse_properties: CoarsePropertiesArg,
    /// Keep a model that the tile budgets leave as one tile as that one tile. By default, when
    /// that tile is heavy (textures, geometry), a coarse root simplified to what a viewer framing
    /// the model needs, with texture levels to match, goes above it when it saves the first view
    /// at least 100 KB.
    #[arg(long)]
    no_coarse_root: bool,
    /// Keep the root tile's GLB a file of its own. By default it goes into tileset.json as a data
    /// URI (3D Tiles 1.1 allows it), so that a one-tile model's first view is one request instead
    /// of two. That is done when the GLB names no other file (texture files, a schema file),
    /// base64's third more bytes stay within a request's worth (100 KB), and its buffer views,
    /// accessors, images and textures times the URI's length stay within 10 million characters
    /// (CesiumJS hashes the URI once per resource); report.json marks the tile
    /// `inlined_in_tileset`.
    #[arg(long)]
    no_inline_root: bool,
    /// geometricError of simplified tiles: measured (the real distance to full detail, checked;
    /// default) or paper-sse (the paper's screen-space error of the longest collapsed edge,
    /// formulas (1) and (2): not a distance bound). The report shows both per level.
    #[arg(long, value_enum, default_value = "measured")]
    error_metric: ErrorMetricArg,
    /// Keep every component as read: no exact-duplicate removal, no sharing of congruent shapes.
    #[arg(long)]
    no_dedup: bool,
    /// Largest distance (metres) between corresponding vertices of two components that are
    /// still the same geometry (dedup).
    #[arg(long, default_value_t = DedupOptions::default().tolerance_m)]
    dedup_tolerance_m: f64,
    /// Write every copy of a repeated shape as plain geometry, for viewers without
    /// EXT_mesh_gpu_instancing.
    #[arg(long)]
    no_instancing: bool,
    /// Instance a shape in a tile only when that stores at least this many fewer triangles
    /// (smaller savings do not pay for the shape's own node, accessors and draw call).
    /// Default: 1000 with Draco and meshopt, 100 otherwise.
    #[arg(long)]
    min_instanced_triangles_saved: Option<usize>,
    /// One primitive per material in every tile. Default with Draco: plain-coloured materials
    /// that differ only in base colour share one primitive, the colours per vertex (fewer draw
    /// calls and Draco streams); without compression materials are kept apart.
    #[arg(long)]
    keep_materials: bool,
    /// Texture level per tile matched to its geometric error (Haar wavelet pyramid): on or off
    /// (every tile gets the full-resolution images).
    #[arg(long, value_enum, default_value = "on")]
    texture_lod: OnOff,
    /// Crop the area of standalone and shared textures that no UV reaches (UVs remapped).
    #[arg(long, value_enum, default_value = "on")]
    texture_crop: OnOff,
    /// Encoding of coarser texture levels: auto (PNG stays PNG, JPEG stays JPEG), png or jpeg;
    /// ktx2: every level, the finest included, as KTX2 / Basis Universal (KHR_texture_basisu).
    #[arg(long, value_enum, default_value = "auto")]
    texture_format: TextureFormatArg,
    /// JPEG quality (1-100) of re-encoded JPEG texture levels.
    #[arg(long, default_value_t = bimtiles::texture::DEFAULT_JPEG_QUALITY,
          value_parser = clap::value_parser!(u8).range(1..=100))]
    jpeg_quality: u8,
    /// Embed each tile's textures in its GLB instead of writing each image level once under
    /// textures/ and referencing it from the tiles.
    #[arg(long)]
    embed_textures: bool,
    /// Embed the texture levels smaller than this many bytes even when sharing texture files.
    #[arg(long, default_value_t = bimtiles::texture::DEFAULT_EMBED_BELOW_BYTES)]
    embed_textures_below: usize,
    /// Pack each tile's small non-repeating textures into one atlas image when that saves
    /// requests and bytes (UVs remapped): on or off.
    #[arg(long, value_enum, default_value = "off")]
    texture_atlas: OnOff,
    /// Worker threads (default: all cores; at most 1024). The output does not depend on it.
    #[arg(long, value_parser = parse_threads)]
    threads: Option<usize>,
    /// Memory the conversion aims to stay within (e.g. 4G, 512M, 800MB; `none`: no limit). Past a
    /// quarter of it, mesh geometry is spilled to a temporary file and read back when used. The
    /// output does not depend on it.
    #[arg(long, default_value = "4G", value_parser = parse_budget)]
    memory_budget: Budget,
    /// Folder for the spill file (default: the output's folder; not a RAM-backed /tmp). The file
    /// has no name and is gone when the process ends.
    #[arg(long)]
    spill_dir: Option<PathBuf>,
    /// No progress bars and no summary (report.json is still written).
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Parser)]
#[command(name = "bimtiles plan")]
struct PlanArgs {
    #[command(flatten)]
    convert: ConvertArgs,
    /// Number of subtree jobs.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    jobs: u64,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum LodArg {
    Hlod,
    None,
}

#[derive(Clone, Copy, PartialEq, clap::ValueEnum)]
enum ErrorMetricArg {
    Measured,
    PaperSse,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum CoarsePropertiesArg {
    Identity,
    All,
}

#[derive(Clone, Copy, PartialEq, clap::ValueEnum)]
enum OnOff {
    On,
    Off,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum TextureFormatArg {
    Auto,
    Png,
    Jpeg,
    Ktx2,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum ClientArg {
    Cesium,
    Three,
    Deckgl,
    Portable,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum EdgesArg {
    All,
    Hard,
    None,
}

/// A crease angle in degrees: above 0, at most 180.
fn parse_edge_angle(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s.parse().map_err(|e| format!("{e}"))?;
    if v > 0.0 && v <= 180.0 {
        Ok(v)
    } else {
        Err(format!("{v} is not an angle in (0, 180] degrees"))
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum CompressionArg {
    Draco,
    Quantized,
    Meshopt,
    None,
}

/// The whole command line as clap defines it: the completions, the manual and the book's CLI
/// reference (`examples/cli_reference.rs`) are all generated from it.
pub fn command() -> clap::Command {
    Cli::command()
}

/// Prints to stdout; a closed pipe (`| head`) ends the output quietly instead of failing.
/// The manual: the top page on stdout, or every page (the top one and one per subcommand) in
/// `out_dir`.
fn write_man_pages(out_dir: Option<&std::path::Path>) -> Result<()> {
    let top = command();
    let render = |cmd: clap::Command| -> Result<Vec<u8>> {
        let mut out = Vec::new();
        clap_mangen::Man::new(cmd).render(&mut out)?;
        Ok(out)
    };
    let Some(dir) = out_dir else {
        return emit(&String::from_utf8_lossy(&render(top)?));
    };
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let mut pages = vec![("bimtiles".to_string(), top.clone())];
    for sub in top.get_subcommands().filter(|c| c.get_name() != "help") {
        let name = format!("bimtiles-{}", sub.get_name());
        pages.push((name.clone(), sub.clone().name(name)));
    }
    for (name, cmd) in pages {
        let path = dir.join(format!("{name}.1"));
        std::fs::write(&path, render(cmd)?)
            .with_context(|| format!("{}: cannot write", path.display()))?;
    }
    Ok(())
}

fn emit(text: &str) -> Result<()> {
    use std::io::Write;
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

pub fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Convert(a) => run_convert(a),
        Command::Completions { shell } => {
            let mut out = Vec::new();
            clap_complete::generate(shell, &mut command(), "bimtiles", &mut out);
            emit(&String::from_utf8_lossy(&out))
        }
        Command::Man { out_dir } => write_man_pages(out_dir.as_deref()),
        Command::Plan(a) => run_plan(a),
        Command::BuildJob {
            dir,
            job,
            threads,
            quiet,
        } => {
            set_threads(threads)?;
            let (inputs, opts) = planned(&dir, quiet)?;
            let s = bimtiles::shard::build_job(&opts.out_dir, job, &inputs, &opts)?;
            if !quiet {
                emit(&format!(
                    "job {}: {} tiles in {:.2} s\n",
                    s.job, s.tiles, s.seconds
                ))?;
            }
            Ok(())
        }
        Command::Merge {
            dir,
            threads,
            quiet,
        } => {
            set_threads(threads)?;
            let (inputs, opts) = planned(&dir, quiet)?;
            let r = match bimtiles::shard::merge(&opts.out_dir, &inputs, &opts)? {
                Updated::Built(r) => r,
                Updated::UpToDate(u) => {
                    if !quiet {
                        emit(&format!(
                            "{}: up to date, nothing built\n{}\n",
                            dir.display(),
                            u.summary()
                        ))?;
                    }
                    return Ok(());
                }
            };
            if !quiet {
                if let Some(note) = r.update.as_ref().and_then(|u| u.build_note()) {
                    eprintln!("note: update: {note}");
                }
                print_warnings(&r);
                emit(&format!(
                    "merged {}: {} tiles, {} triangles, {}\n",
                    dir.display(),
                    r.output.tiles,
                    r.output.triangles,
                    human_bytes(r.output.bytes)
                ))?;
                if let Some(u) = &r.update {
                    emit(&format!("{}\n", u.summary()))?;
                }
            }
            Ok(())
        }
        Command::Serve {
            dir,
            port,
            host,
            viewer_dir,
            cesium_dir,
            log,
        } => {
            // Installed by `make` into the repository; the binary remembers where that is.
            let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
            let mut opts = bimtiles::serve::ServeOptions::new(
                dir,
                viewer_dir.unwrap_or_else(|| repo.join("viewer")),
            );
            opts.cesium_dir = Some(
                cesium_dir.unwrap_or_else(|| repo.join("tools/node_modules/cesium/Build/Cesium")),
            );
            opts.host = host;
            opts.port = port;
            opts.log_requests = log;
            Ok(bimtiles::serve::serve(&opts)?)
        }
        Command::Simplify {
            input,
            out,
            ratio,
            max_error,
            json,
        } => {
            if !(ratio > 0.0 && ratio <= 1.0) {
                anyhow::bail!("--ratio must be in (0, 1], got {ratio}");
            }
            let opts = SimplifyOptions {
                target_ratio: ratio,
                target_error_m: max_error,
                ..Default::default()
            };
            let r = bimtiles::convert::simplify_model(&input, &out, &opts)?;
            if json {
                emit(&format!("{}\n", serde_json::to_string_pretty(&r)?))
            } else {
                emit(&format!(
                    "{} -> {}: {} -> {} triangles, error {:.4} m, {:.2} s\n",
                    r.input, r.output, r.triangles_in, r.triangles_out, r.error_m, r.seconds
                ))
            }
        }
        Command::Inspect {
            dir,
            json,
            feature: Some(id),
        } => match bimtiles::inspect::find_feature(&dir, &id)? {
            Some(f) if json => emit(&format!("{}\n", serde_json::to_string_pretty(&f)?)),
            Some(f) => emit(&f.to_string()),
            None => anyhow::bail!("{}: no element with id '{id}' in its tiles", dir.display()),
        },
        Command::Inspect { dir, json, .. } => {
            let s = inspect(&dir)?;
            if json {
                emit(&format!("{}\n", serde_json::to_string_pretty(&s)?))
            } else {
                emit(&s.to_string())
            }
        }
    }
}

/// Most worker threads accepted: past it a typo (`--threads 4000000000`) would exhaust the
/// process's memory and thread limits before any work is done.
const MAX_THREADS: usize = 1024;

fn parse_threads(text: &str) -> std::result::Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(n) if (1..=MAX_THREADS).contains(&n) => Ok(n),
        _ => Err(format!(
            "'{text}' is not a thread count from 1 to {MAX_THREADS}"
        )),
    }
}

fn parse_leaf_extent(text: &str) -> std::result::Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v > 0.0 => Ok(v),
        _ => Err(format!(
            "'{text}' is not a length in metres above 0 (or inf)"
        )),
    }
}

fn parse_at_least_one(text: &str) -> std::result::Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(format!("'{text}' is not a whole number of at least 1")),
    }
}

/// Largest `--memory-budget` accepted (1 PiB): anything above is a typo, not a machine.
const MAX_BUDGET_BYTES: f64 = (1u64 << 50) as f64;

/// `--memory-budget` in bytes; `None`: no limit.
#[derive(Debug, Clone, Copy)]
struct Budget(Option<u64>);

/// `--memory-budget`: a number with an optional K, M, G or T (powers of 1024; a trailing B or iB
/// is allowed), or `none`.
fn parse_budget(text: &str) -> std::result::Result<Budget, String> {
    let t = text.trim().to_ascii_lowercase();
    if t == "none" {
        return Ok(Budget(None));
    }
    let t = t.trim_end_matches("ib").trim_end_matches('b');
    let (number, unit) = match t.char_indices().find(|(_, c)| c.is_ascii_alphabetic()) {
        Some((i, _)) => t.split_at(i),
        None => (t, ""),
    };
    let scale: u64 = match unit {
        "" => 1,
        "k" => 1 << 10,
        "m" => 1 << 20,
        "g" => 1 << 30,
        "t" => 1 << 40,
        _ => return Err(format!("unknown unit in '{text}' (use K, M, G or T)")),
    };
    match number.trim().parse::<f64>() {
        Ok(n) if n.is_finite() && n > 0.0 && n * scale as f64 > MAX_BUDGET_BYTES => {
            Err(format!("'{text}' is more than 1P (use none for no limit)"))
        }
        Ok(n) if n.is_finite() && n > 0.0 => Ok(Budget(Some((n * scale as f64) as u64))),
        _ => Err(format!("'{text}' is not a size (e.g. 4G, 512M, none)")),
    }
}

/// Sets the process's memory budget (read by every mesh store created after); `out` is where the
/// output goes.
fn set_budget(a: &ConvertArgs, out: &std::path::Path) -> Result<()> {
    if let Some(d) = a.spill_dir.as_ref().filter(|d| !d.is_dir()) {
        anyhow::bail!("--spill-dir {}: no such folder", d.display());
    }
    // The spill file goes beside the output, on the first folder of its path that exists.
    let spill_dir = a.spill_dir.clone().or_else(|| {
        let out = std::path::absolute(out).ok()?;
        out.ancestors()
            .skip(1)
            .find(|d| d.is_dir())
            .map(PathBuf::from)
    });
    bimtiles::scene::set_memory_budget(
        a.memory_budget
            .0
            .map(|bytes| bimtiles::scene::MemoryBudget { bytes, spill_dir }),
    );
    Ok(())
}

fn set_threads(threads: Option<usize>) -> Result<()> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("cannot set up worker threads")?;
    }
    Ok(())
}

/// `bimtiles plan`: the arguments after `plan` are kept in plan.json (with the working folder), so
/// that build-job and merge re-create the same inputs and options.
fn run_plan(a: PlanArgs) -> Result<()> {
    set_threads(a.convert.threads)?;
    set_budget(&a.convert, &a.convert.out)?;
    let opts = convert_options(&a.convert)?;
    let argv: Vec<String> = std::env::args().collect();
    let at = argv.iter().position(|s| s == "plan").unwrap_or(argv.len());
    let cwd = std::env::current_dir().context("cannot read the working folder")?;
    let command = serde_json::json!({
        "cwd": cwd,
        "args": &argv[(at + 1).min(argv.len())..],
    });
    let inputs = InputSet::new(&a.convert.inputs, a.convert.manifest.as_deref());
    let p = bimtiles::shard::plan(&inputs, &opts, a.jobs as usize, command)?;
    if let (Some(u), false) = (&p.update, a.convert.quiet) {
        let run = p.jobs.iter().filter(|j| j.changed).count();
        let reason = u.full_build_reason.as_deref().unwrap_or_default();
        let note = u.tile_cache_note.as_ref().map(|n| format!("; {n}"));
        if u.up_to_date {
            emit(&format!(
                "{}: up to date, no job to run (merge rewrites report.json)\n",
                a.convert.out.display()
            ))?;
        } else if run == p.jobs.len() || u.tile_cache_note.is_some() {
            // (A cache with a note gives nothing: every job with an HLOD tile runs, and jobs of
            // leaves alone have nothing to run.)
            eprintln!(
                "note: update: full build: {reason}{}",
                note.unwrap_or_default()
            );
        } else {
            eprintln!(
                "note: update: {reason}; {run} of {} jobs to run",
                p.jobs.len()
            );
        }
    }
    if !a.convert.quiet && !p.update.as_ref().is_some_and(|u| u.up_to_date) {
        emit(&format!(
            "{}: {} tiles, {} built by merge, {} jobs (triangles per job: {})\n",
            a.convert.out.display(),
            p.tiles,
            p.top.len(),
            p.jobs.len(),
            p.jobs
                .iter()
                .map(|j| j.triangles.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ))?;
    }
    Ok(())
}

/// The inputs and options a plan was made with (paths relative to the folder `plan` ran in).
fn planned(dir: &std::path::Path, quiet: bool) -> Result<(InputSet, ConvertOptions)> {
    let file = bimtiles::shard::read_plan(dir)?;
    let bad = || anyhow::anyhow!("{}: the plan's command is unreadable", dir.display());
    let cwd = PathBuf::from(file.command["cwd"].as_str().ok_or_else(bad)?);
    let args: Vec<String> =
        serde_json::from_value(file.command["args"].clone()).map_err(|_| bad())?;
    let a = PlanArgs::try_parse_from(std::iter::once("plan".to_string()).chain(args))
        .map_err(|e| anyhow::anyhow!("{}: the plan's command: {e}", dir.display()))?;
    let mut opts = convert_options(&a.convert)?;
    opts.out_dir = std::path::absolute(dir).context("cannot resolve the build folder")?;
    set_budget(&a.convert, &opts.out_dir.join("tileset"))?;
    opts.force = false;
    opts.progress = !quiet;
    // Where the plan was made, so that relative input paths (and the report's names for them)
    // are the plan's; a machine without that folder needs absolute input paths in the plan.
    std::env::set_current_dir(&cwd).with_context(|| {
        format!(
            "{}: the plan was made in {}, which is not here (plan with absolute input paths)",
            dir.display(),
            cwd.display()
        )
    })?;
    let inputs = InputSet::new(&a.convert.inputs, a.convert.manifest.as_deref());
    Ok((inputs, opts))
}

fn run_convert(a: ConvertArgs) -> Result<()> {
    set_threads(a.threads)?;
    set_budget(&a, &a.out)?;
    let opts = convert_options(&a)?;
    let inputs = InputSet::new(&a.inputs, a.manifest.as_deref());
    let r = match bimtiles::convert::update_input_set(&inputs, &opts)? {
        Updated::Built(r) => r,
        Updated::UpToDate(u) => {
            if !a.quiet {
                emit(&format!(
                    "{}: up to date, nothing built\n{}\n",
                    a.out.display(),
                    u.summary()
                ))?;
            }
            return Ok(());
        }
    };
    if !a.quiet {
        if let Some(note) = r.update.as_ref().and_then(|u| u.build_note()) {
            eprintln!("note: update: {note}");
        }
        print_warnings(&r);
        print_summary(&a, &r)?;
        if let Some(u) = &r.update {
            emit(&format!("{}\n", u.summary()))?;
        }
    }
    Ok(())
}

fn convert_options(a: &ConvertArgs) -> Result<ConvertOptions> {
    let compression_asked = a.compression.map(|c| match c {
        CompressionArg::Draco => Compression::Draco,
        CompressionArg::Quantized => Compression::Quantized,
        CompressionArg::Meshopt => Compression::Meshopt,
        CompressionArg::None => Compression::None,
    });
    let mut opts = ConvertOptions {
        out_dir: a.out.clone(),
        force: a.force,
        origin: a.origin,
        crs: a.crs.clone(),
        cityjson_lod: a.cityjson_lod.clone(),
        mesh_frame: bimtiles::ingest::interchange::MeshFrame {
            up: a.up,
            unit: a.unit,
        },
        citygml_lod: a.citygml_lod.clone(),
        citygml_theme: a.citygml_theme.clone(),
        strict_georef: a.strict_georef,
        octree: OctreeOptions {
            max_tile_triangles: a.max_tile_triangles,
            max_tile_bytes: a.max_tile_bytes.max(1),
            max_leaf_extent_m: a.max_leaf_extent_m,
            ..OctreeOptions::default()
        },
        compression: compression_asked.unwrap_or_default(),
        edges: bimtiles::encode::edges::EdgeOptions {
            mode: match a.edges {
                EdgesArg::All => bimtiles::encode::edges::EdgeMode::All,
                EdgesArg::Hard => bimtiles::encode::edges::EdgeMode::Hard,
                EdgesArg::None => bimtiles::encode::edges::EdgeMode::None,
            },
            crease_angle_deg: a.edge_angle_deg,
        },
        lod: match (&a.lod_ratios, a.lod) {
            (Some(r), _) => LodMode::Ratios(
                bimtiles::lod::chain_levels::chain_ratios(r).context("--lod-ratios")?,
            ),
            (None, LodArg::Hlod) => LodMode::Hlod,
            (None, LodArg::None) => LodMode::None,
        },
        error_metric: match a.error_metric {
            ErrorMetricArg::Measured => ErrorMetric::Measured,
            ErrorMetricArg::PaperSse => ErrorMetric::PaperSse,
        },
        simplify: SimplifyOptions::default(),
        hlod_error_fraction: a.hlod_error_fraction,
        coarse_tile_properties: match a.coarse_properties {
            CoarsePropertiesArg::Identity => CoarseTileProperties::Identity,
            CoarsePropertiesArg::All => CoarseTileProperties::All,
        },
        coarse_root: !a.no_coarse_root,
        inline_root: !a.no_inline_root,
        dedup: (!a.no_dedup).then(|| DedupOptions {
            tolerance_m: a.dedup_tolerance_m,
            ..DedupOptions::default()
        }),
        instancing: !a.no_instancing,
        min_instanced_triangles_saved: a.min_instanced_triangles_saved,
        merge_plain_materials: a.keep_materials.then_some(false),
        client: Client::default(),
        schema_in_every_tile: false,
        progress: !a.quiet,
        update: a.update,
        keep_stale: a.keep_stale,
        texture: TextureOptions {
            lod: a.texture_lod == OnOff::On,
            crop: a.texture_crop == OnOff::On,
            embed: a.embed_textures,
            embed_below_bytes: a.embed_textures_below,
            format: match a.texture_format {
                TextureFormatArg::Auto => TextureFormat::Auto,
                TextureFormatArg::Png => TextureFormat::Png,
                TextureFormatArg::Jpeg => TextureFormat::Jpeg,
                TextureFormatArg::Ktx2 => TextureFormat::Ktx2,
            },
            jpeg_quality: a.jpeg_quality,
            atlas: a.texture_atlas == OnOff::On,
        },
    };
    let client = match a.client {
        ClientArg::Cesium => Client::Cesium,
        ClientArg::Three => Client::Three,
        ClientArg::Deckgl => Client::Deckgl,
        ClientArg::Portable => Client::Portable,
    };
    client.apply(&mut opts, compression_asked)?;
    if opts.lod == LodMode::None && opts.error_metric == ErrorMetric::PaperSse {
        anyhow::bail!(
            "--error-metric paper-sse needs simplified tiles: use --lod hlod or --lod-ratios"
        );
    }
    if !(a.hlod_error_fraction.is_finite() && a.hlod_error_fraction >= 0.0) {
        anyhow::bail!(
            "--hlod-error-fraction must be a number >= 0, got {}",
            a.hlod_error_fraction
        );
    }
    if !(a.dedup_tolerance_m.is_finite() && a.dedup_tolerance_m >= 0.0) {
        anyhow::bail!(
            "--dedup-tolerance-m must be a distance in metres, got {}",
            a.dedup_tolerance_m
        );
    }
    Ok(opts)
}

/// The report's warnings, one `warning:` line each on stderr.
fn print_warnings(r: &bimtiles::convert::Report) {
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
}

fn print_summary(a: &ConvertArgs, r: &bimtiles::convert::Report) -> Result<()> {
    {
        if let Some(d) = &r.dedup {
            emit(&format!(
                "dedup: {} components, {} shapes drawn, {} redundant copies removed, {} congruent copies share a shape ({:.2} s)\n",
                d.components, d.unique_shapes, d.redundant_removed, d.congruent_rewritten, d.seconds
            ))?;
        }
        emit(&format!(
            "{} -> {}\n\n  input : {} triangles, {} vertices, {} components{}, {}\n  output: {} tiles ({} with content), depth {}, {} triangles ({} stored, {} instances), {}\n  time  : {:.2} s (ingest {:.2}, partition {:.2}, encode+write {:.2}), peak memory {}",
            r.input.files.join(", "),
            a.out.display(),
            r.input.triangles,
            r.input.vertices,
            r.input.components,
            match r.input.renamed_ids {
                0 => String::new(),
                n => format!(" ({n} repeated ids numbered to stay unique)"),
            },
            human_bytes(r.input.bytes),
            r.output.tiles,
            r.output.tiles_with_content,
            r.output.max_depth,
            r.output.triangles,
            r.output.stored_triangles,
            r.output.instances,
            human_bytes(r.output.bytes),
            r.timings_s.total,
            r.timings_s.ingest,
            r.timings_s.partition,
            r.timings_s.encode_write,
            human_bytes(r.peak_memory_bytes),
        ))?;
        emit(&format!("\n  place : {}\n", place_line(&r.georeference)))?;
        if r.output.edge_bytes > 0 {
            emit(&format!("  edges : {}\n", edges_line(r)))?;
        }
    }
    Ok(())
}

/// What the edges cost, gzipped as served: over all tiles and over the tiles of a first
/// whole-model view (`inspect`'s selection; the root inlined in tileset.json is its tile).
fn edges_line(r: &bimtiles::convert::Report) -> String {
    format!(
        "{} gzipped over all tiles ({} as stored), {} on the first view",
        human_bytes(r.output.edge_gzip_bytes),
        human_bytes(r.output.edge_bytes),
        human_bytes(r.output.first_view_edge_gzip_bytes),
    )
}

/// Where the tileset landed: longitude, latitude, height, the CRS and the field that named it.
fn place_line(g: &bimtiles::report::GeoReport) -> String {
    let o = g.origin;
    use bimtiles::geodesy::OriginSource;
    let by = match (g.origin_source, g.crs.first()) {
        (OriginSource::Option, _) => "--origin".to_string(),
        (OriginSource::InputCrs, Some(c)) => {
            format!("{} ({}), from {}", c.crs, c.crs_name, c.source)
        }
        (OriginSource::InputCrs, None) => "a projected CRS".to_string(),
        (OriginSource::InputSite, _) => "the input's site reference (WGS 84)".to_string(),
        (OriginSource::Default, _) => "the default origin: the input names no place".to_string(),
    };
    format!(
        "{:.6}° {}, {:.6}° {}, height {:.2} m, by {by}",
        o.longitude_deg.abs(),
        if o.longitude_deg < 0.0 { 'W' } else { 'E' },
        o.latitude_deg.abs(),
        if o.latitude_deg < 0.0 { 'S' } else { 'N' },
        o.height_m
    )
}
