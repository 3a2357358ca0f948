//! What crosses the wire between coordinator and worker: task specifications and their results.
//!
//! A task is a tile of pixels of one frame times a range of sample indices. Its result is the
//! tile's partial sums over exactly those samples.

use serde::{Deserialize, Serialize};

use crate::film::{Rect, TileAccum};

/// A half-open range of sample indices `[start, end)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct SampleRange {
    /// First sample index.
    pub start: u32,
    /// One past the last sample index.
    pub end: u32,
}

impl SampleRange {
    /// Number of samples.
    pub fn len(&self) -> u32 {
        self.end.saturating_sub(self.start)
    }

    /// True when the range holds no sample.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// What a task computes of its samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum TaskKind {
    /// The samples of the tile's pixels, traced from the camera (every integrator).
    #[default]
    Camera,
    /// Bidirectional path tracing's light tracing: for each sample index, a light subpath per
    /// pixel of the frame, connected to the camera wherever it lands; `rect` is the whole frame
    /// and the result holds the light-traced image's samples, which add to the camera tasks'.
    Light,
}

/// One unit of work: samples `samples` of every pixel of `rect` in frame `frame`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct TaskSpec {
    /// Frame number.
    pub frame: i64,
    /// The tile.
    pub rect: Rect,
    /// The sample indices.
    pub samples: SampleRange,
    /// What the samples are.
    pub kind: TaskKind,
}

/// What a worker returns for a task.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TaskResult {
    /// The task it answers.
    pub spec: TaskSpec,
    /// The tile's partial sums.
    pub tile: TileAccum,
    /// Rays traced (camera, bounce and shadow rays), for throughput figures.
    pub rays: u64,
    /// The kernel that rendered it (`"path, AVX-512 x16"`, `"path, AVX2 x8"`, `"path, scalar"`,
    /// `"bdpt, scalar"`...): what the frame's EXR header reports. Every kernel makes the same
    /// sums; at most [`MAX_KERNEL_NAME`] printable ASCII bytes.
    pub kernel: String,
}

/// The longest kernel name a result may carry, in bytes.
pub const MAX_KERNEL_NAME: usize = 64;

impl TaskResult {
    /// Checks that this result really answers `spec`: same task, one pixel sum per pixel of the
    /// tile, every pixel holding exactly the task's samples, and sums that some set of real
    /// sample values could have produced ([`crate::film::PixelSums::check`]: finite, means not
    /// negative and within the renderer's largest sample value). The message names the first
    /// problem found: the pixel (image coordinates), the channel and the value. The kernel's
    /// name must be 1 to [`MAX_KERNEL_NAME`] printable ASCII characters.
    pub fn check_answers(&self, spec: &TaskSpec) -> Result<(), String> {
        let k = &self.kernel;
        if k.is_empty()
            || k.len() > MAX_KERNEL_NAME
            || !k.bytes().all(|b| (b' '..=b'~').contains(&b))
        {
            let shown: String = k.chars().take(MAX_KERNEL_NAME).collect();
            return Err(format!(
                "the kernel's name {shown:?} is not 1 to {MAX_KERNEL_NAME} printable ASCII characters"
            ));
        }
        if self.spec != *spec {
            return Err(format!(
                "the result is for task {:?}, but the lease is for {:?}",
                self.spec, spec
            ));
        }
        if self.tile.rect != spec.rect {
            return Err(format!(
                "tile is {:?}, the task's tile is {:?}",
                self.tile.rect, spec.rect
            ));
        }
        if self.tile.pixels.len() != spec.rect.area() {
            return Err(format!(
                "{} pixel sums for a {}x{} tile ({} pixels)",
                self.tile.pixels.len(),
                spec.rect.width,
                spec.rect.height,
                spec.rect.area()
            ));
        }
        let n = spec.samples.len();
        // Odd indices in [start, end).
        let n_odd = spec.samples.end / 2 - spec.samples.start / 2;
        for (i, p) in self.tile.pixels.iter().enumerate() {
            let (x, y) = (i as u32 % spec.rect.width, i as u32 / spec.rect.width);
            let (x, y) = (spec.rect.x0 + x, spec.rect.y0 + y);
            p.check(n, n_odd)
                .map_err(|e| format!("pixel ({x}, {y}) of frame {}: {e}", spec.frame))?;
        }
        let max_rejected = n as u64 * spec.rect.area() as u64;
        if self.tile.rejected > max_rejected {
            return Err(format!(
                "{} refused samples, more than the task's {max_rejected}",
                self.tile.rejected
            ));
        }
        Ok(())
    }
}

/// Encodes a task result for the wire (bincode, standard configuration).
pub fn encode_result(result: &TaskResult) -> Vec<u8> {
    bincode::serde::encode_to_vec(result, bincode::config::standard())
        .expect("a task result always encodes")
}

/// The most bytes an encoded result for `spec` can take: a pixel's sums are at most 82 bytes
/// (two counts of at most five varint bytes, nine `f64`s), and the rest (the task, the tile's
/// corner and size, the counts of pixels, refused samples and rays, the kernel's name) at most
/// 256. The service
/// reads no more of a result's body than this.
pub fn max_result_bytes(spec: &TaskSpec) -> usize {
    256 + spec.rect.area() * 82
}

/// Decodes a task result; a truncated or malformed body gives a message, never a panic.
/// The decoder allocates at most 1 GiB, whatever the body claims.
pub fn decode_result(bytes: &[u8]) -> Result<TaskResult, String> {
    let config = bincode::config::standard().with_limit::<{ 1 << 30 }>();
    let (result, used): (TaskResult, usize) = bincode::serde::decode_from_slice(bytes, config)
        .map_err(|e| format!("undecodable task result ({} bytes): {e}", bytes.len()))?;
    if used != bytes.len() {
        return Err(format!("{} trailing bytes after the task result", bytes.len() - used));
    }
    Ok(result)
}

/// `POST /api/v1/workers`: a worker joins.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JoinRequest {
    /// A human-readable name (host name and process id by default).
    pub name: String,
    /// Render threads the worker will use.
    pub threads: u32,
    /// The worker's version, for the workers list.
    #[serde(default)]
    pub version: String,
}

/// The answer to a join.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JoinResponse {
    /// The worker's id, sent with every later request.
    pub id: String,
    /// A lease not renewed for this long is given to another worker.
    pub lease_timeout_s: f64,
    /// How often to renew a lease while rendering.
    pub heartbeat_s: f64,
}

/// A leased task: `POST /api/v1/workers/{id}/lease` answers this (or 204: no work now).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LeaseGrant {
    /// The lease id: the result, heartbeats and failure reports name it.
    pub lease: String,
    /// The job the task belongs to.
    pub job: String,
    /// SHA-256 of the scene bundle (fetch it from `/api/v1/scenes/{hash}`).
    pub scene: String,
    /// The job's render settings.
    pub settings: crate::settings::RenderSettings,
    /// What to render.
    pub task: TaskSpec,
    /// Seconds until the lease expires unless renewed.
    pub lease_timeout_s: f64,
    /// The budgets the coordinator checked the scene against: the worker loads it within the
    /// same, so that what the coordinator accepted every worker can load (a coordinator that
    /// sends none: the defaults).
    #[serde(default)]
    pub scene_budget: crate::budget::SceneBudget,
}

/// `POST /api/v1/leases/{lease}/fail`: the worker could not render the task.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FailReport {
    /// Why.
    pub error: String,
}

/// Header carrying the worker id on heartbeats, results and failure reports.
pub const WORKER_HEADER: &str = "x-worker-id";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::PixelSums;

    /// The largest encoding of a result, every count and varint at its widest, fits the bound,
    /// and the bound is not loose by more than its fixed part.
    #[test]
    fn the_result_bound_holds_the_widest_encoding() {
        let rect = Rect { x0: u32::MAX, y0: u32::MAX, width: 37, height: 11 };
        let spec = TaskSpec {
            frame: i64::MIN,
            rect,
            samples: SampleRange { start: u32::MAX, end: u32::MAX },
            kind: TaskKind::Light,
        };
        let widest = PixelSums {
            n: u32::MAX,
            n_odd: u32::MAX,
            mean: [f64::MAX; 3],
            m2: [f64::MAX; 3],
            mean_odd: [f64::MAX; 3],
        };
        let mut tile = TileAccum::new(rect);
        tile.pixels.fill(widest);
        tile.rejected = u64::MAX;
        let kernel = "~".repeat(MAX_KERNEL_NAME);
        let result = TaskResult { spec, tile, rays: u64::MAX, kernel };
        let bytes = encode_result(&result).len();
        let bound = max_result_bytes(&spec);
        assert!(bytes <= bound, "{bytes} bytes over the bound of {bound}");
        assert!(bound - bytes <= 256, "{bytes} bytes against a bound of {bound}");
    }

    /// A result names its kernel in 1 to 64 printable ASCII characters; anything else is
    /// refused, naming the kernel.
    #[test]
    fn kernel_names_are_short_printable_ascii() {
        let rect = Rect { x0: 0, y0: 0, width: 1, height: 1 };
        let samples = SampleRange { start: 0, end: 0 };
        let spec = TaskSpec { frame: 0, rect, samples, kind: TaskKind::Camera };
        let result = |kernel: &str| TaskResult {
            spec,
            tile: TileAccum::new(rect),
            rays: 0,
            kernel: kernel.to_string(),
        };
        assert_eq!(result("path, AVX-512 x16").check_answers(&spec), Ok(()));
        assert_eq!(result(&"~".repeat(MAX_KERNEL_NAME)).check_answers(&spec), Ok(()));
        for bad in
            [String::new(), "x".repeat(MAX_KERNEL_NAME + 1), "path\n".into(), "p\u{e2}th".into()]
        {
            let e = result(&bad).check_answers(&spec).unwrap_err();
            assert!(e.starts_with("the kernel's name"), "{bad:?}: {e}");
        }
    }
}
