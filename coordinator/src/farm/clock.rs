//! Time as the farm sees it: a [`Clock`] handed to the farm, read once per request and passed
//! on as a [`Moment`]. Lease expiry, heartbeats, retries, time limits and running times are all
//! decided from that argument, so tests drive them with a [`ManualClock`] instead of sleeping.
//! Only [`SystemClock`] reads the system's time.

use std::{
    ops::{Add, Sub},
    sync::{
        atomic::{AtomicU64, Ordering},
        Arc,
    },
    time::{Duration, Instant, SystemTime, UNIX_EPOCH},
};

/// A point in monotonic time: how long after its clock's origin.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Moment(Duration);

impl Moment {
    /// The clock's origin.
    pub const ZERO: Moment = Moment(Duration::ZERO);

    /// The time from `earlier` to this moment (zero if `earlier` is later).
    pub fn since(self, earlier: Moment) -> Duration {
        self.0.saturating_sub(earlier.0)
    }
}

impl Add<Duration> for Moment {
    type Output = Moment;

    fn add(self, d: Duration) -> Moment {
        Moment(self.0 + d)
    }
}

impl Sub<Duration> for Moment {
    type Output = Moment;

    /// The moment `d` earlier (the origin at the earliest).
    fn sub(self, d: Duration) -> Moment {
        Moment(self.0.saturating_sub(d))
    }
}

/// Where the farm gets the time.
pub trait Clock: Send + Sync {
    /// Monotonic time, for every duration and deadline.
    fn now(&self) -> Moment;
    /// Seconds since the Unix epoch, for creation times shown to users.
    fn unix(&self) -> f64;
}

/// The system's clocks.
#[derive(Debug)]
pub struct SystemClock {
    origin: Instant,
}

impl SystemClock {
    /// A clock whose origin is now.
    pub fn new() -> Self {
        SystemClock { origin: Instant::now() }
    }
}

impl Default for SystemClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Moment {
        Moment(self.origin.elapsed())
    }

    fn unix(&self) -> f64 {
        unix_now()
    }
}

/// Seconds since the Unix epoch, from the system's clock.
pub fn unix_now() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

/// A clock that moves only when told to (tests). Clones share the same time, so a test keeps
/// one and hands another to the farm.
#[derive(Clone, Debug, Default)]
pub struct ManualClock {
    nanos: Arc<AtomicU64>,
}

impl ManualClock {
    /// A clock at [`Moment::ZERO`].
    pub fn new() -> Self {
        Self::default()
    }

    /// Moves the time forward by `d`.
    pub fn advance(&self, d: Duration) {
        self.nanos.fetch_add(d.as_nanos() as u64, Ordering::Relaxed);
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Moment {
        Moment(Duration::from_nanos(self.nanos.load(Ordering::Relaxed)))
    }

    /// The Unix epoch plus the time the clock was moved forward.
    fn unix(&self) -> f64 {
        self.now().0.as_secs_f64()
    }
}
