//! A worker's cache of built BVHs, so that a scene's geometry is built once per worker, not once
//! per job: jobs that differ in samples, size, seed, integrator, environment or lights reuse the
//! BVH that the first of them built.
//!
//! The key is the SHA-256 of the triangles the BVH is built over (their corners as bits, in
//! order), which `prepare` has already placed in the renderer's space. The build is a function of
//! those triangles alone (`Accel::build` is deterministic and single-threaded), so a hit gives
//! the bits a fresh build would: correct by construction, whatever changed in the scene or the
//! settings. A change that moves any still triangle (another camera, since the renderer's origin
//! is the camera; a frame in which a placement that is not blurred stands elsewhere; a material
//! variant that cuts a mesh out) is another key.
//!
//! The cache is bounded by the bytes of the BVHs it holds (`Accel::memory_bytes` and the
//! triangle order); past the bound the least recently used are dropped. A BVH larger than the
//! whole bound is built and used but not kept. Preparations hold their BVH by `Arc`, so a BVH
//! dropped from the cache lives on while a preparation uses it.

use std::sync::{
    atomic::{AtomicUsize, Ordering},
    Arc, Mutex,
};

use glam::Vec3;
use sha2::{Digest, Sha256};

use super::accel::Accel;

/// A BVH and the triangle order it was built in (`Accel::build`'s pair).
pub type Built = (Arc<Accel>, Arc<[u32]>);

/// Built BVHs by the hash of their triangles, at most `budget` bytes of them.
pub struct BvhCache {
    budget: usize,
    /// Most recently used first: key, BVH, its bytes.
    entries: Mutex<Vec<([u8; 32], Built, usize)>>,
    builds: AtomicUsize,
    hits: AtomicUsize,
}

/// The bound of a worker's cache unless `worker --bvh-cache-mib` gives another: 1 GiB, the BVHs
/// of about ten million triangles.
pub const DEFAULT_BUDGET: usize = 1 << 30;

impl Default for BvhCache {
    fn default() -> Self {
        BvhCache::new(DEFAULT_BUDGET)
    }
}

impl BvhCache {
    /// A cache of at most `budget` bytes of BVHs (0: none kept).
    pub fn new(budget: usize) -> Self {
        BvhCache {
            budget,
            entries: Mutex::new(Vec::new()),
            builds: AtomicUsize::new(0),
            hits: AtomicUsize::new(0),
        }
    }

    /// The BVH over `triangles`: the one kept for the same triangles, or a new build (kept if
    /// it fits the budget).
    pub fn get_or_build(&self, triangles: &[[Vec3; 3]]) -> Built {
        if self.budget == 0 {
            self.builds.fetch_add(1, Ordering::Relaxed);
            return build(triangles);
        }
        let key = key_of(triangles);
        let kept = most_recent(&mut self.entries.lock().unwrap_or_else(|p| p.into_inner()), &key);
        if let Some(kept) = kept {
            self.hits.fetch_add(1, Ordering::Relaxed);
            return kept;
        }
        // Built outside the lock, so that other lookups go on meanwhile.
        let built = build(triangles);
        self.builds.fetch_add(1, Ordering::Relaxed);
        let bytes = built.0.memory_bytes() + built.1.len() * std::mem::size_of::<u32>();
        if bytes <= self.budget {
            let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
            // Another caller built the same BVH meanwhile: share the one kept.
            if let Some(kept) = most_recent(&mut entries, &key) {
                return kept;
            }
            entries.insert(0, (key, built.clone(), bytes));
            // The most recently used, up to the first that would pass the budget.
            let mut total = 0;
            entries.retain(|(.., b)| {
                total += b;
                total <= self.budget
            });
        }
        built
    }

    /// BVHs built through this cache so far.
    pub fn builds(&self) -> usize {
        self.builds.load(Ordering::Relaxed)
    }

    /// BVHs taken from this cache instead of built.
    pub fn hits(&self) -> usize {
        self.hits.load(Ordering::Relaxed)
    }

    /// Bytes of the BVHs kept now.
    pub fn bytes(&self) -> usize {
        let entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        entries.iter().map(|(.., b)| b).sum()
    }
}

/// The entry of `key` in `entries`, moved to the front (the most recently used).
fn most_recent(entries: &mut Vec<([u8; 32], Built, usize)>, key: &[u8; 32]) -> Option<Built> {
    let i = entries.iter().position(|(k, ..)| k == key)?;
    let entry = entries.remove(i);
    let built = entry.1.clone();
    entries.insert(0, entry);
    Some(built)
}

/// The BVH over `triangles`, built (`Accel::build`), as the cache holds it.
pub fn build(triangles: &[[Vec3; 3]]) -> Built {
    let (accel, order) = Accel::build(triangles);
    (Arc::new(accel), order.into())
}

/// SHA-256 of the triangles' count and corners, bit for bit.
fn key_of(triangles: &[[Vec3; 3]]) -> [u8; 32] {
    let mut hash = Sha256::new();
    hash.update((triangles.len() as u64).to_le_bytes());
    let mut bytes = Vec::with_capacity(36 * 4096);
    for chunk in triangles.chunks(4096) {
        bytes.clear();
        for c in chunk.iter().flatten().flat_map(|v| v.to_array()) {
            bytes.extend_from_slice(&c.to_bits().to_le_bytes());
        }
        hash.update(&bytes);
    }
    hash.finalize().into()
}
