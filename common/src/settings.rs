//! Render settings: the JSON object of PRODUCT.md, with defaults and validation.
//!
//! Every key is optional; unknown keys are refused so that a typo never silently renders the
//! wrong thing. `validate` turns absurd values into a message naming the key.

use serde::{Deserialize, Serialize};

/// Upper bound on image width and height accepted by `validate`.
pub const MAX_RESOLUTION: u32 = 16384;
/// Upper bound on the frames of one job accepted by `validate`.
pub const MAX_FRAMES: u64 = 100_000;
/// Upper bound on samples per pixel accepted by `validate`.
pub const MAX_SPP: u32 = 1 << 20;
/// Upper bound on `sppm.photons_per_pass` accepted by `validate`.
pub const MAX_PHOTONS_PER_PASS: u32 = 1 << 24;
/// Upper bound on `bdpt.light_paths` accepted by `validate`.
pub const MAX_LIGHT_PATHS: u32 = 256;

/// Everything that decides what a job renders. Part of the determinism key: the same settings,
/// scene and seed give the same image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderSettings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel (upper bound when stopping adaptively).
    pub spp: u32,
    /// Adaptive stopping: estimated relative RMSE to reach.
    pub target_rel_error: Option<f64>,
    /// Adaptive stopping: wall-clock budget in seconds.
    pub time_limit_s: Option<f64>,
    /// The light-transport algorithm (`"path"`, `"bdpt"` or `"sppm"`; see [`Integrator`]).
    pub integrator: Integrator,
    /// Bidirectional path tracing's parameters (only with `"integrator": "bdpt"`; default: see
    /// [`Bdpt`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bdpt: Option<Bdpt>,
    /// Photon mapping's parameters (only with `"integrator": "sppm"`; default: see [`Sppm`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sppm: Option<Sppm>,
    /// Path length limit in bounces: 0 = emitters seen directly, 1 = direct light only.
    pub max_depth: u32,
    /// Seed of the sample sequences.
    pub seed: u64,
    /// Name of the camera node (or camera) to render; default: the scene's first camera.
    pub camera: Option<String>,
    /// Name of the `KHR_materials_variants` variant to render; default: the scene's default
    /// materials.
    pub variant: Option<String>,
    /// Thin lens.
    pub lens: Lens,
    /// Shutter interval as fractions of the frame interval.
    pub shutter: Shutter,
    /// Frame range.
    pub frames: Frames,
    /// The environment around the scene.
    pub environment: Option<Environment>,
    /// Edge of a square tile in pixels.
    pub tile_size: u32,
    /// Samples per pixel in one task.
    pub samples_per_task: u32,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            width: 640,
            height: 480,
            spp: 256,
            target_rel_error: None,
            time_limit_s: None,
            integrator: Integrator::Path,
            bdpt: None,
            sppm: None,
            max_depth: 64,
            seed: 0,
            camera: None,
            variant: None,
            lens: Lens::default(),
            shutter: Shutter::default(),
            frames: Frames::default(),
            environment: None,
            tile_size: 32,
            samples_per_task: 64,
        }
    }
}

/// The light-transport algorithm of a job, named in the settings' `integrator` key.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Integrator {
    /// `"path"`: the unidirectional path tracer with next-event estimation and multiple
    /// importance sampling.
    #[default]
    Path,
    /// `"bdpt"`: bidirectional path tracing (camera and light subpaths, every connection
    /// weighted by MIS; its light tracing runs as a light task per sample range over the whole
    /// frame; see [`Bdpt`]).
    Bdpt,
    /// `"sppm"`: stochastic progressive photon mapping (each sample index a photon pass over the
    /// whole frame; see [`Sppm`]).
    Sppm,
}

impl Integrator {
    /// Every integrator, in the order the documentation names them.
    pub const ALL: [Integrator; 3] = [Integrator::Path, Integrator::Bdpt, Integrator::Sppm];

    /// The name the settings give it.
    pub fn name(self) -> &'static str {
        match self {
            Integrator::Path => "path",
            Integrator::Bdpt => "bdpt",
            Integrator::Sppm => "sppm",
        }
    }

    /// Whether a frame is also rendered by tasks over the whole frame (bidirectional path
    /// tracing's light tasks, photon mapping's passes), besides or instead of tiles.
    pub fn has_whole_frame_tasks(self) -> bool {
        self != Integrator::Path
    }
}

impl std::fmt::Display for Integrator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Integrator {
    type Err = String;

    /// The integrator of a name, or a message that names the key and the integrators there are.
    fn from_str(name: &str) -> Result<Self, String> {
        Integrator::ALL.into_iter().find(|i| i.name() == name).ok_or_else(|| {
            let names: Vec<&str> = Integrator::ALL.iter().map(|i| i.name()).collect();
            format!(
                "integrator: {name:?} is not an integrator of this renderer (it has: {})",
                names.join(", ")
            )
        })
    }
}

impl<'de> Deserialize<'de> for Integrator {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        name.parse().map_err(serde::de::Error::custom)
    }
}

/// Bidirectional path tracing (`"integrator": "bdpt"`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Bdpt {
    /// Light subpaths light-traced (connected to the camera, t = 1) per pixel sample, each
    /// pixel's sample connecting one of them to its camera subpath as well; default 1. More
    /// spend more of the time on light tracing, the strategy that finds caustics (light reflected
    /// or refracted by specular surfaces onto diffuse ones, seen by the camera); the MIS weights
    /// count them (Veach's balance heuristic with sample counts), so any value converges to the
    /// same image. The light tile of a frame has this many times the samples of a camera tile.
    pub light_paths: u32,
}

impl Default for Bdpt {
    fn default() -> Self {
        Bdpt { light_paths: 1 }
    }
}

/// Stochastic progressive photon mapping (`"integrator": "sppm"`): sample index `i` of a pixel
/// is photon pass `i`, whose gather radius shrinks with `i` by the progressive rule.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Sppm {
    /// The first pass's gather radius in scene units; default: two pixel footprints at the
    /// distance of the scene's centre from the camera.
    pub radius: Option<f64>,
    /// Photons traced from the lights per pass; default: one per pixel of the image.
    pub photons_per_pass: Option<u32>,
    /// The progressive rule's alpha in (0, 1): pass i's squared radius is pass i - 1's times
    /// (i + alpha) / (i + 1), passes counted from 0 (the share of new photons each pass keeps).
    pub alpha: f64,
}

impl Default for Sppm {
    fn default() -> Self {
        Sppm { radius: None, photons_per_pass: None, alpha: 2.0 / 3.0 }
    }
}

/// Thin-lens parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Lens {
    /// Radius of the lens disk in scene units; 0 is a pinhole.
    pub aperture_radius: f64,
    /// Distance from the lens to the plane in focus, along the view axis.
    pub focus_distance: f64,
}

impl Default for Lens {
    fn default() -> Self {
        Lens { aperture_radius: 0.0, focus_distance: 1.0 }
    }
}

/// Shutter interval in fractions of the frame interval.
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Shutter {
    /// Opening time.
    pub open: f64,
    /// Closing time; equal to `open` means no motion blur.
    pub close: f64,
}

/// Frames to render; `end` is inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Frames {
    /// First frame.
    pub start: i64,
    /// Last frame (inclusive).
    pub end: i64,
    /// Frames per second: frame f is at time f / fps.
    pub fps: f64,
}

impl Default for Frames {
    fn default() -> Self {
        Frames { start: 0, end: 0, fps: 24.0 }
    }
}

/// The environment: a uniform colour or an equirectangular map.
///
/// Read through [`EnvironmentKeys`], so that a wrong object is refused in plain words (which
/// key is missing or does not belong) rather than as an unmatched variant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, try_from = "EnvironmentKeys")]
pub enum Environment {
    /// Uniform radiance in every direction.
    Color {
        /// Linear RGB radiance.
        color: [f32; 3],
    },
    /// An equirectangular EXR/HDR map.
    Map {
        /// Path or bundle name of the map.
        map: String,
        /// Multiplier.
        #[serde(default = "one")]
        intensity: f32,
        /// Rotation about the up axis in degrees.
        #[serde(default)]
        rotation_deg: f32,
        /// Whether camera rays see it.
        #[serde(default = "yes")]
        visible: bool,
    },
}

fn one() -> f32 {
    1.0
}

fn yes() -> bool {
    true
}

impl Environment {
    /// True when it sends no light at all (a black colour, or a map at intensity 0).
    pub fn is_black(&self) -> bool {
        match self {
            Environment::Color { color } => color.iter().all(|&c| c == 0.0),
            Environment::Map { intensity, .. } => *intensity == 0.0,
        }
    }
}

/// Every key an `environment` object may have, as written; [`Environment`] is made from it.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EnvironmentKeys {
    color: Option<[f32; 3]>,
    map: Option<String>,
    intensity: Option<f32>,
    rotation_deg: Option<f32>,
    visible: Option<bool>,
}

impl TryFrom<EnvironmentKeys> for Environment {
    type Error = String;

    fn try_from(k: EnvironmentKeys) -> Result<Self, String> {
        match (k.color, k.map) {
            (Some(_), Some(_)) => {
                Err("give either `color` [r, g, b] or `map` \"file.hdr\", not both".into())
            }
            (None, None) => Err(
                "needs `color` (linear RGB radiance, e.g. [1, 1, 1]) or `map` (an equirectangular .hdr or .exr file)"
                    .into(),
            ),
            (Some(color), None) => {
                let extra: Vec<&str> = [
                    ("intensity", k.intensity.is_some()),
                    ("rotation_deg", k.rotation_deg.is_some()),
                    ("visible", k.visible.is_some()),
                ]
                .iter()
                .filter(|(_, set)| *set)
                .map(|(name, _)| *name)
                .collect();
                if extra.is_empty() {
                    Ok(Environment::Color { color })
                } else {
                    Err(format!(
                        "`{}` applies to a `map`, not to a `color` (scale the colour instead)",
                        extra.join("`, `")
                    ))
                }
            }
            (None, Some(map)) => Ok(Environment::Map {
                map,
                intensity: k.intensity.unwrap_or_else(one),
                rotation_deg: k.rotation_deg.unwrap_or_default(),
                visible: k.visible.unwrap_or_else(yes),
            }),
        }
    }
}

/// A setting that cannot be rendered, with the key that is wrong.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("invalid setting `{key}`: {reason}")]
pub struct SettingsError {
    /// The offending key, dotted for nested ones (`lens.focus_distance`).
    pub key: &'static str,
    /// What is wrong with its value.
    pub reason: String,
}

fn err(key: &'static str, reason: impl Into<String>) -> SettingsError {
    SettingsError { key, reason: reason.into() }
}

impl RenderSettings {
    /// Light subpaths light-traced per pixel sample (`bdpt.light_paths`, 1 when not given): the
    /// samples of a frame's light tile per sample of its camera tiles.
    pub fn light_paths(&self) -> u32 {
        self.bdpt.map_or(1, |b| b.light_paths)
    }

    /// Parses settings from JSON, refusing unknown keys.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let settings: RenderSettings =
            serde_json::from_str(text).map_err(|e| format!("settings: {e}"))?;
        settings.validate().map_err(|e| e.to_string())?;
        Ok(settings)
    }

    /// The animation time of frame `frame` in seconds (frame / fps).
    pub fn frame_time(&self, frame: i64) -> f64 {
        frame as f64 / self.frames.fps
    }

    /// Checks every value and names the first key that is wrong.
    pub fn validate(&self) -> Result<(), SettingsError> {
        if let Some(b) = &self.bdpt {
            if self.integrator != Integrator::Bdpt {
                return Err(err(
                    "bdpt",
                    format!(
                        "applies to \"integrator\": \"bdpt\", not {:?}",
                        self.integrator.name()
                    ),
                ));
            }
            if b.light_paths == 0 || b.light_paths > MAX_LIGHT_PATHS {
                return Err(err(
                    "bdpt.light_paths",
                    format!("{} is not in 1..={MAX_LIGHT_PATHS}", b.light_paths),
                ));
            }
        }
        if let Some(p) = &self.sppm {
            if self.integrator != Integrator::Sppm {
                return Err(err(
                    "sppm",
                    format!(
                        "applies to \"integrator\": \"sppm\", not {:?}",
                        self.integrator.name()
                    ),
                ));
            }
            if let Some(r) = p.radius {
                if !(r.is_finite() && r > 0.0) {
                    return Err(err(
                        "sppm.radius",
                        format!("{r} is not a positive number (photons are gathered within it)"),
                    ));
                }
            }
            if let Some(n) = p.photons_per_pass {
                if n == 0 || n > MAX_PHOTONS_PER_PASS {
                    return Err(err(
                        "sppm.photons_per_pass",
                        format!("{n} is not in 1..={MAX_PHOTONS_PER_PASS}"),
                    ));
                }
            }
            if !(p.alpha > 0.0 && p.alpha < 1.0) {
                return Err(err(
                    "sppm.alpha",
                    format!(
                        "{} is not in (0, 1): at 1 the radius never shrinks and the image \
                         never converges, at 0 or below it has no photons left",
                        p.alpha
                    ),
                ));
            }
        }
        if let Some(v) = &self.variant {
            if v.is_empty() || v.chars().any(char::is_control) {
                return Err(err("variant", format!("{v:?} is not a variant name")));
            }
        }
        if self.width == 0 || self.width > MAX_RESOLUTION {
            return Err(err("width", format!("{} is not in 1..={MAX_RESOLUTION}", self.width)));
        }
        if self.height == 0 || self.height > MAX_RESOLUTION {
            return Err(err("height", format!("{} is not in 1..={MAX_RESOLUTION}", self.height)));
        }
        if self.spp == 0 || self.spp > MAX_SPP {
            return Err(err("spp", format!("{} is not in 1..={MAX_SPP}", self.spp)));
        }
        if let Some(e) = self.target_rel_error {
            if !(e.is_finite() && e > 0.0) {
                return Err(err("target_rel_error", format!("{e} is not a positive number")));
            }
        }
        if let Some(t) = self.time_limit_s {
            if !(t.is_finite() && t > 0.0) {
                return Err(err("time_limit_s", format!("{t} is not a positive number")));
            }
        }
        if self.max_depth > 1024 {
            return Err(err("max_depth", format!("{} is over 1024", self.max_depth)));
        }
        let lens = self.lens;
        if !(lens.aperture_radius.is_finite() && lens.aperture_radius >= 0.0) {
            return Err(err("lens.aperture_radius", "must be a finite number >= 0"));
        }
        if !(lens.focus_distance.is_finite() && lens.focus_distance > 0.0) {
            return Err(err("lens.focus_distance", "must be a finite number > 0"));
        }
        let shutter = self.shutter;
        if !(shutter.open.is_finite() && shutter.close.is_finite() && shutter.open <= shutter.close)
        {
            return Err(err("shutter", "needs finite open <= close"));
        }
        if self.frames.end < self.frames.start {
            return Err(err("frames", "end is before start"));
        }
        let count = (self.frames.end as i128) - (self.frames.start as i128) + 1;
        if count > MAX_FRAMES as i128 {
            return Err(err("frames", format!("{count} frames is over the limit of {MAX_FRAMES}")));
        }
        if !(self.frames.fps.is_finite() && self.frames.fps > 0.0) {
            return Err(err("frames.fps", "must be a finite number > 0"));
        }
        match &self.environment {
            Some(Environment::Color { color }) => {
                if color.iter().any(|c| !c.is_finite() || *c < 0.0) {
                    return Err(err("environment.color", "components must be finite and >= 0"));
                }
            }
            Some(Environment::Map { intensity, rotation_deg, .. }) => {
                if !(intensity.is_finite() && *intensity >= 0.0 && rotation_deg.is_finite()) {
                    return Err(err("environment", "intensity and rotation must be finite"));
                }
            }
            None => {}
        }
        if self.tile_size == 0 || self.tile_size > 4096 {
            return Err(err("tile_size", format!("{} is not in 1..=4096", self.tile_size)));
        }
        if self.samples_per_task == 0 {
            return Err(err("samples_per_task", "must be at least 1"));
        }
        Ok(())
    }

    /// Whether samples need a time dimension (a shutter of non-zero length).
    pub fn has_motion_blur(&self) -> bool {
        self.shutter.close > self.shutter.open
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_match_product_contract() {
        let s = RenderSettings::from_json("{}").unwrap();
        assert_eq!((s.width, s.height, s.spp, s.max_depth, s.tile_size), (640, 480, 256, 64, 32));
        assert_eq!(s.environment, None);
    }

    #[test]
    fn the_integrator_is_named_and_an_unknown_one_is_refused_by_key() {
        for name in ["path", "bdpt", "sppm"] {
            let s = RenderSettings::from_json(&format!(r#"{{"integrator": "{name}"}}"#)).unwrap();
            assert_eq!(s.integrator.name(), name);
            assert_eq!(name.parse::<Integrator>(), Ok(s.integrator));
        }
        assert_eq!(RenderSettings::default().integrator, Integrator::Path);
        for bad in ["photons", "", "Path"] {
            let e =
                RenderSettings::from_json(&format!(r#"{{"integrator": "{bad}"}}"#)).unwrap_err();
            assert!(e.contains("integrator") && e.contains("it has: path, bdpt, sppm"), "{e}");
        }
        // Every integrator takes adaptive sampling.
        for name in Integrator::ALL {
            let json = format!(r#"{{"integrator": "{name}", "target_rel_error": 0.1}}"#);
            assert!(RenderSettings::from_json(&json).is_ok(), "{name}");
        }
        // The settings JSON written into EXR headers and job statuses names it (and has no
        // photon-mapping keys unless they were given).
        let json = serde_json::to_string(&RenderSettings::default()).unwrap();
        assert!(json.contains(r#""integrator":"path""#) && !json.contains("sppm"), "{json}");
    }

    #[test]
    fn sppm_settings_that_cannot_converge_name_their_key() {
        let s = RenderSettings::from_json(
            r#"{"integrator": "sppm", "sppm": {"radius": 0.1, "photons_per_pass": 1000}}"#,
        )
        .unwrap();
        let p = s.sppm.unwrap();
        assert_eq!((p.radius, p.photons_per_pass, p.alpha), (Some(0.1), Some(1000), 2.0 / 3.0));
        for (json, key) in [
            (r#"{"integrator": "sppm", "sppm": {"radius": 0}}"#, "sppm.radius"),
            (r#"{"integrator": "sppm", "sppm": {"radius": -1}}"#, "sppm.radius"),
            (r#"{"integrator": "sppm", "sppm": {"photons_per_pass": 0}}"#, "sppm.photons_per_pass"),
            (
                r#"{"integrator": "sppm", "sppm": {"photons_per_pass": 100000000}}"#,
                "sppm.photons_per_pass",
            ),
            (r#"{"integrator": "sppm", "sppm": {"alpha": 1}}"#, "sppm.alpha"),
            (r#"{"integrator": "sppm", "sppm": {"alpha": 0}}"#, "sppm.alpha"),
            (r#"{"integrator": "path", "sppm": {"radius": 1}}"#, "sppm"),
        ] {
            let e = RenderSettings::from_json(json).unwrap_err();
            assert!(e.contains(&format!("`{key}`")), "{json}: {e}");
        }
        // Adaptive sampling takes photon mapping (its frame is one tile).
        RenderSettings::from_json(r#"{"integrator": "sppm", "target_rel_error": 0.1}"#).unwrap();
        let e =
            RenderSettings::from_json(r#"{"integrator": "sppm", "sppm": {"radius": 1, "r": 2}}"#)
                .unwrap_err();
        assert!(e.contains("unknown field `r`"), "{e}");
    }

    #[test]
    fn bdpt_light_paths_are_validated_by_key() {
        let s = RenderSettings::from_json(r#"{"integrator": "bdpt", "bdpt": {"light_paths": 8}}"#)
            .unwrap();
        assert_eq!(s.light_paths(), 8);
        assert_eq!(
            RenderSettings::from_json(r#"{"integrator": "bdpt"}"#).unwrap().light_paths(),
            1
        );
        for (json, key) in [
            (r#"{"integrator": "bdpt", "bdpt": {"light_paths": 0}}"#, "bdpt.light_paths"),
            (r#"{"integrator": "bdpt", "bdpt": {"light_paths": 257}}"#, "bdpt.light_paths"),
            (r#"{"integrator": "path", "bdpt": {"light_paths": 2}}"#, "bdpt"),
            (r#"{"integrator": "sppm", "bdpt": {}}"#, "bdpt"),
        ] {
            let e = RenderSettings::from_json(json).unwrap_err();
            assert!(e.contains(&format!("`{key}`")), "{json}: {e}");
        }
        let e = RenderSettings::from_json(r#"{"integrator": "bdpt", "bdpt": {"paths": 2}}"#)
            .unwrap_err();
        assert!(e.contains("unknown field `paths`"), "{e}");
        // Absent, it leaves the settings JSON (EXR headers, job statuses) as before.
        let json =
            serde_json::to_string(&RenderSettings::from_json(r#"{"integrator": "bdpt"}"#).unwrap())
                .unwrap();
        assert!(!json.contains("light_paths"), "{json}");
    }

    #[test]
    fn a_variant_name_is_validated_by_key() {
        let s = RenderSettings::from_json(r#"{"variant": "blue"}"#).unwrap();
        assert_eq!(s.variant.as_deref(), Some("blue"));
        for bad in [r#"{"variant": ""}"#, r#"{"variant": "a\nb"}"#] {
            let e = RenderSettings::from_json(bad).unwrap_err();
            assert!(e.contains("variant"), "{e}");
        }
    }

    #[test]
    fn unknown_key_is_refused_by_name() {
        let e = RenderSettings::from_json(r#"{"sp": 4}"#).unwrap_err();
        assert!(e.contains("unknown field `sp`"), "{e}");
        let e = RenderSettings::from_json(r#"{"lens": {"radius": 1}}"#).unwrap_err();
        assert!(e.contains("radius"), "{e}");
    }

    #[test]
    fn environment_forms_parse() {
        let s = RenderSettings::from_json(r#"{"environment": {"color": [1, 0.5, 0]}}"#).unwrap();
        assert_eq!(s.environment, Some(Environment::Color { color: [1.0, 0.5, 0.0] }));
        let s = RenderSettings::from_json(r#"{"environment": {"map": "sky.exr"}}"#).unwrap();
        assert!(
            matches!(s.environment, Some(Environment::Map { intensity, visible: true, .. }) if intensity == 1.0)
        );
    }

    #[test]
    fn a_wrong_environment_is_refused_in_plain_words() {
        for (json, needle) in [
            (r#"{"environment": {}}"#, "needs `color`"),
            (r#"{"environment": {"intensity": 2}}"#, "needs `color`"),
            (r#"{"environment": {"color": [1, 1, 1], "map": "a.hdr"}}"#, "not both"),
            (
                r#"{"environment": {"color": [1, 1, 1], "intensity": 2}}"#,
                "`intensity` applies to a `map`",
            ),
            (r#"{"environment": {"map": "a.hdr", "rotation": 90}}"#, "unknown field `rotation`"),
        ] {
            let e = RenderSettings::from_json(json).unwrap_err();
            assert!(e.contains(needle), "{json}: {e}");
            assert!(!e.contains("variant"), "{json}: {e}");
        }
        // Written back, the settings read the same (the EXR header and the farm keep them).
        let s = RenderSettings::from_json(r#"{"environment": {"map": "a.hdr", "visible": false}}"#)
            .unwrap();
        let again: RenderSettings =
            serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert_eq!(again, s);
    }

    #[test]
    fn absurd_values_name_their_key() {
        for (json, key) in [
            (r#"{"width": 0}"#, "width"),
            (r#"{"height": 100000}"#, "height"),
            (r#"{"spp": 0}"#, "spp"),
            (r#"{"lens": {"focus_distance": 0}}"#, "lens.focus_distance"),
            (r#"{"shutter": {"open": 0.5, "close": 0.1}}"#, "shutter"),
            (r#"{"environment": {"color": [-1, 0, 0]}}"#, "environment.color"),
            (r#"{"tile_size": 0}"#, "tile_size"),
        ] {
            let e = RenderSettings::from_json(json).unwrap_err();
            assert!(e.contains(&format!("`{key}`")), "{json}: {e}");
        }
    }
}
