//! CityGML appearances (CityGML 2.0 §9, 3.0 Appearance module): `X3DMaterial` colours and
//! `ParameterizedTexture` images with a `TexCoordList` per ring, for one theme (the one asked
//! for, else the file's first). Images are read relative to the CityGML file and never from
//! outside its folder, as the CityJSON reader reads them.

use crate::ingest::cityjson::appearance::{wrap_of_mode, ImageFiles};
use crate::scene::{Scene, TextureRef};
use std::collections::HashMap;
use std::path::Path;

/// A ParameterizedTexture as read.
#[derive(Debug, Default)]
pub(super) struct TextureDef {
    pub theme: Option<String>,
    pub image: String,
    pub wrap_mode: Option<String>,
    pub targets: Vec<TextureTarget>,
}

/// A texture's target polygon and the UVs of its rings (ring gml:id → UVs, glTF's v).
#[derive(Debug, Default)]
pub(super) struct TextureTarget {
    pub polygon: String,
    pub rings: Vec<(String, Vec<[f32; 2]>)>,
}

/// An X3DMaterial as read.
#[derive(Debug, Default)]
pub(super) struct MaterialDef {
    pub theme: Option<String>,
    pub diffuse: Vec<f64>,
    pub transparency: Option<f64>,
    pub targets: Vec<String>,
}

/// Every appearance of a document.
#[derive(Debug, Default)]
pub(super) struct Appearances {
    pub textures: Vec<TextureDef>,
    pub materials: Vec<MaterialDef>,
}

/// The UVs of each ring of a polygon (`None` for a ring its texture gives none).
pub(super) type RingUvs = Vec<Option<Vec<[f32; 2]>>>;

/// Finds what appearances target: a polygon by gml:id, a ring by gml:id (polygon, ring index),
/// and how many rings a polygon has.
pub(super) struct Targets<'d> {
    pub polygon_ids: &'d HashMap<String, u32>,
    pub ring_ids: HashMap<&'d str, (u32, usize)>,
    pub polygons: &'d [super::parse::Polygon],
}

/// The look of one polygon in the theme drawn: a texture with UVs per ring (in ring order), and
/// a colour.
#[derive(Debug, Default)]
pub(super) struct PolygonLooks {
    pub textured: HashMap<u32, (TextureRef, RingUvs)>,
    pub colours: HashMap<u32, [f32; 4]>,
}

impl Appearances {
    /// The themes present, in the order first seen ("" for appearances with no theme).
    pub(super) fn themes(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        let all = self
            .textures
            .iter()
            .map(|t| &t.theme)
            .chain(self.materials.iter().map(|m| &m.theme));
        for t in all {
            let t = t.clone().unwrap_or_default();
            if !out.contains(&t) {
                out.push(t);
            }
        }
        out
    }

    /// The looks of theme `theme` per polygon.
    pub(super) fn looks(
        &self,
        theme: &str,
        targets: &Targets<'_>,
        images: &mut ImageFiles,
        base_dir: &Path,
        scene: &mut Scene,
    ) -> PolygonLooks {
        let polygon_of = |id: &str| targets.polygon_ids.get(id).copied();
        let ring_of = |id: &str| targets.ring_ids.get(id).copied();
        let rings_in = |p: u32| targets.polygons[p as usize].rings.len();
        let mut looks = PolygonLooks::default();
        let in_theme = |t: &Option<String>| t.as_deref().unwrap_or("") == theme;
        for m in self.materials.iter().filter(|m| in_theme(&m.theme)) {
            let d = |i: usize| m.diffuse.get(i).copied().unwrap_or(0.8) as f32;
            let alpha = 1.0 - m.transparency.unwrap_or(0.0).clamp(0.0, 1.0) as f32;
            // CityGML colours are sRGB-ish display values; glTF base colours are linear.
            let linear = |c: f32| c.clamp(0.0, 1.0).powf(2.2);
            let colour = [linear(d(0)), linear(d(1)), linear(d(2)), alpha];
            for target in &m.targets {
                if let Some(p) = polygon_of(target) {
                    looks.colours.insert(p, colour);
                }
            }
        }
        for t in self.textures.iter().filter(|t| in_theme(&t.theme)) {
            let Some(image) = images.image(t.image.trim(), base_dir, scene) else {
                continue;
            };
            let texture = TextureRef::on_first_uvs(image, wrap_of_mode(t.wrap_mode.as_deref()));
            for target in &t.targets {
                let Some(p) = polygon_of(&target.polygon) else {
                    continue;
                };
                let mut rings = vec![None; rings_in(p)];
                for (ring, uvs) in &target.rings {
                    if let Some((q, r)) = ring_of(ring) {
                        if q == p && r < rings.len() {
                            rings[r] = Some(uvs.clone());
                        }
                    }
                }
                looks.textured.insert(p, (texture.clone(), rings));
            }
        }
        looks
    }
}
