//! The coordinator: splits frames into tasks, has workers render them, merges the partial sums
//! and writes the images.
//!
//! # Layout
//! - [`client`]: `coordinator submit` and `healthcheck`, a user's client of a running farm.
//! - [`farm`]: jobs, their tasks and images, persisted in SQLite; the task-and-lease state
//!   machine (`farm::lease`, a pure transition function) and the workers. Free of HTTP, with
//!   time passed in (`farm::clock`), so that expiry and retries are tested without sleeping.
//! - [`service`]: `coordinator serve`, the farm over HTTP (REST API, worker protocol, metrics),
//!   one file per resource; the only place where the farm's refusals become status codes. Also
//!   the in-process link of the local workers.
//! - [`split`]: frames -> tiles x sample ranges, in progressive order.
//! - [`local`]: the embedded default (`coordinator render`): local worker threads, one process.
//! - [`output`]: EXR and PNG writing (and reading, for checks).

pub mod client;
pub mod farm;
pub mod local;
pub mod log;
pub mod output;
pub mod service;
pub mod split;
