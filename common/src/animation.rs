//! Node animation: the glTF node tree with each node's rest transform and, for animated nodes,
//! translation / rotation / scale curves (STEP, LINEAR, CUBICSPLINE; rotations by slerp), so that
//! any node's world transform can be evaluated at any time; and morph target weight curves, one
//! per target, for nodes whose `weights` are animated. Times outside a curve's keys clamp to its
//! first or last key. Every animation of the file plays at once.

use glam::{DMat4, DQuat, DVec3};

/// How a curve interpolates between keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// The value of the previous key.
    Step,
    /// Linear (slerp for rotations).
    Linear,
    /// Cubic Hermite spline with the in- and out-tangents stored beside each value.
    CubicSpline,
}

/// Keyframes of one property. For `CubicSpline`, `values` holds three entries per key:
/// in-tangent, value, out-tangent.
#[derive(Clone, Debug, PartialEq)]
pub struct Curve<T> {
    /// Key times in seconds, non-decreasing.
    pub times: Vec<f64>,
    /// Key values.
    pub values: Vec<T>,
    /// Interpolation between keys.
    pub interpolation: Interpolation,
}

/// What [`Curve::sample`] needs of a value type.
pub trait Keyframe: Copy {
    /// Linear interpolation (slerp for rotations).
    fn lerp(a: Self, b: Self, s: f64) -> Self;
    /// a * x + b * y.
    fn combine(a: f64, x: Self, b: f64, y: Self) -> Self;
    /// Makes the result of a spline valid (normalises rotations).
    fn finish(self) -> Self {
        self
    }
}

impl Keyframe for DVec3 {
    fn lerp(a: Self, b: Self, s: f64) -> Self {
        a.lerp(b, s)
    }
    fn combine(a: f64, x: Self, b: f64, y: Self) -> Self {
        a * x + b * y
    }
}

impl Keyframe for f64 {
    fn lerp(a: Self, b: Self, s: f64) -> Self {
        a + (b - a) * s
    }
    fn combine(a: f64, x: Self, b: f64, y: Self) -> Self {
        a * x + b * y
    }
}

impl Keyframe for DQuat {
    fn lerp(a: Self, b: Self, s: f64) -> Self {
        a.slerp(b, s)
    }
    fn combine(a: f64, x: Self, b: f64, y: Self) -> Self {
        DQuat::from_vec4(glam::DVec4::from(x) * a + glam::DVec4::from(y) * b)
    }
    fn finish(self) -> Self {
        self.normalize()
    }
}

impl<T: Keyframe> Curve<T> {
    /// The value at time `t`.
    pub fn sample(&self, t: f64) -> T {
        let n = self.times.len();
        let cubic = self.interpolation == Interpolation::CubicSpline;
        let value = |k: usize| if cubic { self.values[3 * k + 1] } else { self.values[k] };
        if n == 1 || t <= self.times[0] {
            return value(0);
        }
        if t >= self.times[n - 1] {
            return value(n - 1);
        }
        // The key interval [t_k, t_k+1) holding t.
        let k = self.times.partition_point(|&key| key <= t) - 1;
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let dt = t1 - t0;
        let s = (t - t0) / dt;
        match self.interpolation {
            Interpolation::Step => value(k),
            Interpolation::Linear => T::lerp(value(k), value(k + 1), s),
            Interpolation::CubicSpline => {
                let (s2, s3) = (s * s, s * s * s);
                let out_tangent = self.values[3 * k + 2];
                let in_tangent = self.values[3 * (k + 1)];
                let p = T::combine(
                    2.0 * s3 - 3.0 * s2 + 1.0,
                    value(k),
                    dt * (s3 - 2.0 * s2 + s),
                    out_tangent,
                );
                let q = T::combine(-2.0 * s3 + 3.0 * s2, value(k + 1), dt * (s3 - s2), in_tangent);
                T::combine(1.0, p, 1.0, q).finish()
            }
        }
    }
}

/// A node's own transform when nothing animates it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trs {
    /// Translation.
    pub translation: DVec3,
    /// Rotation (unit).
    pub rotation: DQuat,
    /// Scale.
    pub scale: DVec3,
}

/// The curves animating one node (each property may be animated or not).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeMotion {
    /// Translation curve.
    pub translation: Option<Curve<DVec3>>,
    /// Rotation curve.
    pub rotation: Option<Curve<DQuat>>,
    /// Scale curve.
    pub scale: Option<Curve<DVec3>>,
}

/// A node of the tree.
#[derive(Clone, Debug, PartialEq)]
pub struct AnimNode {
    /// Parent node.
    pub parent: Option<usize>,
    /// The rest transform (a `matrix` node is decomposed when it is animated).
    pub rest: DMat4,
    /// Rest TRS, the base the curves override property by property.
    pub rest_trs: Trs,
    /// Curves, when the node is animated.
    pub motion: Option<NodeMotion>,
    /// Morph target weight curves (a `weights` channel), one per target of the node's mesh, all
    /// with the channel's key times; kept apart from `motion` because they deform the node's
    /// mesh without moving the node.
    pub weights: Option<Vec<Curve<f64>>>,
}

/// Every node of the file, so that transforms can be evaluated at any time.
#[derive(Clone, Debug, PartialEq)]
pub struct Animation {
    /// The nodes, by glTF index.
    pub nodes: Vec<AnimNode>,
    /// Earliest key time over all curves.
    pub start: f64,
    /// Latest key time over all curves.
    pub end: f64,
}

impl Animation {
    /// A node's local transform at time `t`.
    pub fn local(&self, node: usize, t: f64) -> DMat4 {
        let n = &self.nodes[node];
        let Some(m) = &n.motion else { return n.rest };
        let translation = m.translation.as_ref().map_or(n.rest_trs.translation, |c| c.sample(t));
        let rotation = m.rotation.as_ref().map_or(n.rest_trs.rotation, |c| c.sample(t));
        let scale = m.scale.as_ref().map_or(n.rest_trs.scale, |c| c.sample(t));
        DMat4::from_scale_rotation_translation(scale, rotation.normalize(), translation)
    }

    /// A node's world transform at time `t` (through its ancestors).
    pub fn world(&self, node: usize, t: f64) -> DMat4 {
        let mut m = self.local(node, t);
        let mut at = self.nodes[node].parent;
        while let Some(p) = at {
            m = self.local(p, t) * m;
            at = self.nodes[p].parent;
        }
        m
    }

    /// [`Animation::world`] remembering every node's world transform it works out in `memo`
    /// (for time `t` only), so that posing many joints of one skeleton walks each node once.
    pub fn world_memo(
        &self,
        node: usize,
        t: f64,
        memo: &mut std::collections::HashMap<usize, DMat4>,
    ) -> DMat4 {
        let mut chain = Vec::new();
        let mut at = Some(node);
        while let Some(n) = at.filter(|n| !memo.contains_key(n)) {
            chain.push(n);
            at = self.nodes[n].parent;
        }
        let mut m = at.map_or(DMat4::IDENTITY, |n| memo[&n]);
        for &n in chain.iter().rev() {
            m *= self.local(n, t);
            memo.insert(n, m);
        }
        m
    }

    /// The node's morph target weights at time `t`, when a `weights` channel animates them.
    pub fn weights(&self, node: usize, t: f64) -> Option<Vec<f64>> {
        let curves = self.nodes.get(node)?.weights.as_ref()?;
        Some(curves.iter().map(|c| c.sample(t)).collect())
    }

    /// Whether a `weights` channel animates the node's morph target weights.
    pub fn animates_weights(&self, node: usize) -> bool {
        self.nodes.get(node).is_some_and(|n| n.weights.is_some())
    }

    /// Every key time of every curve (node transforms and morph target weights), unsorted, with
    /// repeats: where a curve may turn.
    pub fn key_times(&self) -> impl Iterator<Item = f64> + '_ {
        self.nodes.iter().flat_map(|n| {
            let m = n.motion.as_ref();
            let trs = [
                m.and_then(|m| m.translation.as_ref()).map(|c| &c.times),
                m.and_then(|m| m.rotation.as_ref()).map(|c| &c.times),
                m.and_then(|m| m.scale.as_ref()).map(|c| &c.times),
            ];
            let weights = n.weights.iter().flatten().map(|c| &c.times);
            trs.into_iter().flatten().chain(weights).flatten().copied()
        })
    }

    /// Whether the node or one of its ancestors is animated.
    pub fn moves(&self, node: usize) -> bool {
        let mut at = Some(node);
        while let Some(n) = at {
            if self.nodes[n].motion.is_some() {
                return true;
            }
            at = self.nodes[n].parent;
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn curve<T>(times: &[f64], values: Vec<T>, interpolation: Interpolation) -> Curve<T> {
        Curve { times: times.to_vec(), values, interpolation }
    }

    #[test]
    fn linear_step_and_clamping() {
        let c =
            curve(&[1.0, 3.0], vec![DVec3::ZERO, DVec3::new(2.0, 4.0, 0.0)], Interpolation::Linear);
        assert_eq!(c.sample(2.0), DVec3::new(1.0, 2.0, 0.0));
        assert_eq!(c.sample(0.0), DVec3::ZERO, "before the first key: the first value");
        assert_eq!(c.sample(9.0), DVec3::new(2.0, 4.0, 0.0), "after the last key: the last value");
        let s = Curve { interpolation: Interpolation::Step, ..c };
        assert_eq!(s.sample(2.9), DVec3::ZERO);
        assert_eq!(s.sample(3.0), DVec3::new(2.0, 4.0, 0.0));
    }

    #[test]
    fn rotations_slerp_at_constant_angular_speed() {
        let a = DQuat::IDENTITY;
        let b = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2);
        let c = curve(&[0.0, 1.0], vec![a, b], Interpolation::Linear);
        for s in [0.1, 0.25, 0.5, 0.9] {
            let q = c.sample(s);
            let angle = q.to_axis_angle().1;
            assert!((angle - s * std::f64::consts::FRAC_PI_2).abs() < 1e-12, "{s}: {angle}");
        }
    }

    #[test]
    fn cubic_spline_is_hermite() {
        // Value 0 -> 1 over [0, 2] with zero tangents: 3s² - 2s³ at s = t / 2.
        let v = |x: f64| DVec3::splat(x);
        let c = curve(
            &[0.0, 2.0],
            vec![v(0.0), v(0.0), v(0.0), v(0.0), v(1.0), v(0.0)],
            Interpolation::CubicSpline,
        );
        let s: f64 = 0.25;
        assert!((c.sample(0.5).x - (3.0 * s * s - 2.0 * s * s * s)).abs() < 1e-12);
        // A tangent of 1 per second at both ends with values 0 and 2 over [0, 2] is the line t.
        let c = curve(
            &[0.0, 2.0],
            vec![v(1.0), v(0.0), v(1.0), v(1.0), v(2.0), v(1.0)],
            Interpolation::CubicSpline,
        );
        assert!((c.sample(0.7).x - 0.7).abs() < 1e-12);
    }

    #[test]
    fn world_transforms_compose_through_parents() {
        let trs = Trs { translation: DVec3::ZERO, rotation: DQuat::IDENTITY, scale: DVec3::ONE };
        let spin = NodeMotion {
            rotation: Some(curve(
                &[0.0, 1.0],
                vec![DQuat::IDENTITY, DQuat::from_rotation_z(std::f64::consts::PI)],
                Interpolation::Linear,
            )),
            ..Default::default()
        };
        let child_rest = DMat4::from_translation(DVec3::X);
        let anim = Animation {
            nodes: vec![
                AnimNode {
                    parent: None,
                    rest: DMat4::IDENTITY,
                    rest_trs: trs,
                    motion: Some(spin),
                    weights: None,
                },
                AnimNode {
                    parent: Some(0),
                    rest: child_rest,
                    rest_trs: Trs { translation: DVec3::X, ..trs },
                    motion: None,
                    weights: None,
                },
            ],
            start: 0.0,
            end: 1.0,
        };
        // The child, one unit out, follows the parent's spin along the arc: at t = 0.5 it is at +y.
        let p = anim.world(1, 0.5).transform_point3(DVec3::ZERO);
        assert!((p - DVec3::Y).length() < 1e-12, "{p}");
        let mut memo = std::collections::HashMap::new();
        assert_eq!(anim.world_memo(1, 0.5, &mut memo), anim.world(1, 0.5));
        assert_eq!(memo.len(), 2);
        assert_eq!(anim.world_memo(0, 0.5, &mut memo), anim.world(0, 0.5));
        assert!(anim.moves(1) && anim.moves(0));
    }
}
