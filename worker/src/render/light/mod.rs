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
//!
//! `Light` is the one interface the integrators see (pbrt-v4's): `sample_li` / `pdf_li` toward a
//! receiver, `sample_le` / `pdf_le` for light leaving a light (light subpaths, photons), and
//! `radiance` along a direction; `is_delta`, `is_infinite`, `on_surface` and `placed` say what
//! an integrator must know of its kind. No integrator matches on light kinds: a new light
//! touches only this folder.

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
pub use tree::{LightBounds, LightTree, BATCH as CHOOSE_BATCH};

use std::{f32::consts::PI, sync::Arc};

use glam::{Vec2, Vec3};

use crate::render::{
    geometry::{interpolation_error, Frame},
    sampling::{sample_uniform_disk_concentric, sample_uniform_sphere, uniform_sphere_pdf},
};

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

/// Light leaving a light, for a light subpath or a photon (`Light::sample_le`).
#[derive(Clone, Copy, Debug)]
pub struct LeSample {
    /// What leaves along `dir`: radiance for an emissive triangle (the mean of a textured one,
    /// whose texture the integrator evaluates at `barycentrics`) or the environment; intensity
    /// for a point or spot light; irradiance for a directional light.
    pub le: Vec3,
    /// Where it starts: on the light, or for a light at infinity on the disk of the scene's
    /// radius across `dir`, moved back out of the scene.
    pub p: Vec3,
    /// Unit direction it travels.
    pub dir: Vec3,
    /// Rounding error bound of `p` per axis (an emissive triangle's; zero otherwise).
    pub p_error: Vec3,
    /// Barycentrics of `p` on an emissive triangle (zero otherwise).
    pub barycentrics: [f32; 3],
    /// Density of `p`: per unit area on a triangle or the disk; 1 for a point or spot light,
    /// whose position is certain.
    pub pdf_pos: f32,
    /// Density of `dir` per solid angle; 1 for a directional light, whose direction is certain.
    pub pdf_dir: f32,
}

impl LeSample {
    /// The sample's throughput once the light was chosen with probability `pmf`: what leaves,
    /// times the cosine at an emitting surface, over the densities.
    #[inline]
    pub fn beta(&self, light: &Light, pmf: f32) -> Vec3 {
        let pdf = pmf * self.pdf_pos * self.pdf_dir;
        match light.on_surface() {
            Some(l) => self.le * (l.normal.dot(self.dir).abs() / pdf),
            None => self.le / pdf,
        }
    }
}

/// The densities with which `Light::sample_le` makes a given start and direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LePdf {
    /// Of the start (as `LeSample::pdf_pos`).
    pub pos: f32,
    /// Of the direction (as `LeSample::pdf_dir`).
    pub dir: f32,
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

    /// Samples light leaving the light (pbrt-v4's `SampleLe`). `u_main`, the better stratified
    /// pair, goes to what spreads the light most: the direction, but a directional light's point
    /// (its direction is fixed); `u_other` to the rest. `sphere` is the scene's bounding sphere,
    /// which lights at infinity enter through. `None` where nothing leaves.
    #[inline]
    pub fn sample_le(&self, u_main: Vec2, u_other: Vec2, sphere: (Vec3, f32)) -> Option<LeSample> {
        let delta_pos = |p: Vec3, le: Vec3, dir: Vec3| LeSample {
            le,
            p,
            dir,
            p_error: Vec3::ZERO,
            barycentrics: [0.0; 3],
            pdf_pos: 1.0,
            pdf_dir: uniform_sphere_pdf(),
        };
        match self {
            Light::Triangle(l) => {
                let (b, dir, pdf_dir) = l.sample_le(u_other, u_main)?;
                Some(LeSample {
                    le: l.emission,
                    p: l.p[0] * b[0] + l.p[1] * b[1] + l.p[2] * b[2],
                    dir,
                    p_error: interpolation_error(l.p, b),
                    barycentrics: b,
                    pdf_pos: 1.0 / l.area,
                    pdf_dir,
                })
            }
            Light::Point(l) => {
                Some(delta_pos(l.position, l.intensity, sample_uniform_sphere(u_main)))
            }
            Light::Spot(l) => {
                let dir = sample_uniform_sphere(u_main);
                let le = l.intensity * spot_falloff(dir.dot(l.direction), l.cos_inner, l.cos_outer);
                Some(delta_pos(l.position, le, dir))
            }
            Light::Environment(env) => {
                let (wi, le, pdf_dir) = env.sample(u_main)?;
                let (p, pdf_pos) = enter_from_infinity(sphere, -wi, u_other);
                Some(LeSample { pdf_pos, pdf_dir, ..delta_pos(p, le, -wi) })
            }
            Light::Directional(l) => {
                let (p, pdf_pos) = enter_from_infinity(sphere, -l.to_light, u_main);
                Some(LeSample { pdf_pos, pdf_dir: 1.0, ..delta_pos(p, l.irradiance, -l.to_light) })
            }
        }
    }

    /// Densities with which `sample_le` leaves in unit direction `dir` (pbrt-v4's `PDF_Le`),
    /// from the point it starts at (any point of a triangle or of the disk: their densities are
    /// uniform); a scene of radius `radius`. A triangle's face that does not emit has direction
    /// density 0.
    #[inline]
    pub fn pdf_le(&self, dir: Vec3, radius: f32) -> LePdf {
        let disk = 1.0 / (PI * radius * radius);
        match self {
            Light::Triangle(l) => LePdf { pos: 1.0 / l.area, dir: l.pdf_le(l.normal.dot(dir)) },
            Light::Point(_) | Light::Spot(_) => LePdf { pos: 1.0, dir: uniform_sphere_pdf() },
            Light::Environment(env) => LePdf { pos: disk, dir: env.pdf(-dir) },
            Light::Directional(_) => LePdf { pos: disk, dir: 1.0 },
        }
    }

    /// Radiance leaving the light along unit direction `w` (the direction light travels), for
    /// a ray that finds it: an emissive triangle's from an emitting face (the mean of a textured
    /// one), the environment's; zero for delta lights, which no ray finds.
    #[inline]
    pub fn radiance(&self, w: Vec3) -> Vec3 {
        match self {
            Light::Triangle(l) => l.radiance(w),
            Light::Environment(env) => env.radiance(-w),
            Light::Point(_) | Light::Spot(_) | Light::Directional(_) => Vec3::ZERO,
        }
    }

    /// True for point, spot and directional lights (a delta in position or direction).
    #[inline]
    pub fn is_delta(&self) -> bool {
        matches!(self, Light::Point(_) | Light::Spot(_) | Light::Directional(_))
    }

    /// True for lights at infinity (the environment, directional lights).
    #[inline]
    pub fn is_infinite(&self) -> bool {
        matches!(self, Light::Environment(_) | Light::Directional(_))
    }

    /// The emissive triangle, for a light on a surface.
    #[inline]
    pub fn on_surface(&self) -> Option<&TriangleLight> {
        match self {
            Light::Triangle(l) => Some(l),
            _ => None,
        }
    }

    /// Where a light lies in the scene, to find the volumes around it: a point in it and the
    /// direction to look from it (a triangle's centroid and normal, a spot light's axis; `None`
    /// for a point light, which faces nowhere). `None` for lights at infinity.
    pub fn placed(&self) -> Option<(Vec3, Option<Vec3>)> {
        match self {
            Light::Triangle(l) => Some(((l.p[0] + l.p[1] + l.p[2]) / 3.0, Some(l.normal))),
            Light::Point(l) => Some((l.position, None)),
            Light::Spot(l) => Some((l.position, Some(l.direction))),
            Light::Environment(_) | Light::Directional(_) => None,
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

/// A point where light travelling along unit `d` from infinity enters a scene within `sphere`:
/// on the disk of the sphere's radius across `d` (numbers `u`), moved back out of the scene;
/// with the disk's density per unit area.
fn enter_from_infinity(sphere: (Vec3, f32), d: Vec3, u: Vec2) -> (Vec3, f32) {
    let (centre, r) = sphere;
    let disk = sample_uniform_disk_concentric(u) * r;
    let origin = centre + Frame::from_z(d).to_world(Vec3::new(disk.x, disk.y, 0.0)) - d * r;
    (origin, 1.0 / (PI * r * r))
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

/// Scenes with at least this many emitters choose lights by the tree, the others by the
/// mixture, unless their emitters enclose (see `closed_power`). Emitters are counted twice
/// (`emitter_counts`): as placements of emissive meshes with power (see `PowerMixture`), and as
/// pieces, the parts of a placement that share no corner, so that lamps merged into a few meshes
/// count one each. Placements alone decide as before; pieces decide where the lights at infinity
/// carry no more power than the others (the tree gives lights at infinity a fixed half of its
/// choices, the mixture their share of the power: under a map that carries most of it, half the
/// tree's samples would go to lamps that carry little, where the mixture's go by power). On a
/// floor lit by N small quads, each its own placement (`docs/perf/light-tree.md`), the tree had
/// the lower error at equal time from N = 4 on; the threshold sits above the 9 placements and 5
/// pieces (without a map's dominance) of the busiest shipped scenes, so that a few flat lamps
/// keep the mixture, which is cheaper per choice.
pub const TREE_MIN_EMITTERS: usize = 16;

/// The most a piece's vector area (the sum of its triangles' areas times their normals) may be,
/// as a share of its area, for the piece to count as closed: zero for any closed surface, a
/// fifth for a box without its lid, one for a flat panel.
const CLOSED_NET_AREA: f32 = 0.25;

/// The least a piece's signed volume may be, as a share of its area to the power 1.5, for the
/// piece to count as closed: a cube's is 0.068, a sphere's 0.094, two sheets laid back to back
/// (no vector area, no volume) are not closed whatever their rounding.
const CLOSED_MIN_VOLUME: f32 = 1e-3;

/// What `emitter_counts` finds among a scene's emitters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct EmitterCounts {
    /// Placements of emissive meshes with power.
    placements: usize,
    /// Their pieces: triangles joined where they share a corner.
    pieces: usize,
    /// The power of the pieces that enclose a volume and emit outward only, from untextured
    /// triangles. From any point outside such a piece (a tessellated bulb, a glowing box) about
    /// half of its area faces away, so half the mixture's choices on it are wasted, where the
    /// tree's bounds on the emitters' normals pass them by: on Veach's scene (spheres; the
    /// fill light, a sphere too, carries 98% of the power) and on `EmissiveStrengthTest`'s five
    /// cubes the tree reached a given error 0.97-1.30 and 1.95-2.88 times sooner
    /// (`docs/perf/light-tree.md`).
    closed_power: f32,
}

/// The emitters among `lights` with power (`EmitterCounts`). A placement is an emitter of
/// `emitters` (a placement of an emissive mesh); its pieces are its triangles with power
/// joined where they share a corner, bit for bit, so that lamps merged into one mesh count one
/// each, while a lamp of many triangles (a tessellated sphere, a panel) counts once. A textured
/// emitter (or one under a clear coat) is one piece whatever its shape, and never closed: each
/// of its triangles is chosen by the texture's mean, so its pieces look alike to the tree
/// (DamagedHelmet's 55 rendered 40% slower at equal error by the tree, without a map).
fn emitter_counts(lights: &[Light], emitters: &[u32], scene_radius: f32) -> EmitterCounts {
    let lit: Vec<(u32, &TriangleLight, f32)> = lights
        .iter()
        .zip(emitters)
        .filter_map(|(l, &e)| match l {
            Light::Triangle(t) if l.power(scene_radius) > 0.0 => {
                Some((e, t, l.power(scene_radius)))
            }
            _ => None,
        })
        .collect();
    let mut placements: Vec<u32> = lit.iter().map(|&(e, ..)| e).collect();
    placements.sort_unstable();
    placements.dedup();
    // Union-find over the lit triangles, joined through their (emitter, corner) pairs.
    let mut parent: Vec<u32> = (0..lit.len() as u32).collect();
    let root = |parent: &mut [u32], mut i: u32| {
        while parent[i as usize] != i {
            let up = parent[parent[i as usize] as usize];
            parent[i as usize] = up;
            i = up;
        }
        i
    };
    let mut first = std::collections::HashMap::with_capacity(lit.len() * 2);
    let mut pieces = lit.len();
    for (k, &(e, t, _)) in lit.iter().enumerate() {
        // A textured emitter's triangles all take the texture's mean: one piece.
        let corners = if t.textured { [Vec3::ZERO; 3] } else { t.p };
        for q in corners {
            let other = *first.entry((e, q.to_array().map(f32::to_bits))).or_insert(k as u32);
            let (a, b) = (root(&mut parent, k as u32), root(&mut parent, other));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
                pieces -= 1;
            }
        }
    }
    // Each piece's area, vector area, area-weighted centre and whether it may enclose, then its
    // signed volume about that centre (positive where the normals point out).
    #[derive(Clone, Copy, Default)]
    struct Piece {
        area: f64,
        vector_area: glam::DVec3,
        centre: glam::DVec3,
        volume: f64,
        power: f64,
        may_enclose: bool,
    }
    let roots: Vec<u32> = (0..lit.len() as u32).map(|k| root(&mut parent, k)).collect();
    let mut piece: Vec<Piece> = vec![Piece { may_enclose: true, ..Piece::default() }; lit.len()];
    for (&(_, t, power), &r) in lit.iter().zip(&roots) {
        let at = &mut piece[r as usize];
        let area = t.area as f64;
        at.area += area;
        at.vector_area += t.normal.as_dvec3() * area;
        at.centre += (t.p[0] + t.p[1] + t.p[2]).as_dvec3() / 3.0 * area;
        at.power += power as f64;
        at.may_enclose &= !t.textured && !t.two_sided;
    }
    for (&(_, t, _), &r) in lit.iter().zip(&roots) {
        let at = &mut piece[r as usize];
        let c = at.centre / at.area;
        let [a, b, d] = t.p.map(|q| q.as_dvec3() - c);
        at.volume += a.dot(b.cross(d)) / 6.0;
    }
    let closed_power = roots
        .iter()
        .enumerate()
        .filter(|&(k, &r)| k == r as usize)
        .map(|(k, _)| piece[k])
        .filter(|p| {
            p.may_enclose
                && p.volume > CLOSED_MIN_VOLUME as f64 * p.area.powf(1.5)
                && p.vector_area.length() <= CLOSED_NET_AREA as f64 * p.area
        })
        .map(|p| p.power)
        .sum::<f64>() as f32;
    EmitterCounts { placements: placements.len(), pieces, closed_power }
}

/// Which way a scene chooses its lights.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightChoice {
    /// The tree from `TREE_MIN_EMITTERS` emitters on (placements, or pieces where lights at
    /// infinity do not dominate), or where closed emitters carry most of the power (and lights
    /// at infinity do not dominate), else the mixture.
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
                let counts = emitter_counts(&lights, emitters, scene_radius);
                let at_infinity: f32 =
                    lights.iter().filter(|l| l.is_infinite()).map(|l| l.power(scene_radius)).sum();
                let finite: f32 =
                    lights.iter().filter(|l| !l.is_infinite()).map(|l| l.power(scene_radius)).sum();
                // Closed emitters decide where they carry at least half the power of the
                // lights at a finite distance.
                let enclosing = counts.closed_power > 0.0 && 2.0 * counts.closed_power >= finite;
                counts.placements >= TREE_MIN_EMITTERS
                    || ((counts.pieces >= TREE_MIN_EMITTERS || enclosing) && finite >= at_infinity)
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

    /// `choose` at each of `ctx` with each of `u` (at most `tree::BATCH`), into `out`: the same
    /// choices bit for bit, the tree's walks interleaved.
    pub fn choose_batch(
        &self,
        ctx: &[ShadingContext],
        u: &[f32],
        out: &mut [Option<(u32, f32, f32)>],
    ) {
        match &self.strategy {
            Strategy::Mixture(m) => {
                for ((c, &u), o) in ctx.iter().zip(u).zip(out) {
                    *o = ChooseLight::choose(m, c, u);
                }
            }
            Strategy::Tree(t) => t.choose_batch(ctx, u, out),
        }
    }

    /// `pmf` at each of `ctx` for each of `light` (at most `tree::BATCH`), into `out`: the same
    /// probabilities bit for bit, the tree's walks interleaved.
    pub fn pmf_batch(&self, ctx: &[ShadingContext], light: &[u32], out: &mut [f32]) {
        match &self.strategy {
            Strategy::Mixture(m) => {
                for ((c, &l), o) in ctx.iter().zip(light).zip(out) {
                    *o = m.pmf(c, l);
                }
            }
            Strategy::Tree(t) => t.pmf_batch(ctx, light, out),
        }
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
