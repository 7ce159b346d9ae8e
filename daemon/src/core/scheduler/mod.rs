//! The scheduler: one worker per machine runs that machine's queue, first in first out,
//! streaming each job's program through the machine's `Link`, journaling every
//! acknowledged unit, and broadcasting progress, state changes and device status.
//!
//! A job goes queued → running ⇄ paused → completed / failed / cancelled (or interrupted,
//! when the daemon stopped under it). A failed job keeps the device's message and the
//! worker goes on with the next job; nothing a device says stops the daemon. A link that
//! drops pauses its job; a restarted daemon first asks each device what it is doing
//! (`run.rs`). Between jobs the worker keeps the machine's status fresh and carries out
//! the operator's operations (unlock, home, jog).

mod gate;
mod jog;
mod run;

use crate::core::machine::MachineConfig;
use crate::core::resume::{ResumeError, ResumePreview};
use crate::core::store::{JobId, JobRecord, JobState, NewJob, NewJobUnits, Store, StoreError};
use machlink_protocols::kind::{Device, MachineLink};
use machlink_protocols::{Control, DeviceState, LinkError, MachineStatus, Operation, Overrides};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc, oneshot, watch};
use tokio::task::JoinHandle;

/// A machine as the scheduler runs it: its config and what its kind prepared at start-up.
#[derive(Clone)]
pub struct MachineSetup {
    pub config: MachineConfig,
    pub device: Device,
}

/// What watchers hear, as one JSON object per line on `GET /jobs/{id}/events`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Event {
    /// A job changed state (also sent first to every new watcher).
    State {
        job: JobId,
        machine: String,
        state: JobState,
        acked: usize,
        total: usize,
        error: Option<String>,
    },
    /// The machine acknowledged more of the job's units.
    Progress {
        job: JobId,
        acked: usize,
        total: usize,
    },
    /// The machine reported its status while running a job.
    Status {
        machine: String,
        job: Option<JobId>,
        #[serde(flatten)]
        status: MachineStatus,
    },
    /// A message from the machine worth showing the operator.
    Message {
        machine: String,
        job: Option<JobId>,
        text: String,
    },
}

impl Event {
    /// A job's state as the store holds it, as an event.
    pub fn state_of(j: &JobRecord) -> Event {
        Event::State {
            job: j.id,
            machine: j.machine.clone(),
            state: j.state,
            acked: j.acked_units,
            total: j.total_units,
            error: j.error.clone(),
        }
    }

    /// The job the event is about, if any.
    pub fn job(&self) -> Option<JobId> {
        match self {
            Event::State { job, .. } | Event::Progress { job, .. } => Some(*job),
            Event::Status { job, .. } | Event::Message { job, .. } => *job,
        }
    }
}

/// A machine as the API shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MachineInfo {
    pub name: String,
    pub link: String,
    /// The job it is running or holding, if any.
    pub job: Option<JobId>,
    /// Jobs waiting in its queue.
    pub queued: usize,
    /// The device's last report (state unknown before any; offline when its link is down).
    #[serde(flatten)]
    pub status: MachineStatus,
    /// How long ago the device last reported, ms; None before any report.
    #[serde(default)]
    pub age_ms: Option<u64>,
}

/// Why an operator's request was refused.
#[derive(Debug, thiserror::Error)]
pub enum SchedError {
    #[error("there is no job {0}")]
    NoSuchJob(JobId),
    #[error("there is no machine `{name}` (the daemon has: {known})")]
    NoSuchMachine { name: String, known: String },
    #[error("{0}")]
    Conflict(String),
    /// The machine cannot do what was asked, or refused it (its own sentence).
    #[error("{0}")]
    Refused(String),
    #[error(transparent)]
    Store(#[from] StoreError),
}

impl From<ResumeError> for SchedError {
    fn from(e: ResumeError) -> Self {
        match e {
            ResumeError::Conflict(why) => SchedError::Conflict(why),
            ResumeError::Store(e) => SchedError::Store(e),
        }
    }
}

/// Settings of the journal's batching.
#[derive(Clone, Copy, Debug)]
pub struct JournalPolicy {
    pub every: usize,
    pub max_lag: Duration,
}

/// How often the workers ask an idle machine for its status.
const STATUS_POLL: Duration = Duration::from_secs(1);

/// The scheduler; cheap to clone, shared by the API handlers.
#[derive(Clone)]
pub struct Scheduler {
    inner: Arc<Inner>,
}

struct Inner {
    store: Store,
    events: broadcast::Sender<Event>,
    machines: BTreeMap<String, Machine>,
    journal: JournalPolicy,
    workers: Mutex<Vec<JoinHandle<()>>>,
    /// Set by a graceful shutdown: no new jobs, nothing new starts.
    closing: AtomicBool,
    /// The metrics attached with `Scheduler::attach_metrics` (each machine holds them too).
    metrics: std::sync::OnceLock<Arc<dyn Counters>>,
}

struct Machine {
    config: MachineConfig,
    device: Device,
    queue: mpsc::UnboundedSender<JobId>,
    /// The operator's operations between jobs, for the worker.
    ops: mpsc::UnboundedSender<OpRequest>,
    /// The job being streamed; taken under this lock together with the store's claim.
    active: Mutex<Option<Active>>,
    status: Mutex<Seen>,
    /// The overrides of the job it runs.
    overrides: Mutex<Overrides>,
    /// Its slot in the store's progress file.
    slot: usize,
    /// Where link openings and failures are counted (`Scheduler::attach_metrics`).
    metrics: std::sync::OnceLock<Arc<dyn Counters>>,
    /// A link to the machine has been opened before (a later opening is a reconnect).
    opened: AtomicBool,
}

/// What the core counts as it goes, for whoever keeps the figures (the daemon's Prometheus
/// metrics, `services::metrics`, attached with [`Scheduler::attach_metrics`]): the core
/// tells, and never asks who listens.
pub trait Counters: Send + Sync {
    /// A link to `machine` opened (`reopened`: not its first).
    fn link_opened(&self, machine: &str, reopened: bool);
    /// A link to `machine` failed to open or dropped.
    fn link_failed(&self, machine: &str, error: &LinkError);
    /// A job was planned (in `planning`) and queued on `machine`.
    fn job_submitted(&self, machine: &str, planning: std::time::Duration);
}

/// The device's last report and when it came.
#[derive(Clone, Debug, Default)]
struct Seen {
    status: MachineStatus,
    at: Option<Instant>,
}

struct Active {
    job: JobId,
    commands: mpsc::UnboundedSender<Command>,
    /// Set while the job waits, paused, for the operator after its machine came back: the
    /// unit it goes on at.
    waits_at: Option<usize>,
}

/// The overrides the operator changes; the others stay as they are.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OverridePatch {
    #[serde(default)]
    pub feed: Option<u16>,
    #[serde(default)]
    pub spindle: Option<u16>,
    #[serde(default)]
    pub rapid: Option<u16>,
}

impl OverridePatch {
    /// `o` with this patch's changes.
    pub fn apply(&self, mut o: Overrides) -> Overrides {
        if let Some(f) = self.feed {
            o.feed = f;
        }
        if let Some(s) = self.spindle {
            o.spindle = s;
        }
        if let Some(r) = self.rapid {
            o.rapid = r;
        }
        o
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Request {
    Pause,
    /// With a 1-based line: restart a stopped job there instead of at its resume point.
    Resume(Option<usize>),
    Cancel,
    Override(OverridePatch),
    /// The daemon is stopping: hold the machine and leave the job interrupted.
    Shutdown,
}

struct Command {
    request: Request,
    reply: oneshot::Sender<Result<(), SchedError>>,
}

struct OpRequest {
    op: Operation,
    /// The operator confirmed what the machine warned about (a jog below the stock top).
    confirmed: bool,
    reply: oneshot::Sender<Result<String, SchedError>>,
}

impl Scheduler {
    /// Recovers the store (jobs left running become interrupted), queues the jobs that
    /// were waiting, and starts one worker per machine, which first asks its device about
    /// the interrupted jobs (and follows one it still runs). Must run inside a tokio runtime.
    pub fn start(
        store: Store,
        machines: Vec<MachineSetup>,
        journal: JournalPolicy,
    ) -> Result<Scheduler, StoreError> {
        let interrupted = store.mark_interrupted()?;
        for j in &interrupted {
            tracing::warn!(
                "job {} on {} was interrupted at unit {} of {}; asking the machine what it is doing",
                j.id,
                j.machine,
                j.acked_units,
                j.total_units,
            );
        }
        let (events, _) = broadcast::channel(4096);
        let mut receivers = Vec::new();
        let mut map = BTreeMap::new();
        for (slot, MachineSetup { config, device }) in machines.into_iter().enumerate() {
            let (tx, rx) = mpsc::unbounded_channel();
            let (otx, orx) = mpsc::unbounded_channel();
            let follow: Vec<JobId> = interrupted
                .iter()
                .filter(|j| j.machine == config.name)
                .map(|j| j.id)
                .collect();
            receivers.push((config.name.clone(), rx, orx, follow));
            map.insert(
                config.name.clone(),
                Machine {
                    config,
                    device,
                    queue: tx,
                    ops: otx,
                    active: Mutex::new(None),
                    status: Mutex::new(Seen::default()),
                    overrides: Mutex::new(Overrides::default()),
                    slot,
                    metrics: std::sync::OnceLock::new(),
                    opened: AtomicBool::new(false),
                },
            );
        }
        let inner = Arc::new(Inner {
            store,
            events,
            machines: map,
            journal,
            workers: Mutex::new(Vec::new()),
            closing: AtomicBool::new(false),
            metrics: std::sync::OnceLock::new(),
        });
        for job in inner.store.jobs_in(JobState::Queued)? {
            match inner.machines.get(&job.machine) {
                Some(m) => {
                    let _ = m.queue.send(job.id);
                }
                None => inner.store.set_state(
                    job.id,
                    JobState::Failed,
                    Some(&format!(
                        "the machine `{}` is no longer in the configuration",
                        job.machine
                    )),
                )?,
            }
        }
        let mut handles = Vec::new();
        for (name, rx, orx, follow) in receivers {
            let inner2 = inner.clone();
            handles.push(tokio::spawn(async move {
                worker(inner2, name, rx, orx, follow).await
            }));
        }
        *lock(&inner.workers) = handles;
        Ok(Scheduler { inner })
    }

    pub fn store(&self) -> &Store {
        &self.inner.store
    }

    /// Every state change, progress step and status report, for every job.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.inner.events.subscribe()
    }

    fn machine(&self, name: &str) -> Result<&Machine, SchedError> {
        self.inner
            .machines
            .get(name)
            .ok_or_else(|| SchedError::NoSuchMachine {
                name: name.to_string(),
                known: self.machine_names(),
            })
    }

    fn machine_names(&self) -> String {
        if self.inner.machines.is_empty() {
            "no machines".into()
        } else {
            self.inner
                .machines
                .keys()
                .map(|k| format!("`{k}`"))
                .collect::<Vec<_>>()
                .join(", ")
        }
    }

    /// The configuration of machine `name`.
    pub fn machine_config(&self, name: &str) -> Result<&MachineConfig, SchedError> {
        Ok(&self.machine(name)?.config)
    }

    /// What machine `name`'s kind prepared at start-up (a simulator's handle, for tests
    /// and the demo to read its trace), as the kind's own type.
    pub fn device<T: 'static>(&self, name: &str) -> Option<&T> {
        self.inner.machines.get(name)?.device.downcast_ref()
    }

    /// What machine `name`'s kind prepared at start-up, untyped (for the metrics to ask
    /// the kind's own crate about it).
    pub fn device_any(&self, name: &str) -> Option<&Device> {
        Some(&self.inner.machines.get(name)?.device)
    }

    /// The counters attached with `attach_metrics`, for the intake to count into.
    pub fn metrics(&self) -> Option<&Arc<dyn Counters>> {
        self.inner.metrics.get()
    }

    /// Counts link openings and failures into `metrics` (the daemon's Prometheus metrics) from
    /// now on.
    pub fn attach_metrics(&self, metrics: Arc<dyn Counters>) {
        let _ = self.inner.metrics.set(metrics.clone());
        for m in self.inner.machines.values() {
            let _ = m.metrics.set(metrics.clone());
        }
    }

    /// Stores the job with its program (and the machining time its kind estimates) and
    /// queues it on its machine.
    pub fn submit(&self, job: NewJob) -> Result<JobRecord, SchedError> {
        let m = self.machine(&job.machine)?;
        if self.inner.closing.load(Ordering::SeqCst) {
            return Err(SchedError::Conflict(
                "the daemon is shutting down and takes no new jobs".into(),
            ));
        }
        if job.program.is_empty() {
            return Err(SchedError::Conflict(
                "the program is empty: there is nothing to send".into(),
            ));
        }
        let estimate = m.config.kind.estimate(&m.config.settings, &job.program);
        let id = self.inner.store.insert_job(&job)?;
        if let Some(t) = estimate {
            self.inner.store.set_estimate(id, t)?;
        }
        let rec = self.job(id)?;
        self.inner.broadcast_state(&rec);
        let _ = m.queue.send(id);
        Ok(rec)
    }

    /// Like [`Scheduler::submit`], for a program already in the store's form (a G-code file
    /// stored as it streamed in).
    pub fn submit_units(&self, job: NewJobUnits) -> Result<JobRecord, SchedError> {
        let m = self.machine(&job.machine)?;
        if self.inner.closing.load(Ordering::SeqCst) {
            return Err(SchedError::Conflict(
                "the daemon is shutting down and takes no new jobs".into(),
            ));
        }
        if job.pages.units() == 0 {
            return Err(SchedError::Conflict(
                "the program is empty: there is nothing to send".into(),
            ));
        }
        let id = self.inner.store.insert_job_units(&job)?;
        let rec = self.job(id)?;
        self.inner.broadcast_state(&rec);
        let _ = m.queue.send(id);
        Ok(rec)
    }

    pub fn job(&self, id: JobId) -> Result<JobRecord, SchedError> {
        self.inner.store.job(id)?.ok_or(SchedError::NoSuchJob(id))
    }

    pub fn jobs(&self) -> Result<Vec<JobRecord>, SchedError> {
        Ok(self.inner.store.jobs()?)
    }

    pub fn machines(&self) -> Result<Vec<MachineInfo>, SchedError> {
        let jobs = self.inner.store.jobs_in(JobState::Queued)?;
        Ok(self
            .inner
            .machines
            .values()
            .map(|m| {
                let seen = lock(&m.status).clone();
                MachineInfo {
                    name: m.config.name.clone(),
                    link: m.config.link.clone(),
                    job: lock(&m.active).as_ref().map(|a| a.job),
                    queued: jobs.iter().filter(|j| j.machine == m.config.name).count(),
                    status: match seen.status.state {
                        // counted to now: its last report grows older while it says nothing
                        DeviceState::NotAnswering { .. } => MachineStatus {
                            state: DeviceState::NotAnswering {
                                silent_s: seen.at.map_or(0, |t| t.elapsed().as_secs()),
                            },
                            ..seen.status
                        },
                        _ => seen.status,
                    },
                    age_ms: seen.at.map(|t| t.elapsed().as_millis() as u64),
                }
            })
            .collect())
    }

    /// Feed hold on a running job.
    pub async fn pause(&self, id: JobId) -> Result<JobRecord, SchedError> {
        self.request(id, Request::Pause).await
    }

    /// Continues a held job, or queues a stopped one (interrupted, failed, cancelled) again
    /// from its last acknowledged unit.
    pub async fn resume(&self, id: JobId) -> Result<JobRecord, SchedError> {
        self.request(id, Request::Resume(None)).await
    }

    /// Queues a stopped job (interrupted, failed, cancelled) again from program line
    /// `line` (1-based), e.g. a few lines before its resume point when the machine had
    /// not cut every line it acknowledged.
    pub async fn resume_from_line(&self, id: JobId, line: usize) -> Result<JobRecord, SchedError> {
        self.request(id, Request::Resume(Some(line))).await
    }

    /// Cancels a queued, running or held job; returns once the machine has stopped.
    pub async fn cancel(&self, id: JobId) -> Result<JobRecord, SchedError> {
        self.request(id, Request::Cancel).await
    }

    /// Changes the overrides of a running or held job (feed and spindle 50 to 200 %, rapids
    /// 25, 50 or 100 %); refused with the machine's reason when its kind takes none.
    /// Returns the job and the overrides now in force.
    pub async fn override_job(
        &self,
        id: JobId,
        patch: OverridePatch,
    ) -> Result<(JobRecord, Overrides), SchedError> {
        patch
            .apply(Overrides::default())
            .check()
            .map_err(SchedError::Conflict)?;
        let job = self.request(id, Request::Override(patch)).await?;
        let o = *lock(&self.machine(&job.machine)?.overrides);
        Ok((job, o))
    }

    /// What `resume` would do for job `id` (from program line `from_line`, 1-based, when
    /// given), for the operator to confirm: nothing is sent.
    pub fn resume_preview(
        &self,
        id: JobId,
        from_line: Option<usize>,
    ) -> Result<ResumePreview, SchedError> {
        let job = self.job(id)?;
        let m = self.machine(&job.machine)?;
        let active = match lock(&m.active).as_ref() {
            Some(a) if a.job == id => Some(a.waits_at),
            _ => None,
        };
        Ok(crate::core::resume::preview(
            &self.inner.store,
            &m.config,
            &job,
            from_line,
            active,
        )?)
    }

    /// Carries out an operator's operation on a machine between jobs (unlock, home, jog);
    /// returns what the machine said. Refused while a job runs or holds on it, and with
    /// the machine's reason when its kind cannot do it.
    pub async fn operate(&self, machine: &str, op: Operation) -> Result<String, SchedError> {
        self.operate_confirmed(machine, op, false).await
    }

    /// Like [`Scheduler::operate`]; `confirmed` is the operator's yes to what a jog warns
    /// about (an XY jog while the tool stands below the stock top). A jog is checked as
    /// every job is: its target in the work area, its feed at most `max_feed`.
    pub async fn operate_confirmed(
        &self,
        machine: &str,
        op: Operation,
        confirmed: bool,
    ) -> Result<String, SchedError> {
        let m = self.machine(machine)?;
        op.check().map_err(SchedError::Conflict)?;
        if let Some(a) = lock(&m.active).as_ref() {
            return Err(SchedError::Conflict(format!(
                "job {} is on machine `{machine}`; {} waits until it has ended (or is cancelled)",
                a.job,
                op.name()
            )));
        }
        let (tx, rx) = oneshot::channel();
        m.ops
            .send(OpRequest {
                op,
                confirmed,
                reply: tx,
            })
            .map_err(|_| SchedError::Conflict("the machine's worker has stopped".into()))?;
        rx.await
            .map_err(|_| SchedError::Conflict("the machine's worker has stopped".into()))?
    }

    async fn request(&self, id: JobId, request: Request) -> Result<JobRecord, SchedError> {
        let job = self.job(id)?;
        let m = self.machine(&job.machine)?;
        let reply = {
            let active = lock(&m.active);
            match active.as_ref() {
                Some(a) if a.job == id => {
                    let (tx, rx) = oneshot::channel();
                    let _ = a.commands.send(Command { request, reply: tx });
                    Some(rx)
                }
                _ => {
                    // not streaming: settle it here, under the lock the worker claims with
                    let job = self.job(id)?;
                    self.settle_idle(m, &job, request)?;
                    None
                }
            }
        };
        if let Some(rx) = reply {
            // a dropped reply means the stream ended meanwhile: the job is final already
            if let Ok(r) = rx.await {
                r?
            }
        }
        if request == Request::Cancel {
            // answer with the state the cancel leaves the job in, once the machine stopped
            let mut rx = self.subscribe();
            let give_up = Instant::now() + Duration::from_secs(30);
            while !self.job(id)?.state.is_final() && Instant::now() < give_up {
                let _ = tokio::time::timeout(Duration::from_millis(100), rx.recv()).await;
            }
        }
        self.job(id)
    }

    /// A request for a job that is not streaming.
    fn settle_idle(
        &self,
        m: &Machine,
        job: &JobRecord,
        request: Request,
    ) -> Result<(), SchedError> {
        let store = &self.inner.store;
        match (request, job.state) {
            (Request::Cancel, JobState::Queued) => {
                store.set_state(
                    job.id,
                    JobState::Cancelled,
                    Some("cancelled before it started"),
                )?;
            }
            (
                Request::Resume(from),
                JobState::Interrupted | JobState::Failed | JobState::Cancelled,
            ) => self.inner.requeue(m, job, from)?,
            (Request::Resume(None), JobState::Queued) => return Ok(()),
            (Request::Cancel, JobState::Interrupted | JobState::Failed) => {
                store.set_state(job.id, JobState::Cancelled, job.error.as_deref())?;
            }
            (Request::Pause, JobState::Queued) => {
                return Err(SchedError::Conflict(format!(
                    "job {} is still queued; only a running job can be paused (cancel it instead)",
                    job.id
                )))
            }
            (r, s) => {
                let what = match r {
                    Request::Pause => "paused",
                    Request::Resume(None) => "resumed",
                    Request::Resume(Some(_)) => "restarted from a line",
                    Request::Cancel => "cancelled",
                    Request::Override(_) => "overridden (only a running or held job is)",
                    Request::Shutdown => "held for the shutdown",
                };
                return Err(SchedError::Conflict(format!(
                    "job {} is {s} and cannot be {what}",
                    job.id
                )));
            }
        }
        let rec = self.job(job.id)?;
        self.inner.broadcast_state(&rec);
        Ok(())
    }

    /// Cancels every job that is streaming and waits for each to stop.
    pub async fn cancel_all(&self) {
        for id in self.active_jobs() {
            let _ = self.cancel(id).await;
        }
    }

    fn active_jobs(&self) -> Vec<JobId> {
        self.inner
            .machines
            .values()
            .filter_map(|m| lock(&m.active).as_ref().map(|a| a.job))
            .collect()
    }

    /// A graceful stop (SIGTERM): takes no new jobs, feed-holds every running machine,
    /// waits (up to `wait`) for each to stand still, leaves its job interrupted at its exact
    /// unit with the machine held, and stops the workers. The next start shows those jobs
    /// interrupted; `resume` lets the machine go on.
    pub async fn shutdown(&self, wait: Duration) {
        self.inner.closing.store(true, Ordering::SeqCst);
        let active = self.active_jobs();
        let mut replies = Vec::new();
        for id in &active {
            if let Ok(job) = self.job(*id) {
                if let Some(m) = self.inner.machines.get(&job.machine) {
                    if let Some(a) = lock(&m.active).as_ref() {
                        let (tx, rx) = oneshot::channel();
                        let _ = a.commands.send(Command {
                            request: Request::Shutdown,
                            reply: tx,
                        });
                        replies.push(rx);
                    }
                }
            }
        }
        let _ = tokio::time::timeout(wait, futures::future::join_all(replies)).await;
        self.abort();
        for id in active {
            if let Ok(j) = self.job(id) {
                if !j.state.is_final() {
                    self.inner.set_state(
                        id,
                        JobState::Interrupted,
                        Some(&format!(
                            "the daemon was stopped with {} of {} units acknowledged",
                            j.acked_units, j.total_units
                        )),
                    );
                }
            }
        }
    }

    /// Stops every worker at once, without flushing or marking anything: what a crash
    /// leaves behind (jobs stay `running` in the store). For tests and the demo's exit.
    pub fn abort(&self) {
        for h in lock(&self.inner.workers).drain(..) {
            h.abort();
        }
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        for h in lock(&self.workers).drain(..) {
            h.abort();
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Inner {
    /// Queues a stopped job again for `resume` (from its resume point, or from line `from`).
    fn requeue(&self, m: &Machine, job: &JobRecord, from: Option<usize>) -> Result<(), SchedError> {
        if self.closing.load(Ordering::SeqCst) {
            return Err(SchedError::Conflict(
                "the daemon is shutting down; resume the job once it is back".into(),
            ));
        }
        if let Some(line) = from {
            if line == 0 || line > job.total_units {
                return Err(SchedError::Conflict(format!(
                    "job {} has lines 1 to {}; it cannot resume from line {line}",
                    job.id, job.total_units
                )));
            }
            self.store.set_resume_point(job.id, line - 1)?;
            self.store.set_restart_at(job.id, Some(line - 1))?;
        } else {
            self.store.set_restart_at(job.id, None)?;
        }
        self.store.set_state(job.id, JobState::Queued, None)?;
        let _ = m.queue.send(job.id);
        Ok(())
    }

    fn broadcast_state(&self, j: &JobRecord) {
        let _ = self.events.send(Event::state_of(j));
    }

    /// Records a job's state and tells the watchers, once per change: a state set again
    /// as it was (a job that goes on running after a reconnect) is no event.
    fn set_state(&self, id: JobId, state: JobState, error: Option<&str>) {
        let before = self.store.job(id).ok().flatten();
        if let Err(e) = self.store.set_state(id, state, error) {
            tracing::error!("job {id}: cannot record the state {state}: {e}");
        }
        if let Ok(Some(j)) = self.store.job(id) {
            let same = before.is_some_and(|b| b.state == j.state && b.error == j.error);
            if !same {
                self.broadcast_state(&j);
            }
        }
    }

    /// Notes why a job waits (or clears the note), and tells the watchers when it changed.
    fn note(&self, id: JobId, note: Option<&str>) {
        let before = self.store.job(id).ok().flatten();
        if before.as_ref().is_some_and(|b| b.note.as_deref() == note) {
            return;
        }
        if let Err(e) = self.store.set_note(id, note) {
            tracing::error!("job {id}: cannot record a note: {e}");
        }
        if let Ok(Some(j)) = self.store.job(id) {
            self.broadcast_state(&j);
        }
    }

    /// Records the device's status (now).
    fn saw(&self, m: &Machine, status: MachineStatus) {
        let mut seen = lock(&m.status);
        // a device that says nothing has not reported: its last report keeps its age
        let at = match status.state {
            DeviceState::NotAnswering { .. } => seen.at,
            _ => Some(Instant::now()),
        };
        *seen = Seen { status, at };
    }

    /// Records that the device has answered nothing since its last report (its link gave
    /// up on it, or cannot be opened again while it stays silent), saying why in the
    /// status's detail.
    fn not_answering(&self, m: &Machine, why: &str) {
        let mut s = lock(&m.status);
        let silent = s.at.map_or(std::time::Duration::ZERO, |t| t.elapsed());
        let mut status = MachineStatus::not_answering(&s.status, silent);
        status.detail = why.to_string();
        s.status = status;
    }

    /// Records that the machine's link is down, saying why in the status's detail.
    fn offline(&self, m: &Machine, why: &str) {
        let mut s = lock(&m.status);
        s.status.state = DeviceState::Offline;
        s.status.detail = why.to_string();
        s.status.feed = 0.0;
        s.at = Some(Instant::now());
    }
}

/// One machine's worker: first asks the device about the jobs a crash interrupted on it
/// (following one it still runs), then takes job ids off the queue one at a time, carries
/// out the operator's operations between jobs, and keeps the machine's status fresh.
async fn worker(
    inner: Arc<Inner>,
    name: String,
    mut queue: mpsc::UnboundedReceiver<JobId>,
    mut ops: mpsc::UnboundedReceiver<OpRequest>,
    follow: Vec<JobId>,
) {
    let Some(m) = inner.machines.get(&name) else {
        return;
    };
    let mut link: Option<Box<dyn MachineLink>> = None;
    let mut status = run::StatusKeeper::default();
    for id in follow {
        run::run_job(&inner, m, &mut link, id, run::Mode::Follow).await;
    }
    let mut poll = tokio::time::interval(STATUS_POLL);
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut waiting = gate::Waiting::default();
    loop {
        tokio::select! {
            biased;
            id = queue.recv() => match id {
                Some(id) => waiting.take(&inner, m, &mut link, &mut status, id).await,
                None => return,
            },
            op = ops.recv() => {
                let Some(op) = op else { return };
                let r = run::operate(&inner, m, &mut link, &op.op, op.confirmed).await;
                let _ = op.reply.send(r);
            }
            _ = poll.tick() => {
                status.keep(&inner, m, &mut link).await;
                waiting.retry(&inner, m, &mut link, &mut status).await;
            }
        }
    }
}

/// The operator's sentence for a link error, for messages that are not about a line.
fn say(e: &LinkError) -> String {
    e.to_string()
}

#[cfg(test)]
mod tests;
