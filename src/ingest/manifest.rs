//! Manifests: many building models placed in one scene ("many buildings in one tileset"), so that
//! one octree and one tileset cover all of them.
//!
//! A manifest is a JSON file (`schemas/manifest.schema.json`, book, "Campus manifests"): an
//! optional geographic `origin` (the tileset's east-north-up frame; default [`GeoOrigin::DEFAULT`])
//! and a list of `models`, each a file path relative to the manifest's folder with its placement: a
//! geographic point (`longitude_deg`, `latitude_deg`, `height_m`) or an offset in metres from the
//! origin (`east_m`, `north_m`, `up_m`), and a `heading_deg` (clockwise from north, the compass
//! convention). Each model's own anchor (the rule of `convert`: its origin, its footprint centre
//! when it is in projected coordinates, or its IFC site reference point turned to true north) goes
//! to its placement. Geographic placements are exact rigid transforms into the origin's frame (the
//! local east-north-up frame of the placement point, expressed in the origin's), so a building
//! kilometres away still lands on its point to the millimetre.
//!
//! Identity: every element keeps its id, except that an id used by several entries (the same model
//! placed twice) is prefixed with the entry's `name` and a slash in each of them; every element's
//! `building` is the entry's name, and its hierarchy path starts with it.

use crate::error::{Error, Result};
use crate::geodesy::GeoOrigin;
use crate::scene::{Node, NodeId, Scene, SharedText};
use glam::{DMat4, DVec3};
use serde::Deserialize;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Component as PathPart, Path, PathBuf};

/// The manifest file, as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    #[serde(default)]
    pub origin: Option<ManifestOrigin>,
    pub models: Vec<ManifestModel>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestOrigin {
    pub longitude_deg: f64,
    pub latitude_deg: f64,
    #[serde(default)]
    pub height_m: f64,
}

/// One placed model.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestModel {
    /// The building's name (default: the file stem); unique in the manifest.
    #[serde(default)]
    pub name: Option<String>,
    /// Relative to the manifest's folder, inside it.
    pub path: String,
    #[serde(default)]
    pub longitude_deg: Option<f64>,
    #[serde(default)]
    pub latitude_deg: Option<f64>,
    #[serde(default)]
    pub height_m: Option<f64>,
    #[serde(default)]
    pub east_m: Option<f64>,
    #[serde(default)]
    pub north_m: Option<f64>,
    #[serde(default)]
    pub up_m: Option<f64>,
    /// Clockwise from north, degrees: the model's +y (north) axis turns to this bearing.
    #[serde(default)]
    pub heading_deg: f64,
    /// The projected CRS of the model's map coordinates ("EPSG:28992"): the model is placed where
    /// they are, by its own CRS, instead of by a placement.
    #[serde(default)]
    pub crs: Option<String>,
    /// An OBJ model's up axis (`y`, `z`); default: `--up`.
    #[serde(default)]
    pub up: Option<crate::ingest::interchange::UpAxis>,
    /// An OBJ model's length unit (`m`, `cm`, `mm`, `ft`, `in`); default: `--unit`.
    #[serde(default)]
    pub unit: Option<crate::ingest::interchange::LengthUnit>,
    /// The LoD to read of a CityGML or CityJSON model ("2"), instead of `--citygml-lod` /
    /// `--cityjson-lod`.
    #[serde(default)]
    pub lod: Option<String>,
}

/// A checked manifest entry: the model file and its transform from the model's anchored frame into
/// the origin's east-north-up frame.
#[derive(Debug, Clone)]
pub struct Placement {
    pub name: String,
    pub file: PathBuf,
    pub transform: DMat4,
    /// The model's map coordinates are in this CRS: it goes where they are.
    pub crs: Option<String>,
    /// The entry's own OBJ up axis and unit.
    pub mesh_frame: crate::ingest::interchange::MeshFrame,
    /// The entry's LoD of a city model.
    pub lod: Option<String>,
}

impl Manifest {
    /// Reads and checks a manifest; every problem is one error naming the manifest.
    pub fn read(path: &Path) -> Result<(GeoOrigin, Vec<Placement>)> {
        let text = super::read_regular(path).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                Error::input(path, "no such manifest file")
            } else {
                Error::input_from(path, "cannot read the manifest", e)
            }
        })?;
        Manifest::from_bytes(path, &text)
    }

    /// [`Manifest::read`] of the manifest text `text` at `path` (its models are looked up beside
    /// `path`).
    pub fn from_bytes(path: &Path, text: &[u8]) -> Result<(GeoOrigin, Vec<Placement>)> {
        let m: Manifest = serde_json::from_slice(text)
            .map_err(|e| Error::input_from(path, "not a valid manifest", e))?;
        m.check(path)
    }

    fn check(&self, path: &Path) -> Result<(GeoOrigin, Vec<Placement>)> {
        let bad = |m: String| Error::input(path, m);
        let origin = match self.origin {
            None => GeoOrigin::DEFAULT,
            Some(o) => GeoOrigin::parse(&format!(
                "{},{},{}",
                o.longitude_deg, o.latitude_deg, o.height_m
            ))
            .map_err(|e| Error::input_from(path, "origin", e))?,
        };
        if self.models.is_empty() {
            return Err(bad("the manifest lists no models".into()));
        }
        let folder = path.parent().unwrap_or(Path::new(""));
        let ecef_to_origin = origin.enu_to_ecef().inverse();
        let mut names = BTreeSet::new();
        let mut out = Vec::new();
        for (i, e) in self.models.iter().enumerate() {
            let what = format!("models[{i}] ('{}')", e.path);
            let rel = Path::new(&e.path);
            let escapes = rel.is_absolute()
                || rel.components().any(|c| {
                    matches!(
                        c,
                        PathPart::ParentDir | PathPart::RootDir | PathPart::Prefix(_)
                    )
                });
            if e.path.is_empty() || escapes {
                return Err(bad(format!(
                    "{what}: the path must be relative and stay inside the manifest's folder"
                )));
            }
            let file = folder.join(rel);
            // Inside by its text, but a symlink could still lead out of the folder.
            if crate::uri::confine::leads_outside(&file, folder) {
                return Err(bad(format!(
                    "{what}: a symlink leads outside the manifest's folder (refused)"
                )));
            }
            match super::open_regular(&file) {
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    return Err(bad(format!(
                        "{what}: no such model file {}",
                        file.display()
                    )))
                }
                Err(e) => return Err(bad(format!("{what}: {}: {e}", file.display()))),
                Ok(_) => {}
            }
            let name = match &e.name {
                Some(n) if n.trim().is_empty() || n.contains('/') => {
                    return Err(bad(format!(
                        "{what}: name '{n}' must be non-empty and without '/'"
                    )))
                }
                Some(n) => n.clone(),
                None => rel
                    .file_stem()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_default(),
            };
            if !names.insert(name.clone()) {
                return Err(bad(format!(
                    "{what}: the name '{name}' is used twice (give each entry a distinct \"name\")"
                )));
            }
            let numbers = [
                ("longitude_deg", e.longitude_deg),
                ("latitude_deg", e.latitude_deg),
                ("height_m", e.height_m),
                ("east_m", e.east_m),
                ("north_m", e.north_m),
                ("up_m", e.up_m),
            ];
            let implausible = numbers.iter().find_map(|(field, v)| {
                v.filter(|v| !crate::geodesy::plausible_m(*v))
                    .map(|v| (field, v))
            });
            if let Some((field, v)) = implausible {
                return Err(bad(format!(
                    "{what}: {field} {v:e} is not plausible (beyond ±{:e}, the Earth's circumference in metres)",
                    crate::geodesy::PLAUSIBLE_COORDINATE_M
                )));
            }
            if !e.heading_deg.is_finite() || e.heading_deg.abs() > 360.0 {
                return Err(bad(format!(
                    "{what}: heading_deg {:e} is not within ±360",
                    e.heading_deg
                )));
            }
            let geographic = e.longitude_deg.is_some() || e.latitude_deg.is_some();
            let offset = e.east_m.is_some() || e.north_m.is_some() || e.up_m.is_some();
            if e.crs.is_some() && (geographic || offset || e.height_m.is_some()) {
                return Err(bad(format!(
                    "{what}: a model with a \"crs\" is placed by its map coordinates; give no placement with it"
                )));
            }
            let heading = DMat4::from_rotation_z(-e.heading_deg.to_radians());
            let transform = match (geographic, offset) {
                (true, true) => {
                    return Err(bad(format!(
                        "{what}: give either longitude_deg/latitude_deg/height_m or east_m/north_m/up_m, not both"
                    )))
                }
                (true, false) => {
                    let (Some(lon), Some(lat)) = (e.longitude_deg, e.latitude_deg) else {
                        return Err(bad(format!(
                            "{what}: a geographic placement needs both longitude_deg and latitude_deg"
                        )));
                    };
                    let here = GeoOrigin::parse(&format!(
                        "{lon},{lat},{}",
                        e.height_m.unwrap_or(0.0)
                    ))
                    .map_err(|m| bad(format!("{what}: {m}")))?;
                    ecef_to_origin * here.enu_to_ecef() * heading
                }
                (false, _) => {
                    if e.height_m.is_some() {
                        return Err(bad(format!(
                            "{what}: height_m goes with longitude_deg/latitude_deg; an offset uses up_m"
                        )));
                    }
                    let t = DVec3::new(
                        e.east_m.unwrap_or(0.0),
                        e.north_m.unwrap_or(0.0),
                        e.up_m.unwrap_or(0.0),
                    );
                    DMat4::from_translation(t) * heading
                }
            };
            out.push(Placement {
                name,
                file,
                transform,
                crs: e.crs.clone(),
                mesh_frame: crate::ingest::interchange::MeshFrame {
                    up: e.up,
                    unit: e.unit,
                },
                lod: e.lod.clone(),
            });
        }
        Ok((origin, out))
    }
}

/// `read` of each of `items`, in their order, run on as many plain threads as the thread pool has,
/// each taking the next item: not on the pool itself, because a reader may block its thread on
/// one of its own (the IFC reader reads geometry beside the georeference) whose parallel work then
/// waits for a pool thread that would never come free.
fn side_by_side<T: Sync, R: Send>(items: &[T], read: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let done: Vec<std::sync::Mutex<Option<R>>> = items.iter().map(|_| Default::default()).collect();
    let threads = rayon::current_num_threads().clamp(1, items.len().max(1));
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(item) = items.get(i) else { break };
                *done[i].lock().expect("read slot") = Some(read(item));
            });
        }
    });
    done.into_iter()
        .map(|r| r.into_inner().expect("read slot").expect("every item read"))
        .collect()
}

/// Reads every model of a manifest, places it, and returns one scene in the manifest origin's
/// east-north-up frame. The scene carries the origin as its georeference (anchor at the frame's
/// origin, no turn), so `convert` places the site there unless `--origin` moves it.
pub fn read_manifest(path: &Path, opts: super::ReadOptions<'_>) -> Result<Scene> {
    let (origin, placements) = Manifest::read(path)?;
    let ecef_to_origin = origin.enu_to_ecef().inverse();
    // The models are read side by side (a campus of IFC files spends most of an update reading
    // them), and joined in the manifest's order; the first failing entry, in that order, is the
    // error.
    let read_placed = |p: &Placement| -> Result<Scene> {
        let given = p.crs.as_deref().map(|crs| super::GivenCrs {
            crs,
            source: "manifest",
        });
        let lod = p.lod.as_deref();
        let read = super::ReadOptions {
            crs: given,
            cityjson_lod: lod.or(opts.cityjson_lod),
            citygml_lod: lod.or(opts.citygml_lod),
            mesh_frame: p.mesh_frame.or(opts.mesh_frame),
            ..opts
        };
        let mut s = super::read_input_with(&p.file, read)?;
        // The model's own anchor goes to its placement (the rule of `convert`); a model in map
        // coordinates goes where its CRS puts its anchor.
        let local = crate::scene::placement::Placement::of(&s).local;
        let transform = match (&p.crs, s.georeference) {
            (Some(_), Some(g)) if g.map_linear.is_some() => {
                let here = GeoOrigin {
                    longitude_deg: g.longitude_deg,
                    latitude_deg: g.latitude_deg,
                    height_m: g.height_m,
                };
                ecef_to_origin * here.enu_to_ecef()
            }
            _ => p.transform,
        };
        s.georeference = None;
        s.apply_transform(&(transform * local));
        Ok(s)
    };
    let mut parts: Vec<Scene> = side_by_side(&placements, read_placed)
        .into_iter()
        .collect::<Result<_>>()?;
    // Ids used by more than one entry get the entry's name as a prefix, in every entry.
    let mut users: BTreeMap<String, BTreeSet<usize>> = BTreeMap::new();
    for (i, s) in parts.iter().enumerate() {
        for e in s.elements.iter() {
            users.entry(e.key).or_default().insert(i);
        }
    }
    let clashing: BTreeSet<String> = users
        .into_iter()
        .filter(|(_, u)| u.len() > 1)
        .map(|(k, _)| k)
        .collect();
    let mut scene = Scene::default();
    for (s, p) in parts.iter_mut().zip(&placements) {
        let building: SharedText = p.name.as_str().into();
        s.elements = std::mem::take(&mut s.elements).map(|e| {
            if clashing.contains(&e.key) {
                e.key = format!("{}/{}", p.name, e.key);
                s.renamed_ids += 1;
            }
            e.building = Some(building.clone());
        });
        // A root node named after the entry heads the model's hierarchy.
        let root = NodeId(s.nodes.len() as u32);
        for n in &mut s.nodes {
            if n.parent.is_none() {
                n.parent = Some(root);
            }
        }
        for c in &mut s.components {
            if c.node.is_none() {
                c.node = Some(root);
            }
        }
        s.nodes.push(Node {
            name: Some(p.name.clone()),
            parent: None,
            extras: None,
            name_repeat: 0,
        });
    }
    for s in parts {
        scene.append(s);
    }
    // Two entries of one name could still clash.
    super::keep_ids_unique(&mut scene);
    scene.georeference = Some(crate::scene::SourceGeoreference {
        longitude_deg: origin.longitude_deg,
        latitude_deg: origin.latitude_deg,
        height_m: origin.height_m,
        true_north_deg: None,
        anchor: DVec3::ZERO,
        map_linear: None,
    });
    scene.stable_layout = true;
    scene.finish();
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readers_that_wait_on_threads_of_their_own_finish_in_order() {
        // As the IFC reader: each read waits for a thread of its own whose work is parallel.
        use rayon::prelude::*;
        let items: Vec<u64> = (0..4 * rayon::current_num_threads() as u64 + 3).collect();
        let read = |&k: &u64| {
            std::thread::scope(|s| {
                s.spawn(|| (0..10_000u64).into_par_iter().map(|x| x * k).sum::<u64>())
                    .join()
                    .expect("no panic")
            })
        };
        let sums = side_by_side(&items, read);
        let expected: Vec<u64> = items.iter().map(|k| k * 49_995_000).collect();
        assert_eq!(sums, expected);
        assert!(side_by_side(&[] as &[u64], read).is_empty());
    }

    fn check(json: &str) -> std::result::Result<Vec<Placement>, String> {
        let dir = std::env::temp_dir().join(format!("bimtiles-manifest-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("a.glb"), b"x").unwrap();
        let p = dir.join("m.json");
        std::fs::write(&p, json).unwrap();
        Manifest::read(&p)
            .map(|(_, v)| v)
            .map_err(|e| crate::error::chain_text(&e))
    }

    #[test]
    fn placements_and_errors() {
        let v = check(r#"{"models":[{"path":"a.glb","east_m":10,"north_m":-2,"heading_deg":90}]}"#)
            .unwrap();
        // Heading 90°: the model's north (+y) turns to east (+x).
        let p = v[0].transform.transform_point3(DVec3::new(0.0, 1.0, 0.0));
        assert!((p - DVec3::new(11.0, -2.0, 0.0)).length() < 1e-12, "{p}");
        for (json, want) in [
            (r#"{"models":[{"path":"../a.glb"}]}"#, "inside the manifest"),
            (r#"{"models":[{"path":"b.glb"}]}"#, "no such model file"),
            (
                r#"{"models":[{"path":"a.glb","colour":1}]}"#,
                "unknown field",
            ),
            (
                r#"{"models":[{"path":"a.glb","east_m":1,"longitude_deg":8,"latitude_deg":49}]}"#,
                "not both",
            ),
            (
                r#"{"models":[{"path":"a.glb"},{"path":"a.glb"}]}"#,
                "used twice",
            ),
            (
                r#"{"models":[{"path":"a.glb","longitude_deg":8}]}"#,
                "both longitude_deg",
            ),
            (r#"{"models":[]}"#, "no models"),
            (r#"{"models":[{"path":"a.glb"}"#, "not a valid manifest"),
        ] {
            let e = check(json).unwrap_err();
            assert!(
                e.contains(want) && e.contains("m.json") && !e.contains('\n'),
                "{json}: {e}"
            );
        }
    }
}
