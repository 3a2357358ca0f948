//! Writing a frame: the OpenEXR file of PRODUCT.md (`R`, `G`, `B`, `variance.R/G/B`, `samples`,
//! header attributes) and a PNG preview (exposure + sRGB transfer) beside it.

use std::{
    io::Write,
    path::{Path, PathBuf},
};

use anyhow::{Context, Result};
use common::film::{ErrorEstimate, TileAccum};
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
    /// The kernels that rendered it (`TaskResult::kernel`), by name.
    pub kernels: Vec<String>,
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
        self.put_tile_below(tile, 0);
    }

    /// Writes a tile's pixels into an image of the frame's rows from `first_row` on (a band of
    /// the frame); the tile's rows must lie inside it.
    pub fn put_tile_below(&mut self, tile: &TileAccum, first_row: u32) {
        let r = tile.rect;
        for row in 0..r.height {
            for col in 0..r.width {
                let p = &tile.pixels[(row * r.width + col) as usize];
                let i = ((r.y0 - first_row + row) * self.width + r.x0 + col) as usize;
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

    /// Estimated relative MSE of the image (mean over pixels).
    pub fn est_rel_mse(&self) -> f64 {
        self.rel_mse_sum / self.samples.len().max(1) as f64
    }
}

/// Writes a frame's files: the EXR at `exr_path` and its PNG preview at `png_path`, both
/// encoded at once (the EXR's compression is most of the time).
pub fn write_frame(
    exr_path: &Path,
    png_path: &Path,
    image: FrameImage,
    info: &FrameInfo,
) -> Result<()> {
    // The preview needs only the mean (a 12-byte-a-pixel copy); the EXR takes the rest.
    let (width, height, mean) = (image.width, image.height, image.mean.clone());
    let (exr, png) = std::thread::scope(|s| {
        let png = s.spawn(move || png_of_mean(width, height, &mean, 0.0, ToneMap::Clamp));
        (exr_bytes(image, info), png.join().expect("PNG encoding panicked"))
    });
    std::fs::write(exr_path, exr?).with_context(|| format!("writing {}", exr_path.display()))?;
    std::fs::write(png_path, png?).with_context(|| format!("writing {}", png_path.display()))
}

/// Name of the file's first part: the image (`R`, `G`, `B`) and `samples`, with the header
/// attributes.
pub const IMAGE_PART: &str = "rgba";
/// Name of the file's second part: `variance.R`, `variance.G`, `variance.B`.
pub const VARIANCE_PART: &str = "variance";

/// How both parts are stored: run-length encoded scanlines, lossless. Noisy float data barely
/// deflates; most of what ZIP saves is the constant `samples` channel and infinite variances,
/// which run-length encoding removes too. Measured with `examples/exr_speed.rs` (all seven
/// channels, fastest of five): a 256x256 Cornell box frame at 256 spp encodes in 3.1 ms and
/// 1.64 MB against 28 ms and 1.45 MB for ZIP16 on both cores; at 1 spp 3.2 ms and 1.25 MB
/// against 14 ms and 0.69 MB; a 1920x1080 frame at 2 spp in 42 ms and 30 MB against 475 ms
/// and 25 MB.
const ENCODING: Encoding = Encoding {
    compression: Compression::RLE,
    blocks: Blocks::ScanLines,
    line_order: LineOrder::Increasing,
};

/// Encodes a frame as the EXR file of PRODUCT.md: a two-part file (OpenEXR 2.0 multi-part).
/// The first part, `rgba`, holds `R`, `G`, `B` and `samples` with the header attributes; the
/// second, `variance`, holds `variance.R`, `variance.G`, `variance.B`. A reader that takes only
/// the first part (most viewers) or one that keys channels by the last component of their name
/// (`variance.R` -> `R`) still gets the image, never the variance.
pub fn exr_bytes(image: FrameImage, info: &FrameInfo) -> Result<Vec<u8>> {
    let size = (image.width as usize, image.height as usize);
    let totals = ExrTotals {
        samples: image.samples.iter().map(|&n| n as u64).sum(),
        rejected: image.rejected,
        rel_mse_sum: image.rel_mse_sum,
    };
    // The channels move into the encoder (no copy: a 4K frame's would be 230 MB).
    let ([r, g, b], [vr, vg, vb]) = (image.mean, image.variance);
    let image = exr_image(size, info, &totals, [r, g, b, vr, vg, vb], image.samples);
    let mut out = std::io::Cursor::new(Vec::new());
    // Below a megapixel, handing run-length blocks to a pool of threads costs more than it
    // saves (3.2 ms on one thread, 4.2 ms on two for 256x256; 66 and 42 ms for 1920x1080).
    if size.0 * size.1 < 1 << 20 {
        image.write().non_parallel().to_buffered(&mut out)
    } else {
        image.write().to_buffered(&mut out)
    }
    .context("encoding the EXR")?;
    Ok(out.into_inner())
}

/// What an EXR's header says of the whole frame, summed a tile at a time in tile order (the
/// order [`FrameImage::put_tile`] is called in, so that both give the same bits).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExrTotals {
    /// Samples over all pixels.
    pub samples: u64,
    /// Refused samples.
    pub rejected: u64,
    /// Sum over pixels of the estimated relative MSE.
    rel_mse_sum: f64,
}

impl ExrTotals {
    /// Adds a tile's sums.
    pub fn add_tile(&mut self, tile: &TileAccum) {
        self.samples += tile.pixels.iter().map(|p| p.n as u64).sum::<u64>();
        self.rejected += tile.rejected;
        self.rel_mse_sum +=
            ErrorEstimate::of_pixels(&tile.pixels).rel_mse * tile.rect.area() as f64;
    }
}

/// The two-part image of [`exr_bytes`]: channels `R`, `G`, `B`, `variance.R/G/B` (in that
/// order in `rgb_var`) and `samples`, each `size.0 * size.1` long, or all empty when only the
/// headers are wanted.
fn exr_image(
    size: (usize, usize),
    info: &FrameInfo,
    totals: &ExrTotals,
    rgb_var: [Vec<f32>; 6],
    samples: Vec<u32>,
) -> Image<Layers2> {
    let [r, g, b, vr, vg, vb] = rgb_var;
    let image_channels = AnyChannels::sort(SmallVec::from_vec(vec![
        AnyChannel::new("R", FlatSamples::F32(r)),
        AnyChannel::new("G", FlatSamples::F32(g)),
        AnyChannel::new("B", FlatSamples::F32(b)),
        AnyChannel::new("samples", FlatSamples::U32(samples)),
    ]));
    let variance_channels = AnyChannels::sort(SmallVec::from_vec(vec![
        AnyChannel::new("variance.R", FlatSamples::F32(vr)),
        AnyChannel::new("variance.G", FlatSamples::F32(vg)),
        AnyChannel::new("variance.B", FlatSamples::F32(vb)),
    ]));
    let est_rel_mse = totals.rel_mse_sum / (size.0 * size.1).max(1) as f64;
    let mut attributes = LayerAttributes::named(IMAGE_PART);
    let text = |s: String| AttributeValue::Text(Text::from(s.as_str()));
    let other = &mut attributes.other;
    other.insert(Text::from("renderfarm.settings"), text(info.settings_json.clone()));
    other.insert(Text::from("renderfarm.scene_sha256"), text(info.scene_hash.clone()));
    other.insert(Text::from("renderfarm.samples"), text(totals.samples.to_string()));
    other.insert(
        Text::from("renderfarm.render_seconds"),
        text(format!("{:.3}", info.render_seconds)),
    );
    other.insert(Text::from("renderfarm.frame"), text(info.frame.to_string()));
    other.insert(Text::from("renderfarm.kernels"), text(info.kernels.join("; ")));
    other.insert(Text::from("renderfarm.rejected_samples"), text(totals.rejected.to_string()));
    other.insert(Text::from("renderfarm.est_rel_mse"), text(format!("{est_rel_mse:.6e}")));
    let bounds = IntegerBounds::from_dimensions(size);
    Image::empty(ImageAttributes::new(bounds))
        .with_layer(Layer::new(size, attributes, ENCODING, image_channels))
        .with_layer(Layer::new(
            size,
            LayerAttributes::named(VARIANCE_PART),
            ENCODING,
            variance_channels,
        ))
}

/// The layers of [`exr_image`]: the image part, then the variance part.
type Layers2 = exr::image::recursive::Recursive<
    exr::image::recursive::Recursive<
        exr::image::recursive::NoneMore,
        Layer<AnyChannels<FlatSamples>>,
    >,
    Layer<AnyChannels<FlatSamples>>,
>;

/// Writes the EXR of [`exr_bytes`], the same bytes, without ever holding the whole frame: the
/// rows come from `band(y0, rows)` (a `width` x `rows` image of the frame's rows
/// `y0..y0 + rows`), asked for in bands of `band_rows` from the top, once for the image part
/// and once more for the variance part; `totals` are the header's, summed beforehand. Memory
/// is one band (28 bytes a pixel) and one scanline block; `out` must seek (the block offsets
/// are written last).
pub fn write_exr_in_bands<W: std::io::Write + std::io::Seek>(
    out: W,
    (width, height): (u32, u32),
    info: &FrameInfo,
    totals: &ExrTotals,
    band_rows: u32,
    mut band: impl FnMut(u32, u32) -> Result<FrameImage>,
) -> Result<()> {
    use exr::block::{self, writer::ChunksWriter, UncompressedBlock};
    let (w, band_rows) = (width as usize, band_rows.max(1));
    let empty = || [(); 6].map(|_| Vec::new());
    let headers = exr_image((w, height as usize), info, totals, empty(), Vec::new())
        .write()
        .infer_meta_data();
    let mut failure = None;
    let mut out = std::io::BufWriter::new(out);
    block::write(&mut out, headers, true, |meta, writer| {
        let mut compressor = writer.sequential_blocks_compressor(&meta);
        // The band in hand: its first row, and its rows.
        let mut held: Option<(u32, FrameImage)> = None;
        for (index, block) in block::enumerate_ordered_header_block_indices(&meta.headers) {
            let header = &meta.headers[block.layer];
            let y0 = block.pixel_position.y() as u32;
            let rows = y0..y0 + block.pixel_size.y() as u32;
            // Blocks never straddle bands: both start at multiples of the block height.
            let stale = !matches!(&held, Some((b0, img)) if rows.start >= *b0 && rows.end <= b0 + img.height);
            if stale {
                let b0 = rows.start / band_rows * band_rows;
                let n = band_rows.min(height - b0);
                match band(b0, n) {
                    Ok(image) if image.width == width && image.height == n => held = Some((b0, image)),
                    Ok(_) => {
                        failure = Some(anyhow::anyhow!("a band of the wrong size"));
                        return Err(exr::error::Error::Aborted);
                    }
                    Err(e) => {
                        failure = Some(e);
                        return Err(exr::error::Error::Aborted);
                    }
                }
            }
            let (b0, image) = held.as_ref().expect("a band is held");
            let data = UncompressedBlock::from_lines(&header.channels, block, |line| {
                let name = header.channels.list[line.location.channel].name.to_string();
                let start = (line.location.position.y() - *b0 as usize) * w;
                let row = start..start + w;
                let written = match name.as_str() {
                    "samples" => line.write_samples_from_slice(&image.samples[row]),
                    other => {
                        let c = match other.rsplit('.').next() {
                            Some("R") => 0,
                            Some("G") => 1,
                            _ => 2,
                        };
                        let values = if other.starts_with("variance.") {
                            &image.variance[c]
                        } else {
                            &image.mean[c]
                        };
                        line.write_samples_from_slice(&values[row])
                    }
                };
                written.expect("a line holds its samples");
            });
            compressor.compress_block(index, data)?;
        }
        Ok(())
    })
    .map_err(|e| failure.take().unwrap_or_else(|| anyhow::Error::new(e)))
    .context("encoding the EXR")?;
    out.flush().context("writing the EXR")
}

/// sRGB transfer of a linear value in [0, 1].
fn srgb_encode(v: f32) -> f32 {
    if v <= 0.0031308 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Encodes an 8-bit sRGB PNG preview of a frame, scaled by 2^`exposure`.
pub fn png_bytes(image: &FrameImage, exposure: f32) -> Result<Vec<u8>> {
    png_of_mean(image.width, image.height, &image.mean, exposure, ToneMap::Clamp)
}

/// How a preview maps radiance (after the exposure) to the displayable [0, 1].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ToneMap {
    /// Values above 1 are cut at 1: the image as it is (the EXR's values, in sRGB).
    #[default]
    Clamp,
    /// v / (1 + v) per channel (Reinhard et al. 2002's global operator): nothing clips, highlights
    /// compress.
    Reinhard,
    /// Narkowicz's 2015 fit of the ACES filmic curve, per channel: a toe, and a shoulder that
    /// reaches 1 near v = 8 (and 1.03 at most).
    Aces,
}

impl ToneMap {
    /// The names the API takes, in the order of [`ToneMap::parse`]'s choices.
    pub const NAMES: [&'static str; 3] = ["clamp", "reinhard", "aces"];

    /// The tone map named `name` (one of [`ToneMap::NAMES`]).
    pub fn parse(name: &str) -> Option<ToneMap> {
        match name {
            "clamp" => Some(ToneMap::Clamp),
            "reinhard" => Some(ToneMap::Reinhard),
            "aces" => Some(ToneMap::Aces),
            _ => None,
        }
    }

    /// `v` (>= 0 after the exposure) mapped toward [0, 1] (the caller clamps).
    #[inline]
    fn apply(self, v: f32) -> f32 {
        match self {
            ToneMap::Clamp => v,
            // Below 0 (and NaN) black; past a million white (so that infinity is not NaN).
            ToneMap::Reinhard => {
                let v = v.max(0.0).min(1e6);
                v / (1.0 + v)
            }
            ToneMap::Aces => {
                let v = v.max(0.0).min(1e6);
                (v * (2.51 * v + 0.03)) / (v * (2.43 * v + 0.59) + 0.14)
            }
        }
    }
}

/// The longest side of a preview: larger frames are previewed downscaled.
pub const PREVIEW_MAX_SIDE: u32 = 2048;

/// A PNG preview built tile by tile, so that whoever serves it need hold a frame's sums one
/// tile at a time, and at most [`PREVIEW_MAX_SIDE`] pixels on a side: a frame larger than that
/// is shown at an integer fraction of its size, each preview pixel the mean of the frame
/// pixels it covers. A frame that fits is shown at full size, the PNG of [`png_bytes`] bit for
/// bit.
pub struct Preview {
    /// Frame pixels per preview pixel along each side.
    factor: u32,
    width: u32,
    height: u32,
    mean: [Vec<f32>; 3],
    /// Per preview pixel: the sum of the means it covers so far, and their count.
    sum: Vec<[f64; 3]>,
    count: Vec<u32>,
}

impl Preview {
    /// An empty (black) preview of a `width` x `height` frame.
    pub fn new(width: u32, height: u32) -> Self {
        let factor = width.max(height).div_ceil(PREVIEW_MAX_SIDE).max(1);
        let (w, h) = (width.div_ceil(factor), height.div_ceil(factor));
        let n = w as usize * h as usize;
        let mean = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        let (sum, count) =
            if factor == 1 { (Vec::new(), Vec::new()) } else { (vec![[0.0; 3]; n], vec![0; n]) };
        Preview { factor, width: w, height: h, mean, sum, count }
    }

    /// The preview's size in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Adds a tile's merged means.
    pub fn add_tile(&mut self, tile: &TileAccum) {
        let r = tile.rect;
        for row in 0..r.height {
            for col in 0..r.width {
                let m = tile.pixels[(row * r.width + col) as usize].mean();
                let (x, y) = ((r.x0 + col) / self.factor, (r.y0 + row) / self.factor);
                let i = (y * self.width + x) as usize;
                if self.factor == 1 {
                    for c in 0..3 {
                        self.mean[c][i] = m[c] as f32;
                    }
                } else {
                    for c in 0..3 {
                        self.sum[i][c] += m[c];
                    }
                    self.count[i] += 1;
                }
            }
        }
    }

    /// The PNG, scaled by 2^`exposure`.
    pub fn png(self, exposure: f32) -> Result<Vec<u8>> {
        self.png_mapped(exposure, ToneMap::Clamp)
    }

    /// The PNG, scaled by 2^`exposure`, then tone-mapped by `tone`.
    pub fn png_mapped(mut self, exposure: f32, tone: ToneMap) -> Result<Vec<u8>> {
        if self.factor > 1 {
            for (i, (s, &n)) in self.sum.iter().zip(&self.count).enumerate() {
                for c in 0..3 {
                    self.mean[c][i] = if n > 0 { (s[c] / n as f64) as f32 } else { 0.0 };
                }
            }
        }
        png_of_mean(self.width, self.height, &self.mean, exposure, tone)
    }
}

/// Encodes the 8-bit sRGB PNG of a `width` x `height` mean image, scaled by 2^`exposure` and
/// tone-mapped by `tone`.
fn png_of_mean(
    width: u32,
    height: u32,
    mean: &[Vec<f32>; 3],
    exposure: f32,
    tone: ToneMap,
) -> Result<Vec<u8>> {
    let scale = exposure.exp2();
    let n = width as usize * height as usize;
    let mut bytes = Vec::with_capacity(n * 3);
    for i in 0..n {
        for channel in mean {
            let v = tone.apply(channel[i] * scale).clamp(0.0, 1.0);
            bytes.push((srgb_encode(v) * 255.0 + 0.5) as u8);
        }
    }
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    // A preview: the fastest deflate. A 256x256 preview, sRGB conversion included, took
    // 1.9-3.7 ms (three runs) against about 15 ms at the default level.
    encoder.set_compression(png::Compression::Fast);
    let mut writer = encoder.write_header().context("writing PNG header")?;
    writer.write_image_data(&bytes).context("writing PNG data")?;
    writer.finish().context("finishing the PNG")?;
    Ok(out)
}

/// The EXR path for `-o OUT`: `OUT` itself when it names an `.exr`, `OUT` with the extension
/// `.exr` when it names a `.png` (the PNG preview goes beside the EXR, so both are written, and
/// a PNG never takes the EXR's place); anything else is refused.
pub fn exr_output(out: &Path) -> Result<PathBuf> {
    let ext = out.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
    match ext.as_deref() {
        Some("exr") => Ok(out.to_path_buf()),
        Some("png") => Ok(out.with_extension("exr")),
        _ => anyhow::bail!(
            "-o {}: name the image OUT.exr (an OpenEXR file and its PNG preview OUT.png are written)",
            out.display()
        ),
    }
}

/// Refuses, before any rendering, output files that could not be written: a folder that does
/// not exist or is not writable, a path that is a folder, a read-only file. Creates nothing it
/// leaves behind.
pub fn check_writable(paths: &[PathBuf]) -> Result<()> {
    for path in paths {
        let dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        if path.is_dir() {
            anyhow::bail!("cannot write {}: it is a folder", path.display());
        }
        if path.exists() {
            std::fs::OpenOptions::new()
                .append(true)
                .open(path)
                .with_context(|| format!("cannot write {}", path.display()))?;
        } else {
            tempfile::Builder::new().prefix(".renderfarm-probe-").tempfile_in(dir).with_context(
                || format!("cannot write {}: folder {}", path.display(), dir.display()),
            )?;
        }
    }
    Ok(())
}

/// The mean luminance below which an image is called nearly black: about five and a half
/// stops under middle grey (0.18). The damaged helmet lit by its own emissive parts alone comes
/// out at 0.002; under the studio map at 0.03, the Cornell box at 0.16.
pub const NEARLY_BLACK: f64 = 0.005;

/// The image's mean luminance (Rec. 709 weights) when it is above zero and below
/// [`NEARLY_BLACK`]: an image its lights barely reach.
pub fn nearly_black(mean_rgb: &[[f32; 3]]) -> Option<f64> {
    let luminance =
        |p: &[f32; 3]| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64;
    let mean = mean_rgb.iter().map(luminance).sum::<f64>() / mean_rgb.len().max(1) as f64;
    (mean > 0.0 && mean < NEARLY_BLACK).then_some(mean)
}

/// What `render` and `submit` say of a nearly black image of a scene with no environment.
pub fn nearly_black_warning(mean: f64) -> String {
    format!(
        "the image is nearly black (mean luminance {mean:.4}): the scene's own lights reach little of what the camera sees; light it with an environment map: --env FILE.hdr, or \"environment\": {{\"map\": \"FILE.hdr\"}} in the settings (\"environment\": {{\"color\": [1, 1, 1]}} for a uniform white sky)"
    )
}

/// True when every mean of the image is zero (nothing lit what the camera sees).
pub fn is_black(mean_rgb: &[[f32; 3]]) -> bool {
    mean_rgb.iter().all(|p| p.iter().all(|&c| c == 0.0))
}

/// The error estimate as every command prints it: the estimated relative RMSE (the square root
/// of the relative MSE in the EXR header and of `est_rel_error` in the job status) in percent.
/// A black image has no relative error to speak of, and one sample per pixel gives no estimate.
pub fn describe_error(rel_mse: Option<f64>, black: bool) -> String {
    match rel_mse {
        _ if black => "no error estimate (the image is black: nothing lit it)".to_string(),
        Some(m) if m.is_finite() => {
            format!("estimated relative error {:.2}% (relMSE {m:.3e})", m.sqrt() * 100.0)
        }
        _ => "no error estimate (it needs 2 samples per pixel)".to_string(),
    }
}

/// Reads the mean RGB of an EXR written by `write_frame` (or any RGB EXR), row-major.
pub fn read_exr_rgb(path: &Path) -> Result<(usize, usize, Vec<[f32; 3]>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let (w, h, texels) = common::envmap::read_exr_rgb(&bytes, u64::MAX)
        .map_err(anyhow::Error::msg)
        .with_context(|| format!("reading {}", path.display()))?;
    Ok((w, h, texels.iter().map(|t| t.to_array()).collect()))
}

/// Every channel of an EXR (bytes), by name, as raw bits (f32 bits, u32 values, f16 bits), for
/// bitwise comparisons: the channels of every part, part by part.
pub fn read_channel_bits(bytes: &[u8]) -> Result<Vec<(String, Vec<u32>)>> {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .context("reading the EXR")?;
    Ok(image
        .layer_data
        .iter()
        .flat_map(|layer| layer.channel_data.list.iter())
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

/// The headers of an EXR, from its first bytes (enough of them to hold the headers).
pub fn read_exr_meta(bytes: &[u8]) -> Result<exr::meta::MetaData> {
    exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
        .context("reading the EXR header")
}

/// The header attributes of an EXR's parts (bytes): (part name, attribute name, text value)
/// for every text attribute.
pub fn read_text_attributes(bytes: &[u8]) -> Result<Vec<(String, String, String)>> {
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
        .context("reading the EXR header")?;
    let mut out = Vec::new();
    for header in &meta.headers {
        let part = header.own_attributes.layer_name.as_ref().map(Text::to_string);
        for (name, value) in &header.own_attributes.other {
            if let AttributeValue::Text(text) = value {
                out.push((part.clone().unwrap_or_default(), name.to_string(), text.to_string()));
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::film::Rect;

    /// Tiles of a `width` x `height` frame whose pixel (x, y) has the value `value(x, y)`.
    fn tiles(width: u32, height: u32, value: impl Fn(u32, u32) -> f32) -> Vec<TileAccum> {
        let mut out = Vec::new();
        for y0 in (0..height).step_by(32) {
            for x0 in (0..width).step_by(32) {
                let rect = Rect { x0, y0, width: 32.min(width - x0), height: 32.min(height - y0) };
                let mut tile = TileAccum::new(rect);
                for row in 0..rect.height {
                    for col in 0..rect.width {
                        let v = value(x0 + col, y0 + row);
                        tile.add_sample(col, row, 0, [v, v * 0.5, 0.25]);
                    }
                }
                out.push(tile);
            }
        }
        out
    }

    /// A frame that fits is previewed at full size, bit for bit the PNG of the whole image; a
    /// larger one at an integer fraction, each pixel the mean of those it covers.
    #[test]
    fn previews_built_tile_by_tile_match_and_downscale() {
        let (w, h) = (70, 45);
        let value = |x: u32, y: u32| ((x * 7 + y * 13) % 17) as f32 / 17.0;
        let mut image = FrameImage::new(w, h);
        let mut preview = Preview::new(w, h);
        for tile in tiles(w, h, value) {
            image.put_tile(&tile);
            preview.add_tile(&tile);
        }
        assert_eq!(preview.size(), (w, h));
        assert_eq!(preview.png(0.0).unwrap(), png_bytes(&image, 0.0).unwrap());

        let (w, h) = (2 * PREVIEW_MAX_SIDE + 5, 40);
        let mut preview = Preview::new(w, h);
        for tile in tiles(w, h, |x, _| if x % 3 == 0 { 0.9 } else { 0.0 }) {
            preview.add_tile(&tile);
        }
        // Three frame pixels a preview pixel: 4101 wide becomes 1367, 40 high becomes 14.
        assert_eq!(preview.size(), (1367, 14));
        let mut small = Preview::new(1367, 14);
        for tile in tiles(1367, 14, |_, _| 0.3) {
            small.add_tile(&tile);
        }
        // Every preview pixel covers one lit column in three: a mean of 0.3.
        let decoded = |png: Vec<u8>| {
            let decoder = png::Decoder::new(std::io::Cursor::new(png));
            let mut reader = decoder.read_info().unwrap();
            let mut buf = vec![0; reader.output_buffer_size().unwrap()];
            reader.next_frame(&mut buf).unwrap();
            buf
        };
        let (big, reference) =
            (decoded(preview.png(0.0).unwrap()), decoded(small.png(0.0).unwrap()));
        assert_eq!(big, reference, "every preview pixel is the mean of the three it covers");
    }

    /// An EXR written a band of rows at a time is the EXR of the whole frame (the same bits in
    /// every channel, the same attributes, the same length), whatever the band height (a frame's tile rows, or bands that cut across tiles).
    #[test]
    fn exr_written_in_bands_is_the_whole_frames_exr() {
        let (w, h) = (70, 45);
        let all = tiles(w, h, |x, y| ((x * 7 + y * 13) % 17) as f32 / 17.0 + 0.01 * x as f32);
        let info = FrameInfo {
            settings_json: "{\"spp\":1}".into(),
            scene_hash: "ab".repeat(32),
            render_seconds: 1.25,
            frame: 3,
            kernels: vec!["path, AVX2 x8".into(), "path, scalar".into()],
        };
        let mut image = FrameImage::new(w, h);
        let mut totals = ExrTotals::default();
        // One tile left without samples, as in a running job.
        for tile in all.iter().filter(|t| t.rect.x0 != 32 || t.rect.y0 != 0) {
            image.put_tile(tile);
            totals.add_tile(tile);
        }
        let whole = exr_bytes(image.clone(), &info).unwrap();
        for band_rows in [32, 7, 45, 100] {
            let mut asked = Vec::new();
            let mut out = std::io::Cursor::new(Vec::new());
            write_exr_in_bands(&mut out, (w, h), &info, &totals, band_rows, |y0, rows| {
                asked.push((y0, rows));
                let mut band = FrameImage::new(w, rows);
                for tile in all.iter().filter(|t| t.rect.x0 != 32 || t.rect.y0 != 0) {
                    let (top, bottom) = (tile.rect.y0, tile.rect.y0 + tile.rect.height);
                    if top < y0 + rows && bottom > y0 {
                        // Only the tile's rows inside the band.
                        let from = y0.max(top);
                        let to = (y0 + rows).min(bottom);
                        let mut part = TileAccum::new(Rect {
                            x0: tile.rect.x0,
                            y0: from,
                            width: tile.rect.width,
                            height: to - from,
                        });
                        let width = tile.rect.width as usize;
                        let (skip, n) = ((from - top) as usize * width, part.pixels.len());
                        part.pixels.copy_from_slice(&tile.pixels[skip..skip + n]);
                        band.put_tile_below(&part, y0);
                    }
                }
                Ok(band)
            })
            .unwrap();
            // The same file but for the order of the header's attributes (a hash map's).
            let banded = out.into_inner();
            assert_eq!(banded.len(), whole.len(), "bands of {band_rows} rows");
            assert_eq!(read_channel_bits(&banded).unwrap(), read_channel_bits(&whole).unwrap());
            let sorted = |bytes: &[u8]| {
                let mut text = read_text_attributes(bytes).unwrap();
                text.sort();
                text
            };
            assert_eq!(sorted(&banded), sorted(&whole), "bands of {band_rows} rows");
            // Each part reads the frame once, top to bottom (a band of the whole frame once).
            let once: Vec<u32> = (0..h.div_ceil(band_rows)).map(|b| b * band_rows).collect();
            let starts: Vec<u32> = asked.iter().map(|&(y0, _)| y0).collect();
            let expected = if band_rows >= h { once } else { [once.clone(), once].concat() };
            assert_eq!(starts, expected, "bands of {band_rows} rows");
        }
        // A failing band fails the file with its own error.
        let mut out = std::io::Cursor::new(Vec::new());
        let err = write_exr_in_bands(&mut out, (w, h), &info, &totals, 32, |_, _| {
            Err(anyhow::anyhow!("the job was removed"))
        })
        .unwrap_err();
        assert!(format!("{err:#}").contains("the job was removed"), "{err:#}");
    }

    /// The tone maps: the clamp is the plain image; Reinhard's operator and the ACES fit start
    /// at 0, rise monotonically, keep what is bright near or below white (v / (1 + v) = 1/2 at 1;
    /// the ACES fit 0.80 at 1, 1.0 at 8) and map a pixel of 2 below 255.
    #[test]
    fn tone_maps_keep_highlights_below_white() {
        for name in ToneMap::NAMES {
            assert_eq!(ToneMap::parse(name).map(|t| ToneMap::NAMES[t as usize]), Some(name));
        }
        assert_eq!(ToneMap::parse("filmic"), None);
        assert_eq!(ToneMap::Clamp.apply(3.0), 3.0);
        assert_eq!(ToneMap::Reinhard.apply(1.0), 0.5);
        assert!((ToneMap::Aces.apply(1.0) - 0.8038).abs() < 1e-3);
        assert!((ToneMap::Aces.apply(8.0) - 1.0).abs() < 0.01);
        for tone in [ToneMap::Reinhard, ToneMap::Aces] {
            assert_eq!(tone.apply(0.0), 0.0);
            assert_eq!(tone.apply(f32::NAN), 0.0);
            assert!((tone.apply(f32::INFINITY) - 1.0).abs() < 0.04, "{tone:?}");
            assert_eq!(tone.apply(-1.0), 0.0, "{tone:?}");
            let mut last = 0.0;
            for i in 1..1000 {
                let v = tone.apply(i as f32 * 0.05);
                assert!(v > last && v < 1.04, "{tone:?} at {}: {v}", i as f32 * 0.05);
                last = v;
            }
        }
        let pixels = |tone| {
            let mut preview = Preview::new(2, 1);
            let mut tile = TileAccum::new(Rect { x0: 0, y0: 0, width: 2, height: 1 });
            tile.add_sample(0, 0, 0, [0.25; 3]);
            tile.add_sample(1, 0, 0, [2.0; 3]);
            preview.add_tile(&tile);
            let png = preview.png_mapped(0.0, tone).unwrap();
            let decoder = png::Decoder::new(std::io::Cursor::new(png));
            let mut reader = decoder.read_info().unwrap();
            let mut buf = vec![0; reader.output_buffer_size().unwrap()];
            reader.next_frame(&mut buf).unwrap();
            [buf[0], buf[3]]
        };
        assert_eq!(pixels(ToneMap::Clamp)[1], 255);
        // Reinhard: 2 -> 2/3, 0.25 -> 0.2, in sRGB.
        assert_eq!(pixels(ToneMap::Reinhard), [124, 213]);
        let aces = pixels(ToneMap::Aces);
        assert!(aces[1] < 255 && aces[1] > pixels(ToneMap::Reinhard)[1], "{aces:?}");
    }

    /// A 3x2 frame with distinct values everywhere (pixel 4 has no samples yet).
    fn frame() -> FrameImage {
        let mut image = FrameImage::new(3, 2);
        for i in 0..6 {
            for c in 0..3 {
                image.mean[c][i] = (10 * i + c) as f32 + 0.5;
                image.variance[c][i] = (10 * i + c) as f32 * 1e-3;
            }
            image.samples[i] = 7 + i as u32;
        }
        image.variance[1][4] = f32::INFINITY;
        image
    }

    #[test]
    fn exr_holds_every_channel_bit_for_bit_with_the_variance_in_its_own_part() {
        let image = frame();
        let bytes = exr_bytes(image.clone(), &FrameInfo::default()).unwrap();
        let channels = read_channel_bits(&bytes).unwrap();
        let names: Vec<&str> = channels.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["B", "G", "R", "samples", "variance.B", "variance.G", "variance.R"]);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (k, c) in [2, 1, 0].into_iter().enumerate() {
            assert_eq!(channels[k].1, bits(&image.mean[c]));
            assert_eq!(channels[4 + k].1, bits(&image.variance[c]));
        }
        assert_eq!(channels[3].1, image.samples);
        // A reader of the first part alone (most viewers, and any that key channels by the last
        // component of their name) sees the image, never the variance.
        let first = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_buffered(std::io::Cursor::new(&bytes))
            .unwrap();
        assert_eq!(first.layer_data.attributes.layer_name, Some(Text::from(IMAGE_PART)));
        let first_names: Vec<String> =
            first.layer_data.channel_data.list.iter().map(|c| c.name.to_string()).collect();
        assert_eq!(first_names, ["B", "G", "R", "samples"]);
        let parts: Vec<String> =
            read_text_attributes(&bytes).unwrap().into_iter().map(|(part, _, _)| part).collect();
        assert!(parts.iter().all(|p| p == IMAGE_PART), "attributes live in the image part");
    }

    #[test]
    fn png_is_the_srgb_encoded_mean() {
        let mut image = FrameImage::new(2, 1);
        image.mean = [vec![0.0, 1.0], vec![0.5, 4.0], vec![0.002, 0.2]];
        let bytes = png_bytes(&image, 0.0).unwrap();
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = decoder.read_info().unwrap();
        let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut pixels).unwrap();
        // sRGB(0.5) = 0.7354, sRGB(0.002) = 0.02584, sRGB(0.2) = 0.4845; 4.0 clips.
        assert_eq!(pixels, [0, 188, 7, 255, 255, 124]);
    }
}
