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
