//! Materials, textures, samplers and images: the metallic-roughness model with the extensions
//! the renderer honours (emissive strength, specular, ior, transmission, diffuse transmission,
//! volume, clearcoat, sheen, anisotropy, iridescence, unlit, texture transform), and
//! PNG/JPEG/WebP decoding into RGBA8 texels (16-bit PNGs into RGBA16) and KTX2 transcoding
//! (`KHR_texture_basisu`, in `basisu.rs`) into RGBA8, each image decoded once however many
//! textures use it.

use std::collections::HashMap;
use std::io::Cursor;
use std::sync::Arc;

use ::gltf::json;
use glam::{Vec2, Vec3, Vec4};
use json::texture::{MagFilter, MinFilter, WrappingMode};
use json::validation::Checked;
use serde_json::Value;

use super::{basisu, fail, Context, Image, ImageFormat, Loader, PendingImage, SceneError};
use crate::budget;
use crate::scene::{
    AlphaMode, Anisotropy, Clearcoat, Iridescence, Material, Sheen, TexTransform, Texels, Texture,
    TextureRef, Volume, Wrap,
};

impl Loader<'_> {
    /// The materials of the scene: every glTF material a loaded mesh uses, in file order, then
    /// the default material if a mesh has none. Sets `Mesh::material` accordingly.
    pub(crate) fn load_materials(&mut self) -> Result<Vec<Material>, SceneError> {
        let mut used: Vec<usize> = self.mesh_materials.iter().flatten().copied().collect();
        // A variant's materials are loaded whether or not a mesh uses them by default.
        used.extend(self.mesh_variant_materials.iter().flatten().map(|&(_, m)| m));
        used.sort_unstable();
        used.dedup();
        let mut materials = Vec::with_capacity(used.len() + 1);
        for &m in &used {
            materials.push(self.material(m).context(|| format!("material {m}"))?);
        }
        let default_index = materials.len();
        if self.mesh_materials.iter().any(Option::is_none) {
            materials.push(Material::default());
        }
        for (mesh, mappings) in self.meshes.iter_mut().zip(&self.mesh_variant_materials) {
            mesh.variant_materials = mappings
                .iter()
                .map(|&(variant, m)| (variant, used.binary_search(&m).unwrap_or(default_index)))
                .collect();
        }
        for (mesh, gltf_material) in self.meshes.iter_mut().zip(&self.mesh_materials) {
            mesh.material = match gltf_material {
                Some(m) => used.binary_search(m).unwrap_or(default_index),
                None => default_index,
            };
        }
        Ok(materials)
    }

    fn material(&mut self, index: usize) -> Result<Material, SceneError> {
        let root = self.root;
        let m = &root.materials[index];
        let pbr = &m.pbr_metallic_roughness;
        let ext = m.extensions.as_ref();

        let base_color = Vec4::from_array(pbr.base_color_factor.0);
        let metallic = pbr.metallic_factor.0;
        let roughness = pbr.roughness_factor.0;
        let mut emissive = Vec3::from_array(m.emissive_factor.0);
        if let Some(s) = ext.and_then(|e| e.emissive_strength.as_ref()) {
            let strength = s.emissive_strength.0;
            if !(strength >= 0.0 && strength.is_finite()) {
                return fail(format!(
                    "KHR_materials_emissive_strength: invalid emissiveStrength {strength}"
                ));
            }
            emissive *= strength;
        }
        let specular_ext = ext.and_then(|e| e.specular.as_ref());
        let (specular, specular_color) = match specular_ext {
            Some(s) => (s.specular_factor.0, Vec3::from_array(s.specular_color_factor.0)),
            None => (1.0, Vec3::ONE),
        };
        let ior = ext.and_then(|e| e.ior.as_ref()).map_or(1.5, |i| i.ior.0);
        let transmission =
            ext.and_then(|e| e.transmission.as_ref()).map_or(0.0, |t| t.transmission_factor.0);
        let (diffuse_transmission, diffuse_transmission_color, dt_textures) =
            match ext.and_then(|e| e.others.get("KHR_materials_diffuse_transmission")) {
                Some(v) => diffuse_transmission(v)
                    .context(|| "KHR_materials_diffuse_transmission".into())?,
                None => (0.0, Vec3::ONE, (None, None)),
            };
        let diffuse_transmission_texture = match dt_textures.0 {
            Some(info) => self.texture_info(
                Some(&info),
                "KHR_materials_diffuse_transmission.diffuseTransmissionTexture",
            )?,
            None => None,
        };
        let diffuse_transmission_color_texture = match dt_textures.1 {
            Some(info) => self.texture_info(
                Some(&info),
                "KHR_materials_diffuse_transmission.diffuseTransmissionColorTexture",
            )?,
            None => None,
        };
        let mut volume = match ext.and_then(|e| e.others.get("KHR_materials_volume")) {
            Some(v) => volume(v).context(|| "KHR_materials_volume".into())?,
            None => None,
        };
        if let Some(v) = ext.and_then(|e| e.others.get("KHR_materials_volume_scatter")) {
            let (color, anisotropy) =
                volume_scatter(v).context(|| "KHR_materials_volume_scatter".into())?;
            match (&mut volume, volume_distance(ext)) {
                (Some(vol), Some(distance)) => {
                    *vol = vol.with_scattering(color, anisotropy, distance);
                }
                _ => tracing::warn!(
                    "material {index}: KHR_materials_volume_scatter without a volume (KHR_materials_volume with thicknessFactor > 0 and a finite attenuationDistance) scatters nothing"
                ),
            }
        }
        let clearcoat = match ext.and_then(|e| e.others.get("KHR_materials_clearcoat")) {
            Some(v) => self.clearcoat(v).context(|| "KHR_materials_clearcoat".into())?,
            None => None,
        };
        let sheen = match ext.and_then(|e| e.others.get("KHR_materials_sheen")) {
            Some(v) => self.sheen(v).context(|| "KHR_materials_sheen".into())?,
            None => None,
        };
        let anisotropy = match ext.and_then(|e| e.others.get("KHR_materials_anisotropy")) {
            Some(v) => self.anisotropy(v).context(|| "KHR_materials_anisotropy".into())?,
            None => None,
        };
        let dispersion = match ext.and_then(|e| e.others.get("KHR_materials_dispersion")) {
            Some(v) => {
                let d =
                    number(v, "dispersion", 0.0).context(|| "KHR_materials_dispersion".into())?;
                if !(d.is_finite() && d >= 0.0) {
                    return fail(format!(
                        "KHR_materials_dispersion: dispersion {d} must be finite and not negative"
                    ));
                }
                d as f32
            }
            None => 0.0,
        };
        let iridescence = match ext.and_then(|e| e.others.get("KHR_materials_iridescence")) {
            Some(v) => self.iridescence(v).context(|| "KHR_materials_iridescence".into())?,
            None => None,
        };
        let alpha_mode = match m.alpha_mode {
            Checked::Valid(json::material::AlphaMode::Opaque) => AlphaMode::Opaque,
            Checked::Valid(json::material::AlphaMode::Mask) => {
                AlphaMode::Mask { cutoff: m.alpha_cutoff.as_ref().map_or(0.5, |c| c.0) }
            }
            Checked::Valid(json::material::AlphaMode::Blend) => AlphaMode::Blend,
            Checked::Invalid => return fail("invalid alphaMode"),
        };

        let checks: [(&str, &[f32]); 8] = [
            ("baseColorFactor", &base_color.to_array()),
            ("metallicFactor", &[metallic]),
            ("roughnessFactor", &[roughness]),
            ("emissiveFactor", &emissive.to_array()),
            ("specularFactor", &[specular]),
            ("specularColorFactor", &specular_color.to_array()),
            ("transmissionFactor", &[transmission]),
            ("ior", &[ior]),
        ];
        for (name, values) in checks {
            if values.iter().any(|v| !v.is_finite() || *v < 0.0) {
                return fail(format!("{name} {values:?} must be finite and not negative"));
            }
        }
        if ior != 0.0 && ior < 1.0 {
            return fail(format!("KHR_materials_ior: ior {ior} must be 0 or at least 1"));
        }
        if let AlphaMode::Mask { cutoff } = alpha_mode {
            if !cutoff.is_finite() || cutoff < 0.0 {
                return fail(format!("invalid alphaCutoff {cutoff}"));
            }
        }

        let base_color_texture =
            self.texture_info(pbr.base_color_texture.as_ref(), "baseColorTexture")?;
        let metallic_roughness_texture =
            self.texture_info(pbr.metallic_roughness_texture.as_ref(), "metallicRoughnessTexture")?;
        let emissive_texture = self.texture_info(m.emissive_texture.as_ref(), "emissiveTexture")?;
        let transmission_texture = match ext.and_then(|e| e.transmission.as_ref()) {
            Some(t) => self.texture_info(
                t.transmission_texture.as_ref(),
                "KHR_materials_transmission.transmissionTexture",
            )?,
            None => None,
        };
        let (specular_texture, specular_color_texture) = match specular_ext {
            Some(s) => (
                self.texture_info(
                    s.specular_texture.as_ref(),
                    "KHR_materials_specular.specularTexture",
                )?,
                self.texture_info(
                    s.specular_color_texture.as_ref(),
                    "KHR_materials_specular.specularColorTexture",
                )?,
            ),
            None => (None, None),
        };
        let normal_texture = match &m.normal_texture {
            Some(n) => self.normal_texture(n, "normalTexture")?,
            None => None,
        };

        let mut material = Material {
            name: m.name.clone().unwrap_or_else(|| format!("material {index}")),
            base_color: base_color.min(Vec4::ONE),
            base_color_texture,
            metallic: metallic.min(1.0),
            roughness: roughness.min(1.0),
            metallic_roughness_texture,
            normal_texture,
            emissive,
            emissive_texture,
            specular,
            specular_color,
            specular_texture,
            specular_color_texture,
            ior,
            transmission: transmission.min(1.0),
            transmission_texture,
            diffuse_transmission,
            diffuse_transmission_texture,
            diffuse_transmission_color,
            diffuse_transmission_color_texture,
            volume,
            clearcoat,
            sheen,
            anisotropy,
            dispersion,
            iridescence,
            unlit: ext.is_some_and(|e| e.others.contains_key("KHR_materials_unlit")),
            alpha_mode,
            double_sided: m.double_sided,
            glossiness_texture: None,
        };
        if let Some(v) = ext.and_then(|e| e.others.get("KHR_materials_pbrSpecularGlossiness")) {
            self.specular_glossiness(v, &mut material)
                .context(|| "KHR_materials_pbrSpecularGlossiness".into())?;
        }
        if material.dispersion > 0.0 && !material.refracts() {
            tracing::warn!(
                "material {index} ({}): KHR_materials_dispersion bends light by colour only in a refractive volume (KHR_materials_volume with full transmission); ignored",
                material.name
            );
        }
        if material.volume.is_some()
            && (material.transmission > 0.0 || material.diffuse_transmission > 0.0)
            && !material.bounds_medium()
        {
            tracing::warn!(
                "material {index} ({}): KHR_materials_volume with metal, or with partial or textured transmission, is rendered thin-walled for now (a fully transmitting dielectric refracts, and diffuse transmission without specular transmission enters the volume)",
                material.name
            );
        }
        Ok(material)
    }

    /// A `normalTextureInfo` with its `KHR_texture_transform`, and its scale.
    fn normal_texture(
        &mut self,
        n: &json::material::NormalTexture,
        slot: &str,
    ) -> Result<Option<(TextureRef, f32)>, SceneError> {
        let transform = n.extensions.as_ref().and_then(|e| e.others.get("KHR_texture_transform"));
        let transform = transform.map(parse_transform).transpose().context(|| slot.to_string())?;
        let r = self
            .texture_ref(n.index.value(), n.tex_coord, transform)
            .context(|| slot.to_string())?;
        if !n.scale.is_finite() {
            return fail(format!("{slot}: invalid scale {}", n.scale));
        }
        Ok(r.map(|r| (r, n.scale)))
    }

    /// A `KHR_materials_clearcoat` object: `None` when `clearcoatFactor` is 0 (the spec's "the
    /// whole clearcoat layer is disabled").
    fn clearcoat(&mut self, v: &Value) -> Result<Option<Clearcoat>, SceneError> {
        let factor = unit_number(v, "clearcoatFactor", 0.0)?;
        let roughness = unit_number(v, "clearcoatRoughnessFactor", 0.0)?;
        let texture = ext_texture(v, "clearcoatTexture")?;
        let roughness_texture = ext_texture(v, "clearcoatRoughnessTexture")?;
        let normal: Option<json::material::NormalTexture> = match v.get("clearcoatNormalTexture") {
            None => None,
            Some(t) => Some(
                serde_json::from_value(t.clone())
                    .or_else(|e| fail(format!("clearcoatNormalTexture: {e}")))?,
            ),
        };
        if factor == 0.0 {
            return Ok(None);
        }
        let texture = self.texture_info(texture.as_ref(), "clearcoatTexture")?;
        let roughness_texture =
            self.texture_info(roughness_texture.as_ref(), "clearcoatRoughnessTexture")?;
        let normal_texture = match &normal {
            Some(n) => self.normal_texture(n, "clearcoatNormalTexture")?,
            None => None,
        };
        Ok(Some(Clearcoat { factor, texture, roughness, roughness_texture, normal_texture }))
    }

    /// A `KHR_materials_pbrSpecularGlossiness` object (archived; older Sketchfab and Blender
    /// exports) turned into the metallic-roughness model with `KHR_materials_specular`, in
    /// place of the material's metallic-roughness values: the base colour is `diffuseFactor` x
    /// `diffuseTexture`, metallic 0, roughness 1 - `glossinessFactor` x the
    /// `specularGlossinessTexture`'s alpha, and the specular layer's reflectance at normal
    /// incidence is `specularFactor` x that texture's RGB (sRGB) exactly: `ior` 0 makes the
    /// dielectric's F0 ((ior - 1) / (ior + 1))² x specular colour the specular colour itself.
    fn specular_glossiness(&mut self, v: &Value, m: &mut Material) -> Result<(), SceneError> {
        let diffuse = match v.get("diffuseFactor") {
            None => Vec4::ONE,
            Some(Value::Array(c)) if c.len() == 4 => {
                let c: Vec<f64> = c.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect();
                if c.iter().any(|x| !(0.0..=1.0).contains(x)) {
                    return fail(format!("diffuseFactor {c:?} must lie in [0, 1]"));
                }
                Vec4::new(c[0] as f32, c[1] as f32, c[2] as f32, c[3] as f32)
            }
            Some(other) => return fail(format!("diffuseFactor must be 4 numbers, not {other}")),
        };
        let specular = unit_color(v, "specularFactor")?;
        let glossiness = unit_number(v, "glossinessFactor", 1.0)?;
        let diffuse_texture = ext_texture(v, "diffuseTexture")?;
        let sg_texture = ext_texture(v, "specularGlossinessTexture")?;
        m.base_color = diffuse;
        m.base_color_texture = self.texture_info(diffuse_texture.as_ref(), "diffuseTexture")?;
        m.metallic = 0.0;
        m.roughness = 1.0 - glossiness;
        m.metallic_roughness_texture = None;
        m.specular = 1.0;
        m.specular_color = specular;
        m.specular_texture = None;
        let sg_texture = self.texture_info(sg_texture.as_ref(), "specularGlossinessTexture")?;
        m.specular_color_texture = sg_texture;
        m.glossiness_texture = sg_texture;
        m.ior = 0.0;
        Ok(())
    }

    /// A `KHR_materials_sheen` object: `None` when `sheenColorFactor` is black (the spec's "the
    /// whole sheen layer is disabled").
    fn sheen(&mut self, v: &Value) -> Result<Option<Sheen>, SceneError> {
        let color = unit_color_or(v, "sheenColorFactor", [0.0; 3])?;
        let roughness = unit_number(v, "sheenRoughnessFactor", 0.0)?;
        let color_texture = ext_texture(v, "sheenColorTexture")?;
        let roughness_texture = ext_texture(v, "sheenRoughnessTexture")?;
        if color == Vec3::ZERO {
            return Ok(None);
        }
        let color_texture = self.texture_info(color_texture.as_ref(), "sheenColorTexture")?;
        let roughness_texture =
            self.texture_info(roughness_texture.as_ref(), "sheenRoughnessTexture")?;
        Ok(Some(Sheen { color, color_texture, roughness, roughness_texture }))
    }

    /// A `KHR_materials_anisotropy` object: `None` when `anisotropyStrength` is 0.
    fn anisotropy(&mut self, v: &Value) -> Result<Option<Anisotropy>, SceneError> {
        let strength = unit_number(v, "anisotropyStrength", 0.0)?;
        let rotation = number(v, "anisotropyRotation", 0.0)?;
        if !rotation.is_finite() {
            return fail(format!("anisotropyRotation {rotation} must be finite"));
        }
        let texture = ext_texture(v, "anisotropyTexture")?;
        if strength == 0.0 {
            return Ok(None);
        }
        let texture = self.texture_info(texture.as_ref(), "anisotropyTexture")?;
        Ok(Some(Anisotropy { strength, rotation: rotation as f32, texture }))
    }

    /// A `KHR_materials_iridescence` object: `None` when `iridescenceFactor` is 0 (the spec's
    /// "the iridescence extension has no effect on the material").
    fn iridescence(&mut self, v: &Value) -> Result<Option<Iridescence>, SceneError> {
        let factor = unit_number(v, "iridescenceFactor", 0.0)?;
        let ior = number(v, "iridescenceIor", 1.3)?;
        if !(ior.is_finite() && ior >= 1.0) {
            return fail(format!("iridescenceIor {ior} must be finite and at least 1"));
        }
        let thickness_min = thickness(v, "iridescenceThicknessMinimum", 100.0)?;
        let thickness_max = thickness(v, "iridescenceThicknessMaximum", 400.0)?;
        let texture = ext_texture(v, "iridescenceTexture")?;
        let thickness_texture = ext_texture(v, "iridescenceThicknessTexture")?;
        if factor == 0.0 {
            return Ok(None);
        }
        let texture = self.texture_info(texture.as_ref(), "iridescenceTexture")?;
        let thickness_texture =
            self.texture_info(thickness_texture.as_ref(), "iridescenceThicknessTexture")?;
        Ok(Some(Iridescence {
            factor,
            texture,
            ior: ior as f32,
            thickness_min,
            thickness_max,
            thickness_texture,
        }))
    }

    /// A `textureInfo` with its `KHR_texture_transform`.
    fn texture_info(
        &mut self,
        info: Option<&json::texture::Info>,
        slot: &str,
    ) -> Result<Option<TextureRef>, SceneError> {
        let Some(info) = info else { return Ok(None) };
        let ext = info.extensions.as_ref();
        let transform = ext.and_then(|e| e.texture_transform.as_ref()).map(|t| {
            (
                TexTransform {
                    offset: Vec2::from_array(t.offset.0),
                    rotation: t.rotation.0,
                    scale: Vec2::from_array(t.scale.0),
                },
                t.tex_coord,
            )
        });
        if let Some((t, _)) = &transform {
            check_transform(t).context(|| slot.to_string())?;
        }
        self.texture_ref(info.index.value(), info.tex_coord, transform).context(|| slot.to_string())
    }

    fn texture_ref(
        &mut self,
        texture: usize,
        tex_coord: u32,
        transform: Option<(TexTransform, Option<u32>)>,
    ) -> Result<Option<TextureRef>, SceneError> {
        let tex_coord = transform.and_then(|(_, t)| t).unwrap_or(tex_coord);
        let Some(scene_texture) = self.texture(texture)? else {
            return Ok(None);
        };
        if tex_coord > 1 {
            tracing::warn!("texture {texture} uses TEXCOORD_{tex_coord}; only sets 0 and 1 are supported, texture ignored");
            return Ok(None);
        }
        Ok(Some(TextureRef {
            texture: scene_texture,
            tex_coord,
            transform: transform.map(|(t, _)| t),
        }))
    }

    /// The scene texture for glTF texture `index`, decoded on first use.
    fn texture(&mut self, index: usize) -> Result<Option<usize>, SceneError> {
        if let Some(&known) = self.texture_map.get(&index) {
            return Ok(known);
        }
        let root = self.root;
        let Some(tex) = root.textures.get(index) else {
            return fail(format!(
                "texture {index}: does not exist (the file has {} textures)",
                root.textures.len()
            ));
        };
        let source = match (
            ext_source(self.raw, index, basisu::EXTENSION)?,
            ext_source(self.raw, index, "EXT_texture_webp")?,
        ) {
            (Some(ktx2), _) => ktx2,
            (None, Some(webp)) => webp,
            (None, None) => tex.source.value(),
        };
        let result = if source == u32::MAX as usize {
            tracing::warn!(
                "texture {index}: has no source image (only an unsupported extension's); ignored"
            );
            None
        } else {
            let (wrap_s, wrap_t, nearest, mipmaps) = match tex.sampler {
                Some(s) => sampler(root, s.value()).context(|| format!("texture {index}"))?,
                None => (Wrap::Repeat, Wrap::Repeat, false, true),
            };
            self.decode_image(source).context(|| format!("texture {index}"))?;
            let image = &self.images[&source];
            // The texels come when the images are decoded, all at once (`decode_images`).
            self.textures.push(Texture {
                width: image.width,
                height: image.height,
                texels: Vec::new().into(),
                wrap_s,
                wrap_t,
                nearest,
                mipmaps,
                levels: Vec::new(),
            });
            self.texture_images.push((self.textures.len() - 1, source));
            Some(self.textures.len() - 1)
        };
        self.texture_map.insert(index, result);
        Ok(result)
    }

    /// Reads image `index` and checks its header into `self.images` unless it is there already,
    /// charging its texels to the budget, and queues it for `decode_images`.
    fn decode_image(&mut self, index: usize) -> Result<(), SceneError> {
        if self.images.contains_key(&index) {
            return Ok(());
        }
        let Some(image) = self.root.images.get(index) else {
            return fail(format!(
                "image {index}: does not exist (the file has {} images)",
                self.root.images.len()
            ));
        };
        let bytes: Vec<u8> = match (&image.uri, image.buffer_view) {
            (Some(uri), _) => self.fetch(uri).context(|| format!("image {index}"))?,
            (None, Some(view)) => {
                self.view(view.value()).context(|| format!("image {index}"))?.0.to_vec()
            }
            (None, None) => return fail(format!("image {index}: has neither uri nor bufferView")),
        };
        // The texels are charged from the header, before anything is decoded: an image too
        // large for the budget costs its header's bytes, not its decoded size.
        let (format, (width, height)) = if basisu::is_ktx2(&bytes) {
            let size = basisu::dimensions(&bytes)
                .map_err(|e| SceneError(format!("image {index}: {}: {e}", basisu::EXTENSION)))?;
            (ImageFormat::Ktx2, size)
        } else {
            let format = format_of(&bytes).context(|| format!("image {index}"))?;
            let size = image::ImageReader::with_format(Cursor::new(&bytes), format)
                .into_dimensions()
                .map_err(|e| {
                    SceneError(format!("image {index}: cannot decode the {format:?} header: {e}"))
                })?;
            (ImageFormat::Image(format), size)
        };
        if width == 0 || height == 0 {
            return fail(format!("image {index}: has no texels"));
        }
        self.charge_scene(budget::Line::Texels, width as u64 * height as u64, || {
            format!("image {index}, {width}x{height}")
        })?;
        self.images.insert(index, Image { width, height });
        self.pending_images.push(PendingImage { index, bytes, format, width, height });
        Ok(())
    }

    /// Decodes the queued images, on the threads the caller lent (`self.spread`), and gives
    /// each texture its texels. A failure names the image (the lowest-numbered one that fails,
    /// whatever the threads).
    pub(super) fn decode_images(&mut self) -> Result<(), SceneError> {
        let mut pending = std::mem::take(&mut self.pending_images);
        // Largest first, so that the threads finish together.
        pending.sort_by_key(|p| std::cmp::Reverse(p.width as u64 * p.height as u64));
        let mut decoded: Vec<Option<Result<Texels, SceneError>>> =
            pending.iter().map(|_| None).collect();
        let jobs = pending
            .iter()
            .zip(&mut decoded)
            .map(|(p, out)| {
                Box::new(move || *out = Some(decode(&p.bytes, p.format, (p.width, p.height))))
                    as crate::spread::Job<'_>
            })
            .collect();
        self.spread.run(jobs);
        let mut by_image: Vec<(usize, Result<Texels, SceneError>)> = pending
            .iter()
            .zip(decoded)
            .map(|(p, d)| (p.index, d.unwrap_or_else(|| fail("was not decoded"))))
            .collect();
        by_image.sort_by_key(|(index, _)| *index);
        let mut texels = HashMap::with_capacity(by_image.len());
        for (index, d) in by_image {
            texels.insert(index, d.context(|| format!("image {index}"))?);
        }
        for &(texture, image) in &self.texture_images {
            self.textures[texture].texels = texels[&image].clone();
        }
        Ok(())
    }
}

/// The image texture `index` reads by extension `name` (`KHR_texture_basisu` or
/// `EXT_texture_webp`: its `source`), which takes the place of the texture's own PNG or JPEG
/// fallback; `None` when the texture has no such extension.
fn ext_source(raw: &Value, index: usize, name: &str) -> Result<Option<usize>, SceneError> {
    let Some(ext) = raw["textures"][index].get("extensions").and_then(|e| e.get(name)) else {
        return Ok(None);
    };
    match ext.get("source").and_then(Value::as_u64).and_then(|s| usize::try_from(s).ok()) {
        Some(source) if source < u32::MAX as usize => Ok(Some(source)),
        _ => fail(format!("texture {index}: {name} has no valid source image")),
    }
}

/// The format of image bytes: PNG, JPEG, or WebP (`EXT_texture_webp`).
fn format_of(bytes: &[u8]) -> Result<image::ImageFormat, SceneError> {
    let format = image::guess_format(bytes).map_err(|_| {
        SceneError("unrecognised image format (only PNG, JPEG, WebP and KTX2 are supported)".into())
    })?;
    if !matches!(
        format,
        image::ImageFormat::Png | image::ImageFormat::Jpeg | image::ImageFormat::WebP
    ) {
        return fail(format!("{format:?} images are not supported (only PNG, JPEG and WebP)"));
    }
    Ok(format)
}

/// Decodes PNG, JPEG, WebP or KTX2 bytes of the size their header gave into RGBA8 (RGBA16 for
/// a 16-bit PNG), allocating no more than that size needs.
fn decode(
    bytes: &[u8],
    format: ImageFormat,
    (width, height): (u32, u32),
) -> Result<Texels, SceneError> {
    let format = match format {
        ImageFormat::Image(format) => format,
        ImageFormat::Ktx2 => {
            let texels = basisu::decode(bytes)
                .map_err(|e| SceneError(format!("{}: {e}", basisu::EXTENSION)))?;
            return Ok(Texels::Rgba8(texels.into()));
        }
    };
    use image::{
        ColorType::{La16, La8, Rgb16, Rgb8, Rgba16, Rgba8, L16, L8},
        ImageDecoder,
    };
    let cannot = |e: image::ImageError| SceneError(format!("cannot decode {format:?}: {e}"));
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format);
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(width);
    limits.max_image_height = Some(height);
    // What a decoder allocates of its own (rows, tables; a whole image for some formats).
    limits.max_alloc = Some(width as u64 * height as u64 * 20 + (1 << 20));
    reader.limits(limits);
    let decoder = reader.into_decoder().map_err(cannot)?;
    if decoder.dimensions() != (width, height) {
        let (w, h) = decoder.dimensions();
        return fail(format!("decoded to {w}x{h}, not the {width}x{height} of its header"));
    }
    // Decoded into the texels' own buffer (RGBA, 8 or 16 bits a channel, as the image has), then
    // spread in place where the image has fewer channels (grey, grey and alpha, RGB): one
    // buffer of the decoded size, where decoding, converting and sharing took three.
    let n = width as usize * height as usize;
    let channels = decoder.color_type().channel_count() as usize;
    match decoder.color_type() {
        L8 | La8 | Rgb8 | Rgba8 => {
            // Allocated once, in place (an exact-length iterator collects straight into an
            // `Arc<[_]>`), and written through the one reference there is.
            let mut texels: Arc<[[u8; 4]]> = std::iter::repeat_n([0u8; 4], n).collect();
            let only = Arc::get_mut(&mut texels).expect("a new Arc has one owner");
            let bytes = bytemuck::cast_slice_mut::<[u8; 4], u8>(only);
            decoder.read_image(&mut bytes[..n * channels]).map_err(cannot)?;
            spread_to_rgba(bytes, channels, u8::MAX);
            Ok(Texels::Rgba8(texels))
        }
        L16 | La16 | Rgb16 | Rgba16 => {
            // 16 bits a channel kept (a 16-bit PNG): native-endian u16s.
            let mut texels: Arc<[[u16; 4]]> = std::iter::repeat_n([0u16; 4], n).collect();
            let only = Arc::get_mut(&mut texels).expect("a new Arc has one owner");
            let bytes = bytemuck::cast_slice_mut::<[u16; 4], u8>(only);
            decoder.read_image(&mut bytes[..n * channels * 2]).map_err(cannot)?;
            spread_to_rgba(bytemuck::cast_slice_mut(only), channels, u16::MAX);
            Ok(Texels::Rgba16(texels))
        }
        // Anything else (floating point: no glTF image format gives it) through `image`'s
        // conversion.
        _ => {
            let rgba = image::DynamicImage::from_decoder(decoder).map_err(cannot)?.into_rgba8();
            Ok(Texels::Rgba8(bytemuck::cast_slice::<u8, [u8; 4]>(rgba.as_raw()).into()))
        }
    }
}

/// Spreads the first `channels` (1: grey, 2: grey and alpha, 3: RGB, 4: RGBA) values of each
/// texel, packed at the start of `data`, to four a texel over the whole of it, in place: grey
/// to its three colours, an absent alpha to `opaque` (as `image`'s conversions to RGBA do).
/// From the last texel down, so that no texel is written over before it is read.
fn spread_to_rgba<T: Copy>(data: &mut [T], channels: usize, opaque: T) {
    if channels == 4 {
        return;
    }
    for i in (0..data.len() / 4).rev() {
        let s = &data[i * channels..i * channels + channels];
        let rgba = match channels {
            1 => [s[0], s[0], s[0], opaque],
            2 => [s[0], s[0], s[0], s[1]],
            _ => [s[0], s[1], s[2], opaque],
        };
        data[i * 4..i * 4 + 4].copy_from_slice(&rgba);
    }
}

/// Wrap modes, nearest magnification and mipmapped minification of sampler `index`.
fn sampler(root: &json::Root, index: usize) -> Result<(Wrap, Wrap, bool, bool), SceneError> {
    let Some(s) = root.samplers.get(index) else {
        return fail(format!(
            "sampler {index}: does not exist (the file has {} samplers)",
            root.samplers.len()
        ));
    };
    let wrap = |w: Checked<WrappingMode>, name: &str| match w {
        Checked::Valid(WrappingMode::Repeat) => Ok(Wrap::Repeat),
        Checked::Valid(WrappingMode::ClampToEdge) => Ok(Wrap::ClampToEdge),
        Checked::Valid(WrappingMode::MirroredRepeat) => Ok(Wrap::MirroredRepeat),
        Checked::Invalid => fail(format!("sampler {index}: invalid {name}")),
    };
    let nearest = match s.mag_filter {
        Some(Checked::Valid(MagFilter::Nearest)) => true,
        Some(Checked::Invalid) => return fail(format!("sampler {index}: invalid magFilter")),
        _ => false,
    };
    let mipmaps = match s.min_filter {
        Some(Checked::Valid(MinFilter::Nearest | MinFilter::Linear)) => false,
        Some(Checked::Invalid) => return fail(format!("sampler {index}: invalid minFilter")),
        _ => true,
    };
    Ok((wrap(s.wrap_s, "wrapS")?, wrap(s.wrap_t, "wrapT")?, nearest, mipmaps))
}

/// A `KHR_texture_transform` from raw JSON (texture infos the typed layer does not cover).
fn parse_transform(v: &Value) -> Result<(TexTransform, Option<u32>), SceneError> {
    let pair = |key: &str, default: [f32; 2]| -> Result<Vec2, SceneError> {
        match v.get(key) {
            None => Ok(Vec2::from_array(default)),
            Some(Value::Array(a)) if a.len() == 2 => match (a[0].as_f64(), a[1].as_f64()) {
                (Some(x), Some(y)) => Ok(Vec2::new(x as f32, y as f32)),
                _ => fail(format!("KHR_texture_transform: invalid {key}")),
            },
            Some(_) => fail(format!("KHR_texture_transform: invalid {key}")),
        }
    };
    let rotation = match v.get("rotation") {
        None => 0.0,
        Some(r) => r
            .as_f64()
            .ok_or_else(|| SceneError("KHR_texture_transform: invalid rotation".into()))?
            as f32,
    };
    let tex_coord = match v.get("texCoord") {
        None => None,
        Some(t) => Some(
            t.as_u64()
                .and_then(|t| u32::try_from(t).ok())
                .ok_or_else(|| SceneError("KHR_texture_transform: invalid texCoord".into()))?,
        ),
    };
    let t = TexTransform {
        offset: pair("offset", [0.0, 0.0])?,
        rotation,
        scale: pair("scale", [1.0, 1.0])?,
    };
    check_transform(&t)?;
    Ok((t, tex_coord))
}

fn check_transform(t: &TexTransform) -> Result<(), SceneError> {
    if !(t.offset.is_finite() && t.scale.is_finite() && t.rotation.is_finite()) {
        return fail("KHR_texture_transform: non-finite offset, rotation or scale");
    }
    Ok(())
}

/// `KHR_materials_volume`: a volume when `thicknessFactor > 0`, thin-walled (`None`) at 0.
/// `thicknessTexture` only approximates a volume for rasterizers: a path tracer follows the
/// light through the mesh itself, so it is not read.
fn volume(v: &Value) -> Result<Option<Volume>, SceneError> {
    let number = |key: &str, default: f64| -> Result<f64, SceneError> {
        match v.get(key) {
            None => Ok(default),
            Some(Value::Number(n)) => Ok(n.as_f64().unwrap_or(f64::NAN)),
            Some(other) => fail(format!("{key} must be a number, not {other}")),
        }
    };
    let thickness = number("thicknessFactor", 0.0)?;
    if !(thickness.is_finite() && thickness >= 0.0) {
        return fail(format!("thicknessFactor {thickness} must be finite and not negative"));
    }
    let distance = number("attenuationDistance", f64::INFINITY)?;
    if distance.is_nan() || distance <= 0.0 {
        return fail(format!("attenuationDistance {distance} must be greater than 0"));
    }
    let color = unit_color(v, "attenuationColor")?;
    if thickness == 0.0 {
        return Ok(None);
    }
    Ok(Some(Volume::new(color, distance as f32)))
}

/// `KHR_materials_volume_scatter`: `multiscatterColor` (in [0, 1], black when absent) and
/// `scatterAnisotropy` (in [-1, 1], 0 when absent; ±1, a delta, is taken as ±0.999).
fn volume_scatter(v: &Value) -> Result<(Vec3, f32), SceneError> {
    let color = match v.get("multiscatterColor") {
        None => Vec3::ZERO,
        Some(_) => unit_color(v, "multiscatterColor")?,
    };
    let g = number(v, "scatterAnisotropy", 0.0)?;
    if !(-1.0..=1.0).contains(&g) {
        return fail(format!("scatterAnisotropy {g} must lie in [-1, 1]"));
    }
    Ok((color, (g as f32).clamp(-0.999, 0.999)))
}

/// The finite `attenuationDistance` of a material's `KHR_materials_volume`, if it has one.
fn volume_distance(ext: Option<&json::extensions::material::Material>) -> Option<f32> {
    let d = ext?.others.get("KHR_materials_volume")?.get("attenuationDistance")?.as_f64()?;
    (d.is_finite() && d > 0.0).then_some(d as f32)
}

/// The number under `key` of an extension object (`default` when absent).
fn number(v: &Value, key: &str, default: f64) -> Result<f64, SceneError> {
    match v.get(key) {
        None => Ok(default),
        Some(Value::Number(n)) => Ok(n.as_f64().unwrap_or(f64::NAN)),
        Some(other) => fail(format!("{key} must be a number, not {other}")),
    }
}

/// A thin film's thickness in nanometres under `key` of an extension object: finite and not
/// negative (`default` when absent).
fn thickness(v: &Value, key: &str, default: f64) -> Result<f32, SceneError> {
    let x = number(v, key, default)?;
    if !(x.is_finite() && x >= 0.0 && x as f32 <= f32::MAX) {
        return fail(format!("{key} {x} must be a finite thickness in nanometres, at least 0"));
    }
    Ok(x as f32)
}

/// The number under `key` of an extension object, in [0, 1] (`default` when absent).
fn unit_number(v: &Value, key: &str, default: f64) -> Result<f32, SceneError> {
    let x = number(v, key, default)?;
    if !(0.0..=1.0).contains(&x) {
        return fail(format!("{key} {x} must lie in [0, 1]"));
    }
    Ok(x as f32)
}

/// The `textureInfo` under `key` of an extension object, if present.
fn ext_texture(v: &Value, key: &str) -> Result<Option<json::texture::Info>, SceneError> {
    match v.get(key) {
        None => Ok(None),
        Some(t) => {
            serde_json::from_value(t.clone()).map(Some).or_else(|e| fail(format!("{key}: {e}")))
        }
    }
}

/// The RGB colour under `key` of an extension object, each component in [0, 1] (white when
/// absent).
fn unit_color(v: &Value, key: &str) -> Result<Vec3, SceneError> {
    unit_color_or(v, key, [1.0; 3])
}

/// The RGB colour under `key` of an extension object, each component in [0, 1] (`default` when
/// absent).
fn unit_color_or(v: &Value, key: &str, default: [f64; 3]) -> Result<Vec3, SceneError> {
    let color = match v.get(key) {
        None => default,
        Some(Value::Array(c)) if c.len() == 3 => {
            let c: Vec<f64> = c.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect();
            [c[0], c[1], c[2]]
        }
        Some(other) => return fail(format!("{key} must be 3 numbers, not {other}")),
    };
    if color.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return fail(format!("{key} {color:?} must lie in [0, 1]"));
    }
    Ok(Vec3::new(color[0] as f32, color[1] as f32, color[2] as f32))
}

/// A `KHR_materials_diffuse_transmission` object: the factor (in [0, 1]), the colour factor (in
/// [0, 1]) and the two texture infos.
#[allow(clippy::type_complexity)]
fn diffuse_transmission(
    v: &Value,
) -> Result<(f32, Vec3, (Option<json::texture::Info>, Option<json::texture::Info>)), SceneError> {
    let factor = match v.get("diffuseTransmissionFactor") {
        None => 0.0,
        Some(x) => x.as_f64().unwrap_or(f64::NAN),
    };
    if !(0.0..=1.0).contains(&factor) {
        return fail(format!("diffuseTransmissionFactor {factor} must lie in [0, 1]"));
    }
    let color = unit_color(v, "diffuseTransmissionColorFactor")?;
    let textures = (
        ext_texture(v, "diffuseTransmissionTexture")?,
        ext_texture(v, "diffuseTransmissionColorTexture")?,
    );
    Ok((factor as f32, color, textures))
}

#[cfg(test)]
mod decode_tests {
    use image::{ColorType, ExtendedColorType, ImageEncoder};

    use super::*;

    /// What `image`'s own conversion gives (the decoder's image, then to RGBA 8 or 16 bits):
    /// the reference for decoding into one buffer.
    fn by_conversion(bytes: &[u8], format: image::ImageFormat) -> Texels {
        let decoded = image::load_from_memory_with_format(bytes, format).unwrap();
        if matches!(
            decoded.color(),
            ColorType::L16 | ColorType::La16 | ColorType::Rgb16 | ColorType::Rgba16
        ) {
            let rgba = decoded.into_rgba16();
            return Texels::Rgba16(bytemuck::cast_slice::<u16, [u16; 4]>(rgba.as_raw()).into());
        }
        let rgba = decoded.into_rgba8();
        bytemuck::cast_slice::<u8, [u8; 4]>(rgba.as_raw()).to_vec().into()
    }

    /// Decoding straight into the texels' buffer and spreading grey, grey and alpha, and RGB to
    /// RGBA in place gives exactly `image`'s conversion, for every channel layout and depth a
    /// PNG has, for JPEG (colour and grey) and for lossless WebP (colour and alpha), on images
    /// of odd sizes.
    #[test]
    fn one_buffer_decodes_to_the_texels_of_the_conversion() {
        let (w, h) = (37u32, 23u32);
        let value = |i: usize, k: usize| ((i * 131 + k * 71 + (i / 7) * 17) % 256) as u8;
        let mut cases: Vec<(String, Vec<u8>, image::ImageFormat)> = Vec::new();
        for (color, channels, wide) in [
            (ExtendedColorType::L8, 1, false),
            (ExtendedColorType::La8, 2, false),
            (ExtendedColorType::Rgb8, 3, false),
            (ExtendedColorType::Rgba8, 4, false),
            (ExtendedColorType::L16, 1, true),
            (ExtendedColorType::La16, 2, true),
            (ExtendedColorType::Rgb16, 3, true),
            (ExtendedColorType::Rgba16, 4, true),
        ] {
            let n = (w * h) as usize * channels;
            let raw: Vec<u8> = if wide {
                let words: Vec<u16> =
                    (0..n).map(|i| value(i, 1) as u16 * 257 + (i % 3) as u16).collect();
                // `write_image` takes 16-bit samples in native byte order.
                bytemuck::cast_slice(&words).to_vec()
            } else {
                (0..n).map(|i| value(i, 0)).collect()
            };
            let mut png = Vec::new();
            image::codecs::png::PngEncoder::new(&mut png).write_image(&raw, w, h, color).unwrap();
            cases.push((format!("PNG {color:?}"), png, image::ImageFormat::Png));
            if !wide && channels != 2 && channels != 4 {
                let mut jpeg = Vec::new();
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
                    .write_image(&raw, w, h, color)
                    .unwrap();
                cases.push((format!("JPEG {color:?}"), jpeg, image::ImageFormat::Jpeg));
            }
            if !wide && channels >= 3 {
                let mut webp = Vec::new();
                image::codecs::webp::WebPEncoder::new_lossless(&mut webp)
                    .write_image(&raw, w, h, color)
                    .unwrap();
                cases.push((format!("WebP {color:?}"), webp, image::ImageFormat::WebP));
            }
        }
        assert_eq!(cases.len(), 8 + 2 + 2);
        for (what, bytes, format) in &cases {
            let ours = decode(bytes, ImageFormat::Image(*format), (w, h)).unwrap();
            let theirs = by_conversion(bytes, *format);
            assert_eq!(ours.len(), (w * h) as usize, "{what}");
            match (&ours, &theirs) {
                (Texels::Rgba8(a), Texels::Rgba8(b)) => assert_eq!(a, b, "{what}"),
                (Texels::Rgba16(a), Texels::Rgba16(b)) => assert_eq!(a, b, "{what}"),
                _ => panic!("{what}: different depths"),
            }
        }
        // A header that lies about the size is refused.
        let (_, png, _) = &cases[0];
        let e = decode(png, ImageFormat::Image(image::ImageFormat::Png), (w + 1, h)).unwrap_err();
        assert!(e.0.contains("not the 38x23 of its header"), "{}", e.0);
    }
}
