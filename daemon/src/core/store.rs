//! The job store: jobs, their programs and the journal of acknowledged units, in SQLite (WAL).
//!
//! A job's row and its program are committed before the first byte goes to the machine;
//! every unit the machine acknowledges is journaled (`Journal`, one unit at a time by
//! default), and links whose devices cannot be asked afterwards (GRBL) journal each write
//! before its bytes leave (`sending_units`) and after (`sent_units`), so after a crash the
//! store says exactly which units the device may hold. Those per-write records go to a
//! small progress file beside the database (one fixed-size slot per machine, written with
//! one `pwrite`: it reaches the page cache at once and survives a crash of the process,
//! like a `synchronous = NORMAL` commit, at a twentieth of its cost); they are copied into
//! SQLite when the stream ends, and at the next start after a crash. Commits do not wait
//! for the disk; a thread of its own checkpoints the write-ahead log, so no fsync stalls a
//! stream.

use machlink_protocols::{Program, UnitPages};
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
    /// Units handed to the machine (for links that journal their writes, else 0).
    #[serde(default)]
    pub sent_units: usize,
    /// Why a paused or interrupted job waits, and what the daemon found on the machine.
    #[serde(default)]
    pub note: Option<String>,
    /// How long the program takes on the machine, as its kind estimates it, ms.
    #[serde(default)]
    pub estimate_ms: Option<i64>,
    /// Time since the job started (to its end, once it ended), ms.
    #[serde(default)]
    pub elapsed_ms: Option<i64>,
    /// The machining time left, from the estimate and the units still to run, ms.
    #[serde(default)]
    pub eta_ms: Option<i64>,
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

/// A new job whose program is already in the store's pages (a G-code file written page by
/// page as it streamed in, [`Store::page_writer`]).
#[derive(Debug)]
pub struct NewJobUnits {
    pub machine: String,
    pub op: String,
    pub file_name: String,
    pub params: serde_json::Value,
    /// The post that made the units.
    pub post: String,
    pub pages: PageSet,
}

/// Units a program is stored in a page of: a page of G-code lines is some 20 KB of JSON,
/// and a link holds two pages at a time.
pub const PAGE_UNITS: usize = 1024;

/// A program as the store holds it.
#[derive(Clone, Debug)]
pub struct StoredProgram {
    /// The post that made it (`grbl`, `dst`, …, or `gcode-file`).
    pub post: String,
    pub units: StoredUnits,
}

/// Where a stored program's units are.
#[derive(Clone, Debug)]
pub enum StoredUnits {
    /// All of them, one JSON array (a store written before programs were paged).
    Whole(String),
    /// In pages of [`PAGE_UNITS`], each read when a link comes to it.
    Pages(Arc<StorePages>),
}

impl StoredProgram {
    /// The program, read back by the kind of machine it was made for: a paged program stays
    /// in the store, and is read a page at a time.
    pub fn decode(&self, kind: &dyn machlink_protocols::AnyKind) -> Result<Program, StoreError> {
        match &self.units {
            StoredUnits::Whole(json) => kind
                .decode(&self.post, json)
                .map_err(|e| StoreError::Corrupt(format!("a stored {} program: {e}", self.post))),
            StoredUnits::Pages(p) => Ok(kind.decode_pages(&self.post, p.clone())),
        }
    }
}

/// A program's pages in the store, read one at a time.
#[derive(Clone)]
pub struct StorePages {
    store: Store,
    set: i64,
    units: usize,
}

impl std::fmt::Debug for StorePages {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "page set {} ({} units)", self.set, self.units)
    }
}

impl UnitPages for StorePages {
    fn len(&self) -> usize {
        self.units
    }
    fn page_len(&self) -> usize {
        PAGE_UNITS
    }
    fn page(&self, k: usize) -> Result<Vec<u8>, String> {
        self.store
            .conn()
            .query_row(
                "SELECT units FROM program_pages WHERE page_set = ?1 AND page = ?2",
                params![self.set, k as i64],
                |r| text_or_blob(r.get_ref(0)?),
            )
            .optional()
            .map_err(|e| format!("the job store failed: {e}"))?
            .map(String::into_bytes)
            .ok_or_else(|| format!("page {k} of the stored program is missing"))
    }
}

/// A program's units as they are written to the store, a page at a time; what is written
/// so far is deleted if it is dropped unfinished (a refused upload).
pub struct PageWriter {
    store: Store,
    set: i64,
    /// The page being filled, a JSON array still open.
    page: Vec<u8>,
    in_page: usize,
    pages: usize,
    units: usize,
    finished: bool,
}

/// A finished set of pages: a program's units in the store, not yet any job's.
#[derive(Debug)]
pub struct PageSet {
    set: i64,
    units: usize,
}

impl PageSet {
    /// Units in the set.
    pub fn units(&self) -> usize {
        self.units
    }
}

impl PageWriter {
    /// Appends one unit, given as its JSON.
    pub fn push_json(&mut self, unit: &[u8]) -> Result<(), StoreError> {
        self.page.push(if self.in_page == 0 { b'[' } else { b',' });
        self.page.extend_from_slice(unit);
        self.in_page += 1;
        self.units += 1;
        if self.in_page == PAGE_UNITS {
            self.flush()?;
        }
        Ok(())
    }

    /// Appends a whole page: `json` is the array of its `units` units (a page of
    /// [`PAGE_UNITS`], or fewer for the last), as [`Program::page_json`] writes them.
    fn push_page(&mut self, json: &str, units: usize) -> Result<(), StoreError> {
        self.flush()?;
        self.insert(json.as_bytes())?;
        self.units += units;
        Ok(())
    }

    /// Units written so far.
    pub fn units(&self) -> usize {
        self.units
    }

    fn insert(&mut self, page: &[u8]) -> Result<(), StoreError> {
        self.store.conn().execute(
            "INSERT INTO program_pages (page_set, page, units) VALUES (?1, ?2, ?3)",
            params![self.set, self.pages as i64, page],
        )?;
        self.pages += 1;
        Ok(())
    }

    /// Writes the page being filled.
    fn flush(&mut self) -> Result<(), StoreError> {
        if self.in_page == 0 {
            return Ok(());
        }
        let mut page = std::mem::take(&mut self.page);
        page.push(b']');
        self.insert(&page)?;
        page.clear();
        self.page = page;
        self.in_page = 0;
        Ok(())
    }

    /// The pages, for [`NewJobUnits`].
    pub fn finish(mut self) -> Result<PageSet, StoreError> {
        self.flush()?;
        self.finished = true;
        Ok(PageSet {
            set: self.set,
            units: self.units,
        })
    }
}

impl Drop for PageWriter {
    fn drop(&mut self) {
        if !self.finished {
            let conn = self.store.conn();
            let _ = conn.execute("DELETE FROM program_pages WHERE page_set = ?1", [self.set]);
            let _ = conn.execute("DELETE FROM page_sets WHERE id = ?1", [self.set]);
        }
    }
}

/// The store: one SQLite connection shared by the daemon's tasks. Every call is short.
#[derive(Clone)]
pub struct Store {
    conn: Arc<Mutex<Connection>>,
    /// Journal flushes so far (tests count them).
    flushes: Arc<std::sync::atomic::AtomicU64>,
    /// Journal writes so far (acknowledgements committed, writes recorded in the progress
    /// file), for the benchmark.
    commits: Arc<std::sync::atomic::AtomicU64>,
    progress: Arc<ProgressFile>,
    _checkpoints: Arc<Checkpointer>,
}

/// The progress file: one slot of [`SLOT_BYTES`] per machine, each the job id and its
/// acknowledged, sent and sending units (little-endian 64-bit), written whole with one
/// `pwrite`; a slot of job 0 is empty.
struct ProgressFile {
    file: std::fs::File,
}

const SLOT_BYTES: usize = 32;
/// Slots in the file (machines per daemon).
pub const PROGRESS_SLOTS: usize = 1024;

/// One slot's record.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Slot {
    job: JobId,
    acked: u64,
    sent: u64,
    sending: u64,
}

impl ProgressFile {
    fn open(db: &Path) -> std::io::Result<ProgressFile> {
        let mut name = db.as_os_str().to_owned();
        name.push("-progress");
        use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .mode(0o600)
            .open(std::path::PathBuf::from(name))?;
        // the progress file takes the store's own mode (0600, or 0660 for a socket group),
        // whatever the umask, and an older, wider one is narrowed to it
        let store_mode = std::fs::metadata(db)?.permissions().mode() & 0o660;
        if file.metadata()?.permissions().mode() & 0o777 != store_mode {
            file.set_permissions(std::fs::Permissions::from_mode(store_mode))?;
        }
        Ok(ProgressFile { file })
    }

    fn write(&self, slot: usize, s: Slot) -> std::io::Result<()> {
        use std::os::unix::fs::FileExt;
        let mut b = [0u8; SLOT_BYTES];
        b[0..8].copy_from_slice(&s.job.to_le_bytes());
        b[8..16].copy_from_slice(&s.acked.to_le_bytes());
        b[16..24].copy_from_slice(&s.sent.to_le_bytes());
        b[24..32].copy_from_slice(&s.sending.to_le_bytes());
        self.file.write_all_at(&b, (slot * SLOT_BYTES) as u64)
    }

    /// Every slot that holds a job, with its number.
    fn read(&self) -> Vec<(usize, Slot)> {
        use std::io::Read;
        let mut all = Vec::new();
        let mut f = &self.file;
        use std::io::Seek;
        if f.seek(std::io::SeekFrom::Start(0)).is_err() || f.read_to_end(&mut all).is_err() {
            return Vec::new();
        }
        let u = |c: &[u8]| u64::from_le_bytes(c.try_into().unwrap_or([0; 8]));
        all.chunks_exact(SLOT_BYTES)
            .enumerate()
            .map(|(k, c)| {
                (
                    k,
                    Slot {
                        job: u(&c[0..8]) as i64,
                        acked: u(&c[8..16]),
                        sent: u(&c[16..24]),
                        sending: u(&c[24..32]),
                    },
                )
            })
            .filter(|(_, s)| s.job > 0)
            .collect()
    }
}

/// The journal of one stream's writes, in its machine's slot of the progress file (see the
/// module's paragraph); cheap to clone, every clone writes the same slot.
#[derive(Clone)]
pub struct SendRecord {
    store: Store,
    slot: usize,
    state: Arc<Mutex<Slot>>,
}

impl SendRecord {
    /// Units `..upto` are about to be handed to the device, `acked` acknowledged so far.
    pub fn sending(&self, acked: usize, upto: usize) -> Result<(), StoreError> {
        let mut s = lock(&self.state);
        s.acked = s.acked.max(acked as u64);
        s.sending = upto as u64;
        self.store
            .progress
            .write(self.slot, *s)
            .map_err(progress_err)?;
        self.store.count_commit();
        Ok(())
    }

    /// The device holds units `..upto`.
    pub fn sent(&self, upto: usize) -> Result<(), StoreError> {
        let mut s = lock(&self.state);
        s.sent = upto as u64;
        s.sending = upto as u64;
        self.store
            .progress
            .write(self.slot, *s)
            .map_err(progress_err)?;
        self.store.count_commit();
        Ok(())
    }

    /// Copies the record into the job's row and empties the slot (when the stream ends).
    pub fn persist(&self) -> Result<(), StoreError> {
        let s = *lock(&self.state);
        self.store.absorb(s)?;
        self.store
            .progress
            .write(self.slot, Slot::default())
            .map_err(progress_err)
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

fn progress_err(e: std::io::Error) -> StoreError {
    StoreError::Corrupt(format!("the progress file cannot be written: {e}"))
}

/// The thread that checkpoints the write-ahead log into the database file (the only writes
/// that wait for the disk), so commits on the streaming path never do; it stops with the
/// last clone of the store.
struct Checkpointer {
    stop: Arc<(Mutex<bool>, std::sync::Condvar)>,
}

impl Checkpointer {
    fn start(path: &Path) -> Checkpointer {
        let stop = Arc::new((Mutex::new(false), std::sync::Condvar::new()));
        let s = stop.clone();
        let path = path.to_path_buf();
        let _ = std::thread::Builder::new()
            .name("store-checkpoint".into())
            .spawn(move || {
                let Ok(conn) = Connection::open(&path) else {
                    return;
                };
                let _ = conn.busy_timeout(Duration::from_millis(100));
                let (lock, cv) = &*s;
                let mut stopped = lock.lock().unwrap_or_else(|p| p.into_inner());
                while !*stopped {
                    let (g, _) = cv
                        .wait_timeout(stopped, Duration::from_millis(500))
                        .unwrap_or_else(|p| p.into_inner());
                    stopped = g;
                    if *stopped {
                        break;
                    }
                    drop(stopped);
                    let _ = conn.query_row("PRAGMA wal_checkpoint(PASSIVE)", [], |_| Ok(()));
                    stopped = lock.lock().unwrap_or_else(|p| p.into_inner());
                }
            });
        Checkpointer { stop }
    }
}

impl Drop for Checkpointer {
    fn drop(&mut self) {
        let (lock, cv) = &*self.stop;
        *lock.lock().unwrap_or_else(|p| p.into_inner()) = true;
        cv.notify_all();
    }
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
    acked_units INTEGER NOT NULL DEFAULT 0,
    sent_units  INTEGER NOT NULL DEFAULT 0,
    sending_units INTEGER NOT NULL DEFAULT 0,
    estimate_ms INTEGER,
    note        TEXT,
    restart_at  INTEGER
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
CREATE TABLE IF NOT EXISTS page_sets (
    id         INTEGER PRIMARY KEY AUTOINCREMENT,
    created_ms INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS program_pages (
    page_set INTEGER NOT NULL REFERENCES page_sets(id),
    page     INTEGER NOT NULL,
    units    BLOB    NOT NULL, -- a JSON array of up to PAGE_UNITS units
    PRIMARY KEY (page_set, page)
);
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
        // the checkpoint thread does what the commits would otherwise stop for
        conn.pragma_update(None, "wal_autocheckpoint", 0)
            .map_err(open_err)?;
        conn.execute_batch(SCHEMA).map_err(open_err)?;
        migrate(&conn).map_err(open_err)?;
        let progress = ProgressFile::open(path).map_err(|e| StoreError::Open {
            path: path.display().to_string(),
            source: rusqlite::Error::ToSqlConversionFailure(Box::new(e)),
        })?;
        Ok(Store {
            conn: Arc::new(Mutex::new(conn)),
            flushes: Arc::default(),
            commits: Arc::default(),
            progress: Arc::new(progress),
            _checkpoints: Arc::new(Checkpointer::start(path)),
        })
    }

    /// The journal of a stream of job `id` from unit `from` on machine slot `slot` (the
    /// machine's place in the daemon's list).
    pub fn send_record(
        &self,
        slot: usize,
        id: JobId,
        from: usize,
    ) -> Result<SendRecord, StoreError> {
        if slot >= PROGRESS_SLOTS {
            return Err(StoreError::Corrupt(format!(
                "machine slot {slot} is beyond the progress file's {PROGRESS_SLOTS}"
            )));
        }
        let s = Slot {
            job: id,
            acked: from as u64,
            sent: from as u64,
            sending: from as u64,
        };
        self.progress.write(slot, s).map_err(progress_err)?;
        Ok(SendRecord {
            store: self.clone(),
            slot,
            state: Arc::new(Mutex::new(s)),
        })
    }

    /// Copies a slot's record into its job's row.
    fn absorb(&self, s: Slot) -> Result<(), StoreError> {
        self.conn().execute(
            "UPDATE jobs SET acked_units = MAX(acked_units, ?2), sent_units = ?3, sending_units = ?4
             WHERE id = ?1",
            params![s.job, s.acked as i64, s.sent as i64, s.sending as i64],
        )?;
        Ok(())
    }

    /// Empties the slots that hold job `id` (its journal starts afresh).
    fn forget_progress(&self, id: JobId) -> Result<(), StoreError> {
        for (k, s) in self.progress.read() {
            if s.job == id {
                self.progress
                    .write(k, Slot::default())
                    .map_err(progress_err)?;
            }
        }
        Ok(())
    }

    /// A job's row with what the progress file knows beyond it.
    fn overlay(&self, jobs: &mut [JobRecord]) {
        let slots = self.progress.read();
        if slots.is_empty() {
            return;
        }
        for j in jobs.iter_mut() {
            if let Some((_, s)) = slots.iter().find(|(_, s)| s.job == j.id) {
                j.acked_units = j.acked_units.max(s.acked as usize);
                j.sent_units = s.sent as usize;
                j.eta_ms = eta_ms(j.estimate_ms, j.acked_units, j.total_units, j.state);
            }
        }
    }

    fn conn(&self) -> std::sync::MutexGuard<'_, Connection> {
        // a panic while holding the lock cannot leave SQLite half-written (transactions
        // roll back), so a poisoned lock is still usable
        self.conn.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Inserts a queued job and its program (written in pages first); returns its id.
    pub fn insert_job(&self, job: &NewJob) -> Result<JobId, StoreError> {
        let mut w = self.page_writer()?;
        let n = job.program.len();
        for at in (0..n).step_by(PAGE_UNITS) {
            let end = (at + PAGE_UNITS).min(n);
            let json = job
                .program
                .page_json(at..end)
                .map_err(|e| StoreError::Corrupt(format!("cannot encode the program: {e}")))?;
            w.push_page(&json, end - at)?;
        }
        self.insert_job_units(&NewJobUnits {
            machine: job.machine.clone(),
            op: job.op.clone(),
            file_name: job.file_name.clone(),
            params: job.params.clone(),
            post: job.program.post().to_string(),
            pages: w.finish()?,
        })
    }

    /// A writer of a new program's pages, for [`Store::insert_job_units`].
    pub fn page_writer(&self) -> Result<PageWriter, StoreError> {
        let conn = self.conn();
        conn.execute("INSERT INTO page_sets (created_ms) VALUES (?1)", [now_ms()])?;
        let set = conn.last_insert_rowid();
        Ok(PageWriter {
            store: self.clone(),
            set,
            page: Vec::new(),
            in_page: 0,
            pages: 0,
            units: 0,
            finished: false,
        })
    }

    /// Inserts a queued job whose program is in the store's pages already (a G-code file
    /// whose units were written as it streamed in), in one transaction; returns its id.
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
                job.pages.units as i64
            ],
        )?;
        let id = tx.last_insert_rowid();
        // the units stay in their pages: the program's row names them
        tx.execute(
            "INSERT INTO programs (job_id, kind, units, page_set, page_units) VALUES (?1, ?2, '', ?3, ?4)",
            params![id, job.post, job.pages.set, job.pages.units as i64],
        )?;
        tx.execute(
            "INSERT INTO journal (job_id, at_ms, event, acked_units) VALUES (?1, ?2, 'queued', 0)",
            params![id, now_ms()],
        )?;
        tx.commit()?;
        Ok(id)
    }

    pub fn job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        let j = self
            .conn()
            .query_row(
                &format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1"),
                [id],
                row_to_job,
            )
            .optional()?
            .transpose()?;
        Ok(j.map(|j| {
            let mut one = [j];
            self.overlay(&mut one);
            let [j] = one;
            j
        }))
    }

    /// Every job, oldest first.
    pub fn jobs(&self) -> Result<Vec<JobRecord>, StoreError> {
        let mut out = Vec::new();
        {
            let conn = self.conn();
            let mut st = conn.prepare(&format!("SELECT {JOB_COLUMNS} FROM jobs ORDER BY id"))?;
            let rows = st.query_map([], row_to_job)?;
            for r in rows {
                out.push(r??);
            }
        }
        self.overlay(&mut out);
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
        let (post, set, count): (String, Option<i64>, i64) = self
            .conn()
            .query_row(
                "SELECT kind, page_set, page_units FROM programs WHERE job_id = ?1",
                [id],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
            )
            .optional()?
            .ok_or_else(|| StoreError::Corrupt(format!("job {id} has no program")))?;
        let units = match set {
            Some(set) => StoredUnits::Pages(Arc::new(StorePages {
                store: self.clone(),
                set,
                units: count.max(0) as usize,
            })),
            None => StoredUnits::Whole(self.conn().query_row(
                "SELECT units FROM programs WHERE job_id = ?1",
                [id],
                |r| text_or_blob(r.get_ref(0)?),
            )?),
        };
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

    /// Records that units up to `acked_units` (exclusive) are acknowledged: the job's resume
    /// point, and a journal row when the count passes a hundred (the history; every
    /// acknowledgement would make the table grow by one row a line).
    pub fn record_acks(
        &self,
        id: JobId,
        from_units: usize,
        acked_units: usize,
    ) -> Result<(), StoreError> {
        if from_units / 100 != acked_units / 100 {
            self.move_resume_point(
                id,
                acked_units,
                "acked",
                &format!("units {from_units}..{acked_units}"),
            )?;
        } else {
            self.conn()
                .prepare_cached("UPDATE jobs SET acked_units = ?2 WHERE id = ?1")?
                .execute(params![id, acked_units as i64])?;
        }
        self.flushes
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.count_commit();
        Ok(())
    }

    fn count_commit(&self) {
        self.commits
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }

    /// How many journal writes (acknowledgements committed, writes recorded in the progress
    /// file) the store made.
    pub fn commit_count(&self) -> u64 {
        self.commits.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// How far the job's program went towards the device, as the journal knows it.
    pub fn handed(&self, id: JobId) -> Result<machlink_protocols::Handed, StoreError> {
        let (acked, sent, sending): (i64, i64, i64) = self.conn().query_row(
            "SELECT acked_units, sent_units, sending_units FROM jobs WHERE id = ?1",
            [id],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
        )?;
        let mut h = machlink_protocols::Handed {
            acked: acked as usize,
            sent: sent as usize,
            sending: sending as usize,
            cut_off: false,
            go_on: false,
        };
        if let Some((_, s)) = self.progress.read().into_iter().find(|(_, s)| s.job == id) {
            h.acked = h.acked.max(s.acked as usize);
            h.sent = s.sent as usize;
            h.sending = s.sending as usize;
        }
        Ok(h)
    }

    /// Where a stream starts: `from` units done, nothing beyond handed over yet.
    pub fn start_stream_at(&self, id: JobId, from: usize) -> Result<(), StoreError> {
        self.forget_progress(id)?;
        self.conn().execute(
            "UPDATE jobs SET acked_units = ?2, sent_units = ?2, sending_units = ?2 WHERE id = ?1",
            params![id, from as i64],
        )?;
        Ok(())
    }

    /// Notes why a job waits (or clears the note).
    pub fn set_note(&self, id: JobId, note: Option<&str>) -> Result<(), StoreError> {
        self.conn()
            .execute("UPDATE jobs SET note = ?2 WHERE id = ?1", params![id, note])?;
        Ok(())
    }

    /// The machining time the job's kind estimates, s.
    pub fn set_estimate(&self, id: JobId, seconds: f64) -> Result<(), StoreError> {
        self.conn().execute(
            "UPDATE jobs SET estimate_ms = ?2 WHERE id = ?1",
            params![id, (seconds * 1000.0).round() as i64],
        )?;
        Ok(())
    }

    /// Where the operator asked a stopped job to restart (0-based unit), until it does.
    pub fn set_restart_at(&self, id: JobId, unit: Option<usize>) -> Result<(), StoreError> {
        self.conn().execute(
            "UPDATE jobs SET restart_at = ?2 WHERE id = ?1",
            params![id, unit.map(|u| u as i64)],
        )?;
        Ok(())
    }

    /// The restart point the operator chose, taken (it holds for one start).
    pub fn take_restart_at(&self, id: JobId) -> Result<Option<usize>, StoreError> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let at: Option<i64> =
            tx.query_row("SELECT restart_at FROM jobs WHERE id = ?1", [id], |r| {
                r.get(0)
            })?;
        tx.execute("UPDATE jobs SET restart_at = NULL WHERE id = ?1", [id])?;
        tx.commit()?;
        Ok(at.map(|a| a as usize))
    }

    /// Moves a stopped job's resume point to unit `acked_units` (the operator's choice).
    pub fn set_resume_point(&self, id: JobId, acked_units: usize) -> Result<(), StoreError> {
        self.forget_progress(id)?;
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
        if event == "acked" {
            tx.execute(
                "UPDATE jobs SET acked_units = ?2 WHERE id = ?1",
                params![id, acked_units as i64],
            )?;
        } else {
            tx.execute(
                "UPDATE jobs SET acked_units = ?2, sent_units = ?2, sending_units = ?2 WHERE id = ?1",
                params![id, acked_units as i64],
            )?;
        }
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
        // what the progress file knows of the streams the crash cut short goes into the
        // jobs' rows first
        for (k, s) in self.progress.read() {
            self.absorb(s)?;
            self.progress
                .write(k, Slot::default())
                .map_err(progress_err)?;
        }
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
    finished_ms, error, total_units, acked_units, sent_units, note, estimate_ms";

/// The machining time left of a job whose kind estimated `estimate_ms` for all `total`
/// units, `acked` of them acknowledged: the estimate's share of the units not yet
/// acknowledged. A running job's machine still works off what it acknowledged last (GRBL
/// acknowledges a line when it enters the planner, ahead of the motion), so while it runs
/// the time left is never below one second; None for a job that ended or has no estimate.
pub fn eta_ms(
    estimate_ms: Option<i64>,
    acked: usize,
    total: usize,
    state: JobState,
) -> Option<i64> {
    let e = estimate_ms?;
    if total == 0 {
        return None;
    }
    let left = total.saturating_sub(acked) as f64 / total as f64;
    let t = (e as f64 * left).round() as i64;
    match state {
        JobState::Running => Some(t.max(1000)),
        JobState::Queued | JobState::Paused | JobState::Interrupted => Some(t),
        _ => None,
    }
}

/// Adds the columns a store written by an older daemon lacks, and drops the pages of
/// programs that never became a job (an upload the daemon stopped in).
fn migrate(conn: &Connection) -> rusqlite::Result<()> {
    let mut st = conn.prepare("PRAGMA table_info(programs)")?;
    let have: Vec<String> = st
        .query_map([], |r| r.get::<_, String>(1))?
        .collect::<Result<_, _>>()?;
    for (col, def) in [
        ("page_set", "INTEGER REFERENCES page_sets(id)"),
        ("page_units", "INTEGER NOT NULL DEFAULT 0"),
    ] {
        if !have.iter().any(|h| h == col) {
            conn.execute_batch(&format!("ALTER TABLE programs ADD COLUMN {col} {def}"))?;
        }
    }
    conn.execute_batch(
        "DELETE FROM program_pages WHERE page_set NOT IN
             (SELECT page_set FROM programs WHERE page_set IS NOT NULL);
         DELETE FROM page_sets WHERE id NOT IN
             (SELECT page_set FROM programs WHERE page_set IS NOT NULL);",
    )?;
    let mut st = conn.prepare("PRAGMA table_info(jobs)")?;
    let have: Vec<String> = st
        .query_map([], |r| r.get::<_, String>(1))?
        .collect::<Result<_, _>>()?;
    for (col, def) in [
        ("sent_units", "INTEGER NOT NULL DEFAULT 0"),
        ("sending_units", "INTEGER NOT NULL DEFAULT 0"),
        ("estimate_ms", "INTEGER"),
        ("note", "TEXT"),
        ("restart_at", "INTEGER"),
    ] {
        if !have.iter().any(|h| h == col) {
            conn.execute_batch(&format!("ALTER TABLE jobs ADD COLUMN {col} {def}"))?;
        }
    }
    Ok(())
}

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
    let started_ms: Option<i64> = r.get(7)?;
    let finished_ms: Option<i64> = r.get(8)?;
    let total_units = r.get::<_, i64>(10)? as usize;
    let acked_units = r.get::<_, i64>(11)? as usize;
    let estimate_ms: Option<i64> = r.get(14)?;
    let elapsed_ms = started_ms.map(|s| (finished_ms.unwrap_or_else(now_ms) - s).max(0));
    let eta_ms = eta_ms(estimate_ms, acked_units, total_units, state);
    Ok(Ok(JobRecord {
        id,
        machine: r.get(1)?,
        state,
        op: r.get(3)?,
        file_name: r.get(4)?,
        params,
        created_ms: r.get(6)?,
        started_ms,
        finished_ms,
        error: r.get(9)?,
        total_units,
        acked_units,
        sent_units: r.get::<_, i64>(12)? as usize,
        note: r.get(13)?,
        estimate_ms,
        elapsed_ms,
        eta_ms,
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

/// Queries for the service side: metrics and the fleet.
impl Store {
    /// How many jobs each machine has in each state (for the `machlink_jobs` gauge).
    pub fn count_by_machine_state(
        &self,
    ) -> Result<std::collections::HashMap<(String, &'static str), usize>, StoreError> {
        let conn = self.conn();
        let mut st =
            conn.prepare("SELECT machine, state, COUNT(*) FROM jobs GROUP BY machine, state")?;
        let rows = st.query_map([], |r| {
            Ok((
                r.get::<_, String>(0)?,
                r.get::<_, String>(1)?,
                r.get::<_, i64>(2)?,
            ))
        })?;
        let mut out = std::collections::HashMap::new();
        for r in rows {
            let (machine, state, n) = r?;
            let state = JobState::parse(&state)
                .ok_or_else(|| StoreError::Corrupt(format!("an unknown job state `{state}`")))?;
            out.insert((machine, state.as_str()), n as usize);
        }
        Ok(out)
    }

    /// Indexes jobs by the fleet id in their parameters (once, when the daemon joins a
    /// fleet), so `job_by_fleet_id` is a lookup.
    pub fn index_fleet_ids(&self) -> Result<(), StoreError> {
        self.conn().execute_batch(
            "CREATE INDEX IF NOT EXISTS jobs_fleet_id ON jobs(json_extract(params, '$.fleet_id'))",
        )?;
        Ok(())
    }

    /// The job whose parameters carry `"fleet_id": id` (a job taken from the fleet's queue).
    pub fn job_by_fleet_id(&self, fleet_id: &str) -> Result<Option<JobRecord>, StoreError> {
        let conn = self.conn();
        conn.query_row(
            &format!(
                "SELECT {JOB_COLUMNS} FROM jobs WHERE json_extract(params, '$.fleet_id') = ?1"
            ),
            [fleet_id],
            row_to_job,
        )
        .optional()?
        .transpose()
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
