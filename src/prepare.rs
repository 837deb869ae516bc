//! Everything before the tiles are built, as one pure function of the input and the options (so
//! every process of a sharded build gets the same): read, place (anchor, georeference), dedup
//! (paper III.A), texture preparation (III.D) and the octree plan (IV.A).

use crate::dedup::{deduplicate, DedupReport};
use crate::error::{Error, Result};
use crate::geodesy::{GeoOrigin, OriginSource};
use crate::ingest::InputSet;
use crate::lod::chain_levels::with_lod_chains;
use crate::options::{LodMode, Settings};
use crate::partition::content::AppearanceClasses;
use crate::partition::{plan_octree, TilePlan};
use crate::scene::placement::{AnchorRule, Placement};
use crate::scene::Scene;
use crate::texture::admit::ImageLimits;
use glam::DVec3;
use serde::Serialize;
use std::time::Instant;

/// What was read: `report.json`'s `input` (made here, where the scene is read).
#[derive(Debug, Clone, Serialize)]
pub struct InputReport {
    pub files: Vec<String>,
    pub bytes: u64,
    /// Elements a reader could not use (e.g. IFC elements that failed to triangulate).
    pub skipped_elements: usize,
    /// IFC products left out because their only geometry is a curve (alignments, footprints).
    pub curve_only_elements: usize,
    pub triangles: usize,
    pub vertices: usize,
    pub components: usize,
    pub meshes: usize,
    pub materials: usize,
    pub images: usize,
    pub skipped_primitives: usize,
    /// Elements whose id was numbered or prefixed because it repeated (book: guide/bim-models.md,
    /// "Element ids").
    pub renamed_ids: usize,
}

/// Reads an input set into one scene; an input without triangles is an error, and so is a
/// georeference that could not be used under `--strict-georef`.
pub(crate) fn read_scene(inputs: &InputSet, opts: &Settings) -> Result<Scene> {
    let scene = inputs.read_with(crate::ingest::ReadOptions {
        crs: opts.crs.as_deref().map(|crs| crate::ingest::GivenCrs {
            crs,
            source: "option",
        }),
        cityjson_lod: opts.cityjson_lod.as_deref(),
        citygml_lod: opts.citygml_lod.as_deref(),
        citygml_theme: opts.citygml_theme.as_deref(),
        mesh_frame: opts.mesh_frame,
    })?;
    if let Some(w) = scene.georef_warnings.first().filter(|_| opts.strict_georef) {
        return Err(Error::input(
            &w.file,
            format!("{} (--strict-georef)", w.message),
        ));
    }
    refuse_implausible(&scene)?;
    if scene.triangle_count() == 0 {
        let name = scene
            .sources
            .first()
            .map(|s| s.path.clone())
            .unwrap_or_default();
        return Err(Error::input(name, "the input has no triangles to tile"));
    }
    Ok(scene)
}

/// Refuses a scene with a coordinate or transform that is not plausible (book: guide/safety.md),
/// naming the file, the element and the value.
fn refuse_implausible(scene: &Scene) -> Result<()> {
    match scene.first_implausible() {
        Some((file, number)) => Err(Error::input_from(file, "", number)),
        None => Ok(()),
    }
}

/// A scene placed, deduplicated and planned: everything before the tiles are built. A pure
/// function of the input and the options, so every process of a sharded build gets the same.
pub(crate) struct Prepared {
    pub input: InputReport,
    pub anchor: DVec3,
    pub anchor_rule: AnchorRule,
    pub origin: GeoOrigin,
    pub origin_source: OriginSource,
    /// The projected CRSs that placed inputs, and georeferences that could not be used.
    pub crs_used: Vec<crate::geodesy::crs::CrsUse>,
    pub georef_warnings: Vec<String>,
    /// What the readers left out (one line each, naming the file).
    pub reader_warnings: Vec<String>,
    pub dedup: Option<DedupReport>,
    pub textures_prepared: crate::texture::Prepared,
    /// White twin materials added to the scene for merging plain colours per tile.
    pub appearance: AppearanceClasses,
    pub plan: TilePlan,
    /// Per plan tile, its level in a discrete LOD chain (`--lod-ratios`; empty otherwise).
    pub chain_level: Vec<Option<usize>>,
    pub t_dedup: f64,
    pub t_partition: f64,
}

/// Place, dedup, texture preparation and the octree plan. Fails on an image over the limits
/// (`crate::texture::admit`).
pub(crate) fn prepare(scene: &mut Scene, opts: &Settings) -> Result<Prepared> {
    // The anchored grid and name-derived codes cost bytes (a larger root cube, fewer shared
    // columns); they pay only where a tileset is kept up to date.
    scene.stable_layout &= opts.update;
    let input = InputReport {
        files: scene
            .sources
            .iter()
            .map(|s| s.path.display().to_string())
            .collect(),
        bytes: scene.sources.iter().map(|s| s.bytes).sum(),
        skipped_elements: scene.skipped_elements,
        curve_only_elements: scene.curve_only_elements,
        triangles: scene.triangle_count(),
        vertices: scene.vertex_count(),
        components: scene.components.len(),
        meshes: scene.meshes.len(),
        materials: scene.materials.len(),
        images: scene.images.len(),
        skipped_primitives: scene.skipped_primitives,
        renamed_ids: scene.renamed_ids,
    };

    // Place: the anchor goes to the scene frame's origin, in f64, before anything is rounded. An
    // input's own georeference (IFC site) gives the anchor, the true-north turn and, unless
    // --origin overrides it, the place on Earth.
    let placed = Placement::of(scene);
    if scene.georeference.is_some() || placed.anchor != DVec3::ZERO {
        scene.apply_transform(&placed.local);
        // The input's own georeference (a map conversion's scales) placed it.
        refuse_implausible(scene)?;
    }
    let (origin, origin_source) = match (scene.georeference, opts.origin) {
        (_, Some(user)) => (user, OriginSource::Option),
        (Some(g), None) => (
            GeoOrigin {
                longitude_deg: g.longitude_deg,
                latitude_deg: g.latitude_deg,
                height_m: g.height_m,
            },
            if g.map_linear.is_some() {
                OriginSource::InputCrs
            } else {
                OriginSource::InputSite
            },
        ),
        (None, None) => (GeoOrigin::DEFAULT, OriginSource::Default),
    };
    if opts.strict_georef && origin_source == OriginSource::Default {
        let file = scene
            .sources
            .first()
            .map(|s| s.path.clone())
            .unwrap_or_default();
        return Err(Error::input(
            file,
            "no georeference places the model: it would go to the default origin (--strict-georef); give --crs EPSG:CODE or --origin LON,LAT",
        ));
    }
    let (anchor, anchor_rule) = (placed.anchor, placed.rule);

    let t_dedup_start = Instant::now();
    let dedup = opts.dedup.as_ref().map(|d| deduplicate(scene, d));
    let t_dedup = t_dedup_start.elapsed().as_secs_f64();

    let limits = ImageLimits::under_budget(crate::scene::memory_budget().map(|b| b.bytes));
    let textures_prepared = crate::texture::prepare(scene, &opts.texture, &limits)
        .map_err(|(file, refused)| Error::input_from(file, "", refused))?;
    let appearance = match opts.merge_plain_materials {
        true => AppearanceClasses::add_to(scene),
        false => AppearanceClasses::default(),
    };
    let t1 = Instant::now();
    let mut plan = plan_octree(scene, &opts.octree);
    let mut chain_level = Vec::new();
    match &opts.lod {
        LodMode::Hlod => plan = plan.with_content_in_leaves(),
        LodMode::Ratios(r) => {
            let c = with_lod_chains(&plan.with_content_in_leaves(), r.len());
            (plan, chain_level) = (c.plan, c.level);
        }
        LodMode::None => {}
    }
    let t_partition = t1.elapsed().as_secs_f64();
    Ok(Prepared {
        input,
        anchor,
        anchor_rule,
        origin,
        origin_source,
        crs_used: scene.crs_used.clone(),
        georef_warnings: scene
            .georef_warnings
            .iter()
            .map(|w| {
                format!(
                    "{}: {}; the model is placed without it",
                    w.file.display(),
                    w.message
                )
            })
            .collect(),
        reader_warnings: std::mem::take(&mut scene.reader_warnings),
        dedup,
        textures_prepared,
        appearance,
        plan,
        chain_level,
        t_dedup,
        t_partition,
    })
}
