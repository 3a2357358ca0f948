//! Wavelengths, for what bends light by colour (`KHR_materials_dispersion`).
//!
//! The renderer works in linear sRGB. A path that meets a dispersive boundary picks one
//! wavelength there (a hero wavelength whose companions a dispersive interface would end, as
//! pbrt-v4's `TerminateSecondary` does), and carries on at that wavelength alone: its RGB
//! throughput is weighted by the colour that light of that wavelength has,
//! `w(lambda) / p(lambda)`, where `w` is the CIE 1931 colour matching functions (the analytic
//! fit of Wyman, Sloan and Shirley 2013) taken to linear sRGB, their negative parts (the
//! spectral colours outside the sRGB gamut) clipped to 0, and scaled so that each channel's
//! integral over the visible range is 1; `p` is the density the wavelength was drawn with
//! (proportional to w_r + w_g + w_b, tabulated per nanometre). So in expectation white stays
//! white and every channel keeps its value, a path that crosses no dispersive boundary is
//! weighted by nothing, and no sample is negative (the film takes radiance only).

use std::sync::OnceLock;

use glam::Vec3;

/// The wavelengths sampled, in nanometres: [`LAMBDA_MIN`, `LAMBDA_MAX`).
pub const LAMBDA_MIN: f32 = 360.0;
/// See [`LAMBDA_MIN`].
pub const LAMBDA_MAX: f32 = 830.0;

/// The index of refraction at wavelength `lambda` (nanometres) of a material of index `n_d` at
/// 587.6 nm and `dispersion` 20 / V_d (Abbe number V_d), by `KHR_materials_dispersion`'s
/// two-term Cauchy equation: max(n_d + (n_d - 1) / V_d (523655 / lambda² - 1.5168), 1).
#[inline]
pub fn dispersive_ior(n_d: f32, dispersion: f32, lambda: f32) -> f32 {
    if dispersion <= 0.0 {
        return n_d;
    }
    let per_abbe = (n_d - 1.0) * dispersion / 20.0;
    (n_d + per_abbe * (523_655.0 / (lambda * lambda) - 1.5168)).max(1.0)
}

/// One lobe of the colour matching functions' fit: a Gaussian with a different width on each
/// side of its peak.
#[inline]
fn lobe(lambda: f64, mu: f64, below: f64, above: f64) -> f64 {
    let s = if lambda < mu { below } else { above };
    let t = (lambda - mu) / s;
    (-0.5 * t * t).exp()
}

/// CIE 1931 x-bar, y-bar, z-bar at `lambda` nm (Wyman, Sloan and Shirley 2013, multi-lobe fit).
pub fn xyz_bar(lambda: f64) -> [f64; 3] {
    let x = 1.056 * lobe(lambda, 599.8, 37.9, 31.0) + 0.362 * lobe(lambda, 442.0, 16.0, 26.7)
        - 0.065 * lobe(lambda, 501.1, 20.4, 26.2);
    let y = 0.821 * lobe(lambda, 568.8, 46.9, 40.5) + 0.286 * lobe(lambda, 530.9, 16.3, 31.1);
    let z = 1.217 * lobe(lambda, 437.0, 11.8, 36.0) + 0.681 * lobe(lambda, 459.0, 26.0, 13.8);
    [x, y, z]
}

/// Linear sRGB (D65) of the colour matching functions at `lambda`, clipped to the gamut's
/// non-negative part, before normalisation.
fn rgb_bar(lambda: f64) -> [f64; 3] {
    let [x, y, z] = xyz_bar(lambda);
    [
        3.2406 * x - 1.5372 * y - 0.4986 * z,
        -0.9689 * x + 1.8758 * y + 0.0415 * z,
        0.0557 * x - 0.2040 * y + 1.0570 * z,
    ]
    .map(|c| c.max(0.0))
}

/// The tabulated sampling distribution: per nanometre bin, w_r + w_g + w_b at the bin's
/// centre and its cumulative sum; and the channels' normalisation.
struct Table {
    /// 1 / the integral of each channel of `rgb_bar` over the range.
    norm: [f64; 3],
    /// The density's unnormalised value per bin.
    value: Vec<f64>,
    /// The cumulative sums of `value`, from 0 to `total`.
    cdf: Vec<f64>,
}

const BINS: usize = (LAMBDA_MAX - LAMBDA_MIN) as usize;

fn table() -> &'static Table {
    static TABLE: OnceLock<Table> = OnceLock::new();
    TABLE.get_or_init(|| {
        let centre = |i: usize| LAMBDA_MIN as f64 + i as f64 + 0.5;
        // Each channel's integral, by the midpoint rule on a finer grid (10 per nanometre).
        let mut integral = [0.0f64; 3];
        for k in 0..BINS * 10 {
            let c = rgb_bar(LAMBDA_MIN as f64 + (k as f64 + 0.5) / 10.0);
            for ch in 0..3 {
                integral[ch] += c[ch] / 10.0;
            }
        }
        let norm = integral.map(|v| 1.0 / v);
        let value: Vec<f64> = (0..BINS)
            .map(|i| {
                let c = rgb_bar(centre(i));
                (0..3).map(|ch| c[ch] * norm[ch]).sum()
            })
            .collect();
        let mut cdf = Vec::with_capacity(BINS + 1);
        cdf.push(0.0);
        for v in &value {
            cdf.push(cdf.last().unwrap() + v);
        }
        Table { norm, value, cdf }
    })
}

/// w(lambda): the linear sRGB colour of light of wavelength `lambda` nm, each channel scaled so
/// that its integral over [`LAMBDA_MIN`, `LAMBDA_MAX`) is 1.
pub fn rgb_weights(lambda: f32) -> Vec3 {
    let norm = table().norm;
    let c = rgb_bar(lambda as f64);
    Vec3::new((c[0] * norm[0]) as f32, (c[1] * norm[1]) as f32, (c[2] * norm[2]) as f32)
}

/// Density per nanometre of [`sample_wavelength`] drawing `lambda`.
pub fn wavelength_pdf(lambda: f32) -> f32 {
    let t = table();
    if !(LAMBDA_MIN..LAMBDA_MAX).contains(&lambda) {
        return 0.0;
    }
    let i = ((lambda - LAMBDA_MIN) as usize).min(BINS - 1);
    (t.value[i] / t.cdf[BINS]) as f32
}

/// A wavelength from uniform `u`, and the weight `w(lambda) / p(lambda)` a path takes on at it.
pub fn sample_wavelength(u: f32) -> (f32, Vec3) {
    let t = table();
    let target = u as f64 * t.cdf[BINS];
    // The last bin whose cumulative start is at most the target.
    let i = t.cdf.partition_point(|&c| c <= target).saturating_sub(1).min(BINS - 1);
    let within = if t.value[i] > 0.0 { (target - t.cdf[i]) / t.value[i] } else { 0.5 };
    let within = within.clamp(0.0, 1.0 - 1e-7);
    let lambda = LAMBDA_MIN + (i as f64 + within) as f32;
    let pdf = t.value[i] / t.cdf[BINS];
    // The weight at the bin's density (the density is constant over the bin).
    (lambda, rgb_weights(lambda) / pdf as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_channel_integrates_to_one_and_white_stays_white_in_expectation() {
        // The mean of the weights over many stratified wavelengths is (1, 1, 1).
        let n = 200_000;
        let mut sum = glam::DVec3::ZERO;
        for k in 0..n {
            let (_, w) = sample_wavelength((k as f32 + 0.5) / n as f32);
            sum += w.as_dvec3();
        }
        let mean = sum / n as f64;
        assert!((mean - glam::DVec3::ONE).abs().max_element() < 2e-3, "{mean}");
    }

    #[test]
    fn the_weights_have_the_colours_of_the_spectrum() {
        // Red light is red, green green, blue blue; the peak of y-bar (555 nm) is greenish.
        let red = rgb_weights(650.0);
        assert!(red.x > 0.0 && red.x > 5.0 * red.y && red.x > 5.0 * red.z, "{red}");
        for k in 0..470 {
            assert!(rgb_weights(360.5 + k as f32).min_element() >= 0.0);
        }
        let green = rgb_weights(530.0);
        assert!(green.y > green.x && green.y > green.z, "{green}");
        let blue = rgb_weights(450.0);
        assert!(blue.z > blue.x && blue.z > blue.y, "{blue}");
    }

    #[test]
    fn sampled_wavelengths_follow_their_density() {
        // Chi-square over 47 bins of 10 nm.
        let n = 100_000;
        let bins = 47;
        let mut counts = vec![0u64; bins];
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        for _ in 0..n {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            let u = (rng >> 40) as f32 / (1u64 << 24) as f32;
            let (lambda, _) = sample_wavelength(u);
            assert!((LAMBDA_MIN..LAMBDA_MAX).contains(&lambda));
            counts[(((lambda - LAMBDA_MIN) / 10.0) as usize).min(bins - 1)] += 1;
        }
        let mut chi2 = 0.0;
        let mut dof = 0;
        for (b, &count) in counts.iter().enumerate() {
            let expected: f64 = (0..10)
                .map(|k| wavelength_pdf(LAMBDA_MIN + (b * 10 + k) as f32 + 0.5) as f64)
                .sum::<f64>()
                * n as f64;
            if expected < 5.0 {
                continue;
            }
            chi2 += (count as f64 - expected).powi(2) / expected;
            dof += 1;
        }
        // The 99.9th percentile of chi-square with about 45 degrees of freedom is about 80.
        assert!(chi2 < 80.0, "chi-square {chi2} over {dof} bins");
    }

    #[test]
    fn dispersion_follows_the_cauchy_equation_through_n_d() {
        assert_eq!(dispersive_ior(1.5, 0.0, 400.0), 1.5);
        assert!((dispersive_ior(1.5, 1.0, 587.56) - 1.5).abs() < 1e-4);
        // V_d = 20 / dispersion = n_d - 1 over n_F - n_C.
        let spread = dispersive_ior(1.5, 0.5, 486.1) - dispersive_ior(1.5, 0.5, 656.3);
        assert!((spread - 0.5 / 40.0).abs() < 1e-4, "{spread}");
        assert_eq!(dispersive_ior(1.01, 200.0, 830.0), 1.0);
    }
}
