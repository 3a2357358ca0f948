//! The environment: a uniform colour or an equirectangular map (the direction convention is
//! `common::envmap`'s), optionally rotated about +y and scaled. Maps are importance-sampled in
//! proportion to texel luminance x sin(theta) (a piecewise-constant 2D distribution), so a
//! small bright sun is found by light sampling rather than by chance.

use std::f32::consts::PI;

use common::envmap::EnvMap;
use glam::{Vec2, Vec3};

use crate::render::sampling::{sample_uniform_sphere, uniform_sphere_pdf};

/// The environment seen by rays that leave the scene.
#[derive(Clone, Debug)]
pub enum Environment {
    /// The same radiance from every direction.
    Uniform(Vec3),
    /// An equirectangular map.
    Map(MapEnvironment),
}

/// An equirectangular map ready to evaluate and sample.
#[derive(Clone, Debug)]
pub struct MapEnvironment {
    width: u32,
    height: u32,
    /// Radiance per texel (intensity applied), row 0 at the top.
    texels: Vec<Vec3>,
    /// sin and cos of the rotation about +y.
    rotation: (f32, f32),
    /// Cumulative row weights, normalised, `height` entries ending at 1.
    row_cdf: Vec<f32>,
    /// Per row, cumulative texel weights, normalised; `width` entries per row.
    col_cdf: Vec<f32>,
    /// Row weights normalised to sum 1 (probability of each row).
    row_prob: Vec<f32>,
    /// Texel weights normalised within their row.
    col_prob: Vec<f32>,
}

#[inline]
fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

fn normalised_cdf(weights: &[f64]) -> (Vec<f32>, Vec<f32>) {
    let total: f64 = weights.iter().sum();
    let n = weights.len();
    if !(total > 0.0) {
        let p = 1.0 / n as f32;
        return ((1..=n).map(|i| i as f32 * p).collect(), vec![p; n]);
    }
    let mut acc = 0.0;
    let mut cdf = Vec::with_capacity(n);
    for w in weights {
        acc += w;
        cdf.push((acc / total) as f32);
    }
    *cdf.last_mut().expect("non-empty") = 1.0;
    (cdf, weights.iter().map(|w| (w / total) as f32).collect())
}

/// Index and remapped number for `u` in a cdf (the number stretched to [0, 1) within the bin).
#[inline]
fn pick(cdf: &[f32], prob: &[f32], u: f32) -> (usize, f32) {
    let i = cdf.partition_point(|&c| c <= u).min(cdf.len() - 1);
    let start = if i == 0 { 0.0 } else { cdf[i - 1] };
    let r = if prob[i] > 0.0 { (u - start) / prob[i] } else { 0.5 };
    (i, r.clamp(0.0, 1.0 - f32::EPSILON / 2.0))
}

impl MapEnvironment {
    /// Prepares `map` scaled by `intensity` and rotated by `rotation_deg` about +y.
    pub fn new(map: &EnvMap, intensity: f32, rotation_deg: f32) -> Self {
        let (w, h) = (map.width as usize, map.height as usize);
        let texels: Vec<Vec3> = map.texels.iter().map(|t| *t * intensity).collect();
        let mut row_weights = Vec::with_capacity(h);
        let mut col_cdf = Vec::with_capacity(w * h);
        let mut col_prob = Vec::with_capacity(w * h);
        for y in 0..h {
            let sin_theta = ((y as f64 + 0.5) / h as f64 * std::f64::consts::PI).sin();
            let weights: Vec<f64> = texels[y * w..(y + 1) * w]
                .iter()
                .map(|t| luminance(*t).max(0.0) as f64 * sin_theta)
                .collect();
            row_weights.push(weights.iter().sum::<f64>());
            let (cdf, prob) = normalised_cdf(&weights);
            col_cdf.extend(cdf);
            col_prob.extend(prob);
        }
        let (row_cdf, row_prob) = normalised_cdf(&row_weights);
        let rotation = rotation_deg.to_radians().sin_cos();
        MapEnvironment {
            width: map.width,
            height: map.height,
            texels,
            rotation,
            row_cdf,
            col_cdf,
            row_prob,
            col_prob,
        }
    }

    /// World direction -> map direction (undo the rotation about +y).
    #[inline]
    fn to_map(&self, d: Vec3) -> Vec3 {
        let (s, c) = self.rotation;
        Vec3::new(c * d.x - s * d.z, d.y, s * d.x + c * d.z)
    }

    /// Map direction -> world direction.
    #[inline]
    fn to_world(&self, d: Vec3) -> Vec3 {
        let (s, c) = self.rotation;
        Vec3::new(c * d.x + s * d.z, d.y, -s * d.x + c * d.z)
    }

    #[inline]
    fn texel_of(&self, d_map: Vec3) -> (usize, usize) {
        let (u, v) = EnvMap::direction_to_uv(d_map);
        let x = ((u * self.width as f32) as usize).min(self.width as usize - 1);
        let y = ((v * self.height as f32) as usize).min(self.height as usize - 1);
        (x, y)
    }

    /// Radiance arriving from world direction `d` (unit), nearest texel.
    #[inline]
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        let (x, y) = self.texel_of(self.to_map(d));
        self.texels[y * self.width as usize + x]
    }

    /// Density per solid angle of `sample` choosing world direction `d`.
    #[inline]
    pub fn pdf(&self, d: Vec3) -> f32 {
        let d_map = self.to_map(d);
        let (x, y) = self.texel_of(d_map);
        // sqrt(x² + z²) rather than sqrt(1 - y²): exact near the poles.
        let sin_theta = (d_map.x * d_map.x + d_map.z * d_map.z).sqrt();
        if sin_theta <= 0.0 {
            return 0.0;
        }
        let pdf_uv = self.row_prob[y]
            * self.col_prob[y * self.width as usize + x]
            * (self.width * self.height) as f32;
        pdf_uv / (2.0 * PI * PI * sin_theta)
    }

    /// Samples a direction: (world direction, radiance, density per solid angle).
    #[inline]
    pub fn sample(&self, u: Vec2) -> Option<(Vec3, Vec3, f32)> {
        let (y, ry) = pick(&self.row_cdf, &self.row_prob, u.y);
        let w = self.width as usize;
        let (x, rx) =
            pick(&self.col_cdf[y * w..(y + 1) * w], &self.col_prob[y * w..(y + 1) * w], u.x);
        let uu = (x as f32 + rx) / self.width as f32;
        let vv = (y as f32 + ry) / self.height as f32;
        let d_map = EnvMap::uv_to_direction(uu, vv);
        let sin_theta = (vv * PI).sin();
        if !(sin_theta > 0.0) {
            return None;
        }
        let pdf_uv =
            self.row_prob[y] * self.col_prob[y * w + x] * (self.width * self.height) as f32;
        let pdf = pdf_uv / (2.0 * PI * PI * sin_theta);
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        Some((self.to_world(d_map), self.texels[y * w + x], pdf))
    }

    /// Mean radiance luminance over the sphere (for choosing between lights).
    pub fn mean_luminance(&self) -> f32 {
        let (w, h) = (self.width as usize, self.height as usize);
        let mut sum = 0.0f64;
        let mut weight = 0.0f64;
        for y in 0..h {
            let s = ((y as f64 + 0.5) / h as f64 * std::f64::consts::PI).sin();
            for t in &self.texels[y * w..(y + 1) * w] {
                sum += luminance(*t) as f64 * s;
                weight += s;
            }
        }
        (sum / weight.max(1e-30)) as f32
    }
}

impl Environment {
    /// Radiance arriving from world direction `d`.
    #[inline]
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        match self {
            Environment::Uniform(c) => *c,
            Environment::Map(m) => m.radiance(d),
        }
    }

    /// Density per solid angle of `sample` choosing `d`.
    #[inline]
    pub fn pdf(&self, d: Vec3) -> f32 {
        match self {
            Environment::Uniform(_) => uniform_sphere_pdf(),
            Environment::Map(m) => m.pdf(d),
        }
    }

    /// Samples a direction: (direction, radiance, density per solid angle).
    #[inline]
    pub fn sample(&self, u: Vec2) -> Option<(Vec3, Vec3, f32)> {
        match self {
            Environment::Uniform(c) => Some((sample_uniform_sphere(u), *c, uniform_sphere_pdf())),
            Environment::Map(m) => m.sample(u),
        }
    }

    /// Mean luminance over the sphere.
    pub fn mean_luminance(&self) -> f32 {
        match self {
            Environment::Uniform(c) => luminance(*c),
            Environment::Map(m) => m.mean_luminance(),
        }
    }
}
