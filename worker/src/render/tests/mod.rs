//! Statistical tests of the renderer's sampling code: every warp, BSDF and light sampler against
//! its own pdf (chi-square, `chi2.rs`), plus energy and consistency checks. Test-only.
//!
//! Layout: `chi2` is the harness; `warps`, `bsdfs` and `lights` hold the tests. Each file counts
//! its chi-square tests in `N_CHI2`, and the sum sets the Šidák-corrected significance level.

mod bsdfs;
mod chi2;
mod lights;
mod warps;

/// Number of chi-square tests in the suite (every `Chi2Test::run` that a test asserts on), so
/// that the whole suite fails by chance with probability 0.01.
const N_CHI2_TESTS: usize = warps::N_CHI2 + bsdfs::N_CHI2 + lights::N_CHI2;
