//! The job store: jobs, their programs and the journal of acknowledged units, in SQLite (WAL).
//!
//! A job's row and its program are committed before the first byte goes to the machine;
//! the units the machine acknowledges are journaled in batches (`Journal`), never more than
//! `journal_max_lag` behind, so after a crash `acked_units` is where the job resumes.

use machlink_protocols::Program;
use rusqlite::{params, Connection, OptionalExtension};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// A job's number in the store.
pub type JobId = i64;

/// Why the store failed.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("the job store {path} cannot be opened: {source}")]
    Open {
        path: String,
        #[source]
        source: rusqlite::Error,
    },
    #[error("the job store failed: {0}")]
    Sql(#[from] rusqlite::Error),
    #[error("the job store holds a bad record: {0}")]
    Corrupt(String),
}

/// Where a job is in its life.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    Queued,
    Running,
    Paused,
    Completed,
    Failed,
    Cancelled,
    /// The daemon stopped (crash, power cut) while the job ran; it resumes from `acked_units`.
    Interrupted,
}

impl JobState {
    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Paused => "paused",
            JobState::Completed => "completed",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
            JobState::Interrupted => "interrupted",
        }
    }
    pub fn parse(s: &str) -> Option<JobState> {
        Some(match s {
            "queued" => JobState::Queued,
            "running" => JobState::Running,
            "paused" => JobState::Paused,
            "completed" => JobState::Completed,
            "failed" => JobState::Failed,
            "cancelled" => JobState::Cancelled,
            "interrupted" => JobState::Interrupted,
            _ => return None,
        })
    }
    /// The job will not move again unless the operator resumes it.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            JobState::Completed | JobState::Failed | JobState::Cancelled | JobState::Interrupted
        )
    }
}

impl std::fmt::Display for JobState {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A job as the store holds it (without its program).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    pub id: JobId,
    pub machine: String,
    pub state: JobState,
    /// The operation, e.g. "profile".
    pub op: String,
    /// The shape file's name as submitted.
    pub file_name: String,
    /// The planning parameters, as submitted.
    pub params: serde_json::Value,
    /// Unix milliseconds.
    pub created_ms: i64,
    pub started_ms: Option<i64>,
    pub finished_ms: Option<i64>,
    /// Why the job failed, in the device's words (naming the line).
    pub error: Option<String>,
    pub total_units: usize,
    /// Units acknowledged by the machine; a resume starts at this unit.
    pub acked_units: usize,
}

/// What a new job is made of.
#[derive(Clone, Debug)]
pub struct NewJob {
    pub machine: String,
    pub op: String,
    pub file_name: String,
    pub params: serde_json::Value,
    pub program: Program,
}

/// A new job whose program is already in the store's form: the post's name and the units as
/// a JSON array (what `AnyKind::decode` reads back), with their count.
#[derive(Clone, Debug)]
pub struct NewJobUnits {
    pub machine: String,
    pub op: String,
    pub file_name: String,
    pub params: serde_json::Value,
    pub post: String,
    pub units_json: String,
    pub total_units: usize,
}

/// A program as the store holds it.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredProgram {
    /// The post that made it (`grbl`, `dst`, …, or `gcode-file`).
    pub post: String,
    /// Its units, a JSON array.
    pub units: String,
}

impl StoredProgram {
    /// The program, read back by the kind of machine it was made for.
    pub fn decode(&self, kind: &dyn machlink_protocols::AnyKind) -> Result<Program, StoreError> {
        kind.decode(&self.post, &self.units)
            .map_err(|e| StoreError::Corrupt(format!("a stored {} program: {e}", self.post)))
    }
}

/// The store: one SQLite connection shared by the daemon's tasks. Every call is short.
#[derive(Clone)]
pub struct Store {
    conn: Arc<Mutex<Connection>>,
    /// Journal flushes so far (tests count them).
    flushes: Arc<std::sync::atomic::AtomicU64>,
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS jobs (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    machine     TEXT    NOT NULL,
    state       TEXT    NOT NULL,
    op          TEXT    NOT NULL,
    file_name   TEXT    NOT NULL,
    params      TEXT    NOT NULL,
    created_ms  INTEGER NOT NULL,
    started_ms  INTEGER,
    finished_ms INTEGER,
    error       TEXT,
    total_units INTEGER NOT NULL,
    acked_units INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS programs (
    job_id INTEGER PRIMARY KEY REFERENCES jobs(id),
    kind   TEXT NOT NULL, -- the post that made the program
    units  TEXT NOT NULL  -- its units, a JSON array
);
CREATE TABLE IF NOT EXISTS journal (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id      INTEGER NOT NULL REFERENCES jobs(id),
    at_ms       INTEGER NOT NULL,
    event       TEXT    NOT NULL,
    acked_units INTEGER NOT NULL,
    detail      TEXT
);
CREATE INDEX IF NOT EXISTS journal_job ON journal(job_id);
";

/// Now, in Unix milliseconds.
pub fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}

impl Store {
    /// Opens (creating if needed) the store at `path`, in WAL mode.
    pub fn open(path: &Path) -> Result<Store, StoreError> {
        let open_err = |source| StoreError::Open {
            path: path.display().to_string(),
            source,
        };
        let conn = Connection::open(path).map_err(open_err)?;
        conn.pragma_update(None, "journal_mode", "WAL")
            .map_err(open_err)?;
        // WAL + NORMAL: a commit survives the daemon's crash; only a power cut can lose the
        // last commits, which the journal's batching already allows for.
        conn.pragma_update(None, "synchronous", "NORMAL")
            .map_err(open_err)?;
        conn.pragma_update(None, "foreign_keys", "ON")
            .map_err(open_err)?;
        conn.busy_timeout(Duration::from_secs(5))
            .map_err(open_err)?;
        conn.execute_batch(SCHEMA).map_err(open_err)?;
        Ok(Store {
            conn: Arc::new(Mutex::new(conn)),
            flushes: Arc::default(),
        })
    }

    fn conn(&self) -> std::sync::MutexGuard<'_, Connection> {
        // a panic while holding the lock cannot leave SQLite half-written (transactions
        // roll back), so a poisoned lock is still usable
        self.conn.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Inserts a queued job and its program in one transaction; returns its id.
    pub fn insert_job(&self, job: &NewJob) -> Result<JobId, StoreError> {
        let units = job
            .program
            .to_json()
            .map_err(|e| StoreError::Corrupt(format!("cannot encode the program: {e}")))?;
        self.insert_job_units(&NewJobUnits {
            machine: job.machine.clone(),
            op: job.op.clone(),
            file_name: job.file_name.clone(),
            params: job.params.clone(),
            post: job.program.post().to_string(),
            units_json: units,
            total_units: job.program.len(),
        })
    }

    /// Inserts a queued job whose program comes as the store keeps it (a G-code file whose
    /// units were written as it streamed in), in one transaction; returns its id.
    pub fn insert_job_units(&self, job: &NewJobUnits) -> Result<JobId, StoreError> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        tx.execute(
            "INSERT INTO jobs (machine, state, op, file_name, params, created_ms, total_units)
             VALUES (?1, 'queued', ?2, ?3, ?4, ?5, ?6)",
            params![
                job.machine,
                job.op,
                job.file_name,
                job.params.to_string(),
                now_ms(),
                job.total_units as i64
            ],
        )?;
        let id = tx.last_insert_rowid();
        // the units are written into a blob of their size, page by page: no copy of a large
        // program is made on the way into the store
        tx.execute(
            "INSERT INTO programs (job_id, kind, units) VALUES (?1, ?2, zeroblob(?3))",
            params![id, job.post, job.units_json.len() as i64],
        )?;
        {
            use std::io::Write;
            let mut blob = tx.blob_open(rusqlite::MAIN_DB, "programs", "units", id, false)?;
            blob.write_all(job.units_json.as_bytes()).map_err(|e| {
                StoreError::Corrupt(format!("cannot write job {id}'s program: {e}"))
            })?;
        }
        tx.execute(
            "INSERT INTO journal (job_id, at_ms, event, acked_units) VALUES (?1, ?2, 'queued', 0)",
            params![id, now_ms()],
        )?;
        tx.commit()?;
        Ok(id)
    }

    pub fn job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        self.conn()
            .query_row(
                &format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1"),
                [id],
                row_to_job,
            )
            .optional()?
            .transpose()
    }

    /// Every job, oldest first.
    pub fn jobs(&self) -> Result<Vec<JobRecord>, StoreError> {
        let conn = self.conn();
        let mut st = conn.prepare(&format!("SELECT {JOB_COLUMNS} FROM jobs ORDER BY id"))?;
        let rows = st.query_map([], row_to_job)?;
        let mut out = Vec::new();
        for r in rows {
            out.push(r??);
        }
        Ok(out)
    }

    /// Jobs in `state`, oldest first.
    pub fn jobs_in(&self, state: JobState) -> Result<Vec<JobRecord>, StoreError> {
        Ok(self
            .jobs()?
            .into_iter()
            .filter(|j| j.state == state)
            .collect())
    }

    /// A job's program as stored: the post that made it and its units as JSON, for the
    /// machine's kind to read back (`AnyKind::decode`).
    pub fn program(&self, id: JobId) -> Result<StoredProgram, StoreError> {
        let (post, units): (String, String) = self
            .conn()
            .query_row(
                "SELECT kind, units FROM programs WHERE job_id = ?1",
                [id],
                |r| Ok((r.get(0)?, text_or_blob(r.get_ref(1)?)?)),
            )
            .optional()?
            .ok_or_else(|| StoreError::Corrupt(format!("job {id} has no program")))?;
        Ok(StoredProgram { post, units })
    }

    /// Moves a job to `state`, journaling the change; `error` is kept for failed jobs.
    pub fn set_state(
        &self,
        id: JobId,
        state: JobState,
        error: Option<&str>,
    ) -> Result<(), StoreError> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let now = now_ms();
        match state {
            JobState::Running => tx.execute(
                "UPDATE jobs SET state = ?2, error = NULL, finished_ms = NULL,
                 started_ms = COALESCE(started_ms, ?3) WHERE id = ?1",
                params![id, state.as_str(), now],
            )?,
            JobState::Queued | JobState::Paused => tx.execute(
                "UPDATE jobs SET state = ?2 WHERE id = ?1",
                params![id, state.as_str()],
            )?,
            _ => tx.execute(
                "UPDATE jobs SET state = ?2, error = ?3, finished_ms = ?4 WHERE id = ?1",
                params![id, state.as_str(), error, now],
            )?,
        };
        tx.execute(
            "INSERT INTO journal (job_id, at_ms, event, acked_units, detail)
             SELECT id, ?2, ?3, acked_units, ?4 FROM jobs WHERE id = ?1",
            params![id, now, state.as_str(), error],
        )?;
        tx.commit()?;
        Ok(())
    }

    /// Records that units up to `acked_units` (exclusive) are acknowledged: one journal row
    /// for the batch and the job's resume point, in one transaction.
    pub fn record_acks(
        &self,
        id: JobId,
        from_units: usize,
        acked_units: usize,
    ) -> Result<(), StoreError> {
        self.move_resume_point(
            id,
            acked_units,
            "acked",
            &format!("units {from_units}..{acked_units}"),
        )?;
        self.flushes
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        Ok(())
    }

    /// Moves a stopped job's resume point to unit `acked_units` (the operator's choice).
    pub fn set_resume_point(&self, id: JobId, acked_units: usize) -> Result<(), StoreError> {
        self.move_resume_point(
            id,
            acked_units,
            "rewind",
            "resume point set by the operator",
        )
    }

    /// Sets a job's resume point and journals why, in one transaction.
    fn move_resume_point(
        &self,
        id: JobId,
        acked_units: usize,
        event: &str,
        detail: &str,
    ) -> Result<(), StoreError> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        tx.execute(
            "UPDATE jobs SET acked_units = ?2 WHERE id = ?1",
            params![id, acked_units as i64],
        )?;
        tx.execute(
            "INSERT INTO journal (job_id, at_ms, event, acked_units, detail)
             VALUES (?1, ?2, ?3, ?4, ?5)",
            params![id, now_ms(), event, acked_units as i64, detail],
        )?;
        tx.commit()?;
        Ok(())
    }

    /// Gives the connection's page cache back to the allocator (after a large program went
    /// in or out, so the daemon's memory returns to its baseline).
    pub fn release_memory(&self) {
        if let Err(e) = self.conn().execute_batch("PRAGMA shrink_memory") {
            tracing::warn!("the job store could not release its cache: {e}");
        }
    }

    /// How many journal flushes this store has made (for tests and stats).
    pub fn flush_count(&self) -> u64 {
        self.flushes.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// At start: every job left running or paused by a crash becomes interrupted, keeping
    /// its resume point. Returns the jobs it marked.
    pub fn mark_interrupted(&self) -> Result<Vec<JobRecord>, StoreError> {
        let stale: Vec<JobRecord> = self
            .jobs()?
            .into_iter()
            .filter(|j| matches!(j.state, JobState::Running | JobState::Paused))
            .collect();
        for j in &stale {
            self.set_state(
                j.id,
                JobState::Interrupted,
                Some(&format!(
                    "the daemon stopped while the job ran; {} of {} units were acknowledged",
                    j.acked_units, j.total_units
                )),
            )?;
        }
        stale
            .iter()
            .map(|j| {
                self.job(j.id)?
                    .ok_or_else(|| StoreError::Corrupt(format!("job {} vanished", j.id)))
            })
            .collect()
    }
}

/// A program's units as text, stored as text (older stores) or as a blob written in place.
fn text_or_blob(v: rusqlite::types::ValueRef<'_>) -> rusqlite::Result<String> {
    use rusqlite::types::{FromSqlError, ValueRef};
    match v {
        ValueRef::Text(b) | ValueRef::Blob(b) => String::from_utf8(b.to_vec())
            .map_err(|e| rusqlite::Error::FromSqlConversionFailure(1, v.data_type(), Box::new(e))),
        other => Err(rusqlite::Error::FromSqlConversionFailure(
            1,
            other.data_type(),
            Box::new(FromSqlError::InvalidType),
        )),
    }
}

const JOB_COLUMNS: &str = "id, machine, state, op, file_name, params, created_ms, started_ms,
    finished_ms, error, total_units, acked_units";

fn row_to_job(r: &rusqlite::Row) -> rusqlite::Result<Result<JobRecord, StoreError>> {
    let id: i64 = r.get(0)?;
    let state: String = r.get(2)?;
    let params: String = r.get(5)?;
    let Some(state) = JobState::parse(&state) else {
        return Ok(Err(StoreError::Corrupt(format!(
            "job {id} has an unknown state `{state}`"
        ))));
    };
    let params = match serde_json::from_str(&params) {
        Ok(p) => p,
        Err(e) => {
            return Ok(Err(StoreError::Corrupt(format!(
                "job {id}'s parameters: {e}"
            ))))
        }
    };
    Ok(Ok(JobRecord {
        id,
        machine: r.get(1)?,
        state,
        op: r.get(3)?,
        file_name: r.get(4)?,
        params,
        created_ms: r.get(6)?,
        started_ms: r.get(7)?,
        finished_ms: r.get(8)?,
        error: r.get(9)?,
        total_units: r.get::<_, i64>(10)? as usize,
        acked_units: r.get::<_, i64>(11)? as usize,
    }))
}

/// The batching of acknowledged units for one running job: a flush is due after `every`
/// new acks, or when the oldest unflushed ack is `max_lag` old. Pure bookkeeping over a
/// clock the caller passes in, so the policy is tested without sleeping.
#[derive(Debug)]
pub struct Journal {
    every: usize,
    max_lag: Duration,
    /// Units acknowledged so far (the resume point once flushed).
    acked: usize,
    /// Units the store has.
    flushed: usize,
    /// When the oldest unflushed ack came in.
    oldest_pending: Option<Instant>,
}

impl Journal {
    pub fn new(start: usize, every: usize, max_lag: Duration) -> Journal {
        Journal {
            every: every.max(1),
            max_lag,
            acked: start,
            flushed: start,
            oldest_pending: None,
        }
    }

    /// Notes that units up to and including `unit` are acknowledged; true when a flush is due.
    pub fn ack(&mut self, unit: usize, now: Instant) -> bool {
        if unit + 1 > self.acked {
            self.acked = unit + 1;
            self.oldest_pending.get_or_insert(now);
        }
        self.acked - self.flushed >= self.every || self.is_due(now)
    }

    /// True when unflushed acks have waited `max_lag`.
    pub fn is_due(&self, now: Instant) -> bool {
        self.oldest_pending
            .is_some_and(|t| now.duration_since(t) >= self.max_lag)
    }

    /// When the next time-based flush is due, if any ack waits.
    pub fn deadline(&self) -> Option<Instant> {
        self.oldest_pending.map(|t| t + self.max_lag)
    }

    pub fn acked(&self) -> usize {
        self.acked
    }

    pub fn has_pending(&self) -> bool {
        self.acked > self.flushed
    }

    /// Takes the batch to write: (first unit, end unit exclusive); None when nothing waits.
    pub fn take(&mut self) -> Option<(usize, usize)> {
        if !self.has_pending() {
            return None;
        }
        let batch = (self.flushed, self.acked);
        self.flushed = self.acked;
        self.oldest_pending = None;
        Some(batch)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job(n: usize) -> NewJob {
        NewJob {
            machine: "mill".into(),
            op: "profile".into(),
            file_name: "plate.json".into(),
            params: serde_json::json!({"op": "profile"}),
            program: Program::new(
                "grbl",
                (0..n).map(|i| format!("G1 X{i}")).collect::<Vec<String>>(),
            ),
        }
    }

    #[test]
    fn jobs_and_programs_round_trip_and_survive_reopening() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("jobs.db");
        let id = {
            let s = Store::open(&path).unwrap();
            let id = s.insert_job(&job(5)).unwrap();
            s.set_state(id, JobState::Running, None).unwrap();
            s.record_acks(id, 0, 3).unwrap();
            id
        };
        let s = Store::open(&path).unwrap();
        let j = s.job(id).unwrap().unwrap();
        assert_eq!(j.state, JobState::Running);
        assert_eq!((j.total_units, j.acked_units), (5, 3));
        assert!(j.started_ms.is_some());
        let kind = machlink_protocols::grbl::kind::GrblKind;
        assert_eq!(
            s.program(id).unwrap().decode(&kind).unwrap(),
            job(5).program
        );
        let marked = s.mark_interrupted().unwrap();
        assert_eq!(marked.len(), 1);
        assert_eq!(marked[0].state, JobState::Interrupted);
        assert_eq!(marked[0].acked_units, 3);
        assert!(marked[0].error.as_deref().unwrap().contains("3 of 5"));
        let mode: String = s
            .conn()
            .query_row("PRAGMA journal_mode", [], |r| r.get(0))
            .unwrap();
        assert_eq!(mode, "wal");
    }

    #[test]
    fn the_journal_flushes_every_n_acks() {
        let t0 = Instant::now();
        let mut j = Journal::new(0, 10, Duration::from_secs(1));
        let mut batches = Vec::new();
        for unit in 0..35 {
            if j.ack(unit, t0) {
                batches.push(j.take().unwrap());
            }
        }
        assert_eq!(batches, vec![(0, 10), (10, 20), (20, 30)]);
        assert_eq!(j.take(), Some((30, 35)));
        assert_eq!(j.take(), None);
    }

    #[test]
    fn the_journal_is_never_more_than_the_lag_behind() {
        // one ack every 70 ms, batches of 1000: only the clock can make it flush, and it
        // must do so before any ack has waited a full second
        let t0 = Instant::now();
        let lag = Duration::from_secs(1);
        let mut j = Journal::new(0, 1000, lag);
        let mut oldest_unflushed: Option<Instant> = None;
        let mut flushes = 0;
        for unit in 0..200 {
            let now = t0 + Duration::from_millis(70 * unit as u64);
            // the caller's timer fires at the deadline, before this ack arrives
            if let Some(d) = j.deadline() {
                if d <= now {
                    assert!(j.is_due(d));
                    j.take().unwrap();
                    flushes += 1;
                    assert!(d.duration_since(oldest_unflushed.unwrap()) <= lag);
                    oldest_unflushed = None;
                }
            }
            if j.ack(unit, now) {
                j.take().unwrap();
                flushes += 1;
                oldest_unflushed = None;
            } else {
                oldest_unflushed.get_or_insert(now);
            }
        }
        // 200 acks over 14 s: about one flush a second
        assert!((13..=15).contains(&flushes), "{flushes}");
    }
}
