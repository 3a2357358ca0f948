//! What the coordinator must not lose, in SQLite (WAL mode) under `--data`: scenes (files,
//! content-addressed by SHA-256), jobs, each tile's sums of its tasks `0..prefix`, and the
//! accepted results still waiting for an earlier task (`pending`).
//!
//! A result is accepted in memory and its writes (tile row, pending rows, job row) committed
//! before the worker hears "merged", so after a `kill -9` the database holds exactly the
//! accepted tasks: the tasks that were leased but not yet committed are simply leased again. WAL with `synchronous = NORMAL` survives a process crash at any point; only a power
//! loss may lose the last transactions (which are then re-rendered, never double counted).
//!
//! Group commit: under the farm lock a merge only queues a copy of what it changed
//! ([`Store::queue_task`]); the worker's request then waits for its [`Commit`] outside the lock,
//! and whichever waiter takes the database first writes every write queued so far in one
//! transaction (one tile row for several results of a tile, one job row per job). Every other
//! use of the database first commits what is queued, so the database always holds a prefix of
//! the farm's changes in the order the farm made them; a group that fails to commit stops all
//! later commits (`commit_queue`), so that it stays a prefix. Between a merge and its commit,
//! the farm's answers to users (status, images of frames still in memory) already show the
//! merge; a worker hears "merged" only after the commit.

use std::{
    collections::{HashMap, HashSet},
    io::Write,
    path::{Path, PathBuf},
    sync::{Arc, Mutex, MutexGuard},
};

use anyhow::{Context, Result};
use common::{film::TileAccum, settings::RenderSettings};
use rusqlite::{params, Connection, OptionalExtension};

use super::{
    clock::{unix_now, Moment},
    job::{Job, JobState},
};

/// The database and the scene folder.
pub struct Store {
    shared: Arc<Shared>,
    /// The database file.
    path: PathBuf,
    scenes_dir: PathBuf,
    /// Whether what is written must survive a crash (scene files are synced to disk).
    durable: bool,
    /// The frames (job, frame) whose pilot image is queued or stored: a merge copies it once.
    pilots_queued: HashSet<(String, u32)>,
}

/// The most merges queued for a commit: the merge that fills the queue commits it before the
/// farm goes on (so that at most this many wait in the queue, and as many again in a group
/// being committed).
pub(crate) const MAX_QUEUED: usize = 64;

/// What the farm and the requests waiting for their commits share.
struct Shared {
    /// The connection; whoever holds it commits the queue before anything else.
    db: Mutex<Connection>,
    queue: Mutex<Queue>,
}

/// Merges accepted in memory whose writes are not yet committed.
#[derive(Default)]
struct Queue {
    writes: Vec<TaskWrite>,
    /// The number of the next write queued.
    next: u64,
    /// Writes numbered below this are settled: committed, or failed with their error in
    /// `failed`.
    settled: u64,
    /// The error of each write whose transaction failed, until its waiter takes it.
    failed: HashMap<u64, String>,
    /// Transactions of queued writes, and the seconds they took (for `/metrics`).
    groups: u64,
    group_seconds: f64,
    /// The error of the group that failed, once one has: nothing is committed after it.
    broken: Option<String>,
}

/// What accepting one result changed, copied out of its job under the farm lock and encoded by
/// whoever commits it.
struct TaskWrite {
    seq: u64,
    job: String,
    frame: u32,
    tile: u32,
    change: Change,
    /// The frame's pilot image, the first time a merge finds it fixed.
    pilot: Option<Vec<[f32; 3]>>,
    kernels: Vec<String>,
    row: JobRow,
}

/// A result's change to its tile.
enum Change {
    /// It waits for an earlier task of its tile.
    Pending { k: u32, sums: TileAccum },
    /// The tile's new prefix and sums (the pending results below the prefix absorbed).
    Tile { prefix: u32, sums: TileAccum },
}

/// The mutable columns of a job's row.
struct JobRow {
    state: &'static str,
    error: Option<String>,
    elapsed_s: f64,
    scales: String,
    finished: Option<f64>,
}

impl JobRow {
    fn of(job: &Job, now: Moment) -> JobRow {
        JobRow {
            state: job.state.name(),
            error: job.error.clone(),
            elapsed_s: job.elapsed(now),
            scales: scales_json(job),
            finished: job.finished_unix,
        }
    }

    fn write(&self, db: &Connection, id: &str) -> Result<()> {
        db.prepare_cached(
            "UPDATE jobs SET state = ?2, error = ?3, elapsed_s = ?4, scales = ?5, finished = ?6
             WHERE id = ?1",
        )?
        .execute(params![
            id,
            self.state,
            self.error,
            self.elapsed_s,
            self.scales,
            self.finished
        ])?;
        Ok(())
    }
}

/// A merge's writes, queued: [`Commit::wait`] returns once they are committed.
#[must_use = "a merge is answered only once its writes are committed"]
pub struct Commit {
    shared: Arc<Shared>,
    seq: u64,
}

impl Commit {
    /// Waits until the write is committed, committing the queue itself if no one else is; the
    /// error of the transaction it was in, if that failed.
    pub fn wait(self) -> Result<()> {
        loop {
            {
                let mut queue = lock(&self.shared.queue);
                if queue.settled > self.seq {
                    return match queue.failed.remove(&self.seq) {
                        Some(e) => Err(anyhow::anyhow!("committing a merged result failed: {e}")),
                        None => Ok(()),
                    };
                }
            }
            let mut db = lock(&self.shared.db);
            // This write's own outcome is read above.
            let _ = commit_queue(&self.shared, &mut db);
        }
    }
}

/// A mutex's guard, whether or not a thread panicked holding it (the data are written whole or
/// not at all by SQLite's transactions).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Writes every queued write in one transaction (the caller holds the connection, so queued
/// writes are taken and committed in the order they were queued).
///
/// A failure is for good: the database then holds the farm's merges up to the failed group, and
/// committing any later one would leave a gap (a tile's sums, a frame's pilot image) behind
/// what it records. Every later commit and use of the database returns the same error, and the
/// coordinator must be restarted: it resumes from what was committed, the rest leased again.
fn commit_queue(shared: &Shared, db: &mut Connection) -> Result<()> {
    let writes = {
        let mut queue = lock(&shared.queue);
        if let Some(e) = &queue.broken {
            let e = e.clone();
            // Nothing more reaches the database: what is queued fails with the first error.
            let writes = std::mem::take(&mut queue.writes);
            if let Some(last) = writes.last() {
                queue.settled = last.seq + 1;
                for w in &writes {
                    queue.failed.insert(w.seq, e.clone());
                }
            }
            return Err(anyhow::anyhow!("{e}"));
        }
        std::mem::take(&mut queue.writes)
    };
    let Some(last) = writes.last().map(|w| w.seq) else { return Ok(()) };
    let start = std::time::Instant::now();
    // A panic while writing fails the group like an error, so that no waiter is left to take
    // a later group's commit for its own.
    let outcome =
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| write_batch(db, &writes)))
            .unwrap_or_else(|_| Err(anyhow::anyhow!("writing the group panicked")));
    let mut queue = lock(&shared.queue);
    queue.settled = last + 1;
    queue.groups += 1;
    queue.group_seconds += start.elapsed().as_secs_f64();
    if let Err(e) = &outcome {
        let e = format!(
            "committing merged results failed ({e:#}): the farm's database stops here; restart the coordinator to resume from what it holds"
        );
        tracing::error!("{e}");
        for w in &writes {
            queue.failed.insert(w.seq, e.clone());
        }
        queue.broken = Some(e);
    }
    outcome
}

/// The writes of a batch, in order, in one transaction: of several new sums of one tile only the
/// last is written, and of several rows of one job only the last.
fn write_batch(db: &mut Connection, writes: &[TaskWrite]) -> Result<()> {
    let mut last_tile = HashMap::new();
    let mut last_row = HashMap::new();
    for (i, w) in writes.iter().enumerate() {
        if let Change::Tile { .. } = w.change {
            last_tile.insert((w.job.as_str(), w.frame, w.tile), i);
        }
        last_row.insert(w.job.as_str(), i);
    }
    let tx = db.transaction()?;
    for (i, w) in writes.iter().enumerate() {
        let (job, frame, tile) = (w.job.as_str(), w.frame, w.tile);
        match &w.change {
            Change::Pending { k, sums } => put_pending(&tx, job, frame, tile, *k, sums)?,
            Change::Tile { prefix, sums } => {
                if last_tile[&(job, frame, tile)] == i {
                    put_tile(&tx, job, frame, tile, *prefix, sums)?;
                }
                tx.prepare_cached(
                    "DELETE FROM pending WHERE job = ?1 AND frame = ?2 AND tile = ?3 AND task < ?4",
                )?
                .execute(params![job, frame, tile, prefix])?;
            }
        }
        if let Some(means) = &w.pilot {
            let blob = bincode::serde::encode_to_vec(means, bincode_config())?;
            tx.prepare_cached(
                "INSERT OR IGNORE INTO pilots (job, frame, means) VALUES (?1, ?2, ?3)",
            )?
            .execute(params![job, frame, blob])?;
        }
        put_kernels(&tx, job, frame, &w.kernels)?;
        if last_row[job] == i {
            w.row.write(&tx, job)?;
        }
    }
    tx.commit()?;
    Ok(())
}

/// A job row as stored.
pub struct StoredJob {
    /// Id.
    pub id: String,
    /// Creation order.
    pub seq: u64,
    /// Scene hash.
    pub scene: String,
    /// Settings.
    pub settings: RenderSettings,
    /// Priority.
    pub priority: i32,
    /// State.
    pub state: JobState,
    /// Failure reason.
    pub error: Option<String>,
    /// Creation time (Unix seconds).
    pub created_unix: f64,
    /// Running seconds so far.
    pub elapsed_s: f64,
    /// Adaptive stopping scale per frame (fixed from each frame's pilot).
    pub scales: Vec<Option<f64>>,
    /// When it ended (Unix seconds); `None` while it runs, and for jobs that ended before the
    /// column existed.
    pub finished_unix: Option<f64>,
    /// Its name (`None` for jobs without one, and those from before the column existed).
    pub name: Option<String>,
}

/// A tile row as stored.
pub struct StoredTile {
    /// Frame index.
    pub frame: u32,
    /// Tile index.
    pub tile: u32,
    /// Tasks `0..prefix` are in `sums`.
    pub prefix: u32,
    /// Their sums, added in task order (`None`: no task is summed yet).
    pub sums: Option<TileAccum>,
    /// Accepted results waiting for an earlier task.
    pub pending: Vec<(u32, TileAccum)>,
}

/// Scales as JSON, each f64 as its bit pattern (decimal text need not parse back to the same
/// bits, and the adaptive decisions after a restart must be the same as before it).
fn scales_json(job: &Job) -> String {
    let bits: Vec<Option<u64>> = job.scales().iter().map(|s| s.map(f64::to_bits)).collect();
    serde_json::to_string(&bits).unwrap_or_else(|_| "[]".into())
}

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::standard()
}

/// Upserts a tile's prefix and its sums.
fn put_tile(
    tx: &rusqlite::Transaction<'_>,
    job: &str,
    frame: u32,
    tile: u32,
    prefix: u32,
    sums: &TileAccum,
) -> Result<()> {
    let sums = bincode::serde::encode_to_vec(sums, bincode_config())?;
    tx.prepare_cached(
        "INSERT INTO tiles (job, frame, tile, prefix, sums) VALUES (?1, ?2, ?3, ?4, ?5)
         ON CONFLICT (job, frame, tile) DO UPDATE SET prefix = ?4, sums = ?5",
    )?
    .execute(params![job, frame, tile, prefix, sums])?;
    Ok(())
}

/// Stores task `k`'s result, waiting for an earlier task of its tile.
fn put_pending(
    tx: &rusqlite::Transaction<'_>,
    job: &str,
    frame: u32,
    tile: u32,
    k: u32,
    acc: &TileAccum,
) -> Result<()> {
    let sums = bincode::serde::encode_to_vec(acc, bincode_config())?;
    tx.prepare_cached(
        "INSERT OR REPLACE INTO pending (job, frame, tile, task, sums) VALUES (?1, ?2, ?3, ?4, ?5)",
    )?
    .execute(params![job, frame, tile, k, sums])?;
    Ok(())
}

/// Stores the kernels that rendered frame index `frame` of `job` (those stored already stay).
fn put_kernels<'k>(
    db: &Connection,
    job: &str,
    frame: u32,
    kernels: impl IntoIterator<Item = &'k String>,
) -> Result<()> {
    let mut insert = db
        .prepare_cached("INSERT OR IGNORE INTO kernels (job, frame, kernel) VALUES (?1, ?2, ?3)")?;
    for kernel in kernels {
        insert.execute(params![job, frame, kernel])?;
    }
    Ok(())
}

/// Updates the job's row: state, error, elapsed time, adaptive scales, end time.
fn put_job_state(db: &Connection, job: &Job, now: Moment) -> Result<()> {
    JobRow::of(job, now).write(db, &job.id)
}

impl Store {
    /// Opens (creating) the store under `dir`. `durable: false` is for scratch stores that
    /// need not survive a crash: commits skip the write-ahead log and every sync.
    pub fn open(dir: &Path, durable: bool) -> Result<Store> {
        let scenes_dir = dir.join("scenes");
        std::fs::create_dir_all(&scenes_dir)
            .with_context(|| format!("creating {}", scenes_dir.display()))?;
        let path = dir.join("farm.sqlite");
        let db = Connection::open(&path).with_context(|| format!("opening {}", path.display()))?;
        if durable {
            db.pragma_update(None, "journal_mode", "WAL")?;
            db.pragma_update(None, "synchronous", "NORMAL")?;
        } else {
            // A scratch store (the one-shot `coordinator render`, whose folder is deleted at
            // exit): no write-ahead log and no syncs, so committing a result costs no disk time.
            db.pragma_update(None, "journal_mode", "MEMORY")?;
            db.pragma_update(None, "synchronous", "OFF")?;
        }
        db.execute_batch(
            "CREATE TABLE IF NOT EXISTS scenes (
                 hash TEXT PRIMARY KEY, format TEXT NOT NULL, bytes INTEGER NOT NULL,
                 created REAL NOT NULL);
             CREATE TABLE IF NOT EXISTS jobs (
                 id TEXT PRIMARY KEY, seq INTEGER NOT NULL, scene TEXT NOT NULL,
                 settings TEXT NOT NULL, priority INTEGER NOT NULL, state TEXT NOT NULL,
                 error TEXT, created REAL NOT NULL, elapsed_s REAL NOT NULL,
                 scales TEXT NOT NULL DEFAULT '[]', finished REAL, name TEXT);
             CREATE TABLE IF NOT EXISTS tiles (
                 job TEXT NOT NULL, frame INTEGER NOT NULL, tile INTEGER NOT NULL,
                 prefix INTEGER NOT NULL, sums BLOB NOT NULL,
                 PRIMARY KEY (job, frame, tile));
             CREATE TABLE IF NOT EXISTS pending (
                 job TEXT NOT NULL, frame INTEGER NOT NULL, tile INTEGER NOT NULL,
                 task INTEGER NOT NULL, sums BLOB NOT NULL,
                 PRIMARY KEY (job, frame, tile, task));
             CREATE TABLE IF NOT EXISTS pilots (
                 job TEXT NOT NULL, frame INTEGER NOT NULL, means BLOB NOT NULL,
                 PRIMARY KEY (job, frame));
             CREATE TABLE IF NOT EXISTS kernels (
                 job TEXT NOT NULL, frame INTEGER NOT NULL, kernel TEXT NOT NULL,
                 PRIMARY KEY (job, frame, kernel));",
        )
        .context("creating the schema")?;
        // Databases from before jobs had an end time gain the column (empty: such a job's end
        // is noted when the farm opens it).
        let has_finished = db
            .prepare("SELECT 1 FROM pragma_table_info('jobs') WHERE name = 'finished'")?
            .exists([])?;
        if !has_finished {
            db.execute_batch("ALTER TABLE jobs ADD COLUMN finished REAL")
                .context("adding the jobs' end time")?;
        }
        // And before jobs had names (none).
        let has_name =
            db.prepare("SELECT 1 FROM pragma_table_info('jobs') WHERE name = 'name'")?.exists([])?;
        if !has_name {
            db.execute_batch("ALTER TABLE jobs ADD COLUMN name TEXT")
                .context("adding the jobs' names")?;
        }
        // A reader ([`Store::tile_reader`]) may hold the database a moment (without a write-ahead
        // log): a commit waits for it rather than fail.
        db.busy_timeout(std::time::Duration::from_secs(10))?;
        let shared = Arc::new(Shared { db: Mutex::new(db), queue: Mutex::default() });
        Ok(Store { shared, path, scenes_dir, durable, pilots_queued: HashSet::new() })
    }

    /// The connection, once every queued write is committed (the error of that commit, if it
    /// failed: the farm's memory is then ahead of the database).
    fn db(&self) -> Result<MutexGuard<'_, Connection>> {
        let mut db = lock(&self.shared.db);
        commit_queue(&self.shared, &mut db)?;
        Ok(db)
    }

    /// Path of a stored scene's bytes.
    pub fn scene_path(&self, hash: &str) -> PathBuf {
        self.scenes_dir.join(hash)
    }

    /// Whether a scene is stored, and its format.
    pub fn scene_format(&self, hash: &str) -> Result<Option<String>> {
        Ok(self
            .db()?
            .query_row("SELECT format FROM scenes WHERE hash = ?1", [hash], |r| r.get(0))
            .optional()?)
    }

    /// Stores a scene's bytes (atomically: a temporary file renamed into place) and its row.
    pub fn put_scene(&self, hash: &str, format: &str, bytes: &[u8]) -> Result<()> {
        let path = self.scene_path(hash);
        if !path.exists() {
            let mut tmp = tempfile::NamedTempFile::new_in(&self.scenes_dir)?;
            tmp.write_all(bytes)?;
            if self.durable {
                // A scratch store's folder is deleted at exit: its files need no sync (which
                // took 1.5-3 ms of a 1-spp `coordinator render`).
                tmp.as_file().sync_all()?;
            }
            tmp.persist(&path).map_err(|e| e.error)?;
        }
        self.db()?.execute(
            "INSERT OR IGNORE INTO scenes (hash, format, bytes, created) VALUES (?1, ?2, ?3, ?4)",
            params![hash, format, bytes.len() as i64, unix_now()],
        )?;
        Ok(())
    }

    /// Inserts a new job, as it is at `now`.
    pub fn insert_job(&self, job: &Job, now: Moment) -> Result<()> {
        self.db()?.execute(
            "INSERT INTO jobs (id, seq, scene, settings, priority, state, error, created, elapsed_s,
                               name)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
            params![
                job.id,
                job.seq as i64,
                job.scene,
                serde_json::to_string(&job.settings)?,
                job.priority,
                job.state.name(),
                job.error,
                job.created_unix,
                job.elapsed(now),
                job.name,
            ],
        )?;
        Ok(())
    }

    /// Updates a job's state, error, elapsed time and end time, as they are at `now`.
    pub fn update_job(&self, job: &Job, now: Moment) -> Result<()> {
        put_job_state(&*self.db()?, job, now)
    }

    /// Removes a job and everything stored for it (its tiles and pending results) in one
    /// transaction. Its scene stays: other jobs may render it.
    pub fn delete_job(&mut self, id: &str) -> Result<()> {
        self.pilots_queued.retain(|(job, _)| job != id);
        let mut db = self.db()?;
        let tx = db.transaction()?;
        tx.execute("DELETE FROM pending WHERE job = ?1", [id])?;
        tx.execute("DELETE FROM tiles WHERE job = ?1", [id])?;
        tx.execute("DELETE FROM pilots WHERE job = ?1", [id])?;
        tx.execute("DELETE FROM kernels WHERE job = ?1", [id])?;
        tx.execute("DELETE FROM jobs WHERE id = ?1", [id])?;
        tx.commit()?;
        Ok(())
    }

    /// Queues what accepting task `k` of a tile changed, and the job's row: the result itself
    /// when it is pending, else the tile's new prefix and sums (and the pending rows they
    /// absorbed), and the frame's pilot image when a result fixed it. Cheap (copies of the tile's
    /// sums): call it under the farm lock, and wait for the [`Commit`] outside it.
    pub fn queue_task(&mut self, job: &Job, frame: u32, tile: u32, k: u32, now: Moment) -> Commit {
        let t = &job.frames[frame as usize].tiles[tile as usize];
        let change = match t.pending.get(&k) {
            Some(acc) => Change::Pending { k, sums: acc.clone() },
            None => Change::Tile { prefix: t.prefix, sums: t.sums.clone() },
        };
        let pilot = match job.pilot(frame) {
            Some(means) if self.pilots_queued.insert((job.id.clone(), frame)) => {
                Some(means.to_vec())
            }
            _ => None,
        };
        let mut queue = lock(&self.shared.queue);
        let seq = queue.next;
        queue.next += 1;
        queue.writes.push(TaskWrite {
            seq,
            job: job.id.clone(),
            frame,
            tile,
            change,
            pilot,
            kernels: job.frames[frame as usize].kernels.iter().cloned().collect(),
            row: JobRow::of(job, now),
        });
        let full = queue.writes.len() >= MAX_QUEUED;
        drop(queue);
        if full {
            // The farm outruns the disk: commit here, under the farm lock, so that what waits
            // stays bounded (each write holds a copy of its tile's sums). The writes' own
            // waiters read the outcome.
            let _ = commit_queue(&self.shared, &mut lock(&self.shared.db));
        }
        Commit { shared: self.shared.clone(), seq }
    }

    /// The transactions that committed queued merges so far, and the seconds they took.
    pub fn groups(&self) -> (u64, f64) {
        let queue = lock(&self.shared.queue);
        (queue.groups, queue.group_seconds)
    }

    /// [`Store::queue_task`] and [`Commit::wait`] in one (tests; the farm waits for its commits
    /// outside its lock).
    #[cfg(test)]
    pub fn commit_task(
        &mut self,
        job: &Job,
        frame: u32,
        tile: u32,
        k: u32,
        now: Moment,
    ) -> Result<()> {
        self.queue_task(job, frame, tile, k, now).wait()
    }

    /// Writes every tile of frame `frame` (its prefix sums and pending results) and the job's
    /// row in one transaction: what a scratch store, which skips `commit_task`, keeps of a frame
    /// before it leaves memory.
    pub fn commit_frame(&mut self, job: &Job, frame: u32, now: Moment) -> Result<()> {
        let mut db = self.db()?;
        let tx = db.transaction()?;
        for (i, t) in job.frames[frame as usize].tiles.iter().enumerate() {
            let tile = i as u32;
            if !t.sums.pixels.is_empty() {
                put_tile(&tx, &job.id, frame, tile, t.prefix, &t.sums)?;
            }
            for (&k, acc) in &t.pending {
                put_pending(&tx, &job.id, frame, tile, k, acc)?;
            }
        }
        if let Some(means) = job.pilot(frame) {
            let blob = bincode::serde::encode_to_vec(means, bincode_config())?;
            tx.prepare_cached(
                "INSERT OR REPLACE INTO pilots (job, frame, means) VALUES (?1, ?2, ?3)",
            )?
            .execute(params![job.id, frame, blob])?;
        }
        put_kernels(&tx, &job.id, frame, &job.frames[frame as usize].kernels)?;
        put_job_state(&tx, job, now)?;
        tx.commit()?;
        Ok(())
    }

    /// The kernels that rendered each frame of a job (by frame index), as stored.
    pub fn kernels(&self, job: &str) -> Result<Vec<(u32, String)>> {
        let db = self.db()?;
        let mut stmt =
            db.prepare("SELECT frame, kernel FROM kernels WHERE job = ?1 ORDER BY frame")?;
        let rows = stmt.query_map([job], |r| Ok((r.get::<_, u32>(0)?, r.get::<_, String>(1)?)))?;
        Ok(rows.collect::<rusqlite::Result<_>>()?)
    }

    /// Every job, oldest first.
    pub fn jobs(&self) -> Result<Vec<StoredJob>> {
        let db = self.db()?;
        let mut stmt = db.prepare(
            "SELECT id, seq, scene, settings, priority, state, error, created, elapsed_s, scales,
                    finished, name
             FROM jobs ORDER BY seq",
        )?;
        let rows = stmt.query_map([], |r| {
            Ok((
                r.get::<_, String>(0)?,
                r.get::<_, i64>(1)?,
                r.get::<_, String>(2)?,
                r.get::<_, String>(3)?,
                r.get::<_, i32>(4)?,
                r.get::<_, String>(5)?,
                r.get::<_, Option<String>>(6)?,
                r.get::<_, f64>(7)?,
                r.get::<_, f64>(8)?,
                r.get::<_, String>(9)?,
                r.get::<_, Option<f64>>(10)?,
                r.get::<_, Option<String>>(11)?,
            ))
        })?;
        let mut out = Vec::new();
        for row in rows {
            let (
                id,
                seq,
                scene,
                settings,
                priority,
                state,
                error,
                created_unix,
                elapsed_s,
                scales,
                finished_unix,
                name,
            ) = row?;
            let bits: Vec<Option<u64>> = serde_json::from_str(&scales)
                .with_context(|| format!("job {id}: stored adaptive scales"))?;
            let scales = bits.into_iter().map(|b| b.map(f64::from_bits)).collect();
            let settings = RenderSettings::from_json(&settings)
                .map_err(|e| anyhow::anyhow!("job {id}: stored settings: {e}"))?;
            let state = JobState::parse(&state)
                .with_context(|| format!("job {id}: unknown state '{state}'"))?;
            out.push(StoredJob {
                id,
                seq: seq as u64,
                scene,
                settings,
                priority,
                state,
                error,
                created_unix,
                elapsed_s,
                scales,
                finished_unix,
                name,
            });
        }
        Ok(out)
    }

    /// How many rows job `id` has, over its job row, tiles, pending results and pilot images
    /// (tests).
    #[cfg(test)]
    pub fn rows_of(&self, id: &str) -> i64 {
        let db = self.db().unwrap();
        ["jobs WHERE id", "tiles WHERE job", "pending WHERE job", "pilots WHERE job"]
            .iter()
            .map(|t| {
                let sql = format!("SELECT COUNT(*) FROM {t} = ?1");
                db.query_row(&sql, [id], |r| r.get::<_, i64>(0)).unwrap()
            })
            .sum()
    }

    /// The summed tiles of one frame of a job (pending results left out).
    pub fn frame_sums(&self, job: &str, frame: u32) -> Result<Vec<(u32, TileAccum)>> {
        let rows = self.tile_rows(
            "SELECT frame, tile, prefix, sums FROM tiles WHERE job = ?1 AND frame = ?2",
            params![job, frame],
        )?;
        Ok(rows.into_iter().map(|(_, tile, _, sums)| (tile, sums)).collect())
    }

    /// A second connection to the database, read-only, for reading tiles without the farm.
    pub fn tile_reader(&self) -> Result<TileReader> {
        use rusqlite::OpenFlags;
        // What it reads is committed first.
        drop(self.db()?);
        let db = Connection::open_with_flags(
            &self.path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .with_context(|| format!("opening {} to read", self.path.display()))?;
        db.busy_timeout(std::time::Duration::from_secs(10))?;
        Ok(TileReader { db })
    }

    /// Rows of (frame, tile, a task number, decoded sums) from `sql`.
    fn tile_rows(
        &self,
        sql: &str,
        args: impl rusqlite::Params,
    ) -> Result<Vec<(u32, u32, u32, TileAccum)>> {
        let db = self.db()?;
        let mut stmt = db.prepare(sql)?;
        let rows = stmt.query_map(args, |r| {
            Ok((
                r.get::<_, u32>(0)?,
                r.get::<_, u32>(1)?,
                r.get::<_, u32>(2)?,
                r.get::<_, Vec<u8>>(3)?,
            ))
        })?;
        let mut out = Vec::new();
        for row in rows {
            let (frame, tile, k, blob) = row?;
            let (sums, _): (TileAccum, usize) =
                bincode::serde::decode_from_slice(&blob, bincode_config())?;
            out.push((frame, tile, k, sums));
        }
        Ok(out)
    }

    /// The stored pilot images of a job's bidirectional frames under adaptive sampling, by frame
    /// index.
    pub fn pilots(&self, job: &str) -> Result<Vec<(u32, Vec<[f32; 3]>)>> {
        let db = self.db()?;
        let mut stmt = db.prepare("SELECT frame, means FROM pilots WHERE job = ?1")?;
        let rows = stmt.query_map([job], |r| Ok((r.get::<_, u32>(0)?, r.get::<_, Vec<u8>>(1)?)))?;
        let mut out = Vec::new();
        for row in rows {
            let (frame, blob) = row?;
            let (means, _): (Vec<[f32; 3]>, usize) =
                bincode::serde::decode_from_slice(&blob, bincode_config())?;
            out.push((frame, means));
        }
        Ok(out)
    }

    /// The stored tiles of a job (a tile with only pending results has prefix 0 and no sums).
    pub fn tiles(&self, job: &str) -> Result<Vec<StoredTile>> {
        let mut pending: std::collections::BTreeMap<(u32, u32), Vec<(u32, TileAccum)>> =
            Default::default();
        let sql = "SELECT frame, tile, task, sums FROM pending WHERE job = ?1";
        for (frame, tile, task, sums) in self.tile_rows(sql, [job])? {
            pending.entry((frame, tile)).or_default().push((task, sums));
        }
        let sql = "SELECT frame, tile, prefix, sums FROM tiles WHERE job = ?1";
        let mut out = Vec::new();
        for (frame, tile, prefix, sums) in self.tile_rows(sql, [job])? {
            let pending = pending.remove(&(frame, tile)).unwrap_or_default();
            out.push(StoredTile { frame, tile, prefix, sums: Some(sums), pending });
        }
        for ((frame, tile), pending) in pending {
            out.push(StoredTile { frame, tile, prefix: 0, sums: None, pending });
        }
        Ok(out)
    }
}

/// Reads stored tiles one at a time on a connection of its own, so that serving the image of a
/// finished job (whose sums left memory) holds neither the farm's lock nor more than one tile.
pub struct TileReader {
    db: Connection,
}

impl TileReader {
    /// The summed tile `tile` of frame `frame` of job `job` (`None`: nothing is stored for it).
    pub fn tile(&self, job: &str, frame: u32, tile: u32) -> Result<Option<TileAccum>> {
        let blob: Option<Vec<u8>> = self
            .db
            .prepare_cached("SELECT sums FROM tiles WHERE job = ?1 AND frame = ?2 AND tile = ?3")?
            .query_row(params![job, frame, tile], |r| r.get(0))
            .optional()?;
        Ok(match blob {
            Some(blob) => Some(bincode::serde::decode_from_slice(&blob, bincode_config())?.0),
            None => None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A folder with a database of one finished job as an older coordinator wrote it: the jobs
    /// table of before end times and names, plus the columns `extra` (", finished REAL" and
    /// its value ", 3.0" for one from before names alone).
    fn older_database(extra: (&str, &str)) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        let (column, value) = extra;
        let name = if column.is_empty() { "" } else { ", finished" };
        let db = Connection::open(dir.path().join("farm.sqlite")).unwrap();
        db.execute_batch(&format!(
            "CREATE TABLE jobs (
                 id TEXT PRIMARY KEY, seq INTEGER NOT NULL, scene TEXT NOT NULL,
                 settings TEXT NOT NULL, priority INTEGER NOT NULL, state TEXT NOT NULL,
                 error TEXT, created REAL NOT NULL, elapsed_s REAL NOT NULL,
                 scales TEXT NOT NULL DEFAULT '[]'{column});
             INSERT INTO jobs (id, seq, scene, settings, priority, state, created, elapsed_s{name})
             VALUES ('j', 0, 's', '{{}}', 0, 'done', 1.0, 2.0{value});"
        ))
        .unwrap();
        dir
    }

    /// A database from before jobs had an end time or a name opens, gains the columns, and keeps
    /// its rows.
    #[test]
    fn an_older_database_gains_the_end_time() {
        let dir = older_database(("", ""));
        let store = Store::open(dir.path(), true).unwrap();
        let jobs = store.jobs().unwrap();
        assert_eq!(jobs.len(), 1);
        assert_eq!((jobs[0].state, jobs[0].finished_unix), (JobState::Done, None));
        assert_eq!(jobs[0].name, None, "it gains the name column too, empty");
        drop(store);
        // Opening it again finds the column there.
        assert_eq!(Store::open(dir.path(), true).unwrap().jobs().unwrap().len(), 1);
    }

    /// A database with the end time but from before job names gains the name column alone,
    /// and keeps its rows and their end times.
    #[test]
    fn a_database_with_end_times_gains_the_names() {
        let dir = older_database((", finished REAL", ", 3.0"));
        let jobs = Store::open(dir.path(), true).unwrap().jobs().unwrap();
        assert_eq!((jobs.len(), jobs[0].finished_unix, jobs[0].name.clone()), (1, Some(3.0), None));
    }
}
