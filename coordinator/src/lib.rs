//! The coordinator: splits frames into tasks, has workers render them, merges the partial sums
//! and writes the images.
//!
//! # Layout
//! - [`client`]: `coordinator submit` and `healthcheck`, a user's client of a running farm.
//! - [`farm`]: the state machine of jobs, tasks, leases and workers, persisted in SQLite.
//! - [`service`]: `coordinator serve`, the farm over HTTP (REST API, worker protocol, metrics).
//! - [`split`]: frames -> tiles x sample ranges, in progressive order.
//! - [`local`]: the embedded default (`coordinator render`): local worker threads, one process.
//! - [`output`]: EXR and PNG writing (and reading, for checks).

pub mod client;
pub mod farm;
pub mod local;
pub mod output;
pub mod service;
pub mod split;
