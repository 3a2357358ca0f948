//! A top-down binned SAH build (Wald 2007), for the input `obvhs`'s PLOC build handles badly:
//! many primitives with the same box (the same mesh placed many times at one spot), where PLOC
//! merges one pair per pass and takes quadratic time. Each node is split where the surface area
//! heuristic over 16 centroid bins is lowest; when no bin boundary separates the primitives
//! (their centroids coincide), the node is split at the object median in input order instead, so
//! that coincident primitives cost O(n log n). The result has the layout of `obvhs`'s `Bvh2` (the root first, the two
//! children of a node side by side), so `accel` collapses it like any other.

use glam::{Vec3, Vec3A};
use obvhs::{
    aabb::Aabb,
    bvh2::{node::Bvh2Node, Bvh2},
};

use super::sampler::mix64;

/// Centroid bins per split.
const BINS: usize = 16;

/// Builds a binary BVH over `triangles` with at most `max_leaf` primitives per leaf.
pub fn build(triangles: &[[Vec3; 3]], max_leaf: usize) -> Bvh2 {
    build_boxes(&triangles.iter().map(triangle_box).collect::<Vec<_>>(), max_leaf)
}

/// A triangle's bounding box.
pub fn triangle_box(t: &[Vec3; 3]) -> Aabb {
    let (a, b, c) = (Vec3A::from(t[0]), Vec3A::from(t[1]), Vec3A::from(t[2]));
    Aabb { min: a.min(b).min(c), max: a.max(b).max(c) }
}

/// Builds a binary BVH over primitives given by their boxes (a deforming triangle's box holds it
/// at every time), with at most `max_leaf` primitives per leaf.
pub fn build_boxes(boxes: &[Aabb], max_leaf: usize) -> Bvh2 {
    let max_leaf = max_leaf.max(1);
    let centers: Vec<Vec3A> = boxes.iter().map(Aabb::center).collect();
    let mut indices: Vec<u32> = (0..boxes.len() as u32).collect();
    let mut nodes = vec![Bvh2Node::default()];
    // (node, first primitive, primitive count)
    let mut work = vec![(0usize, 0usize, boxes.len())];
    while let Some((node, first, count)) = work.pop() {
        let range = &mut indices[first..first + count];
        let bounds = range.iter().fold(Aabb::empty(), |b, &i| b.union(&boxes[i as usize]));
        if count <= max_leaf {
            nodes[node] = Bvh2Node::new(bounds, count as u32, first as u32);
            continue;
        }
        let left = split(range, boxes, &centers).unwrap_or(count / 2);
        let children = nodes.len();
        nodes.extend([Bvh2Node::default(), Bvh2Node::default()]);
        nodes[node] = Bvh2Node::new(bounds, 0, children as u32);
        work.push((children + 1, first + left, count - left));
        work.push((children, first, left));
    }
    Bvh2 { nodes, primitive_indices: indices, ..Bvh2::default() }
}

/// Partitions `range` at the best SAH split of its centroids and returns the size of the left
/// part, or `None` when no bin boundary separates the primitives (the caller then splits at the
/// median).
fn split(range: &mut [u32], boxes: &[Aabb], centers: &[Vec3A]) -> Option<usize> {
    let mut centroid_bounds = Aabb::empty();
    for &i in range.iter() {
        centroid_bounds.extend(centers[i as usize]);
    }
    let axis = centroid_bounds.largest_axis();
    let (lo, hi) = (centroid_bounds.min[axis], centroid_bounds.max[axis]);
    if !(hi > lo) {
        return None;
    }
    let scale = BINS as f32 / (hi - lo);
    let bin_of = |i: u32| (((centers[i as usize][axis] - lo) * scale) as usize).min(BINS - 1);
    let mut bin_boxes = [Aabb::empty(); BINS];
    let mut bin_counts = [0usize; BINS];
    for &i in range.iter() {
        let b = bin_of(i);
        bin_boxes[b] = bin_boxes[b].union(&boxes[i as usize]);
        bin_counts[b] += 1;
    }
    // The area and count left of each boundary, then the best boundary from the right.
    let mut left_area = [0.0f32; BINS];
    let mut left_count = [0usize; BINS];
    let (mut acc, mut n) = (Aabb::empty(), 0);
    for b in 0..BINS - 1 {
        acc = acc.union(&bin_boxes[b]);
        n += bin_counts[b];
        left_area[b] = if n > 0 { acc.half_area() } else { 0.0 };
        left_count[b] = n;
    }
    let (mut acc, mut n) = (Aabb::empty(), 0);
    let mut best: Option<(f32, usize)> = None;
    for b in (0..BINS - 1).rev() {
        acc = acc.union(&bin_boxes[b + 1]);
        n += bin_counts[b + 1];
        if left_count[b] == 0 || n == 0 {
            continue;
        }
        let cost = left_area[b] * left_count[b] as f32 + acc.half_area() * n as f32;
        if best.is_none_or(|(c, _)| cost < c) {
            best = Some((cost, b));
        }
    }
    let (_, boundary) = best?;
    // Partition in place: the primitives of bins up to `boundary` first.
    let mut left = 0;
    for k in 0..range.len() {
        if bin_of(range[k]) <= boundary {
            range.swap(left, k);
            left += 1;
        }
    }
    Some(left)
}

/// The most triangles with one same bounding box that the PLOC build gets: it needs about one
/// pass over all nodes per duplicate of the largest such group.
pub const MAX_STACKED: usize = 64;

/// Whether more than [`MAX_STACKED`] triangles share one bounding box (coincident copies).
pub fn has_stacked_duplicates(triangles: &[[Vec3; 3]]) -> bool {
    if triangles.len() <= MAX_STACKED {
        return false;
    }
    let key = |t: &[Vec3; 3]| {
        let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
        let word = |a: f32, b: f32| (a.to_bits() as u64) << 32 | b.to_bits() as u64;
        let h = word(lo.x, lo.y).wrapping_mul(0x9e37_79b9_7f4a_7c15)
            ^ word(lo.z, hi.x).wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
            ^ word(hi.y, hi.z).wrapping_mul(0x1656_67b1_9e37_79f9);
        mix64(h)
    };
    // A count per hash bucket first (a bucket a triangle: distinct boxes put about ten in the
    // fullest bucket of a million), so that the usual scene costs one pass; the exact count, by
    // sorting, only when a bucket overflows.
    let bits = triangles.len().next_power_of_two().trailing_zeros().clamp(8, 24);
    let mut buckets = vec![0u8; 1 << bits];
    let overflows = triangles.iter().any(|t| {
        let count = &mut buckets[(key(t) >> (64 - bits)) as usize];
        *count = count.saturating_add(1);
        *count as usize > MAX_STACKED
    });
    if !overflows {
        return false;
    }
    let mut keys: Vec<u64> = triangles.iter().map(key).collect();
    keys.sort_unstable();
    keys.chunk_by(|a, b| a == b).any(|run| run.len() > MAX_STACKED)
}
