//! Media: the homogeneous volumes inside closed meshes (`KHR_materials_volume`), what a path
//! knows of the ones it is in, and how light travels through them.
//!
//! **Nesting.** Volumes may overlap and nest (a liquid in a glass, an ice cube in water, a bubble
//! in glass): a path keeps a stack of the volumes it has entered (each by its material), and the
//! medium it travels in is the one it entered last. A boundary is crossed through its front face
//! (the side its winding makes counter-clockwise) into the volume and through its back face out
//! of it; a crossing that leaves the medium the same on both sides is a false interface, which
//! light passes without a change of direction, a bounce or a Fresnel reflection:
//! - entering volume M is real unless M is already the current medium (two overlapping meshes of
//!   one material are their union);
//! - leaving M is real when M is the current medium (the medium beyond is the one entered
//!   before it) and false when M was entered earlier than the current medium (the boundary lies
//!   inside the medium entered later); leaving an M the path never entered (a camera inside a
//!   volume, a mesh with a gap) is real, into the current medium.
//!
//! So a liquid modelled, as artists do, to overlap the glass's inner wall slightly meets the
//! glass-to-liquid interface (relative index n_liquid / n_glass) at the first of the two
//! surfaces it crosses and passes the second. Coincident surfaces are ambiguous (which is hit
//! first is decided by rounding) and should overlap instead. The stack holds
//! `MediumStack::CAPACITY` volumes; a volume entered beyond that is ignored.
//!
//! **Transport.** An absorbing medium keeps exp(-sigma_t d) of the light over a distance d; a
//! scattering one samples free flights by one colour channel, the path's hero, and weighs them
//! by the three channels' densities over the whole path ([`free_flight`]).

use common::scene::{Material, Volume};
use glam::Vec3;

use super::spectrum;

/// The volumes a path is inside, the last entered on top.
#[derive(Clone, Copy, Debug, Default)]
pub struct MediumStack {
    entered: [u32; MediumStack::CAPACITY],
    len: usize,
}

/// What crossing a volume's boundary does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Crossing {
    /// A real interface between the current medium and `beyond` (`None`: air).
    Real { beyond: Option<u32> },
    /// The medium is the same on both sides: light passes unchanged.
    False,
}

impl MediumStack {
    /// How many nested volumes a path tracks.
    pub const CAPACITY: usize = 8;

    /// The medium the path travels in (`None`: air).
    #[inline]
    pub fn current(&self) -> Option<u32> {
        self.len.checked_sub(1).map(|i| self.entered[i])
    }

    /// What crossing the boundary of volume `m` through its front face (`front`, entering) or
    /// its back face (leaving) would be, without crossing it.
    #[inline]
    pub fn crossing(&self, m: u32, front: bool) -> Crossing {
        let current = self.current();
        if front {
            return if current == Some(m) {
                Crossing::False
            } else {
                Crossing::Real { beyond: Some(m) }
            };
        }
        match self.position(m) {
            // On top: into the medium entered before it.
            Some(i) if i + 1 == self.len => {
                let below = i.checked_sub(1).map(|j| self.entered[j]);
                if below == Some(m) {
                    Crossing::False
                } else {
                    Crossing::Real { beyond: below }
                }
            }
            Some(_) => Crossing::False,
            None => Crossing::Real { beyond: current },
        }
    }

    /// Crosses the boundary of volume `m`: entering pushes it, leaving removes its last entry.
    #[inline]
    pub fn cross(&mut self, m: u32, front: bool) {
        if front {
            if self.len < Self::CAPACITY {
                self.entered[self.len] = m;
                self.len += 1;
            }
        } else if let Some(i) = self.position(m) {
            self.entered.copy_within(i + 1..self.len, i);
            self.len -= 1;
        }
    }

    /// The index of the last entry of `m`.
    #[inline]
    fn position(&self, m: u32) -> Option<usize> {
        self.entered[..self.len].iter().rposition(|&e| e == m)
    }
}

/// The index of refraction of the medium bounded by material `m`'s volume (`None`: air, 1),
/// at `wavelength` (nanometres) for a dispersive one once the path has chosen one. `ior` 0
/// (the extension's "no refraction") is 1.
#[inline]
pub fn ior(materials: &[Material], m: Option<u32>, wavelength: Option<f32>) -> f32 {
    match m {
        Some(m) => {
            let material = &materials[m as usize];
            let ior = if material.ior > 0.0 { material.ior } else { 1.0 };
            match wavelength {
                Some(lambda) if material.dispersion > 0.0 => {
                    spectrum::dispersive_ior(ior, material.dispersion, lambda)
                }
                _ => ior,
            }
        }
        None => 1.0,
    }
}

/// What a distance `distance` inside `volume` lets through unscattered, per channel.
#[inline]
pub fn transmittance(volume: &Volume, distance: f32) -> Vec3 {
    if volume.extinction == Vec3::ZERO {
        return Vec3::ONE;
    }
    // exp(-0 x inf) would be NaN: a clear channel passes everything at any distance.
    let through = |a: f32| if a == 0.0 { 1.0 } else { (-a * distance).exp() };
    Vec3::new(
        through(volume.extinction.x),
        through(volume.extinction.y),
        through(volume.extinction.z),
    )
}

/// The colour channel a path draws its free flights by (its hero), from a uniform number.
#[inline]
pub fn hero_channel(u: f32) -> usize {
    ((u * 3.0) as usize).min(2)
}

/// Where light travelling `distance` (world units, infinite for an escape) through the
/// scattering medium `v` is first scattered, from number `u`, and the weight of what was
/// sampled: a scattering at the returned distance, or (`None`) none before `distance`.
///
/// The extinction differs per channel: the distance is drawn from the exponential of the path's
/// hero channel `hero`, and the weight is the event's value over the three channels' densities
/// of the whole path so far, averaged (spectral multiple importance sampling over the path, the
/// balance heuristic; Mitsuba 3's `volpathmis`). `ratios` carries each channel's density of the
/// path so far over their mean (1, 1, 1 at the start of a path; surface events are the same in
/// every channel and leave it alone): the weight is f / mean(ratios p) and the ratios become
/// ratios p / mean(ratios p), with f = sigma_s T(t) and p = sigma_t T(t) for a scattering,
/// f = p = T(d) for none. In a grey medium that is exactly the albedo and 1. Averaging the
/// densities per flight instead lets a channel's weight grow by up to 3 a flight, a product over
/// hundreds of scatterings in a bright medium whose sample mean sits far below its mean.
#[inline]
pub fn free_flight(
    v: &Volume,
    distance: f32,
    hero: usize,
    u: f32,
    ratios: &mut Vec3,
) -> (Vec3, Option<f32>) {
    free_flight_at(v, distance, flight_distance(v, hero, u), ratios)
}

/// The distance to the first scattering that number `u` draws from the exponential of channel
/// `hero` of medium `v` (infinite where that channel is clear).
#[inline]
pub fn flight_distance(v: &Volume, hero: usize, u: f32) -> f32 {
    let sigma = v.extinction[hero];
    if sigma > 0.0 {
        -(1.0 - u).ln() / sigma
    } else {
        f32::INFINITY
    }
}

/// [`free_flight`] with its distance `t` drawn ([`flight_distance`]): a scattering at `t` if
/// it lies within `distance`, else none, and the weight. A flight that passes a surface of the
/// same medium (a false interface) goes on with `t` less the distance travelled, the
/// exponential being memoryless.
#[inline]
pub fn free_flight_at(v: &Volume, distance: f32, t: f32, ratios: &mut Vec3) -> (Vec3, Option<f32>) {
    let (f, p, at) = if t < distance {
        let tr = transmittance(v, t);
        (v.extinction * v.albedo * tr, v.extinction * tr, Some(t))
    } else {
        let tr = transmittance(v, distance);
        (tr, tr, None)
    };
    let weighted = *ratios * p;
    let mean = weighted.element_sum() / 3.0;
    if !(mean > 0.0) {
        return (Vec3::ZERO, at);
    }
    *ratios = weighted / mean;
    (f / mean, at)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_liquid_overlapping_a_glass_wall_meets_one_real_interface_each_way() {
        let (glass, liquid) = (1, 2);
        let mut s = MediumStack::default();
        // Down through the glass's outer wall, the liquid's surface inside the wall, the
        // glass's inner wall (inside the liquid), ...
        assert_eq!(s.crossing(glass, true), Crossing::Real { beyond: Some(glass) });
        s.cross(glass, true);
        assert_eq!(s.crossing(liquid, true), Crossing::Real { beyond: Some(liquid) });
        s.cross(liquid, true);
        assert_eq!(s.crossing(glass, false), Crossing::False);
        s.cross(glass, false);
        assert_eq!(s.current(), Some(liquid));
        // ... then out at the bottom: the glass's inner wall (real: liquid to glass), the
        // liquid's surface inside the glass (false), the glass's outer wall (real: to air).
        assert_eq!(s.crossing(glass, true), Crossing::Real { beyond: Some(glass) });
        s.cross(glass, true);
        assert_eq!(s.crossing(liquid, false), Crossing::False);
        s.cross(liquid, false);
        assert_eq!(s.crossing(glass, false), Crossing::Real { beyond: None });
        s.cross(glass, false);
        assert_eq!(s.current(), None);
    }

    #[test]
    fn overlapping_meshes_of_one_material_are_their_union() {
        let mut s = MediumStack::default();
        s.cross(4, true);
        assert_eq!(s.crossing(4, true), Crossing::False);
        s.cross(4, true);
        assert_eq!(s.crossing(4, false), Crossing::False);
        s.cross(4, false);
        assert_eq!(s.crossing(4, false), Crossing::Real { beyond: None });
        s.cross(4, false);
        assert_eq!(s.current(), None);
    }

    #[test]
    fn leaving_a_volume_never_entered_is_real_and_an_overfull_stack_ignores_the_rest() {
        let mut s = MediumStack::default();
        assert_eq!(s.crossing(7, false), Crossing::Real { beyond: None });
        s.cross(7, false);
        assert_eq!(s.current(), None);
        for m in 0..MediumStack::CAPACITY as u32 + 3 {
            s.cross(m, true);
        }
        assert_eq!(s.current(), Some(MediumStack::CAPACITY as u32 - 1));
        // An ignored volume's back face is then real, into the current medium.
        let ignored = MediumStack::CAPACITY as u32 + 1;
        assert_eq!(s.crossing(ignored, false), Crossing::Real { beyond: s.current() });
    }
}
