//! Writing a frame: the OpenEXR file of PRODUCT.md (`R`, `G`, `B`, `variance.R/G/B`, `samples`,
//! header attributes) and a PNG preview (exposure + sRGB transfer) beside it.

use std::path::Path;

use anyhow::{Context, Result};
use common::film::{ErrorEstimate, Film, TileAccum};
use exr::prelude::*;

/// Metadata written into the EXR header, one text attribute each.
#[derive(Clone, Debug, Default)]
pub struct FrameInfo {
    /// The render settings as JSON.
    pub settings_json: String,
    /// SHA-256 of the scene file, hex.
    pub scene_hash: String,
    /// Wall-clock seconds spent rendering.
    pub render_seconds: f64,
    /// Frame number.
    pub frame: i64,
}

/// What a frame's files hold, per pixel: mean, variance of the mean, sample count (28 bytes a
/// pixel, a third of the merged statistics it is read from).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Mean radiance per channel, row-major.
    pub mean: [Vec<f32>; 3],
    /// Variance of the mean per channel (infinite below two samples).
    pub variance: [Vec<f32>; 3],
    /// Samples per pixel.
    pub samples: Vec<u32>,
    /// Refused samples.
    pub rejected: u64,
    /// Sum over pixels of the estimated relative MSE (see `ErrorEstimate`).
    rel_mse_sum: f64,
}

impl FrameImage {
    /// A black image with no samples.
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        FrameImage {
            width,
            height,
            mean: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
            variance: [vec![f32::INFINITY; n], vec![f32::INFINITY; n], vec![f32::INFINITY; n]],
            samples: vec![0; n],
            rejected: 0,
            rel_mse_sum: 0.0,
        }
    }

    /// Writes a tile's pixels (the tile must lie inside the image).
    pub fn put_tile(&mut self, tile: &TileAccum) {
        let r = tile.rect;
        for row in 0..r.height {
            for col in 0..r.width {
                let p = &tile.pixels[(row * r.width + col) as usize];
                let i = ((r.y0 + row) * self.width + r.x0 + col) as usize;
                let (m, v) = (p.mean(), p.variance_of_mean());
                for c in 0..3 {
                    self.mean[c][i] = m[c] as f32;
                    self.variance[c][i] =
                        if v[c].is_finite() { v[c] as f32 } else { f32::INFINITY };
                }
                self.samples[i] = p.n;
            }
        }
        self.rejected += tile.rejected;
        self.rel_mse_sum += ErrorEstimate::of_pixels(&tile.pixels).rel_mse * r.area() as f64;
    }

    /// The image of a whole film.
    pub fn from_film(film: &Film) -> Self {
        let mut image = FrameImage::new(film.width, film.height);
        let rect = common::film::Rect { x0: 0, y0: 0, width: film.width, height: film.height };
        let tile = TileAccum { rect, pixels: film.pixels.clone(), rejected: film.rejected };
        image.put_tile(&tile);
        image
    }

    /// Estimated relative MSE of the image (mean over pixels).
    pub fn est_rel_mse(&self) -> f64 {
        self.rel_mse_sum / self.samples.len().max(1) as f64
    }
}

/// Writes `film` as an EXR at `path`.
pub fn write_exr(path: &Path, film: &Film, info: &FrameInfo) -> Result<()> {
    let bytes = exr_bytes(FrameImage::from_film(film), info)?;
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// Encodes a frame as the EXR file of PRODUCT.md.
pub fn exr_bytes(image: FrameImage, info: &FrameInfo) -> Result<Vec<u8>> {
    let size = (image.width as usize, image.height as usize);
    let total_samples: u64 = image.samples.iter().map(|&n| n as u64).sum();
    let (rejected, est_rel_mse) = (image.rejected, image.est_rel_mse());
    let [r, g, b] = image.mean;
    let [vr, vg, vb] = image.variance;
    let samples = image.samples;
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![
        AnyChannel::new("R", FlatSamples::F32(r)),
        AnyChannel::new("G", FlatSamples::F32(g)),
        AnyChannel::new("B", FlatSamples::F32(b)),
        AnyChannel::new("variance.R", FlatSamples::F32(vr)),
        AnyChannel::new("variance.G", FlatSamples::F32(vg)),
        AnyChannel::new("variance.B", FlatSamples::F32(vb)),
        AnyChannel::new("samples", FlatSamples::U32(samples)),
    ]));
    let mut attributes = LayerAttributes::named("");
    attributes.layer_name = None;
    let text = |s: String| AttributeValue::Text(Text::from(s.as_str()));
    let other = &mut attributes.other;
    other.insert(Text::from("renderfarm.settings"), text(info.settings_json.clone()));
    other.insert(Text::from("renderfarm.scene_sha256"), text(info.scene_hash.clone()));
    other.insert(Text::from("renderfarm.samples"), text(total_samples.to_string()));
    other.insert(
        Text::from("renderfarm.render_seconds"),
        text(format!("{:.3}", info.render_seconds)),
    );
    other.insert(Text::from("renderfarm.frame"), text(info.frame.to_string()));
    other.insert(Text::from("renderfarm.rejected_samples"), text(rejected.to_string()));
    other.insert(Text::from("renderfarm.est_rel_mse"), text(format!("{est_rel_mse:.6e}")));
    let layer = Layer::new(size, attributes, Encoding::SMALL_LOSSLESS, channels);
    let mut out = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer).write().to_buffered(&mut out).context("encoding the EXR")?;
    Ok(out.into_inner())
}

/// sRGB transfer of a linear value in [0, 1].
fn srgb_encode(v: f32) -> f32 {
    if v <= 0.0031308 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Writes an 8-bit sRGB PNG preview of `film`, scaled by 2^`exposure`.
pub fn write_png(path: &Path, film: &Film, exposure: f32) -> Result<()> {
    let bytes = png_bytes(&FrameImage::from_film(film), exposure)?;
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// Encodes an 8-bit sRGB PNG preview of a frame, scaled by 2^`exposure`.
pub fn png_bytes(image: &FrameImage, exposure: f32) -> Result<Vec<u8>> {
    let scale = exposure.exp2();
    let mut bytes = Vec::with_capacity(image.samples.len() * 3);
    for i in 0..image.samples.len() {
        for c in 0..3 {
            let v = (image.mean[c][i] * scale).clamp(0.0, 1.0);
            bytes.push((srgb_encode(v) * 255.0 + 0.5) as u8);
        }
    }
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, image.width, image.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().context("writing PNG header")?;
    writer.write_image_data(&bytes).context("writing PNG data")?;
    writer.finish().context("finishing the PNG")?;
    Ok(out)
}

/// Reads the mean RGB of an EXR written by `write_exr` (or any RGB EXR), row-major.
pub fn read_exr_rgb(path: &Path) -> Result<(usize, usize, Vec<[f32; 3]>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let (w, h, texels) = common::envmap::read_exr_rgb(&bytes, u64::MAX)
        .map_err(anyhow::Error::msg)
        .with_context(|| format!("reading {}", path.display()))?;
    Ok((w, h, texels.iter().map(|t| t.to_array()).collect()))
}

/// Every channel of an EXR (bytes), by name, as raw bits (f32 bits, u32 values, f16 bits), for
/// bitwise comparisons.
pub fn read_channel_bits(bytes: &[u8]) -> Result<Vec<(String, Vec<u32>)>> {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .context("reading the EXR")?;
    Ok(image
        .layer_data
        .channel_data
        .list
        .iter()
        .map(|c| {
            let bits = match &c.sample_data {
                FlatSamples::F32(v) => v.iter().map(|x| x.to_bits()).collect(),
                FlatSamples::U32(v) => v.clone(),
                FlatSamples::F16(v) => v.iter().map(|x| x.to_bits() as u32).collect(),
            };
            (c.name.to_string(), bits)
        })
        .collect())
}
