//! The checks of what users send before the farm keeps it: uploads (a known format, a scene
//! that loads), job settings (the farm's limits) and the scene-dependent settings (the camera,
//! the environment map, animation). Pure functions of their inputs; the scene checks are slow
//! and run outside the farm lock.

use common::{
    budget::SceneBudget,
    bundle::{Bundle, Format},
    scene::Scene,
    settings::{Environment, Integrator, RenderSettings},
};
use serde::Serialize;
use sha2::{Digest, Sha256};

use super::error::{ErrorKind, FarmError, FarmResult};

/// What an upload became.
#[derive(Clone, Debug, Serialize)]
pub struct SceneInfo {
    /// SHA-256 of the bytes, hex.
    pub scene: String,
    /// `glb`, `gltf` or `zip`.
    pub format: String,
    /// Size of the upload.
    pub bytes: u64,
    /// Triangles after loading.
    pub triangles: u64,
    /// Camera names.
    pub cameras: Vec<String>,
    /// False when the same bytes were already stored.
    pub created: bool,
}

/// Lower-case hex of `bytes`.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// True for 64 lower-case hex digits.
pub fn is_hash(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// Checks settings against their own rules and the farm's limits (the scene-dependent checks
/// are [`validate_job_scene`]).
pub fn check_settings(settings: &RenderSettings, max_spp: u32, max_pixels: u64) -> FarmResult<()> {
    settings.validate().map_err(|e| FarmError::invalid(format!("settings: {e}")))?;
    if settings.spp > max_spp {
        return Err(FarmError::invalid(format!(
            "settings: spp: {} is over this coordinator's limit of {max_spp}",
            settings.spp
        )));
    }
    let pixels = settings.width as u64 * settings.height as u64;
    if pixels > max_pixels {
        return Err(FarmError::invalid(format!(
            "settings: width x height = {pixels} pixels is over the limit of {max_pixels}"
        )));
    }
    Ok(())
}

/// Checks an upload: a known format, a loadable scene with something to render, within the
/// farm's scene budget. Slow for large scenes: call it outside the farm lock.
pub fn validate_upload(
    bytes: &[u8],
    declared: Option<Format>,
    budget: &SceneBudget,
) -> FarmResult<SceneInfo> {
    validate_upload_of(bytes, declared, budget, None)
}

/// [`validate_upload`] where the caller has loaded the scene from these very bytes within the
/// same budget (the embedded render, which loaded it to bundle it): the bundle is checked, the
/// scene not loaded again.
pub fn validate_upload_loaded(
    bytes: &[u8],
    budget: &SceneBudget,
    scene: &Scene,
) -> FarmResult<SceneInfo> {
    validate_upload_of(bytes, None, budget, Some(scene))
}

fn validate_upload_of(
    bytes: &[u8],
    declared: Option<Format>,
    budget: &SceneBudget,
    loaded: Option<&Scene>,
) -> FarmResult<SceneInfo> {
    let format = Format::detect(bytes).map_err(|e| FarmError::invalid(e.0))?;
    if let Some(d) = declared {
        if d != format {
            return Err(FarmError::new(
                ErrorKind::UnsupportedMediaType,
                format!(
                    "the Content-Type says {} but the body is a {} file",
                    d.name(),
                    format.name()
                ),
            ));
        }
    }
    let bundle = Bundle::open(bytes, budget).map_err(|e| FarmError::invalid(e.0))?;
    let own;
    let scene = match loaded {
        Some(scene) => scene,
        None => {
            own = load(&bundle)?;
            &own
        }
    };
    let triangles = scene.triangle_count() as u64;
    Ok(SceneInfo {
        scene: hex(&Sha256::digest(bytes)),
        format: format.name().to_string(),
        bytes: bytes.len() as u64,
        triangles,
        cameras: scene.cameras.iter().map(|c| c.name.clone()).collect(),
        created: true,
    })
}

/// The bundle's scene, its images decoded on every core.
fn load(bundle: &Bundle) -> FarmResult<Scene> {
    bundle
        .load_scene_spread(&worker::spread::Threads::available())
        .map_err(|e| FarmError::invalid(format!("scene: {e}")))
}

/// The scene-dependent checks of a job: the named camera and material variant exist and the
/// environment map, if any, is in the bundle and decodes. Slow: call it outside the farm lock.
/// `loaded`: the scene the caller loaded from this bundle, and whether it decoded the settings'
/// environment map too (the embedded render); neither is then decoded again.
pub fn validate_job_scene(
    bundle_bytes: &[u8],
    settings: &RenderSettings,
    budget: &SceneBudget,
    loaded: Option<(&Scene, bool)>,
) -> FarmResult<()> {
    let bundle = Bundle::open(bundle_bytes, budget).map_err(|e| FarmError::invalid(e.0))?;
    let needs_scene = settings.camera.is_some()
        || settings.lens.aperture_radius > 0.0
        || settings.integrator != Integrator::Path
        || settings.variant.is_some();
    // The scene, loaded at most once, and only where a check reads it.
    let own;
    let scene = match (loaded, needs_scene) {
        (_, false) => None,
        (Some((scene, _)), true) => Some(scene),
        (None, true) => {
            own = load(&bundle)?;
            Some(&own)
        }
    };
    if let Some(scene) = scene {
        if let Some(name) = &settings.camera {
            if !scene.cameras.iter().any(|c| &c.name == name) {
                let names: Vec<&str> = scene.cameras.iter().map(|c| c.name.as_str()).collect();
                return Err(FarmError::invalid(format!(
                    "settings: camera: no camera named '{name}' (the scene has: {})",
                    names.join(", ")
                )));
            }
        }
        if settings.lens.aperture_radius > 0.0 {
            scene.check_lens(settings).map_err(|e| FarmError::invalid(format!("settings: {e}")))?;
        }
        if settings.integrator != Integrator::Path {
            scene
                .check_integrator(settings)
                .map_err(|e| FarmError::invalid(format!("settings: {e}")))?;
        }
        if let Some(name) = &settings.variant {
            scene.variant_index(name).map_err(|e| FarmError::invalid(format!("settings: {e}")))?;
        }
    }
    let map_loaded = loaded.is_some_and(|(_, env)| env);
    if let (Some(Environment::Map { map, .. }), false) = (&settings.environment, map_loaded) {
        bundle
            .load_envmap(map)
            .map_err(|e| FarmError::invalid(format!("settings: environment.map: {e}")))?;
    }
    Ok(())
}
