//! Texture lookups: `KHR_texture_transform`, wrap modes, bilinear (or nearest) filtering, and the
//! sRGB decoding of colour textures (a table per 8-bit value; for 16-bit textures, one per
//! 16-bit value).

use std::sync::OnceLock;

use common::scene::{TexTransform, Texels, Texture, TextureRef, Wrap};
use glam::{Mat2, Vec2, Vec4};

/// 8-bit sRGB to linear, per value.
fn srgb_table() -> &'static [f32; 256] {
    static TABLE: OnceLock<[f32; 256]> = OnceLock::new();
    TABLE.get_or_init(|| {
        std::array::from_fn(|i| {
            let c = i as f32 / 255.0;
            if c <= 0.04045 {
                c / 12.92
            } else {
                ((c + 0.055) / 1.055).powf(2.4)
            }
        })
    })
}

/// 16-bit sRGB to linear, per value.
fn srgb_table16() -> &'static [f32] {
    static TABLE: OnceLock<Vec<f32>> = OnceLock::new();
    TABLE.get_or_init(|| {
        (0..=u16::MAX)
            .map(|i| {
                let c = i as f64 / 65535.0;
                (if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }) as f32
            })
            .collect()
    })
}

/// Applies a texture transform: uv' = offset + R * (scale * uv) with
/// R = [[cos, sin], [-sin, cos]] (rows): the rotation the extension's sample model
/// `TextureTransformTest` marks as correct.
#[inline]
pub fn transform_uv(t: &TexTransform, uv: Vec2) -> Vec2 {
    let (s, c) = t.rotation.sin_cos();
    let rotation = Mat2::from_cols(Vec2::new(c, -s), Vec2::new(s, c));
    t.offset + rotation * (t.scale * uv)
}

#[inline]
fn wrap(i: i64, n: u32, mode: Wrap) -> u32 {
    let n = n as i64;
    match mode {
        Wrap::Repeat => i.rem_euclid(n) as u32,
        Wrap::ClampToEdge => i.clamp(0, n - 1) as u32,
        Wrap::MirroredRepeat => {
            let period = 2 * n;
            let m = i.rem_euclid(period);
            (if m < n { m } else { period - 1 - m }) as u32
        }
    }
}

#[inline]
fn texel(tex: &Texture, x: u32, y: u32, srgb: bool) -> Vec4 {
    let i = (y * tex.width + x) as usize;
    match &tex.texels {
        Texels::Rgba8(texels) => to_linear(texels[i].map(u16::from), srgb_table(), 255.0, srgb),
        Texels::Rgba16(texels) => to_linear(texels[i], srgb_table16(), 65535.0, srgb),
    }
}

/// A texel's values of at most `max` as numbers in [0, 1]: RGB through the sRGB `table` for a
/// colour texture, alpha always linear.
#[inline]
fn to_linear(t: [u16; 4], table: &[f32], max: f32, srgb: bool) -> Vec4 {
    if srgb {
        Vec4::new(
            table[t[0] as usize],
            table[t[1] as usize],
            table[t[2] as usize],
            t[3] as f32 / max,
        )
    } else {
        Vec4::new(t[0] as f32, t[1] as f32, t[2] as f32, t[3] as f32) / max
    }
}

/// Filtered lookup at `uv` (texel centres at half-integers, v = 0 at the top row). Colour
/// textures (`srgb`) decode RGB to linear; alpha is always linear.
pub fn lookup(tex: &Texture, uv: Vec2, srgb: bool) -> Vec4 {
    if tex.width == 0 || tex.height == 0 || !uv.is_finite() {
        return Vec4::ONE;
    }
    let x = uv.x * tex.width as f32 - 0.5;
    let y = uv.y * tex.height as f32 - 0.5;
    if tex.nearest {
        let xi = wrap((x + 0.5).floor() as i64, tex.width, tex.wrap_s);
        let yi = wrap((y + 0.5).floor() as i64, tex.height, tex.wrap_t);
        return texel(tex, xi, yi, srgb);
    }
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let xs = [wrap(x0, tex.width, tex.wrap_s), wrap(x0 + 1, tex.width, tex.wrap_s)];
    let ys = [wrap(y0, tex.height, tex.wrap_t), wrap(y0 + 1, tex.height, tex.wrap_t)];
    let top = texel(tex, xs[0], ys[0], srgb).lerp(texel(tex, xs[1], ys[0], srgb), fx);
    let bottom = texel(tex, xs[0], ys[1], srgb).lerp(texel(tex, xs[1], ys[1], srgb), fx);
    top.lerp(bottom, fy)
}

/// Looks up a material's texture reference with the point's texture coordinate sets.
#[inline]
pub fn sample(textures: &[Texture], r: &TextureRef, uvs: [Vec2; 2], srgb: bool) -> Vec4 {
    let uv = uvs[(r.tex_coord as usize).min(1)];
    let uv = match &r.transform {
        Some(t) => transform_uv(t, uv),
        None => uv,
    };
    lookup(&textures[r.texture], uv, srgb)
}

/// Mean linear value of a texture (for light power estimates).
pub fn mean(tex: &Texture, srgb: bool) -> Vec4 {
    if tex.texels.is_empty() {
        return Vec4::ONE;
    }
    let mut sum = Vec4::ZERO;
    for y in 0..tex.height {
        for x in 0..tex.width {
            sum += texel(tex, x, y, srgb);
        }
    }
    sum / tex.texels.len() as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker() -> Texture {
        Texture {
            width: 2,
            height: 2,
            texels: vec![[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [255, 255, 255, 0]]
                .into(),
            wrap_s: Wrap::Repeat,
            wrap_t: Wrap::ClampToEdge,
            nearest: true,
        }
    }

    #[test]
    fn nearest_lookup_hits_texel_centres_top_row_first() {
        let t = checker();
        assert_eq!(lookup(&t, Vec2::new(0.25, 0.25), false), Vec4::new(1.0, 0.0, 0.0, 1.0));
        assert_eq!(lookup(&t, Vec2::new(0.75, 0.25), false), Vec4::new(0.0, 1.0, 0.0, 1.0));
        assert_eq!(lookup(&t, Vec2::new(0.25, 0.75), false), Vec4::new(0.0, 0.0, 1.0, 1.0));
        // Repeat along u, clamp along v.
        assert_eq!(
            lookup(&t, Vec2::new(1.25, 0.25), false),
            lookup(&t, Vec2::new(0.25, 0.25), false)
        );
        assert_eq!(
            lookup(&t, Vec2::new(0.25, 7.0), false),
            lookup(&t, Vec2::new(0.25, 0.75), false)
        );
    }

    #[test]
    fn bilinear_blends_and_srgb_decodes() {
        let mut t = checker();
        t.nearest = false;
        let mid = lookup(&t, Vec2::new(0.5, 0.25), false);
        assert!((mid - Vec4::new(0.5, 0.5, 0.0, 1.0)).length() < 1e-6);
        let grey =
            Texture { width: 1, height: 1, texels: vec![[188, 188, 188, 255]].into(), ..checker() };
        let v = lookup(&grey, Vec2::splat(0.5), true).x;
        assert!((v - 0.5029).abs() < 1e-3, "sRGB 188 is linear 0.503, got {v}");
    }

    /// 16-bit texels are read at 16 bits: linear values are value / 65535, colour values decode
    /// by the sRGB curve at that precision (agreeing with the 8-bit table where both have the
    /// value), and bilinear filtering blends them as it blends 8-bit ones.
    #[test]
    fn sixteen_bit_texels_keep_their_precision() {
        let t = Texture {
            width: 2,
            height: 1,
            texels: Texels::Rgba16(vec![[1, 32768, 65535, 0], [257 * 188, 0, 65535, 65535]].into()),
            ..checker()
        };
        let a = lookup(&t, Vec2::new(0.25, 0.5), false);
        assert_eq!(a, Vec4::new(1.0, 32768.0, 65535.0, 0.0) / 65535.0);
        let b = lookup(&t, Vec2::new(0.75, 0.5), true);
        assert!((b.x - srgb_table()[188]).abs() < 1e-6, "sRGB 188 x 257: {}", b.x);
        assert_eq!((b.z, b.w), (1.0, 1.0));
        let mut smooth = t.clone();
        smooth.nearest = false;
        let mid = lookup(&smooth, Vec2::new(0.5, 0.5), false);
        assert!((mid.w - 0.5).abs() < 1e-6 && (mid.y - 16384.0 / 65535.0).abs() < 1e-6, "{mid}");
        assert!(mean(&t, false).x > 0.0);
    }

    #[test]
    fn texture_transform_follows_the_extension() {
        let t = TexTransform {
            offset: Vec2::new(0.5, 0.0),
            rotation: std::f32::consts::FRAC_PI_2,
            scale: Vec2::new(2.0, 2.0),
        };
        // Scale (1, 0) -> (2, 0); rotate by 90 degrees -> (0, -2); offset -> (0.5, -2).
        let uv = transform_uv(&t, Vec2::new(1.0, 0.0));
        assert!((uv - Vec2::new(0.5, -2.0)).length() < 1e-5, "{uv}");
    }
}
