//! The path tracer: next-event estimation and BSDF sampling combined with multiple importance
//! sampling (power heuristic), Russian roulette, and a bounce limit.
//!
//! A loop, not recursion. Every bounce takes the same four sampler dimensions in the same order
//! whatever happens (light, lobe, direction, roulette; one it does not need is skipped, not
//! drawn, and a path that ends takes no more), so dimension `k` always means the same thing for
//! every sample of every pixel. The light sample's first coordinate also chooses the light, so
//! its strata span all lights together. In a scene with scattering media each bounce takes two
//! more first, for the free flight; scenes without them keep the layout of four. In a scene with
//! dispersion a path starts with one number for the wavelength it may take on.
//!
//! Media: a path knows the volumes it is inside (`media::MediumStack`: entered through a
//! boundary's front face, left through a back face, the last entered current, false interfaces
//! passed without a bounce), and a refractive boundary's relative index is that of the two media
//! it separates. An absorbing
//! medium weights each segment by its transmittance; a scattering one samples where the light
//! is first scattered (by one channel's exponential for the whole path, weighted by the three
//! channels' densities of the path: `media::free_flight`), and a scattering is a bounce (it
//! counts toward `max_depth` and Russian roulette) whose direction the phase function picks.

use common::scene::Volume;
use glam::{Vec2, Vec3};

use super::{
    super::{
        geometry::{offset_ray_origin, Frame, Ray},
        light::ShadingContext,
        material,
        media::{self, free_flight, transmittance},
        motion::Pose,
        sampler::Sampler,
        sampling::sample_henyey_greenstein,
        scene::{PreparedScene, NONE, UNSAMPLED},
        spectrum,
    },
    shared::{
        environment_hit, hit_error, hit_weight, light_radiance, meet_surface, mis_pdf,
        power_heuristic, roulette, same_side, sample_light, shading_frame, surface_bsdf, Meeting,
        Stats, SHADOW_T_MAX, UNWEIGHTED,
    },
};

/// Radiance arriving at the camera along `ray`.
/// `pose` places what moves at the sample's time (`None`: nothing moves).
pub fn li(
    scene: &PreparedScene,
    ray: Ray,
    sampler: &mut Sampler,
    stats: &mut Stats,
    pose: Option<&Pose<'_>>,
) -> Vec3 {
    // In a scene with dispersion, the number for the wavelength the path takes on at its first
    // dispersive boundary (drawn first, whether used or not).
    let u_wavelength = if scene.dispersive { sampler.next_1d() } else { 0.0 };
    let mut ray = ray;
    let mut radiance = Vec3::ZERO;
    let mut beta = Vec3::ONE;
    let mut depth = 0u32;
    // Density of the BSDF sample that produced `ray` (`UNWEIGHTED` for camera rays and after a
    // delta lobe or a scattering, whose directions no light sample could have chosen).
    let mut prev_bsdf_pdf = UNWEIGHTED;
    // Where that BSDF sample was taken (its point and shading normal): the light choice's
    // probability there is what light sampling would have given the light it hits.
    let mut prev_ctx = ShadingContext::default();
    // The product of eta² over the refractions so far: radiance scaled by 1 / eta² crossing
    // into a denser medium comes back leaving it, so Russian roulette looks past the scale.
    let mut eta_scale = 1.0f32;
    // The volumes the path is inside (each by its boundary's material), the current one on top:
    // at first those the camera lies inside.
    let mut media = scene.camera_media;
    // False interfaces passed (bounded, so that no geometry can hold a path forever).
    let mut passed = 0u32;
    // The wavelength, once a dispersive boundary has given the path one (from `u_wavelength`).
    let mut wavelength: Option<f32> = None;
    // In a scene with scattering media, the channel the path draws its free flights by (from its
    // first free flight's first number) and each channel's density of the path so far over their
    // mean (`media::free_flight`).
    let mut hero: Option<usize> = None;
    let mut ratios = Vec3::ONE;
    let lights = &scene.lights;
    loop {
        stats.rays += 1;
        let hit = scene.intersect(&ray, f32::INFINITY, pose);
        let medium = media.current();
        // In a scene with scattering media every bounce starts with two numbers for the free
        // flight, drawn in a scattering medium and skipped elsewhere; other scenes take none.
        let scattering = match medium {
            Some(m) if scene.scattering_media => {
                scene.materials[m as usize].volume.filter(Volume::scatters)
            }
            _ => None,
        };
        let mut scattered_at = None;
        if let Some(v) = &scattering {
            let distance = hit.map_or(f32::INFINITY, |h| h.t * ray.dir.length());
            let u = sampler.next_2d();
            let h = *hero.get_or_insert_with(|| media::hero_channel(u.x));
            let (weight, at) = free_flight(v, distance, h, u.y, &mut ratios);
            beta *= weight;
            scattered_at = at;
        } else {
            if scene.scattering_media {
                sampler.skip(2);
            }
            if let Some(v) = medium.and_then(|m| scene.materials[m as usize].volume.as_ref()) {
                // Beer-Lambert along the segment inside the volume (an escape is endless).
                let distance = hit.map_or(f32::INFINITY, |h| h.t * ray.dir.length());
                beta *= transmittance(v, distance);
            }
        }
        if let (Some(t), Some(v)) = (scattered_at, &scattering) {
            // A scattering event inside the medium: the phase function, sampled exactly (its
            // value over its density is 1), picks the new direction. No light is sampled from
            // here (a light outside lies beyond the boundary, which a shadow ray cannot cross),
            // so whatever the new direction finds counts in full.
            if depth >= scene.max_depth || beta == Vec3::ZERO || !beta.is_finite() {
                break;
            }
            let dir = ray.dir.normalize();
            let p = ray.origin + dir * t;
            sampler.skip(3); // The light sample and the lobe choice.
            let wi = Frame::from_z(dir)
                .to_world(sample_henyey_greenstein(v.anisotropy, sampler.next_2d()));
            prev_bsdf_pdf = UNWEIGHTED;
            ray = Ray::interior(p, wi);
            depth += 1;
            if !roulette(sampler, depth, &mut beta, eta_scale) {
                break;
            }
            continue;
        }
        let Some(hit) = hit else {
            // Camera rays see the environment only where the settings show it.
            if depth > 0 || scene.environment_visible {
                radiance += environment_hit(scene, beta, ray.dir, &prev_ctx, prev_bsdf_pdf);
            }
            break;
        };
        let tri = scene.shading[hit.prim as usize];
        let ([p0, p1, p2], moved) = scene.triangle(hit.prim, pose);
        let b = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
        let p = p0 * b[0] + p1 * b[1] + p2 * b[2];
        let p_error = hit_error([p0, p1, p2], b, moved);
        let Some(ng) = (p1 - p0).cross(p2 - p0).try_normalize() else {
            break; // A degenerate triangle that the test still reported: nothing to shade.
        };
        let wo = -ray.dir;
        let material = &scene.materials[tri.material as usize];
        // The front face is the one the winding makes counter-clockwise.
        let front = ng.dot(wo) > 0.0;
        let extended = tri.extended;
        let (boundary, beyond) =
            match meet_surface(scene, tri.material, extended, front, &mut media, &mut passed) {
                Meeting::Surface { boundary, beyond } => (boundary, beyond),
                Meeting::Passed => {
                    ray = Ray::new(offset_ray_origin(p, p_error, ng, ray.dir), ray.dir);
                    continue;
                }
                Meeting::Stuck => break,
            };
        let sp = scene.shading_point(hit.prim, [p0, p1, p2], b);
        if extended && material.unlit {
            // `KHR_materials_unlit`: the base colour, seen as it is; nothing goes on from it.
            radiance += beta * material::clamped_base_color(&scene.textures, material, &sp);
            break;
        }

        if tri.light == UNSAMPLED {
            // A moving emitter: no light sampling reaches it, so every hit counts in full.
            if material.double_sided || (p1 - p0).cross(p2 - p0).dot(wo) > 0.0 {
                radiance +=
                    beta * material::emission_toward(&scene.textures, material, &sp, ng, wo);
            }
        } else if tri.light != NONE {
            if let Some(light) = lights.lights[tri.light as usize].on_surface() {
                if light.emits_toward(wo) {
                    let le = material::emission_toward(&scene.textures, material, &sp, ng, wo);
                    let dist2 = hit.t * hit.t * ray.dir.length_squared();
                    let weight =
                        hit_weight(scene, tri.light, &prev_ctx, ray.dir, dist2, prev_bsdf_pdf);
                    radiance += beta * le * weight;
                }
            }
        }
        if depth >= scene.max_depth {
            break;
        }

        // Shading frame on wo's side of the surface (surfaces reflect on both faces).
        let ng = if front { ng } else { -ng };
        let (mut frame, ns_surface) =
            shading_frame(scene, hit.prim, [p0, p1, p2], b, ng, wo, &sp, pose);
        let ns = frame.z;
        let mut wo_local = frame.to_local(wo);
        // A refractive boundary takes every path on, as Mitsuba's and pbrt's dielectrics do:
        // where the interpolated normal turns away from wo it is shaded with the facet's normal,
        // and below which direction it leaves by is the facet's to say (see the crossing below).
        // Ending those paths darkened the outlines of smooth-shaded glass by 1-2.5% against
        // Mitsuba 3 (docs/perf/materials.md).
        let refracting = boundary && material.refracts();
        if wo_local.z <= 0.0 && refracting {
            frame = Frame::from_z(ng);
            wo_local = frame.to_local(wo);
        }
        if wo_local.z <= 0.0 {
            break; // Grazing with a bent normal: no consistent reflection.
        }
        // A refractive boundary's relative index: the volume's against the medium on its
        // other side, the current one entering it, the one beyond leaving it. A dispersive one
        // first gives the path its wavelength, and the path the colour of that light.
        let iors = if boundary {
            let other = if front { medium } else { beyond };
            let dispersive =
                |m: Option<u32>| m.is_some_and(|m| scene.materials[m as usize].dispersion > 0.0);
            if wavelength.is_none()
                && scene.dispersive
                && material.refracts()
                && (material.dispersion > 0.0 || dispersive(other))
            {
                let (lambda, weight) = spectrum::sample_wavelength(u_wavelength);
                wavelength = Some(lambda);
                beta *= weight;
            }
            [
                media::ior(&scene.materials, Some(tri.material), wavelength),
                media::ior(&scene.materials, other, wavelength),
            ]
        } else {
            [1.0; 2]
        };
        let at = (hit.prim, [p0, p1, p2], b);
        let bsdf = surface_bsdf(scene, at, (&sp, front, iors), (&frame, ns_surface), pose);
        let transmits = bsdf.transmits();

        // Next-event estimation. A bounce's numbers are drawn where they are used, in the
        // same order whatever happens; a path that ends skips the rest.
        let u_light = sampler.next_2d();
        let ctx = ShadingContext { p, n: ns };
        if let Some((light_idx, choice_pdf, ls)) =
            sample_light(scene, &ctx, u_light.x, |u_x| Vec2::new(u_x, u_light.y))
        {
            let light = &lights.lights[light_idx as usize];
            let wi_local = frame.to_local(ls.wi);
            if same_side(wi_local.z, ls.wi.dot(ng), transmits) {
                let f = bsdf.eval(wo_local, wi_local) * wi_local.z.abs();
                if f != Vec3::ZERO {
                    let origin = offset_ray_origin(p, p_error, ng, ls.wi);
                    let (shadow, t_max) = match ls.point {
                        Some(q) => {
                            let target = offset_ray_origin(q, ls.point_error, ls.normal, -ls.wi);
                            (Ray::new(origin, target - origin), SHADOW_T_MAX)
                        }
                        None => (Ray::new(origin, ls.wi), f32::INFINITY),
                    };
                    stats.rays += 1;
                    let blocked = scene.occluded(&shadow, t_max, pose);
                    if !blocked {
                        let mut li = light_radiance(scene, light, &ls);
                        // The shadow ray travels in the far side's volume when it crosses into
                        // a medium, else in the path's.
                        let through = if wi_local.z < 0.0 && boundary {
                            if front {
                                Some(tri.material)
                            } else {
                                beyond
                            }
                        } else {
                            medium
                        };
                        if let Some(v) =
                            through.and_then(|m| scene.materials[m as usize].volume.as_ref())
                        {
                            let distance = ls.point.map_or(f32::INFINITY, |q| (q - p).length());
                            li *= transmittance(v, distance);
                        }
                        let light_pdf = ls.pdf * choice_pdf;
                        let weight = if ls.is_delta {
                            1.0
                        } else {
                            power_heuristic(light_pdf, bsdf.pdf(wo_local, wi_local))
                        };
                        radiance += beta * f * li * (weight / light_pdf);
                    }
                }
            }
        }

        // BSDF sampling.
        let u_lobe = if bsdf.chooses_lobe() {
            sampler.next_1d()
        } else {
            sampler.skip(1);
            0.0
        };
        let u_bsdf = sampler.next_2d();
        let Some(bs) = bsdf.sample(wo_local, u_lobe, u_bsdf) else {
            break;
        };
        let wi = frame.to_world(bs.wi);
        if !refracting && !same_side(bs.wi.z, wi.dot(ng), transmits) {
            break;
        }
        beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
        if !beta.is_finite() || beta == Vec3::ZERO {
            break;
        }
        prev_bsdf_pdf = mis_pdf(&bs);
        prev_ctx = ctx;
        if bs.lobe.enters_far_side() {
            eta_scale *= bs.eta * bs.eta;
        }
        // Which side the ray leaves by: the shading frame's, except at a refractive boundary,
        // where the facet's decides (the ray's origin goes there too).
        let crosses = if refracting { wi.dot(ng) < 0.0 } else { bs.wi.z < 0.0 };
        if crosses && boundary {
            media.cross(tri.material, front);
        }
        ray = Ray::new(offset_ray_origin(p, p_error, ng, wi), wi);
        depth += 1;
        if !roulette(sampler, depth, &mut beta, eta_scale) {
            break;
        }
    }
    radiance
}
