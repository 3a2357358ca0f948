//! The worker: a stateless node that path-traces tasks.
//!
//! # Layout
//! - [`render`]: the renderer (synchronous, no I/O): scene preparation, BVH, sampler, BSDFs,
//!   lights, the path tracer, and `render_task`.
//! - [`client`]: `worker --join`, the farm protocol over HTTP (lease, render, heartbeat, result).

pub mod client;
pub mod render;
