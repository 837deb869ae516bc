//! Materials, textures, images and samplers of one tile: each scene material written once, its
//! image as the tile's texture level (embedded or a shared file).

use super::*;

/// The materials, textures, images and samplers of one GLB, each written once.
#[derive(Default)]
pub(super) struct MaterialTable<'a> {
    /// Where image bytes come from (default: the scene's own).
    pub(super) image_source: Option<ImageSource<'a>>,
    pub(super) materials: Vec<Value>,
    pub(super) material_map: BTreeMap<u32, usize>,
    pub(super) images: Vec<Value>,
    pub(super) image_map: BTreeMap<u32, usize>,
    /// Shared files written, by URI, and embedded atlases, by their bytes' address: two scene
    /// images packed into one atlas are one glTF image.
    pub(super) uri_map: BTreeMap<String, usize>,
    pub(super) embedded: Vec<(std::sync::Arc<Vec<u8>>, usize)>,
    /// See [`encode_content_with_images`].
    pub(super) sampled_px: BTreeMap<ImageId, u32>,
    pub(super) samplers: Vec<Sampler>,
    pub(super) textures: Vec<(usize, usize)>,
    /// The material of the edges ([`crate::encode::edges::EDGE_COLOR`]), once a primitive has edges.
    pub(super) edge_material: Option<usize>,
}

impl MaterialTable<'_> {
    /// The glTF index of scene material `mid`, written (with its image) on first use.
    pub(super) fn index(
        &mut self,
        scene: &Scene,
        b: &mut GltfBuilder,
        mid: MaterialId,
    ) -> std::result::Result<usize, EncodeError> {
        if let Some(&i) = self.material_map.get(&mid.0) {
            return Ok(i);
        }
        let mat = &scene.materials[mid.index()];
        let mut tex = None;
        if let Some(t) = mat.base_color_texture.as_ref() {
            let img = match self.image_map.get(&t.image.0) {
                Some(&i) => i,
                None => {
                    let im = &scene.images[t.image.index()];
                    let image = match self.image_source {
                        Some(source) => source(t.image)?,
                        None => TileImage::Embedded {
                            bytes: im.bytes.clone(),
                            mime: im.mime_type.clone(),
                        },
                    };
                    let k = self.push_image(b, image);
                    self.image_map.insert(t.image.0, k);
                    k
                }
            };
            let sampler = self
                .samplers
                .iter()
                .position(|s| *s == t.sampler)
                .unwrap_or_else(|| {
                    self.samplers.push(t.sampler);
                    self.samplers.len() - 1
                });
            tex = Some(
                self.textures
                    .iter()
                    .position(|&x| x == (img, sampler))
                    .unwrap_or_else(|| {
                        self.textures.push((img, sampler));
                        self.textures.len() - 1
                    }),
            );
        }
        self.materials.push(material_json(mat, tex));
        self.material_map.insert(mid.0, self.materials.len() - 1);
        Ok(self.materials.len() - 1)
    }

    /// The glTF index of `image`, written unless the same shared file or the same embedded
    /// bytes (one `Arc`: an atlas) already are.
    pub(super) fn push_image(&mut self, b: &mut GltfBuilder, image: TileImage) -> usize {
        let n = self.images.len();
        match image {
            TileImage::Embedded { bytes, mime } => {
                if let Some(&(_, k)) = self
                    .embedded
                    .iter()
                    .find(|(a, _)| std::sync::Arc::ptr_eq(a, &bytes))
                {
                    return k;
                }
                self.images
                    .push(json!({"bufferView": b.view(&bytes, None), "mimeType": mime}));
                self.embedded.push((bytes, n));
            }
            TileImage::External { uri, mime } => {
                if let Some(&k) = self.uri_map.get(&uri) {
                    return k;
                }
                self.images.push(json!({"uri": uri, "mimeType": mime}));
                self.uri_map.insert(uri, n);
            }
        }
        n
    }

    /// The glTF index of the edges' material, written on first use.
    pub(super) fn edge_index(&mut self) -> usize {
        *self.edge_material.get_or_insert_with(|| {
            self.materials
                .push(json!({"name": "edges", "pbrMetallicRoughness": {
                "baseColorFactor": crate::encode::edges::EDGE_COLOR, "metallicFactor": 0.0}}));
            self.materials.len() - 1
        })
    }

    pub(super) fn write_into(self, root: &mut Value) {
        if !self.materials.is_empty() {
            root["materials"] = json!(self.materials);
        }
        if !self.images.is_empty() {
            let is_ktx2 = |i: usize| self.images[i]["mimeType"] == "image/ktx2";
            // KHR_texture_basisu: a KTX2 image is the extension's source, with no PNG/JPEG
            // fallback, so the extension is required as well as used (its spec, "Using Without a
            // Fallback").
            if self.textures.iter().any(|&(source, _)| is_ktx2(source)) {
                for key in ["extensionsUsed", "extensionsRequired"] {
                    match root[key].as_array_mut() {
                        Some(list) => list.push(json!("KHR_texture_basisu")),
                        None => root[key] = json!(["KHR_texture_basisu"]),
                    }
                }
            }
            root["images"] = json!(self.images);
            root["textures"] = json!(self
                .textures
                .iter()
                .map(|&(source, sampler)| match is_ktx2(source) {
                    true => json!({"extensions": {"KHR_texture_basisu": {"source": source}},
                                   "sampler": sampler}),
                    false => json!({"source": source, "sampler": sampler}),
                })
                .collect::<Vec<_>>());
            root["samplers"] = json!(self.samplers.iter().map(sampler_json).collect::<Vec<_>>());
        }
    }
}

pub(super) fn material_json(m: &Material, texture: Option<usize>) -> Value {
    let mut pbr = json!({
        "baseColorFactor": m.base_color,
        "metallicFactor": m.metallic,
        "roughnessFactor": m.roughness,
    });
    if let Some(t) = texture {
        pbr["baseColorTexture"] = json!({"index": t});
    }
    let mut v = json!({"pbrMetallicRoughness": pbr});
    if let Some(n) = &m.name {
        v["name"] = json!(n);
    }
    if m.emissive != [0.0; 3] {
        v["emissiveFactor"] = json!(m.emissive);
    }
    match m.alpha_mode {
        AlphaMode::Opaque => {}
        AlphaMode::Mask => {
            v["alphaMode"] = json!("MASK");
            v["alphaCutoff"] = json!(m.alpha_cutoff);
        }
        AlphaMode::Blend => v["alphaMode"] = json!("BLEND"),
    }
    if m.double_sided {
        v["doubleSided"] = json!(true);
    }
    v
}

pub(super) fn sampler_json(s: &Sampler) -> Value {
    let mut v = json!({});
    if s.mag_filter != 0 {
        v["magFilter"] = json!(s.mag_filter);
    }
    if s.min_filter != 0 {
        v["minFilter"] = json!(s.min_filter);
    }
    if s.wrap_s != 0 {
        v["wrapS"] = json!(s.wrap_s);
    }
    if s.wrap_t != 0 {
        v["wrapT"] = json!(s.wrap_t);
    }
    v
}
