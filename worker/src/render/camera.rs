//! Camera rays, as PRODUCT.md fixes them: a pixel's samples cover its square uniformly (box
//! filter), row 0 is the top, and the thin lens focuses on the plane z = -focus_distance.
//!
//! The camera sits at the origin of the renderer's camera-relative world (see `scene::prepare`).

use glam::{Mat3, Vec2, Vec3};

use super::{geometry::Ray, sampling::sample_uniform_disk_concentric};

/// The projection, sized for the image.
#[derive(Clone, Copy, Debug)]
pub enum CameraModel {
    /// tan(yfov / 2) and the image aspect ratio.
    Perspective {
        /// tan(yfov / 2).
        tan_half_fov: f32,
    },
    /// Half extents of the view volume (x from the aspect ratio).
    Orthographic {
        /// Half height.
        ymag: f32,
    },
}

/// A camera ready to generate rays.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    /// Camera-to-world rotation (columns: right, up, backward).
    pub to_world: Mat3,
    /// Projection.
    pub model: CameraModel,
    /// Image width in pixels.
    pub width: f32,
    /// Image height in pixels.
    pub height: f32,
    /// Thin-lens aperture radius; 0 is a pinhole.
    pub aperture_radius: f32,
    /// Distance to the plane in focus.
    pub focus_distance: f32,
}

impl Camera {
    /// Whether rays need a lens sample.
    pub fn has_lens(&self) -> bool {
        self.aperture_radius > 0.0 && matches!(self.model, CameraModel::Perspective { .. })
    }

    /// The ray through image position `film` (in pixels, continuous), with lens numbers `lens_u`
    /// (ignored for a pinhole).
    #[inline]
    pub fn generate_ray(&self, film: Vec2, lens_u: Vec2) -> Ray {
        let sx = 2.0 * film.x / self.width - 1.0;
        let sy = 1.0 - 2.0 * film.y / self.height;
        let aspect = self.width / self.height;
        match self.model {
            CameraModel::Perspective { tan_half_fov } => {
                let d = Vec3::new(sx * tan_half_fov * aspect, sy * tan_half_fov, -1.0);
                if self.aperture_radius > 0.0 {
                    let focus = d * self.focus_distance;
                    let l = sample_uniform_disk_concentric(lens_u) * self.aperture_radius;
                    let origin = Vec3::new(l.x, l.y, 0.0);
                    let dir = (focus - origin).normalize();
                    Ray::new(self.to_world * origin, self.to_world * dir)
                } else {
                    Ray::new(Vec3::ZERO, (self.to_world * d).normalize())
                }
            }
            CameraModel::Orthographic { ymag } => {
                let origin = Vec3::new(sx * ymag * aspect, sy * ymag, 0.0);
                Ray::new(self.to_world * origin, self.to_world * -Vec3::Z)
            }
        }
    }
}

/// How far apart the points are that neighbouring pixels' samples see near a point, for
/// filtering textures: pbrt-v4's `CameraBase::Approximate_dp_dxy`, which stands in for ray
/// differentials carried along every path. The ray from the camera to the point, moved by one
/// pixel to the right or down (its direction for a perspective camera, its origin for an
/// orthographic one), meets the surface's plane that far from the point; the lens is ignored.
/// The distance is scaled by 1/sqrt(spp), since a pixel's samples spread over it. pbrt-v4 keeps
/// it at least 1/8; without that floor the filter narrows as the samples grow, so the image
/// converges to the unfiltered texture's, as a renderer that point-samples textures (Cycles)
/// does: at 256 samples per pixel the floor left DamagedHelmet at 128 x 128 (16 texels a pixel)
/// 0.001 of relative MSE further from Cycles' converged image than without mipmaps.
#[derive(Clone, Copy, Debug)]
pub struct PixelSpread {
    camera: Camera,
    /// 1/sqrt(spp).
    scale: f32,
}

impl PixelSpread {
    /// The spread for `camera` rendering `spp` samples per pixel.
    pub fn new(camera: &Camera, spp: u32) -> PixelSpread {
        PixelSpread { camera: *camera, scale: 1.0 / (spp.max(1) as f32).sqrt() }
    }

    /// dp/dx and dp/dy at the camera-relative point `p` of a surface with normal `n` (of any
    /// length): non-finite where the moved ray runs along the plane.
    #[inline]
    pub fn dp(&self, p: Vec3, n: Vec3) -> [Vec3; 2] {
        let c = &self.camera;
        let axes = [c.to_world.x_axis, c.to_world.y_axis];
        let step = match c.model {
            CameraModel::Perspective { tan_half_fov } => 2.0 * tan_half_fov / c.height,
            CameraModel::Orthographic { ymag } => 2.0 * ymag / c.height,
        };
        axes.map(|axis| {
            let moved = axis * step;
            let dp = match c.model {
                CameraModel::Perspective { .. } => {
                    let dir = p.normalize_or_zero() + moved;
                    dir * (n.dot(p) / n.dot(dir)) - p
                }
                CameraModel::Orthographic { .. } => {
                    let dir = -c.to_world.z_axis;
                    moved - dir * (n.dot(moved) / n.dot(dir))
                }
            };
            dp * self.scale
        })
    }
}

/// Where a ray leaving the camera lands on the film, and the camera's importance for it
/// (bidirectional path tracing's light tracing connects light paths to the camera this way).
#[derive(Clone, Copy, Debug)]
pub struct Importance {
    /// Film position in pixels.
    pub film: Vec2,
    /// The importance We (pbrt-v4's `PerspectiveCamera::We`: normalised so that it integrates
    /// to 1 over the whole image and the lens).
    pub we: f32,
    /// Density per solid angle of `generate_ray` choosing the direction, given the lens point.
    pub pdf_dir: f32,
}

impl Camera {
    /// Whether light paths can be connected to the camera: a perspective camera (pinhole or
    /// thin lens). An orthographic camera looks along one direction only, which no connection
    /// from a light path finds.
    pub fn connectable(&self) -> bool {
        matches!(self.model, CameraModel::Perspective { .. })
    }

    /// The lens's area (1 for a pinhole: a point, counted with density 1).
    pub fn lens_area(&self) -> f32 {
        if self.has_lens() {
            std::f32::consts::PI * self.aperture_radius * self.aperture_radius
        } else {
            1.0
        }
    }

    /// A point on the lens for lens numbers `u` (the same as `generate_ray` takes), world space.
    #[inline]
    pub fn lens_point(&self, u: Vec2) -> Vec3 {
        if !self.has_lens() {
            return Vec3::ZERO;
        }
        let l = sample_uniform_disk_concentric(u) * self.aperture_radius;
        self.to_world * Vec3::new(l.x, l.y, 0.0)
    }

    /// The film position, importance and direction density of a ray that leaves the lens at
    /// `origin` (world space, on the lens) along unit `dir`; `None` when it misses the film,
    /// points backward, or the camera is orthographic.
    #[inline]
    pub fn importance(&self, origin: Vec3, dir: Vec3) -> Option<Importance> {
        let CameraModel::Perspective { tan_half_fov } = self.model else { return None };
        let local = self.to_world.transpose() * dir;
        let cos = -local.z;
        if !(cos > 0.0) {
            return None;
        }
        // The point on the plane z = -1 of the pinhole ray through the same film position.
        let d = if self.has_lens() {
            let o = self.to_world.transpose() * origin;
            (o + local * (self.focus_distance / cos)) / self.focus_distance
        } else {
            local / cos
        };
        let aspect = self.width / self.height;
        let film = Vec2::new(
            (d.x / (tan_half_fov * aspect) + 1.0) * 0.5 * self.width,
            (1.0 - d.y / tan_half_fov) * 0.5 * self.height,
        );
        if !(film.x >= 0.0 && film.x < self.width && film.y >= 0.0 && film.y < self.height) {
            return None;
        }
        let area = 4.0 * tan_half_fov * tan_half_fov * aspect;
        let cos2 = cos * cos;
        Some(Importance {
            film,
            we: 1.0 / (area * self.lens_area() * cos2 * cos2),
            pdf_dir: 1.0 / (area * cos2 * cos),
        })
    }
}

/// A camera where it is at one sample's time: `camera` turned as it is then, and its lens
/// centre's position (camera-relative world) when it has moved off the origin. A camera that
/// does not move is the scene's camera with no offset, whose rays are `Camera`'s own bits.
#[derive(Clone, Copy, Debug)]
pub struct PlacedCamera {
    /// The camera, turned as it is at this time.
    pub camera: Camera,
    /// Where its lens centre is, for a camera that moves.
    pub origin: Option<Vec3>,
}

impl PlacedCamera {
    /// A camera that stays at the origin.
    pub fn still(camera: Camera) -> Self {
        PlacedCamera { camera, origin: None }
    }

    /// `Camera::generate_ray`, from where the camera is.
    #[inline]
    pub fn generate_ray(&self, film: Vec2, lens_u: Vec2) -> Ray {
        let r = self.camera.generate_ray(film, lens_u);
        match self.origin {
            Some(o) => Ray { origin: r.origin + o, ..r },
            None => r,
        }
    }

    /// `Camera::lens_point`, where the camera is.
    #[inline]
    pub fn lens_point(&self, u: Vec2) -> Vec3 {
        let p = self.camera.lens_point(u);
        self.origin.map_or(p, |o| p + o)
    }

    /// `Camera::importance` of a ray leaving the lens where the camera is.
    #[inline]
    pub fn importance(&self, origin: Vec3, dir: Vec3) -> Option<Importance> {
        self.camera.importance(self.origin.map_or(origin, |o| origin - o), dir)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(aperture: f32) -> Camera {
        Camera {
            to_world: Mat3::IDENTITY,
            model: CameraModel::Perspective { tan_half_fov: 0.5 },
            width: 200.0,
            height: 100.0,
            aperture_radius: aperture,
            focus_distance: 3.0,
        }
    }

    #[test]
    fn pixel_grid_follows_the_contract() {
        let cam = camera(0.0);
        let centre = cam.generate_ray(Vec2::new(100.0, 50.0), Vec2::ZERO);
        assert!((centre.dir - -Vec3::Z).length() < 1e-6);
        // Top-left corner: x = -tan * aspect, y = +tan (row 0 is the top).
        let corner = cam.generate_ray(Vec2::ZERO, Vec2::ZERO);
        let expect = Vec3::new(-1.0, 0.5, -1.0).normalize();
        assert!((corner.dir - expect).length() < 1e-6, "{:?}", corner.dir);
    }

    /// `importance` inverts `generate_ray` (the film position comes back), its direction density
    /// integrates to 1 over the image (midpoint rule over the film, dω = cos³ dA on the plane at
    /// distance 1), and We is that density over the lens area and the cosine.
    #[test]
    fn importance_inverts_generate_ray_and_integrates_to_one() {
        for aperture in [0.0, 0.2] {
            let cam = camera(aperture);
            for (film, lens) in [
                (Vec2::new(37.5, 81.25), Vec2::new(0.3, 0.8)),
                (Vec2::new(199.0, 1.0), Vec2::new(0.9, 0.1)),
            ] {
                let r = cam.generate_ray(film, lens);
                let imp = cam.importance(r.origin, r.dir).expect("on the film");
                assert!(
                    (imp.film - film).length() < 1e-3,
                    "{aperture}: {:?} for {film:?}",
                    imp.film
                );
                let cos = -r.dir.z;
                assert!((imp.we * cam.lens_area() * cos - imp.pdf_dir).abs() < 1e-5 * imp.pdf_dir);
            }
            assert!(cam.importance(Vec3::ZERO, Vec3::Z).is_none(), "behind the camera");
            let n = 400;
            let mut total = 0.0f64;
            let (half_w, half_h) = (0.5 * 2.0, 0.5);
            let cell = (2.0 * half_w / n as f64) * (2.0 * half_h / n as f64);
            for i in 0..n {
                for j in 0..n {
                    let x = -half_w + (i as f64 + 0.5) * 2.0 * half_w / n as f64;
                    let y = -half_h + (j as f64 + 0.5) * 2.0 * half_h / n as f64;
                    let d = Vec3::new(x as f32, y as f32, -1.0).normalize();
                    let pdf = camera(0.0).importance(Vec3::ZERO, d).expect("inside").pdf_dir as f64;
                    let cos = -d.z as f64;
                    total += pdf * cos * cos * cos * cell;
                }
            }
            assert!((total - 1.0).abs() < 1e-4, "the direction density integrates to {total}");
        }
    }

    #[test]
    fn thin_lens_rays_meet_in_the_focal_plane() {
        let cam = camera(0.2);
        let film = Vec2::new(37.5, 81.25);
        let pinhole = camera(0.0).generate_ray(film, Vec2::ZERO);
        let focus = pinhole.dir * (3.0 / -pinhole.dir.z);
        for u in [Vec2::new(0.1, 0.9), Vec2::new(0.5, 0.5), Vec2::new(0.99, 0.01)] {
            let r = cam.generate_ray(film, u);
            assert!(r.origin.z == 0.0 && r.origin.truncate().length() <= 0.2 + 1e-6);
            let t = -3.0 / r.dir.z;
            let p = r.origin + r.dir * t;
            assert!((p - focus).length() < 1e-4, "{p} vs {focus}");
        }
    }
}
