//! The JSON layer: parses the glTF JSON with the `gltf` crate's types (tolerating integers
//! written as floats), names the object at fault when a field is missing or mistyped, and
//! checks the asset version and `extensionsRequired` before anything else is read.

use ::gltf::json;
use serde_json::Value;

use super::SceneError;

/// Extensions this loader honours; any other extension in `extensionsRequired` is an error.
pub(crate) const SUPPORTED_EXTENSIONS: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_anisotropy",
    "KHR_materials_clearcoat",
    "KHR_materials_diffuse_transmission",
    "KHR_materials_dispersion",
    "KHR_materials_emissive_strength",
    "KHR_materials_specular",
    // Archived; converted to the metallic-roughness model with `KHR_materials_specular`.
    "KHR_materials_pbrSpecularGlossiness",
    "KHR_materials_ior",
    "KHR_materials_iridescence",
    "KHR_materials_sheen",
    "KHR_materials_transmission",
    "KHR_materials_unlit",
    "KHR_materials_variants",
    "KHR_materials_volume",
    "KHR_materials_volume_scatter",
    "KHR_texture_transform",
    // A texture's WebP image in place of its PNG or JPEG fallback.
    "EXT_texture_webp",
    // Only widens the component types accessors may use; the accessor reader takes them all.
    "KHR_mesh_quantization",
    // Instances of a node's mesh from per-instance TRS accessors.
    "EXT_mesh_gpu_instancing",
    // Buffer views decoded from meshoptimizer-compressed bytes; fallback buffers may lack a uri.
    "EXT_meshopt_compression",
    // A texture's KTX2 image (Basis Universal ETC1S or UASTC) in place of its PNG or JPEG
    // fallback, transcoded to RGBA8.
    "KHR_texture_basisu",
    // Primitives decoded from Draco streams.
    "KHR_draco_mesh_compression",
];

/// A parsed glTF document: typed JSON plus the raw tree (node transforms are read from it in
/// f64, the typed layer rounds them to f32).
pub(crate) struct Document {
    pub(crate) root: json::Root,
    pub(crate) raw: Value,
    /// The `animations` array as written (the typed layer may need it removed).
    pub(crate) animations: Option<Value>,
}

/// Parses and checks the JSON of a glTF asset.
pub(crate) fn parse(bytes: &[u8]) -> Result<Document, SceneError> {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let mut raw: Value =
        serde_json::from_slice(bytes).map_err(|e| SceneError(format!("JSON: {e}")))?;
    if !raw.is_object() {
        return Err(SceneError("JSON: the top level is not an object".into()));
    }
    let animations = raw.get("animations").cloned();
    let root = match json::deserialize::from_slice::<json::Root>(bytes) {
        Ok(root) => root,
        Err(_) => {
            // The typed layer is stricter than the spec in a few places; smooth them over and
            // try again (only when needed: it costs a second pass over the JSON).
            patch_for_typed_layer(&mut raw);
            let text = serde_json::to_vec(&raw).map_err(|e| SceneError(format!("JSON: {e}")))?;
            json::deserialize::from_slice::<json::Root>(&text).map_err(|e| locate_error(&raw, e))?
        }
    };
    check_asset(&root)?;
    check_required_extensions(&root)?;
    let ignored = ignored_extensions(&root);
    if !ignored.is_empty() {
        tracing::warn!(
            "extensionsUsed: the renderer ignores {} (what the file gives without them is rendered)",
            ignored.join(", ")
        );
    }
    Ok(Document { root, raw, animations })
}

/// The extensions the file says it uses that this loader does not honour, each named once,
/// with a word on what is rendered instead where one is known.
pub(crate) fn ignored_extensions(root: &json::Root) -> Vec<String> {
    let mut ignored: Vec<String> = Vec::new();
    let mut seen: Vec<&str> = Vec::new();
    for ext in &root.extensions_used {
        if SUPPORTED_EXTENSIONS.contains(&ext.as_str()) || seen.contains(&ext.as_str()) {
            continue;
        }
        seen.push(ext);
        ignored.push(match ext.as_str() {
            "EXT_texture_avif" => {
                format!("{ext} (the PNG or JPEG fallback image is read where there is one)")
            }
            _ => ext.clone(),
        });
    }
    ignored
}

/// Makes valid glTF that the `gltf` crate's types refuse acceptable to them:
/// - integers written as floats (`"count": 3.0`), which the spec's JSON schema accepts;
/// - a scene without `nodes` (optional in the spec, required by the typed layer);
/// - animations, whose channel targets may legitimately lack `node` (`KHR_animation_pointer`):
///   the loader reads them from the JSON as written.
fn patch_for_typed_layer(raw: &mut Value) {
    integralize(raw);
    if let Some(obj) = raw.as_object_mut() {
        obj.remove("animations");
        if let Some(Value::Array(scenes)) = obj.get_mut("scenes") {
            for scene in scenes.iter_mut().filter_map(Value::as_object_mut) {
                scene.entry("nodes").or_insert_with(|| Value::Array(Vec::new()));
            }
        }
    }
}

/// Rewrites every float with an integral value (and no sign trouble) as an integer.
fn integralize(v: &mut Value) {
    match v {
        Value::Number(n) if !n.is_i64() && !n.is_u64() => {
            if let Some(f) = n.as_f64() {
                if f.fract() == 0.0 && f.abs() < 9.0e15 && !(f == 0.0 && f.is_sign_negative()) {
                    *v = if f >= 0.0 { Value::from(f as u64) } else { Value::from(f as i64) };
                }
            }
        }
        Value::Array(a) => a.iter_mut().for_each(integralize),
        Value::Object(o) => o.values_mut().for_each(integralize),
        _ => {}
    }
}

/// Finds which top-level object fails to deserialize, to name it in the message.
fn locate_error(raw: &Value, whole: json::Error) -> SceneError {
    fn try_each<T: serde::de::DeserializeOwned>(
        raw: &Value,
        key: &str,
        label: &str,
    ) -> Option<SceneError> {
        let items = raw.get(key)?;
        let Some(items) = items.as_array() else {
            return Some(SceneError(format!("{key}: expected an array")));
        };
        items.iter().enumerate().find_map(|(i, item)| {
            let text = item.to_string();
            json::deserialize::from_str::<T>(&text)
                .err()
                .map(|e| SceneError(format!("{label} {i}: {e}")))
        })
    }
    if let Some(asset) = raw.get("asset") {
        if let Err(e) = json::deserialize::from_str::<json::Asset>(&asset.to_string()) {
            return SceneError(format!("asset: {e}"));
        }
    } else {
        return SceneError(
            "asset: missing (every glTF file needs \"asset\": {\"version\": \"2.0\"})".into(),
        );
    }
    try_each::<json::Accessor>(raw, "accessors", "accessor")
        .or_else(|| try_each::<json::buffer::View>(raw, "bufferViews", "buffer view"))
        .or_else(|| try_each::<json::Buffer>(raw, "buffers", "buffer"))
        .or_else(|| try_each::<json::Mesh>(raw, "meshes", "mesh"))
        .or_else(|| try_each::<json::Node>(raw, "nodes", "node"))
        .or_else(|| try_each::<json::Scene>(raw, "scenes", "scene"))
        .or_else(|| try_each::<json::Material>(raw, "materials", "material"))
        .or_else(|| try_each::<json::Texture>(raw, "textures", "texture"))
        .or_else(|| try_each::<json::Image>(raw, "images", "image"))
        .or_else(|| try_each::<json::texture::Sampler>(raw, "samplers", "sampler"))
        .or_else(|| try_each::<json::Camera>(raw, "cameras", "camera"))
        .or_else(|| try_each::<json::Skin>(raw, "skins", "skin"))
        .or_else(|| {
            let lights = raw.get("extensions")?.get("KHR_lights_punctual")?;
            try_each::<json::extensions::scene::khr_lights_punctual::Light>(
                lights, "lights", "light",
            )
        })
        .unwrap_or_else(|| SceneError(format!("JSON: {whole}")))
}

fn check_asset(root: &json::Root) -> Result<(), SceneError> {
    fn major_minor(v: &str) -> Option<(u32, u32)> {
        let (a, b) = v.split_once('.')?;
        Some((a.parse().ok()?, b.parse().ok()?))
    }
    let version = &root.asset.version;
    match major_minor(version) {
        Some((2, _)) => {}
        _ => {
            return Err(SceneError(format!(
                "asset: glTF version \"{version}\" is not supported (only 2.x)"
            )))
        }
    }
    if let Some(min) = &root.asset.min_version {
        match major_minor(min) {
            Some((2, 0)) => {}
            _ => {
                return Err(SceneError(format!(
                    "asset: minVersion \"{min}\" is newer than the supported 2.0"
                )))
            }
        }
    }
    Ok(())
}

fn check_required_extensions(root: &json::Root) -> Result<(), SceneError> {
    for ext in &root.extensions_required {
        if !SUPPORTED_EXTENSIONS.contains(&ext.as_str()) {
            return Err(SceneError(format!(
                "extensionsRequired: extension {ext} is not supported (supported: {})",
                SUPPORTED_EXTENSIONS.join(", ")
            )));
        }
    }
    Ok(())
}

/// Reads `N` numbers at `raw[key][index][field]` in f64, if present and well formed.
pub(crate) fn raw_numbers<const N: usize>(
    raw: &Value,
    key: &str,
    index: usize,
    field: &str,
) -> Option<[f64; N]> {
    let arr = raw.get(key)?.get(index)?.get(field)?.as_array()?;
    if arr.len() != N {
        return None;
    }
    let mut out = [0.0; N];
    for (o, v) in out.iter_mut().zip(arr) {
        *o = v.as_f64()?;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers_written_as_floats_parse() {
        let doc = parse(br#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":4.0}],"scene":0e0,"scenes":[{"nodes":[]}]}"#)
            .expect("parses");
        assert_eq!(doc.root.buffers[0].byte_length.0, 4);
    }

    #[test]
    fn errors_name_the_object() {
        let e = parse(br#"{"asset":{"version":"2.0"},"accessors":[{"componentType":5126,"count":1,"type":"VEC3"},{"count":1,"type":"VEC3"}]}"#)
            .err().expect("missing componentType");
        assert!(e.0.starts_with("accessor 1: "), "{e}");
        let e = parse(br#"{"asset":{"version":"3.0"}}"#).err().expect("version 3");
        assert!(e.0.contains("3.0"), "{e}");
        let e = parse(br#"{"asset":{"version":"2.0"},"extensionsRequired":["EXT_foo"]}"#)
            .err()
            .expect("ext");
        assert!(e.0.contains("EXT_foo"), "{e}");
        let e = parse(b"[1,2]").err().expect("not an object");
        assert!(e.0.starts_with("JSON"), "{e}");
    }

    /// Every extension in `extensionsUsed` that the loader does not honour is named once, the
    /// archived specular-glossiness one and the unsupported image formats with what is read
    /// instead; the compression extensions the loader decodes are not named.
    #[test]
    fn ignored_extensions_are_named_once() {
        let doc = parse(
            br#"{"asset":{"version":"2.0"},"extensionsUsed":["KHR_materials_specular",
                "KHR_materials_pbrSpecularGlossiness","EXT_foo","EXT_foo","EXT_texture_avif",
                "KHR_texture_basisu","EXT_meshopt_compression"]}"#,
        )
        .expect("parses: only extensionsRequired is refused");
        let ignored = ignored_extensions(&doc.root);
        assert_eq!(ignored.len(), 2, "{ignored:?}");
        assert_eq!(ignored[0], "EXT_foo");
        assert!(ignored[1].starts_with("EXT_texture_avif (the PNG or JPEG fallback"));
        let plain =
            parse(br#"{"asset":{"version":"2.0"},"extensionsUsed":["KHR_lights_punctual"]}"#);
        assert!(ignored_extensions(&plain.expect("parses").root).is_empty());
    }
}
