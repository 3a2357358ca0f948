//! The chi-square goodness-of-fit harness (after Mitsuba's `ChiSquareTest` in `chi2.py` and
//! pbrt-v4's `Chi2Test`): histogram samples over a grid, integrate the pdf over each cell, pool
//! small cells and compare, plus the p-value arithmetic and the suite's deterministic RNG.

use std::{collections::BinaryHeap, f64::consts::PI, fmt::Debug, fmt::Write as _, path::PathBuf};

use glam::{DVec2, DVec3, Vec2, Vec3};

use super::N_CHI2_TESTS;

/// Significance level of the whole suite; each test uses the Šidák-corrected level.
const SUITE_ALPHA: f64 = 0.01;

/// Cells expecting fewer samples than this are pooled together (both anchors use 5).
const MIN_EXPECTED: f64 = 5.0;

/// A sample that lands this far (as a fraction of the domain) outside the domain is an error;
/// closer ones are f32 rounding and go to the edge cell.
const DOMAIN_SLACK: f64 = 1e-4;

/// A cell with this many samples starts its quadrature one level finer, and another level at ten
/// times as many (10^6 samples over 5151 cells average 194 per cell).
const BUSY_CELL: f64 = 2000.0;

/// Samples allowed in cells whose expected count is exactly zero, as a fraction of all samples
/// (pbrt's `Chi2Test` tolerates 1e-5: f32 rounding puts the odd sample just past a support edge).
const ZERO_CELL_SLACK: f64 = 1e-5;

/// The per-test significance level: 1 - (1 - 0.01)^(1 / n_tests).
pub(super) fn sidak_alpha() -> f64 {
    1.0 - (1.0 - SUITE_ALPHA).powf(1.0 / N_CHI2_TESTS as f64)
}

/// splitmix64: small, fast and good enough to drive warps; seeded per test so runs repeat.
#[derive(Clone, Debug)]
pub(super) struct Rng(u64);

impl Rng {
    /// A generator whose seed is a hash (FNV-1a) of `name`, so each test has its own stream.
    pub(super) fn from_name(name: &str) -> Self {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for b in name.bytes() {
            h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
        Rng(h)
    }

    /// The next 64 random bits.
    pub(super) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) with 24 bits, like the renderer's sampler.
    pub(super) fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// Three uniform numbers.
    pub(super) fn next_vec3(&mut self) -> Vec3 {
        Vec3::new(self.next_f32(), self.next_f32(), self.next_f32())
    }
}

/// A 2D parameterisation of the space a warp samples, with the density of the measure.
pub(super) trait Domain {
    /// What a sample is: a direction or a point in the plane.
    type Point: Copy + Debug;
    /// Lower and upper corners of the parameter rectangle.
    fn bounds(&self) -> [DVec2; 2];
    /// Parameters of `p` (may fall outside `bounds` for a sample outside the domain).
    fn params(&self, p: Self::Point) -> DVec2;
    /// The point at parameters `x` and the measure's density there (solid angle or area per unit
    /// parameter area).
    fn point(&self, x: DVec2) -> (Self::Point, f64);
    /// Grid resolution along the two parameters when the test does not set one.
    fn default_resolution(&self) -> [usize; 2];
    /// Names of the parameters, for the failure report.
    fn axes(&self) -> [&'static str; 2];
}

/// Directions in a cap of half-angle `theta_max` around an axis, parameterised by (theta, phi)
/// in the cap's frame; the measure is solid angle (density sin theta).
#[derive(Clone, Copy, Debug)]
pub(super) struct Spherical {
    /// Local frame: x, y and the cap's axis z.
    frame: [DVec3; 3],
    /// Half-angle of the cap (pi for the whole sphere).
    theta_max: f64,
}

impl Spherical {
    /// The whole sphere around +z.
    pub(super) fn sphere() -> Self {
        Spherical::cap(Vec3::Z, PI)
    }

    /// The upper hemisphere (z >= 0), where reflection BSDFs live.
    pub(super) fn hemisphere() -> Self {
        Spherical::cap(Vec3::Z, 0.5 * PI)
    }

    /// The cap of half-angle `theta_max` around unit `axis`.
    pub(super) fn cap(axis: Vec3, theta_max: f64) -> Self {
        let n = axis.as_dvec3().normalize();
        // Duff et al. 2017, in f64.
        let sign = 1.0f64.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let x = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let y = DVec3::new(b, sign + n.y * n.y * a, -n.y);
        Spherical { frame: [x, y, n], theta_max: theta_max.clamp(1e-6, PI) }
    }
}

impl Domain for Spherical {
    type Point = Vec3;

    fn bounds(&self) -> [DVec2; 2] {
        [DVec2::new(0.0, -PI), DVec2::new(self.theta_max, PI)]
    }

    fn params(&self, p: Vec3) -> DVec2 {
        let d = p.as_dvec3();
        let [x, y, z] = self.frame.map(|axis| axis.dot(d));
        // atan2 instead of acos: accurate near the axis, where sharp lobes sit.
        DVec2::new((x * x + y * y).sqrt().atan2(z), y.atan2(x))
    }

    fn point(&self, x: DVec2) -> (Vec3, f64) {
        let (sin_t, cos_t) = x.x.sin_cos();
        let (sin_p, cos_p) = x.y.sin_cos();
        let [fx, fy, fz] = self.frame;
        let d = fx * (sin_t * cos_p) + fy * (sin_t * sin_p) + fz * cos_t;
        (d.as_vec3(), sin_t)
    }

    fn default_resolution(&self) -> [usize; 2] {
        [51, 101]
    }

    fn axes(&self) -> [&'static str; 2] {
        ["theta", "phi"]
    }
}

/// Directions in the open hemisphere around an axis, parameterised by their central (gnomonic)
/// projection (x/z, y/z) onto the plane z = 1 of a frame, over the rectangle [min, max]; the
/// measure is solid angle (density (1 + x² + y²)^(-3/2)). Great circles project to straight
/// lines, so the directions toward a triangle form a triangle here: its edges are as easy to
/// integrate as in the plane, even seen near the horizon, where (theta, phi) cells are hopeless.
#[derive(Clone, Copy, Debug)]
pub(super) struct Gnomonic {
    /// Local frame: x (along the tangent), y and the axis z.
    frame: [DVec3; 3],
    /// Lower corner in the projection plane.
    min: DVec2,
    /// Upper corner in the projection plane.
    max: DVec2,
}

impl Gnomonic {
    /// The frame with z = `axis` and x along `tangent` (made orthogonal), over [min, max].
    pub(super) fn new(axis: Vec3, tangent: Vec3, min: DVec2, max: DVec2) -> Self {
        let z = axis.as_dvec3().normalize();
        let t = tangent.as_dvec3();
        let x = (t - z * z.dot(t)).normalize();
        Gnomonic { frame: [x, z.cross(x), z], min, max }
    }

    /// Projection of `d` (any length); infinite behind the plane.
    pub(super) fn project(&self, d: DVec3) -> DVec2 {
        let [x, y, z] = self.frame.map(|axis| axis.dot(d));
        if z > 0.0 {
            DVec2::new(x / z, y / z)
        } else {
            DVec2::splat(f64::INFINITY)
        }
    }
}

impl Domain for Gnomonic {
    type Point = Vec3;

    fn bounds(&self) -> [DVec2; 2] {
        [self.min, self.max]
    }

    fn params(&self, p: Vec3) -> DVec2 {
        self.project(p.as_dvec3())
    }

    fn point(&self, x: DVec2) -> (Vec3, f64) {
        let [fx, fy, fz] = self.frame;
        let d = fx * x.x + fy * x.y + fz;
        let len2 = d.length_squared();
        ((d / len2.sqrt()).as_vec3(), len2.powf(-1.5))
    }

    fn default_resolution(&self) -> [usize; 2] {
        [101, 101]
    }

    fn axes(&self) -> [&'static str; 2] {
        ["x/z", "y/z"]
    }
}

/// Points in the rectangle [min, max]; the measure is area.
#[derive(Clone, Copy, Debug)]
pub(super) struct Planar {
    /// Lower corner.
    min: DVec2,
    /// Upper corner.
    max: DVec2,
}

impl Planar {
    /// The rectangle with corners `min` and `max`.
    pub(super) fn new(min: Vec2, max: Vec2) -> Self {
        Planar { min: min.as_dvec2(), max: max.as_dvec2() }
    }
}

impl Domain for Planar {
    type Point = Vec2;

    fn bounds(&self) -> [DVec2; 2] {
        [self.min, self.max]
    }

    fn params(&self, p: Vec2) -> DVec2 {
        p.as_dvec2()
    }

    fn point(&self, x: DVec2) -> (Vec2, f64) {
        (x.as_vec2(), 1.0)
    }

    fn default_resolution(&self) -> [usize; 2] {
        [101, 101]
    }

    fn axes(&self) -> [&'static str; 2] {
        ["x", "y"]
    }
}

/// One chi-square test of a warp against its pdf.
#[derive(Clone, Debug)]
pub(super) struct Chi2Test<D> {
    /// Names the test in messages, the RNG seed and the failure file.
    name: String,
    /// Where samples live.
    domain: D,
    /// Cells along each parameter (odd, as in Mitsuba, so no cell edge sits on a symmetry axis).
    res: [usize; 2],
    /// Samples drawn (failed draws included).
    n_samples: usize,
    /// Each cell is cut into at least 4^min_depth pieces before the adaptive quadrature starts
    /// (more in cells that caught many samples: see `run`).
    min_depth: u32,
    /// Most halvings per cell (bounds the cost where the pdf jumps inside a cell).
    max_pieces: usize,
    /// Whether every sample must have `pdf > 0` (off where `pdf` recomputes the support exactly
    /// and f32 rounding puts samples on the wrong side of an edge; `sample` then checks its own).
    check_sample_pdf: bool,
}

impl<D: Domain> Chi2Test<D> {
    /// A test with 10^6 samples at the domain's default resolution.
    pub(super) fn new(name: impl Into<String>, domain: D) -> Self {
        let res = domain.default_resolution();
        Chi2Test {
            name: name.into(),
            domain,
            res,
            n_samples: 1_000_000,
            min_depth: 1,
            max_pieces: 500,
            check_sample_pdf: true,
        }
    }

    /// Does not require `pdf > 0` at the samples (see `check_sample_pdf`).
    pub(super) fn without_sample_pdf_check(mut self) -> Self {
        self.check_sample_pdf = false;
        self
    }

    /// Draws `n` samples instead.
    pub(super) fn samples(mut self, n: usize) -> Self {
        self.n_samples = n;
        self
    }

    /// Runs the test: `sample` maps three uniform numbers to a point or fails (`None`); `pdf` is
    /// its density in the domain's measure. No I/O: call `Outcome::assert_passed` to fail.
    pub(super) fn run(
        &self,
        mut sample: impl FnMut(Vec3) -> Option<D::Point>,
        pdf: impl Fn(D::Point) -> f32,
    ) -> Outcome {
        let start = std::time::Instant::now();
        let [lo, hi] = self.domain.bounds();
        let [nx, ny] = self.res;
        let mut problems = Vec::new();
        let mut observed = vec![0.0f64; nx * ny];
        let mut failures = 0usize;
        let mut outside = 0usize;
        let mut bad_pdf = 0usize;
        let mut rng = Rng::from_name(&self.name);
        for _ in 0..self.n_samples {
            let u = rng.next_vec3();
            let Some(p) = sample(u) else {
                failures += 1;
                continue;
            };
            let density = if self.check_sample_pdf { pdf(p) } else { 1.0 };
            if !(density > 0.0 && density.is_finite()) {
                if bad_pdf == 0 {
                    problems.push(format!("pdf({p:?}) = {density} at a sample (u = {u:?})"));
                }
                bad_pdf += 1;
            }
            let t = (self.domain.params(p) - lo) / (hi - lo);
            if !(t.min_element() >= -DOMAIN_SLACK && t.max_element() <= 1.0 + DOMAIN_SLACK) {
                if outside == 0 {
                    problems.push(format!("sample {p:?} (u = {u:?}) is outside the domain"));
                }
                outside += 1;
                continue;
            }
            let ix = ((t.x * nx as f64) as usize).min(nx - 1);
            let iy = ((t.y * ny as f64) as usize).min(ny - 1);
            observed[ix * ny + iy] += 1.0;
        }
        if bad_pdf > 0 {
            problems.push(format!("{bad_pdf} samples had a pdf that is not positive and finite"));
        }
        if outside > 0 {
            problems.push(format!("{outside} samples fell outside the domain"));
        }

        let n = self.n_samples as f64;
        let density = |x: DVec2| {
            let (p, jacobian) = self.domain.point(x);
            pdf(p) as f64 * jacobian
        };
        let cell = (hi - lo) / DVec2::new(nx as f64, ny as f64);
        let mut expected = vec![0.0f64; nx * ny];
        for ix in 0..nx {
            for iy in 0..ny {
                let a = lo + cell * DVec2::new(ix as f64, iy as f64);
                let b = a + cell;
                // A fifth of the count's standard deviation, which adds at most 0.04 to the
                // statistic per cell. Cells that will be pooled need relative accuracy instead:
                // the pool may gather thousands of them, and their errors add up.
                let tol = |mass: f64| {
                    if mass * n >= MIN_EXPECTED {
                        0.2 * (mass / n).sqrt()
                    } else {
                        1e-3 * mass + 1e-4 / n
                    }
                };
                // A lobe narrower than the first pieces can slip between their quadrature
                // nodes, and then no error estimate sees it. Such a lobe draws many samples,
                // which also call for more accuracy: cut busy cells finer from the start.
                let count = observed[ix * ny + iy];
                let depth = self.min_depth
                    + u32::from(count >= BUSY_CELL)
                    + u32::from(count >= 10.0 * BUSY_CELL);
                let mass = integrate(&density, a, b, tol, depth, self.max_pieces);
                if !(mass >= 0.0 && mass.is_finite()) && problems.len() < 8 {
                    problems.push(format!("pdf integrates to {mass} over cell ({ix}, {iy})"));
                }
                expected[ix * ny + iy] = mass * n;
            }
        }
        let integral = expected.iter().sum::<f64>() / n;
        let success = (self.n_samples - failures) as f64 / n;
        // Binomial noise of the success rate plus quadrature error.
        let sigma = (success * (1.0 - success) / n).sqrt();
        let mismatch = (integral - success).abs();
        if mismatch.is_nan() || mismatch > 1e-3 + 5.0 * sigma {
            problems.push(format!(
                "the pdf integrates to {integral:.6} but {success:.6} of the samples succeeded"
            ));
        }

        // Failed draws are not a cell: their expected count, n minus the integral, would carry
        // the quadrature error of every cell (a few counts in 10^5) into a bin of a few hundred.
        // The integral check above covers them.
        let stat = chi2_statistic(&observed, &expected, self.n_samples);
        if let Err(e) = &stat {
            problems.push(e.clone());
        }
        Outcome {
            name: self.name.clone(),
            axes: self.domain.axes(),
            res: self.res,
            observed,
            expected,
            n_samples: self.n_samples,
            failures,
            integral,
            success,
            stat: stat.unwrap_or(Chi2Stat { chi2: f64::NAN, dof: 0, p_value: 0.0 }),
            alpha: sidak_alpha(),
            problems,
            seconds: start.elapsed().as_secs_f64(),
        }
    }
}

/// Runs a default `Chi2Test` and panics (after writing the tables) if it fails.
pub(super) fn assert_fits<D: Domain>(
    name: &str,
    domain: D,
    sample: impl FnMut(Vec3) -> Option<D::Point>,
    pdf: impl Fn(D::Point) -> f32,
) -> Outcome {
    let outcome = Chi2Test::new(name, domain).run(sample, pdf);
    outcome.assert_passed();
    outcome
}

/// 3-point Gauss-Legendre nodes on [-1, 1]: exact to degree 5, and never on a cell's edge, where
/// many pdfs jump.
const GAUSS_X: [f64; 3] = [-0.774_596_669_241_483_4, 0.0, 0.774_596_669_241_483_4];
/// Weights of `GAUSS_X`.
const GAUSS_W: [f64; 3] = [5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0];

/// Tensor-product Gauss-Legendre over the rectangle [a, b].
fn gauss(f: &impl Fn(DVec2) -> f64, a: DVec2, b: DVec2) -> f64 {
    let c = 0.5 * (a + b);
    let h = 0.5 * (b - a);
    let mut sum = 0.0;
    for (x, wx) in GAUSS_X.iter().zip(GAUSS_W) {
        for (y, wy) in GAUSS_X.iter().zip(GAUSS_W) {
            sum += wx * wy * f(c + h * DVec2::new(*x, *y));
        }
    }
    sum * h.x * h.y
}

/// A rectangle of the adaptive quadrature, with its estimate already halved along the axis
/// where halving changes it most.
struct Piece {
    /// The halves along the chosen axis: corners and Gauss estimates.
    halves: [(DVec2, DVec2, f64); 2],
    /// How much halving changed the estimate: the error estimate of the coarser one.
    error: f64,
}

impl Piece {
    fn new(f: &impl Fn(DVec2) -> f64, a: DVec2, b: DVec2, whole: f64) -> Self {
        let m = 0.5 * (a + b);
        let half = |ha: DVec2, hb: DVec2| (ha, hb, gauss(f, ha, hb));
        let x = [half(a, DVec2::new(m.x, b.y)), half(DVec2::new(m.x, a.y), b)];
        let y = [half(a, DVec2::new(b.x, m.y)), half(DVec2::new(a.x, m.y), b)];
        let error_x = (x[0].2 + x[1].2 - whole).abs();
        let error_y = (y[0].2 + y[1].2 - whole).abs();
        if error_x >= error_y {
            Piece { halves: x, error: error_x }
        } else {
            Piece { halves: y, error: error_y }
        }
    }

    fn estimate(&self) -> f64 {
        self.halves[0].2 + self.halves[1].2
    }
}

// Ordered by error, so that a max-heap pops the worst piece.
impl PartialEq for Piece {
    fn eq(&self, other: &Self) -> bool {
        self.error.total_cmp(&other.error).is_eq()
    }
}

impl Eq for Piece {}

impl PartialOrd for Piece {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Piece {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.error.total_cmp(&other.error)
    }
}

/// Globally adaptive quadrature of `f` over [a, b] (after QUADPACK's `qag`): cut the rectangle
/// into 4^`min_depth` pieces, then keep halving the piece with the largest error estimate, along
/// the axis where halving matters most, until the errors sum to at most `tol` or `max_pieces`
/// halvings were made. Halving one axis at a time resolves a pdf jump that runs along a grid axis
/// (a light's edge seen near the horizon) in a few dozen steps.
pub(super) fn integrate(
    f: &impl Fn(DVec2) -> f64,
    a: DVec2,
    b: DVec2,
    tol: impl Fn(f64) -> f64,
    min_depth: u32,
    max_pieces: usize,
) -> f64 {
    let n = 1usize << min_depth;
    let step = (b - a) / n as f64;
    let mut pieces = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let pa = a + step * DVec2::new(i as f64, j as f64);
            let pb = pa + step;
            pieces.push(Piece::new(f, pa, pb, gauss(f, pa, pb)));
        }
    }
    let tol = tol(pieces.iter().map(Piece::estimate).sum());
    let mut error: f64 = pieces.iter().map(|p| p.error).sum();
    let mut heap: BinaryHeap<Piece> = pieces.into();
    for _ in 0..max_pieces {
        // A NaN pdf stops here too; `run` reports the NaN mass.
        if error <= tol || error.is_nan() {
            break;
        }
        let worst = heap.pop().expect("pieces");
        error -= worst.error;
        for (ha, hb, estimate) in worst.halves {
            let piece = Piece::new(f, ha, hb, estimate);
            error += piece.error;
            heap.push(piece);
        }
    }
    heap.iter().map(Piece::estimate).sum()
}

/// A chi-square statistic and its upper-tail probability.
#[derive(Clone, Copy, Debug)]
pub(super) struct Chi2Stat {
    /// Sum of (observed - expected)² / expected over the (pooled) cells.
    pub(super) chi2: f64,
    /// Degrees of freedom: cells used minus one.
    pub(super) dof: usize,
    /// P(X >= chi2) for X ~ chi²(dof).
    pub(super) p_value: f64,
}

/// Pearson's statistic of `observed` against `expected` counts out of `n_samples` draws, pooling
/// cells that expect fewer than 5 (Mitsuba's and pbrt's rule: sort by expected count, pool the
/// smallest until the pool expects at least 5). An error if a cell that expects nothing got more
/// than 1e-5 of the samples.
pub(super) fn chi2_statistic(
    observed: &[f64],
    expected: &[f64],
    n_samples: usize,
) -> Result<Chi2Stat, String> {
    assert_eq!(observed.len(), expected.len());
    let mut order: Vec<usize> = (0..observed.len()).collect();
    order.sort_by(|&i, &j| expected[i].total_cmp(&expected[j]));
    let (mut pool_obs, mut pool_exp) = (0.0, 0.0);
    let (mut chi2, mut cells) = (0.0, 0usize);
    for i in order {
        let (o, e) = (observed[i], expected[i]);
        if e == 0.0 {
            if o > ZERO_CELL_SLACK * n_samples as f64 {
                return Err(format!("{o} samples in cell {i}, where the pdf is zero"));
            }
        } else if e < MIN_EXPECTED || (pool_exp > 0.0 && pool_exp < MIN_EXPECTED) {
            pool_obs += o;
            pool_exp += e;
        } else {
            chi2 += (o - e) * (o - e) / e;
            cells += 1;
        }
    }
    if pool_exp > 0.0 {
        chi2 += (pool_obs - pool_exp) * (pool_obs - pool_exp) / pool_exp;
        cells += 1;
    }
    if cells < 2 {
        return Err(format!("only {cells} cells after pooling: nothing to test"));
    }
    let dof = cells - 1;
    Ok(Chi2Stat { chi2, dof, p_value: chi2_p_value(chi2, dof) })
}

/// P(X >= chi2) for X ~ chi²(dof): the regularized upper incomplete gamma Q(dof/2, chi2/2).
pub(super) fn chi2_p_value(chi2: f64, dof: usize) -> f64 {
    gamma_q(0.5 * dof as f64, 0.5 * chi2)
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, n = 9; about 15 digits).
fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection keeps the series in its accurate range.
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut sum = C[0];
    for (i, c) in C.iter().enumerate().skip(1) {
        sum += c / (x + i as f64);
    }
    let t = x + G + 0.5;
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + sum.ln()
}

/// Regularized upper incomplete gamma Q(a, x) = Γ(a, x) / Γ(a): the power series for P below
/// x = a + 1, Lentz's continued fraction for Q above (Numerical Recipes §6.2).
pub(super) fn gamma_q(a: f64, x: f64) -> f64 {
    const EPS: f64 = 1e-15;
    const TINY: f64 = 1e-300;
    const MAX_ITER: usize = 100_000;
    assert!(a > 0.0 && x >= 0.0, "gamma_q({a}, {x})");
    if x == 0.0 {
        return 1.0;
    }
    let prefactor = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut ap, mut term) = (a, 1.0 / a);
        let mut sum = term;
        for _ in 0..MAX_ITER {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * EPS {
                break;
            }
        }
        (1.0 - sum * prefactor).max(0.0)
    } else {
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / TINY;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..MAX_ITER {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < TINY {
                d = TINY;
            }
            c = b + an / c;
            if c.abs() < TINY {
                c = TINY;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < EPS {
                break;
            }
        }
        (prefactor * h).clamp(0.0, 1.0)
    }
}

/// The result of one `Chi2Test::run`.
#[derive(Clone, Debug)]
pub(super) struct Outcome {
    /// The test's name.
    pub(super) name: String,
    /// Parameter names, for the tables.
    axes: [&'static str; 2],
    /// Grid resolution.
    res: [usize; 2],
    /// Samples per cell, row-major (first parameter = row).
    observed: Vec<f64>,
    /// Expected samples per cell.
    expected: Vec<f64>,
    /// Draws made.
    n_samples: usize,
    /// Draws for which `sample` returned `None`.
    failures: usize,
    /// Integral of the pdf over the domain.
    pub(super) integral: f64,
    /// Fraction of draws that produced a sample.
    pub(super) success: f64,
    /// The statistic and its p-value.
    pub(super) stat: Chi2Stat,
    /// The Šidák-corrected significance level.
    pub(super) alpha: f64,
    /// Everything wrong besides the p-value (pdf not positive at a sample, mass mismatch, ...).
    pub(super) problems: Vec<String>,
    /// Wall time of the run (sampling and quadrature).
    seconds: f64,
}

impl Outcome {
    /// True when the p-value clears the corrected level and nothing else went wrong.
    pub(super) fn passed(&self) -> bool {
        self.problems.is_empty() && self.stat.p_value > self.alpha
    }

    /// One line for the test log.
    pub(super) fn summary(&self) -> String {
        format!(
            "{}: chi2 = {:.1}, dof = {}, p = {:.4}, alpha = {:.2e}, integral = {:.6}, success = {:.6} ({:.2} s)",
            self.name,
            self.stat.chi2,
            self.stat.dof,
            self.stat.p_value,
            self.alpha,
            self.integral,
            self.success,
            self.seconds
        )
    }

    /// Prints the summary; on failure writes the tables to `target/chi2/<name>.txt` and panics
    /// with that path.
    pub(super) fn assert_passed(&self) {
        println!("{}", self.summary());
        if self.passed() {
            return;
        }
        let path = self.write_tables();
        panic!(
            "chi-square test failed: {}\n  {}\n  tables: {}",
            self.summary(),
            self.problems.join("\n  "),
            path.map_or_else(|e| format!("not written ({e})"), |p| p.display().to_string())
        );
    }

    fn write_tables(&self) -> std::io::Result<PathBuf> {
        let dir = std::env::var_os("CARGO_TARGET_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target"))
            .join("chi2");
        std::fs::create_dir_all(&dir)?;
        let file: String = self
            .name
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '.' { c } else { '_' })
            .collect();
        let path = dir.join(format!("{file}.txt"));
        let mut text = String::new();
        let _ = writeln!(text, "{}", self.summary());
        for p in &self.problems {
            let _ = writeln!(text, "problem: {p}");
        }
        let _ = writeln!(
            text,
            "failed draws: observed {}, expected {:.1}",
            self.failures,
            self.n_samples as f64 * (1.0 - self.integral)
        );
        let [nx, ny] = self.res;
        let [row, col] = self.axes;
        let tables: [(&str, &dyn Fn(usize) -> String); 3] = [
            ("observed", &|i| format!("{:.0}", self.observed[i])),
            ("expected", &|i| format!("{:.1}", self.expected[i])),
            ("residual (obs - exp) / sqrt(exp)", &|i| {
                let e = self.expected[i];
                if e > 0.0 {
                    format!("{:.2}", (self.observed[i] - e) / e.sqrt())
                } else {
                    format!("{:.0}", self.observed[i])
                }
            }),
        ];
        for (title, cell) in tables {
            let _ = writeln!(text, "\n# {title}: {nx} rows ({row}) x {ny} columns ({col})");
            for ix in 0..nx {
                let line: Vec<String> = (0..ny).map(|iy| cell(ix * ny + iy)).collect();
                let _ = writeln!(text, "{}", line.join(" "));
            }
        }
        std::fs::write(&path, text)?;
        Ok(path.canonicalize().unwrap_or(path))
    }
}

#[test]
fn p_value_matches_known_values() {
    // chi²(2) has survival exp(-x/2); chi²(1) has erfc(sqrt(x/2)).
    for x in [0.1, 1.0, 5.0, 30.0] {
        let p = chi2_p_value(x, 2);
        assert!((p - (-0.5 * x).exp()).abs() < 1e-12, "chi2(2) at {x}: {p}");
    }
    // erfc(sqrt(1.5)) and erfc(2), from tables.
    assert!((chi2_p_value(3.0, 1) - 0.083_264_516_663_550_4).abs() < 1e-10);
    assert!((chi2_p_value(8.0, 1) - 0.004_677_734_981_047_266).abs() < 1e-10);
    // Large dof: the median sits just below dof (Wilson-Hilferty), and 4 sigma out is ~3e-5.
    let dof = 5000;
    let p_mean = chi2_p_value(dof as f64, dof);
    assert!((p_mean - 0.4973).abs() < 1e-3, "{p_mean}");
    let p_tail = chi2_p_value(dof as f64 + 4.0 * (2.0 * dof as f64).sqrt(), dof);
    assert!(p_tail > 1e-5 && p_tail < 1e-4, "{p_tail}");
    assert!((ln_gamma(10.0) - 362_880.0f64.ln()).abs() < 1e-12);
    assert!((ln_gamma(0.5) - PI.sqrt().ln()).abs() < 1e-12);
}

#[test]
fn harness_rejects_a_wrong_pdf() {
    // Uniform directions against the cosine pdf must fail; against the right pdf they pass.
    use crate::render::sampling::{sample_uniform_sphere, uniform_sphere_pdf};
    let sample = |u: Vec3| {
        let w = sample_uniform_sphere(Vec2::new(u.x, u.y));
        Some(Vec3::new(w.x, w.y, w.z.abs()))
    };
    let test =
        Chi2Test::new("harness_rejects_a_wrong_pdf", Spherical::hemisphere()).samples(100_000);
    let wrong = test.run(sample, |w: Vec3| w.z.max(0.0) * std::f32::consts::FRAC_1_PI);
    assert!(!wrong.passed(), "{}", wrong.summary());
    let right = test.run(sample, |_| 2.0 * uniform_sphere_pdf());
    assert!(right.passed(), "{}", right.summary());
}
