//! The light choice that ignores the receiving point: a defensive mixture of each light's power
//! and a uniform choice of emitter. Scenes with few emitters use it (see `super::TREE_MIN_EMITTERS`).

use super::{ChooseLight, Light, ShadingContext};

/// Share of the light choice spread evenly over emitters; the rest goes by power.
///
/// By power alone, a scene with one strong light starves the others: in the Veach MIS scene of
/// the peers harness a fill light holds 98% of the power, each of the four lights the plates
/// reflect 0.5%, and light sampling, the strategy that suits the rougher plates, almost never
/// reaches them (relative MSE 3 times Mitsuba's at 64 spp, whose choice is uniform over
/// emitters). A defensive mixture (Hesterberg 1995; Veach's thesis, 9.2) bounds the loss either
/// way: no light gets less than half its share under either rule, so its light-sampling
/// variance at most doubles. Within an emitter the choice still follows power (area, for
/// uniform emission), and a scene with one emitter (the Cornell box) is chosen exactly as by
/// power alone.
pub const EMITTER_SHARE: f64 = 0.5;

/// Chooses lights by a mixture of power and emitter: with probability 1 - `EMITTER_SHARE` a
/// light in proportion to its power, otherwise an emitter with power uniformly and a light of
/// it in proportion to power. An emitter is one placement of one mesh for emissive triangles;
/// each punctual light and the environment is its own. The choice ignores the receiving point.
#[derive(Clone, Debug, Default)]
pub struct PowerMixture {
    /// Cumulative probability, `lights.len() + 1` entries: 0, then the running sums ending at 1.
    /// Light `i` owns `[cdf[i], cdf[i + 1])`, so its share's start is a lookup, not a branch.
    cdf: Vec<f32>,
    /// Probability of each light.
    prob: Vec<f32>,
    /// A guide table (Chen and Asau's cutpoints) to find a number's light without a search
    /// over every light: `guide[k]` is the first light whose share ends past k / G, for G
    /// (`guide.len() - 1`) a power of two at least the number of lights. A number in
    /// [k / G, (k + 1) / G) lies in a light from `guide[k]` to `guide[k + 1]`, most often one
    /// or two: in Veach's scene of 5,440 emitting triangles the search over all of them took 11%
    /// of a sample's time. With G a power of two, u x G and k / G are exact in `f32`, so the
    /// choice is the full search's, bit for bit.
    guide: Vec<u32>,
}

impl PowerMixture {
    /// Builds the distribution; `emitters[i]` names light `i`'s emitter (any numbers; equal
    /// numbers group lights into one emitter). Lights with zero power are never chosen.
    pub fn new(lights: &[Light], emitters: &[u32], scene_radius: f32) -> Self {
        assert_eq!(lights.len(), emitters.len(), "one emitter per light");
        let powers: Vec<f64> = lights.iter().map(|l| l.power(scene_radius) as f64).collect();
        let total: f64 = powers.iter().sum();
        let mut emitter_power = std::collections::HashMap::<u32, f64>::new();
        for (&p, &e) in powers.iter().zip(emitters) {
            *emitter_power.entry(e).or_default() += p;
        }
        let lit = emitter_power.values().filter(|&&p| p > 0.0).count() as f64;
        let weights: Vec<f64> = powers
            .iter()
            .zip(emitters)
            .map(|(&p, e)| {
                // p / total x (1 - share) + p / emitter power x share / lit, scaled by total:
                // with one emitter the factor is exactly 1 and the weights are the powers.
                let boost =
                    (1.0 - EMITTER_SHARE) + EMITTER_SHARE * total / (lit * emitter_power[e]);
                if p > 0.0 {
                    p * boost
                } else {
                    0.0
                }
            })
            .collect();
        let sum: f64 = weights.iter().sum();
        let mut cdf = Vec::with_capacity(lights.len() + 1);
        cdf.push(0.0);
        let mut prob = Vec::with_capacity(lights.len());
        let mut acc = 0.0f64;
        for &w in &weights {
            acc += w;
            cdf.push(if sum > 0.0 { (acc / sum) as f32 } else { 0.0 });
            prob.push(if sum > 0.0 { (w / sum) as f32 } else { 0.0 });
        }
        if let Some(last) = cdf.last_mut() {
            if sum > 0.0 {
                *last = 1.0;
            }
        }
        let guide = guide_table(&cdf[1..]);
        PowerMixture { cdf, prob, guide }
    }

    /// True when there is no light with power.
    pub fn is_empty(&self) -> bool {
        self.cdf.last().is_none_or(|&c| c <= 0.0)
    }

    /// Picks a light with `u` in [0, 1): (index, probability).
    #[inline]
    pub fn choose(&self, u: f32) -> Option<(u32, f32)> {
        if self.is_empty() {
            return None;
        }
        let ends = &self.cdf[1..];
        let buckets = self.guide.len() - 1;
        let k = ((u * buckets as f32) as usize).min(buckets - 1);
        let (lo, hi) = (self.guide[k] as usize, self.guide[k + 1] as usize);
        let i = (lo + ends[lo..hi].partition_point(|&c| c <= u)).min(self.prob.len() - 1);
        let p = self.prob[i];
        (p > 0.0).then_some((i as u32, p))
    }

    /// Picks a light with `u` in [0, 1) and returns `u` stretched back to [0, 1) within the
    /// chosen light's share, so that one stratified number both chooses and places the sample
    /// (the strata of a 2D sample then cover all lights together).
    #[inline]
    pub fn choose_remapped(&self, u: f32) -> Option<(u32, f32, f32)> {
        let (i, p) = self.choose(u)?;
        let start = self.cdf[i as usize];
        let remapped = ((u - start) / p).clamp(0.0, 1.0 - f32::EPSILON / 2.0);
        Some((i, p, remapped))
    }

    /// Probability that `choose` returns light `i`.
    #[inline]
    pub fn probability(&self, i: u32) -> f32 {
        self.prob[i as usize]
    }
}

/// The guide table of the cumulative shares `ends` (see `PowerMixture::guide`): G + 1 entries
/// for G the smallest power of two at least `ends.len()`.
fn guide_table(ends: &[f32]) -> Vec<u32> {
    let buckets = ends.len().max(1).next_power_of_two();
    let mut guide = Vec::with_capacity(buckets + 1);
    let mut i = 0;
    for k in 0..=buckets {
        let start = k as f32 / buckets as f32;
        while i < ends.len() && ends[i] <= start {
            i += 1;
        }
        guide.push(i as u32);
    }
    guide
}

impl ChooseLight for PowerMixture {
    #[inline]
    fn choose(&self, _ctx: &ShadingContext, u: f32) -> Option<(u32, f32, f32)> {
        self.choose_remapped(u)
    }

    #[inline]
    fn pmf(&self, _ctx: &ShadingContext, light: u32) -> f32 {
        self.probability(light)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::light::PointLight;
    use glam::Vec3;

    /// The guide table finds the light a search over all of them finds, for every number at
    /// and next to each share's ends and each bucket's, and for random ones, over shares with
    /// lights of zero power, tiny lights and one light of almost all the power.
    #[test]
    fn guided_choice_is_the_full_search() {
        let light = |power: f32| {
            Light::Point(PointLight { position: Vec3::ZERO, intensity: Vec3::splat(power) })
        };
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        for n in [1usize, 2, 3, 7, 64, 1000, 3001] {
            let lights: Vec<Light> = (0..n)
                .map(|i| match i % 5 {
                    0 if i > 0 => light(0.0),
                    1 => light(1e-6),
                    2 if i == 2 => light(1e4),
                    _ => light(0.1 + next()),
                })
                .collect();
            let emitters: Vec<u32> = (0..n as u32).map(|i| i / 3).collect();
            let m = PowerMixture::new(&lights, &emitters, 1.0);
            let full = |u: f32| {
                let i = m.cdf[1..].partition_point(|&c| c <= u).min(m.prob.len() - 1);
                (m.prob[i] > 0.0).then_some((i as u32, m.prob[i]))
            };
            let buckets = m.guide.len() - 1;
            let mut us: Vec<f32> = (0..4000).map(|_| next()).collect();
            for &c in m
                .cdf
                .iter()
                .chain((0..=buckets).map(|k| k as f32 / buckets as f32).collect::<Vec<_>>().iter())
            {
                us.extend([
                    c,
                    f32::from_bits(c.to_bits().saturating_sub(1)),
                    f32::from_bits(c.to_bits() + 1),
                ]);
            }
            for u in us.into_iter().filter(|u| (0.0..1.0).contains(u)) {
                assert_eq!(m.choose(u), full(u), "{n} lights, u = {u}");
            }
        }
    }

    #[test]
    fn remapped_choice_spreads_each_lights_numbers_over_the_unit_interval() {
        let light = |power: f32| {
            Light::Point(PointLight { position: Vec3::ZERO, intensity: Vec3::splat(power) })
        };
        let lights = vec![light(1.0), light(3.0), light(0.0), light(4.0)];
        let sampler = PowerMixture::new(&lights, &[0, 1, 2, 3], 1.0);
        let n = 8000;
        let mut per_light: Vec<Vec<f32>> = vec![Vec::new(); 4];
        for k in 0..n {
            let u = (k as f32 + 0.5) / n as f32;
            let (i, p, r) = sampler.choose_remapped(u).unwrap();
            assert_eq!(p, sampler.probability(i));
            assert!((0.0..1.0).contains(&r));
            per_light[i as usize].push(r);
        }
        assert!(per_light[2].is_empty(), "a light without power is never chosen");
        for (i, values) in per_light.iter().enumerate().filter(|(_, v)| !v.is_empty()) {
            let expected = sampler.probability(i as u32) * n as f32;
            assert!(
                (values.len() as f32 - expected).abs() <= 1.0,
                "light {i}: {} picks",
                values.len()
            );
            // Evenly spread: the k-th value sits in the k-th of len equal cells.
            for (k, r) in values.iter().enumerate() {
                let cell = (r * values.len() as f32) as usize;
                assert!(cell.abs_diff(k) <= 1, "light {i}: value {k} = {r} out of its stratum");
            }
        }
    }
}
