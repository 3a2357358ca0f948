//! The worker: a stateless node that path-traces tasks.
//!
//! # Layout
//! - [`render`]: the renderer (synchronous, no I/O): scene preparation, BVH, sampler, BSDFs,
//!   lights, the path tracer, and `render_task`.
//! - [`client`]: the worker's loop (lease, render, heartbeat, result), over any [`link`].
//! - [`link`]: the farm protocol's calls as a trait, and over HTTP (`worker --join`).
//! - [`spread`]: the threads lent to `common`'s parallel work (image decoding).
//! - [`test_scenes`]: scenes built in code for tests and benchmarks.

pub mod client;
pub mod link;
pub mod render;
pub mod spread;
pub mod test_scenes;
