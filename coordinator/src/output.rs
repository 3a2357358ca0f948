//! Writing a frame: the OpenEXR file of PRODUCT.md (`R`, `G`, `B`, `variance.R/G/B`, `samples`,
//! header attributes) and a PNG preview (exposure + sRGB transfer) beside it.

use std::path::Path;

use anyhow::{Context, Result};
use common::film::Film;
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

/// Writes `film` as an EXR at `path`.
pub fn write_exr(path: &Path, film: &Film, info: &FrameInfo) -> Result<()> {
    let bytes = exr_bytes(film, info)?;
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// Encodes `film` as the EXR file of PRODUCT.md.
pub fn exr_bytes(film: &Film, info: &FrameInfo) -> Result<Vec<u8>> {
    let size = (film.width as usize, film.height as usize);
    let n = film.pixels.len();
    let mut mean = [Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n)];
    let mut var = [Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n)];
    let mut samples = Vec::with_capacity(n);
    for p in &film.pixels {
        let m = p.mean();
        let v = p.variance_of_mean();
        for c in 0..3 {
            mean[c].push(m[c] as f32);
            var[c].push(if v[c].is_finite() { v[c] as f32 } else { f32::INFINITY });
        }
        samples.push(p.n);
    }
    let [r, g, b] = mean;
    let [vr, vg, vb] = var;
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
    let estimate = film.error_estimate();
    let text = |s: String| AttributeValue::Text(Text::from(s.as_str()));
    let other = &mut attributes.other;
    other.insert(Text::from("renderfarm.settings"), text(info.settings_json.clone()));
    other.insert(Text::from("renderfarm.scene_sha256"), text(info.scene_hash.clone()));
    other.insert(Text::from("renderfarm.samples"), text(film.total_samples().to_string()));
    other.insert(
        Text::from("renderfarm.render_seconds"),
        text(format!("{:.3}", info.render_seconds)),
    );
    other.insert(Text::from("renderfarm.frame"), text(info.frame.to_string()));
    other.insert(Text::from("renderfarm.rejected_samples"), text(film.rejected.to_string()));
    other.insert(Text::from("renderfarm.est_rel_mse"), text(format!("{:.6e}", estimate.rel_mse)));
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
    let bytes = png_bytes(film, exposure)?;
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// Encodes an 8-bit sRGB PNG preview of `film`, scaled by 2^`exposure`.
pub fn png_bytes(film: &Film, exposure: f32) -> Result<Vec<u8>> {
    let scale = exposure.exp2();
    let mut bytes = Vec::with_capacity(film.pixels.len() * 3);
    for p in &film.pixels {
        for v in p.mean() {
            let v = (v as f32 * scale).clamp(0.0, 1.0);
            bytes.push((srgb_encode(v) * 255.0 + 0.5) as u8);
        }
    }
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, film.width, film.height);
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
