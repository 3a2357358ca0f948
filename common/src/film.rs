//! Film arithmetic: per-pixel partial sums that merge exactly, and the statistics read from them.
//!
//! Each sample's RGB value is quantised once to fixed point (sum: 2^-48, square: 2^-32, truncated)
//! and added
//! into 128-bit integers. Integer addition is associative, so a pixel's sums are bit-for-bit the
//! same however its samples were split into tasks and in whatever order the tasks are merged:
//! this is what makes the farm's images reproducible. The quantisation step (3.6e-15) is far below
//! any radiance a scene produces; values above `MAX_SAMPLE_VALUE` or non-finite are refused and
//! counted as zero-valued samples instead (reported, never silently added).
//!
//! Even and odd sample indices come from two independently scrambled sequences (see the
//! worker's sampler), so the means of the two halves are independent estimates. Their difference
//! measures the real error of a low-discrepancy estimate, which the per-sample variance (made for
//! independent samples) overstates: `Film::error_estimate` uses it.

use serde::{Deserialize, Serialize};

/// Fixed-point scale of the per-channel sums.
const SUM_SCALE: f64 = (1u64 << 48) as f64;
/// Fixed-point scale of the per-channel sums of squares.
const SQ_SCALE: f64 = (1u64 << 32) as f64;
/// Largest magnitude a single sample may have (keeps the 128-bit sums far from overflow:
/// 2^79 / 2^40 = 2^39 samples of this size before the sum could overflow).
pub const MAX_SAMPLE_VALUE: f32 = 1.0e12;

/// Truncates a scaled sample to an integer. Any deterministic rounding keeps merging exact; this
/// one converts through i64 (one instruction) whenever the value fits, which is almost always.
#[inline]
fn to_fixed(scaled: f64) -> i128 {
    const LIMIT: f64 = (1u64 << 62) as f64;
    if scaled.abs() < LIMIT {
        scaled as i64 as i128
    } else {
        scaled as i128
    }
}

/// Sums over the samples of one pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PixelSums {
    /// Number of samples taken (including refused ones, which count as zero).
    pub n: u32,
    /// Sum of sample values per channel, fixed point 2^-48.
    pub sum: [i128; 3],
    /// Sum of squared sample values per channel, fixed point 2^-32.
    pub sum_sq: [i128; 3],
    /// Number of samples with an odd index.
    pub n_odd: u32,
    /// Sum over the samples with an odd index, fixed point 2^-48.
    pub sum_odd: [i128; 3],
}

impl PixelSums {
    /// Adds sample number `sample_idx`. Returns false (and counts a zero sample) when the value
    /// is not finite or too large to be a radiance.
    #[inline]
    pub fn add(&mut self, sample_idx: u32, rgb: [f32; 3]) -> bool {
        let odd = sample_idx & 1 == 1;
        self.n += 1;
        self.n_odd += odd as u32;
        if !rgb.iter().all(|v| v.is_finite() && v.abs() <= MAX_SAMPLE_VALUE) {
            return false;
        }
        for c in 0..3 {
            let v = rgb[c] as f64;
            let fixed = to_fixed(v * SUM_SCALE);
            self.sum[c] += fixed;
            if odd {
                self.sum_odd[c] += fixed;
            }
            self.sum_sq[c] += to_fixed(v * v * SQ_SCALE);
        }
        true
    }

    /// Adds another pixel's sums (exact and associative).
    #[inline]
    pub fn merge(&mut self, other: &PixelSums) {
        self.n += other.n;
        self.n_odd += other.n_odd;
        for c in 0..3 {
            self.sum[c] += other.sum[c];
            self.sum_sq[c] += other.sum_sq[c];
            self.sum_odd[c] += other.sum_odd[c];
        }
    }

    /// Checks that these sums could come from `n` real samples of which `n_odd` have odd
    /// indices: the counts match, sums of squares are non-negative and no smaller than the
    /// squared sums allow (Cauchy-Schwarz), and no sample exceeded [`MAX_SAMPLE_VALUE`].
    pub fn check(&self, n: u32, n_odd: u32) -> Result<(), String> {
        if self.n != n || self.n_odd != n_odd {
            return Err(format!(
                "{} samples ({} odd), the task has {n} ({n_odd} odd)",
                self.n, self.n_odd
            ));
        }
        let max = MAX_SAMPLE_VALUE as f64;
        for c in 0..3 {
            let s = self.sum[c] as f64 / SUM_SCALE;
            let q = self.sum_sq[c] as f64 / SQ_SCALE;
            let s_odd = self.sum_odd[c] as f64 / SUM_SCALE;
            if self.sum_sq[c] < 0 {
                return Err(format!("channel {c}: negative sum of squares"));
            }
            // Truncation to fixed point loses at most one unit of the square per sample.
            let nf = n as f64;
            if s * s > nf * q * (1.0 + 1e-9) + nf * nf * (2.0 / SQ_SCALE) {
                return Err(format!("channel {c}: sum {s:e} impossible with sum of squares {q:e}"));
            }
            if s.abs() > n as f64 * max || s_odd.abs() > n_odd as f64 * max {
                return Err(format!(
                    "channel {c}: sum {s:e} beyond {n} samples of at most {max:e}"
                ));
            }
        }
        Ok(())
    }

    /// Mean radiance per channel (0 with no samples).
    pub fn mean(&self) -> [f64; 3] {
        if self.n == 0 {
            return [0.0; 3];
        }
        let n = self.n as f64;
        [0, 1, 2].map(|c| self.sum[c] as f64 / SUM_SCALE / n)
    }

    /// The variance of the mean estimated from the two independent halves (even and odd sample
    /// indices): unbiased for any sampler, but with one degree of freedom per pixel, so only
    /// meaningful averaged over many pixels. `None` until both halves have samples.
    pub fn half_difference_variance(&self) -> Option<[f64; 3]> {
        let n_even = self.n - self.n_odd;
        if self.n_odd == 0 || n_even == 0 {
            return None;
        }
        let (n, n0, n1) = (self.n as f64, n_even as f64, self.n_odd as f64);
        Some([0, 1, 2].map(|c| {
            let m1 = self.sum_odd[c] as f64 / SUM_SCALE / n1;
            let m0 = (self.sum[c] - self.sum_odd[c]) as f64 / SUM_SCALE / n0;
            (m0 - m1) * (m0 - m1) * n0 * n1 / (n * n)
        }))
    }

    /// Estimated variance of the mean per channel: s² / n with the unbiased sample variance s².
    /// Exact for independent samples; an upper bound for the stratified ones the renderer draws.
    /// Infinite with fewer than two samples (nothing is known about the error yet).
    pub fn variance_of_mean(&self) -> [f64; 3] {
        if self.n < 2 {
            return [f64::INFINITY; 3];
        }
        let n = self.n as f64;
        [0, 1, 2].map(|c| {
            let mean = self.sum[c] as f64 / SUM_SCALE / n;
            let mean_sq = self.sum_sq[c] as f64 / SQ_SCALE / n;
            ((mean_sq - mean * mean) * n / (n - 1.0)).max(0.0) / n
        })
    }
}

/// A rectangle of pixels: `x0..x0+width`, `y0..y0+height`, row 0 at the top of the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Rect {
    /// Left column.
    pub x0: u32,
    /// Top row.
    pub y0: u32,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl Rect {
    /// Number of pixels.
    pub fn area(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// Partial sums for the pixels of one tile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileAccum {
    /// The pixels covered.
    pub rect: Rect,
    /// Row-major sums, `rect.area()` of them.
    pub pixels: Vec<PixelSums>,
    /// Samples refused for being NaN, infinite or absurdly large.
    pub rejected: u64,
}

impl TileAccum {
    /// An empty accumulator for `rect`.
    pub fn new(rect: Rect) -> Self {
        TileAccum { rect, pixels: vec![PixelSums::default(); rect.area()], rejected: 0 }
    }

    /// Adds sample `sample_idx` to the pixel at `(x, y)` relative to the tile's corner.
    #[inline]
    pub fn add_sample(&mut self, x: u32, y: u32, sample_idx: u32, rgb: [f32; 3]) {
        let i = (y * self.rect.width + x) as usize;
        if !self.pixels[i].add(sample_idx, rgb) {
            self.rejected += 1;
        }
    }

    /// Adds another accumulator for the same tile.
    pub fn merge(&mut self, other: &TileAccum) {
        assert_eq!(self.rect, other.rect, "merging sums of different tiles");
        for (a, b) in self.pixels.iter_mut().zip(&other.pixels) {
            a.merge(b);
        }
        self.rejected += other.rejected;
    }
}

/// The merged sums of a whole frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major, row 0 at the top.
    pub pixels: Vec<PixelSums>,
    /// Refused samples over all merged tiles.
    pub rejected: u64,
}

/// The error of a film predicted from its own samples (half differences, see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorEstimate {
    /// sqrt(mean over pixels and channels of the variance of the mean).
    pub rmse: f64,
    /// Mean over pixels and channels of variance / (mean² + 0.01): the expected relative MSE
    /// (the metric of the benchmarks).
    pub rel_mse: f64,
}

impl Film {
    /// A film with no samples.
    pub fn new(width: u32, height: u32) -> Self {
        Film {
            width,
            height,
            pixels: vec![PixelSums::default(); width as usize * height as usize],
            rejected: 0,
        }
    }

    /// Adds a tile's sums. The tile must lie inside the film.
    pub fn merge_tile(&mut self, tile: &TileAccum) {
        let r = tile.rect;
        assert!(
            r.x0 + r.width <= self.width && r.y0 + r.height <= self.height,
            "tile outside film"
        );
        for row in 0..r.height {
            let dst = ((r.y0 + row) * self.width + r.x0) as usize;
            let src = (row * r.width) as usize;
            for (a, b) in self.pixels[dst..dst + r.width as usize]
                .iter_mut()
                .zip(&tile.pixels[src..src + r.width as usize])
            {
                a.merge(b);
            }
        }
        self.rejected += tile.rejected;
    }

    /// Mean radiance, row-major RGB.
    pub fn mean_rgb(&self) -> Vec<[f32; 3]> {
        self.pixels.iter().map(|p| p.mean().map(|v| v as f32)).collect()
    }

    /// Total samples over all pixels.
    pub fn total_samples(&self) -> u64 {
        self.pixels.iter().map(|p| p.n as u64).sum()
    }

    /// The image-level error predicted from per-pixel variances.
    pub fn error_estimate(&self) -> ErrorEstimate {
        ErrorEstimate::of_pixels(&self.pixels)
    }
}

impl ErrorEstimate {
    /// The predicted error of a set of pixels (a film or a tile): per pixel the variance of the
    /// mean from the half difference (or the sample variance before both halves have samples).
    pub fn of_pixels(pixels: &[PixelSums]) -> ErrorEstimate {
        let mut sum_var = 0.0;
        let mut sum_rel = 0.0;
        for p in pixels {
            let mean = p.mean();
            let var = p.half_difference_variance().unwrap_or_else(|| p.variance_of_mean());
            for c in 0..3 {
                sum_var += var[c];
                sum_rel += var[c] / (mean[c] * mean[c] + 0.01);
            }
        }
        let n = (pixels.len() * 3).max(1) as f64;
        ErrorEstimate { rmse: (sum_var / n).sqrt(), rel_mse: sum_rel / n }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(state: &mut u64) -> f32 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (*state >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn merge_is_exact_whatever_the_split_and_order() {
        let mut state = 7;
        let values: Vec<[f32; 3]> = (0..1000)
            .map(|_| [lcg(&mut state) * 1e3, lcg(&mut state) * 1e-3, lcg(&mut state).powi(8) * 1e6])
            .collect();
        let mut whole = PixelSums::default();
        for (i, v) in values.iter().enumerate() {
            whole.add(i as u32, *v);
        }
        let (mut a, mut b, mut c) = Default::default();
        let parts: [&mut PixelSums; 3] = [&mut a, &mut b, &mut c];
        for (i, v) in values.iter().enumerate() {
            parts[i % 3].add(i as u32, *v);
        }
        let mut abc = a;
        abc.merge(&b);
        abc.merge(&c);
        let mut cba = c;
        cba.merge(&b);
        cba.merge(&a);
        assert_eq!(whole, abc);
        assert_eq!(whole, cba);
    }

    #[test]
    fn variance_matches_welford_on_a_bright_pixel() {
        // A bright pixel with small spread is where sum-of-squares formulas cancel badly.
        let mut state = 11;
        let values: Vec<f64> =
            (0..4096).map(|_| 1.0e4 + (lcg(&mut state) as f64 - 0.5) * 1e-1).collect();
        let mut sums = PixelSums::default();
        let (mut mean, mut m2) = (0.0f64, 0.0f64);
        for (i, &v) in values.iter().enumerate() {
            sums.add(i as u32, [v as f32; 3]);
            let v = v as f32 as f64;
            let delta = v - mean;
            mean += delta / (i + 1) as f64;
            m2 += delta * (v - mean);
        }
        let welford = m2 / (values.len() - 1) as f64 / values.len() as f64;
        let ours = sums.variance_of_mean()[0];
        assert!((ours - welford).abs() <= 1e-3 * welford, "{ours} vs {welford}");
        assert!((sums.mean()[0] - mean).abs() <= 1e-9 * mean);
    }

    #[test]
    fn half_differences_estimate_the_variance_of_independent_samples() {
        // Over many pixels of i.i.d. samples both estimators agree with the true variance.
        let mut state = 3;
        let (mut half, mut iid) = (0.0, 0.0);
        let pixels = 20_000;
        for _ in 0..pixels {
            let mut p = PixelSums::default();
            for i in 0..16 {
                p.add(i, [lcg(&mut state); 3]);
            }
            half += p.half_difference_variance().unwrap()[0];
            iid += p.variance_of_mean()[0];
        }
        let truth = 1.0 / 12.0 / 16.0;
        let (half, iid) = (half / pixels as f64, iid / pixels as f64);
        assert!((half / truth - 1.0).abs() < 0.03, "half differences {half} vs {truth}");
        assert!((iid / truth - 1.0).abs() < 0.01, "sample variance {iid} vs {truth}");
    }

    #[test]
    fn non_finite_samples_are_counted_not_added() {
        let mut tile = TileAccum::new(Rect { x0: 0, y0: 0, width: 2, height: 1 });
        tile.add_sample(0, 0, 0, [1.0, 2.0, 3.0]);
        tile.add_sample(0, 0, 1, [f32::NAN, 0.0, 0.0]);
        tile.add_sample(1, 0, 0, [f32::INFINITY, 0.0, 0.0]);
        assert_eq!(tile.rejected, 2);
        assert_eq!(tile.pixels[0].n, 2);
        assert_eq!(tile.pixels[0].mean(), [0.5, 1.0, 1.5]);
        assert_eq!(tile.pixels[1].mean(), [0.0; 3]);
    }

    #[test]
    fn film_merges_tiles_in_place() {
        let mut film = Film::new(4, 3);
        let mut tile = TileAccum::new(Rect { x0: 1, y0: 1, width: 2, height: 2 });
        tile.add_sample(1, 1, 0, [4.0, 4.0, 4.0]);
        film.merge_tile(&tile);
        assert_eq!(film.pixels[2 * 4 + 2].mean(), [4.0; 3]);
        assert_eq!(film.total_samples(), 1);
    }
}
