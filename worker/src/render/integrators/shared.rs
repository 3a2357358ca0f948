//! The shared path layer: the pieces of path logic every integrator calls, written once.
//!
//! - MIS: the power heuristic, the one delta convention (`UNWEIGHTED`: a direction no light
//!   sample could have made takes the whole weight), and the weight of light a sampled
//!   direction finds (`hit_weight`: an emissive triangle or the environment, against sampling
//!   that light from the previous vertex).
//! - Direct lighting: the light chosen from the shading context and sampled
//!   (`sample_light`), and the radiance it sends (`light_radiance`: textured emitters and
//!   coverage).
//! - Russian roulette, which looks past the eta² a path's radiance took crossing refractions.
//! - The shading frame at a hit (interpolated normal, normal map, anisotropy direction).
//! - The BSDF at a surface vertex (`surface_bsdf`), where a clear coat takes its own normal.

use glam::{Vec2, Vec3};

use super::super::{
    bsdf::{Bsdf, BsdfSample, Layered},
    geometry::{interpolation_error, Frame},
    lanes::V3,
    light::{ChooseLight, Light, LightSample, ShadingContext, TriangleLight},
    material,
    media::{Crossing, MediumStack},
    motion::Pose,
    sampler::Sampler,
    scene::PreparedScene,
};

/// Counters kept per task (never logged per ray).
#[derive(Clone, Copy, Debug, Default)]
pub struct Stats {
    /// Rays traced: camera, bounce and shadow rays.
    pub rays: u64,
}

/// Russian roulette: after `RR_MIN_DEPTH` bounces a path goes on with probability
/// min(1, `RR_SURVIVAL_SCALE` x its largest throughput channel), so that only paths whose
/// throughput fell below 1 / `RR_SURVIVAL_SCALE` are ever ended, and a survivor's weight grows by
/// at most that factor. Unbiased for any choice; the choice trades variance against rays.
/// Measured on the Cornell box (relative MSE at 64 spp x instructions at 4 spp, both
/// deterministic): the usual scale of 1 (pbrt, Mitsuba) after 4 bounces gave 2.947e-3 x 3.19 G;
/// a scale of 3 after 2 bounces 2.457e-3 x 3.22 G (16% more efficient, 14-20% from 4 to 256 spp);
/// scales of 2, 4 and 5 and depths of 1 and 3 did no better.
pub(crate) const RR_MIN_DEPTH: u32 = 2;
pub(crate) const RR_SURVIVAL_SCALE: f32 = 3.0;

/// How many false interfaces (volume boundaries with the same medium on both sides) a path
/// passes before it is ended: far more than any sensible nesting, few enough that a pathological
/// mesh cannot hold a path.
pub(crate) const MAX_FALSE_INTERFACES: u32 = 256;

/// 1 - ShadowEpsilon: shadow rays toward a point stop just short of it.
pub(crate) const SHADOW_T_MAX: f32 = 1.0 - 1e-4;

/// Veach's power heuristic (exponent 2): the weight of a sample of strategy a (density `a`)
/// against strategy b (density `b`), one sample of each. An infinite `a` (a direction only `a`
/// could make: a delta lobe, or `UNWEIGHTED`) takes the whole weight.
#[inline]
pub(crate) fn power_heuristic(a: f32, b: f32) -> f32 {
    generic::power_heuristic(a, b)
}

/// Whether a direction with shading-frame z `cos_s` and geometric cosine `cos_g` (both relative
/// to wo's side) lies on one side of both surfaces: wo's side, or the far side for a BSDF that
/// transmits. A direction between the two (a bent shading normal) carries no light.
#[inline]
pub(crate) fn same_side(cos_s: f32, cos_g: f32, transmits: bool) -> bool {
    generic::same_side(cos_s, cos_g, transmits)
}

/// The density MIS gives a direction that no light sample could have made (a camera ray, a
/// delta lobe, a phase function sampled exactly): the light it finds counts whole.
pub(crate) const UNWEIGHTED: f32 = f32::INFINITY;

/// The density MIS weighs a BSDF sample's direction by: its solid-angle density, or
/// `UNWEIGHTED` for a delta lobe.
#[inline]
pub(crate) fn mis_pdf(bs: &BsdfSample) -> f32 {
    if bs.lobe.is_delta() {
        UNWEIGHTED
    } else {
        bs.pdf
    }
}

/// The weight of light that a direction sampled with density `bsdf_pdf` (per solid angle, or
/// `UNWEIGHTED`) from the shading context `from` finds on light `light` (an emissive triangle
/// or the environment), against sampling that light from there: `dir` the unit direction
/// toward it and `dist2` the squared distance to the point hit (ignored for the environment).
#[inline]
pub(crate) fn hit_weight(
    scene: &PreparedScene,
    light: u32,
    from: &ShadingContext,
    dir: Vec3,
    dist2: f32,
    bsdf_pdf: f32,
) -> f32 {
    if bsdf_pdf == UNWEIGHTED {
        return 1.0;
    }
    let lights = &scene.lights;
    let light_pdf = lights.pmf(from, light) * lights.lights[light as usize].pdf_li(dir, dist2);
    power_heuristic(bsdf_pdf, light_pdf)
}

/// The light of the environment along `dir` that reaches a path of throughput `beta` leaving
/// the scene, found by a direction sampled with density `bsdf_pdf` (per solid angle, or
/// `UNWEIGHTED`) from `from` and weighted against sampling the environment there; zero without
/// one. (Whether a camera ray sees it is the caller's to say.)
#[inline]
pub(crate) fn environment_hit(
    scene: &PreparedScene,
    beta: Vec3,
    dir: Vec3,
    from: &ShadingContext,
    bsdf_pdf: f32,
) -> Vec3 {
    let (Some(env), Some(index)) = (&scene.environment, scene.lights.environment) else {
        return Vec3::ZERO;
    };
    let weight = hit_weight(scene, index, from, dir, 0.0, bsdf_pdf);
    if weight > 0.0 {
        beta * env.radiance(dir) * weight
    } else {
        Vec3::ZERO
    }
}

/// A light sample for next-event estimation: the light chosen as the scene chooses from the
/// shading context `ctx` (point `ctx.p`) with number `u_choice`, and sampled with the numbers
/// `u` gives from the choice's number stretched back to [0, 1) within the light's share (the
/// path tracer places the sample with it, so that the strata of one pair span all lights; a
/// bidirectional camera vertex stores numbers of its own). The light's index, the choice's
/// probability and the sample (its density excludes the choice; its radiance is the light's
/// mean for a textured emitter: `light_radiance` gives the real one).
#[inline]
pub(crate) fn sample_light(
    scene: &PreparedScene,
    ctx: &ShadingContext,
    u_choice: f32,
    u: impl FnOnce(f32) -> Vec2,
) -> Option<(u32, f32, LightSample)> {
    let lights = &scene.lights;
    let (index, choice_pdf, u_x) = lights.choose(ctx, u_choice)?;
    let ls = lights.lights[index as usize].sample_li(ctx.p, u(u_x))?;
    Some((index, choice_pdf, ls))
}

/// The radiance light `light`'s sample `ls` sends toward the receiver: an emissive texture's
/// value at the sampled point (a textured emitter), scaled by the coverage there in a scene
/// with alpha-tested materials (an emitter that is only partly there is hit by sampled paths
/// that often: light sampling counts it so).
#[inline]
pub(crate) fn light_radiance(scene: &PreparedScene, light: &Light, ls: &LightSample) -> Vec3 {
    let Some(l) = light.on_surface() else { return ls.li };
    let mut li =
        if l.textured { surface_emission(scene, l, ls.barycentrics, ls.wi) } else { ls.li };
    if scene.alpha_tested {
        li *= scene.coverage(l.prim, ls.barycentrics);
    }
    li
}

/// What a textured emissive triangle `l` sends from its point at barycentrics `b` along `w`
/// (either way: only the cosine's size matters), by its material (`material::emission_toward`).
#[inline]
pub(crate) fn surface_emission(
    scene: &PreparedScene,
    l: &TriangleLight,
    b: [f32; 3],
    w: Vec3,
) -> Vec3 {
    let m = &scene.materials[scene.shading[l.prim as usize].material as usize];
    let sp = scene.surface_point(l.prim, b);
    material::emission_toward(&scene.textures, m, &sp, l.normal, w)
}

/// Russian roulette after `depth` bounces: past `RR_MIN_DEPTH` the path survives with
/// probability min(1, `RR_SURVIVAL_SCALE` x the largest channel of its throughput `beta` times
/// `eta_scale`), and `beta` grows by its inverse; before, its number is skipped. `eta_scale` is
/// the product of eta² over the refractions a radiance-carrying path crossed (1 for light
/// subpaths and photons, whose flux takes no such scale): radiance scaled by 1 / eta² entering
/// a denser medium comes back leaving it, so the roulette looks past the scale. False when the
/// path ends.
#[inline]
pub(crate) fn roulette(sampler: &mut Sampler, depth: u32, beta: &mut Vec3, eta_scale: f32) -> bool {
    if depth <= RR_MIN_DEPTH {
        sampler.skip(1);
        return true;
    }
    let u_rr = sampler.next_1d();
    let q = generic::roulette_end(V3::from(*beta), eta_scale);
    if u_rr < q {
        return false;
    }
    *beta /= 1.0 - q;
    true
}

/// What a path meets at a surface hit, as to the volumes it is inside (`media`).
pub(crate) enum Meeting {
    /// A surface to shade: whether it bounds a medium (`boundary`), and the medium on its far
    /// side (the one beyond a real boundary; elsewhere the current one).
    Surface { boundary: bool, beyond: Option<u32> },
    /// A false interface (the same medium on both sides), crossed in `media`: the path goes on
    /// straight through it.
    Passed,
    /// More false interfaces than `MAX_FALSE_INTERFACES`: the path ends.
    Stuck,
}

/// A volume's boundary is crossed through its front face into it, through its back face out of
/// it; where the medium is the same on both sides light passes unchanged. `material` is the hit
/// triangle's, `extended` its `TriShading::extended` (tested first: a material without volumes,
/// layers or unlit costs one test), `front` whether the ray meets its front face, `passed` the
/// false interfaces the path has passed so far.
#[inline]
pub(crate) fn meet_surface(
    scene: &PreparedScene,
    material: u32,
    extended: bool,
    front: bool,
    media: &mut MediumStack,
    passed: &mut u32,
) -> Meeting {
    let m = &scene.materials[material as usize];
    let boundary = extended && m.volume.is_some() && m.bounds_medium();
    if !boundary {
        return Meeting::Surface { boundary, beyond: media.current() };
    }
    match media.crossing(material, front) {
        Crossing::Real { beyond } => Meeting::Surface { boundary, beyond },
        Crossing::False => {
            media.cross(material, front);
            *passed += 1;
            if *passed > MAX_FALSE_INTERFACES {
                Meeting::Stuck
            } else {
                Meeting::Passed
            }
        }
    }
}

/// The rounding-error bound of the point at barycentrics `b` of triangle `p`, with a few more
/// roundings of the vertices' size when they went through a transform (`moved`: placed at a
/// sample's time).
#[inline]
pub(crate) fn hit_error(p: [Vec3; 3], b: [f32; 3], moved: bool) -> Vec3 {
    let mut p_error = interpolation_error(p, b);
    if moved {
        p_error += (p[0].abs().max(p[1].abs()).max(p[2].abs())) * (8.0 * f32::EPSILON);
    }
    p_error
}

/// The arithmetic above written once over `Real`: for one path (`f32`) and for a vector of
/// paths (the wavefront).
pub(crate) mod generic {
    use super::{
        super::super::lanes::{Real, V3},
        RR_SURVIVAL_SCALE,
    };

    /// `super::power_heuristic`.
    #[inline(always)]
    pub(crate) fn power_heuristic<R: Real>(a: R, b: R) -> R {
        let (a2, b2) = (a * a, b * b);
        let (zero, sum) = (a.konst(0.0), a2 + b2);
        let w = R::select(sum.eq(zero), zero, a2 / sum);
        R::select(a2.eq(a.konst(f32::INFINITY)), a.konst(1.0), w)
    }

    /// `super::same_side`, whether the BSDF transmits given per lane.
    #[inline(always)]
    pub(crate) fn same_side<R: Real>(cos_s: R, cos_g: R, transmits: R::Mask) -> R::Mask {
        let zero = cos_s.konst(0.0);
        (cos_s.gt(zero) & cos_g.gt(zero)) | (transmits & cos_s.lt(zero) & cos_g.lt(zero))
    }

    /// Russian roulette's probability of ending a path of throughput `beta` that crossed
    /// refractions of eta² product `eta_scale` (`super::roulette`).
    #[inline(always)]
    pub(crate) fn roulette_end<R: Real>(beta: V3<R>, eta_scale: R) -> R {
        let one = eta_scale.konst(1.0);
        (one - beta.scale(eta_scale).max_element() * eta_scale.konst(RR_SURVIVAL_SCALE)).max0()
    }
}

/// The shading frame at barycentrics `b` of triangle `prim` (vertices `tri`) whose geometric
/// normal `ng` has been put on the side the surface is seen from, for `wo` (toward the viewer
/// or the path's previous vertex): the interpolated vertex normal (on `ng`'s side), bent by the
/// normal map (and then toward `ng` where `wo`'s mirror reflection would leave below the
/// surface: [`valid_reflection`]), with +x along the direction of anisotropy for an anisotropic
/// material. Also the normal before the normal map (a clear coat's, unless it has its own
/// map).
#[inline]
#[allow(clippy::too_many_arguments)]
pub(crate) fn shading_frame(
    scene: &PreparedScene,
    prim: u32,
    tri: [Vec3; 3],
    b: [f32; 3],
    ng: Vec3,
    wo: Vec3,
    sp: &material::SurfacePoint,
    pose: Option<&Pose<'_>>,
) -> (Frame, Vec3) {
    let shading = scene.shading[prim as usize];
    let material = &scene.materials[shading.material as usize];
    let mut ns = if shading.smooth {
        let [a, bb, c] = shading.vertices;
        let n = scene.vertex_normal(a, prim, pose) * b[0]
            + scene.vertex_normal(bb, prim, pose) * b[1]
            + scene.vertex_normal(c, prim, pose) * b[2];
        match n.try_normalize() {
            Some(n) if n.dot(ng) > 0.0 => n,
            Some(n) if n.dot(ng) < 0.0 => -n,
            _ => ng,
        }
    } else {
        ng
    };
    let ns_surface = ns;
    if let Some(mapped) = material::normal_map(&scene.textures, material, sp) {
        ns = perturb_normal(scene, (prim, tri, b), ns, mapped, pose).unwrap_or(ns);
        ns = valid_reflection(ng, wo, ns);
    }
    let anisotropy =
        if shading.extended { material::anisotropy(&scene.textures, material, sp) } else { None };
    let frame = match anisotropy {
        Some((_, direction)) => match mesh_tangent_basis(scene, prim, b, ns, pose)
            .or_else(|| tangent_basis(scene, prim, tri, ns, 0))
        {
            Some((t, bt)) => Frame::from_z_and_tangent(ns, t * direction.x + bt * direction.y),
            None => Frame::from_z(ns),
        },
        None => Frame::from_z(ns),
    };
    (frame, ns_surface)
}

/// A normal-mapped shading normal `n` bent toward the geometric normal `ng` (on `wo`'s side)
/// just enough that `wo`'s mirror reflection about it leaves the surface at a cosine to `ng` of
/// at least min(0.9 ng.wo, 0.01): Cycles' `ensure_valid_specular_reflection` (Blender 4),
/// which production renderers apply to bump and normal maps. Without it a map that tilts the
/// normal far from `wo` sends the specular reflection below the surface, where the path is
/// lost, and a mirror-like surface goes black. `n` is returned unchanged where the reflection
/// already clears the threshold (and where `wo` is on the other side of `ng`).
///
/// In the plane of `ng` and `n` (x along `n`'s part across `ng`), the bent normal
/// (sqrt(1 - z²), 0, z) reflects `wo` = (I_x, ., I_z) to height t where
/// 4 a z⁴ - 2 b z² + c = 0, a = I_x² + I_z², b = 2 (a + I_z t), c = (I_z + t)²; the root taken
/// is the one that squaring did not add (the larger where `wo` leans away from `n`).
#[inline]
pub(crate) fn valid_reflection(ng: Vec3, wo: Vec3, n: Vec3) -> Vec3 {
    let iz = wo.dot(ng);
    if !(iz > 0.0) {
        return n;
    }
    let r = 2.0 * n.dot(wo) * n - wo;
    let threshold = (0.9 * iz).min(0.01);
    if r.dot(ng) >= threshold {
        return n;
    }
    let x = (n - n.dot(ng) * ng).try_normalize().unwrap_or(n);
    let ix = wo.dot(x);
    let a = ix * ix + iz * iz;
    let b = 2.0 * (a + iz * threshold);
    let c = (threshold + iz) * (threshold + iz);
    let root = (b * b - 4.0 * a * c).max(0.0).sqrt();
    let z2 = if ix < 0.0 { 0.25 * (b + root) / a } else { 0.25 * (b - root) / a };
    let (nx, nz) = ((1.0 - z2).max(0.0).sqrt(), z2.max(0.0).sqrt());
    (nx * x + nz * ng).normalize()
}

/// Applies a tangent-space normal from a normal map in the frame of [`tangent_basis`].
pub(crate) fn perturb_normal(
    scene: &PreparedScene,
    (prim, tri, b): (u32, [Vec3; 3], [f32; 3]),
    ns: Vec3,
    (tangent_normal, uv_set): (Vec3, u32),
    pose: Option<&Pose<'_>>,
) -> Option<Vec3> {
    let (t, bt) = mesh_tangent_basis(scene, prim, b, ns, pose)
        .or_else(|| tangent_basis(scene, prim, tri, ns, uv_set))?;
    let n =
        (t * tangent_normal.x + bt * tangent_normal.y + ns * tangent_normal.z).try_normalize()?;
    (n.dot(ns) > 0.0).then_some(n)
}

/// The BSDF at barycentrics `b` of triangle `prim` (`material::bsdf` of its material at `sp`,
/// seen from the `front` face or not, with the relative indices `iors`), shaded in `frame`. A
/// clear coat takes its own normal: its normal map's, perturbed from `ns_surface` (the shading
/// normal without the base's normal map), or `ns_surface` itself, as the extension defines it.
/// Every integrator's surface vertex is made here.
pub(crate) fn surface_bsdf(
    scene: &PreparedScene,
    (prim, tri, b): (u32, [Vec3; 3], [f32; 3]),
    (sp, front, iors): (&material::SurfacePoint, bool, [f32; 2]),
    (frame, ns_surface): (&Frame, Vec3),
    pose: Option<&Pose<'_>>,
) -> Bsdf {
    let extended = scene.shading[prim as usize].extended;
    let m = &scene.materials[scene.shading[prim as usize].material as usize];
    let mut bsdf = material::bsdf(&scene.textures, m, sp, front, iors, extended);
    if let (true, Bsdf::Layered(Layered { coat: Some(coat), .. })) = (extended, &mut bsdf) {
        let nc = match material::clearcoat_normal_map(&scene.textures, m, sp) {
            Some(mapped) => perturb_normal(scene, (prim, tri, b), ns_surface, mapped, pose)
                .unwrap_or(ns_surface),
            None => ns_surface,
        };
        coat.normal = frame.to_local(nc);
    }
    bsdf
}

/// The tangent and bitangent at barycentrics `b` of triangle `prim` from the mesh's tangents (its
/// TANGENT attribute, or those the loader made; kept for normal-mapped and anisotropic
/// materials): the interpolated tangent orthogonalised against `ns`, and the bitangent
/// cross(ns, tangent) times the sign in `w`, as glTF defines it. `None` where the mesh has no
/// tangents (or they are degenerate).
fn mesh_tangent_basis(
    scene: &PreparedScene,
    prim: u32,
    b: [f32; 3],
    ns: Vec3,
    pose: Option<&Pose<'_>>,
) -> Option<(Vec3, Vec3)> {
    if scene.tangents.is_empty() {
        return None;
    }
    let [i0, i1, i2] = scene.shading[prim as usize].vertices;
    let [t0, t1, t2] = [i0, i1, i2].map(|v| scene.vertex_tangent(v, prim, pose));
    if t0.w == 0.0 {
        return None; // A mesh without tangents.
    }
    let t = t0.truncate() * b[0] + t1.truncate() * b[1] + t2.truncate() * b[2];
    let t = (t - ns * ns.dot(t)).try_normalize()?;
    Some((t, ns.cross(t) * t0.w.signum()))
}

/// The tangent and bitangent of texture space at a point of triangle `prim` with shading normal
/// `ns`: from the derivatives (dp/du, dp/dv) of the triangle's texture coordinates of set
/// `uv_set`, orthogonalised against `ns`. `None` without those coordinates or where they are
/// degenerate. Normal maps and anisotropy use these where the mesh has no tangents: neither a
/// TANGENT attribute nor MikkTSpace tangents from the loader (which makes none without normals).
fn tangent_basis(
    scene: &PreparedScene,
    prim: u32,
    [p0, p1, p2]: [Vec3; 3],
    ns: Vec3,
    uv_set: u32,
) -> Option<(Vec3, Vec3)> {
    let uvs = scene.uvs.get(uv_set as usize).filter(|uv| !uv.is_empty())?;
    let [i0, i1, i2] = scene.shading[prim as usize].vertices.map(|v| v as usize);
    let (duv1, duv2) = (uvs[i1] - uvs[i0], uvs[i2] - uvs[i0]);
    let det = duv1.x * duv2.y - duv1.y * duv2.x;
    if det.abs() < 1e-12 {
        return None;
    }
    let dpdu = ((p1 - p0) * duv2.y - (p2 - p0) * duv1.y) / det;
    let dpdv = ((p2 - p0) * duv1.x - (p1 - p0) * duv2.x) / det;
    let t = (dpdu - ns * ns.dot(dpdu)).try_normalize()?;
    // glTF's v runs down the image, so the bitangent points along -dp/dv.
    let handedness = if ns.cross(t).dot(dpdv) < 0.0 { 1.0 } else { -1.0 };
    let bt = ns.cross(t) * handedness;
    Some((t, bt))
}

#[cfg(test)]
mod tests {
    use common::{
        gltf::{load_path, load_slice, NoFiles},
        settings::{Environment, RenderSettings},
    };
    use glam::{UVec2, Vec2, Vec3};
    use serde_json::{json, Value};

    use super::*;
    use crate::render::{
        bsdf::Lobe,
        light::ShadingContext,
        sampler::Sampler,
        scene::{prepare, PreparedScene},
    };

    #[test]
    fn the_power_heuristic_sums_to_one_over_two_strategies_and_a_delta_takes_all() {
        // Densities whose squares are normal numbers (below 1e-19 they vanish, as in pbrt).
        let values = [1e-18f32, 1e-6, 0.01, 0.3, 1.0, 2.5, 40.0, 1e6, 1e18];
        for a in values {
            for b in values {
                let sum = power_heuristic(a, b) + power_heuristic(b, a);
                assert!((sum - 1.0).abs() <= 2.0 * f32::EPSILON, "{a} {b}: {sum}");
            }
            assert_eq!(power_heuristic(UNWEIGHTED, a), 1.0);
            assert_eq!(power_heuristic(a, UNWEIGHTED), 0.0);
        }
        assert_eq!(power_heuristic(0.0, 0.0), 0.0);
    }

    #[test]
    fn a_delta_lobe_takes_the_whole_weight() {
        let sample = |lobe| BsdfSample { f: Vec3::ONE, wi: Vec3::Z, pdf: 0.7, lobe, eta: 1.0 };
        for lobe in [Lobe::SpecularReflection, Lobe::SpecularTransmission] {
            assert_eq!(mis_pdf(&sample(lobe)), UNWEIGHTED);
        }
        for lobe in [Lobe::Diffuse, Lobe::Glossy, Lobe::Transmission, Lobe::GlossyTransmission] {
            assert_eq!(mis_pdf(&sample(lobe)), 0.7);
        }
        let scene = cornell(None);
        let (light, _) = first_emitter(&scene);
        let ctx = ShadingContext { p: Vec3::ZERO, n: Vec3::Y };
        assert_eq!(hit_weight(&scene, light, &ctx, Vec3::Y, 1.0, UNWEIGHTED), 1.0);
    }

    fn cornell(environment: Option<Environment>) -> PreparedScene {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/cornell-box.gltf");
        let scene = load_path(std::path::Path::new(path)).expect("the shipped Cornell box");
        let settings = RenderSettings { width: 16, height: 16, environment, ..Default::default() };
        prepare(&scene, &settings).expect("prepared")
    }

    fn first_emitter(scene: &PreparedScene) -> (u32, Vec3) {
        let i = scene.lights.lights.iter().position(|l| matches!(l, Light::Triangle(_)));
        let i = i.expect("an emitter") as u32;
        let Light::Triangle(l) = &scene.lights.lights[i as usize] else { unreachable!() };
        (i, l.normal)
    }

    /// Shading contexts where camera rays through a grid of pixels first hit the scene.
    fn contexts(scene: &PreparedScene, size: u32) -> Vec<ShadingContext> {
        let mut out = Vec::new();
        for y in 0..4 {
            for x in 0..4 {
                let film = Vec2::new(
                    (x as f32 + 0.5) * size as f32 / 4.0,
                    (y as f32 + 0.5) * size as f32 / 4.0,
                );
                let ray = scene.camera.generate_ray(film, Vec2::ZERO);
                let Some(hit) = scene.intersect(&ray, f32::INFINITY, None) else { continue };
                let ([p0, p1, p2], _) = scene.triangle(hit.prim, None);
                let b = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
                let p = p0 * b[0] + p1 * b[1] + p2 * b[2];
                let ng = (p1 - p0).cross(p2 - p0).normalize();
                let n = if ng.dot(ray.dir) < 0.0 { ng } else { -ng };
                out.push(ShadingContext { p, n });
            }
        }
        out
    }

    /// For every light sample taken from a shading point, the light-sampling weight and the
    /// weight `hit_weight` gives the same direction found by a (cosine) BSDF sample add to one:
    /// the densities the two strategies are weighed by are the same on both sides.
    fn check_partition(scene: &PreparedScene, size: u32) -> usize {
        let mut checked = 0;
        let mut sampler = Sampler::new(7, 0);
        for (k, ctx) in contexts(scene, size).iter().enumerate() {
            for s in 0..64 {
                sampler.start_pixel_sample(UVec2::new(k as u32, 0), s);
                let u = sampler.next_2d();
                let Some((light, choice, ls)) =
                    sample_light(scene, ctx, u.x, |u_x| Vec2::new(u_x, u.y))
                else {
                    continue;
                };
                let cos = ctx.n.dot(ls.wi);
                if ls.is_delta || cos <= 0.0 || ls.pdf <= 0.0 {
                    continue;
                }
                let bsdf_pdf = cos * std::f32::consts::FRAC_1_PI;
                let dist2 = ls.point.map_or(0.0, |q| (q - ctx.p).length_squared());
                let by_light = power_heuristic(ls.pdf * choice, bsdf_pdf);
                let by_bsdf = hit_weight(scene, light, ctx, ls.wi, dist2, bsdf_pdf);
                assert!(
                    (by_light + by_bsdf - 1.0).abs() < 1e-3,
                    "light {light} from {ctx:?}: {by_light} + {by_bsdf}"
                );
                checked += 1;
            }
        }
        checked
    }

    #[test]
    fn light_sampling_and_hit_weights_partition_unity() {
        // The Cornell box's emitter (the mixture), then with a uniform sky through its open side.
        assert!(check_partition(&cornell(None), 16) > 500);
        let sky = Environment::Color { color: [0.5, 0.6, 0.7] };
        assert!(check_partition(&cornell(Some(sky)), 16) > 500);
        // 64 small lamps, chosen by the light tree from the shading point.
        let json = crate::test_scenes::many_lights_gltf(64);
        let scene = load_slice(json.as_bytes(), &NoFiles).expect("the many-lights scene");
        let settings = RenderSettings { width: 16, height: 16, ..Default::default() };
        let many =
            prepare_with_light_choice(&scene, &settings, crate::render::light::LightChoice::Tree);
        assert!(many.lights.uses_tree());
        assert!(check_partition(&many, 16) > 500);
    }

    /// A quad facing +z, its texture's u along +x and v down +y's opposite (so the UVs give a
    /// tangent along +x), normal-mapped by a texel that tilts the normal 45 degrees toward the
    /// tangent; with `tangent`, the TANGENT attribute of every vertex; with `uv1`, the map reads
    /// a second set of texture coordinates, whose u runs along +y.
    fn tilted_quad(tangent: Option<[f32; 4]>, uv1: bool) -> PreparedScene {
        tilted_quad_with(tangent, uv1, json!({}))
    }

    /// `tilted_quad` with the material's `extensions`.
    fn tilted_quad_with(tangent: Option<[f32; 4]>, uv1: bool, extensions: Value) -> PreparedScene {
        use base64::Engine as _;
        let floats = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        let mut bin = floats(&[-1., -1., 0., 1., -1., 0., 1., 1., 0., -1., 1., 0.]);
        bin.extend(floats(&[0., 0., 1., 0., 0., 1., 0., 0., 1., 0., 0., 1.]));
        bin.extend(floats(&[0., 1., 1., 1., 1., 0., 0., 0.]));
        bin.extend(floats(&tangent.unwrap_or_default().repeat(4)));
        bin.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
        bin.extend(floats(&[0., 0., 0., 1., 1., 1., 1., 0.]));
        let data = base64::engine::general_purpose::STANDARD.encode(&bin);
        let view = |offset: usize, length: usize| json!({"buffer": 0, "byteOffset": offset, "byteLength": length});
        let accessor = |view: usize, kind: &str| json!({"bufferView": view, "componentType": 5126, "count": 4, "type": kind});
        let mut attributes = json!({"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2});
        if tangent.is_some() {
            attributes["TANGENT"] = json!(3);
        }
        attributes["TEXCOORD_1"] = json!(5);
        // One texel (255, 128, 255): the tangent-space normal (1, 1/255, 1), normalised.
        let png = "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAIAAACQd1PeAAAADElEQVR4nGP43/AfAAUAAn8gmLxdAAAAAElFTkSuQmCC";
        let doc = json!({
            "asset": {"version": "2.0"},
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": attributes, "indices": 4, "material": 0}]}],
            "materials": [{
                "normalTexture": {"index": 0, "texCoord": u32::from(uv1)},
                "extensions": extensions
            }],
            "textures": [{"source": 0}],
            "images": [{"uri": format!("data:image/png;base64,{png}")}],
            "accessors": [
                accessor(0, "VEC3"), accessor(1, "VEC3"), accessor(2, "VEC2"), accessor(3, "VEC4"),
                {"bufferView": 4, "componentType": 5123, "count": 6, "type": "SCALAR"},
                accessor(5, "VEC2")
            ],
            "bufferViews": [
                view(0, 48), view(48, 48), view(96, 32), view(128, 64), view(192, 12), view(204, 32)
            ],
            "buffers": [{"byteLength": bin.len(), "uri": format!("data:application/octet-stream;base64,{data}")}]
        });
        let scene = load_slice(doc.to_string().as_bytes(), &NoFiles).expect("the quad");
        let settings = RenderSettings { width: 8, height: 8, ..Default::default() };
        prepare(&scene, &settings).expect("prepared")
    }

    /// A normal map turns the normal toward the tangent of the mesh's TANGENT attribute where
    /// it has one (here along +y, its bitangent by the sign in w), and toward the tangent the
    /// loader makes from the map's own texture coordinates where it has none (MikkTSpace: +x for
    /// set 0, +y for set 1).
    #[test]
    fn normal_maps_follow_the_tangent_attribute() {
        let h = std::f32::consts::FRAC_1_SQRT_2;
        for (tangent, uv1, expected) in [
            (None, false, Vec3::new(h, 0.0, h)),
            (None, true, Vec3::new(0.0, h, h)),
            (Some([0.0, 1.0, 0.0, 1.0]), false, Vec3::new(0.0, h, h)),
            (Some([0.0, 1.0, 0.0, -1.0]), false, Vec3::new(0.0, h, h)),
            (Some([-1.0, 0.0, 0.0, 1.0]), true, Vec3::new(-h, 0.0, h)),
        ] {
            let scene = tilted_quad(tangent, uv1);
            assert_eq!(scene.tangents.len(), 4, "given or made, one per vertex");
            for prim in 0..2 {
                let (tri, _) = scene.triangle(prim, None);
                let b = [0.2, 0.3, 0.5];
                let sp = scene.surface_point(prim, b);
                let (frame, surface) =
                    shading_frame(&scene, prim, tri, b, Vec3::Z, Vec3::Z, &sp, None);
                assert!((surface - Vec3::Z).length() < 1e-6);
                // The texel's 1/255 along the bitangent aside, the normal is the expected one.
                let n = frame.z;
                assert!((n - expected).length() < 0.01, "{tangent:?}: {n}");
            }
        }
    }

    /// A clear coat takes its own normal, the same in every integrator (`surface_bsdf`): its
    /// normal map's where it has one, else the surface's without the base's normal map.
    #[test]
    fn a_clear_coat_takes_its_own_normal() {
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let tilted = Vec3::new(h, 0.0, h);
        let plain = json!({"KHR_materials_clearcoat": {"clearcoatFactor": 1.0}});
        let mapped = json!({"KHR_materials_clearcoat": {
            "clearcoatFactor": 1.0, "clearcoatNormalTexture": {"index": 0}
        }});
        for (extensions, coat_normal) in [(plain, Vec3::Z), (mapped, tilted)] {
            let scene = tilted_quad_with(None, false, extensions);
            let (prim, b) = (0, [0.2, 0.3, 0.5]);
            let (tri, _) = scene.triangle(prim, None);
            let sp = scene.surface_point(prim, b);
            let (frame, surface) = shading_frame(&scene, prim, tri, b, Vec3::Z, Vec3::Z, &sp, None);
            assert!((frame.z - tilted).length() < 0.01, "the base's map tilts the frame");
            let at = (prim, tri, b);
            let bsdf = surface_bsdf(&scene, at, (&sp, true, [1.0; 2]), (&frame, surface), None);
            let Bsdf::Layered(Layered { coat: Some(coat), .. }) = bsdf else {
                panic!("a coated BSDF: {bsdf:?}")
            };
            let n = frame.to_world(coat.normal);
            assert!((n - coat_normal).length() < 0.01, "{coat_normal}: {n}");
        }
    }

    fn prepare_with_light_choice(
        scene: &common::scene::Scene,
        settings: &RenderSettings,
        choice: crate::render::light::LightChoice,
    ) -> PreparedScene {
        crate::render::scene::prepare_with_light_choice(scene, settings, choice).expect("prepared")
    }

    /// Roulette keeps the expectation: the mean of what survives, weighted, is the throughput
    /// it was given, whatever eta² scale it looks past; before `RR_MIN_DEPTH` every path goes
    /// on unchanged, its number skipped.
    #[test]
    fn roulette_keeps_the_expectation() {
        let n = 1u32 << 14;
        for eta_scale in [1.0f32, 2.25, 1.0 / 2.25] {
            for beta0 in [Vec3::new(0.05, 0.1, 0.02), Vec3::splat(0.3), Vec3::new(0.01, 0.0, 0.2)] {
                let mut sampler = Sampler::new(3, 0);
                let (mut sum, mut sum2, mut ended) = (Vec3::ZERO, Vec3::ZERO, 0);
                for s in 0..n {
                    sampler.start_pixel_sample(UVec2::new(5, 9), s);
                    let mut beta = beta0;
                    let v = if roulette(&mut sampler, RR_MIN_DEPTH + 1, &mut beta, eta_scale) {
                        beta
                    } else {
                        ended += 1;
                        Vec3::ZERO
                    };
                    sum += v;
                    sum2 += v * v;
                }
                let mean = sum / n as f32;
                let var = (sum2 / n as f32 - mean * mean) / n as f32;
                let tolerance = var.max(Vec3::splat(0.0)).powf(0.5) * 5.0 + Vec3::splat(1e-6);
                assert!(
                    (mean - beta0).abs().cmple(tolerance).all(),
                    "eta² {eta_scale}, beta {beta0}: mean {mean}, tolerance {tolerance}"
                );
                let survive = ((beta0 * eta_scale).max_element() * RR_SURVIVAL_SCALE).min(1.0);
                if survive < 1.0 {
                    assert!(ended > 0, "eta² {eta_scale}, beta {beta0}: no path ended");
                }
            }
        }
        // Before the minimum depth: unchanged, and one number skipped.
        let (mut a, mut b) = (Sampler::new(3, 0), Sampler::new(3, 0));
        a.start_pixel_sample(UVec2::ZERO, 0);
        b.start_pixel_sample(UVec2::ZERO, 0);
        let mut beta = Vec3::splat(1e-3);
        assert!(roulette(&mut a, RR_MIN_DEPTH, &mut beta, 1.0));
        assert_eq!(beta, Vec3::splat(1e-3));
        b.skip(1);
        assert_eq!(a.next_1d(), b.next_1d());
    }
}
