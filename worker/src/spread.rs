//! The threads the worker and coordinator lend to `common`'s work that may run at once
//! (decoding a scene's images): [`Threads`], a scoped pool over a shared queue.

use std::sync::Mutex;

use common::spread::{Job, Spread};

/// Runs jobs on up to this many threads at once (scoped: they end with the call).
#[derive(Clone, Copy, Debug)]
pub struct Threads(pub usize);

impl Threads {
    /// As many threads as the machine runs at once.
    pub fn available() -> Threads {
        Threads(std::thread::available_parallelism().map_or(1, |n| n.get()))
    }
}

impl Spread for Threads {
    fn run<'a>(&self, jobs: Vec<Job<'a>>) {
        let threads = self.0.min(jobs.len());
        if threads <= 1 {
            jobs.into_iter().for_each(|job| job());
            return;
        }
        // Each thread takes the next job in order (the largest first) until none is left.
        let queue = Mutex::new(jobs.into_iter());
        let next = || queue.lock().unwrap_or_else(|p| p.into_inner()).next();
        std::thread::scope(|s| {
            for _ in 0..threads {
                s.spawn(|| {
                    while let Some(job) = next() {
                        job();
                    }
                });
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use super::*;

    #[test]
    fn every_job_runs_once_on_any_number_of_threads() {
        for threads in [0, 1, 2, 3, 8] {
            let mut out = vec![0usize; 37];
            let calls = AtomicUsize::new(0);
            let jobs: Vec<Job<'_>> = out
                .iter_mut()
                .enumerate()
                .map(|(i, o)| {
                    let calls = &calls;
                    Box::new(move || {
                        calls.fetch_add(1, Ordering::Relaxed);
                        *o = i * i;
                    }) as Job<'_>
                })
                .collect();
            Threads(threads).run(jobs);
            assert_eq!(calls.load(Ordering::Relaxed), 37, "{threads} threads");
            assert!(out.iter().enumerate().all(|(i, &o)| o == i * i), "{threads} threads");
        }
    }
}
