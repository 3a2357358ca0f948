//! Chi-square tests of the warps in `sampling.rs` and of the camera's lens sampling.

use std::f32::consts::PI;

use glam::{Mat3, Vec2, Vec3};

use super::chi2::{assert_fits, Planar, Spherical};
use crate::render::{
    camera::{Camera, CameraModel},
    sampling::{
        cosine_hemisphere_pdf, henyey_greenstein, sample_cosine_hemisphere,
        sample_henyey_greenstein, sample_uniform_cone, sample_uniform_disk_concentric,
        sample_uniform_sphere, sample_uniform_triangle, uniform_cone_pdf, uniform_disk_pdf,
        uniform_sphere_pdf,
    },
};

/// Cone half-angles tested, in degrees: narrow, medium, a hemisphere and wider than one.
const CONE_DEGREES: [f32; 4] = [5.0, 30.0, 90.0, 150.0];

/// Mean cosines of the Henyey-Greenstein cases: backward, isotropic, forward, strongly forward.
const HG_G: [f32; 4] = [-0.7, 0.0, 0.3, 0.9];

/// Chi-square tests in this file.
pub(super) const N_CHI2: usize = 5 + CONE_DEGREES.len() + HG_G.len();

fn xy(u: Vec3) -> Vec2 {
    Vec2::new(u.x, u.y)
}

#[test]
fn cosine_hemisphere_matches_pdf() {
    assert_fits(
        "cosine_hemisphere",
        Spherical::hemisphere(),
        |u| Some(sample_cosine_hemisphere(xy(u))),
        |w| cosine_hemisphere_pdf(w.z),
    );
}

#[test]
fn uniform_sphere_matches_pdf() {
    assert_fits(
        "uniform_sphere",
        Spherical::sphere(),
        |u| Some(sample_uniform_sphere(xy(u))),
        |_| uniform_sphere_pdf(),
    );
}

#[test]
fn uniform_cone_matches_pdf() {
    for degrees in CONE_DEGREES {
        let cos_max = degrees.to_radians().cos();
        // The domain is the cone itself, so a sample outside it fails the test.
        assert_fits(
            &format!("uniform_cone_{degrees}deg"),
            Spherical::cap(Vec3::Z, (cos_max as f64).acos()),
            |u| Some(sample_uniform_cone(xy(u), cos_max)),
            |_| uniform_cone_pdf(cos_max),
        );
    }
}

#[test]
fn concentric_disk_matches_pdf() {
    assert_fits(
        "concentric_disk",
        Planar::new(Vec2::splat(-1.0), Vec2::ONE),
        |u| Some(sample_uniform_disk_concentric(xy(u))),
        |p| if p.length_squared() <= 1.0 { uniform_disk_pdf() } else { 0.0 },
    );
}

#[test]
fn thin_lens_origins_are_uniform_on_the_aperture() {
    // The lens sample as the camera uses it: ray origins (camera space, divided by the aperture
    // radius) must cover the unit disk uniformly.
    let aperture_radius = 0.25;
    let camera = Camera {
        to_world: Mat3::IDENTITY,
        model: CameraModel::Perspective { tan_half_fov: (0.5f32 * PI / 3.0).tan() },
        width: 64.0,
        height: 48.0,
        aperture_radius,
        focus_distance: 3.0,
    };
    assert!(camera.has_lens());
    assert_fits(
        "thin_lens_origins",
        Planar::new(Vec2::splat(-1.0), Vec2::ONE),
        |u| {
            let ray = camera.generate_ray(Vec2::new(20.5, 30.25), xy(u));
            assert!(ray.origin.z.abs() < 1e-6, "origin off the lens plane: {:?}", ray.origin);
            Some(Vec2::new(ray.origin.x, ray.origin.y) / aperture_radius)
        },
        |p| if p.length_squared() <= 1.0 { uniform_disk_pdf() } else { 0.0 },
    );
}

#[test]
fn uniform_triangle_matches_pdf() {
    // Barycentrics (b0, b1) are uniform on the unit triangle b0, b1 >= 0, b0 + b1 <= 1: density 2.
    assert_fits(
        "uniform_triangle",
        Planar::new(Vec2::ZERO, Vec2::ONE),
        |u| {
            let (b0, b1) = sample_uniform_triangle(xy(u));
            Some(Vec2::new(b0, b1))
        },
        |p| if p.x >= 0.0 && p.y >= 0.0 && p.x + p.y <= 1.0 { 2.0 } else { 0.0 },
    );
}

#[test]
fn the_quarter_sine_and_cosine_are_exact_to_f32_rounding() {
    // Every 1000th float of [0, pi/4], and its negative, against f64: the error relative to the
    // value stays within one f32 epsilon (0.74 measured), so the disk
    // mapping still lands on the unit circle's radius to f32 precision.
    let mut worst = 0.0f64;
    let mut bits = 0u32;
    while f32::from_bits(bits) <= std::f32::consts::FRAC_PI_4 {
        for x in [f32::from_bits(bits), -f32::from_bits(bits)] {
            let (s, c) = crate::render::sampling::sin_cos_quarter(x);
            let (es, ec) = (x as f64).sin_cos();
            for (got, exact) in [(s, es), (c, ec)] {
                if exact != 0.0 {
                    worst = worst.max((got as f64 - exact).abs() / exact.abs());
                } else {
                    assert_eq!(got, 0.0);
                }
            }
        }
        bits += 1000;
    }
    let eps = f64::from(f32::EPSILON);
    println!("worst relative error: {:.3} f32 epsilons", worst / eps);
    assert!(worst <= eps, "worst relative error {:.3} epsilons", worst / eps);
}

#[test]
fn henyey_greenstein_matches_its_phase_function() {
    // Around a direction off the grid's axes; the density over the whole sphere integrates to 1.
    let dir = Vec3::new(0.3, -0.5, 0.81).normalize();
    let frame = crate::render::geometry::Frame::from_z(dir);
    for g in HG_G {
        assert_fits(
            &format!("henyey_greenstein_g{g}"),
            Spherical::sphere(),
            |u| Some(frame.to_world(sample_henyey_greenstein(g, xy(u)))),
            |w| henyey_greenstein(dir.dot(w), g),
        );
    }
}
