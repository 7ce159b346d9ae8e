//! The scheduler: one worker per machine runs that machine's queue, first in first out,
//! streaming each job's program through the machine's `Link`, journaling every
//! acknowledged unit, and broadcasting progress, state changes and device status.
//!
//! A job goes queued → running ⇄ paused → completed / failed / cancelled (or interrupted,
//! when the daemon stopped under it). A failed job keeps the device's message and the
//! worker goes on with the next job; nothing a device says stops the daemon.

use crate::config::MachineConfig;
use crate::store::{JobId, JobRecord, JobState, Journal, NewJob, NewJobUnits, Store, StoreError};
use machlink_protocols::kind::{Device, MachineLink};
use machlink_protocols::untrusted::{printable, MAX_TEXT};
use machlink_protocols::{
    Control, DeviceState, LinkError, LinkEvent, MachineStatus, Program, StreamEnd,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
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
    /// The device's last report (state unknown before any).
    #[serde(flatten)]
    pub status: MachineStatus,
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
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// Settings of the journal's batching.
#[derive(Clone, Copy, Debug)]
pub struct JournalPolicy {
    pub every: usize,
    pub max_lag: Duration,
}

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
}

struct Machine {
    config: MachineConfig,
    device: Device,
    queue: mpsc::UnboundedSender<JobId>,
    /// The job being streamed; taken under this lock together with the store's claim.
    active: Mutex<Option<Active>>,
    status: Mutex<MachineStatus>,
}

struct Active {
    job: JobId,
    commands: mpsc::UnboundedSender<Command>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Request {
    Pause,
    /// With a 1-based line: restart a stopped job there instead of at its resume point.
    Resume(Option<usize>),
    Cancel,
}

struct Command {
    request: Request,
    reply: oneshot::Sender<Result<(), SchedError>>,
}

impl Scheduler {
    /// Recovers the store (jobs left running become interrupted), queues the jobs that
    /// were waiting, and starts one worker per machine. Must run inside a tokio runtime.
    pub fn start(
        store: Store,
        machines: Vec<MachineSetup>,
        journal: JournalPolicy,
    ) -> Result<Scheduler, StoreError> {
        let interrupted = store.mark_interrupted()?;
        for j in &interrupted {
            tracing::warn!(
                "job {} on {} was interrupted at unit {} of {}; `machlink resume {}` continues it",
                j.id,
                j.machine,
                j.acked_units,
                j.total_units,
                j.id
            );
        }
        let (events, _) = broadcast::channel(4096);
        let mut receivers = Vec::new();
        let mut map = BTreeMap::new();
        for MachineSetup { config, device } in machines {
            let (tx, rx) = mpsc::unbounded_channel();
            receivers.push((config.name.clone(), rx));
            map.insert(
                config.name.clone(),
                Machine {
                    config,
                    device,
                    queue: tx,
                    active: Mutex::new(None),
                    status: Mutex::new(MachineStatus::default()),
                },
            );
        }
        let inner = Arc::new(Inner {
            store,
            events,
            machines: map,
            journal,
            workers: Mutex::new(Vec::new()),
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
        for (name, rx) in receivers {
            let inner2 = inner.clone();
            handles.push(tokio::spawn(async move { worker(inner2, name, rx).await }));
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

    /// Stores the job with its program and queues it on its machine.
    pub fn submit(&self, job: NewJob) -> Result<JobRecord, SchedError> {
        let m = self.machine(&job.machine)?;
        if job.program.is_empty() {
            return Err(SchedError::Conflict(
                "the program is empty: there is nothing to send".into(),
            ));
        }
        let id = self.inner.store.insert_job(&job)?;
        let rec = self.job(id)?;
        self.inner.broadcast_state(&rec);
        let _ = m.queue.send(id);
        Ok(rec)
    }

    /// Like [`Scheduler::submit`], for a program already in the store's form (a G-code file
    /// stored as it streamed in).
    pub fn submit_units(&self, job: NewJobUnits) -> Result<JobRecord, SchedError> {
        let m = self.machine(&job.machine)?;
        if job.total_units == 0 {
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
                let st = lock(&m.status).clone();
                MachineInfo {
                    name: m.config.name.clone(),
                    link: m.config.link.clone(),
                    job: lock(&m.active).as_ref().map(|a| a.job),
                    queued: jobs.iter().filter(|j| j.machine == m.config.name).count(),
                    status: st,
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

    /// Cancels a queued, running or held job.
    pub async fn cancel(&self, id: JobId) -> Result<JobRecord, SchedError> {
        self.request(id, Request::Cancel).await
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
            ) => {
                if let Some(line) = from {
                    if line == 0 || line > job.total_units {
                        return Err(SchedError::Conflict(format!(
                            "job {} has lines 1 to {}; it cannot resume from line {line}",
                            job.id, job.total_units
                        )));
                    }
                    store.set_resume_point(job.id, line - 1)?;
                }
                store.set_state(job.id, JobState::Queued, None)?;
                let _ = m.queue.send(job.id);
            }
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
        let active: Vec<JobId> = self
            .inner
            .machines
            .values()
            .filter_map(|m| lock(&m.active).as_ref().map(|a| a.job))
            .collect();
        for id in active {
            let _ = self.cancel(id).await;
            let mut rx = self.subscribe();
            while self.job(id).map(|j| !j.state.is_final()).unwrap_or(false) {
                let _ = tokio::time::timeout(Duration::from_millis(100), rx.recv()).await;
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
    fn broadcast_state(&self, j: &JobRecord) {
        let _ = self.events.send(Event::state_of(j));
    }

    fn set_state(&self, id: JobId, state: JobState, error: Option<&str>) {
        if let Err(e) = self.store.set_state(id, state, error) {
            tracing::error!("job {id}: cannot record the state {state}: {e}");
        }
        if let Ok(Some(j)) = self.store.job(id) {
            self.broadcast_state(&j);
        }
    }
}

/// One machine's worker: takes job ids off the queue, one at a time.
async fn worker(inner: Arc<Inner>, name: String, mut queue: mpsc::UnboundedReceiver<JobId>) {
    let mut link: Option<Box<dyn MachineLink>> = None;
    while let Some(id) = queue.recv().await {
        let Some(m) = inner.machines.get(&name) else {
            return;
        };
        run_job(&inner, m, &mut link, id).await;
    }
}

/// Runs one job to its end; every outcome lands in the store, none escapes.
async fn run_job(inner: &Inner, m: &Machine, link: &mut Option<Box<dyn MachineLink>>, id: JobId) {
    // claim the job under the machine's lock, so a cancel cannot slip in between
    let (cmd_tx, mut cmd_rx) = mpsc::unbounded_channel();
    let job = {
        let mut active = lock(&m.active);
        match inner.store.job(id) {
            Ok(Some(j)) if j.state == JobState::Queued => {
                *active = Some(Active {
                    job: id,
                    commands: cmd_tx,
                });
                j
            }
            Ok(_) => return, // cancelled while queued, or resumed twice
            Err(e) => {
                tracing::error!("job {id}: {e}");
                return;
            }
        }
    };
    let outcome = stream_job(inner, m, link, &job, &mut cmd_rx).await;
    // refuse late commands with the final state
    *lock(&m.active) = None;
    while let Ok(c) = cmd_rx.try_recv() {
        let _ = c.reply.send(Ok(()));
    }
    let (state, error) = outcome;
    if let Some(e) = &error {
        tracing::warn!("job {id} on {}: {e}", m.config.name);
    }
    inner.set_state(id, state, error.as_deref());
}

/// Streams a claimed job; returns its final state and error message.
async fn stream_job(
    inner: &Inner,
    m: &Machine,
    link: &mut Option<Box<dyn MachineLink>>,
    job: &JobRecord,
    commands: &mut mpsc::UnboundedReceiver<Command>,
) -> (JobState, Option<String>) {
    let id = job.id;
    let program = match inner
        .store
        .program(id)
        .and_then(|p| p.decode(m.config.kind.as_ref()))
    {
        Ok(p) => p,
        Err(e) => return (JobState::Failed, Some(e.to_string())),
    };
    inner.set_state(id, JobState::Running, None);
    if link.is_none() {
        match open_link(m).await {
            Ok(l) => *link = Some(l),
            Err(e) => {
                return (
                    JobState::Failed,
                    Some(format!("cannot reach machine `{}`: {e}", m.config.name)),
                )
            }
        }
    }
    let Some(l) = link.as_mut() else {
        return (JobState::Failed, Some("no link".into()));
    };
    let total = program.len();
    let from = job.acked_units.min(total);
    let (ev_tx, mut ev_rx) = mpsc::unbounded_channel();
    let (ctl_tx, ctl_rx) = watch::channel(Control::Run);
    let mut journal = Journal::new(from, inner.journal.every, inner.journal.max_lag);
    let mut cancel_requested = false;
    let result = {
        let mut stream = l.stream(&program, from, ev_tx, ctl_rx);
        loop {
            tokio::select! {
                biased;
                Some(ev) = ev_rx.recv() => {
                    // a machine that stopped itself for the operator (a thread break, a
                    // program stop, an open door) pauses the job: `machlink resume JOB`
                    // continues it
                    if let LinkEvent::Status(MachineStatus {
                        state: DeviceState::NeedsOperator { .. },
                        ..
                    }) = &ev
                    {
                        let _ = on_command(inner, id, &ctl_tx, Request::Pause);
                    }
                    on_link_event(inner, m, id, total, &mut journal, ev)
                }
                Some(cmd) = commands.recv() => {
                    let r = on_command(inner, id, &ctl_tx, cmd.request);
                    cancel_requested |= cmd.request == Request::Cancel;
                    let _ = cmd.reply.send(r);
                }
                _ = sleep_until(journal.deadline()) => flush(inner, id, &mut journal),
                r = &mut stream => break r,
            }
        }
    };
    while let Ok(ev) = ev_rx.try_recv() {
        on_link_event(inner, m, id, total, &mut journal, ev);
    }
    flush(inner, id, &mut journal);
    let outcome = match result {
        Ok(StreamEnd::Completed) => (JobState::Completed, None),
        Ok(StreamEnd::Cancelled { acked }) => {
            if acked > journal.acked() {
                journal.ack(acked - 1, Instant::now());
                flush(inner, id, &mut journal);
            }
            (JobState::Cancelled, None)
        }
        Err(e) => {
            let msg = printable(&describe_failure(&e, &program, journal.acked()), MAX_TEXT);
            // a device that refused a line or raised an alarm is still talking (the link
            // resets it); a link that broke is opened afresh for the next job
            if !e.keeps_link() {
                *link = None;
            }
            if cancel_requested {
                (JobState::Cancelled, Some(msg))
            } else {
                (JobState::Failed, Some(msg))
            }
        }
    };
    if outcome.0 == JobState::Completed && journal.acked() < total {
        // a link that says completed has had every unit acknowledged
        journal.ack(total - 1, Instant::now());
        flush(inner, id, &mut journal);
    }
    outcome
}

/// Opens the machine's link through its kind; a port still held by the link just closed
/// (its lock is released a moment later) is tried again for up to two seconds.
async fn open_link(m: &Machine) -> Result<Box<dyn MachineLink>, LinkError> {
    let give_up = Instant::now() + Duration::from_secs(2);
    loop {
        let c = &m.config;
        match c.kind.open(&c.name, &c.settings, &m.device).await {
            Err(LinkError::PortBusy { .. }) if Instant::now() < give_up => {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            r => return r,
        }
    }
}

async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d.into()).await,
        None => std::future::pending().await,
    }
}

fn flush(inner: &Inner, id: JobId, journal: &mut Journal) {
    if let Some((a, b)) = journal.take() {
        if let Err(e) = inner.store.record_acks(id, a, b) {
            tracing::error!("job {id}: cannot journal units {a}..{b}: {e}");
        }
    }
}

fn on_link_event(
    inner: &Inner,
    m: &Machine,
    id: JobId,
    total: usize,
    journal: &mut Journal,
    ev: LinkEvent,
) {
    match ev {
        LinkEvent::Acked { unit } => {
            if journal.ack(unit, Instant::now()) {
                flush(inner, id, journal);
            }
            let _ = inner.events.send(Event::Progress {
                job: id,
                acked: journal.acked(),
                total,
            });
        }
        LinkEvent::Status(mut s) => {
            // device text is untrusted: no control characters reach a log or a terminal
            s.detail = printable(&s.detail, MAX_TEXT);
            let _ = inner.events.send(Event::Status {
                machine: m.config.name.clone(),
                job: Some(id),
                status: s.clone(),
            });
            *lock(&m.status) = s;
        }
        LinkEvent::Message(text) => {
            let _ = inner.events.send(Event::Message {
                machine: m.config.name.clone(),
                job: Some(id),
                text: printable(&text, MAX_TEXT),
            });
        }
    }
}

fn on_command(
    inner: &Inner,
    id: JobId,
    control: &watch::Sender<Control>,
    request: Request,
) -> Result<(), SchedError> {
    let current = *control.borrow();
    match (request, current) {
        (Request::Pause, Control::Run) => {
            let _ = control.send(Control::Hold);
            inner.set_state(id, JobState::Paused, None);
        }
        (Request::Resume(Some(_)), _) => {
            return Err(SchedError::Conflict(format!(
                "job {id} is still streaming; only a stopped job restarts from a line (cancel it first)"
            )))
        }
        (Request::Resume(None), Control::Hold) => {
            let _ = control.send(Control::Run);
            inner.set_state(id, JobState::Running, None);
        }
        (Request::Pause, Control::Hold) | (Request::Resume(None), Control::Run) => {}
        (Request::Cancel, _) => {
            let _ = control.send(Control::Cancel);
        }
        (_, Control::Cancel) => {
            return Err(SchedError::Conflict(format!("job {id} is being cancelled")))
        }
    }
    Ok(())
}

/// The operator's sentence for a failed stream, naming the program line (1-based, as in
/// the program file `machlink plan` writes).
fn describe_failure(e: &LinkError, program: &Program, acked: usize) -> String {
    match e {
        LinkError::Rejected { unit, text, reason } => {
            format!("the machine refused line {} `{text}`: {reason}", unit + 1)
        }
        // the GRBL link names the line that was running when the alarm came
        LinkError::Alarm { text, .. } => format!(
            "the machine raised {text} ({acked} of {} lines had been acknowledged)",
            program.len()
        ),
        other => format!(
            "{other} (after {acked} of {} lines were acknowledged)",
            program.len()
        ),
    }
}

#[cfg(test)]
mod tests;
