//! Environment maps: equirectangular Radiance HDR (`.hdr`) or OpenEXR (`.exr`) images decoded
//! into linear RGB, with the direction convention every part of the renderer shares.
//!
//! Convention: +y is up; the image's top row looks straight up and its bottom row straight
//! down; its centre column looks along -z, and u grows toward +x (a viewer standing at the
//! origin facing -z sees the middle of the panorama, with +x to the right).

use std::path::Path;

use glam::Vec3;

/// A decoded equirectangular map, row 0 at the top.
#[derive(Clone, Debug)]
pub struct EnvMap {
    /// Width in texels (the full 360 degrees).
    pub width: u32,
    /// Height in texels (180 degrees).
    pub height: u32,
    /// Linear RGB radiance, row-major.
    pub texels: Vec<Vec3>,
}

/// Why an environment map could not be read.
#[derive(Debug, thiserror::Error)]
#[error("environment map {path}: {reason}")]
pub struct EnvMapError {
    /// The file.
    pub path: String,
    /// What went wrong.
    pub reason: String,
}

/// Largest accepted map (texels), to refuse absurd files before allocating for them.
pub const MAX_TEXELS: u64 = 1 << 26;

impl EnvMap {
    /// Reads `.hdr` or `.exr` (recognised from the bytes).
    pub fn load(path: &Path) -> Result<EnvMap, EnvMapError> {
        let bytes = std::fs::read(path)
            .map_err(|e| EnvMapError { path: path.display().to_string(), reason: e.to_string() })?;
        Self::from_bytes(&path.display().to_string(), &bytes)
    }

    /// Decodes `.hdr` or `.exr` bytes (recognised from the bytes); `name` appears in errors.
    pub fn from_bytes(name: &str, bytes: &[u8]) -> Result<EnvMap, EnvMapError> {
        let fail = |reason: String| EnvMapError { path: name.to_string(), reason };
        let map = if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
            decode_exr(bytes)
        } else if bytes.starts_with(b"#?") {
            decode_hdr(bytes)
        } else {
            Err("not a Radiance HDR or OpenEXR file".to_string())
        }
        .map_err(fail)?;
        map.validate().map_err(fail)?;
        Ok(map)
    }

    fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err("empty image".into());
        }
        if self.texels.iter().any(|t| !t.is_finite() || t.min_element() < 0.0) {
            return Err("texels must be finite and non-negative".into());
        }
        Ok(())
    }

    /// Texture coordinates (u, v) in [0, 1)² of direction `d` (unit).
    #[inline]
    pub fn direction_to_uv(d: Vec3) -> (f32, f32) {
        let u = 0.5 + d.x.atan2(-d.z) * (0.5 * std::f32::consts::FRAC_1_PI);
        let v = d.y.clamp(-1.0, 1.0).acos() * std::f32::consts::FRAC_1_PI;
        (u.rem_euclid(1.0), v.min(1.0 - f32::EPSILON / 2.0))
    }

    /// The direction at texture coordinates (u, v), inverse of `direction_to_uv`.
    #[inline]
    pub fn uv_to_direction(u: f32, v: f32) -> Vec3 {
        let phi = (u - 0.5) * 2.0 * std::f32::consts::PI;
        let theta = v * std::f32::consts::PI;
        let (sin_t, cos_t) = theta.sin_cos();
        let (sin_p, cos_p) = phi.sin_cos();
        Vec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p)
    }
}

fn decode_hdr(bytes: &[u8]) -> Result<EnvMap, String> {
    let image = image::load_from_memory_with_format(bytes, image::ImageFormat::Hdr)
        .map_err(|e| e.to_string())?;
    let (width, height) = (image.width(), image.height());
    if width as u64 * height as u64 > MAX_TEXELS {
        return Err(format!("{width}x{height} is larger than {MAX_TEXELS} texels"));
    }
    let rgb = image.into_rgb32f();
    let texels = rgb.pixels().map(|p| Vec3::new(p[0], p[1], p[2])).collect();
    Ok(EnvMap { width, height, texels })
}

fn decode_exr(bytes: &[u8]) -> std::result::Result<EnvMap, String> {
    let (width, height, texels) = read_exr_rgb(bytes, MAX_TEXELS)?;
    Ok(EnvMap { width: width as u32, height: height as u32, texels })
}

/// The `R`, `G`, `B` channels of the first layer of an OpenEXR file, row-major from the top:
/// (width, height, texels). Refuses images over `max_texels`.
pub fn read_exr_rgb(
    bytes: &[u8],
    max_texels: u64,
) -> std::result::Result<(usize, usize, Vec<Vec3>), String> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| e.to_string())?;
    let layer = &image.layer_data;
    let (width, height) = (layer.size.width(), layer.size.height());
    if width as u64 * height as u64 > max_texels {
        return Err(format!("{width}x{height} is larger than {max_texels} texels"));
    }
    let channel = |name: &str| -> std::result::Result<Vec<f32>, String> {
        layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == name)
            .map(|c| c.sample_data.values_as_f32().collect())
            .ok_or_else(|| format!("no {name} channel"))
    };
    let (r, g, b) = (channel("R")?, channel("G")?, channel("B")?);
    let texels = (0..width * height).map(|i| Vec3::new(r[i], g[i], b[i])).collect();
    Ok((width, height, texels))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uv_and_directions_round_trip_and_follow_the_convention() {
        let (u, v) = EnvMap::direction_to_uv(-Vec3::Z);
        assert!((u - 0.5).abs() < 1e-6 && (v - 0.5).abs() < 1e-6, "-z is the centre");
        let (u, _) = EnvMap::direction_to_uv(Vec3::X);
        assert!((u - 0.75).abs() < 1e-6, "+x is right of centre");
        let (_, v) = EnvMap::direction_to_uv(Vec3::Y);
        assert!(v < 1e-6, "+y is the top row");
        for (u, v) in [(0.1f32, 0.2f32), (0.5, 0.5), (0.9, 0.95), (0.3, 0.01)] {
            let (u2, v2) = EnvMap::direction_to_uv(EnvMap::uv_to_direction(u, v));
            assert!((u - u2).abs() < 1e-5 && (v - v2).abs() < 1e-5, "({u}, {v}) -> ({u2}, {v2})");
        }
    }

    #[test]
    fn the_shipped_studio_map_loads() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/assets/real/environments/studio_small_05_1k.hdr");
        let map = EnvMap::load(&path).unwrap();
        assert_eq!((map.width, map.height), (1024, 512));
        assert!(map.texels.iter().any(|t| t.max_element() > 1.0), "HDR values above 1");
    }

    #[test]
    fn bad_files_are_refused_with_the_path() {
        let dir = std::env::temp_dir().join(format!("envmap-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("sky.hdr");
        std::fs::write(&path, b"#?RADIANCE\ngarbage").unwrap();
        let e = EnvMap::load(&path).unwrap_err().to_string();
        assert!(e.contains("sky.hdr"), "{e}");
        std::fs::write(&path, b"hello").unwrap();
        assert!(EnvMap::load(&path).unwrap_err().to_string().contains("not a Radiance HDR"));
        assert!(EnvMap::load(&dir.join("missing.hdr")).is_err());
    }
}
