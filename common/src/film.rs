//! Film arithmetic: per-pixel running statistics that merge deterministically, and the statistics
//! read from them.
//!
//! A pixel keeps, per channel, the mean of its samples and the sum of squared deviations from it
//! (Welford's update for one sample, Chan et al.'s for merging two sets): numerically stable even
//! for a bright pixel with a small spread, where sums of squares cancel. 80 bytes a pixel.
//!
//! Floating-point merging is deterministic but not associative, so the farm merges in a
//! canonical order: a pixel's samples in index order within a task (one thread renders a pixel),
//! and a tile's tasks in task order. Merging into an empty accumulator is exact (`0 + x = x`,
//! `x * 1 = x`), so how the rows of a task are spread over threads does not change a bit. The
//! image is then a pure function of the samples and the task decomposition (which the settings
//! fix), never of timing, worker count or arrival order.
//!
//! Values above `MAX_SAMPLE_VALUE` or non-finite are refused and counted as zero-valued samples
//! instead (reported, never silently added); a negative component (rounding) counts as zero.
//! So the statistics of real samples always pass `PixelSums::check`, which the farm runs on
//! every result before merging it.
//!
//! Even and odd sample indices come from two independently scrambled sequences (see the
//! worker's sampler), so the means of the two halves are independent estimates. Their difference
//! measures the real error of a low-discrepancy estimate, which the per-sample variance (made for
//! independent samples) overstates: `Film::error_estimate` uses it.

use serde::{Deserialize, Serialize};

/// Largest magnitude a single sample may have: the renderer refuses (and counts) a sample
/// beyond it, and the farm refuses a result whose means or spread go beyond what samples within
/// it can give ([`PixelSums::check`]).
pub const MAX_SAMPLE_VALUE: f32 = 1.0e12;

/// The relative margin the upper bounds of [`PixelSums::check`] leave for rounding, far above
/// what Welford's and Chan's updates can accumulate (n ε for n samples).
pub const ROUNDING_MARGIN: f64 = 1e-6;

/// Running statistics of the samples of one pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PixelSums {
    /// Number of samples taken (including refused ones, which count as zero).
    pub n: u32,
    /// Number of samples with an odd index.
    pub n_odd: u32,
    /// Mean per channel.
    pub mean: [f64; 3],
    /// Sum of squared deviations from the mean per channel.
    pub m2: [f64; 3],
    /// Mean of the samples with an odd index per channel.
    pub mean_odd: [f64; 3],
}

impl PixelSums {
    /// Adds sample number `sample_idx`. Returns false (and counts a zero sample) when the value
    /// is not finite or too large to be a radiance. A negative component counts as zero: radiance
    /// is never negative, and only rounding (a BSDF's `1 - F` a few ulps below zero) makes one,
    /// so that the sums of an honest renderer always pass [`PixelSums::check`].
    #[inline]
    pub fn add(&mut self, sample_idx: u32, rgb: [f32; 3]) -> bool {
        let ok = rgb.iter().all(|v| v.is_finite() && v.abs() <= MAX_SAMPLE_VALUE);
        let rgb = if ok { rgb.map(|v| v.max(0.0)) } else { [0.0; 3] };
        self.n += 1;
        let inv_n = 1.0 / self.n as f64;
        let odd = sample_idx & 1 == 1;
        if odd {
            self.n_odd += 1;
        }
        let inv_odd = 1.0 / self.n_odd.max(1) as f64;
        for c in 0..3 {
            let v = rgb[c] as f64;
            let delta = v - self.mean[c];
            self.mean[c] += delta * inv_n;
            self.m2[c] += delta * (v - self.mean[c]);
            if odd {
                self.mean_odd[c] += (v - self.mean_odd[c]) * inv_odd;
            }
        }
        ok
    }

    /// Adds another pixel's samples (Chan et al.). Deterministic; exact when either is empty.
    #[inline]
    pub fn merge(&mut self, other: &PixelSums) {
        if other.n == 0 {
            return;
        }
        if self.n == 0 {
            *self = *other;
            return;
        }
        let (na, nb) = (self.n as f64, other.n as f64);
        let n = na + nb;
        let (oa, ob) = (self.n_odd as f64, other.n_odd as f64);
        for c in 0..3 {
            let delta = other.mean[c] - self.mean[c];
            self.mean[c] += delta * (nb / n);
            self.m2[c] += other.m2[c] + delta * delta * (na * nb / n);
            if other.n_odd > 0 {
                self.mean_odd[c] += (other.mean_odd[c] - self.mean_odd[c]) * (ob / (oa + ob));
            }
        }
        self.n += other.n;
        self.n_odd += other.n_odd;
    }

    /// Checks that these statistics could come from `n` real samples of which `n_odd` have odd
    /// indices, each a radiance the renderer keeps (finite, not negative, at most
    /// [`MAX_SAMPLE_VALUE`]): the counts match, every value is finite, means lie in
    /// `[0, MAX_SAMPLE_VALUE]`, and squared deviations in `[0, n MAX_SAMPLE_VALUE² / 4]`.
    /// The message names the channel, the quantity and its value.
    ///
    /// An honest renderer always passes: the scene's inputs (emission, lights, colours, the
    /// environment) are refused when negative and its BSDFs are clamped, so samples are never
    /// negative; Welford's and Chan's updates keep a mean between the smallest and largest value
    /// merged (each step adds a fraction at most 1 of a difference) and squared deviations
    /// non-negative; and the upper bounds carry a margin ([`ROUNDING_MARGIN`]) for rounding.
    pub fn check(&self, n: u32, n_odd: u32) -> Result<(), String> {
        if self.n != n || self.n_odd != n_odd {
            return Err(format!(
                "{} samples ({} odd), the task has {n} ({n_odd} odd)",
                self.n, self.n_odd
            ));
        }
        let max_mean = MAX_SAMPLE_VALUE as f64 * (1.0 + ROUNDING_MARGIN);
        // n values in [0, M] deviate from their mean by at most n M² / 4 in all (half at 0,
        // half at M).
        let max_m2 = n as f64 * (MAX_SAMPLE_VALUE as f64).powi(2) / 4.0 * (1.0 + ROUNDING_MARGIN);
        for c in 0..3 {
            let values = [("mean", self.mean[c]), ("mean of odd samples", self.mean_odd[c])];
            for (what, v) in values {
                if !v.is_finite() {
                    return Err(format!("channel {c}: {what} {v} is not finite"));
                }
                if v < 0.0 {
                    return Err(format!("channel {c}: {what} {v} is negative"));
                }
                if v > max_mean {
                    return Err(format!(
                        "channel {c}: {what} {v:e} is beyond the largest sample value {MAX_SAMPLE_VALUE:e}"
                    ));
                }
            }
            let m2 = self.m2[c];
            let what = "sum of squared deviations";
            if !m2.is_finite() {
                return Err(format!("channel {c}: {what} {m2} is not finite"));
            }
            if m2 < 0.0 {
                return Err(format!("channel {c}: {what} {m2} is negative"));
            }
            if m2 > max_m2 {
                return Err(format!(
                    "channel {c}: {what} {m2:e} is more than {n} samples of at most {MAX_SAMPLE_VALUE:e} can have"
                ));
            }
            if self.n_odd == 0 && self.mean_odd[c] != 0.0 {
                return Err(format!(
                    "channel {c}: a mean of odd samples ({}) without odd samples",
                    self.mean_odd[c]
                ));
            }
        }
        Ok(())
    }

    /// Mean radiance per channel (0 with no samples).
    pub fn mean(&self) -> [f64; 3] {
        self.mean
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
            let m1 = self.mean_odd[c];
            let m0 = (self.mean[c] * n - m1 * n1) / n0;
            (m0 - m1) * (m0 - m1) * n0 * n1 / (n * n)
        }))
    }

    /// Statistics that stand for the sum of this pixel's estimate and an independent one of the
    /// same pixel (bidirectional path tracing's camera-traced and light-traced images): the means
    /// add, and so do the variances of the mean and the half-difference variances; the counts are
    /// this one's. For showing and writing a frame only, never merged further.
    pub fn plus_independent(&self, other: &PixelSums) -> PixelSums {
        if other.n == 0 {
            return *self;
        }
        if self.n == 0 {
            return *other;
        }
        let mut out = *self;
        let n = self.n as f64;
        let (va, vb) = (self.variance_of_mean(), other.variance_of_mean());
        for c in 0..3 {
            out.mean[c] = self.mean[c] + other.mean[c];
            if self.n >= 2 {
                out.m2[c] = (va[c] + vb[c]) * n * (n - 1.0);
            }
        }
        match (self.half_difference_variance(), other.half_difference_variance()) {
            (Some(ha), Some(hb)) => {
                // The halves' means 'm0 - m1 = d' with d² n0 n1 / n² = ha + hb, about the mean.
                let (n0, n1) = (n - self.n_odd as f64, self.n_odd as f64);
                for c in 0..3 {
                    let d = ((ha[c] + hb[c]) * n * n / (n0 * n1)).sqrt();
                    out.mean_odd[c] = out.mean[c] - d * n0 / n;
                }
            }
            _ => {
                for c in 0..3 {
                    out.mean_odd[c] = self.mean_odd[c] + other.mean_odd[c];
                }
            }
        }
        out
    }

    /// The variance of the mean per channel as the error estimates read it: the half
    /// difference's, or the sample variance's before both halves have samples.
    pub fn estimated_variance(&self) -> [f64; 3] {
        self.half_difference_variance().unwrap_or_else(|| self.variance_of_mean())
    }

    /// Estimated variance of the mean per channel: s² / n with the unbiased sample variance s².
    /// Exact for independent samples; an upper bound for the stratified ones the renderer draws.
    /// Infinite with fewer than two samples (nothing is known about the error yet).
    pub fn variance_of_mean(&self) -> [f64; 3] {
        if self.n < 2 {
            return [f64::INFINITY; 3];
        }
        let n = self.n as f64;
        [0, 1, 2].map(|c| (self.m2[c] / (n - 1.0)).max(0.0) / n)
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

    /// This tile's pixels plus the same pixels of `frame_wide`, sums over the whole frame (its
    /// rect starts at the origin), by [`PixelSums::plus_independent`]; a tile with no sums yet
    /// counts as empty pixels. `frame_wide`'s refused samples are not added (count them once
    /// for the frame).
    pub fn plus_frame_wide(&self, frame_wide: &TileAccum) -> TileAccum {
        let r = self.rect;
        let fw = frame_wide.rect;
        assert!(
            fw.x0 == 0 && fw.y0 == 0 && r.x0 + r.width <= fw.width && r.y0 + r.height <= fw.height
        );
        let mut out =
            TileAccum { rect: r, pixels: Vec::with_capacity(r.area()), rejected: self.rejected };
        for row in 0..r.height {
            for col in 0..r.width {
                let own =
                    self.pixels.get((row * r.width + col) as usize).copied().unwrap_or_default();
                let other = frame_wide
                    .pixels
                    .get(((r.y0 + row) * fw.width + r.x0 + col) as usize)
                    .copied()
                    .unwrap_or_default();
                out.pixels.push(own.plus_independent(&other));
            }
        }
        out
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
            let var = p.estimated_variance();
            for v in var {
                sum_var += v;
            }
            ErrorEstimate::add_relative(&mut sum_rel, var, p.mean());
        }
        let n = (pixels.len() * 3).max(1) as f64;
        ErrorEstimate { rmse: (sum_var / n).sqrt(), rel_mse: sum_rel / n }
    }

    /// The relative MSE of the pixels of `rect` (`pixels`, row-major) as a share of another
    /// image's: each pixel's estimated variance over the square of `means` at that pixel (a
    /// frame `width` wide, row-major) instead of its own mean's. For the part of an image that
    /// one of two added estimates contributes (bidirectional path tracing's camera-traced and
    /// light-traced images), measured against the sum. Pixels not yet sampled count zero.
    pub fn rel_mse_against(
        pixels: &[PixelSums],
        rect: Rect,
        means: &[[f32; 3]],
        width: u32,
    ) -> f64 {
        let mut sum_rel = 0.0;
        for row in 0..rect.height {
            let from = (row * rect.width) as usize;
            let at = ((rect.y0 + row) * width + rect.x0) as usize;
            let own = pixels.get(from..from + rect.width as usize).unwrap_or_default();
            for (p, m) in own.iter().zip(&means[at..at + rect.width as usize]) {
                ErrorEstimate::add_relative(&mut sum_rel, p.estimated_variance(), m.map(f64::from));
            }
        }
        sum_rel / (rect.area() * 3).max(1) as f64
    }

    /// Adds a pixel's terms of `rel_mse` to `sum`: per channel, the variance of the mean `var`
    /// over the squared mean `mean` plus 0.01 (so that near-black pixels count their absolute
    /// error), channels in order.
    pub fn add_relative(sum: &mut f64, var: [f64; 3], mean: [f64; 3]) {
        for c in 0..3 {
            *sum += var[c] / (mean[c] * mean[c] + 0.01);
        }
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
    fn merging_in_order_matches_one_pass_and_empty_merges_are_exact() {
        let mut state = 7;
        let values: Vec<[f32; 3]> = (0..1000)
            .map(|_| [lcg(&mut state) * 1e3, lcg(&mut state) * 1e-3, lcg(&mut state).powi(8) * 1e6])
            .collect();
        let mut whole = PixelSums::default();
        for (i, v) in values.iter().enumerate() {
            whole.add(i as u32, *v);
        }
        // Three consecutive ranges, merged in order: the same statistics up to rounding.
        let mut parts = [PixelSums::default(); 3];
        for (i, v) in values.iter().enumerate() {
            parts[i * 3 / values.len()].add(i as u32, *v);
        }
        let mut merged = PixelSums::default();
        for p in &parts {
            merged.merge(p);
        }
        assert_eq!((merged.n, merged.n_odd), (whole.n, whole.n_odd));
        for c in 0..3 {
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1e-300);
            assert!(close(merged.mean[c], whole.mean[c]), "mean {c}");
            assert!((merged.m2[c] - whole.m2[c]).abs() <= 1e-10 * whole.m2[c], "m2 {c}");
            assert!(close(merged.mean_odd[c], whole.mean_odd[c]), "odd mean {c}");
        }
        // The same order gives the same bits; merging into or with an empty pixel changes none.
        let mut again = PixelSums::default();
        for p in &parts {
            again.merge(p);
        }
        assert_eq!(again, merged);
        let mut into_empty = PixelSums::default();
        into_empty.merge(&whole);
        into_empty.merge(&PixelSums::default());
        assert_eq!(into_empty, whole);
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
        assert!((ours - welford).abs() <= 1e-9 * welford, "{ours} vs {welford}");
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

    /// Statistics of real samples pass the check; each impossible value is refused with its
    /// channel, its name and the value.
    #[test]
    fn the_check_refuses_what_no_samples_give() {
        let mut state = 5;
        let mut honest = PixelSums::default();
        for i in 0..64 {
            // Some bright, some black, and a rounding-negative one (counted as zero).
            let v = if i % 7 == 0 { -1e-9 } else { lcg(&mut state).powi(4) * 1e4 };
            assert!(honest.add(i, [v, 0.0, MAX_SAMPLE_VALUE]));
        }
        assert_eq!(honest.check(64, 32), Ok(()));
        let max = MAX_SAMPLE_VALUE as f64;
        let cases: [(fn(&mut PixelSums, f64), &str); 8] = [
            (|p, _| p.mean[0] = -100.0, "channel 0: mean -100 is negative"),
            (|p, _| p.mean[1] = f64::NAN, "channel 1: mean NaN is not finite"),
            (|p, _| p.mean_odd[2] = -1.0, "channel 2: mean of odd samples -1 is negative"),
            (|p, _| p.m2[0] = -0.25, "channel 0: sum of squared deviations -0.25 is negative"),
            (|p, _| p.m2[1] = f64::INFINITY, "channel 1: sum of squared deviations inf is not"),
            (|p, _| p.mean[2] = 2e12, "channel 2: mean 2e12 is beyond the largest"),
            (|p, max| p.m2[2] = 17.0 * max * max, "more than 64 samples of at most 1e12"),
            (|p, _| p.n -= 1, "63 samples (32 odd), the task has 64 (32 odd)"),
        ];
        for (forge, message) in cases {
            let mut p = honest;
            forge(&mut p, max);
            let refused = p.check(64, 32).unwrap_err();
            assert!(refused.contains(message), "{refused}");
        }
        // Samples at the largest value pass (means and spread at their bounds).
        let mut bright = PixelSums::default();
        for i in 0..64 {
            bright.add(i, [if i % 2 == 0 { 0.0 } else { MAX_SAMPLE_VALUE }; 3]);
        }
        assert_eq!(bright.check(64, 32), Ok(()));
    }

    #[test]
    fn negative_samples_count_as_zero() {
        let mut p = PixelSums::default();
        assert!(p.add(0, [-0.5, 1.0, -1e-30]));
        assert_eq!(p.mean(), [0.0, 1.0, 0.0]);
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
