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

/// One unit of work: samples `samples` of every pixel of `rect` in frame `frame`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct TaskSpec {
    /// Frame number.
    pub frame: i64,
    /// The tile.
    pub rect: Rect,
    /// The sample indices.
    pub samples: SampleRange,
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
}
