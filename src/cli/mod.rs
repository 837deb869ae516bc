//! Command-line interface: parses arguments, calls the library, prints. Nothing else lives here.

use anyhow::{Context, Result};
use bimtiles::convert::{convert, ConvertOptions, ErrorMetric, LodMode};
use bimtiles::dedup::DedupOptions;
use bimtiles::encode::Compression;
use bimtiles::inspect::{human_bytes, inspect};
use bimtiles::partition::OctreeOptions;
use bimtiles::simplify::SimplifyOptions;
use bimtiles::texture::{TextureFormat, TextureOptions};
use bimtiles::tileset::georef::GeoOrigin;
use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "bimtiles",
    version,
    about = "Building models (glTF/GLB) to OGC 3D Tiles 1.1"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert models into a 3D Tiles 1.1 tileset.
    Convert(ConvertArgs),
    /// Simplify a model with our QEM and write it as one GLB (to compare simplifiers).
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
}

#[derive(Args)]
struct ConvertArgs {
    /// Input models (.glb, .gltf). Without any, the bundled sample building is converted.
    inputs: Vec<PathBuf>,
    /// Output folder (must not exist, unless --force).
    #[arg(long, short)]
    out: PathBuf,
    /// Replace an existing output folder that holds a tileset.
    #[arg(long)]
    force: bool,
    /// Geographic place of the model's anchor: LON,LAT[,HEIGHT] (degrees, degrees, metres on WGS84).
    #[arg(long, value_parser = GeoOrigin::parse, allow_hyphen_values = true)]
    origin: Option<GeoOrigin>,
    /// Split an octree cell while its content has more triangles than this.
    #[arg(long, default_value_t = OctreeOptions::default().max_tile_triangles)]
    max_tile_triangles: usize,
    /// Split an octree cell while its content is larger than this many (uncompressed) bytes.
    #[arg(long, default_value_t = OctreeOptions::default().max_tile_bytes)]
    max_tile_bytes: usize,
    /// Geometry compression of the tiles: draco (KHR_draco_mesh_compression) or none.
    #[arg(long, value_enum, default_value = "draco")]
    compression: CompressionArg,
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
    /// Default: 1000 with Draco, 100 without.
    #[arg(long)]
    min_instanced_triangles_saved: Option<usize>,
    /// Texture level per tile matched to its geometric error (Haar wavelet pyramid): on or off
    /// (every tile gets the full-resolution images).
    #[arg(long, value_enum, default_value = "on")]
    texture_lod: OnOff,
    /// Crop the area of standalone and shared textures that no UV reaches (UVs remapped).
    #[arg(long, value_enum, default_value = "on")]
    texture_crop: OnOff,
    /// Encoding of coarser texture levels: auto (PNG stays PNG, JPEG stays JPEG), png or jpeg.
    #[arg(long, value_enum, default_value = "auto")]
    texture_format: TextureFormatArg,
    /// JPEG quality (1-100) of re-encoded JPEG texture levels.
    #[arg(long, default_value_t = bimtiles::texture::DEFAULT_JPEG_QUALITY,
          value_parser = clap::value_parser!(u8).range(1..=100))]
    jpeg_quality: u8,
    /// Worker threads (default: all cores). The output does not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// No progress bars and no summary (report.json is still written).
    #[arg(long, short)]
    quiet: bool,
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
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum CompressionArg {
    Draco,
    None,
}

/// Prints to stdout; a closed pipe (`| head`) ends the output quietly instead of failing.
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

fn run_convert(a: ConvertArgs) -> Result<()> {
    if let Some(n) = a.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global()
            .context("cannot set up worker threads")?;
    }
    let opts = ConvertOptions {
        out_dir: a.out.clone(),
        force: a.force,
        origin: a.origin,
        octree: OctreeOptions {
            max_tile_triangles: a.max_tile_triangles.max(1),
            max_tile_bytes: a.max_tile_bytes.max(1),
            ..OctreeOptions::default()
        },
        compression: match a.compression {
            CompressionArg::Draco => Compression::Draco,
            CompressionArg::None => Compression::None,
        },
        lod: match (&a.lod_ratios, a.lod) {
            (Some(r), _) => LodMode::Ratios(
                bimtiles::simplify::lod_chain::chain_ratios(r)
                    .map_err(|e| anyhow::anyhow!("--lod-ratios: {e}"))?,
            ),
            (None, LodArg::Hlod) => LodMode::Hlod,
            (None, LodArg::None) => LodMode::None,
        },
        error_metric: match a.error_metric {
            ErrorMetricArg::Measured => ErrorMetric::Measured,
            ErrorMetricArg::PaperSse => ErrorMetric::PaperSse,
        },
        simplify: SimplifyOptions::default(),
        dedup: (!a.no_dedup).then(|| DedupOptions {
            tolerance_m: a.dedup_tolerance_m,
            ..DedupOptions::default()
        }),
        instancing: !a.no_instancing,
        min_instanced_triangles_saved: a.min_instanced_triangles_saved,
        progress: !a.quiet,
        texture: TextureOptions {
            lod: a.texture_lod == OnOff::On,
            crop: a.texture_crop == OnOff::On,
            format: match a.texture_format {
                TextureFormatArg::Auto => TextureFormat::Auto,
                TextureFormatArg::Png => TextureFormat::Png,
                TextureFormatArg::Jpeg => TextureFormat::Jpeg,
            },
            jpeg_quality: a.jpeg_quality,
        },
    };
    if opts.lod == LodMode::None && opts.error_metric == ErrorMetric::PaperSse {
        anyhow::bail!(
            "--error-metric paper-sse needs simplified tiles: use --lod hlod or --lod-ratios"
        );
    }
    if !(a.dedup_tolerance_m.is_finite() && a.dedup_tolerance_m >= 0.0) {
        anyhow::bail!(
            "--dedup-tolerance-m must be a distance in metres, got {}",
            a.dedup_tolerance_m
        );
    }
    let r = convert(&a.inputs, &opts)?;
    if !a.quiet {
        if let Some(d) = &r.dedup {
            emit(&format!(
                "dedup: {} components, {} shapes drawn, {} redundant copies removed, {} congruent copies share a shape ({:.2} s)\n",
                d.components, d.unique_shapes, d.redundant_removed, d.congruent_rewritten, d.seconds
            ))?;
        }
        emit(&format!(
            "{} -> {}\n\n  input : {} triangles, {} vertices, {} components, {}\n  output: {} tiles ({} with content), depth {}, {} triangles ({} stored, {} instances), {}\n  time  : {:.2} s (ingest {:.2}, partition {:.2}, encode+write {:.2}), peak memory {}",
            r.input.files.join(", "),
            a.out.display(),
            r.input.triangles,
            r.input.vertices,
            r.input.components,
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
    }
    Ok(())
}
