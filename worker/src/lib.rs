//! The worker: a stateless node that path-traces tasks.
//!
//! # Layout
//! - [`render`]: the renderer (synchronous, no I/O): scene preparation, BVH, sampler, BSDFs,
//!   lights, the path tracer, and `render_task`.

pub mod render;
