//! The streaming pass over a CityGML document (CityGML 1.0/2.0/3.0 encodings, GML 3.1/3.2): XML
//! events from `quick-xml`, one at a time, become a [`Document`] of polygons, city objects that
//! list their polygons per LoD (inline or by `xlink:href`, resolved later), attributes and
//! appearances. Nothing of the XML tree is kept, so memory follows the model, not the file.

use super::appearance::{
    Appearances, GeoreferencedPlacement, MaterialDef, TextureDef, TextureTarget,
};
use super::attributes::{self, GenericAttribute};
use crate::scene::PropertyValue;
use glam::DVec3;
use quick_xml::events::{BytesStart, Event};
use quick_xml::name::ResolveResult;
use quick_xml::NsReader;
use std::collections::{BTreeMap, HashMap};
use std::io::BufRead;

/// City object classes of CityGML 1.0–3.0 (local names in an OGC namespace): each with geometry
/// becomes an element. Thematic surfaces are not among them: they are the semantic types of
/// their parent's surfaces.
const CITY_OBJECT_CLASSES: &[&str] = &[
    "Building",
    "BuildingPart",
    "BuildingInstallation",
    "IntBuildingInstallation",
    "BuildingFurniture",
    "BuildingConstructiveElement",
    "BuildingRoom",
    "Room",
    "Bridge",
    "BridgePart",
    "BridgeInstallation",
    "IntBridgeInstallation",
    "BridgeConstructionElement",
    "BridgeConstructiveElement",
    "BridgeFurniture",
    "BridgeRoom",
    "Tunnel",
    "TunnelPart",
    "TunnelInstallation",
    "IntTunnelInstallation",
    "TunnelConstructiveElement",
    "TunnelFurniture",
    "HollowSpace",
    "Road",
    "Railway",
    "Track",
    "Square",
    "Waterway",
    "Section",
    "Intersection",
    "TrafficArea",
    "AuxiliaryTrafficArea",
    "TrafficSpace",
    "AuxiliaryTrafficSpace",
    "ReliefFeature",
    "TINRelief",
    "MassPointRelief",
    "BreaklineRelief",
    "WaterBody",
    "SolitaryVegetationObject",
    "PlantCover",
    "CityFurniture",
    "GenericCityObject",
    "GenericOccupiedSpace",
    "GenericUnoccupiedSpace",
    "GenericLogicalSpace",
    "LandUse",
    "OtherConstruction",
];

/// Openings (CityGML 2.0 `_Opening`, 3.0 filling elements): city objects of their own (a window
/// is picked as the window, with its name), inside the thematic surface of their wall, whose
/// polygons take the opening's class as their semantic type.
const OPENING_CLASSES: &[&str] = &["Window", "Door"];

/// Thematic boundary surfaces: the semantic type of the polygons inside them.
const THEMATIC_SURFACES: &[&str] = &[
    "WallSurface",
    "RoofSurface",
    "GroundSurface",
    "ClosureSurface",
    "OuterCeilingSurface",
    "OuterFloorSurface",
    "FloorSurface",
    "InteriorWallSurface",
    "CeilingSurface",
    "WaterSurface",
    "WaterGroundSurface",
    "WaterClosureSurface",
    "GenericThematicSurface",
    "HoleSurface",
    "Marking",
];

/// A polygon (GML Polygon, PolygonPatch or Triangle): its rings without the closing point, outer
/// first, and the semantic type of the thematic surface it lies in.
#[derive(Debug, Default)]
pub(super) struct Polygon {
    pub rings: Vec<Vec<DVec3>>,
    pub ring_ids: Vec<Option<String>>,
    pub semantic: Option<usize>,
    /// A prototype's polygon (inside an ImplicitGeometry), in the prototype's own coordinates:
    /// never drawn itself, only its placements.
    pub template: bool,
    /// A placed prototype's polygon: its rings are offsets in metres from this point of the
    /// file's CRS (the placement's reference point), until the CRS is known and they are placed.
    pub anchor: Option<DVec3>,
    /// A placed prototype's polygon: the prototype's polygon it is a copy of, whose appearance
    /// (targeted by that polygon's or its rings' gml:ids) it wears.
    pub prototype: Option<u32>,
}

/// An ImplicitGeometry (CityGML 2.0 clause 8.2, 3.0 core): a prototype's surfaces, placed by a
/// 4x4 row-major transformation and a reference point, at the LoD of its property.
#[derive(Debug, Clone)]
pub(super) struct ImplicitPlacement {
    pub lod: u8,
    pub matrix_row_major: [f64; 16],
    pub reference: DVec3,
    pub template: Vec<Member>,
}

/// What an ImplicitGeometry has said so far.
#[derive(Debug, Default)]
struct ImplicitState {
    /// The LoD list of the object it belongs to: its prototype's surfaces are collected apart
    /// meanwhile.
    outer_lod: Option<(u8, Vec<Member>)>,
    matrix_row_major: Option<[f64; 16]>,
    reference: Option<DVec3>,
    library_object: bool,
}

/// A surface of a geometry: a polygon read inline, or an `xlink:href` to a polygon or a
/// geometry elsewhere in the file; `true` when an OrientableSurface turns it over.
#[derive(Debug, Clone)]
pub(super) enum Member {
    Polygon(u32, bool),
    Href(String, bool),
}

/// A city object: its id, class, parent, surfaces per LoD and attributes.
#[derive(Debug, Default)]
pub(super) struct CityObject {
    pub id: String,
    pub class: String,
    pub parent: Option<usize>,
    pub lods: BTreeMap<u8, Vec<Member>>,
    pub name: Option<String>,
    pub attributes: Vec<(String, PropertyValue)>,
    /// The LoD a relief component states in its own `lod` element.
    plain_lod: Option<u8>,
    /// Its ImplicitGeometry placements, drawn as surfaces of the LoD they are under.
    pub implicit: Vec<ImplicitPlacement>,
    /// An Application Domain Extension's feature (a class outside the OGC namespaces).
    pub ade: bool,
}

/// Everything read from one CityGML document.
#[derive(Debug, Default)]
pub(super) struct Document {
    pub polygons: Vec<Polygon>,
    pub objects: Vec<CityObject>,
    /// gml:id of a polygon → its index.
    pub polygon_ids: HashMap<String, u32>,
    /// gml:id of any other geometry (a surface, solid, composite) → its surfaces.
    pub geometry_ids: HashMap<String, Vec<Member>>,
    /// Semantic type names (`Polygon::semantic` indexes them).
    pub semantics: Vec<String>,
    /// The first `srsName` of the file.
    pub srs_name: Option<String>,
    pub appearances: Appearances,
    /// ImplicitGeometry instances not drawn: a library object (an external file), no
    /// transformation or reference point, or outside a LoD property.
    pub implicit_not_drawn: usize,
    /// Bytes read (decompressed).
    pub bytes: u64,
}

/// What an open element means to the reader, so its end restores the state its start changed.
#[derive(Debug)]
enum Frame {
    Plain,
    Object,
    Thematic(Option<usize>),
    /// A `lodN…` geometry property (or, for a relief component, its geometry itself).
    Lod,
    /// A geometry with a gml:id: its surfaces start at this index of the open LoD list.
    GeometryId(String, usize),
    Orientable(bool),
    Polygon(Option<String>),
    Ring,
    Implicit,
    GenericAttribute,
    Appearance,
    Texture,
    Material,
    TextureTarget,
    TexCoordList(Option<String>),
    /// Two meanings of one element: the first ends first.
    Both(Box<Frame>, Box<Frame>),
}

/// An open element: what it means, whether it has children, its name and namespace (for leaf
/// text: coordinates, appearance fields, attributes).
#[derive(Debug)]
struct Open {
    frame: Frame,
    had_child: bool,
    local: String,
    prefix: String,
    ns: Namespace,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Namespace {
    Gml,
    CityGml,
    Generics,
    /// An Application Domain Extension (any namespace outside OGC, W3C and OASIS xAL).
    Ade,
    Other,
}

fn namespace_of(ns: &[u8]) -> Namespace {
    if ns.starts_with(b"http://www.opengis.net/gml") {
        Namespace::Gml
    } else if is_ogc(ns) && ns.windows(8).any(|w| w == b"generics") {
        Namespace::Generics
    } else if is_ogc(ns) {
        Namespace::CityGml
    } else if ns.is_empty()
        || ns.starts_with(b"http://www.w3.org/")
        || ns.starts_with(b"urn:oasis:")
    {
        Namespace::Other
    } else {
        Namespace::Ade
    }
}

/// An XML error or a reading problem, with the byte offset where it happened.
pub(super) struct ParseError {
    pub offset: u64,
    pub message: String,
}

struct Parser {
    doc: Document,
    frames: Vec<Open>,
    text: String,
    objects: Vec<usize>,
    /// The semantic type in effect where each open object starts (an opening's own): text
    /// read under another one belongs to a thematic surface, not to the object.
    object_semantics: Vec<Option<usize>>,
    semantic: Option<usize>,
    lod: Option<(u8, Vec<Member>)>,
    reversed: bool,
    polygon: Option<Polygon>,
    ring: Option<(Vec<DVec3>, Option<String>)>,
    implicit_depth: usize,
    /// The ImplicitGeometry being read.
    implicit: Option<ImplicitState>,
    srs_dimension: usize,
    in_appearance: bool,
    theme: Option<String>,
    texture: Option<TextureDef>,
    material: Option<MaterialDef>,
    target: Option<TextureTarget>,
    generic: Option<GenericAttribute>,
}

fn is_ogc(ns: &[u8]) -> bool {
    ns.starts_with(b"http://www.opengis.net/")
}

/// Reads a whole document from `input`.
pub(super) fn parse(input: impl BufRead) -> Result<Document, ParseError> {
    let mut reader = NsReader::from_reader(input);
    reader.config_mut().expand_empty_elements = true;
    reader.config_mut().trim_text(true);
    let mut p = Parser {
        doc: Document::default(),
        frames: Vec::new(),
        text: String::new(),
        objects: Vec::new(),
        object_semantics: Vec::new(),
        semantic: None,
        lod: None,
        reversed: false,
        polygon: None,
        ring: None,
        implicit_depth: 0,
        implicit: None,
        srs_dimension: 3,
        in_appearance: false,
        theme: None,
        texture: None,
        material: None,
        target: None,
        generic: None,
    };
    let mut buf = Vec::new();
    let mut saw_root = false;
    loop {
        let at = reader.buffer_position();
        let fail = |message: String| ParseError {
            offset: at,
            message,
        };
        let event = reader
            .read_resolved_event_into(&mut buf)
            .map_err(|e| fail(format!("invalid XML: {e}")))?;
        match event {
            (ns, Event::Start(e)) => {
                let ns: Vec<u8> = match ns {
                    ResolveResult::Bound(n) => n.as_ref().to_vec(),
                    _ => Vec::new(),
                };
                if !saw_root {
                    saw_root = true;
                    let local = e.local_name();
                    if local.as_ref() != b"CityModel" {
                        return Err(fail(format!(
                            "not a CityGML file: the root element is <{}>, not CityModel",
                            String::from_utf8_lossy(e.name().as_ref())
                        )));
                    }
                }
                p.start(&ns, &e).map_err(fail)?;
            }
            (_, Event::End(_)) => p.end().map_err(fail)?,
            (_, Event::Text(t)) => {
                let t = t
                    .xml_content()
                    .map_err(|e| fail(format!("text is not UTF-8: {e}")))?;
                p.text.push_str(&t);
            }
            (_, Event::CData(t)) => p.text.push_str(&String::from_utf8_lossy(&t)),
            (_, Event::GeneralRef(r)) => {
                let c = match r.resolve_char_ref() {
                    Ok(Some(c)) => c.to_string(),
                    _ => {
                        let name = String::from_utf8_lossy(&r).into_owned();
                        quick_xml::escape::resolve_predefined_entity(&name)
                            .map(str::to_string)
                            .ok_or_else(|| fail(format!("unknown entity &{name};")))?
                    }
                };
                p.text.push_str(&c);
            }
            (_, Event::Eof) => break,
            _ => {}
        }
        buf.clear();
    }
    if !saw_root {
        return Err(ParseError {
            offset: 0,
            message: "not a CityGML file: no XML element".into(),
        });
    }
    if !p.frames.is_empty() {
        return Err(ParseError {
            offset: reader.buffer_position(),
            message: "the document ends inside an element (truncated file?)".into(),
        });
    }
    p.doc.bytes = reader.buffer_position();
    Ok(p.doc)
}

fn attr(e: &BytesStart<'_>, local: &[u8]) -> Option<String> {
    e.attributes().flatten().find_map(|a| {
        (a.key.local_name().as_ref() == local).then(|| {
            a.unescape_value()
                .map(|v| v.into_owned())
                .unwrap_or_else(|_| String::from_utf8_lossy(&a.value).into_owned())
        })
    })
}

/// `#id` (or `id`) as the id.
fn href_id(s: &str) -> String {
    s.trim().trim_start_matches('#').to_string()
}

impl Parser {
    fn start(&mut self, ns: &[u8], e: &BytesStart<'_>) -> Result<(), String> {
        // The text so far belonged to the parent, which has children: not a leaf.
        self.text.clear();
        if let Some(f) = self.frames.last_mut() {
            f.had_child = true;
        }
        let local_name = e.local_name();
        let local = std::str::from_utf8(local_name.as_ref()).unwrap_or("");
        let ogc = is_ogc(ns);
        let is_gml = ns.starts_with(b"http://www.opengis.net/gml");
        if let Some(s) = attr(e, b"srsName") {
            self.doc.srs_name.get_or_insert(s);
        }
        if let Some(d) = attr(e, b"srsDimension").and_then(|d| d.trim().parse().ok()) {
            self.srs_dimension = d;
        }
        let id = attr(e, b"id");
        let href = attr(e, b"href");
        let namespace = namespace_of(ns);
        let ade = namespace == Namespace::Ade;
        let frame = if local == "ImplicitGeometry" {
            self.implicit_depth += 1;
            if self.implicit_depth == 1 {
                match self.lod.as_ref() {
                    Some(&(lod, _)) => {
                        // The prototype's surfaces go to a list of their own.
                        let outer_lod = self.lod.replace((lod, Vec::new()));
                        self.implicit = Some(ImplicitState {
                            outer_lod,
                            ..ImplicitState::default()
                        });
                    }
                    None => self.doc.implicit_not_drawn += 1,
                }
            }
            Frame::Implicit
        } else if self.implicit_depth > 1 {
            Frame::Plain
        } else if self.implicit.is_some() && local == "relativeGMLGeometry" {
            if let Some(h) = href {
                self.push_member(Member::Href(href_id(&h), self.reversed));
            }
            Frame::Plain
        } else if ogc && !is_gml && local == "Appearance" {
            self.in_appearance = true;
            self.theme = None;
            Frame::Appearance
        } else if self.in_appearance {
            self.appearance_start(local, e)
        } else if ogc && !is_gml && CITY_OBJECT_CLASSES.contains(&local) {
            self.object_start(local, id)
        } else if ogc && !is_gml && OPENING_CLASSES.contains(&local) {
            let object = self.object_start(local, id);
            let thematic = self.thematic_start(local);
            if let Some(s) = self.object_semantics.last_mut() {
                *s = self.semantic;
            }
            Frame::Both(Box::new(thematic), Box::new(object))
        } else if ogc && !is_gml && THEMATIC_SURFACES.contains(&local) {
            self.thematic_start(local)
        } else if ade && self.lod.is_none() && is_ade_feature(local, id.as_deref()) {
            // An ADE's own feature: a boundary surface of its parent when it is one (it sits in a
            // `boundedBy`), else a city object.
            let in_bounded_by = self.frames.last().is_some_and(|f| f.local == "boundedBy");
            if in_bounded_by {
                self.thematic_start(local)
            } else {
                let frame = self.object_start(local, id);
                if let Some(&o) = self.objects.last() {
                    self.doc.objects[o].ade = true;
                }
                frame
            }
        } else if self.lod.is_none()
            && ((ogc && !is_gml && lod_of_property(local).is_some())
                || (ade && !self.objects.is_empty() && ade_geometry_lod(local).is_some()))
        {
            self.lod = Some((lod_of_property(local).unwrap_or(0), Vec::new()));
            if let Some(h) = href {
                self.push_member(Member::Href(href_id(&h), self.reversed));
            }
            Frame::Lod
        } else if is_gml {
            self.geometry_start(local, e, id, href)?
        } else if attributes::is_generic_attribute(ns, local) {
            self.generic = Some(GenericAttribute::new(local, attr(e, b"name")));
            Frame::GenericAttribute
        } else {
            Frame::Plain
        };
        let qname = e.name();
        let prefix = qname
            .prefix()
            .map(|p| String::from_utf8_lossy(p.as_ref()).into_owned())
            .unwrap_or_default();
        self.frames.push(Open {
            frame,
            had_child: false,
            local: local.to_string(),
            prefix,
            ns: namespace,
        });
        Ok(())
    }

    /// A city object opens: its polygons and attributes are its own until it ends.
    fn object_start(&mut self, local: &str, id: Option<String>) -> Frame {
        let index = self.doc.objects.len();
        self.doc.objects.push(CityObject {
            id: id.unwrap_or_else(|| format!("{local}-{index}")),
            class: local.to_string(),
            parent: self.objects.last().copied(),
            ..CityObject::default()
        });
        self.objects.push(index);
        self.object_semantics.push(self.semantic);
        Frame::Object
    }

    /// A thematic surface opens: the polygons inside it are of its semantic type.
    fn thematic_start(&mut self, local: &str) -> Frame {
        let index = match self.doc.semantics.iter().position(|s| s == local) {
            Some(i) => i,
            None => {
                self.doc.semantics.push(local.to_string());
                self.doc.semantics.len() - 1
            }
        };
        Frame::Thematic(self.semantic.replace(index))
    }

    fn push_member(&mut self, m: Member) {
        if let Some((_, list)) = self.lod.as_mut() {
            list.push(m);
        }
    }

    fn geometry_start(
        &mut self,
        local: &str,
        e: &BytesStart<'_>,
        id: Option<String>,
        href: Option<String>,
    ) -> Result<Frame, String> {
        let is_surface = matches!(local, "Polygon" | "PolygonPatch" | "Triangle");
        // Geometry outside a `lodN…` property: a relief component's TIN, at its stated LoD.
        let relief = self
            .objects
            .last()
            .is_some_and(|&o| self.doc.objects[o].class.ends_with("Relief"));
        if self.lod.is_none() && relief && is_surface_geometry(local) {
            let object = &self.doc.objects[*self.objects.last().unwrap_or(&0)];
            let lod = object.plain_lod.unwrap_or(0);
            self.lod = Some((lod, Vec::new()));
            let inner = self.geometry_start(local, e, id, href)?;
            return Ok(Frame::Both(Box::new(inner), Box::new(Frame::Lod)));
        }
        if self.lod.is_none() {
            return Ok(Frame::Plain);
        }
        if let Some(h) = href {
            self.push_member(Member::Href(href_id(&h), self.reversed));
        }
        Ok(match local {
            _ if is_surface => {
                self.polygon = Some(Polygon {
                    semantic: self.semantic,
                    ..Polygon::default()
                });
                Frame::Polygon(id)
            }
            "LinearRing" if self.polygon.is_some() => {
                self.ring = Some((Vec::new(), id));
                Frame::Ring
            }
            "OrientableSurface" => {
                let flip = attr(e, b"orientation").is_some_and(|o| o.trim() == "-");
                let was = self.reversed;
                self.reversed ^= flip;
                match id {
                    Some(id) => {
                        // Its id names it as turned: recorded as a geometry of its own.
                        let start = self.lod.as_ref().map_or(0, |l| l.1.len());
                        Frame::Both(
                            Box::new(Frame::GeometryId(id, start)),
                            Box::new(Frame::Orientable(was)),
                        )
                    }
                    None => Frame::Orientable(was),
                }
            }
            _ => match id {
                Some(id) => {
                    let start = self.lod.as_ref().map_or(0, |l| l.1.len());
                    Frame::GeometryId(id, start)
                }
                None => Frame::Plain,
            },
        })
    }

    /// An ImplicitGeometry ends: the object's LoD list is back, and the placement is recorded
    /// (or counted as not drawn when it names no prototype here, or no transformation).
    fn implicit_end(&mut self) {
        let Some(state) = self.implicit.take() else {
            return;
        };
        let template = std::mem::replace(&mut self.lod, state.outer_lod).map(|(_, list)| list);
        let lod = self.lod.as_ref().map(|&(lod, _)| lod);
        match (
            state.matrix_row_major,
            state.reference,
            template,
            lod,
            self.objects.last(),
        ) {
            (Some(matrix_row_major), Some(reference), Some(template), Some(lod), Some(&o))
                if !template.is_empty() =>
            {
                self.doc.objects[o].implicit.push(ImplicitPlacement {
                    lod,
                    matrix_row_major,
                    reference,
                    template,
                });
            }
            _ => self.doc.implicit_not_drawn += 1,
        }
    }

    fn appearance_start(&mut self, local: &str, e: &BytesStart<'_>) -> Frame {
        match local {
            "ParameterizedTexture" | "GeoreferencedTexture" => {
                self.texture = Some(TextureDef {
                    theme: self.theme.clone(),
                    georeferenced: (local == "GeoreferencedTexture")
                        .then(GeoreferencedPlacement::default),
                    ..TextureDef::default()
                });
                Frame::Texture
            }
            "X3DMaterial" => {
                self.material = Some(MaterialDef {
                    theme: self.theme.clone(),
                    ..MaterialDef::default()
                });
                Frame::Material
            }
            // CityGML 2.0: <target uri="#polygon">; 3.0: <TextureAssociation> with a <target>.
            "target" if self.texture.is_some() && attr(e, b"uri").is_some() => {
                self.target = Some(TextureTarget {
                    polygon: href_id(&attr(e, b"uri").unwrap_or_default()),
                    rings: Vec::new(),
                });
                Frame::TextureTarget
            }
            "TextureAssociation" if self.texture.is_some() => {
                self.target = Some(TextureTarget::default());
                Frame::TextureTarget
            }
            "textureCoordinates" => Frame::TexCoordList(attr(e, b"ring")),
            _ => Frame::Plain,
        }
    }

    fn end(&mut self) -> Result<(), String> {
        let Some(mut open) = self.frames.pop() else {
            return Err("an end tag without its start".into());
        };
        let text = std::mem::take(&mut self.text);
        let frame = std::mem::replace(&mut open.frame, Frame::Plain);
        self.end_frame(frame, &open, text)
    }

    fn end_frame(&mut self, frame: Frame, open: &Open, text: String) -> Result<(), String> {
        match frame {
            Frame::Both(inner, outer) => {
                self.end_frame(*inner, open, String::new())?;
                self.end_frame(*outer, open, text)?;
            }
            Frame::Plain => {
                if !open.had_child && !text.trim().is_empty() {
                    self.leaf_text(open, text.trim())?;
                }
            }
            Frame::Object => {
                self.objects.pop();
                self.object_semantics.pop();
            }
            Frame::Thematic(previous) => self.semantic = previous,
            Frame::Lod => {
                if let Some((lod, list)) = self.lod.take() {
                    if let Some(&o) = self.objects.last() {
                        self.doc.objects[o]
                            .lods
                            .entry(lod)
                            .or_default()
                            .extend(list);
                    }
                }
            }
            Frame::GeometryId(id, start) => {
                if let Some((_, list)) = &self.lod {
                    let members = list.get(start..).unwrap_or_default().to_vec();
                    self.doc.geometry_ids.insert(id, members);
                }
            }
            Frame::Orientable(was) => self.reversed = was,
            Frame::Polygon(id) => {
                if let Some(mut polygon) = self.polygon.take() {
                    polygon.template = self.implicit.is_some();
                    if !polygon.rings.is_empty() {
                        let index = self.doc.polygons.len() as u32;
                        self.doc.polygons.push(polygon);
                        if let Some(id) = id {
                            self.doc.polygon_ids.insert(id, index);
                        }
                        self.push_member(Member::Polygon(index, self.reversed));
                    }
                }
            }
            Frame::Ring => {
                if let (Some((mut points, id)), Some(polygon)) =
                    (self.ring.take(), self.polygon.as_mut())
                {
                    if points.len() > 1 && points.first() == points.last() {
                        points.pop();
                    }
                    polygon.rings.push(points);
                    polygon.ring_ids.push(id);
                }
            }
            Frame::Implicit => {
                self.implicit_depth -= 1;
                if self.implicit_depth == 0 {
                    self.implicit_end();
                }
            }
            Frame::GenericAttribute => {
                if let (Some(g), Some(&o)) = (self.generic.take(), self.objects.last()) {
                    if let Some(a) = g.finish() {
                        if self.semantic.is_none() {
                            self.doc.objects[o].attributes.push(a);
                        }
                    }
                }
            }
            Frame::Appearance => self.in_appearance = false,
            Frame::Texture => {
                if let Some(t) = self.texture.take() {
                    self.doc.appearances.textures.push(t);
                }
            }
            Frame::Material => {
                if let Some(m) = self.material.take() {
                    self.doc.appearances.materials.push(m);
                }
            }
            Frame::TextureTarget => {
                if let (Some(t), Some(tex)) = (self.target.take(), self.texture.as_mut()) {
                    tex.targets.push(t);
                }
            }
            Frame::TexCoordList(ring) => {
                if let (Some(ring), Some(t)) = (ring, self.target.as_mut()) {
                    let values = parse_numbers(&text)?;
                    let uvs = values
                        .chunks_exact(2)
                        .map(|c| [c[0] as f32, (1.0 - c[1]) as f32])
                        .collect();
                    t.rings.push((href_id(&ring), uvs));
                }
            }
        }
        Ok(())
    }

    /// The text of an element with no children: coordinates, appearance fields, attributes.
    fn leaf_text(&mut self, open: &Open, text: &str) -> Result<(), String> {
        let local = open.local.as_str();
        if let Some(state) = self.implicit.as_mut().filter(|_| self.ring.is_none()) {
            match local {
                "transformationMatrix" => {
                    let values = parse_numbers(text)?;
                    let matrix: [f64; 16] = values.try_into().map_err(|v: Vec<f64>| {
                        format!("transformationMatrix of {} numbers, not 16", v.len())
                    })?;
                    state.matrix_row_major = Some(matrix);
                }
                "pos" | "coordinates" => {
                    let values = parse_numbers(&text.replace(',', " "))?;
                    if !(2..=3).contains(&values.len()) {
                        return Err(format!(
                            "ImplicitGeometry reference point '{text}' is not a point"
                        ));
                    }
                    state.reference = Some(point(&values));
                }
                "libraryObject" => state.library_object = true,
                _ => {}
            }
            return Ok(());
        }
        if open.ns == Namespace::Gml && self.implicit_depth <= 1 {
            if let Some((points, _)) = self.ring.as_mut() {
                match local {
                    "posList" | "pos" => {
                        let values = parse_numbers(text)?;
                        let dim = if local == "pos" {
                            values.len()
                        } else {
                            self.srs_dimension
                        };
                        if !(2..=3).contains(&dim) || values.len() % dim != 0 {
                            return Err(format!(
                                "gml:{local} of {} numbers does not divide into points of dimension {dim}",
                                values.len()
                            ));
                        }
                        points.extend(values.chunks_exact(dim).map(point));
                    }
                    "coordinates" => {
                        for tuple in text.split_ascii_whitespace() {
                            let values = parse_numbers(&tuple.replace(',', " "))?;
                            if !(2..=3).contains(&values.len()) {
                                return Err(format!(
                                    "gml:coordinates tuple '{tuple}' is not a point"
                                ));
                            }
                            points.push(point(&values));
                        }
                    }
                    _ => {}
                }
                return Ok(());
            }
        }
        if self.in_appearance {
            let text = text.to_string();
            if local == "theme" {
                self.theme = Some(text);
            } else if let Some(t) = self.texture.as_mut() {
                match (local, self.target.as_mut(), t.georeferenced.as_mut()) {
                    ("imageURI", _, _) => t.image = text,
                    ("wrapMode", _, _) => t.wrap_mode = Some(text),
                    ("target", Some(target), _) => target.polygon = href_id(&text),
                    ("target", None, Some(g)) => g.targets.push(href_id(&text)),
                    ("orientation", _, Some(g)) => {
                        let values = parse_numbers(&text)?;
                        g.orientation = Some(values.try_into().map_err(|v: Vec<f64>| {
                            format!(
                                "GeoreferencedTexture orientation of {} numbers, not 4",
                                v.len()
                            )
                        })?);
                    }
                    ("preferWorldFile", _, Some(g)) => {
                        g.prefer_world_file = matches!(text.trim(), "true" | "1");
                    }
                    ("pos" | "coordinates", _, Some(g)) => {
                        let values = parse_numbers(&text.replace(',', " "))?;
                        if values.len() < 2 {
                            return Err(format!(
                                "GeoreferencedTexture reference point '{text}' is not a point"
                            ));
                        }
                        g.reference = Some([values[0], values[1]]);
                    }
                    _ => {}
                }
            } else if let Some(m) = self.material.as_mut() {
                match local {
                    "diffuseColor" => m.diffuse = parse_numbers(&text)?,
                    "transparency" => m.transparency = parse_numbers(&text)?.first().copied(),
                    "target" => m.targets.push(href_id(&text)),
                    _ => {}
                }
            }
            return Ok(());
        }
        if let Some(g) = self.generic.as_mut() {
            g.field(local, text);
            return Ok(());
        }
        let Some(&o) = self.objects.last() else {
            return Ok(());
        };
        if self.object_semantics.last() != Some(&self.semantic) || self.lod.is_some() {
            return Ok(());
        }
        let object = &mut self.doc.objects[o];
        // The nearest object must be the element's own: a nested object's fields are its own.
        match open.ns {
            Namespace::CityGml if local == "lod" => {
                object.plain_lod = text.trim().parse().ok();
            }
            Namespace::CityGml | Namespace::Gml => {
                if let Some(a) = attributes::core_attribute(local, text) {
                    if local == "name" && object.name.is_none() {
                        object.name = Some(text.to_string());
                    }
                    if !object.attributes.iter().any(|(n, _)| *n == a.0) {
                        object.attributes.push(a);
                    }
                }
            }
            Namespace::Ade => {
                let name = if open.prefix.is_empty() {
                    local.to_string()
                } else {
                    format!("{}:{local}", open.prefix)
                };
                if !object.attributes.iter().any(|(n, _)| *n == name) {
                    object
                        .attributes
                        .push((name, PropertyValue::Text(text.to_string())));
                }
            }
            _ => {}
        }
        Ok(())
    }
}

fn point(c: &[f64]) -> DVec3 {
    DVec3::new(c[0], c[1], c.get(2).copied().unwrap_or(0.0))
}

/// Whether a GML element is a surface geometry (one that holds polygons).
fn is_surface_geometry(local: &str) -> bool {
    matches!(
        local,
        "Polygon"
            | "Surface"
            | "TriangulatedSurface"
            | "Tin"
            | "MultiSurface"
            | "CompositeSurface"
            | "Solid"
            | "CompositeSolid"
            | "MultiSolid"
            | "OrientableSurface"
    )
}

/// Whether an ADE element is a feature of its own: a class name (capitalised) with a gml:id.
/// Data types of an ADE (an attribute's structure) have no id and stay attributes.
fn is_ade_feature(local: &str, id: Option<&str>) -> bool {
    id.is_some() && local.starts_with(|c: char| c.is_ascii_uppercase())
}

/// The LoD of an ADE's geometry property (`lod2Solid`, `lod0Geometry`…): named like CityGML's,
/// ending in a geometry word, so that an ADE attribute such as `lod1HeightType` stays an
/// attribute.
fn ade_geometry_lod(local: &str) -> Option<u8> {
    const GEOMETRY_WORDS: &[&str] = &[
        "Solid",
        "Surface",
        "Geometry",
        "FootPrint",
        "RoofEdge",
        "Curve",
    ];
    let lod = lod_of_property(local)?;
    GEOMETRY_WORDS
        .iter()
        .any(|w| local.ends_with(w))
        .then_some(lod)
}

/// The LoD of a geometry property (`lod2Solid`, `lod0FootPrint`, `lod3MultiSurface`…).
fn lod_of_property(local: &str) -> Option<u8> {
    let rest = local.strip_prefix("lod")?;
    let digit = rest.chars().next()?.to_digit(10)?;
    (rest.len() > 1).then_some(digit as u8)
}

/// Whitespace-separated numbers.
pub(super) fn parse_numbers(text: &str) -> Result<Vec<f64>, String> {
    text.split_ascii_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("'{t}' is not a number"))
        })
        .collect()
}
