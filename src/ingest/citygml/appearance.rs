//! CityGML appearances (CityGML 2.0 §9, 3.0 Appearance module): `X3DMaterial` colours,
//! `ParameterizedTexture` images with a `TexCoordList` per ring, and `GeoreferencedTexture`
//! images laid over their surfaces from above (by the texture's reference point and orientation,
//! or its image's world file), for one theme (the one asked for, else the file's first). Images
//! are read relative to the CityGML file and never from outside its folder, as the CityJSON
//! reader reads them.

use crate::ingest::cityjson::appearance::{wrap_of_mode, ImageFiles};
use crate::scene::{Scene, TextureRef};
use crate::uri::confine;
use std::collections::HashMap;
use std::path::Path;

/// A ParameterizedTexture as read.
#[derive(Debug, Default)]
pub(super) struct TextureDef {
    pub theme: Option<String>,
    pub image: String,
    pub wrap_mode: Option<String>,
    pub targets: Vec<TextureTarget>,
    /// A GeoreferencedTexture's placement (`None`: a ParameterizedTexture).
    pub georeferenced: Option<GeoreferencedPlacement>,
}

/// Where a GeoreferencedTexture's image lies on the ground: the centre of its upper-left pixel
/// and the 2x2 row-major matrix from (column, row) to map x, y (a world file's A B / D E), and
/// the surfaces (polygons or geometries, by gml:id) it covers.
#[derive(Debug, Default, Clone)]
pub(super) struct GeoreferencedPlacement {
    pub reference: Option<[f64; 2]>,
    pub orientation: Option<[f64; 4]>,
    pub prefer_world_file: bool,
    pub targets: Vec<String>,
}

impl GeoreferencedPlacement {
    /// The placement used: the world file beside the image when the texture prefers it or states
    /// none of its own, else its own.
    pub(super) fn resolve(&self, base_dir: &Path, image: &str) -> Option<([f64; 2], [f64; 4])> {
        let own = self.reference.zip(self.orientation);
        if self.prefer_world_file || own.is_none() {
            if let Some(w) = world_file(base_dir, image) {
                return Some(w);
            }
        }
        own
    }
}

/// An image's world file (`name.jgw`, `.pgw`, `.tfw`, `name.ext` + `w`, or `.wld`): six numbers
/// A D B E C F, read from beside the image and never from outside the folder.
fn world_file(base_dir: &Path, image: &str) -> Option<([f64; 2], [f64; 4])> {
    let image = image.trim();
    let (stem, ext) = image.rsplit_once('.')?;
    let short: String = [ext.chars().next()?, ext.chars().last()?, 'w']
        .iter()
        .collect();
    for name in [
        format!("{stem}.{short}"),
        format!("{image}w"),
        format!("{stem}.wld"),
    ] {
        let Ok(path) = confine::inside(base_dir, &name, &confine::INPUT) else {
            continue;
        };
        let Ok(bytes) = crate::ingest::read_regular(&path) else {
            continue;
        };
        let numbers: Vec<f64> = String::from_utf8_lossy(&bytes)
            .split_ascii_whitespace()
            .map_while(|t| t.parse().ok())
            .collect();
        if let [a, d, b, e, c, f] = numbers[..] {
            return Some(([c, f], [a, b, d, e]));
        }
    }
    None
}

/// Where each ring point of a polygon falls in a georeferenced image, in pixels (column, row).
pub(super) type RingPixels = Vec<Vec<[f64; 2]>>;

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
    /// The looks of theme `theme` per polygon. `georeferenced[t]` lists, for the t-th texture
    /// when it is a GeoreferencedTexture, its polygons and where their points fall in its image.
    pub(super) fn looks(
        &self,
        theme: &str,
        targets: &Targets<'_>,
        georeferenced: &HashMap<usize, Vec<(u32, RingPixels)>>,
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
        for (i, t) in self
            .textures
            .iter()
            .enumerate()
            .filter(|(_, t)| in_theme(&t.theme))
        {
            if t.georeferenced.is_some() && !georeferenced.contains_key(&i) {
                continue; // no placement: nothing to lay it by
            }
            let Some(image) = images.image(t.image.trim(), base_dir, scene) else {
                continue;
            };
            let texture = TextureRef::on_first_uvs(image, wrap_of_mode(t.wrap_mode.as_deref()));
            if let Some(polygons) = georeferenced.get(&i) {
                let Some((width_px, height_px)) = image_size_px(&scene.images[image.0 as usize])
                else {
                    continue;
                };
                // The centre of pixel (0, 0) is at (0.5, 0.5) of the image's width and height.
                let uv = |[col, row]: [f64; 2]| {
                    [
                        ((col + 0.5) / width_px) as f32,
                        ((row + 0.5) / height_px) as f32,
                    ]
                };
                for (p, rings) in polygons {
                    let rings = rings
                        .iter()
                        .map(|ring| Some(ring.iter().map(|&px| uv(px)).collect()))
                        .collect();
                    looks.textured.insert(*p, (texture.clone(), rings));
                }
                continue;
            }
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

/// An image's width and height in pixels, from its header.
fn image_size_px(image: &crate::scene::Image) -> Option<(f64, f64)> {
    let (w, h) = image::ImageReader::new(std::io::Cursor::new(image.bytes.as_slice()))
        .with_guessed_format()
        .ok()?
        .into_dimensions()
        .ok()?;
    (w > 0 && h > 0).then_some((w as f64, h as f64))
}
