//! CityGML reader (CityGML 1.0, 2.0 and 3.0 GML encodings; `.gml`/`.xml`, optionally gzipped)
//! yielding the same [`Scene`] as the CityJSON reader ([`crate::ingest::cityjson`]).
//!
//! The document is read as a stream of XML events ([`parse`]). Every city object with geometry
//! (Building, BuildingPart, BuildingInstallation, Bridge and its parts, Tunnel, Road, Track,
//! TrafficArea, TINRelief, WaterBody, vegetation, CityFurniture, GenericCityObject, and the
//! openings Window and Door) becomes an element: its `gml:id` the key, its element name the
//! class, its enclosing city objects the hierarchy path, its attributes typed properties
//! ([`attributes`]). Thematic surfaces (WallSurface, RoofSurface…) are the semantic types of
//! their polygons, split per type as for CityJSON. Surfaces are gml:Polygon, PolygonPatch and Triangle in any GML
//! aggregate (MultiSurface, CompositeSurface, Solid, CompositeSolid, TriangulatedSurface,
//! OrientableSurface, which turns them over), inline or by `xlink:href` to a gml:id anywhere in
//! the file; a polygon reached twice (a solid built from its boundary surfaces) is drawn once.
//! ImplicitGeometry placements become polygons of their object (the prototype through the
//! placement's matrix, from its reference point), and an Application Domain Extension's features
//! and geometry properties are read like CityGML's own ([`parse`]).
//! One LoD of each object is read: its highest, or the one asked for (`--citygml-lod`).
//! Coordinates stay f64 until the object's mesh is made relative to its corner: a projected
//! `srsName` is returned for the per-vertex placement, a geographic one (latitude first when
//! PROJ says so) is placed here, vertex by vertex ([`crs`]). Appearances: [`appearance`].

mod appearance;
mod attributes;
pub mod crs;
mod parse;
#[cfg(test)]
mod tests;

use crate::error::{Error, Result};
use crate::geometry::triangulate;
use crate::ingest::cityjson::appearance::ImageFiles;
use crate::ingest::cityjson::{object_mesh, push_surface_material, ObjectTriangles, NO_SEMANTICS};
use crate::scene::*;
use glam::{DMat4, DVec3};
use parse::{Document, Member};
use std::collections::{BTreeSet, HashMap, HashSet};
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

/// How deep `xlink:href`s may lead to other references (a loop ends here).
const MAX_REFERENCE_DEPTH: usize = 16;

/// How a CityGML file is read: the LoD (`None`: each object's highest), the appearance theme
/// (`None`: the file's first) and a CRS that overrides the file's `srsName`.
#[derive(Debug, Clone, Copy, Default)]
pub struct CityGmlOptions<'a> {
    pub lod: Option<&'a str>,
    pub theme: Option<&'a str>,
    pub crs: Option<&'a str>,
}

/// A CityGML file read: its scene and, when its coordinates are map coordinates of a projected
/// CRS, that CRS (a PROJ definition) and where it came from (`option`, `citygml-srs-name`) for
/// the per-vertex placement. A geographic CRS is placed already.
#[derive(Debug)]
pub struct CityModel {
    pub scene: Scene,
    pub map_crs: Option<(String, &'static str)>,
}

/// Whether a file is CityGML: by name (`.gml`, `.gml.gz`), or for `.xml` (and gzipped files) by
/// a `CityModel` root element near its start.
pub fn is_citygml(path: &Path) -> bool {
    let name = super::lowercase_name(path);
    if name.ends_with(".gml") || name.ends_with(".gml.gz") {
        return true;
    }
    if !(name.ends_with(".xml") || name.ends_with(".gz")) {
        return false;
    }
    let mut head = vec![0u8; 8192];
    let n = open(path)
        .and_then(|mut r| read_up_to(&mut r, &mut head))
        .unwrap_or(0);
    String::from_utf8_lossy(&head[..n]).contains("CityModel")
}

fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

/// The file's bytes, gunzipped when they start with the gzip magic.
fn open(path: &Path) -> std::io::Result<Box<dyn BufRead>> {
    let mut file = BufReader::new(super::open_regular(path)?);
    let gzipped = file.fill_buf()?.starts_with(&[0x1f, 0x8b]);
    Ok(if gzipped {
        Box::new(BufReader::new(flate2::bufread::MultiGzDecoder::new(file)))
    } else {
        Box::new(file)
    })
}

/// The line of a byte offset of the (decompressed) document, for error messages.
fn line_at(path: &Path, offset: u64) -> Option<usize> {
    let reader = open(path).ok()?;
    let mut line = 1;
    for byte in reader.bytes().take(offset as usize) {
        if byte.ok()? == b'\n' {
            line += 1;
        }
    }
    Some(line)
}

/// Reads a CityGML file into a new scene ([`CityGmlOptions`]). A LoD or theme the file does not
/// have is an error naming those it has.
pub fn read_citygml(path: &Path, opts: CityGmlOptions<'_>) -> Result<CityModel> {
    let input = open(path).map_err(|e| Error::input_from(path, "cannot read", e))?;
    let doc = parse::parse(input).map_err(|e| {
        let line = line_at(path, e.offset).map_or(String::new(), |l| format!("line {l}: "));
        Error::input(path, format!("{line}{}", e.message))
    })?;
    read_document(path, doc, opts)
}

/// Like [`read_citygml`], from the (uncompressed) bytes of a file named `path` (fuzzing).
pub fn read_citygml_bytes(path: &Path, data: &[u8], opts: CityGmlOptions<'_>) -> Result<CityModel> {
    let doc = parse::parse(data).map_err(|e| {
        let head = &data[..(e.offset as usize).min(data.len())];
        let line = head.iter().filter(|&&b| b == b'\n').count() + 1;
        Error::input(path, format!("line {line}: {}", e.message))
    })?;
    read_document(path, doc, opts)
}

fn read_document(path: &Path, mut doc: Document, opts: CityGmlOptions<'_>) -> Result<CityModel> {
    let mut warnings = Vec::new();
    place_implicit_geometries(&mut doc);
    hand_up_attributes_of_empty_ade_features(&mut doc);
    // In the file's own x, y: before the CRS moves a geographic file's points to metres.
    let georeferenced = georeferenced_pixels(path, &doc);
    let (map_crs, geographic) = choose_crs(path, &mut doc, opts.crs, &mut warnings);
    if geographic.is_none() {
        // The file's coordinates are kept (map or local): a placed prototype is its reference
        // point plus its offsets.
        for p in &mut doc.polygons {
            if let Some(anchor) = p.anchor.take() {
                p.rings.iter_mut().flatten().for_each(|v| *v += anchor);
            }
        }
    }
    let mut builder = Builder {
        path,
        doc: &doc,
        lod_wanted: match opts.lod {
            Some(l) => Some(
                l.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|l| (0.0..=4.0).contains(l))
                    .ok_or_else(|| {
                        Error::input(
                            path,
                            format!("--citygml-lod {l}: not a CityGML LoD (0 to 4)"),
                        )
                    })? as u8,
            ),
            None => None,
        },
        scene: Scene::default(),
        texts: TextInterner::default(),
        materials: HashMap::new(),
        lods_present: BTreeSet::new(),
        objects_without_lod: 0,
    };
    let looks = builder.looks(opts.theme, &georeferenced)?;
    builder.build(&looks)?;
    let Builder {
        mut scene,
        lods_present,
        objects_without_lod,
        lod_wanted,
        ..
    } = builder;
    if let Some(wanted) = lod_wanted {
        if scene.components.is_empty() {
            let present: Vec<String> = lods_present.iter().map(u8::to_string).collect();
            return Err(Error::input(
                path,
                format!(
                    "--citygml-lod {wanted}: no object has geometry at LoD {wanted}; the LoDs present are {}",
                    if present.is_empty() { "none".into() } else { present.join(", ") }
                ),
            ));
        }
        if objects_without_lod > 0 {
            warnings.push(format!(
                "{}: {objects_without_lod} city objects with geometry have none at LoD {wanted} and are left out (--citygml-lod)",
                path.display()
            ));
        }
    }
    if doc.implicit_not_drawn > 0 {
        warnings.push(format!(
            "{}: {} ImplicitGeometry instances are not drawn (a library object in another file, no prototype in this file, or no transformation or reference point)",
            path.display(),
            doc.implicit_not_drawn
        ));
    }
    scene.reader_warnings.extend(warnings);
    scene.sources.push(SourceFile {
        path: path.to_path_buf(),
        bytes: doc.bytes,
    });
    scene.finish();
    if let Some((place, source)) = geographic {
        scene.crs_used.push(crate::geodesy::crs::CrsUse::new(
            &path.display().to_string(),
            source,
            &place,
            place.place.longitude_deg,
            place.place.latitude_deg,
        ));
        scene.georeference = Some(SourceGeoreference {
            longitude_deg: place.place.longitude_deg,
            latitude_deg: place.place.latitude_deg,
            height_m: place.place.height_m,
            true_north_deg: Some(0.0),
            anchor: DVec3::ZERO,
            map_linear: Some(glam::DMat3::IDENTITY),
        });
    }
    Ok(CityModel { scene, map_crs })
}

/// The CRS of the coordinates: the given one, else the file's `srsName`. A geographic CRS is
/// placed here (its points become east-north-up metres); a projected one is returned for the
/// per-vertex placement, unless the file's own srsName is plainly wrong for its coordinates
/// (local coordinates of a few hundred metres), which is a warning naming both.
#[allow(clippy::type_complexity)]
fn choose_crs(
    path: &Path,
    doc: &mut Document,
    given: Option<&str>,
    warnings: &mut Vec<String>,
) -> (
    Option<(String, &'static str)>,
    Option<(crate::geodesy::crs::MapPlace, &'static str)>,
) {
    let (text, source) = match (given, doc.srs_name.as_deref()) {
        (Some(g), _) => (g.to_string(), "option"),
        (None, Some(own)) => (own.to_string(), "citygml-srs-name"),
        (None, None) => {
            let bounds = raw_bounds(doc);
            let centre = (bounds.0 + bounds.1) / 2.0;
            if centre.length() > crate::scene::placement::PROJECTED_COORDINATES_THRESHOLD_M {
                warnings.push(format!(
                    "{}: no srsName, and the coordinates look like map coordinates: the model is placed at the default origin; give --crs EPSG:CODE to place it",
                    path.display()
                ));
            }
            return (None, None);
        }
    };
    let what = if source == "option" {
        "--crs"
    } else {
        "srsName"
    };
    let definition = crs::srs_name_definition(&text);
    match crs::crs_kind(&definition) {
        crs::CrsKind::Geographic { latitude_first } => {
            if latitude_first {
                let swap = |p: &mut DVec3| *p = DVec3::new(p.y, p.x, p.z);
                for polygon in doc.polygons.iter_mut().filter(|p| !p.template) {
                    match polygon.anchor.as_mut() {
                        // A placed prototype's offsets are metres, east and north already.
                        Some(anchor) => swap(anchor),
                        None => polygon.rings.iter_mut().flatten().for_each(swap),
                    }
                }
            }
            match crs::geographic_to_enu(&definition, &mut doc.polygons) {
                Ok(place) => (None, Some((place, source))),
                Err(e) => {
                    warnings.push(format!("{}: {what} {text}: {e}", path.display()));
                    (None, None)
                }
            }
        }
        crs::CrsKind::Projected => {
            let (min, max) = raw_bounds(doc);
            let centre = (min + max) / 2.0;
            if source != "option"
                && centre.length() <= crate::scene::placement::PROJECTED_COORDINATES_THRESHOLD_M
            {
                warnings.push(format!(
                    "{}: srsName {text} ({definition}) is a map CRS, but the coordinates are local (x {:.1}..{:.1}, y {:.1}..{:.1}): the model is placed at the default origin; give --crs or --origin to place it",
                    path.display(), min.x, max.x, min.y, max.y
                ));
                return (None, None);
            }
            (Some((definition, source)), None)
        }
        crs::CrsKind::Other => {
            warnings.push(format!(
                "{}: {what} {text}: PROJ knows no projected or geographic CRS of that name; the model is placed at the default origin",
                path.display()
            ));
            (None, None)
        }
    }
}

/// The bounds of the drawn polygons in the file's coordinates (a placed prototype's at its
/// reference point plus its offsets).
fn raw_bounds(doc: &Document) -> (DVec3, DVec3) {
    doc.polygons
        .iter()
        .filter(|p| !p.template)
        .flat_map(|p| {
            let anchor = p.anchor.unwrap_or(DVec3::ZERO);
            p.rings.iter().flatten().map(move |v| *v + anchor)
        })
        .fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(a, b), p| (a.min(p), b.max(p)),
        )
}

/// The polygons a member stands for (with whether each is turned over), references followed.
fn expand(doc: &Document, m: &Member, reversed: bool, depth: usize, out: &mut Vec<(u32, bool)>) {
    match m {
        Member::Polygon(p, r) => out.push((*p, r ^ reversed)),
        Member::Href(id, r) => {
            if depth >= MAX_REFERENCE_DEPTH {
                return;
            }
            if let Some(&p) = doc.polygon_ids.get(id) {
                out.push((p, r ^ reversed));
            } else if let Some(list) = doc.geometry_ids.get(id) {
                for m in list {
                    expand(doc, m, r ^ reversed, depth + 1, out);
                }
            }
        }
    }
}

/// Every ImplicitGeometry placement becomes polygons of its object at its LoD: the prototype's
/// points through the row-major transformation, as offsets from the reference point (added once
/// the CRS is known). Each copy keeps its prototype polygon's index for its appearance. Copies of
/// one prototype are congruent, so dedup makes them instances.
fn place_implicit_geometries(doc: &mut Document) {
    for o in 0..doc.objects.len() {
        for placement in std::mem::take(&mut doc.objects[o].implicit) {
            let m = placement.matrix_row_major;
            let transform = DMat4::from_cols_array(&m).transpose();
            let mut polygons = Vec::new();
            for member in &placement.template {
                expand(doc, member, false, 0, &mut polygons);
            }
            let mut placed = Vec::with_capacity(polygons.len());
            for (p, reversed) in polygons {
                let template = &doc.polygons[p as usize];
                let rings = template
                    .rings
                    .iter()
                    .map(|ring| {
                        ring.iter()
                            .map(|v| transform.transform_point3(*v))
                            .collect()
                    })
                    .collect::<Vec<Vec<DVec3>>>();
                let index = doc.polygons.len() as u32;
                doc.polygons.push(parse::Polygon {
                    ring_ids: vec![None; rings.len()],
                    rings,
                    semantic: template.semantic,
                    template: false,
                    anchor: Some(placement.reference),
                    prototype: Some(p),
                });
                placed.push(Member::Polygon(index, reversed));
            }
            doc.objects[o]
                .lods
                .entry(placement.lod)
                .or_default()
                .extend(placed);
        }
    }
}

/// Where the points of each GeoreferencedTexture's polygons fall in its image (pixels), from the
/// texture's placement (its own, or its image's world file) in the file's x, y; textures without
/// a placement are left out.
fn georeferenced_pixels(
    path: &Path,
    doc: &Document,
) -> HashMap<usize, Vec<(u32, appearance::RingPixels)>> {
    let base_dir = path.parent().unwrap_or(Path::new(""));
    let mut out = HashMap::new();
    for (i, texture) in doc.appearances.textures.iter().enumerate() {
        let Some(g) = texture.georeferenced.as_ref() else {
            continue;
        };
        let Some((reference, [a, b, d, e])) = g.resolve(base_dir, &texture.image) else {
            continue;
        };
        let determinant = a * e - b * d;
        if determinant.abs() < f64::MIN_POSITIVE || !determinant.is_finite() {
            continue;
        }
        // (column, row) = M⁻¹ (point − reference).
        let to_pixel = |v: &DVec3| {
            let (x, y) = (v.x - reference[0], v.y - reference[1]);
            [(e * x - b * y) / determinant, (a * y - d * x) / determinant]
        };
        let mut polygons = Vec::new();
        for target in &g.targets {
            expand(
                doc,
                &Member::Href(target.clone(), false),
                false,
                0,
                &mut polygons,
            );
        }
        let placed = polygons
            .into_iter()
            .map(|(p, _)| {
                let rings = doc.polygons[p as usize]
                    .rings
                    .iter()
                    .map(|ring| ring.iter().map(to_pixel).collect())
                    .collect();
                (p, rings)
            })
            .collect();
        out.insert(i, placed);
    }
    out
}

/// An ADE feature that draws nothing (a data record with an id) gives its attributes to the
/// object it is in, so they stay pickable.
fn hand_up_attributes_of_empty_ade_features(doc: &mut Document) {
    for o in (0..doc.objects.len()).rev() {
        let object = &doc.objects[o];
        let draws = object.lods.values().any(|l| !l.is_empty());
        let (Some(parent), true, false) = (object.parent, object.ade, draws) else {
            continue;
        };
        let attributes = std::mem::take(&mut doc.objects[o].attributes);
        let into = &mut doc.objects[parent].attributes;
        for (name, value) in attributes {
            if !into.iter().any(|(n, _)| *n == name) {
                into.push((name, value));
            }
        }
    }
}

/// What makes two surfaces' materials the same: semantic type, texture, colour (as bits).
type MaterialKey = (Option<usize>, Option<TextureRef>, Option<[u32; 4]>);

/// Turns the document into the scene.
struct Builder<'a> {
    path: &'a Path,
    doc: &'a Document,
    lod_wanted: Option<u8>,
    scene: Scene,
    texts: TextInterner,
    /// Material per (semantic type, texture, colour), made on first use.
    materials: HashMap<MaterialKey, MaterialId>,
    lods_present: BTreeSet<u8>,
    objects_without_lod: usize,
}

impl Builder<'_> {
    /// The looks of the theme drawn (the one asked for, else the file's first).
    fn looks(
        &mut self,
        theme: Option<&str>,
        georeferenced: &HashMap<usize, Vec<(u32, appearance::RingPixels)>>,
    ) -> Result<appearance::PolygonLooks> {
        let doc = self.doc;
        let themes = doc.appearances.themes();
        let chosen = match theme {
            Some(t) if themes.iter().any(|x| x == t) => t.to_string(),
            Some(t) => {
                return Err(Error::input(
                    self.path,
                    format!(
                    "--citygml-theme {t}: the file has no such appearance theme; its themes are {}",
                    if themes.is_empty() {
                        "none".into()
                    } else {
                        themes.join(", ")
                    }
                ),
                ))
            }
            None => match themes.first() {
                Some(t) => t.clone(),
                None => return Ok(appearance::PolygonLooks::default()),
            },
        };
        let mut targets = appearance::Targets {
            polygon_ids: &doc.polygon_ids,
            ring_ids: HashMap::new(),
            polygons: &doc.polygons,
        };
        for (i, p) in doc.polygons.iter().enumerate() {
            for (r, id) in p.ring_ids.iter().enumerate() {
                if let Some(id) = id {
                    targets.ring_ids.insert(id, (i as u32, r));
                }
            }
        }
        let mut images = ImageFiles::default();
        let base_dir = self.path.parent().unwrap_or(Path::new("")).to_path_buf();
        let looks = doc.appearances.looks(
            &chosen,
            &targets,
            georeferenced,
            &mut images,
            &base_dir,
            &mut self.scene,
        );
        if let Some(line) = images.missing_warning(self.path) {
            self.scene.reader_warnings.push(line);
        }
        Ok(looks)
    }

    fn build(&mut self, looks: &appearance::PolygonLooks) -> Result<()> {
        let doc = self.doc;
        let mut nodes = Vec::with_capacity(doc.objects.len());
        for object in &doc.objects {
            let node = NodeId(self.scene.nodes.len() as u32);
            self.scene.nodes.push(Node {
                name: Some(object.id.clone()),
                parent: object.parent.map(|p| nodes[p]),
                ..Node::default()
            });
            nodes.push(node);
        }
        for (o, object) in doc.objects.iter().enumerate() {
            let mut at_lod: HashMap<u8, Vec<(u32, bool)>> = HashMap::new();
            for (lod, members) in &object.lods {
                let mut polygons = Vec::new();
                for m in members {
                    expand(doc, m, false, 0, &mut polygons);
                }
                if !polygons.is_empty() {
                    at_lod.insert(*lod, polygons);
                }
            }
            self.lods_present.extend(at_lod.keys());
            let chosen = match self.lod_wanted {
                Some(l) => l,
                None => at_lod.keys().max().copied().unwrap_or(0),
            };
            let Some(polygons) = at_lod.get(&chosen) else {
                if !at_lod.is_empty() {
                    self.objects_without_lod += 1;
                }
                continue;
            };
            let mut triangles = ObjectTriangles::default();
            let mut seen = HashSet::new();
            for &(p, reversed) in polygons {
                if seen.insert(p) {
                    self.polygon(p, reversed, looks, &object.id, &mut triangles)?;
                }
            }
            if triangles.by_material.is_empty() {
                continue;
            }
            let mut info = ElementInfo::keyed(object.id.clone());
            info.class = Some(self.texts.get(&object.class));
            info.name = object.name.clone();
            for (semantic, count) in &triangles.per_semantic {
                info.properties.push(Property {
                    set: self.texts.get("semantics"),
                    name: self.texts.get(semantic),
                    value: PropertyValue::Integer(*count),
                });
            }
            for (name, value) in &object.attributes {
                info.properties.push(Property {
                    set: self.texts.get("attributes"),
                    name: self.texts.get(name),
                    value: value.clone(),
                });
            }
            let (mesh, origin) = object_mesh(&object.id, triangles);
            let mesh_id = self.scene.meshes.push(mesh);
            let component = Component {
                node: Some(nodes[o]),
                ..Component::new(mesh_id, DMat4::from_translation(origin))
            };
            self.scene.push_component(component, &info);
        }
        Ok(())
    }

    /// One polygon triangulated into `out`, with its look.
    fn polygon(
        &mut self,
        p: u32,
        reversed: bool,
        looks: &appearance::PolygonLooks,
        what: &str,
        out: &mut ObjectTriangles,
    ) -> Result<()> {
        let polygon = &self.doc.polygons[p as usize];
        // A placed copy has no gml:id of its own: it wears its prototype polygon's look, the same
        // on every copy, so that the copies stay congruent in geometry and material (instances).
        let look = polygon.prototype.unwrap_or(p);
        let textured = looks.textured.get(&look);
        let mut points: Vec<DVec3> = Vec::new();
        let mut holes = Vec::new();
        let mut uvs: Option<Vec<[f32; 2]>> = textured.map(|_| Vec::new());
        for (r, ring) in polygon.rings.iter().enumerate() {
            if r > 0 {
                holes.push(points.len());
            }
            let start = points.len();
            points.extend(ring);
            let ring_uvs = textured
                .and_then(|(_, rings)| rings.get(r).cloned().flatten())
                .map(|mut u| {
                    // The texture coordinates close the ring as its points do.
                    if u.len() == ring.len() + 1 {
                        u.pop();
                    }
                    u
                })
                .filter(|u| u.len() == ring.len());
            match (ring_uvs, uvs.as_mut()) {
                (Some(u), Some(all)) => all.extend(u),
                _ => uvs = None,
            }
            if reversed {
                points[start..].reverse();
                if let Some(all) = uvs.as_mut() {
                    all[start..].reverse();
                }
            }
        }
        let Some(corners) = triangulate(&points, &holes).map_err(|e| {
            Error::input(self.path, format!("{what}: polygon not triangulated: {e}"))
        })?
        else {
            return Ok(());
        };
        let texture = textured.map(|(t, _)| t.clone()).filter(|_| uvs.is_some());
        let colour = looks.colours.get(&look).copied();
        let semantic = polygon.semantic;
        let key = (
            semantic,
            texture.clone(),
            colour.map(|c| c.map(f32::to_bits)),
        );
        let semantic_name = semantic.map_or(NO_SEMANTICS, |s| self.doc.semantics[s].as_str());
        let material = match self.materials.get(&key) {
            Some(&m) => m,
            None => {
                let m =
                    push_surface_material(&mut self.scene, semantic_name, colour, texture.as_ref());
                self.materials.insert(key, m);
                m
            }
        };
        *out.per_semantic
            .entry(semantic_name.to_string())
            .or_default() += (corners.indices.len() / 3) as i64;
        let into = out.by_material.entry(material).or_default();
        for &i in &corners.indices {
            into.corners.push(points[i]);
            into.normals.push(corners.normal);
            if let (Some(_), Some(uvs)) = (&texture, &uvs) {
                into.uvs.push(uvs[i]);
            }
        }
        Ok(())
    }
}
