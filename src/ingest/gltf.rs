//! glTF 2.0 reader (`.gltf` with external or embedded buffers and images, and `.glb`).
//!
//! Every node that has a mesh becomes a [`Component`], keeping its name, `extras` and parent
//! chain; its id is its GlobalId or its node path, kept unique by the rules of
//! [`crate::scene::ids`]. Node transforms are read from the raw JSON as f64 (the `gltf` crate keeps them as f32,
//! which loses millimetres on projected coordinates); the y-up → z-up change is applied once
//! here, through [`Y_UP_TO_Z_UP`].
//!
//! The `gltf` crate parses the container; the JSON is read in one streaming pass
//! ([`super::gltf_index`]: the large arrays reduced element by element through their `gltf_json`
//! types, the rest a small `gltf_json::Root`). We run the crate's validator only for broken
//! references (it rejects extensions 3D Tiles content needs), then read every accessor ourselves
//! with explicit bounds checks, so malformed input gives an error and never a panic.
//!
//! Compressed input (`EXT_meshopt_compression` views, `KHR_draco_mesh_compression` primitives)
//! and `KHR_texture_transform` are undone through [`super::gltf_compressed`].

use super::gltf_compressed::{decode_meshopt_view, draco_vectors, UvTransform};
use super::gltf_index::{
    AccessorDesc, GltfIndex, GltfIndexError, IndexNode, MeshDesc, PrimitiveDesc, ViewDesc,
};
use crate::error::{Error, Result};
use crate::scene::*;
use crate::uri::{confine, UriError};
use glam::{DMat4, DQuat, DVec3};
use gltf::json::validation::Validate;
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

/// Extensions we read correctly (or can ignore without changing the geometry) when a file
/// declares them required.
const SUPPORTED_REQUIRED: &[&str] = &[
    "KHR_mesh_quantization",
    "KHR_draco_mesh_compression",
    "EXT_meshopt_compression",
    "KHR_texture_transform",
    "KHR_materials_unlit",
    "KHR_materials_emissive_strength",
];

/// Reads one glTF/GLB file into a new scene. The file is memory-mapped, so the JSON chunk's pages
/// and each decoded run of the BIN chunk are handed back as the reader moves on: the file never
/// counts whole towards peak memory.
pub fn read_gltf(path: &Path) -> Result<Scene> {
    let cannot_read = |e: std::io::Error| Error::input_from(path, "cannot read", e);
    let file = super::open_regular(path).map_err(cannot_read)?;
    let len = file.metadata().map_err(cannot_read)?.len();
    // SAFETY: the map is read-only and private. A file truncated by another process while it is
    // read would fault, as with any memory-mapped reader; inputs do not change during a run.
    let mapped = match len {
        0 => None,
        _ => unsafe { memmap2::Mmap::map(&file) }.ok(),
    };
    let bytes = match mapped {
        Some(m) => FileBytes::Mapped(m),
        None => FileBytes::Owned(super::read_regular(path).map_err(cannot_read)?),
    };
    read_gltf_from(path, &bytes)
}

/// Reads glTF/GLB bytes; `path` names the file in errors and anchors relative URIs.
pub fn read_gltf_bytes(path: &Path, bytes: &[u8]) -> Result<Scene> {
    read_gltf_from(path, &FileBytes::Owned(bytes.to_vec()))
}

/// The input's bytes, and whether its pages can be handed back once read.
enum FileBytes {
    Mapped(memmap2::Mmap),
    Owned(Vec<u8>),
}

impl FileBytes {
    fn bytes(&self) -> &[u8] {
        match self {
            FileBytes::Mapped(m) => m,
            FileBytes::Owned(v) => v,
        }
    }

    /// Drops the resident pages inside `range` (a mapped file only). Nothing borrowed changes:
    /// the map is a read-only view of the file, and a page touched again is read back from it.
    fn release(&self, range: std::ops::Range<usize>) {
        #[cfg(unix)]
        if let FileBytes::Mapped(m) = self {
            let page = 4096;
            // Whole pages only: a page shared with bytes still to be read stays resident.
            let start = range.start.div_ceil(page) * page;
            let end = (range.end.min(m.len()) / page) * page;
            if start < end {
                // SAFETY: see above; DONTNEED on a read-only file map only drops cached pages.
                let _ = unsafe {
                    m.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, start, end - start)
                };
            }
        }
    }
}

/// Why a GLB header is refused (glTF 2.0, 4.4.2).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
enum GlbHeaderError {
    /// Fewer than the header's 12 bytes.
    #[error("truncated GLB: no complete 12-byte header")]
    Truncated,
    /// A version other than 2.
    #[error("GLB version {0}: only version 2 exists")]
    Version(u32),
    /// The header's length is not the file's.
    #[error("the GLB header says the file has {declared_bytes} bytes, but it has {actual_bytes}")]
    Length {
        declared_bytes: u32,
        actual_bytes: usize,
    },
}

/// The GLB header's version and length (glTF 2.0, 4.4.2): version 2, and the length of the whole
/// file (the `gltf` crate checks only the magic): a file cut short or with bytes appended is
/// refused rather than read as far as it goes.
fn check_glb_header(bytes: &[u8]) -> std::result::Result<(), GlbHeaderError> {
    let word = |at: usize| {
        let b = bytes.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let (Some(version), Some(length_bytes)) = (word(4), word(8)) else {
        return Err(GlbHeaderError::Truncated);
    };
    if version != 2 {
        return Err(GlbHeaderError::Version(version));
    }
    if length_bytes as usize != bytes.len() {
        return Err(GlbHeaderError::Length {
            declared_bytes: length_bytes,
            actual_bytes: bytes.len(),
        });
    }
    Ok(())
}

/// Reads a glTF/GLB from its bytes: a GLB's BIN chunk is read in place, never copied.
fn read_gltf_from(path: &Path, file: &FileBytes) -> Result<Scene> {
    let bytes = file.bytes();
    let err = |m: String| Error::input(path, m);
    let is_glb = bytes.starts_with(b"glTF");
    if !is_glb {
        let first = bytes.iter().find(|b| !b.is_ascii_whitespace());
        if first != Some(&b'{') {
            return Err(err(
                "not a glTF file (no GLB header and no JSON object)".into()
            ));
        }
    }
    // (JSON text, BIN chunk's byte range inside `bytes`).
    let (json_text, bin_range): (&[u8], Option<std::ops::Range<usize>>) = if is_glb {
        check_glb_header(bytes).map_err(|e| err(e.to_string()))?;
        let glb = gltf::binary::Glb::from_slice(bytes)
            .map_err(|e| Error::input_from(path, "invalid or truncated GLB", e))?;
        let json: &[u8] = match glb.json {
            std::borrow::Cow::Borrowed(j) => j,
            std::borrow::Cow::Owned(_) => return Err(err("invalid GLB JSON chunk".into())),
        };
        let bin = match glb.bin {
            Some(std::borrow::Cow::Borrowed(b)) => {
                let start = b.as_ptr() as usize - bytes.as_ptr() as usize;
                Some(start..start + b.len())
            }
            _ => None,
        };
        (json, bin)
    } else {
        (bytes, None)
    };
    let index: GltfIndex = serde_json::from_slice(json_text).map_err(|e| {
        let what = match is_glb {
            true => "invalid GLB JSON chunk",
            false => "invalid glTF JSON",
        };
        Error::input_from(path, what, e)
    })?;
    let file_bytes = bytes.len() as u64;
    let json_start = json_text.as_ptr() as usize - bytes.as_ptr() as usize;
    file.release(json_start..json_start + json_text.len());
    let bin_start = bin_range.as_ref().map(|r| r.start);
    let bin: Option<&[u8]> = bin_range.map(|r| &bytes[r]);

    let index_check = index.check_references();
    let GltfIndex {
        root,
        image_views,
        mut nodes,
        scenes,
        scene: default_scene,
        meshes,
        accessors,
        mut views,
    } = index;
    let doc = gltf::Document::from_json_without_validation(root);
    check_references(&doc)
        .and(index_check)
        .map_err(|e| Error::input_from(path, "invalid glTF", e))?;
    for ext in doc.extensions_required() {
        if !SUPPORTED_REQUIRED.contains(&ext) {
            return Err(err(format!(
                "requires extension {ext}, which bimtiles does not read"
            )));
        }
    }

    let base_dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let external = load_buffers(&doc, bin, &base_dir, path)?;
    let mut buffers: Vec<&[u8]> = external
        .iter()
        .map(|b| match b {
            BufferData::Bin => bin.unwrap_or(&[]),
            BufferData::Owned(v) => &v[..],
        })
        .collect();
    // Compressed views are decoded into buffers of their own, appended after the file's, and
    // the views pointed at them: the accessor reader then sees plain data.
    let decoded_views = decode_meshopt_views(path, &buffers, &views)?;
    for (k, (view, bytes)) in decoded_views.iter().enumerate() {
        let v = &mut views[*view];
        v.buffer = buffers.len() + k;
        v.offset = 0;
        v.length = bytes.len();
        v.meshopt = None;
    }
    buffers.extend(decoded_views.iter().map(|(_, b)| &b[..]));
    let mut reader = Reader {
        texts: TextInterner::default(),
        path,
        buffers: &buffers,
        views: &views,
        accessors: &accessors,
        file,
        in_file: external
            .iter()
            .map(|b| match b {
                BufferData::Bin => bin_start,
                BufferData::Owned(_) => None,
            })
            .collect(),
        scene: Scene::default(),
        uv_transforms: Vec::new(),
    };
    reader.scene.sources.push(SourceFile {
        path: path.to_path_buf(),
        bytes: file_bytes,
    });
    reader.read_images(&doc, &image_views, &base_dir)?;
    reader.read_materials(&doc);
    drop(doc);
    let roots = default_scene
        .or((!scenes.is_empty()).then_some(0))
        .map(|s| &scenes[s as usize][..]);
    let mesh_order = reader.read_nodes(&mut nodes, roots, meshes.len())?;
    drop(nodes);
    crate::memory::release_freed_heap();
    reader.read_meshes(&meshes, &mesh_order)?;
    let mut scene = reader.scene;
    scene.finish();
    Ok(scene)
}

/// Decodes every `EXT_meshopt_compression` bufferView: (view index, its decoded bytes).
fn decode_meshopt_views(
    path: &Path,
    buffers: &[&[u8]],
    views: &[ViewDesc],
) -> Result<Vec<(usize, Vec<u8>)>> {
    use rayon::prelude::*;
    views
        .par_iter()
        .enumerate()
        .filter_map(|(i, v)| v.meshopt.as_deref().map(|m| (i, m)))
        .map(|(i, m)| {
            // The buffer index was checked with the other references.
            decode_meshopt_view(m, buffers[m.buffer])
                .map(|bytes| (i, bytes))
                .map_err(|e| {
                    Error::input_from(path, format!("bufferView {i} (EXT_meshopt_compression)"), e)
                })
        })
        .collect()
}

/// Broken indices (an accessor naming a missing bufferView, a node naming a missing mesh...) are
/// fatal; "unsupported extension" and "missing data" reports are not (3D Tiles content relies on
/// both), since the accessor reader checks data on its own.
fn check_references(doc: &gltf::Document) -> std::result::Result<(), GltfIndexError> {
    let root = doc.as_json();
    let mut first: Option<GltfIndexError> = None;
    root.validate(root, gltf::json::Path::new, &mut |path, e| {
        use gltf::json::validation::Error as E;
        if matches!(e, E::IndexOutOfBounds | E::Invalid | E::Oversize) && first.is_none() {
            first = Some(GltfIndexError::Validation {
                path: path().to_string(),
                source: e,
            });
        }
    });
    first.map_or(Ok(()), Err)
}

/// The bytes of a buffer's or an image's URI: a data URI's, or the file's it names inside the
/// input folder ([`confine::INPUT`]).
fn load_uri(base_dir: &Path, uri: &str) -> std::result::Result<Vec<u8>, UriError> {
    if let Some(data) = crate::uri::data::decode(uri) {
        return data;
    }
    let path = confine::inside(base_dir, uri, &confine::INPUT)?;
    super::read_regular(&path).map_err(|source| UriError::Read { path, source })
}

/// A buffer's bytes: the GLB BIN chunk (borrowed from the file) or loaded from a URI.
enum BufferData {
    Bin,
    Owned(Vec<u8>),
}

fn load_buffers(
    doc: &gltf::Document,
    bin: Option<&[u8]>,
    base_dir: &Path,
    path: &Path,
) -> Result<Vec<BufferData>> {
    let mut out = Vec::new();
    for b in doc.buffers() {
        // A meshopt fallback buffer holds nothing: only compressed views name it, and they are
        // read from their extension's buffer.
        let fallback = b
            .extensions()
            .and_then(|e| e.get("EXT_meshopt_compression"))
            .and_then(|m| m.get("fallback"))
            .and_then(Value::as_bool)
            .unwrap_or(false);
        if fallback && (b.index() > 0 || bin.is_none()) {
            if let gltf::buffer::Source::Bin = b.source() {
                out.push(BufferData::Owned(Vec::new()));
                continue;
            }
        }
        let (data, len) = match b.source() {
            gltf::buffer::Source::Bin => {
                let bin = bin.ok_or_else(|| {
                    Error::input(
                        path,
                        format!("buffer {} refers to a missing GLB BIN chunk", b.index()),
                    )
                })?;
                (BufferData::Bin, bin.len())
            }
            gltf::buffer::Source::Uri(uri) => {
                let v = load_uri(base_dir, uri)
                    .map_err(|e| Error::input_from(path, format!("buffer {}", b.index()), e))?;
                let n = v.len();
                (BufferData::Owned(v), n)
            }
        };
        if len < b.length() {
            return Err(Error::input(
                path,
                format!(
                    "buffer {} is truncated: {} bytes, byteLength says {}",
                    b.index(),
                    len,
                    b.length()
                ),
            ));
        }
        out.push(data);
    }
    Ok(out)
}

struct Reader<'a> {
    path: &'a Path,
    buffers: &'a [&'a [u8]],
    views: &'a [ViewDesc],
    accessors: &'a [AccessorDesc],
    /// The input file, and where each buffer starts in it (the GLB BIN chunk), so decoded
    /// geometry's pages can be handed back.
    file: &'a FileBytes,
    in_file: Vec<Option<usize>>,
    scene: Scene,
    /// Repeated metadata text (classes, storeys, property names), one copy each.
    texts: TextInterner,
    /// Each material's `KHR_texture_transform` on its base-colour texture, applied to the UVs
    /// of the primitives that use it.
    uv_transforms: Vec<Option<UvTransform>>,
}

/// BIM semantics from a node's `extras`, as BIM exporters write them (IfcOpenShell:
/// `{ifc_class, name, storey}`; others: `guid`/`GlobalId`, `building`, `site`, `material`). Other
/// scalar extras become properties of the set "extras".
fn element_info(extras: Option<&Value>, texts: &mut TextInterner) -> ElementInfo {
    let mut info = ElementInfo::default();
    let Some(obj) = extras.and_then(Value::as_object) else {
        return info;
    };
    for (k, v) in obj {
        let mut shared = || v.as_str().map(|s| texts.get(s));
        match k.as_str() {
            "guid" | "GlobalId" | "globalId" | "ifc_guid" => {
                info.guid = v.as_str().map(str::to_string)
            }
            "ifc_class" | "ifcClass" | "IfcClass" | "class" => info.class = shared(),
            "storey" | "Storey" | "level" | "Level" => info.storey = shared(),
            "building" => info.building = shared(),
            "site" => info.site = shared(),
            "material" => info.material = shared(),
            _ => {
                let Some(value) = PropertyValue::from_json_scalar(v) else {
                    continue;
                };
                info.properties.push(Property {
                    set: texts.get("extras"),
                    name: texts.get(k),
                    value,
                });
            }
        }
    }
    // One vector per element, kept for the whole run: no spare capacity (a million elements on
    // a 100M-triangle site).
    info.properties.shrink_to_fit();
    info
}

/// Whether `s` has the form of an IFC GlobalId: 22 characters of IFC's base-64 alphabet, the first
/// one of 0-3 (it encodes the top 2 bits of a 128-bit GUID).
pub fn is_ifc_guid(s: &str) -> bool {
    s.len() == 22
        && s.starts_with(['0', '1', '2', '3'])
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'$')
}

/// Raw node transform as f64 (matrix, or T·R·S).
fn node_local_matrix(node: &IndexNode) -> DMat4 {
    let Some(raw) = node.transform.as_deref() else {
        return DMat4::IDENTITY;
    };
    if let Some(m) = raw.matrix {
        return DMat4::from_cols_array(&m);
    }
    let t = raw.translation.map_or(DVec3::ZERO, DVec3::from_array);
    let r = raw.rotation.map_or(DQuat::IDENTITY, |v| {
        DQuat::from_xyzw(v[0], v[1], v[2], v[3]).normalize()
    });
    let s = raw.scale.map_or(DVec3::ONE, DVec3::from_array);
    DMat4::from_scale_rotation_translation(s, r, t)
}

impl Reader<'_> {
    fn err(&self, m: impl Into<String>) -> Error {
        Error::input(self.path, m)
    }

    fn view_bytes(&self, index: u32) -> Result<&[u8]> {
        let view = self
            .views
            .get(index as usize)
            .ok_or_else(|| self.err(format!("bufferView {index} does not exist")))?;
        let buf = self
            .buffers
            .get(view.buffer)
            .ok_or_else(|| self.err(format!("bufferView {index} names a missing buffer")))?;
        let end = view.offset.checked_add(view.length);
        match end {
            Some(end) if end <= buf.len() => Ok(&buf[view.offset..end]),
            _ => Err(self.err(format!(
                "bufferView {} (offset {}, length {}) points past the end of buffer {} ({} bytes)",
                index,
                view.offset,
                view.length,
                view.buffer,
                buf.len()
            ))),
        }
    }

    fn accessor(&self, index: u32) -> Result<&AccessorDesc> {
        self.accessors
            .get(index as usize)
            .ok_or_else(|| self.err(format!("accessor {index} does not exist")))
    }

    fn read_images(
        &mut self,
        doc: &gltf::Document,
        image_views: &[Option<u32>],
        base_dir: &Path,
    ) -> Result<()> {
        for img in doc.images() {
            let json = &doc.as_json().images[img.index()];
            let declared = json.mime_type.as_ref().map(|m| m.0.as_str());
            let bytes = match (image_views.get(img.index()).copied().flatten(), &json.uri) {
                (Some(view), _) => self.view_bytes(view)?.to_vec(),
                (None, Some(uri)) => load_uri(base_dir, uri).map_err(|e| {
                    Error::input_from(self.path, format!("image {}", img.index()), e)
                })?,
                (None, None) => {
                    return Err(self.err(format!(
                        "image {} has neither a uri nor a bufferView",
                        img.index()
                    )))
                }
            };
            let mime = crate::uri::mime::sniff_image(&bytes)
                .map(str::to_string)
                .or(declared.map(str::to_string))
                .ok_or_else(|| {
                    self.err(format!("image {} is not PNG, JPEG or WebP", img.index()))
                })?;
            self.scene.images.push(Image {
                name: img.name().map(str::to_string),
                mime_type: mime,
                bytes: Arc::new(bytes),
            });
        }
        Ok(())
    }

    fn read_materials(&mut self, doc: &gltf::Document) {
        for m in doc.materials() {
            let pbr = m.pbr_metallic_roughness();
            let transform = pbr
                .base_color_texture()
                .and_then(|info| info.extensions()?.get("KHR_texture_transform").cloned());
            self.uv_transforms
                .push(transform.as_ref().and_then(UvTransform::from_json));
            let tex = pbr.base_color_texture().map(|info| {
                let s = info.texture().sampler();
                TextureRef {
                    image: ImageId(info.texture().source().index() as u32),
                    sampler: Sampler {
                        mag_filter: s.mag_filter().map_or(0, |f| f.as_gl_enum()),
                        min_filter: s.min_filter().map_or(0, |f| f.as_gl_enum()),
                        wrap_s: s.wrap_s().as_gl_enum(),
                        wrap_t: s.wrap_t().as_gl_enum(),
                    },
                    tex_coord: info.tex_coord(),
                }
            });
            self.scene.materials.push(Material {
                name: m.name().map(str::to_string),
                base_color: pbr.base_color_factor(),
                metallic: pbr.metallic_factor(),
                roughness: pbr.roughness_factor(),
                emissive: m.emissive_factor(),
                base_color_texture: tex,
                alpha_mode: match m.alpha_mode() {
                    gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
                    gltf::material::AlphaMode::Mask => AlphaMode::Mask,
                    gltf::material::AlphaMode::Blend => AlphaMode::Blend,
                },
                alpha_cutoff: m.alpha_cutoff().unwrap_or(0.5),
                double_sided: m.double_sided(),
            });
        }
    }

    /// Reads the node hierarchy into components, from `roots` (the scene's; every parentless
    /// node when there is no scene); returns the glTF meshes they use, in order of first use,
    /// for [`Reader::read_meshes`]. Names and extras move into the scene's nodes (not copied:
    /// a million nodes on a 100M-triangle site).
    fn read_nodes(
        &mut self,
        nodes: &mut [IndexNode],
        roots: Option<&[u32]>,
        mesh_count: usize,
    ) -> Result<Vec<usize>> {
        // Hierarchy: every glTF node becomes a scene node with the same index.
        let mut parent = vec![None; nodes.len()];
        for (i, n) in nodes.iter().enumerate() {
            for &c in &n.children {
                let c = c as usize;
                if parent[c].is_some() || c == i {
                    return Err(self.err(format!("node {c} has more than one parent")));
                }
                parent[c] = Some(NodeId(i as u32));
            }
        }
        let roots: Vec<u32> = match roots {
            Some(r) => r.to_vec(),
            None => (0..parent.len() as u32)
                .filter(|&i| parent[i as usize].is_none())
                .collect(),
        };
        // Same-named siblings are numbered in their glTF order (scene::ids, rule 1).
        let names: Vec<Option<&str>> = nodes.iter().map(|n| n.name.as_deref()).collect();
        let groups = std::iter::once(&roots[..]).chain(nodes.iter().map(|n| &n.children[..]));
        let name_repeat = crate::scene::ids::number_same_named(&names, groups);
        self.scene.nodes.reserve_exact(nodes.len());
        for (i, n) in nodes.iter_mut().enumerate() {
            self.scene.nodes.push(Node {
                name: n.name.take(),
                parent: parent[i],
                extras: n.extras.take(),
                name_repeat: name_repeat[i],
            });
        }
        // Components are the reachable nodes with a mesh: reserved once, not grown by doubling.
        let with_mesh = nodes.iter().filter(|n| n.mesh.is_some()).count();
        self.scene.components.reserve_exact(with_mesh);
        self.scene.elements.reserve(with_mesh);
        // Elements are pushed once every GlobalId is known (rule 2: a repeated one is not an id).
        let mut elements: Vec<(Component, ElementInfo)> = Vec::with_capacity(with_mesh);
        // glTF mesh index → our MeshId, in order of first use; meshes are decoded afterwards, in
        // parallel.
        let mut mesh_ids: Vec<Option<MeshId>> = vec![None; mesh_count];
        let mut mesh_order: Vec<usize> = Vec::new();
        let mut visited = vec![false; parent.len()];
        let mut stack: Vec<(usize, DMat4)> = roots
            .iter()
            .rev()
            .map(|&i| (i as usize, Y_UP_TO_Z_UP))
            .collect();
        while let Some((idx, parent_world)) = stack.pop() {
            if std::mem::replace(&mut visited[idx], true) {
                return Err(self.err(format!(
                    "node {idx} is reached twice (a cycle or a shared child)"
                )));
            }
            let node = &nodes[idx];
            let world = parent_world * node_local_matrix(node);
            if !world.is_finite() {
                return Err(self.err(format!("node {idx} has a non-finite transform")));
            }
            if let Some(mesh) = node.mesh {
                // gltfpack (and other quantizers) move a mesh into an unnamed child node that
                // carries only its dequantization transform: the element is the named parent.
                let idx = match parent[idx] {
                    Some(p)
                        if self.scene.nodes[idx].name.is_none()
                            && self.scene.nodes[idx].extras.is_none()
                            && node.children.is_empty()
                            && nodes[p.index()].mesh.is_none()
                            && nodes[p.index()].children.len() == 1 =>
                    {
                        p.index()
                    }
                    _ => idx,
                };
                let mesh_id = *mesh_ids[mesh as usize].get_or_insert_with(|| {
                    mesh_order.push(mesh as usize);
                    MeshId(mesh_order.len() as u32 - 1)
                });
                // Parsed into the element's info and properties, then dropped: nothing reads a mesh
                // node's raw extras after this (tens of bytes an element).
                let extras = self.scene.nodes[idx].extras_value();
                self.scene.nodes[idx].extras = None;
                let name = &self.scene.nodes[idx].name;
                let mut info = element_info(extras.as_ref(), &mut self.texts);
                if info.guid.is_none() {
                    // IfcOpenShell names each node by its element's GlobalId.
                    info.guid = name
                        .as_deref()
                        .filter(|n| is_ifc_guid(n))
                        .map(str::to_string);
                }
                info.name = self.scene.nodes[idx].name.clone();
                let component = Component {
                    node: Some(NodeId(idx as u32)),
                    ..Component::new(mesh_id, world)
                };
                elements.push((component, info));
            }
            for &c in node.children.iter().rev() {
                stack.push((c as usize, world));
            }
        }
        self.push_elements(elements);
        Ok(mesh_order)
    }

    /// Gives each element its id (a unique GlobalId, else its node path: `scene::ids`) and adds
    /// it to the scene, counting the ids that differ from the plain GlobalId or path.
    fn push_elements(&mut self, elements: Vec<(Component, ElementInfo)>) {
        let mut guid_uses: HashMap<&str, u32> = HashMap::new();
        for (_, info) in &elements {
            if let Some(g) = &info.guid {
                *guid_uses.entry(g).or_insert(0) += 1;
            }
        }
        let mut keys = Vec::with_capacity(elements.len());
        for (c, info) in &elements {
            match info.guid.as_deref() {
                Some(g) if guid_uses[g] == 1 => keys.push(g.to_string()),
                guid => {
                    let node = c.node.expect("a glTF component has its node");
                    keys.push(self.scene.node_path(node));
                    let numbered = self.scene.path_is_numbered(node);
                    self.scene.renamed_ids += usize::from(guid.is_some() || numbered);
                }
            }
        }
        drop(guid_uses);
        self.scene.renamed_ids += crate::scene::ids::make_unique(&mut keys);
        for ((component, mut info), key) in elements.into_iter().zip(keys) {
            info.key = key;
            self.scene.push_component(component, &info);
        }
    }

    /// Decodes the meshes [`Reader::read_nodes`] listed (`order`: glTF mesh indices) into
    /// `scene.meshes`: in parallel, a run at a time, handing back the file pages each run has
    /// read (exports write a mesh's data after the previous mesh's, so the file's resident part
    /// stays about one run).
    fn read_meshes(&mut self, meshes: &[MeshDesc], order: &[usize]) -> Result<()> {
        use rayon::prelude::*;
        const RUN_MESHES: usize = 4096;
        self.scene.meshes.reserve(order.len());
        for run in order.chunks(RUN_MESHES) {
            let this = &*self;
            let decoded: Vec<Result<(Mesh, usize)>> = run
                .par_iter()
                .map(|&m| this.read_mesh(m, &meshes[m]))
                .collect();
            self.release_read(run.iter().map(|&m| &meshes[m]));
            for d in decoded {
                let (mesh, skipped) = d?;
                self.scene.meshes.push(mesh);
                self.scene.skipped_primitives += skipped;
            }
        }
        Ok(())
    }

    /// Hands back the file pages spanned by these meshes' bufferViews.
    fn release_read<'m>(&self, meshes: impl Iterator<Item = &'m MeshDesc>) {
        let mut span: Option<std::ops::Range<usize>> = None;
        let views = meshes
            .flat_map(|m| &m.primitives)
            .flat_map(|p| p.accessors())
            .filter_map(|a| self.accessors.get(a as usize))
            .flat_map(|a| a.views())
            .filter_map(|v| self.views.get(v as usize));
        for v in views {
            let Some(Some(base)) = self.in_file.get(v.buffer) else {
                continue;
            };
            let start = base.saturating_add(v.offset);
            let end = start.saturating_add(v.length);
            span = Some(match span {
                None => start..end,
                Some(s) => s.start.min(start)..s.end.max(end),
            });
        }
        if let Some(span) = span {
            self.file.release(span);
        }
    }

    /// Decodes one mesh (glTF index `index`); also returns how many primitives were not surfaces.
    fn read_mesh(&self, index: usize, mesh: &MeshDesc) -> Result<(Mesh, usize)> {
        let mut out = Mesh {
            name: mesh.name.clone(),
            ..Default::default()
        };
        let mut skipped = 0;
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let what = format!("mesh {index} primitive {pi}");
            match self.read_primitive(prim, &what)? {
                Some(p) => out.primitives.push(p),
                None => skipped += 1,
            }
        }
        Ok((out, skipped))
    }

    /// `Ok(None)` for primitives that are not surfaces (points, lines).
    fn read_primitive(&self, prim: &PrimitiveDesc, what: &str) -> Result<Option<Primitive>> {
        use gltf::mesh::Mode;
        let mode = prim.mode;
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            return Ok(None);
        }
        let data = match &prim.draco {
            Some(draco) => self.read_draco(prim, draco, what)?,
            None => self.read_attributes(prim, what)?,
        };
        let RawPrimitive {
            positions,
            normals,
            mut uvs,
            colors,
            indices: raw_indices,
        } = data;
        let n = positions.len();
        if let Some(i) = positions
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(self.err(format!(
                "{what}: POSITION {i} is not finite (NaN or infinity)"
            )));
        }
        if let Some(v) = &uvs {
            if v.iter().any(|t| !t[0].is_finite() || !t[1].is_finite()) {
                return Err(self.err(format!("{what}: TEXCOORD_0 has non-finite values")));
            }
        }
        let transform = prim
            .material
            .and_then(|m| self.uv_transforms.get(m as usize).copied().flatten());
        if let (Some(t), Some(v)) = (transform, uvs.as_mut()) {
            v.iter_mut().for_each(|uv| *uv = t.apply(*uv));
        }
        if let Some(bad) = raw_indices.iter().find(|&&i| i as usize >= n) {
            return Err(self.err(format!(
                "{what}: index {bad} is out of range ({n} vertices)"
            )));
        }
        // A Draco stream decodes to a triangle list whatever the primitive's mode.
        let mode = if prim.draco.is_some() {
            Mode::Triangles
        } else {
            mode
        };
        let indices = match mode {
            Mode::Triangles => {
                let mut v = raw_indices;
                v.truncate(v.len() / 3 * 3);
                v
            }
            Mode::TriangleStrip => (2..raw_indices.len())
                .flat_map(|i| {
                    let (a, b, c) = (raw_indices[i - 2], raw_indices[i - 1], raw_indices[i]);
                    if i % 2 == 0 {
                        [a, b, c]
                    } else {
                        [b, a, c]
                    }
                })
                .collect(),
            _ => (2..raw_indices.len())
                .flat_map(|i| [raw_indices[0], raw_indices[i - 1], raw_indices[i]])
                .collect(),
        };
        Ok(Some(Primitive {
            material: prim.material.map(MaterialId),
            positions,
            normals: normals.map(|v| v.into_iter().map(sanitize_normal).collect()),
            uvs,
            colors,
            indices,
        }))
    }

    /// A primitive's attributes and indices read from its accessors.
    fn read_attributes(&self, prim: &PrimitiveDesc, what: &str) -> Result<RawPrimitive> {
        let pos_acc = prim
            .positions
            .ok_or_else(|| self.err(format!("{what} has no POSITION")))?;
        let pos_acc = self.accessor(pos_acc)?;
        let positions: Vec<[f32; 3]> = self.read_vec::<3>(pos_acc, &format!("{what} POSITION"))?;
        let n = positions.len();
        let attr = |acc: Option<u32>, name: &str| -> Result<Option<&AccessorDesc>> {
            let Some(a) = acc else {
                return Ok(None);
            };
            let a = self.accessor(a)?;
            match a.count != n {
                true => Err(self.err(format!(
                    "{what}: {name} has {} elements, POSITION has {n}",
                    a.count
                ))),
                false => Ok(Some(a)),
            }
        };
        let normals = match attr(prim.normals, "NORMAL")? {
            Some(a) => Some(self.read_vec::<3>(a, &format!("{what} NORMAL"))?),
            None => None,
        };
        let uvs = match attr(prim.uvs, "TEXCOORD_0")? {
            Some(a) => Some(self.read_vec::<2>(a, &format!("{what} TEXCOORD_0"))?),
            None => None,
        };
        let colors = match attr(prim.colors, "COLOR_0")? {
            Some(a) if a.dimensions == gltf::accessor::Dimensions::Vec3 => Some(
                self.read_vec::<3>(a, &format!("{what} COLOR_0"))?
                    .into_iter()
                    .map(|c| [c[0], c[1], c[2], 1.0])
                    .collect(),
            ),
            Some(a) => Some(self.read_vec::<4>(a, &format!("{what} COLOR_0"))?),
            None => None,
        };
        let indices: Vec<u32> = match prim.indices {
            Some(a) => self.read_indices(self.accessor(a)?, what)?,
            None => (0..n as u32).collect(),
        };
        Ok(RawPrimitive {
            positions,
            normals,
            uvs,
            colors,
            indices,
        })
    }

    /// A `KHR_draco_mesh_compression` primitive decoded by libdraco; each attribute is the one
    /// the extension's `attributes` map names, typed by its accessor.
    fn read_draco(
        &self,
        prim: &PrimitiveDesc,
        draco: &super::gltf_index::DracoDesc,
        what: &str,
    ) -> Result<RawPrimitive> {
        let stream = self.view_bytes(draco.view)?;
        let mesh = crate::draco::decode_mesh(stream).map_err(|e| {
            Error::input_from(self.path, format!("{what} (KHR_draco_mesh_compression)"), e)
        })?;
        // (Draco unique id, its accessor) of an attribute both name.
        let attribute = |id: Option<u32>, acc: Option<u32>, name: &str| -> Result<_> {
            let (Some(id), Some(acc)) = (id, acc) else {
                return Ok(None);
            };
            let normalized = self.accessor(acc)?.normalized;
            let decoded = mesh.attribute(id).ok_or_else(|| {
                self.err(format!(
                    "{what}: {name} names Draco attribute {id}, which the stream does not have"
                ))
            })?;
            Ok(Some((decoded, normalized)))
        };
        let short = |name: &str| self.err(format!("{what}: Draco {name} has too few components"));
        let (p, norm) = attribute(draco.positions, prim.positions, "POSITION")?
            .ok_or_else(|| self.err(format!("{what} has no POSITION")))?;
        let positions = draco_vectors::<3>(p, norm).ok_or_else(|| short("POSITION"))?;
        let normals = match attribute(draco.normals, prim.normals, "NORMAL")? {
            Some((a, norm)) => Some(draco_vectors::<3>(a, norm).ok_or_else(|| short("NORMAL"))?),
            None => None,
        };
        let uvs = match attribute(draco.uvs, prim.uvs, "TEXCOORD_0")? {
            Some((a, norm)) => {
                Some(draco_vectors::<2>(a, norm).ok_or_else(|| short("TEXCOORD_0"))?)
            }
            None => None,
        };
        let colors = match attribute(draco.colors, prim.colors, "COLOR_0")? {
            Some((a, norm)) if a.components == 3 => Some(
                draco_vectors::<3>(a, norm)
                    .ok_or_else(|| short("COLOR_0"))?
                    .into_iter()
                    .map(|c| [c[0], c[1], c[2], 1.0])
                    .collect(),
            ),
            Some((a, norm)) => Some(draco_vectors::<4>(a, norm).ok_or_else(|| short("COLOR_0"))?),
            None => None,
        };
        Ok(RawPrimitive {
            positions,
            normals,
            uvs,
            colors,
            indices: mesh.indices,
        })
    }

    fn read_indices(&self, acc: &AccessorDesc, what: &str) -> Result<Vec<u32>> {
        use gltf::accessor::DataType as D;
        if acc.dimensions != gltf::accessor::Dimensions::Scalar {
            return Err(self.err(format!("{what}: indices accessor is not SCALAR")));
        }
        let (raw, _) = self.accessor_elements(acc, &format!("{what} indices"))?;
        Ok(match acc.data_type {
            D::U8 => raw.iter().map(|&e| e as u32).collect(),
            D::U16 => raw
                .chunks_exact(2)
                .map(|e| u16::from_le_bytes([e[0], e[1]]) as u32)
                .collect(),
            D::U32 => raw
                .chunks_exact(4)
                .map(|e| u32::from_le_bytes([e[0], e[1], e[2], e[3]]))
                .collect(),
            other => return Err(self.err(format!("{what}: indices have component type {other:?}"))),
        })
    }

    /// Reads a float (or quantized integer) vector accessor into f32 arrays, applying
    /// `normalized` as glTF defines it and sparse substitution.
    fn read_vec<const N: usize>(&self, acc: &AccessorDesc, what: &str) -> Result<Vec<[f32; N]>> {
        let dims = acc.dimensions.multiplicity();
        if dims < N {
            return Err(self.err(format!(
                "{what}: expected {N} components, accessor has {dims}"
            )));
        }
        let (packed, elem) = self.accessor_elements(acc, what)?;
        let comp = acc.data_type.size();
        let dt = acc.data_type;
        let norm = acc.normalized;
        let mut out = Vec::with_capacity(acc.count);
        if dt == gltf::accessor::DataType::F32 {
            // The common case, without the per-component dispatch.
            for e in packed.chunks_exact(elem.max(1)) {
                let mut v = [0f32; N];
                for (k, x) in v.iter_mut().enumerate() {
                    *x = f32::from_le_bytes([e[4 * k], e[4 * k + 1], e[4 * k + 2], e[4 * k + 3]]);
                }
                out.push(v);
            }
            return Ok(out);
        }
        for e in packed.chunks_exact(elem.max(1)) {
            let mut v = [0f32; N];
            for (k, x) in v.iter_mut().enumerate() {
                *x = decode_component(&e[k * comp..(k + 1) * comp], dt, norm);
            }
            out.push(v);
        }
        Ok(out)
    }

    /// The accessor's elements packed tightly (`count * element_size` bytes, sparse values
    /// applied), after checking that every byte lies inside its bufferView and buffer. Tightly
    /// packed data without sparse values is borrowed from the buffer, not copied: a mesh of a
    /// million triangles would otherwise hold its indices twice while it is decoded.
    fn accessor_elements(
        &self,
        acc: &AccessorDesc,
        what: &str,
    ) -> Result<(std::borrow::Cow<'_, [u8]>, usize)> {
        use std::borrow::Cow;
        let comp = acc.data_type.size();
        let elem = comp * acc.dimensions.multiplicity();
        let count = acc.count;
        let total = count
            .checked_mul(elem)
            .ok_or_else(|| self.err(format!("{what}: accessor size overflows")))?;
        let mut out: Cow<[u8]> = match acc.view {
            None => Cow::Owned(vec![0u8; total]),
            Some(view) => {
                let data = self.view_bytes(view)?;
                let stride = self.views[view as usize].stride.unwrap_or(elem).max(elem);
                let need = if count == 0 {
                    0
                } else {
                    (count - 1)
                        .checked_mul(stride)
                        .and_then(|x| x.checked_add(elem))
                        .and_then(|x| x.checked_add(acc.offset))
                        .ok_or_else(|| self.err(format!("{what}: accessor size overflows")))?
                };
                if need > data.len() {
                    return Err(self.err(format!(
                        "{what}: accessor ({count} elements) points past the end of its bufferView ({need} > {} bytes)",
                        data.len()
                    )));
                }
                if stride == elem {
                    Cow::Borrowed(&data[acc.offset..acc.offset + total])
                } else {
                    let mut v = Vec::with_capacity(total);
                    for i in 0..count {
                        let s = acc.offset + i * stride;
                        v.extend_from_slice(&data[s..s + elem]);
                    }
                    Cow::Owned(v)
                }
            }
        };
        if let Some(sparse) = &acc.sparse {
            let n = sparse.count;
            let idata = self.view_bytes(sparse.index_view)?;
            let isize = sparse.index_size;
            let vdata = self.view_bytes(sparse.value_view)?;
            let fits = |offset: usize, size: usize, len: usize| {
                n.checked_mul(size)
                    .and_then(|x| x.checked_add(offset))
                    .is_some_and(|end| end <= len)
            };
            if !fits(sparse.index_offset, isize, idata.len())
                || !fits(sparse.value_offset, elem, vdata.len())
            {
                return Err(self.err(format!("{what}: sparse data points past its bufferView")));
            }
            for k in 0..n {
                let s = sparse.index_offset + k * isize;
                let idx = match isize {
                    1 => idata[s] as usize,
                    2 => u16::from_le_bytes([idata[s], idata[s + 1]]) as usize,
                    _ => u32::from_le_bytes([idata[s], idata[s + 1], idata[s + 2], idata[s + 3]])
                        as usize,
                };
                if idx >= count {
                    return Err(self.err(format!("{what}: sparse index {idx} out of range")));
                }
                let vs = sparse.value_offset + k * elem;
                out.to_mut()[idx * elem..(idx + 1) * elem].copy_from_slice(&vdata[vs..vs + elem]);
            }
        }
        Ok((out, elem))
    }
}

/// A primitive's data as read, before the checks and fixes every source shares.
struct RawPrimitive {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    uvs: Option<Vec<[f32; 2]>>,
    colors: Option<Vec<[f32; 4]>>,
    indices: Vec<u32>,
}

fn decode_component(b: &[u8], dt: gltf::accessor::DataType, normalized: bool) -> f32 {
    use gltf::accessor::DataType as D;
    match dt {
        D::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        D::U8 if normalized => b[0] as f32 / 255.0,
        D::U8 => b[0] as f32,
        D::I8 if normalized => (b[0] as i8 as f32 / 127.0).max(-1.0),
        D::I8 => b[0] as i8 as f32,
        D::U16 if normalized => u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0,
        D::U16 => u16::from_le_bytes([b[0], b[1]]) as f32,
        D::I16 if normalized => (i16::from_le_bytes([b[0], b[1]]) as f32 / 32767.0).max(-1.0),
        D::I16 => i16::from_le_bytes([b[0], b[1]]) as f32,
        D::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
    }
}

/// Exporters sometimes write zero or non-finite normals; a unit up-vector is harmless where a NaN
/// would poison shading and simplification.
fn sanitize_normal(n: [f32; 3]) -> [f32; 3] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l.is_finite() && l > 1e-12 {
        [n[0] / l, n[1] / l, n[2] / l]
    } else {
        [0.0, 1.0, 0.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_uri_and_file_errors_are_typed() {
        let dir = Path::new("/nonexistent-bimtiles-dir");
        let ok = load_uri(dir, "data:application/octet-stream;base64,AAEC").unwrap();
        assert_eq!(ok, vec![0, 1, 2]);
        let e = load_uri(dir, "data:application/octet-stream;base64,@@@").unwrap_err();
        assert!(matches!(e, UriError::BadBase64 { .. }), "{e}");
        assert!(std::error::Error::source(&e).is_some());
        let e = load_uri(dir, "data:text/plain,hello").unwrap_err();
        assert!(matches!(e, UriError::DataNotBase64), "{e}");
        let e = load_uri(dir, "missing.bin").unwrap_err();
        match &e {
            UriError::Read { path, source } => {
                assert_eq!(path, &dir.join("missing.bin"));
                assert_eq!(source.kind(), std::io::ErrorKind::NotFound);
            }
            other => panic!("expected a read error, got {other}"),
        }
        // The reader's line: "<file>: buffer 0: cannot read '<path>': <io error>".
        let line = crate::error::chain_text(&Error::input_from("m.gltf", "buffer 0", e));
        assert!(
            line.starts_with(
                "m.gltf: buffer 0: cannot read '/nonexistent-bimtiles-dir/missing.bin': "
            ),
            "{line}"
        );
    }

    #[test]
    fn node_matrix_from_raw_json_keeps_f64() {
        let v: IndexNode =
            serde_json::from_str(r#"{"translation": [512345.678, 0.0, -5412345.123]}"#).unwrap();
        let m = node_local_matrix(&v);
        assert_eq!(m.w_axis.x, 512345.678);
        assert_eq!(m.w_axis.z, -5412345.123);
        let v: IndexNode =
            serde_json::from_str(r#"{"matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 5,6,7,1]}"#).unwrap();
        assert_eq!(
            node_local_matrix(&v).w_axis.truncate(),
            DVec3::new(5.0, 6.0, 7.0)
        );
    }

    #[test]
    fn normalized_components_decode() {
        use gltf::accessor::DataType as D;
        assert_eq!(decode_component(&[255], D::U8, true), 1.0);
        assert_eq!(decode_component(&[0x81], D::I8, true), -1.0);
        assert_eq!(decode_component(&[0xff, 0xff], D::U16, true), 1.0);
        assert_eq!(decode_component(&[7, 0], D::U16, false), 7.0);
    }

    #[test]
    fn ifc_guids_and_extras() {
        assert!(is_ifc_guid("2V3RCMqZPE5ad58ZlBLt5Y"));
        assert!(is_ifc_guid("1srAI$R4T8ihLXSNHmUSET"));
        assert!(!is_ifc_guid("Window-07"));
        assert!(!is_ifc_guid("9V3RCMqZPE5ad58ZlBLt5Y"));
        let v = serde_json::json!({"ifc_class": "IfcWindow", "storey": "Level 1", "name": "W1", "width": 1.2, "count": 3, "fire": true});
        let i = element_info(Some(&v), &mut TextInterner::default());
        assert_eq!(i.class.as_deref(), Some("IfcWindow"));
        assert_eq!(i.storey.as_deref(), Some("Level 1"));
        assert!(i
            .properties
            .iter()
            .any(|p| &*p.name == "width" && p.value == PropertyValue::Number(1.2)));
        assert!(i
            .properties
            .iter()
            .any(|p| &*p.name == "count" && p.value == PropertyValue::Integer(3)));
        assert!(i
            .properties
            .iter()
            .any(|p| &*p.name == "fire" && p.value == PropertyValue::Bool(true)));
    }
}
