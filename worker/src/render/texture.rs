//! Texture lookups: `KHR_texture_transform`, wrap modes, bilinear (or nearest) filtering, and the
//! sRGB decoding of colour textures (a table per 8-bit value; for 16-bit textures, one per
//! 16-bit value).
//!
//! Mipmaps: a texture whose sampler asks for them gets levels, each half the last's size, whose
//! texels are area averages of the last's in linear values (so every level keeps the texture's
//! mean), stored in the texture's own format. A lookup with a footprint (the width in texture
//! coordinates that one pixel's share of the samples covers there, `SurfacePoint::footprint`)
//! blends the two levels whose texels are nearest that width (trilinear filtering, pbrt-v4's
//! `MIPMap::Filter` with `Trilinear`); a footprint below one texel of the full texture reads it
//! bilinearly as before.

use std::sync::{Mutex, OnceLock};

use common::{
    scene::{TexTransform, Texels, Texture, TextureRef, Wrap},
    spread::{Job, Spread},
};
use glam::{Mat2, Vec2, Vec4};

use crate::spread::Threads;

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

/// Looks up a material's texture reference at texture coordinate sets `uvs`, filtered over
/// the footprint `footprint` of each set (`SurfacePoint::footprint`), scaled as the texture
/// transform scales the set.
#[inline]
pub fn sample(
    textures: &[Texture],
    r: &TextureRef,
    uvs: [Vec2; 2],
    footprint: [f32; 2],
    srgb: bool,
) -> Vec4 {
    let set = (r.tex_coord as usize).min(1);
    let (uv, width) = match &r.transform {
        Some(t) => (transform_uv(t, uvs[set]), footprint[set] * t.scale.abs().max_element()),
        None => (uvs[set], footprint[set]),
    };
    filtered(&textures[r.texture], uv, width, srgb)
}

/// Trilinear lookup at `uv` over a footprint `width` wide in texture coordinates: the bilinear
/// lookups of the two levels between which a texel is that wide, blended by where it falls
/// (`lookup` itself below one texel, or where the texture has no levels).
#[inline]
pub fn filtered(tex: &Texture, uv: Vec2, width: f32, srgb: bool) -> Vec4 {
    let texels = width * tex.width.max(tex.height) as f32;
    // Also for a NaN width.
    if tex.levels.is_empty() || !(texels > 1.0) {
        return lookup(tex, uv, srgb);
    }
    let level = texels.log2();
    let last = tex.levels.len();
    if level >= last as f32 {
        return lookup(&tex.levels[last - 1], uv, srgb);
    }
    let fine = level as usize; // Below `last`: the level's integer part.
    let coarse = &tex.levels[fine];
    let fine = if fine == 0 { tex } else { &tex.levels[fine - 1] };
    lookup(fine, uv, srgb).lerp(lookup(coarse, uv, srgb), level.fract())
}

/// How a filtered lookup decodes a texture: its RGB as sRGB colour or as linear values, or only
/// its alpha (linear either way).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Decode {
    /// RGB as sRGB colour.
    Colour,
    /// RGB as linear values.
    Linear,
    /// Only the alpha channel.
    Alpha,
}

/// Builds the mip levels (`build_levels`) of every texture in `textures` that asks for them and
/// that `uses` reads through a footprint (texture index, decoding:
/// `material::filtered_textures`), on every core; whether any texture has levels then. A
/// texture read both as colour and as linear values gets none (its levels would hold one
/// decoding's averages); alpha is linear in both.
pub fn add_levels(
    textures: &mut [Texture],
    uses: impl IntoIterator<Item = (usize, Decode)>,
) -> bool {
    // Per texture: not read, read as `Some(srgb)`, or read both ways (`Some(None)`).
    let mut decodes: Vec<Option<Option<bool>>> = vec![None; textures.len()];
    for (t, d) in uses {
        let srgb = match d {
            Decode::Colour => Some(true),
            Decode::Linear => Some(false),
            Decode::Alpha => None,
        };
        let Some(slot) = decodes.get_mut(t) else { continue };
        *slot = Some(match (*slot, srgb) {
            (None, s) => Some(s.unwrap_or(false)),
            (Some(None), _) => None,
            (Some(Some(was)), Some(s)) if was != s => None,
            (Some(Some(was)), _) => Some(was),
        });
    }
    let mut jobs: Vec<(usize, bool)> = decodes
        .iter()
        .enumerate()
        .filter_map(|(t, d)| Some((t, (*d)??)))
        .filter(|&(t, _)| {
            let tex = &textures[t];
            tex.mipmaps && tex.levels.is_empty() && tex.width.max(tex.height) > 1
        })
        .collect();
    if jobs.is_empty() {
        return textures.iter().any(|t| !t.levels.is_empty());
    }
    // The largest first, so that the threads finish together.
    jobs.sort_by_key(|&(t, _)| std::cmp::Reverse(textures[t].texels.len()));
    let built: Vec<Mutex<Vec<Texture>>> = jobs.iter().map(|_| Mutex::default()).collect();
    let work: Vec<Job<'_>> = jobs
        .iter()
        .zip(&built)
        .map(|(&(t, srgb), out)| {
            let tex = &textures[t];
            Box::new(move || {
                *out.lock().unwrap_or_else(|p| p.into_inner()) = build_levels(tex, srgb)
            }) as Job<'_>
        })
        .collect();
    Threads::available().run(work);
    for ((t, _), levels) in jobs.into_iter().zip(built) {
        textures[t].levels = levels.into_inner().unwrap_or_else(|p| p.into_inner());
    }
    true
}

/// The mip levels of `tex` past the first (`Texture::levels`), for lookups that decode it as
/// `srgb` says: each is the last halved (rounded down, at least 1) along each axis, each texel
/// the area-weighted mean of the last's texels it covers, in linear values, then stored in the
/// texture's format (the nearest sRGB or linear value). Level 1 of a 2048 x 2048 texture is
/// 1024 x 1024, and so on down to 1 x 1.
pub fn build_levels(tex: &Texture, srgb: bool) -> Vec<Texture> {
    let mut levels: Vec<Texture> = Vec::new();
    if tex.texels.is_empty() {
        return levels;
    }
    loop {
        let last = levels.last().unwrap_or(tex);
        if last.width <= 1 && last.height <= 1 {
            return levels;
        }
        let next = downsample(last, srgb);
        levels.push(next);
    }
}

/// For each of `to` texels along an axis of `from`: the texels of `from` it covers and the share
/// of its width each covers (summing to 1).
fn spans(from: u32, to: u32) -> Vec<Vec<(u32, f32)>> {
    let scale = from as f64 / to as f64;
    (0..to)
        .map(|i| {
            let (lo, hi) = (i as f64 * scale, (i + 1) as f64 * scale);
            (lo.floor() as u32..(hi.ceil() as u32).min(from))
                .map(|j| {
                    let cover = hi.min(j as f64 + 1.0) - lo.max(j as f64);
                    (j, (cover / scale) as f32)
                })
                .filter(|&(_, w)| w > 0.0)
                .collect()
        })
        .collect()
}

/// `tex` halved along each axis (rounded down, at least 1), by area, in linear values: row by
/// row, the source rows an output row covers summed by their weights, then across.
fn downsample(tex: &Texture, srgb: bool) -> Texture {
    let (width, height) = ((tex.width / 2).max(1), (tex.height / 2).max(1));
    match &tex.texels {
        Texels::Rgba8(t) if tex.width % 2 == 0 && tex.height % 2 == 0 => {
            let texels = Texels::Rgba8(halve8(t, tex.width as usize, srgb).into());
            Texture {
                width,
                height,
                texels,
                mipmaps: false,
                levels: Vec::new(),
                nearest: false,
                ..*tex
            }
        }
        _ => downsample_area(tex, srgb),
    }
}

/// `downsample` for any size and format.
fn downsample_area(tex: &Texture, srgb: bool) -> Texture {
    let (width, height) = ((tex.width / 2).max(1), (tex.height / 2).max(1));
    let (xs, ys) = (spans(tex.width, width), spans(tex.height, height));
    let mut rows = vec![Vec4::ZERO; tex.width as usize];
    let mut means = Vec::with_capacity(width as usize * height as usize);
    for row in &ys {
        rows.fill(Vec4::ZERO);
        for &(y, wy) in row {
            let start = y as usize * tex.width as usize;
            let end = start + tex.width as usize;
            match &tex.texels {
                Texels::Rgba8(t) => {
                    for (sum, t) in rows.iter_mut().zip(&t[start..end]) {
                        *sum += to_linear(t.map(u16::from), srgb_table(), 255.0, srgb) * wy;
                    }
                }
                Texels::Rgba16(t) => {
                    for (sum, t) in rows.iter_mut().zip(&t[start..end]) {
                        *sum += to_linear(*t, srgb_table16(), 65535.0, srgb) * wy;
                    }
                }
            }
        }
        for column in &xs {
            means.push(column.iter().fold(Vec4::ZERO, |sum, &(x, wx)| sum + rows[x as usize] * wx));
        }
    }
    let texels = match &tex.texels {
        Texels::Rgba8(_) => {
            let (table, inverse) = (srgb_table(), inverse_table(srgb_table()));
            let encode = |m: &Vec4| encode(*m, table, inverse, srgb).map(|v| v as u8);
            Texels::Rgba8(means.iter().map(encode).collect())
        }
        Texels::Rgba16(_) => {
            let (table, inverse) = (srgb_table16(), inverse_table(srgb_table16()));
            Texels::Rgba16(means.iter().map(|m| encode(*m, table, inverse, srgb)).collect())
        }
    };
    Texture { width, height, texels, mipmaps: false, levels: Vec::new(), nearest: false, ..*tex }
}

/// The common case of `downsample`, 8-bit texels and even sizes: each texel the mean of a 2 x 2
/// block in linear values, its RGB encoded by one comparison (`encode8`).
fn halve8(texels: &[[u8; 4]], width: usize, srgb: bool) -> Vec<[u8; 4]> {
    let (table, inverse) = (srgb_table(), inverse_table(srgb_table()));
    let mut out = Vec::with_capacity(texels.len() / 4);
    for rows in texels.chunks_exact(2 * width) {
        let (top, bottom) = rows.split_at(width);
        for (t, b) in top.chunks_exact(2).zip(bottom.chunks_exact(2)) {
            let block = [t[0], t[1], b[0], b[1]];
            // Linear values: the sum's quarter, ties to even, in integers.
            let linear = |c: usize| {
                let sum: u32 = block.iter().map(|p| p[c] as u32).sum();
                let (q, r) = (sum >> 2, sum & 3);
                (q + u32::from(r > 2 || (r == 2 && q & 1 == 1))) as u8
            };
            let colour = |c: usize| {
                let sum: f32 = block.iter().map(|p| table[p[c] as usize]).sum();
                encode8(sum * 0.25, table, inverse)
            };
            let rgb = |c: usize| if srgb { colour(c) } else { linear(c) };
            out.push([rgb(0), rgb(1), rgb(2), linear(3)]);
        }
    }
    out
}

/// The 8-bit sRGB value whose decoding is nearest the linear `v` (the lower on ties): the
/// `inverse` table's cells are narrower than the table's steps, so it is the cell's first value
/// at or above the cell's start, or one of its neighbours.
#[inline]
fn encode8(v: f32, table: &[f32; 256], inverse: &[u16]) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let i = inverse[(v * (inverse.len() - 1) as f32) as usize] as usize;
    let mut best = i;
    if i > 0 && v - table[i - 1] <= table[i] - v {
        best = i - 1;
    } else if i < 255 && table[i + 1] - v < v - table[i] {
        best = i + 1;
    }
    best as u8
}

/// For each cell of [0, 1] (4,096 for the 8-bit table, narrower than its smallest step, 2^16
/// for the 16-bit one), the first stored value whose sRGB decoding (`table`) is at least the
/// cell's start: where `encode` starts its search. Built once per table.
fn inverse_table(table: &'static [f32]) -> &'static [u16] {
    static EIGHT: OnceLock<Vec<u16>> = OnceLock::new();
    static SIXTEEN: OnceLock<Vec<u16>> = OnceLock::new();
    let (cell, cells) = if table.len() <= 256 { (&EIGHT, 1 << 12) } else { (&SIXTEEN, 1 << 16) };
    cell.get_or_init(|| {
        let mut next = 0;
        (0..cells)
            .map(|i| {
                let start = i as f32 / (cells - 1) as f32;
                while next + 1 < table.len() && table[next] < start {
                    next += 1;
                }
                next as u16
            })
            .collect()
    })
}

/// The stored values (at most `table.len() - 1`) nearest a linear texel: RGB through the sRGB
/// `table` for a colour texture (the value whose decoding is nearest, found from the `inverse`
/// table's guess), alpha always linear.
fn encode(linear: Vec4, table: &[f32], inverse: &[u16], srgb: bool) -> [u16; 4] {
    let max = (table.len() - 1) as f32;
    // Ties to even: a mean of four stored values is often halfway, and rounding those up
    // would brighten every level by an eighth of a step.
    let plain = |v: f32| (v.clamp(0.0, 1.0) * max).round_ties_even() as u16;
    let nearest = |v: f32| {
        let v = v.clamp(0.0, 1.0);
        let mut i = inverse[(v * (inverse.len() - 1) as f32) as usize] as usize;
        while i + 1 < table.len() && table[i + 1] - v < v - table[i] {
            i += 1;
        }
        while i > 0 && v - table[i - 1] <= table[i] - v {
            i -= 1;
        }
        i as u16
    };
    let rgb = |v: f32| if srgb { nearest(v) } else { plain(v) };
    [rgb(linear.x), rgb(linear.y), rgb(linear.z), plain(linear.w)]
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
            mipmaps: false,
            levels: Vec::new(),
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

    /// A `width` x `height` texture of pseudo-random 8- or 16-bit texels.
    fn noise(width: u32, height: u32, sixteen: bool) -> Texture {
        let mut state = 0x9e37_79b9_u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let n = (width * height) as usize;
        let texels = if sixteen {
            Texels::Rgba16((0..n).map(|_| [0; 4].map(|_: u16| next() as u16)).collect())
        } else {
            Texels::Rgba8((0..n).map(|_| [0; 4].map(|_: u8| next() as u8)).collect())
        };
        Texture { width, height, texels, nearest: false, mipmaps: true, ..checker() }
    }

    /// Every level halves the last (rounded down, at least 1) down to 1 x 1, and keeps the
    /// texture's mean in linear values, colour or not, 8 or 16 bits, for even and odd sizes: the
    /// area weights cover every texel once, and only each texel's rounding to its format's
    /// nearest value is left. That rounding is uniform over a step (variance step² / 12 per
    /// texel, the step in linear values at most 2.5 / 255 for 8-bit sRGB), so the mean of a level
    /// of n texels moves by at most 5 standard deviations, sqrt(step² / 12 / n), summed in
    /// variance over the levels so far.
    #[test]
    fn mip_levels_halve_the_size_and_keep_the_mean() {
        for (width, height, sixteen) in
            [(64, 64, false), (37, 23, false), (5, 40, true), (1, 9, false)]
        {
            let tex = noise(width, height, sixteen);
            for srgb in [false, true] {
                let levels = build_levels(&tex, srgb);
                let mean = super::mean(&tex, srgb);
                let step = if sixteen { 1.0 / 65535.0 } else { 1.0 / 255.0 };
                let step = if srgb { 2.5 * step } else { step };
                let (mut w, mut h, mut variance) = (width, height, 0.0);
                for level in &levels {
                    (w, h) = ((w / 2).max(1), (h / 2).max(1));
                    assert_eq!((level.width, level.height), (w, h));
                    assert_eq!(level.texels.len(), (w * h) as usize);
                    variance += step * step / 12.0 / (w * h) as f32;
                    let m = super::mean(level, srgb);
                    let off = (m - mean).abs().max_element();
                    let bound = 5.0 * variance.sqrt();
                    assert!(
                        off < bound,
                        "{width}x{height} srgb {srgb} {w}x{h}: {m} against {mean} (bound {bound})"
                    );
                }
                assert_eq!((w, h), (1, 1), "{width}x{height}: the last level is 1 x 1");
            }
        }
    }

    /// A black and white checker of single texels, a colour texture: level 1 is grey of linear
    /// 0.5 (sRGB 188), not the sRGB mean 127.5 (linear 0.21) that averaging stored values gives.
    #[test]
    fn colour_levels_average_linear_light() {
        let texels =
            (0..16 * 16).map(|i| if (i % 16 + i / 16) % 2 == 0 { [0; 4] } else { [255; 4] });
        let tex = Texture {
            width: 16,
            height: 16,
            texels: Texels::Rgba8(texels.collect()),
            mipmaps: true,
            ..checker()
        };
        let levels = build_levels(&tex, true);
        assert_eq!(levels.len(), 4);
        for level in &levels {
            let t = level.texels.rgba8().expect("8 bits");
            assert!(t.iter().all(|&t| t == [188, 188, 188, 128]), "{t:?}");
        }
    }

    /// The filtered lookup reads the full-size texture bit for bit below one texel of footprint
    /// (and with no levels, or a NaN width), one level exactly at a power of two texels, blends
    /// two levels between, and reads the last level beyond the texture's size.
    #[test]
    fn filtered_lookups_choose_levels_by_the_footprint() {
        let mut tex = noise(32, 16, false);
        let uv = Vec2::new(0.37, 0.61);
        let plain = lookup(&tex, uv, true);
        assert_eq!(filtered(&tex, uv, 0.5, true), plain, "no levels");
        tex.levels = build_levels(&tex, true);
        assert_eq!(tex.levels.len(), 5);
        for width in [0.0, 1.0 / 64.0, 1.0 / 32.0, f32::NAN, -1.0] {
            assert_eq!(filtered(&tex, uv, width, true), plain, "width {width}");
        }
        // 32 texels wide: a footprint of 4 / 32 is 4 texels, level 2.
        assert_eq!(filtered(&tex, uv, 4.0 / 32.0, true), lookup(&tex.levels[1], uv, true));
        let between = filtered(&tex, uv, 2.0f32.powf(2.5) / 32.0, true);
        let expected = lookup(&tex.levels[1], uv, true).lerp(lookup(&tex.levels[2], uv, true), 0.5);
        assert!((between - expected).abs().max_element() < 1e-5, "{between} against {expected}");
        let last = lookup(&tex.levels[4], uv, true);
        assert_eq!(filtered(&tex, uv, 1.0, true), last);
        assert_eq!(filtered(&tex, uv, 1e9, true), last);
        assert_eq!(filtered(&tex, uv, f32::INFINITY, true), last);
    }

    /// Only textures that ask for mipmaps and that a material reads through a footprint get
    /// levels: not one whose sampler says LINEAR, not one read only as emission, and not one
    /// read both as colour and as linear values.
    #[test]
    fn levels_are_built_for_filtered_textures_only() {
        use common::scene::{Material, TextureRef};
        let r = |texture| Some(TextureRef { texture, tex_coord: 0, transform: None });
        let mut textures = vec![noise(8, 8, false); 5];
        textures[1].mipmaps = false;
        let material = Material {
            base_color_texture: r(0),
            metallic_roughness_texture: r(1),
            emissive_texture: r(2),
            specular_color_texture: r(3),
            transmission_texture: r(3),
            normal_texture: r(4).map(|r| (r, 1.0)),
            ..Material::default()
        };
        let mut uses = Vec::new();
        crate::render::material::filtered_textures(&material, |t, d| uses.push((t, d)));
        assert!(add_levels(&mut textures, uses));
        let built: Vec<bool> = textures.iter().map(|t| !t.levels.is_empty()).collect();
        assert_eq!(built, [true, false, false, false, true]);
        let mut plain = vec![noise(8, 8, false)];
        assert!(!add_levels(&mut plain, []), "no material reads it");
    }

    /// The fast halving of even-sized 8-bit textures stores what the general area filter
    /// stores, within one step (the two sum the same four values in another order).
    #[test]
    fn the_even_halving_agrees_with_the_area_filter() {
        let tex = noise(64, 32, false);
        for srgb in [false, true] {
            let fast = downsample(&tex, srgb);
            let area = downsample_area(&tex, srgb);
            let (fast, area) = (fast.texels.rgba8().unwrap(), area.texels.rgba8().unwrap());
            assert_eq!(fast.len(), area.len());
            for (f, a) in fast.iter().zip(area) {
                assert!(f.iter().zip(a).all(|(&f, &a)| f.abs_diff(a) <= 1), "{f:?} {a:?}");
            }
        }
    }

    /// `encode8` and `encode` find the stored value whose decoding is nearest, as a search over
    /// every value does (the lower on ties), at and between every table value.
    #[test]
    fn encoding_finds_the_nearest_stored_value() {
        let table = srgb_table();
        let inverse = inverse_table(table);
        let nearest = |v: f32| {
            let distance = |i: usize| (table[i] - v.clamp(0.0, 1.0)).abs();
            (0..256).fold(0, |best, i| if distance(i) < distance(best) { i } else { best })
        };
        let probes = (0..256).flat_map(|i| {
            let t = table[i];
            let next = table[(i + 1).min(255)];
            [t, t + (next - t) * 0.25, (t + next) * 0.5, t + (next - t) * 0.75, next.next_down()]
        });
        for v in probes.chain([-1.0, 0.0, 1.0, 2.0, 1e-7]) {
            let want = nearest(v);
            assert_eq!(encode8(v, table, inverse) as usize, want, "{v}");
            let v4 = Vec4::new(v, v, v, 0.0);
            assert_eq!(encode(v4, table, inverse, true)[0] as usize, want, "{v}");
        }
    }
}
