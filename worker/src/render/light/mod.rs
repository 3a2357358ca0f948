//! Light sources and the choice between them.
//!
//! Lights are picked by a `ChooseLight` given the receiving point and its normal
//! (`ShadingContext`), then sampled (`Light::sample_li`). A scene with few emitters picks by a
//! mixture of power and a uniform choice of emitter (`PowerMixture`, blind to the point); one
//! with many by a light tree (`LightTree`, pbrt-v4's light BVH), which favours near lights that
//! face the point. `LightSampler` holds the lights and the one the scene uses. Every density is returned per unit solid angle at the receiving point and
//! already includes the probability of choosing the light, so the integrator's MIS weights compare
//! like with like. Delta lights (point, spot, directional) report `is_delta` and are never hit by
//! BSDF-sampled rays.

mod area;
mod environment;
mod mixture;
mod punctual;
mod tree;

pub(crate) use area::generic;
pub use area::TriangleLight;
pub use environment::{Environment, MapEnvironment};
pub use mixture::{PowerMixture, EMITTER_SHARE};
pub use punctual::{spot_falloff, DirectionalLight, PointLight, SpotLight};
pub use tree::{LightBounds, LightTree};

use std::{f32::consts::PI, sync::Arc};

use glam::{Vec2, Vec3};

/// A light's contribution toward a receiving point.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Radiance (or, for delta lights, radiance-equivalent) arriving along `-wi`.
    pub li: Vec3,
    /// Unit direction from the receiver toward the light.
    pub wi: Vec3,
    /// The point on the light (for the shadow ray); `None` for lights at infinity.
    pub point: Option<Vec3>,
    /// Geometric normal at `point` (area lights), to offset the shadow ray's end.
    pub normal: Vec3,
    /// Rounding error bound of `point` per axis (zero for punctual lights).
    pub point_error: Vec3,
    /// Barycentrics of `point` on an emissive triangle (zero otherwise).
    pub barycentrics: [f32; 3],
    /// Density per solid angle including the choice of light (1 x choice for delta lights).
    pub pdf: f32,
    /// True for point, spot and directional lights.
    pub is_delta: bool,
}

/// Any light source.
#[derive(Clone, Debug)]
pub enum Light {
    /// An emissive triangle.
    Triangle(TriangleLight),
    /// A point light.
    Point(PointLight),
    /// A spot light.
    Spot(SpotLight),
    /// A directional light.
    Directional(DirectionalLight),
    /// The environment (shared with `PreparedScene::environment`).
    Environment(Arc<Environment>),
}

impl Light {
    /// Samples an incident direction at receiver `p` (numbers `u`). The density excludes the
    /// choice of light.
    #[inline]
    pub fn sample_li(&self, p: Vec3, u: Vec2) -> Option<LightSample> {
        match self {
            Light::Triangle(l) => l.sample_li(p, u),
            Light::Point(l) => l.sample_li(p),
            Light::Spot(l) => l.sample_li(p),
            Light::Directional(l) => l.sample_li(),
            Light::Environment(env) => {
                let (wi, li, pdf) = env.sample(u)?;
                Some(LightSample {
                    li,
                    wi,
                    point: None,
                    normal: Vec3::ZERO,
                    point_error: Vec3::ZERO,
                    barycentrics: [0.0; 3],
                    pdf,
                    is_delta: false,
                })
            }
        }
    }

    /// Density per unit solid angle at a receiver with which `sample_li` chooses direction `wi`
    /// (unit, toward the light), the light's point lying at distance² `dist2` along it (ignored
    /// for lights at infinity); the choice of light excluded. Zero for delta lights, which no
    /// direction sampled otherwise finds.
    #[inline]
    pub fn pdf_li(&self, wi: Vec3, dist2: f32) -> f32 {
        match self {
            Light::Triangle(l) => l.pdf_li(wi, dist2),
            Light::Environment(env) => env.pdf(wi),
            Light::Point(_) | Light::Spot(_) | Light::Directional(_) => 0.0,
        }
    }

    /// Power estimate used to choose between lights (luminance of emitted flux).
    pub fn power(&self, scene_radius: f32) -> f32 {
        let lum = |c: Vec3| c.dot(Vec3::new(0.2126, 0.7152, 0.0722)).max(0.0);
        match self {
            Light::Triangle(l) => {
                lum(l.emission) * l.area * PI * if l.two_sided { 2.0 } else { 1.0 }
            }
            Light::Point(l) => 4.0 * PI * lum(l.intensity),
            Light::Spot(l) => lum(l.intensity) * l.cone_solid_angle_weight(),
            Light::Directional(l) => lum(l.irradiance) * PI * scene_radius * scene_radius,
            Light::Environment(env) => {
                env.mean_luminance().max(0.0) * 4.0 * PI * PI * scene_radius * scene_radius
            }
        }
    }
}

/// Where a light is chosen for: the receiving point and its shading normal (zero where there is
/// no surface, so that no cosine is counted).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ShadingContext {
    /// The receiving point.
    pub p: Vec3,
    /// Its shading normal, either side (or zero).
    pub n: Vec3,
}

/// A way to choose lights: the choice and its probability, both given the receiving point.
pub trait ChooseLight {
    /// Picks a light with `u` in [0, 1): (index, probability, `u` stretched back to [0, 1)
    /// within the chosen light's share), so that one stratified number both chooses and places
    /// the sample (the strata of a 2D sample then cover all lights together). `None` when no
    /// light has power.
    fn choose(&self, ctx: &ShadingContext, u: f32) -> Option<(u32, f32, f32)>;

    /// Probability that `choose` at `ctx` returns `light`.
    fn pmf(&self, ctx: &ShadingContext, light: u32) -> f32;
}

/// Scenes with at least this many emitters (placements of emissive meshes with power; see
/// `PowerMixture`) choose lights by the tree, the others by the mixture. On a floor lit by N
/// small quads, each its own placement (`docs/perf/light-tree.md`), the tree had the lower
/// error at equal time from N = 4 on; the threshold sits above the 9 emitters of the busiest
/// shipped scene, so that scenes like those (a few lamps, one emissive mesh of many triangles)
/// keep their images.
pub const TREE_MIN_EMITTERS: usize = 16;

/// Which way a scene chooses its lights.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightChoice {
    /// The tree from `TREE_MIN_EMITTERS` emitters on, else the mixture.
    #[default]
    Auto,
    /// Always the mixture.
    Mixture,
    /// Always the tree.
    Tree,
}

/// The way a scene's lights are chosen.
#[derive(Clone, Debug)]
enum Strategy {
    Mixture(PowerMixture),
    Tree(LightTree),
}

/// A scene's lights and the way they are chosen.
#[derive(Clone, Debug)]
pub struct LightSampler {
    /// All lights.
    pub lights: Vec<Light>,
    /// Index in `lights` of the environment, if any.
    pub environment: Option<u32>,
    /// The choice between them.
    strategy: Strategy,
}

impl Default for LightSampler {
    fn default() -> Self {
        LightSampler {
            lights: Vec::new(),
            environment: None,
            strategy: Strategy::Mixture(PowerMixture::default()),
        }
    }
}

impl LightSampler {
    /// The lights and their choice (`LightChoice::Auto`); `emitters[i]` names light `i`'s
    /// emitter (any numbers; equal numbers group lights into one emitter). Lights with zero
    /// power are never chosen.
    pub fn new(lights: Vec<Light>, emitters: &[u32], scene_radius: f32) -> Self {
        Self::with_choice(lights, emitters, scene_radius, LightChoice::Auto)
    }

    /// `new` with the choice given.
    pub fn with_choice(
        lights: Vec<Light>,
        emitters: &[u32],
        scene_radius: f32,
        choice: LightChoice,
    ) -> Self {
        assert_eq!(lights.len(), emitters.len(), "one emitter per light");
        let tree = match choice {
            LightChoice::Auto => {
                let mut lit: Vec<u32> = lights
                    .iter()
                    .zip(emitters)
                    .filter(|(l, _)| matches!(l, Light::Triangle(_)) && l.power(scene_radius) > 0.0)
                    .map(|(_, &e)| e)
                    .collect();
                lit.sort_unstable();
                lit.dedup();
                lit.len() >= TREE_MIN_EMITTERS
            }
            LightChoice::Mixture => false,
            LightChoice::Tree => true,
        };
        let strategy = if tree {
            Strategy::Tree(LightTree::new(&lights, scene_radius))
        } else {
            Strategy::Mixture(PowerMixture::new(&lights, emitters, scene_radius))
        };
        let environment =
            lights.iter().position(|l| matches!(l, Light::Environment(_))).map(|i| i as u32);
        LightSampler { lights, environment, strategy }
    }

    /// True when there is no light with power.
    pub fn is_empty(&self) -> bool {
        match &self.strategy {
            Strategy::Mixture(m) => m.is_empty(),
            Strategy::Tree(t) => t.is_empty(),
        }
    }

    /// The mixture, when the scene chooses by it (its probabilities do not depend on the point,
    /// so the wavefront bakes them).
    pub fn mixture(&self) -> Option<&PowerMixture> {
        match &self.strategy {
            Strategy::Mixture(m) => Some(m),
            Strategy::Tree(_) => None,
        }
    }

    /// Whether the scene chooses by the tree.
    pub fn uses_tree(&self) -> bool {
        matches!(self.strategy, Strategy::Tree(_))
    }
}

impl ChooseLight for LightSampler {
    #[inline]
    fn choose(&self, ctx: &ShadingContext, u: f32) -> Option<(u32, f32, f32)> {
        match &self.strategy {
            Strategy::Mixture(m) => ChooseLight::choose(m, ctx, u),
            Strategy::Tree(t) => ChooseLight::choose(t, ctx, u),
        }
    }

    #[inline]
    fn pmf(&self, ctx: &ShadingContext, light: u32) -> f32 {
        match &self.strategy {
            Strategy::Mixture(m) => m.pmf(ctx, light),
            Strategy::Tree(t) => t.pmf(ctx, light),
        }
    }
}
