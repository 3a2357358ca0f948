//! How a caller lends `common` its threads. `common` runs no threads of its own, so work that
//! may run at once (decoding a scene's images) is handed to a [`Spread`] the caller supplies:
//! [`InOrder`] runs it on the calling thread, and the worker's and coordinator's own spreads on
//! theirs. Whatever the spread, the results are the same: each job writes only its own output.

/// One piece of independent work.
pub type Job<'a> = Box<dyn FnOnce() + Send + 'a>;

/// Runs independent jobs.
pub trait Spread: Sync {
    /// Runs every job once, in any order and possibly several at once, and returns when all
    /// have run. The jobs come largest first, so that a spread that takes them in order
    /// balances its threads.
    fn run<'a>(&self, jobs: Vec<Job<'a>>);
}

/// Runs the jobs one after the other on the calling thread.
#[derive(Clone, Copy, Debug, Default)]
pub struct InOrder;

impl Spread for InOrder {
    fn run<'a>(&self, jobs: Vec<Job<'a>>) {
        for job in jobs {
            job();
        }
    }
}
