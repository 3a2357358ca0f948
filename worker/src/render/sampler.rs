//! The deterministic sampler: the numbers for sample `s` of pixel `p` in frame `f` are a pure
//! function of (seed, f, p, s, dimension).
//!
//! Padded Owen-scrambled Sobol (pbrt-v4 `PaddedSobolSampler`, Burley 2020): each 1D or 2D draw
//! uses the first two Sobol dimensions at a sample index that is itself Owen-scrambled with a
//! hash of (pixel, dimension), and the point is Owen-scrambled with another hash. Any aligned
//! block of 2^k sample indices (for example the samples [64, 128) of one task) is a stratified
//! (0, k, 2)-net on its own, so splitting a pixel's samples into tasks loses no stratification.
//!
//! Even and odd sample indices are two independently scrambled sequences (sample `s` is number
//! `s / 2` of sequence `s % 2`): two independent randomised estimates whose difference tells the
//! film its real error (`common::film::PixelSums::half_difference_variance`).
//!
//! Frame-wide sequences (`Sampler::frame_point`) are the other kind: one point per index of a
//! sequence shared by a whole frame (a pass's photons, a light-traced film's subpaths), a pure
//! function of (seed, f, sequence, index), for numbers that should cover their domain evenly
//! across many paths together.

use glam::{UVec2, Vec2};
use pulp::Simd;

use super::lanes::{BIT_STEPS, F, M, U, U64};

/// Per-pixel sample generator. Create one per thread and call `start_pixel_sample` for every
/// sample: it holds no state that outlives a sample (but a cache of the frame-wide sequences'
/// seeds, which depend on the job, frame and sequence alone).
#[derive(Clone, Debug)]
pub struct Sampler {
    /// Hash of (seed, frame): the job-level scramble.
    base: u64,
    /// Hash of (base, pixel) for the current sample.
    pixel_hash: u64,
    /// The sample index within its sequence, bit-reversed (every draw needs it so).
    sample_idx_reversed: u32,
    /// Next dimension to draw.
    dimension: u32,
    /// The scramble seeds of the frame-wide sequence (and block of 2^32 points) last drawn
    /// from (`frame_point`), which depend on the job, frame and sequence alone.
    frame_seeds: (Option<(u64, u64)>, [u32; FRAME_DIMENSIONS]),
}

impl Sampler {
    /// A sampler for frame `frame` of a job with seed `seed`.
    pub fn new(seed: u64, frame: i64) -> Self {
        let base = mix64(seed ^ mix64(frame as u64 ^ 0x9e37_79b9_7f4a_7c15));
        Sampler {
            base,
            pixel_hash: 0,
            sample_idx_reversed: 0,
            dimension: 0,
            frame_seeds: (None, [0; FRAME_DIMENSIONS]),
        }
    }

    /// Positions the sampler at sample `sample_idx` of `pixel`, dimension 0.
    #[inline]
    pub fn start_pixel_sample(&mut self, pixel: UVec2, sample_idx: u32) {
        let half = (sample_idx & 1) as u64;
        self.pixel_hash =
            mix64(self.base ^ mix64(((pixel.x as u64) << 32) | pixel.y as u64) ^ (half << 63));
        self.sample_idx_reversed = (sample_idx >> 1).reverse_bits();
        self.dimension = 0;
    }

    #[inline]
    fn dimension_hash(&mut self) -> u64 {
        let d = self.dimension;
        self.dimension += 1;
        mix64(self.pixel_hash ^ (d as u64).wrapping_mul(DIMENSION_MULTIPLIER))
    }

    /// Moves to dimension `d` of the current sample: a part of the sample that draws an
    /// unbounded number of dimensions (bidirectional path tracing's light subpath) starts at a
    /// fixed dimension of its own, so that the camera subpath's numbers never reach it.
    #[inline]
    pub fn set_dimension(&mut self, d: u32) {
        self.dimension = d;
    }

    /// Passes over `n` dimensions without computing them (a draw this sample does not need,
    /// so that later draws keep their dimensions).
    #[inline]
    pub fn skip(&mut self, n: u32) {
        self.dimension += n;
    }

    /// The next uniform number in [0, 1).
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        let h = self.dimension_hash();
        // The index, Owen-scrambled: reverse(LK(reverse(i))). Its first Sobol dimension is its
        // bit reversal, and Owen scrambling that point is reverse(LK(reverse(point))), so the
        // reversals pair up and cancel: point = reverse(LK(index, seed)).
        let index = laine_karras_permutation(self.sample_idx_reversed, h as u32).reverse_bits();
        to_unit(laine_karras_permutation(index, (h >> 32) as u32).reverse_bits())
    }

    /// The next pair of uniform numbers in [0, 1)², stratified jointly.
    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        let h = self.dimension_hash();
        let index = laine_karras_permutation(self.sample_idx_reversed, h as u32).reverse_bits();
        let seed_y = (h.wrapping_mul(SEED_Y_MULTIPLIER) >> 32) as u32;
        Vec2::new(
            to_unit(laine_karras_permutation(index, (h >> 32) as u32).reverse_bits()),
            to_unit(laine_karras_permutation(sobol_1_reversed(index), seed_y).reverse_bits()),
        )
    }
}

/// How many numbers a point of a frame-wide sequence has (`Sampler::frame_point`).
pub const FRAME_DIMENSIONS: usize = 5;

impl Sampler {
    /// Point `index` of the frame-wide sequence `sequence` of this job and frame: the first
    /// `FRAME_DIMENSIONS` dimensions of the Sobol sequence at that index, Owen-scrambled (each
    /// dimension with its own seed from the job, frame and sequence), so that each point is
    /// uniform on its own while any 2^k consecutive points aligned on 2^k form a (t, k, 5)-net:
    /// numbers drawn across many paths (a photon pass's photons, a light-traced film's subpaths)
    /// cover their domain evenly together, where the per-pixel sequences stratify each pixel's
    /// samples only. (Not for numbers a pixel needs stratified over its own samples: indexed by
    /// sample and pixel, one pixel's points share the index's low bits, so its first dimension
    /// stays in a few strata.) Every 2^32 points start another independently scrambled net.
    /// The sampler's pixel sample is left as it was.
    pub fn frame_point(&mut self, sequence: u64, index: u64) -> [f32; FRAME_DIMENSIONS] {
        let key = (sequence, index >> 32);
        if self.frame_seeds.0 != Some(key) {
            let h = mix64(self.base ^ mix64(sequence ^ mix64(index >> 32)));
            let seeds = std::array::from_fn(|d| {
                mix64(h ^ (d as u64 + 1).wrapping_mul(DIMENSION_MULTIPLIER)) as u32
            });
            self.frame_seeds = (Some(key), seeds);
        }
        let (i, seeds) = (index as u32, &self.frame_seeds.1);
        // Owen scrambling is reverse(LK(reverse(x))); the tables hold the points reversed.
        std::array::from_fn(|d| {
            to_unit(laine_karras_permutation(sobol_reversed(d, i), seeds[d]).reverse_bits())
        })
    }
}

/// Joe and Kuo's primitive polynomials and initial direction numbers (`new-joe-kuo-6.21201`)
/// for Sobol dimensions 1 to 4 (dimension 0 is van der Corput's): the degree `s`, the
/// polynomial's inner coefficients `a` and `m_1..m_s`.
const SOBOL_PARAMETERS: [(usize, u32, [u32; 3]); FRAME_DIMENSIONS - 1] =
    [(1, 0, [1, 0, 0]), (2, 1, [1, 3, 0]), (3, 1, [1, 3, 1]), (3, 2, [1, 1, 1])];

/// The generator matrices (columns as 32-bit binary fractions) of Sobol dimensions 0 to 4, by
/// Bratley and Fox's recurrence for the direction numbers m_i.
const SOBOL_MATRICES: [[u32; 32]; FRAME_DIMENSIONS] = {
    let mut out = [[0u32; 32]; FRAME_DIMENSIONS];
    let mut j = 0;
    while j < 32 {
        out[0][j] = 1 << (31 - j);
        j += 1;
    }
    let mut d = 1;
    while d < FRAME_DIMENSIONS {
        let (s, a, m0) = SOBOL_PARAMETERS[d - 1];
        let mut m = [0u32; 32];
        let mut i = 0;
        while i < 32 {
            if i < s {
                m[i] = m0[i];
            } else {
                // m_i = 2 a_1 m_{i-1} ^ 4 a_2 m_{i-2} ^ ... ^ 2^s m_{i-s} ^ m_{i-s}.
                let mut v = m[i - s] ^ (m[i - s] << s);
                let mut k = 1;
                while k < s {
                    if (a >> (s - 1 - k)) & 1 == 1 {
                        v ^= m[i - k] << k;
                    }
                    k += 1;
                }
                m[i] = v;
            }
            out[d][i] = m[i] << (31 - i);
            i += 1;
        }
        d += 1;
    }
    out
};

/// `SOBOL_MATRICES` by bytes of the index, bits reversed: entry `[d][k][b]` is the XOR of
/// dimension `d`'s columns `8k..8k + 8` selected by the bits of `b` (20 KiB, four loads a
/// dimension).
static SOBOL_BYTES: [[[u32; 256]; 4]; FRAME_DIMENSIONS] = {
    let mut out = [[[0u32; 256]; 4]; FRAME_DIMENSIONS];
    let mut d = 0;
    while d < FRAME_DIMENSIONS {
        let mut k = 0;
        while k < 4 {
            let mut b = 1usize;
            while b < 256 {
                // The entry of `b` is that of `b` without its lowest bit, plus that bit's column.
                let low = b.trailing_zeros() as usize;
                out[d][k][b] =
                    out[d][k][b & (b - 1)] ^ SOBOL_MATRICES[d][8 * k + low].reverse_bits();
                b += 1;
            }
            k += 1;
        }
        d += 1;
    }
    out
};

/// Dimension `d` of the Sobol point `i` as a 32-bit binary fraction, bits reversed.
#[inline]
fn sobol_reversed(d: usize, i: u32) -> u32 {
    let t = &SOBOL_BYTES[d];
    let [b0, b1, b2, b3] = i.to_le_bytes();
    t[0][b0 as usize] ^ t[1][b1 as usize] ^ t[2][b2 as usize] ^ t[3][b3 as usize]
}

/// Spreads a dimension's index over the hash (a sample's dimensions differ in many bits).
const DIMENSION_MULTIPLIER: u64 = 0xd1b5_4a32_d192_ed03;
/// Derives the second coordinate's scramble seed from a 2D draw's hash.
const SEED_Y_MULTIPLIER: u64 = 0x9e37_79b9_7f4a_7c15;
/// The splitmix64 finaliser's multipliers.
const MIX64_MULTIPLIERS: [u64; 2] = [0xbf58_476d_1ce4_e5b9, 0x94d0_49bb_1331_11eb];
/// Burley's improved Laine-Karras multipliers.
const LK_MULTIPLIERS: [u32; 4] = [0x6c50_b47c, 0xb82f_1e52, 0xc7af_e638, 0x8d22_f6e6];

/// A strong 64-bit mixer (the splitmix64 finaliser).
#[inline]
pub fn mix64(mut x: u64) -> u64 {
    x ^= x >> 30;
    x = x.wrapping_mul(MIX64_MULTIPLIERS[0]);
    x ^= x >> 27;
    x = x.wrapping_mul(MIX64_MULTIPLIERS[1]);
    x ^ (x >> 31)
}

/// First Sobol dimension (van der Corput): the bits of `i` reversed.
#[inline]
#[cfg(test)]
fn sobol_0(i: u32) -> u32 {
    i.reverse_bits()
}

/// Generator matrix columns of the second Sobol dimension: v_0 = 2^31, v_j = v_{j-1} ^ (v_{j-1} >> 1).
#[cfg(test)]
const SOBOL_1_COLUMNS: [u32; 32] = {
    let mut v = [0u32; 32];
    v[0] = 1 << 31;
    let mut j = 1;
    while j < 32 {
        v[j] = v[j - 1] ^ (v[j - 1] >> 1);
        j += 1;
    }
    v
};

/// Second Sobol dimension: the XOR of the columns selected by the bits of `i`.
#[cfg(test)]
fn sobol_1(mut i: u32) -> u32 {
    let mut x = 0;
    while i != 0 {
        x ^= SOBOL_1_COLUMNS[i.trailing_zeros() as usize];
        i &= i - 1;
    }
    x
}

/// The second Sobol dimension with its bits reversed. Its generator matrix is Pascal's triangle
/// mod 2: column `j` has bit `k` (counted from the top, so bit `k` of the reversed value) set
/// where `k` is a submask of `j` (Lucas). Bit `k` of the result is therefore the parity of the
/// index's set bits `j` that contain `k`: a superset sum over GF(2), five shift-and-xor steps.
#[inline]
fn sobol_1_reversed(mut i: u32) -> u32 {
    for (n, mask) in BIT_STEPS {
        i ^= (i >> n) & mask;
    }
    i
}

/// Burley's improved Laine-Karras hash: each bit is flipped by a function of the lower bits.
#[inline]
fn laine_karras_permutation(mut x: u32, seed: u32) -> u32 {
    x = x.wrapping_add(seed);
    for k in LK_MULTIPLIERS {
        x ^= x.wrapping_mul(k);
    }
    x
}

/// Owen scrambling of a binary fraction (each bit flipped by a hash of the bits above it).
#[cfg(test)]
fn nested_uniform_scramble(x: u32, seed: u32) -> u32 {
    laine_karras_permutation(x.reverse_bits(), seed).reverse_bits()
}

#[inline]
pub(crate) fn to_unit(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// The samplers of a vector's lanes, drawing for all of them at once: each lane's numbers are
/// bit for bit those its `Sampler` would draw (the same integer arithmetic, lane by lane), for the
/// wavefront renderer. A lane takes its state from a `Sampler` that started its pixel sample.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LaneSampler<S: Simd> {
    pixel_hash: U64<S>,
    sample_idx_reversed: U<S>,
    dimension: U<S>,
}

impl<S: Simd> LaneSampler<S> {
    /// Every lane at pixel hash 0, sample 0, dimension 0 (set lanes before drawing).
    #[inline(always)]
    pub(crate) fn new(s: S) -> Self {
        LaneSampler {
            pixel_hash: U64::splat(s, 0),
            sample_idx_reversed: U::splat(s, 0),
            dimension: U::splat(s, 0),
        }
    }

    /// Lane `i` continues where `sampler` stands.
    #[inline(always)]
    pub(crate) fn set_lane(&mut self, i: usize, sampler: &Sampler) {
        self.pixel_hash.set_lane(i, sampler.pixel_hash);
        self.sample_idx_reversed.set_lane(i, sampler.sample_idx_reversed);
        self.dimension.set_lane(i, sampler.dimension);
    }

    /// Dimension `dimension + offset`'s hash (`Sampler::dimension_hash`).
    #[inline(always)]
    fn hash(&self, offset: u32) -> U64<S> {
        let s = self.dimension.s();
        let d = self.dimension.wrapping_add(U::splat(s, offset));
        let spread = U64 { lo: d, hi: U::splat(s, 0) }.wrapping_mul(DIMENSION_MULTIPLIER);
        let x = self.pixel_hash.xor(spread).xor_shr(30).wrapping_mul(MIX64_MULTIPLIERS[0]);
        x.xor_shr(27).wrapping_mul(MIX64_MULTIPLIERS[1]).xor_shr(31)
    }

    /// `Sampler::next_1d` at `dimension + offset`, every lane (the dimension does not move).
    #[inline(always)]
    pub(crate) fn draw_1d(&self, offset: u32) -> F<S> {
        let h = self.hash(offset);
        let index = lk_lanes(self.sample_idx_reversed, h.lo).reverse_bits();
        to_unit_lanes(lk_lanes(index, h.hi).reverse_bits())
    }

    /// `Sampler::next_2d` at `dimension + offset`, every lane (the dimension does not move).
    #[inline(always)]
    pub(crate) fn draw_2d(&self, offset: u32) -> (F<S>, F<S>) {
        let h = self.hash(offset);
        let index = lk_lanes(self.sample_idx_reversed, h.lo).reverse_bits();
        let seed_y = h.wrapping_mul(SEED_Y_MULTIPLIER).hi;
        (
            to_unit_lanes(lk_lanes(index, h.hi).reverse_bits()),
            to_unit_lanes(lk_lanes(sobol_1_reversed_lanes(index), seed_y).reverse_bits()),
        )
    }

    /// Moves the lanes in `m` on by `n` dimensions.
    #[inline(always)]
    pub(crate) fn advance(&mut self, m: M<S>, n: u32) {
        let s = self.dimension.s();
        self.dimension = m.select_u(self.dimension.wrapping_add(U::splat(s, n)), self.dimension);
    }
}

/// `laine_karras_permutation`, lane by lane.
#[inline(always)]
fn lk_lanes<S: Simd>(x: U<S>, seed: U<S>) -> U<S> {
    let mut x = x.wrapping_add(seed);
    for k in LK_MULTIPLIERS {
        x = x ^ x.wrapping_mul(U::splat(x.s(), k));
    }
    x
}

/// `sobol_1_reversed`, lane by lane.
#[inline(always)]
fn sobol_1_reversed_lanes<S: Simd>(mut i: U<S>) -> U<S> {
    for (n, mask) in BIT_STEPS {
        i = i ^ (i.shr(n) & U::splat(i.s(), mask));
    }
    i
}

/// `to_unit`, lane by lane.
#[inline(always)]
fn to_unit_lanes<S: Simd>(x: U<S>) -> F<S> {
    x.shr(8).small_to_f32() * F::splat(x.s(), 1.0 / (1u32 << 24) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_depend_only_on_pixel_sample_and_dimension() {
        let mut a = Sampler::new(3, 0);
        let mut b = Sampler::new(3, 0);
        b.start_pixel_sample(UVec2::new(9, 9), 77);
        b.next_2d();
        a.start_pixel_sample(UVec2::new(5, 6), 41);
        let first = (a.next_1d(), a.next_2d(), a.next_1d());
        b.start_pixel_sample(UVec2::new(5, 6), 41);
        assert_eq!(first, (b.next_1d(), b.next_2d(), b.next_1d()));
        let mut c = Sampler::new(4, 0);
        c.start_pixel_sample(UVec2::new(5, 6), 41);
        assert_ne!(first.0, c.next_1d(), "seed must matter");
        let mut d = Sampler::new(3, 1);
        d.start_pixel_sample(UVec2::new(5, 6), 41);
        assert_ne!(first.0, d.next_1d(), "frame must matter");
    }

    /// Every aligned block of 2^k samples is a (0, k, 2)-net: each elementary interval of area
    /// 2^-k holds exactly one point, for every dimension pair and any block offset.
    #[test]
    fn aligned_blocks_are_stratified_nets() {
        let mut s = Sampler::new(0, 0);
        for (log_n, offset) in [(4u32, 0u32), (6, 64), (6, 128), (8, 256), (5, 1 << 20)] {
            let n = 1u32 << log_n;
            for dim in 0..6 {
                // Even sample indices 2i: consecutive points i of one of the two sequences.
                let points: Vec<Vec2> = (offset..offset + n)
                    .map(|i| {
                        s.start_pixel_sample(UVec2::new(3, 17), 2 * i);
                        for _ in 0..dim {
                            s.next_2d();
                        }
                        s.next_2d()
                    })
                    .collect();
                for log_x in 0..=log_n {
                    let (nx, ny) = (1u32 << log_x, 1u32 << (log_n - log_x));
                    let mut seen = vec![false; n as usize];
                    for p in &points {
                        let cell = (p.x * nx as f32) as u32 + nx * (p.y * ny as f32) as u32;
                        assert!(
                            !seen[cell as usize],
                            "block {offset}+{n} dim {dim}: cell {cell} twice"
                        );
                        seen[cell as usize] = true;
                    }
                }
            }
        }
    }

    #[test]
    fn one_dimensional_draws_are_stratified_and_uniform() {
        let mut s = Sampler::new(1, 0);
        let n = 1024;
        let mut seen = vec![false; n];
        let mut mean = 0.0f64;
        for i in 0..n as u32 {
            s.start_pixel_sample(UVec2::new(0, 0), 2 * i + 1);
            s.next_2d();
            let u = s.next_1d();
            assert!((0.0..1.0).contains(&u));
            let cell = (u * n as f32) as usize;
            assert!(!seen[cell], "cell {cell} twice");
            seen[cell] = true;
            mean += u as f64;
        }
        assert!((mean / n as f64 - 0.5).abs() < 1e-3);
    }

    #[test]
    fn sobol_dimensions_match_their_definitions() {
        // Dimension 1 is a (0, 1)-sequence too: the first 2^k points hit every 2^-k interval.
        for k in 0..12 {
            let n = 1u32 << k;
            let mut seen = vec![false; n as usize];
            for i in 0..n {
                let cell = (sobol_1(i) >> (32 - k.max(1))) as usize * (k > 0) as usize;
                assert!(!seen[cell] || k == 0, "k {k}: cell {cell} twice");
                seen[cell] = true;
            }
        }
        assert_eq!(sobol_0(1), 1 << 31);
        assert_eq!(sobol_1(3), (1 << 31) ^ (3 << 30));
        let mut i = 0u32;
        for k in 0..100_000u64 {
            assert_eq!(sobol_1_reversed(i), sobol_1(i).reverse_bits(), "index {i}");
            i = mix64(k) as u32;
        }
        for i in [1u32, 2, 3, 77, 1023, 65_535, u32::MAX] {
            assert_eq!(sobol_1_reversed(i), sobol_1(i).reverse_bits());
        }
        // The fast draw equals the textbook composition: Owen-scrambled point of the
        // Owen-scrambled index.
        let (i, seed_index, seed_point) = (12_345u32, 0xdead_beefu32, 0x1234_5678u32);
        let index = nested_uniform_scramble(i, seed_index);
        let textbook = nested_uniform_scramble(sobol_0(index), seed_point);
        let fast = laine_karras_permutation(
            laine_karras_permutation(i.reverse_bits(), seed_index).reverse_bits(),
            seed_point,
        )
        .reverse_bits();
        assert_eq!(fast, textbook);
    }

    /// The frame-wide sequence's matrices are Sobol's: dimension 1 is the one the per-pixel
    /// sampler uses, each dimension's first 2^k points hit every interval of length 2^-k, and
    /// its pairs of dimensions have the t-values of Joe and Kuo's first five dimensions (0 for
    /// the first two, at most 2 otherwise, up to 2^12 points).
    #[test]
    fn frame_sequences_are_sobol_nets() {
        // The byte tables give the matrices' product, bit by bit.
        let by_bits = |d: usize, mut i: u32| {
            let mut x = 0;
            while i != 0 {
                x ^= SOBOL_MATRICES[d][i.trailing_zeros() as usize];
                i &= i - 1;
            }
            x
        };
        for k in 0..20_000u64 {
            let i = mix64(k) as u32;
            for d in 0..FRAME_DIMENSIONS {
                assert_eq!(
                    sobol_reversed(d, i),
                    by_bits(d, i).reverse_bits(),
                    "dimension {d} index {i}"
                );
            }
        }
        // Joe and Kuo's dimensions 3 to 5 as tabulated elsewhere (pbrt-v4's `SobolMatrices32`).
        let published: [[u32; 6]; 3] = [
            [0x8000_0000, 0xc000_0000, 0x6000_0000, 0x9000_0000, 0xe800_0000, 0x5c00_0000],
            [0x8000_0000, 0xc000_0000, 0x2000_0000, 0x5000_0000, 0xf800_0000, 0x7400_0000],
            [0x8000_0000, 0x4000_0000, 0x2000_0000, 0xb000_0000, 0xf800_0000, 0xdc00_0000],
        ];
        for (d, columns) in published.iter().enumerate() {
            assert_eq!(&SOBOL_MATRICES[d + 2][..6], columns, "dimension {}", d + 2);
        }
        for i in (0..4096u32).chain([65_535, 1 << 31, u32::MAX]) {
            assert_eq!(sobol_reversed(1, i), sobol_1(i).reverse_bits(), "index {i}");
            assert_eq!(sobol_reversed(0, i), i, "index {i}");
        }
        // The t-value of dimensions (a, b) over the first 2^k points: the least t for which
        // every elementary interval of area 2^(t - k) holds 2^t points.
        let t_value = |a: usize, b: usize, k: u32, at: &dyn Fn(usize, u32) -> u32| -> u32 {
            (0..=k)
                .find(|&t| {
                    (0..=k - t).all(|kx| {
                        let ky = k - t - kx;
                        let mut count = vec![0u32; 1 << (k - t)];
                        for i in 0..1u32 << k {
                            let (x, y) = (at(a, i) as u64, at(b, i) as u64);
                            let cell = (x >> (32 - kx)) | ((y >> (32 - ky)) << kx);
                            count[cell as usize] += 1;
                        }
                        count.iter().all(|&c| c == 1 << t)
                    })
                })
                .unwrap()
        };
        for d in 0..FRAME_DIMENSIONS {
            let mut seen = vec![false; 4096];
            for i in 0..4096 {
                let cell = (by_bits(d, i) >> 20) as usize;
                assert!(!seen[cell], "dimension {d}: cell {cell} twice");
                seen[cell] = true;
            }
        }
        for a in 0..FRAME_DIMENSIONS {
            for b in a + 1..FRAME_DIMENSIONS {
                let t = t_value(a, b, 12, &|d, i| by_bits(d, i));
                let most = if (a, b) == (0, 1) { 0 } else { 2 };
                assert!(t <= most, "dimensions ({a}, {b}): t = {t}");
            }
        }
        // Scrambled, an aligned block of 2^k points of the frame sequence keeps the t-values of
        // the first 2^k points (it is those points digitally shifted, and Owen scrambling maps
        // elementary intervals onto elementary intervals).
        let mut s = Sampler::new(7, 2);
        for (k, offset) in [(8u32, 0u64), (10, 1 << 10), (6, (1 << 32) + 64)] {
            let points: Vec<[f32; FRAME_DIMENSIONS]> =
                (offset..offset + (1 << k)).map(|i| s.frame_point(3, i)).collect();
            let at = |d: usize, i: u32| ((points[i as usize][d] as f64) * 2f64.powi(32)) as u32;
            for a in 0..FRAME_DIMENSIONS {
                for b in a + 1..FRAME_DIMENSIONS {
                    let t = t_value(a, b, k, &at);
                    let want = t_value(a, b, k, &|d, i| by_bits(d, i));
                    assert!(t <= want, "block {offset}+2^{k}: ({a}, {b}) t = {t}, not {want}");
                }
            }
        }
    }

    /// Each point of a frame-wide sequence is uniform over its scrambles: a chi-square test of
    /// one index's points over 20,000 sequences, in 8x8 cells of every pair of dimensions and at
    /// several indices (the cells' counts against 1 / 64 each, 63 degrees of freedom, p = 1e-4
    /// bound 114.6). The numbers depend on the seed, frame, sequence and index alone.
    #[test]
    fn frame_points_are_uniform_and_deterministic() {
        let n = 20_000u64;
        for (seed, index) in [(1u64, 0u64), (2, 1), (3, 777), (4, (1 << 32) + 5)] {
            let mut s = Sampler::new(seed, 0);
            let points: Vec<[f32; FRAME_DIMENSIONS]> =
                (0..n).map(|seq| s.frame_point(seq, index)).collect();
            for a in 0..FRAME_DIMENSIONS {
                for b in a + 1..FRAME_DIMENSIONS {
                    let mut count = [0u32; 64];
                    for p in &points {
                        assert!((0.0..1.0).contains(&p[a]) && (0.0..1.0).contains(&p[b]));
                        count[(p[a] * 8.0) as usize + 8 * (p[b] * 8.0) as usize] += 1;
                    }
                    let expected = n as f64 / 64.0;
                    let chi2: f64 =
                        count.iter().map(|&c| (c as f64 - expected).powi(2) / expected).sum();
                    assert!(chi2 < 114.6, "index {index} dimensions ({a}, {b}): chi2 {chi2}");
                }
            }
        }
        let mut pixel = Sampler::new(3, 1);
        let first = pixel.frame_point(9, 12_345);
        pixel.start_pixel_sample(UVec2::new(4, 4), 9);
        pixel.next_2d();
        assert_eq!(first, pixel.frame_point(9, 12_345), "the pixel sample must not matter");
        assert_ne!(first, Sampler::new(4, 1).frame_point(9, 12_345), "seed");
        assert_ne!(first, Sampler::new(3, 2).frame_point(9, 12_345), "frame");
        assert_ne!(first, pixel.frame_point(10, 12_345), "sequence");
        assert_ne!(first, pixel.frame_point(9, 12_346), "index");
    }

    #[test]
    fn pixels_are_decorrelated() {
        let mut s = Sampler::new(0, 0);
        let first: Vec<f32> = (0..64)
            .map(|x| {
                s.start_pixel_sample(UVec2::new(x, 0), 0);
                s.next_1d()
            })
            .collect();
        let mut sorted = first.clone();
        sorted.sort_by(f32::total_cmp);
        sorted.dedup();
        assert_eq!(sorted.len(), 64, "pixels must not share sample values");
    }

    /// Every lane of a `LaneSampler` draws what its lane's `Sampler` draws, bit for bit, at 4, 8
    /// and 16 lanes (emulated, so that every width is checked on any CPU) and on this CPU's own.
    #[test]
    fn lane_samplers_draw_the_scalar_numbers() {
        struct Check;
        impl pulp::WithSimd for Check {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: Simd>(self, s: S) {
                let lanes = S::F32_LANES;
                for round in 0..200u32 {
                    let mut scalar: Vec<Sampler> = (0..lanes)
                        .map(|i| {
                            let h = mix64((round as u64) << 8 | i as u64);
                            let mut sm = Sampler::new(h >> 40, (h >> 20) as i64 & 7);
                            let pixel = UVec2::new(h as u32 & 0x3ff, (h >> 10) as u32 & 0x3ff);
                            // Small sample indices and some up to 2^32 - 1.
                            let idx =
                                if i % 3 == 0 { (h >> 24) as u32 } else { (h >> 24) as u32 & 63 };
                            sm.start_pixel_sample(pixel, idx);
                            sm.skip((h >> 56) as u32 % 40);
                            sm
                        })
                        .collect();
                    let mut lane = LaneSampler::new(s);
                    for (i, sm) in scalar.iter().enumerate() {
                        lane.set_lane(i, sm);
                    }
                    for _ in 0..3 {
                        let (x0, y0) = lane.draw_2d(0);
                        let x1 = lane.draw_1d(1);
                        let (x2, y2) = lane.draw_2d(2);
                        // Some lanes move on, the others stay (as paths that ended).
                        let moving: Vec<bool> =
                            (0..lanes).map(|i| (i + round as usize) % 3 != 0).collect();
                        for (i, sm) in scalar.iter_mut().enumerate() {
                            let mut probe = sm.clone();
                            let want = (probe.next_2d(), probe.next_1d(), probe.next_2d());
                            let got = (
                                Vec2::new(x0.lane(i), y0.lane(i)),
                                x1.lane(i),
                                Vec2::new(x2.lane(i), y2.lane(i)),
                            );
                            assert_eq!(
                                got.0.to_array().map(f32::to_bits),
                                want.0.to_array().map(f32::to_bits)
                            );
                            assert_eq!(got.1.to_bits(), want.1.to_bits());
                            assert_eq!(
                                got.2.to_array().map(f32::to_bits),
                                want.2.to_array().map(f32::to_bits)
                            );
                            if moving[i] {
                                sm.skip(3);
                            }
                        }
                        lane.advance(M::from_bools(s, &moving), 3);
                    }
                }
            }
        }
        pulp::WithSimd::with_simd(Check, pulp::Scalar128b);
        pulp::WithSimd::with_simd(Check, pulp::Scalar256b);
        pulp::WithSimd::with_simd(Check, pulp::Scalar512b);
        pulp::Arch::new().dispatch(Check);
    }

    #[test]
    fn lane_bit_tricks_are_exact() {
        let s = pulp::Scalar512b;
        let values: Vec<u32> = (0..16u64).map(|k| mix64(k) as u32).collect();
        let mut v = U::splat(s, 0);
        for (i, &x) in values.iter().enumerate() {
            v.set_lane(i, x);
        }
        let reversed = v.reverse_bits();
        let sobol = sobol_1_reversed_lanes(v);
        for (i, &x) in values.iter().enumerate() {
            assert_eq!(reversed.lane(i), x.reverse_bits());
            assert_eq!(sobol.lane(i), sobol_1_reversed(x));
        }
        // Conversions of every kind of value below 2^24: both halves, the edges, zero.
        for x in [0u32, 1, 2, 0x7f_ffff, 0x80_0000, 0x80_0001, 0xff_ffff, 0x12_3456, 0xab_cdef] {
            let f = U::splat(s, x).small_to_f32();
            assert_eq!(f.lane(3).to_bits(), (x as f32).to_bits(), "{x:#x}");
            assert_eq!(to_unit_lanes(U::splat(s, x << 8)).lane(0), to_unit(x << 8));
        }
    }
}
