//! The light tree: pbrt-v4's light BVH (`BVHLightSampler`, after Conty Estevez and Kulla 2018).
//! Each node bounds its lights' positions, power and emission directions (`LightBounds`); a
//! choice walks down from the root, taking each child in proportion to an importance that
//! bounds what the child's lights could send to the receiving point. Lights at infinity (the
//! environment, directional lights) are chosen beside the tree with a fixed probability.
//!
//! The tree is built binary, as pbrt's, then folded four-wide (`WideNode`: a node's children are
//! its binary node's grandchildren, or children where those are leaves), and the choice takes one
//! of up to four children in proportion to their importance, evaluated for all four at once in
//! SIMD lanes (`WideBounds`): half the steps of the binary walk, whose cost is the latency of
//! each step's chain of roots and divisions. A child's probability is its own importance's share,
//! where pbrt's is a product of two binary shares; either is unbiased, since every node above a
//! light that can reach the point has nonzero importance there.
//!
//! The tree is built from the lights alone, in their order, with no hashing or threads, so a
//! scene always gets the same tree.

use std::f32::consts::{FRAC_PI_2, PI};

use glam::{Quat, Vec3, Vec4, Vec4Swizzles};

use super::{ChooseLight, Light, ShadingContext};

/// Bounds on what a group of lights emits: where (a box), how much (`phi`) and toward which
/// directions (within `theta_o` of `w`, each spreading by up to `theta_e` around its normal).
#[derive(Clone, Copy, Debug)]
pub struct LightBounds {
    /// Lower corner of the box around the lights.
    pub min: Vec3,
    /// Upper corner of the box.
    pub max: Vec3,
    /// Unit axis of the cone of normals.
    pub w: Vec3,
    /// Total power (the same estimate as the mixture's, `Light::power`).
    pub phi: f32,
    /// Cosine of the cone's half angle: every light's normal lies within it of `w`.
    pub cos_theta_o: f32,
    /// Cosine of the angle past a normal over which light still leaves (pi/2 for a surface).
    pub cos_theta_e: f32,
    /// Whether some light emits from both faces.
    pub two_sided: bool,
}

impl LightBounds {
    /// The bounds of one light, or `None` for a light at infinity or one without power.
    pub fn of(light: &Light, scene_radius: f32) -> Option<LightBounds> {
        let phi = light.power(scene_radius);
        if phi <= 0.0 || !phi.is_finite() {
            return None;
        }
        match light {
            Light::Triangle(l) => Some(LightBounds {
                min: l.p[0].min(l.p[1]).min(l.p[2]),
                max: l.p[0].max(l.p[1]).max(l.p[2]),
                w: l.normal,
                phi,
                cos_theta_o: 1.0,
                cos_theta_e: 0.0,
                two_sided: l.two_sided,
            }),
            Light::Point(l) => Some(LightBounds {
                min: l.position,
                max: l.position,
                w: Vec3::Z,
                phi,
                cos_theta_o: -1.0,
                cos_theta_e: 0.0,
                two_sided: false,
            }),
            Light::Spot(l) => {
                let theta_inner = l.cos_inner.clamp(-1.0, 1.0).acos();
                let theta_outer = l.cos_outer.clamp(-1.0, 1.0).acos();
                Some(LightBounds {
                    min: l.position,
                    max: l.position,
                    w: l.direction,
                    phi,
                    cos_theta_o: l.cos_inner,
                    cos_theta_e: (theta_outer - theta_inner).max(0.0).cos(),
                    two_sided: false,
                })
            }
            Light::Directional(_) | Light::Environment(_) => None,
        }
    }

    fn centroid(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// The bounds of two groups together (pbrt-v4 `Union`).
    fn union(&self, other: &LightBounds) -> LightBounds {
        let (w, cos_theta_o) = cone_union((self.w, self.cos_theta_o), (other.w, other.cos_theta_o));
        LightBounds {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
            w,
            phi: self.phi + other.phi,
            cos_theta_o,
            cos_theta_e: self.cos_theta_e.min(other.cos_theta_e),
            two_sided: self.two_sided || other.two_sided,
        }
    }

    /// An upper bound on what the lights send to `p` with normal `n` (zero: no cosine), up to
    /// a common factor (pbrt-v4 `LightBounds::Importance`).
    pub fn importance(&self, p: Vec3, n: Vec3) -> f32 {
        let pc = self.centroid();
        // The distance to the centre, kept from falling below half the box's diagonal, so that
        // points inside or near a box do not make it infinitely important.
        let d2 = p.distance_squared(pc).max((self.max - self.min).length() * 0.5);
        let wi = (p - pc).normalize_or_zero();
        let mut cos_theta_w = self.w.dot(wi);
        if self.two_sided {
            cos_theta_w = cos_theta_w.abs();
        }
        let sin_theta_w = safe_sqrt(1.0 - cos_theta_w * cos_theta_w);
        // The cone of directions from the box toward p.
        let cos_theta_b = self.cos_subtended(p);
        let sin_theta_b = safe_sqrt(1.0 - cos_theta_b * cos_theta_b);
        let sin_theta_o = safe_sqrt(1.0 - self.cos_theta_o * self.cos_theta_o);
        cone_importance(
            self.phi,
            d2,
            wi,
            n,
            (sin_theta_w, cos_theta_w),
            (sin_theta_o, self.cos_theta_o),
            self.cos_theta_e,
            (sin_theta_b, cos_theta_b),
        )
    }

    /// The cosine of the half angle of a cone from `p` holding the box (-1 from inside it).
    fn cos_subtended(&self, p: Vec3) -> f32 {
        if p.cmpge(self.min).all() && p.cmple(self.max).all() {
            return -1.0;
        }
        let center = self.centroid();
        let radius2 = center.distance_squared(self.max);
        let dist2 = p.distance_squared(center);
        if dist2 < radius2 {
            return -1.0;
        }
        safe_sqrt(1.0 - radius2 / dist2)
    }
}

fn safe_sqrt(x: f32) -> f32 {
    x.max(0.0).sqrt()
}

/// cos(max(0, a - b)) from the sines and cosines of a and b.
fn cos_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b {
        return 1.0;
    }
    cos_a * cos_b + sin_a * sin_b
}

/// sin(max(0, a - b)) from the sines and cosines of a and b.
fn sin_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b {
        return 0.0;
    }
    sin_a * cos_b - cos_a * sin_b
}

/// The smallest cone holding two cones, each (unit axis, cosine of the half angle) (pbrt-v4
/// `Union(DirectionCone, DirectionCone)`).
fn cone_union(a: (Vec3, f32), b: (Vec3, f32)) -> (Vec3, f32) {
    let theta_a = a.1.clamp(-1.0, 1.0).acos();
    let theta_b = b.1.clamp(-1.0, 1.0).acos();
    let theta_d = a.0.dot(b.0).clamp(-1.0, 1.0).acos();
    if (theta_d + theta_b).min(PI) <= theta_a {
        return a;
    }
    if (theta_d + theta_a).min(PI) <= theta_b {
        return b;
    }
    let theta_o = (theta_a + theta_d + theta_b) * 0.5;
    if theta_o >= PI {
        return (a.0, -1.0);
    }
    let theta_r = theta_o - theta_a;
    let Some(axis) = a.0.cross(b.0).try_normalize() else {
        return (a.0, -1.0);
    };
    let w = (Quat::from_axis_angle(axis, theta_r) * a.0).normalize();
    (w, theta_o.cos())
}

/// The build's cost of a group on split axis `dim` of a box `extent` (pbrt-v4
/// `EvaluateCost`): power times the solid angle its cone reaches times its box's area, with
/// thin boxes cut across their long side favoured.
fn split_cost(b: &LightBounds, extent: Vec3, dim: usize) -> f32 {
    let theta_o = b.cos_theta_o.clamp(-1.0, 1.0).acos();
    let theta_e = b.cos_theta_e.clamp(-1.0, 1.0).acos();
    let theta_w = (theta_o + theta_e).min(PI);
    let sin_theta_o = safe_sqrt(1.0 - b.cos_theta_o * b.cos_theta_o);
    let m_omega = 2.0 * PI * (1.0 - b.cos_theta_o)
        + FRAC_PI_2
            * (2.0 * theta_w * sin_theta_o
                - (theta_o - 2.0 * theta_w).cos()
                - 2.0 * theta_o * sin_theta_o
                + b.cos_theta_o);
    let kr = if extent[dim] > 0.0 { extent.max_element() / extent[dim] } else { 1.0 };
    let d = b.max - b.min;
    let area = 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x);
    b.phi * m_omega * kr * area
}

/// Buckets per axis for the split search.
const BUCKETS: usize = 12;

/// Past this depth a node splits its lights in halves by order, so that no tree grows deeper
/// than this plus log2 of the lights (and `pmf`'s path fits its stack).
const MAX_SAH_DEPTH: usize = 40;

/// Room for a path from the root to a leaf (of the binary tree, twice what the four-wide one
/// needs).
const MAX_DEPTH: usize = MAX_SAH_DEPTH + 34;

/// `LightBounds` as the choice reads it, with what does not depend on the receiving point
/// worked out once: the same importance, with fewer roots and divisions per evaluation.
#[derive(Clone, Copy, Debug)]
struct NodeBounds {
    /// Centre of the box.
    centre: Vec3,
    /// Half the box's diagonal: the least squared distance the importance divides by.
    half_diagonal: f32,
    /// Squared radius of the sphere around the box (from its centre).
    radius2: f32,
    /// Axis of the cone of normals.
    w: Vec3,
    phi: f32,
    cos_theta_o: f32,
    sin_theta_o: f32,
    cos_theta_e: f32,
    two_sided: bool,
}

impl NodeBounds {
    fn new(b: &LightBounds) -> NodeBounds {
        let centre = b.centroid();
        NodeBounds {
            centre,
            half_diagonal: (b.max - b.min).length() * 0.5,
            radius2: centre.distance_squared(b.max),
            w: b.w,
            phi: b.phi,
            cos_theta_o: b.cos_theta_o,
            sin_theta_o: safe_sqrt(1.0 - b.cos_theta_o * b.cos_theta_o),
            cos_theta_e: b.cos_theta_e,
            two_sided: b.two_sided,
        }
    }
}

/// The importance of lights of power `phi` at squared distance `d2` in direction `wi` from a
/// receiver of normal `n` (zero: no cosine), given the sines and cosines of the angle between
/// their cone's axis and `wi` (`w`), of the cone's spread (`o`) and of the box's half-angle as
/// seen from the receiver (`b`), and the cosine of the emission falloff `cos_e`: pbrt-v4's
/// `LightBounds::Importance` after its geometry. The smallest angle between an emission
/// direction and a direction toward the receiver decides; the receiver's cosine counts either
/// side (a surface may transmit).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn cone_importance(
    phi: f32,
    d2: f32,
    wi: Vec3,
    n: Vec3,
    (sin_theta_w, cos_theta_w): (f32, f32),
    (sin_theta_o, cos_theta_o): (f32, f32),
    cos_theta_e: f32,
    (sin_theta_b, cos_theta_b): (f32, f32),
) -> f32 {
    let cos_theta_x = cos_sub_clamped(sin_theta_w, cos_theta_w, sin_theta_o, cos_theta_o);
    let sin_theta_x = sin_sub_clamped(sin_theta_w, cos_theta_w, sin_theta_o, cos_theta_o);
    let cos_theta_p = cos_sub_clamped(sin_theta_x, cos_theta_x, sin_theta_b, cos_theta_b);
    if cos_theta_p <= cos_theta_e {
        return 0.0;
    }
    let mut importance = phi * cos_theta_p / d2;
    if n != Vec3::ZERO {
        let cos_theta_i = wi.dot(n).abs();
        let sin_theta_i = safe_sqrt(1.0 - cos_theta_i * cos_theta_i);
        importance *= cos_sub_clamped(sin_theta_i, cos_theta_i, sin_theta_b, cos_theta_b);
    }
    importance.max(0.0)
}

/// A node of the binary tree as built: its bounds and either its second child (the first
/// follows it) or its light.
#[derive(Clone, Copy, Debug)]
struct Node {
    bounds: NodeBounds,
    /// The second child's index for an interior node, the light's index for a leaf.
    child_or_light: u32,
    leaf: bool,
}

/// Up to four children's `NodeBounds` side by side, one lane each, so that one evaluation in
/// SIMD gives the importance of them all. An empty lane has no power.
#[derive(Clone, Copy, Debug)]
struct WideBounds {
    centre: [Vec4; 3],
    half_diagonal: Vec4,
    radius2: Vec4,
    w: [Vec4; 3],
    phi: Vec4,
    cos_theta_o: Vec4,
    sin_theta_o: Vec4,
    cos_theta_e: Vec4,
    /// 1 where the lights emit from both faces, else 0.
    two_sided: Vec4,
}

impl WideBounds {
    const EMPTY: WideBounds = WideBounds {
        centre: [Vec4::ZERO; 3],
        half_diagonal: Vec4::ONE,
        radius2: Vec4::ZERO,
        w: [Vec4::ZERO, Vec4::ZERO, Vec4::ONE],
        phi: Vec4::ZERO,
        cos_theta_o: Vec4::ONE,
        sin_theta_o: Vec4::ZERO,
        cos_theta_e: Vec4::ZERO,
        two_sided: Vec4::ZERO,
    };

    fn set(&mut self, k: usize, b: &NodeBounds) {
        for axis in 0..3 {
            self.centre[axis][k] = b.centre[axis];
            self.w[axis][k] = b.w[axis];
        }
        self.half_diagonal[k] = b.half_diagonal;
        self.radius2[k] = b.radius2;
        self.phi[k] = b.phi;
        self.cos_theta_o[k] = b.cos_theta_o;
        self.sin_theta_o[k] = b.sin_theta_o;
        self.cos_theta_e[k] = b.cos_theta_e;
        self.two_sided[k] = if b.two_sided { 1.0 } else { 0.0 };
    }

    /// `LightBounds::importance` of each lane at `p` with normal `n` (zero: no cosine), the same
    /// formula up to rounding (the branches as selects; the box's half-angle from the sphere
    /// around it alone, as `NodeBounds` keeps it); 0 in empty lanes.
    #[inline(always)]
    fn importance(&self, p: Vec3, n: Vec3) -> Vec4 {
        let (zero, one) = (Vec4::ZERO, Vec4::ONE);
        let d = [0, 1, 2].map(|axis| Vec4::splat(p[axis]) - self.centre[axis]);
        let dist2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        let d2 = dist2.max(self.half_diagonal);
        let inv = Vec4::select(dist2.cmpgt(zero), one / dist2.sqrt(), zero);
        let wi = d.map(|c| c * inv);
        let cos_w = self.w[0] * wi[0] + self.w[1] * wi[1] + self.w[2] * wi[2];
        let cos_w = Vec4::select(self.two_sided.cmpgt(zero), cos_w.abs(), cos_w);
        let sin_w = (one - cos_w * cos_w).max(zero).sqrt();
        // The cone of directions from the box toward p: all of them from inside its sphere.
        let inside = dist2.cmple(self.radius2);
        let sin2 = self.radius2 / dist2;
        let cos_b = Vec4::select(inside, -one, (one - sin2).max(zero).sqrt());
        let sin_b = Vec4::select(inside, zero, sin2.sqrt());
        let (cos_o, sin_o) = (self.cos_theta_o, self.sin_theta_o);
        let cos_x = cos_sub_clamped4(sin_w, cos_w, sin_o, cos_o);
        let beyond = cos_w.cmpgt(cos_o);
        let sin_x = Vec4::select(beyond, zero, sin_w * cos_o - cos_w * sin_o);
        let cos_p = cos_sub_clamped4(sin_x, cos_x, sin_b, cos_b);
        let mut importance = self.phi * cos_p / d2;
        if n != Vec3::ZERO {
            let cos_i = (wi[0] * n.x + wi[1] * n.y + wi[2] * n.z).abs();
            let sin_i = (one - cos_i * cos_i).max(zero).sqrt();
            importance *= cos_sub_clamped4(sin_i, cos_i, sin_b, cos_b);
        }
        let reaches = cos_p.cmpgt(self.cos_theta_e) & self.phi.cmpgt(zero);
        Vec4::select(reaches, importance.max(zero), zero)
    }
}

/// `cos_sub_clamped` in each lane.
#[inline(always)]
fn cos_sub_clamped4(sin_a: Vec4, cos_a: Vec4, sin_b: Vec4, cos_b: Vec4) -> Vec4 {
    Vec4::select(cos_a.cmpgt(cos_b), Vec4::ONE, cos_a * cos_b + sin_a * sin_b)
}

/// A node of the four-wide tree the choice walks: the binary tree with every other level
/// folded in (an interior node's children are its binary node's grandchildren, or children
/// where those are leaves), so that a choice takes half the steps, each one SIMD evaluation of
/// up to four children.
#[derive(Clone, Copy, Debug)]
struct WideNode {
    bounds: WideBounds,
    /// Each lane's wide node, or its light where `leaves` has the lane's bit.
    children: [u32; 4],
    leaves: u8,
}

/// pbrt-v4's `BVHLightSampler` over the lights that have bounds, four-wide, chosen down by
/// importance, and the lights at infinity beside it.
#[derive(Clone, Debug, Default)]
pub struct LightTree {
    /// Wide nodes depth first, node 0 the root.
    nodes: Vec<WideNode>,
    /// Each node's parent and its lane there (the root's: itself, 0).
    parents: Vec<(u32, u8)>,
    /// The node and lane of each light (`u32::MAX` for lights not in the tree).
    leaf_of: Vec<(u32, u8)>,
    /// Lights at infinity with power, chosen uniformly among themselves.
    infinite: Vec<u32>,
    /// Index of each light in `infinite` (`u32::MAX` for others).
    infinite_of: Vec<u32>,
}

impl LightTree {
    /// Builds the tree over `lights` (deterministic: only their order and values matter).
    pub fn new(lights: &[Light], scene_radius: f32) -> LightTree {
        let mut tree = LightTree {
            leaf_of: vec![(u32::MAX, 0); lights.len()],
            infinite_of: vec![u32::MAX; lights.len()],
            ..LightTree::default()
        };
        let mut bounded = Vec::new();
        for (i, light) in lights.iter().enumerate() {
            match light {
                Light::Directional(_) | Light::Environment(_) => {
                    let phi = light.power(scene_radius);
                    if phi > 0.0 && phi.is_finite() {
                        tree.infinite_of[i] = tree.infinite.len() as u32;
                        tree.infinite.push(i as u32);
                    }
                }
                _ => {
                    if let Some(b) = LightBounds::of(light, scene_radius) {
                        bounded.push((i as u32, b));
                    }
                }
            }
        }
        if !bounded.is_empty() {
            let mut binary = Vec::new();
            build(&mut binary, &mut bounded, 0);
            tree.collapse(&binary, 0, (0, 0));
        }
        tree
    }

    /// Adds the wide node of binary node `b` (and its subtree) under `parent`; returns its
    /// index.
    fn collapse(&mut self, binary: &[Node], b: usize, parent: (u32, u8)) -> u32 {
        let index = self.nodes.len() as u32;
        let mut node = WideNode { bounds: WideBounds::EMPTY, children: [u32::MAX; 4], leaves: 0 };
        self.nodes.push(node);
        self.parents.push(parent);
        let mut lanes = arrayvec::ArrayVec::<usize, 4>::new();
        if binary[b].leaf {
            lanes.push(b);
        } else {
            for c in [b + 1, binary[b].child_or_light as usize] {
                if binary[c].leaf {
                    lanes.push(c);
                } else {
                    lanes.extend([c + 1, binary[c].child_or_light as usize]);
                }
            }
        }
        for (k, &c) in lanes.iter().enumerate() {
            node.bounds.set(k, &binary[c].bounds);
            if binary[c].leaf {
                let light = binary[c].child_or_light;
                node.children[k] = light;
                node.leaves |= 1 << k;
                self.leaf_of[light as usize] = (index, k as u8);
            } else {
                node.children[k] = self.collapse(binary, c, (index, k as u8));
            }
        }
        self.nodes[index as usize] = node;
        index
    }

    /// True when no light has power.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty() && self.infinite.is_empty()
    }

    /// Probability of choosing among the lights at infinity (each gets an equal share of it).
    fn infinite_share(&self) -> f32 {
        let n = self.infinite.len() as f32;
        n / (n + if self.nodes.is_empty() { 0.0 } else { 1.0 })
    }

    /// The probability of each lane of node `node` at `ctx`: by importance, or by power where
    /// no child can reach the point. pbrt-v4 gives up there instead, so its probabilities sum
    /// to less than one; going on keeps every point's sum at one and costs nothing in bias,
    /// since a light that reaches the point has nonzero importance at every node above it.
    #[inline]
    fn child_probabilities(&self, node: usize, ctx: &ShadingContext) -> [f32; 4] {
        let bounds = &self.nodes[node].bounds;
        let importance = bounds.importance(ctx.p, ctx.n);
        let sum = sum4(importance);
        let usable = sum > 0.0 && (1.0 / sum).is_finite();
        let weights = if usable { importance } else { bounds.phi };
        (weights * (1.0 / sum4(weights))).to_array()
    }
}

/// The sum of the four lanes in a fixed order on every target (glam's `element_sum` adds in its
/// backend's order): (x + y) + (z + w), SSE2's and NEON's order, the pairs added in the vector
/// (as fast as `element_sum` in `examples/tree_walk.rs`; lane by lane was 3-5% slower).
#[inline(always)]
fn sum4(v: Vec4) -> f32 {
    let pairs = v + v.yxwz();
    pairs.x + pairs.z
}

/// Adds the binary subtree over `lights` to `nodes` (pbrt-v4's build) and returns its bounds.
fn build(nodes: &mut Vec<Node>, lights: &mut [(u32, LightBounds)], depth: usize) -> LightBounds {
    let index = nodes.len();
    if let [(light, bounds)] = *lights {
        nodes.push(Node { bounds: NodeBounds::new(&bounds), child_or_light: light, leaf: true });
        return bounds;
    }
    // A placeholder until the children are built.
    let placeholder = NodeBounds::new(&lights[0].1);
    nodes.push(Node { bounds: placeholder, child_or_light: 0, leaf: false });
    let mid = split(lights, depth);
    let (first, second) = lights.split_at_mut(mid);
    let a = build(nodes, first, depth + 1);
    let second_index = nodes.len() as u32;
    let b = build(nodes, second, depth + 1);
    let bounds = a.union(&b);
    nodes[index] =
        Node { bounds: NodeBounds::new(&bounds), child_or_light: second_index, leaf: false };
    bounds
}

/// Reorders `lights` (stably) into two groups and returns where the second starts: the
/// cheapest bucket boundary by `split_cost`, else the middle.
fn split(lights: &mut [(u32, LightBounds)], depth: usize) -> usize {
    let half = lights.len() / 2;
    if depth >= MAX_SAH_DEPTH {
        return half;
    }
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    let (mut box_min, mut box_max) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for (_, b) in lights.iter() {
        lo = lo.min(b.centroid());
        hi = hi.max(b.centroid());
        box_min = box_min.min(b.min);
        box_max = box_max.max(b.max);
    }
    let extent = box_max - box_min;
    let bucket = |b: &LightBounds, dim: usize| {
        let offset = (b.centroid()[dim] - lo[dim]) / (hi[dim] - lo[dim]);
        ((BUCKETS as f32 * offset) as usize).min(BUCKETS - 1)
    };
    let mut best: Option<(f32, usize, usize)> = None;
    for dim in 0..3 {
        if hi[dim] <= lo[dim] {
            continue;
        }
        let mut buckets: [Option<LightBounds>; BUCKETS] = [None; BUCKETS];
        for (_, b) in lights.iter() {
            let k = bucket(b, dim);
            buckets[k] = Some(buckets[k].map_or(*b, |u| u.union(b)));
        }
        let union = |range: &[Option<LightBounds>]| {
            range
                .iter()
                .flatten()
                .fold(None, |acc: Option<LightBounds>, b| Some(acc.map_or(*b, |u| u.union(b))))
        };
        for split in 0..BUCKETS - 1 {
            let (Some(below), Some(above)) =
                (union(&buckets[..=split]), union(&buckets[split + 1..]))
            else {
                continue;
            };
            let cost = split_cost(&below, extent, dim) + split_cost(&above, extent, dim);
            if cost > 0.0 && best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, dim, split));
            }
        }
    }
    let Some((_, dim, split)) = best else {
        return half;
    };
    let (below, above): (Vec<_>, Vec<_>) =
        lights.iter().partition(|(_, b)| bucket(b, dim) <= split);
    if below.is_empty() || above.is_empty() {
        return half;
    }
    let mid = below.len();
    for (slot, light) in lights.iter_mut().zip(below.into_iter().chain(above)) {
        *slot = light;
    }
    mid
}

/// A choice on its way down the tree: the node it stands at, the share of [0, 1) it has come
/// down to (`start`, `width`), the probability so far, and the number being placed.
#[derive(Clone, Copy, Debug)]
struct Walk {
    node: usize,
    start: f64,
    width: f64,
    pmf: f32,
    u: f64,
}

/// The (node, lane) steps from a light's leaf up to the root.
type Path = arrayvec::ArrayVec<(u32, u8), MAX_DEPTH>;

/// The largest f32 below 1: remapped numbers stay in [0, 1).
const BELOW_ONE: f64 = 1.0 - f32::EPSILON as f64 / 2.0;

/// Most receivers whose lights are chosen, or whose probabilities are worked out, together
/// (`LightTree::choose_batch`, `pmf_batch`): their walks go down level by level side by side,
/// each level's importances first for every walk (work without branches that the processor
/// overlaps), then each walk's step. With the step's branchless choice, this took 13-18% off
/// a sample of Veach's scene with the tree forced, and about 10% off one of 1,024 lamps
/// (`docs/perf/light-tree.md`).
pub const BATCH: usize = 16;

impl LightTree {
    /// A choice's first step: a light at infinity, or a walk from the root (`Err` holds a
    /// finished choice).
    #[inline(always)]
    fn begin(&self, u: f32) -> Result<Walk, Option<(u32, f32, f32)>> {
        let p_infinite = self.infinite_share();
        let u = u as f64;
        if u < p_infinite as f64 {
            let n = self.infinite.len();
            let scaled = u / p_infinite as f64 * n as f64;
            let k = (scaled as usize).min(n - 1);
            let remapped = (scaled - k as f64).clamp(0.0, BELOW_ONE) as f32;
            return Err(Some((self.infinite[k], p_infinite / n as f32, remapped)));
        }
        if self.nodes.is_empty() {
            return Err(None);
        }
        // The chosen node's share of [0, 1): `u` is stretched over it once, at the leaf, rather
        // than divided at every level (a chain of divisions the walk would wait on).
        Ok(Walk {
            node: 0,
            start: 0.0,
            width: 1.0,
            pmf: 1.0 - p_infinite,
            u: ((u - p_infinite as f64) / (1.0 - p_infinite) as f64).clamp(0.0, BELOW_ONE),
        })
    }

    /// One level of a walk, given its node's `child_probabilities`: down to the child whose
    /// share holds the number, or the choice where that child is a light (`Some`).
    #[inline(always)]
    fn step(&self, w: &mut Walk, probabilities: [f32; 4]) -> Option<Option<(u32, f32, f32)>> {
        // The lane whose share holds `u`; the last with a share where rounding leaves `u`
        // past them all. Lanes without a share end where the one before them ends, so none is
        // taken: the shares' ends rise, and the lane is the number of ends at or below `u`.
        let last = match probabilities.map(|p| p > 0.0) {
            [_, _, _, true] => 3,
            [_, _, true, false] => 2,
            [_, true, false, false] => 1,
            [true, false, false, false] => 0,
            [false, false, false, false] => return Some(None),
        };
        let mut ends = [0.0f64; 4];
        let mut end = w.start;
        for (e, &p) in ends.iter_mut().zip(&probabilities) {
            end += w.width * p as f64;
            *e = end;
        }
        let k = (ends[..3].iter().filter(|&&e| e <= w.u).count()).min(last);
        let lane_start = if k == 0 { w.start } else { ends[k - 1] };
        let p = probabilities[k];
        w.start = lane_start;
        w.width *= p as f64;
        w.pmf *= p;
        let n = &self.nodes[w.node];
        if n.leaves & (1 << k) != 0 {
            let remapped = ((w.u - w.start) / w.width).clamp(0.0, BELOW_ONE);
            return Some(Some((n.children[k], w.pmf, remapped as f32)));
        }
        w.node = n.children[k] as usize;
        None
    }

    /// `choose` at each of `ctx` with each of `u` (at most `BATCH`), into `out`: the same
    /// choices bit for bit, the walks interleaved.
    pub fn choose_batch(
        &self,
        ctx: &[ShadingContext],
        u: &[f32],
        out: &mut [Option<(u32, f32, f32)>],
    ) {
        assert!(ctx.len() <= BATCH && u.len() == ctx.len() && out.len() == ctx.len());
        let mut walks = arrayvec::ArrayVec::<(usize, Walk), BATCH>::new();
        for (i, &u) in u.iter().enumerate() {
            match self.begin(u) {
                Ok(w) => walks.push((i, w)),
                Err(done) => out[i] = done,
            }
        }
        // Each level in two passes: the probabilities of every walk's node (independent work,
        // without branches, that the processor overlaps), then every walk's step.
        let mut probabilities = [[0.0; 4]; BATCH];
        while !walks.is_empty() {
            for (p, (i, w)) in probabilities.iter_mut().zip(&walks) {
                *p = self.child_probabilities(w.node, &ctx[*i]);
            }
            let mut kept = 0;
            for k in 0..walks.len() {
                let (i, mut w) = walks[k];
                match self.step(&mut w, probabilities[k]) {
                    Some(done) => out[i] = done,
                    None => {
                        walks[kept] = (i, w);
                        kept += 1;
                    }
                }
            }
            walks.truncate(kept);
        }
    }

    /// The path from the root to `light`'s leaf, leaf first (empty for a light not in the tree).
    fn path(&self, light: u32) -> Path {
        let mut path = arrayvec::ArrayVec::new();
        let (leaf, lane) = self.leaf_of[light as usize];
        if leaf == u32::MAX {
            return path;
        }
        let mut at = (leaf, lane);
        loop {
            path.push(at);
            if at.0 == 0 {
                break;
            }
            at = self.parents[at.0 as usize];
        }
        path
    }

    /// `pmf`'s start: the probability of a light at infinity or of one not in the tree
    /// (`Err`), or the tree's share and the path down to the light's leaf, which `pmf`
    /// multiplies root first.
    #[inline(always)]
    fn pmf_begin(&self, light: u32) -> Result<(f32, Path), f32> {
        let p_infinite = self.infinite_share();
        if self.infinite_of[light as usize] != u32::MAX {
            return Err(p_infinite / self.infinite.len() as f32);
        }
        let path = self.path(light);
        if path.is_empty() {
            return Err(0.0);
        }
        Ok((1.0 - p_infinite, path))
    }

    /// `pmf` at each of `ctx` for each of `light` (at most `BATCH`), into `out`: the same
    /// probabilities bit for bit, the walks interleaved.
    pub fn pmf_batch(&self, ctx: &[ShadingContext], light: &[u32], out: &mut [f32]) {
        assert!(ctx.len() <= BATCH && light.len() == ctx.len() && out.len() == ctx.len());
        let mut walks = arrayvec::ArrayVec::<(usize, Path), BATCH>::new();
        for (i, &l) in light.iter().enumerate() {
            match self.pmf_begin(l) {
                Ok((share, path)) => {
                    out[i] = share;
                    walks.push((i, path));
                }
                Err(done) => out[i] = done,
            }
        }
        // Root first, as `pmf` multiplies.
        while !walks.is_empty() {
            for (i, path) in walks.iter_mut() {
                let (node, lane) = path.pop().expect("walks end when their paths do");
                out[*i] *= self.child_probabilities(node as usize, &ctx[*i])[lane as usize];
            }
            walks.retain(|(_, path)| !path.is_empty());
        }
    }
}

impl ChooseLight for LightTree {
    fn choose(&self, ctx: &ShadingContext, u: f32) -> Option<(u32, f32, f32)> {
        let mut w = match self.begin(u) {
            Ok(w) => w,
            Err(done) => return done,
        };
        loop {
            let probabilities = self.child_probabilities(w.node, ctx);
            if let Some(done) = self.step(&mut w, probabilities) {
                return done;
            }
        }
    }

    fn pmf(&self, ctx: &ShadingContext, light: u32) -> f32 {
        let (mut pmf, path) = match self.pmf_begin(light) {
            Ok(start) => start,
            Err(done) => return done,
        };
        // The same products in the same order as `choose`.
        for &(node, lane) in path.iter().rev() {
            pmf *= self.child_probabilities(node as usize, ctx)[lane as usize];
        }
        pmf
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::light::{PointLight, SpotLight, TriangleLight};

    /// The importance the walk evaluates, four lanes at once (`WideBounds`), is pbrt-v4's
    /// (`LightBounds::importance`) in each lane but for rounding, and zero in empty lanes: over
    /// the boxes of single triangles, points and spots and of unions of them, seen from points
    /// inside, near and far, with a normal and without.
    #[test]
    fn wide_importance_is_the_bounds_importance_in_every_lane() {
        let mut state = 0x1234_5678_9abc_def0u64;
        let mut next = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut vec3 = |scale: f32| {
            let v = Vec3::new(next(), next(), next());
            (v - 0.5) * scale
        };
        let mut lights = Vec::new();
        for k in 0..60 {
            let centre = vec3(8.0);
            lights.push(match k % 6 {
                0 => Light::Point(PointLight { position: centre, intensity: Vec3::ONE }),
                1 => Light::Spot(SpotLight {
                    position: centre,
                    direction: vec3(2.0).normalize_or(Vec3::Y),
                    intensity: Vec3::splat(3.0),
                    cos_inner: 0.9,
                    cos_outer: 0.7,
                }),
                _ => {
                    let p = [centre, centre + vec3(1.0), centre + vec3(1.0)];
                    let Some(t) = TriangleLight::new(p, Vec3::splat(2.0), k % 4 == 0) else {
                        continue;
                    };
                    Light::Triangle(t)
                }
            });
        }
        let single: Vec<LightBounds> =
            lights.iter().filter_map(|l| LightBounds::of(l, 8.0)).collect();
        let mut bounds = single.clone();
        for triple in single.windows(3) {
            bounds.push(triple[0].union(&triple[1]));
            bounds.push(triple[0].union(&triple[1]).union(&triple[2]));
        }
        let (mut compared, mut nonzero) = (0, 0);
        // Four lanes at a time, and three (an empty lane).
        for group in bounds.chunks(4).chain(bounds.chunks(3)) {
            let mut wide = WideBounds::EMPTY;
            for (lane, b) in group.iter().enumerate() {
                wide.set(lane, &NodeBounds::new(b));
            }
            for k in 0..40 {
                let b = &group[k % group.len()];
                let p = if k % 4 == 0 { b.centroid() + vec3(0.5) } else { vec3(16.0) };
                let n = if k % 5 == 0 { Vec3::ZERO } else { vec3(2.0).normalize_or(Vec3::Z) };
                let lanes = wide.importance(p, n).to_array();
                assert!(lanes[group.len()..].iter().all(|&l| l == 0.0), "empty lanes: {lanes:?}");
                for (b, &got) in group.iter().zip(&lanes) {
                    let want = b.importance(p, n);
                    // The angles' differences (cos_sub_clamped) cancel digits: the worst of these
                    // cases differs by about 2e-4.
                    assert!(
                        (got - want).abs() <= 1e-3 * want,
                        "{b:?} at {p}, {n}: {got} against {want}"
                    );
                    compared += 1;
                    nonzero += (want > 0.0) as usize;
                }
            }
        }
        assert!(compared > 5000 && nonzero > compared / 3, "{nonzero} of {compared}");
    }
}
