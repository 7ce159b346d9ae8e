//! Running one job on a machine: asking the device where a job that ran before stands (and
//! following what it still runs), streaming with the journal, pausing on a dropped link and
//! reconnecting with backoff, and the operator's operations between jobs.

use super::*;
use crate::core::store::{Journal, SendRecord};
use machlink_protocols::untrusted::{printable, MAX_TEXT};
use machlink_protocols::{LinkEvent, Program, Reattach, SendJournal, StreamEnd};
use std::sync::atomic::{AtomicUsize, Ordering as AtomicOrdering};

/// Why a job is taken up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Mode {
    /// The operator queued it: stream it, after asking the device where it stands when it
    /// ran before.
    Run,
    /// A crash interrupted it: ask the device, follow what it still runs, and otherwise
    /// leave the job waiting for `machlink resume` at the exact next unit.
    Follow,
}

/// How a job's run ends.
enum Outcome {
    Final(JobState, Option<String>),
    /// Back to interrupted, waiting for the operator, with a note saying why.
    Waits(String),
}

/// What asking the device found.
enum Attached {
    /// Stream from this unit (the device may still be running the job: the stream follows).
    Go(usize),
    /// The device is not running it; the program goes on at `next` when the operator says.
    Wait {
        next: usize,
        note: String,
    },
    Done,
    Cancelled,
    Offline(LinkError),
    Failed(String),
}

/// What comes after the machine came back.
enum Back {
    Stream(usize),
    Done,
    Cancelled,
    Failed(String),
}

/// The journal a link writes before its bytes leave (GRBL): the job's record in its
/// machine's slot of the store's progress file.
struct StoreJournal {
    record: SendRecord,
    /// The acknowledged count the store has, shared with the ack journal (which then
    /// skips a commit the link's journal already made).
    committed: Arc<AtomicUsize>,
}

impl SendJournal for StoreJournal {
    fn sending(&mut self, acked: usize, upto: usize) -> Result<(), String> {
        self.record
            .sending(acked, upto)
            .map_err(|e| e.to_string())?;
        self.committed.fetch_max(acked, AtomicOrdering::SeqCst);
        Ok(())
    }
    fn sent(&mut self, upto: usize) -> Result<(), String> {
        self.record.sent(upto).map_err(|e| e.to_string())
    }
}

/// One job being run: what the handlers of its commands and events share.
struct Job<'a> {
    inner: &'a Inner,
    m: &'a Machine,
    id: JobId,
    total: usize,
    commands: &'a mut mpsc::UnboundedReceiver<Command>,
    control: watch::Sender<Control>,
    overrides: watch::Sender<Overrides>,
    /// Why the machine's kind takes no overrides, once its link said so.
    overrides_refused: Option<String>,
    cancel_requested: bool,
    /// The operator said resume while the daemon was still asking the device.
    resume_requested: bool,
    /// The watchers heard that the device still runs this job on its own.
    told_following: bool,
    shutdown_reply: Option<oneshot::Sender<Result<(), SchedError>>>,
    committed: Arc<AtomicUsize>,
}

/// Runs one job to its end (or back to waiting); every outcome lands in the store.
pub(super) async fn run_job(
    inner: &Inner,
    m: &Machine,
    link: &mut Option<Box<dyn MachineLink>>,
    id: JobId,
    mode: Mode,
) {
    if inner.closing.load(Ordering::SeqCst) {
        return;
    }
    // claim the job under the machine's lock, so a cancel cannot slip in between
    let (cmd_tx, mut cmd_rx) = mpsc::unbounded_channel();
    let job = {
        let mut active = lock(&m.active);
        let want = match mode {
            Mode::Run => JobState::Queued,
            Mode::Follow => JobState::Interrupted,
        };
        match inner.store.job(id) {
            Ok(Some(j)) if j.state == want => {
                *active = Some(Active {
                    job: id,
                    commands: cmd_tx,
                    waits_at: None,
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
    let mut j = Job {
        inner,
        m,
        id,
        total: job.total_units,
        commands: &mut cmd_rx,
        control: watch::channel(Control::Run).0,
        // each job starts at 100 %
        overrides: watch::channel(Overrides::default()).0,
        overrides_refused: None,
        cancel_requested: false,
        resume_requested: false,
        told_following: false,
        shutdown_reply: None,
        committed: Arc::new(AtomicUsize::new(job.acked_units)),
    };
    *lock(&m.overrides) = Overrides::default();
    let outcome = j.run(link, &job, mode).await;
    if let Some(r) = j.shutdown_reply.take() {
        let _ = r.send(Ok(()));
    }
    // A run that leaves the job waiting (interrupted) records that while the job still
    // counts as active: a resume that then finds the machine free sees "interrupted" and
    // queues it (settled as "queued" in between, it was overwritten and lost), and one that
    // came to the run too late is queued below. A final state is recorded after, as before:
    // a request in between finds the job still running and is refused, not lost.
    let waits = matches!(outcome, Outcome::Waits(_));
    let settle = |outcome: Outcome| match outcome {
        Outcome::Final(state, error) => {
            if let Some(e) = &error {
                tracing::warn!("job {id} on {}: {e}", m.config.name);
            }
            inner.note(id, None);
            inner.set_state(id, state, error.as_deref());
        }
        Outcome::Waits(note) => {
            tracing::info!("job {id} on {}: {note}", m.config.name);
            inner.note(id, Some(&note));
            let error = inner.store.job(id).ok().flatten().and_then(|j| j.error);
            inner.set_state(id, JobState::Interrupted, error.as_deref());
        }
    };
    let mut outcome = Some(outcome);
    if waits {
        settle(outcome.take().expect("the outcome"));
    }
    let late: Vec<Command> = {
        let mut active = lock(&m.active);
        *active = None;
        std::iter::from_fn(|| cmd_rx.try_recv().ok()).collect()
    };
    if let Some(o) = outcome {
        settle(o);
    }
    for c in late {
        let answer = match c.request {
            // a resume that came while the daemon was asking the device, too late for the
            // run to take it: the job waits interrupted, so queue it as asked
            Request::Resume(from) if waits => match inner.store.job(id) {
                Ok(Some(j)) => inner.requeue(m, &j, from).inspect(|()| {
                    if let Ok(Some(queued)) = inner.store.job(id) {
                        inner.broadcast_state(&queued);
                    }
                }),
                _ => Ok(()),
            },
            // the others find the job final: nothing left to do
            _ => Ok(()),
        };
        let _ = c.reply.send(answer);
    }
}

impl Job<'_> {
    async fn run(
        &mut self,
        link: &mut Option<Box<dyn MachineLink>>,
        job: &JobRecord,
        mode: Mode,
    ) -> Outcome {
        let (inner, m, id) = (self.inner, self.m, self.id);
        let program = match inner
            .store
            .program(id)
            .and_then(|p| p.decode(m.config.kind.as_ref()))
        {
            Ok(p) => p,
            Err(e) => return Outcome::Final(JobState::Failed, Some(e.to_string())),
        };
        // a program stored as it streamed in (a G-code file) has its machining time
        // estimated here, where its units are at hand anyway, so its ETA exists too
        if job.estimate_ms.is_none() {
            if let Some(t) = m.config.kind.estimate(&m.config.settings, &program) {
                let _ = inner.store.set_estimate(id, t);
            }
        }
        if mode == Mode::Run {
            inner.set_state(id, JobState::Running, None);
        }
        if link.is_none() {
            match open_link(m).await {
                Ok(l) => *link = Some(l),
                Err(e) => {
                    inner.offline(m, &say(&e));
                    return match mode {
                        Mode::Follow => Outcome::Waits(format!(
                            "machine `{}` could not be reached to ask what it is doing ({e}); `machlink resume {id}` asks again",
                            m.config.name
                        )),
                        Mode::Run => Outcome::Final(
                            JobState::Failed,
                            Some(format!("cannot reach machine `{}`: {e}", m.config.name)),
                        ),
                    };
                }
            }
        }
        let restart_at = match mode {
            Mode::Run => inner.store.take_restart_at(id).ok().flatten(),
            Mode::Follow => None,
        };
        let mut from = match restart_at {
            Some(at) => at,
            None if job.started_ms.is_some() || mode == Mode::Follow => {
                let asked = match mode {
                    Mode::Follow => self.attach_after_stop(link, &program, false).await,
                    Mode::Run => self.attach(link, &program, mode, false).await,
                };
                match asked {
                    Attached::Go(f) => f,
                    Attached::Wait { next, note } => {
                        if mode == Mode::Follow && !self.resume_requested {
                            return Outcome::Waits(note);
                        }
                        let _ = inner.events.send(Event::Message {
                            machine: m.config.name.clone(),
                            job: Some(id),
                            text: note,
                        });
                        next
                    }
                    Attached::Done => return Outcome::Final(JobState::Completed, None),
                    Attached::Cancelled => return Outcome::Final(JobState::Cancelled, None),
                    Attached::Failed(msg) => return Outcome::Final(JobState::Failed, Some(msg)),
                    Attached::Offline(e) => match mode {
                        Mode::Follow => {
                            *link = None;
                            inner.offline(m, &say(&e));
                            return Outcome::Waits(format!(
                                "the link to machine `{}` failed while asking it what it is doing ({e}); `machlink resume {id}` asks again",
                                m.config.name
                            ));
                        }
                        Mode::Run => match self.reconnect(link, &program, &e).await {
                            Back::Stream(f) => f,
                            Back::Done => return Outcome::Final(JobState::Completed, None),
                            Back::Cancelled => return Outcome::Final(JobState::Cancelled, None),
                            Back::Failed(msg) => {
                                return Outcome::Final(JobState::Failed, Some(msg))
                            }
                        },
                    },
                }
            }
            None => job.acked_units,
        };
        loop {
            let Some(l) = link.as_mut() else {
                return Outcome::Final(JobState::Failed, Some("no link".into()));
            };
            from = from.min(self.total);
            if let Err(e) = inner.store.start_stream_at(id, from) {
                return Outcome::Final(JobState::Failed, Some(e.to_string()));
            }
            self.committed.store(from, AtomicOrdering::SeqCst);
            if *self.control.borrow() == Control::Run {
                inner.note(id, None);
                inner.set_state(id, JobState::Running, None);
            }
            let record = match inner.store.send_record(m.slot, id, from) {
                Ok(r) => r,
                Err(e) => return Outcome::Final(JobState::Failed, Some(e.to_string())),
            };
            l.keep_journal(Box::new(StoreJournal {
                record: record.clone(),
                committed: self.committed.clone(),
            }));
            self.overrides_refused = l
                .follow_overrides(self.overrides.subscribe())
                .err()
                .map(|e| say(&e));
            let (ev_tx, mut ev_rx) = mpsc::unbounded_channel();
            let mut journal = Journal::new(from, inner.journal.every, inner.journal.max_lag);
            let ctl = self.control.subscribe();
            let result = self
                .drive(
                    l.stream(&program, from, ev_tx, ctl),
                    &mut ev_rx,
                    &mut journal,
                )
                .await;
            // the stream's record of its writes goes into the job's row
            if let Err(e) = record.persist() {
                tracing::error!("job {id}: cannot record how far the program went: {e}");
            }
            return match result {
                Ok(StreamEnd::Completed) => {
                    self.flush_to(&mut journal, self.total);
                    Outcome::Final(JobState::Completed, None)
                }
                Ok(StreamEnd::Cancelled { acked }) => {
                    self.flush_to(&mut journal, acked);
                    Outcome::Final(JobState::Cancelled, None)
                }
                Err(e) if self.cancel_requested => {
                    if !e.keeps_link() {
                        *link = None;
                    }
                    Outcome::Final(
                        JobState::Cancelled,
                        Some(printable(
                            &describe_failure(&e, &program, journal.acked()),
                            MAX_TEXT,
                        )),
                    )
                }
                Err(e) if e.is_disconnect() => {
                    if let Some(metrics) = m.metrics.get() {
                        metrics.link_failed(&m.config.name, &e);
                    }
                    *link = None;
                    match self.reconnect(link, &program, &e).await {
                        Back::Stream(f) => {
                            from = f;
                            continue;
                        }
                        Back::Done => Outcome::Final(JobState::Completed, None),
                        Back::Cancelled => Outcome::Final(
                            JobState::Cancelled,
                            Some("cancelled while the machine was offline".into()),
                        ),
                        Back::Failed(msg) => Outcome::Final(JobState::Failed, Some(msg)),
                    }
                }
                Err(e) => {
                    if let Some(metrics) = m.metrics.get() {
                        metrics.link_failed(&m.config.name, &e);
                    }
                    let msg = printable(&describe_failure(&e, &program, journal.acked()), MAX_TEXT);
                    // a device that refused a line or raised an alarm is still talking (the
                    // link resets it); a link that broke is opened afresh for the next job
                    if !e.keeps_link() {
                        *link = None;
                    }
                    Outcome::Final(JobState::Failed, Some(msg))
                }
            };
        }
    }

    /// Asks the device where this job stands and follows what it still runs of it.
    async fn attach(
        &mut self,
        link: &mut Option<Box<dyn MachineLink>>,
        program: &Program,
        mode: Mode,
        cut_off: bool,
    ) -> Attached {
        let (inner, m, id) = (self.inner, self.m, self.id);
        let Some(l) = link.as_mut() else {
            return Attached::Failed("no link".into());
        };
        // a machine that holds stays held until the operator says otherwise
        let held = match with_timeout(l.inquire()).await {
            Ok(st) => {
                let held = matches!(
                    st.state,
                    DeviceState::Held | DeviceState::NeedsOperator { .. }
                );
                inner.saw(m, st);
                held
            }
            Err(e) if e.is_disconnect() => return Attached::Offline(e),
            Err(_) => false,
        };
        if held && mode == Mode::Follow && !self.resume_requested {
            let _ = self.control.send(Control::Hold);
            inner.set_state(id, JobState::Paused, None);
            inner.note(
                id,
                Some("the machine holds this job: `machlink resume` lets it go on"),
            );
        } else {
            let _ = self.control.send(Control::Run);
        }
        // only the operator's word lets a holding device go on; asking after a stop sends
        // nothing that makes motion
        let go_on = mode == Mode::Run || self.resume_requested;
        let handed = match inner.store.handed(id) {
            Ok(h) => machlink_protocols::Handed {
                cut_off,
                go_on,
                ..h
            },
            Err(e) => return Attached::Failed(e.to_string()),
        };
        let (ev_tx, mut ev_rx) = mpsc::unbounded_channel();
        let mut journal = Journal::new(handed.acked, inner.journal.every, inner.journal.max_lag);
        let ctl = self.control.subscribe();
        let r = self
            .drive(
                l.reattach(program, handed, ev_tx, ctl),
                &mut ev_rx,
                &mut journal,
            )
            .await;
        let n = program.len();
        let line = |k: usize| {
            if k >= n {
                "the end".to_string()
            } else {
                format!("line {} (`{}`)", k + 1, program.describe_unit(k))
            }
        };
        match r {
            Ok(Reattach::Running { acked }) => {
                self.set_acked(acked);
                // one write: a held job never reads `running` in between (a resume that came
                // then was refused as "nothing to resume")
                let state = if *self.control.borrow() == Control::Hold {
                    JobState::Paused
                } else {
                    JobState::Running
                };
                inner.set_state(id, state, None);
                if !std::mem::replace(&mut self.told_following, true) {
                    let _ = inner.events.send(Event::Message {
                        machine: m.config.name.clone(),
                        job: Some(id),
                        text: format!(
                            "the machine is still running this job ({acked} of {n} units done): following it"
                        ),
                    });
                }
                Attached::Go(acked)
            }
            Ok(Reattach::Completed) => {
                self.set_acked(n);
                Attached::Done
            }
            Ok(Reattach::Stopped { next }) => {
                self.set_acked(next);
                Attached::Wait {
                    next,
                    note: format!(
                        "the machine stands idle with {next} of {n} units done; `machlink resume {id}` goes on at {}",
                        line(next)
                    ),
                }
            }
            Ok(Reattach::Unsure { next, why }) => {
                self.set_acked(next);
                Attached::Wait {
                    next,
                    note: format!(
                        "{why}; the journal's point is {} (`machlink resume {id} --from-line N` to choose)",
                        line(next)
                    ),
                }
            }
            Err(_) if self.cancel_requested => Attached::Cancelled,
            Err(e) if e.is_disconnect() => Attached::Offline(e),
            Err(e) => Attached::Failed(format!(
                "asking the machine where the job stands failed: {e}"
            )),
        }
    }

    /// Asks the device where this job stands after a stop (a restart of the daemon, a link
    /// that came back). A device that runs the job on its own (a sewing machine sewing the
    /// pattern it holds, a ring with blocks left) is watched, never fed: asked again every
    /// quarter second until it stops, or until the operator resumes, pauses or cancels,
    /// which the stream then carries out. Nothing that makes motion is sent before.
    async fn attach_after_stop(
        &mut self,
        link: &mut Option<Box<dyn MachineLink>>,
        program: &Program,
        cut_off: bool,
    ) -> Attached {
        loop {
            let at = match self.attach(link, program, Mode::Follow, cut_off).await {
                Attached::Go(at)
                    if !self.resume_requested && *self.control.borrow() == Control::Run =>
                {
                    at
                }
                other => return other,
            };
            self.inner.note(
                self.id,
                Some(&format!(
                    "the machine runs what it holds of this job on its own; nothing more is sent until `machlink resume {}`",
                    self.id
                )),
            );
            let until = tokio::time::Instant::now() + Duration::from_millis(250);
            loop {
                tokio::select! {
                    Some(cmd) = self.commands.recv() => {
                        // the daemon stopping leaves the device to what it has
                        let r = match cmd.request {
                            Request::Shutdown => Ok(()),
                            other => self.on_command(other),
                        };
                        let _ = cmd.reply.send(r);
                    }
                    _ = tokio::time::sleep_until(until) => break,
                }
                if self.resume_requested || *self.control.borrow() != Control::Run {
                    self.inner.note(self.id, None);
                    return Attached::Go(at);
                }
            }
        }
    }

    /// The store's resume point is `acked`: what the device confirmed.
    fn set_acked(&mut self, acked: usize) {
        let acked = acked.min(self.total);
        if let Err(e) = self.inner.store.start_stream_at(self.id, acked) {
            tracing::error!("job {}: cannot record its resume point: {e}", self.id);
        }
        self.committed.store(acked, AtomicOrdering::SeqCst);
        let _ = self.inner.events.send(Event::Progress {
            job: self.id,
            acked,
            total: self.total,
        });
    }

    /// The link dropped: the job pauses, the daemon reconnects with backoff, asks the
    /// device what it is doing (following what it still runs), and waits for the operator.
    async fn reconnect(
        &mut self,
        link: &mut Option<Box<dyn MachineLink>>,
        program: &Program,
        e: &LinkError,
    ) -> Back {
        let (inner, m, id) = (self.inner, self.m, self.id);
        *link = None;
        let mut why = say(e);
        // a device that went silent (rather than a port that went away) shows as not
        // answering, counted from its last report, until it answers or its port goes
        let mut silent = e.is_silence();
        let down = |silent: bool, why: &str| {
            if silent {
                inner.not_answering(m, why);
            } else {
                inner.offline(m, why);
            }
        };
        loop {
            down(silent, &why);
            let acked = inner
                .store
                .job(id)
                .ok()
                .flatten()
                .map_or(0, |j| j.acked_units);
            inner.set_state(id, JobState::Paused, None);
            inner.note(
                id,
                Some(&format!(
                    "the link to machine `{}` dropped with {acked} of {} units acknowledged ({why}); reconnecting, then `machlink resume {id}` goes on",
                    m.config.name, self.total
                )),
            );
            // reconnect with backoff, answering the operator meanwhile
            let mut delay = Duration::from_millis(250);
            loop {
                tokio::select! {
                    cmd = self.commands.recv() => {
                        let Some(cmd) = cmd else { return Back::Cancelled };
                        match cmd.request {
                            Request::Cancel => {
                                let _ = cmd.reply.send(Ok(()));
                                return Back::Cancelled;
                            }
                            Request::Resume(_) => {
                                let _ = cmd.reply.send(Err(SchedError::Conflict(format!(
                                    "machine `{}` is offline ({why}); job {id} goes on once it is back and you resume it",
                                    m.config.name
                                ))));
                            }
                            r => {
                                let reply = self.on_command(r);
                                let _ = cmd.reply.send(reply);
                            }
                        }
                    }
                    _ = tokio::time::sleep(delay) => {
                        match open_link(m).await {
                            Ok(l) => {
                                *link = Some(l);
                                break;
                            }
                            Err(e2) => {
                                why = format!("reconnecting: {e2}");
                                silent &= !matches!(e2, LinkError::Open { .. } | LinkError::PortBusy { .. });
                                down(silent, &why);
                                delay = (delay * 2).min(Duration::from_secs(5));
                            }
                        }
                    }
                }
            }
            tracing::info!(
                "machine `{}` is back; asking it where job {id} stands",
                m.config.name
            );
            self.resume_requested = false;
            match self.attach_after_stop(link, program, true).await {
                Attached::Go(f) => return Back::Stream(f),
                Attached::Done => return Back::Done,
                Attached::Cancelled => return Back::Cancelled,
                Attached::Failed(msg) => return Back::Failed(msg),
                Attached::Offline(e) => {
                    *link = None;
                    why = say(&e);
                    continue;
                }
                Attached::Wait { next, note } => {
                    if self.resume_requested {
                        return Back::Stream(next);
                    }
                    let _ = self.control.send(Control::Run);
                    inner.set_state(id, JobState::Paused, None);
                    inner.note(id, Some(&format!("the machine is back: {note}")));
                    if let Some(a) = lock(&m.active).as_mut() {
                        a.waits_at = Some(next);
                    }
                    let r = self.wait_for_resume(link, next).await;
                    if let Some(a) = lock(&m.active).as_mut() {
                        a.waits_at = None;
                    }
                    match r {
                        Some(Ok(from)) => return Back::Stream(from),
                        Some(Err(())) => return Back::Cancelled,
                        None => {
                            why = "the link dropped again".into();
                            continue;
                        }
                    }
                }
            }
        }
    }

    /// Waits, paused, for the operator's resume (Ok with the unit to go on at), cancel
    /// (Err), or a link that drops again (None); keeps the machine's status fresh.
    async fn wait_for_resume(
        &mut self,
        link: &mut Option<Box<dyn MachineLink>>,
        next: usize,
    ) -> Option<Result<usize, ()>> {
        let (inner, m, id) = (self.inner, self.m, self.id);
        let mut poll = tokio::time::interval(STATUS_POLL);
        loop {
            tokio::select! {
                cmd = self.commands.recv() => {
                    let Some(cmd) = cmd else { return Some(Err(())) };
                    match cmd.request {
                        Request::Cancel => {
                            let _ = cmd.reply.send(Ok(()));
                            return Some(Err(()));
                        }
                        Request::Resume(line) => {
                            let from = match line {
                                None => next,
                                Some(l) if l >= 1 && l <= self.total => l - 1,
                                Some(l) => {
                                    let _ = cmd.reply.send(Err(SchedError::Conflict(format!(
                                        "job {id} has lines 1 to {}; it cannot resume from line {l}",
                                        self.total
                                    ))));
                                    continue;
                                }
                            };
                            let _ = self.control.send(Control::Run);
                            inner.note(id, None);
                            inner.set_state(id, JobState::Running, None);
                            let _ = cmd.reply.send(Ok(()));
                            return Some(Ok(from));
                        }
                        r => {
                            let reply = self.on_command(r);
                            let _ = cmd.reply.send(reply);
                        }
                    }
                }
                _ = poll.tick() => {
                    let l = link.as_mut()?;
                    match with_timeout(l.inquire()).await {
                        Ok(st) => inner.saw(m, st),
                        Err(e) if e.is_disconnect() => {
                            *link = None;
                            return None;
                        }
                        Err(_) => {}
                    }
                }
            }
        }
    }

    /// Runs a link's future (a stream, a reattach) to its end, journaling and passing on
    /// its events and the operator's commands.
    async fn drive<T>(
        &mut self,
        fut: futures::future::BoxFuture<'_, Result<T, LinkError>>,
        ev_rx: &mut mpsc::UnboundedReceiver<LinkEvent>,
        journal: &mut Journal,
    ) -> Result<T, LinkError> {
        let mut fut = fut;
        let result = loop {
            tokio::select! {
                biased;
                Some(ev) = ev_rx.recv() => {
                    let ev = with_tool_name(ev, &self.m.config.tools);
                    // a machine that stopped itself for the operator (a thread break, a
                    // program stop, an open door) pauses the job: `machlink resume JOB`
                    // continues it
                    if let LinkEvent::Status(MachineStatus {
                        state: DeviceState::NeedsOperator { reason },
                        ..
                    }) = &ev
                    {
                        if *self.control.borrow() == Control::Run {
                            let _ = self.on_command(Request::Pause);
                            self.inner.note(
                                self.id,
                                Some(&format!("needs operator: {reason}, then `machlink resume {}`", self.id)),
                            );
                        }
                    }
                    self.on_event(journal, ev);
                }
                Some(cmd) = self.commands.recv() => {
                    let r = self.on_command(cmd.request);
                    if cmd.request == Request::Shutdown && r.is_ok() {
                        self.shutdown_reply = Some(cmd.reply);
                    } else {
                        let _ = cmd.reply.send(r);
                    }
                }
                _ = sleep_until(journal.deadline()) => self.flush(journal),
                r = &mut fut => break r,
            }
        };
        drop(fut);
        while let Ok(ev) = ev_rx.try_recv() {
            self.on_event(journal, ev);
        }
        self.flush(journal);
        result
    }

    fn flush(&self, journal: &mut Journal) {
        if let Some((a, b)) = journal.take() {
            // the link's own journal may have recorded these with its last write
            if self.committed.load(AtomicOrdering::SeqCst) >= b {
                return;
            }
            if let Err(e) = self.inner.store.record_acks(self.id, a, b) {
                tracing::error!("job {}: cannot journal units {a}..{b}: {e}", self.id);
            }
            self.committed.fetch_max(b, AtomicOrdering::SeqCst);
        }
    }

    /// Journals every unit up to `acked` (a link that said completed or cancelled at
    /// `acked` has had them acknowledged).
    fn flush_to(&self, journal: &mut Journal, acked: usize) {
        if acked > journal.acked() {
            journal.ack(acked - 1, Instant::now());
        }
        self.flush(journal);
    }

    fn on_event(&mut self, journal: &mut Journal, ev: LinkEvent) {
        let (inner, m, id) = (self.inner, self.m, self.id);
        match ev {
            LinkEvent::Acked { unit } => {
                if journal.ack(unit, Instant::now()) {
                    self.flush(journal);
                }
                let _ = inner.events.send(Event::Progress {
                    job: id,
                    acked: journal.acked(),
                    total: self.total,
                });
            }
            LinkEvent::Status(mut s) => {
                // device text is untrusted: no control characters reach a log or a terminal
                s.detail = printable(&s.detail, MAX_TEXT);
                let held = matches!(
                    s.state,
                    DeviceState::Held | DeviceState::Idle | DeviceState::NeedsOperator { .. }
                );
                let _ = inner.events.send(Event::Status {
                    machine: m.config.name.clone(),
                    job: Some(id),
                    status: s.clone(),
                });
                inner.saw(m, s);
                if held {
                    // the machine stands still: a shutdown waiting for that may go on
                    if let Some(r) = self.shutdown_reply.take() {
                        let _ = r.send(Ok(()));
                    }
                }
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

    fn on_command(&mut self, request: Request) -> Result<(), SchedError> {
        let (inner, id) = (self.inner, self.id);
        let current = *self.control.borrow();
        match (request, current) {
            (Request::Override(patch), _) => {
                if let Some(why) = &self.overrides_refused {
                    return Err(SchedError::Refused(why.clone()));
                }
                let o = patch.apply(*self.overrides.borrow());
                o.check().map_err(SchedError::Conflict)?;
                let _ = self.overrides.send(o);
                *lock(&self.m.overrides) = o;
                let _ = inner.events.send(Event::Message {
                    machine: self.m.config.name.clone(),
                    job: Some(id),
                    text: format!(
                        "overrides: feed {} %, spindle {} %, rapids {} %",
                        o.feed, o.spindle, o.rapid
                    ),
                });
            }
            (Request::Shutdown, Control::Cancel) => {}
            (Request::Shutdown, _) => {
                let _ = self.control.send(Control::Hold);
            }
            (Request::Pause, Control::Run) => {
                let _ = self.control.send(Control::Hold);
                inner.set_state(id, JobState::Paused, None);
            }
            (Request::Resume(Some(_)), _) => {
                return Err(SchedError::Conflict(format!(
                    "job {id} is still streaming; only a stopped job restarts from a line (cancel it first)"
                )))
            }
            (Request::Resume(None), Control::Hold) => {
                let _ = self.control.send(Control::Run);
                // the operator's word: what the device then says goes on without asking again
                self.resume_requested = true;
                inner.note(id, None);
                inner.set_state(id, JobState::Running, None);
            }
            (Request::Resume(None), Control::Run) => {
                // asked while the daemon still asks the device: go on once it has answered
                if !self.resume_requested {
                    self.resume_requested = true;
                    if let Ok(Some(j)) = inner.store.job(id) {
                        if j.state == JobState::Interrupted {
                            inner.set_state(id, JobState::Running, None);
                        }
                    }
                }
            }
            (Request::Pause, Control::Hold) => {}
            (Request::Cancel, _) => {
                let _ = self.control.send(Control::Cancel);
                self.cancel_requested = true;
            }
            (_, Control::Cancel) => {
                return Err(SchedError::Conflict(format!("job {id} is being cancelled")))
            }
        }
        Ok(())
    }
}

/// A status question that cannot hang the worker: a device silent for five seconds is
/// taken as gone.
async fn with_timeout(
    f: futures::future::BoxFuture<'_, Result<MachineStatus, LinkError>>,
) -> Result<MachineStatus, LinkError> {
    let limit = Duration::from_secs(5);
    match tokio::time::timeout(limit, f).await {
        Ok(r) => r,
        Err(_) => Err(LinkError::Timeout(limit)),
    }
}

/// Opens the machine's link through its kind; a port still held by the link just closed
/// (its lock is released a moment later) is tried again for up to two seconds.
pub(super) async fn open_link(m: &Machine) -> Result<Box<dyn MachineLink>, LinkError> {
    let give_up = Instant::now() + Duration::from_secs(2);
    loop {
        let c = &m.config;
        match c.kind.open(&c.name, &c.settings, &m.device).await {
            Err(LinkError::PortBusy { .. }) if Instant::now() < give_up => {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            r => {
                if let Some(metrics) = m.metrics.get() {
                    match &r {
                        Ok(_) => metrics.link_opened(
                            &c.name,
                            m.opened.swap(true, std::sync::atomic::Ordering::Relaxed),
                        ),
                        Err(e) => metrics.link_failed(&c.name, e),
                    }
                }
                return r;
            }
        }
    }
}

async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d.into()).await,
        None => std::future::pending().await,
    }
}

/// Carries out an operator's operation between jobs.
pub(super) async fn operate(
    inner: &Inner,
    m: &Machine,
    link: &mut Option<Box<dyn MachineLink>>,
    op: &Operation,
    confirmed: bool,
) -> Result<String, SchedError> {
    let name = &m.config.name;
    if link.is_none() {
        match open_link(m).await {
            Ok(l) => *link = Some(l),
            Err(e) => {
                inner.offline(m, &say(&e));
                return Err(SchedError::Refused(format!(
                    "cannot reach machine `{name}`: {e}"
                )));
            }
        }
    }
    let Some(l) = link.as_mut() else {
        return Err(SchedError::Refused(format!(
            "cannot reach machine `{name}`"
        )));
    };
    if let Operation::Jog { .. } = op {
        let at = match with_timeout(l.inquire()).await {
            Ok(st) => {
                let p = st.position;
                inner.saw(m, st);
                Some(p)
            }
            Err(LinkError::Unsupported(_)) => None,
            Err(e) => {
                return Err(SchedError::Refused(format!(
                "machine `{name}` could not say where it stands, so the jog cannot be checked: {e}"
            )))
            }
        };
        super::jog::check(&m.config, op, at, confirmed).map_err(SchedError::Conflict)?;
    }
    let r = l.operate(op).await;
    if let Ok(st) = with_timeout(l.inquire()).await {
        inner.saw(m, st);
    }
    match r {
        Ok(said) => {
            tracing::info!("machine `{name}`: {said}");
            Ok(said)
        }
        Err(LinkError::Unsupported(why)) => Err(SchedError::Refused(format!(
            "machine `{name}` (link = \"{}\"): {why}",
            m.config.link
        ))),
        Err(e) => {
            if e.is_disconnect() {
                *link = None;
                inner.offline(m, &say(&e));
            }
            Err(SchedError::Refused(format!(
                "machine `{name}` could not {}: {e}",
                op.name()
            )))
        }
    }
}

/// Keeps an idle machine's status fresh: opens its link (with backoff while it cannot)
/// and asks the device what it is doing.
#[derive(Default)]
pub(super) struct StatusKeeper {
    next_try: Option<Instant>,
    backoff: Duration,
}

impl StatusKeeper {
    pub(super) async fn keep(
        &mut self,
        inner: &Inner,
        m: &Machine,
        link: &mut Option<Box<dyn MachineLink>>,
    ) {
        if inner.closing.load(Ordering::SeqCst) {
            return;
        }
        if link.is_none() {
            if self.next_try.is_some_and(|t| Instant::now() < t) {
                return;
            }
            match open_link(m).await {
                Ok(l) => {
                    *link = Some(l);
                    self.backoff = Duration::ZERO;
                    self.next_try = None;
                }
                Err(e) => {
                    inner.offline(m, &say(&e));
                    self.backoff = (self.backoff * 2)
                        .max(STATUS_POLL)
                        .min(Duration::from_secs(30));
                    self.next_try = Some(Instant::now() + self.backoff);
                    tracing::debug!("machine `{}` is offline: {e}", m.config.name);
                    return;
                }
            }
        }
        let Some(l) = link.as_mut() else { return };
        match with_timeout(l.inquire()).await {
            Ok(st) => inner.saw(m, st),
            Err(LinkError::Unsupported(_)) => {}
            Err(e) if e.is_disconnect() => {
                *link = None;
                inner.offline(m, &say(&e));
            }
            Err(e) => tracing::debug!("machine `{}`: {e}", m.config.name),
        }
    }
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

/// A device that asks for a tool by number alone (a Modbus tool block carries only the
/// number) is told the tool's name from the machine's `tools` table, as `machines` and the
/// job's note show it: `load T2 (6 mm flat end mill)`.
fn with_tool_name(ev: LinkEvent, tools: &[crate::core::machine::ToolConfig]) -> LinkEvent {
    use machlink_protocols::{MachineStatus, OperatorReason};
    match ev {
        LinkEvent::Status(MachineStatus {
            state:
                DeviceState::NeedsOperator {
                    reason: OperatorReason::LoadTool { number, name },
                },
            detail,
            position,
            feed,
        }) if name.is_empty() => {
            let name = tools
                .iter()
                .find(|t| t.number == number)
                .map(|t| match &t.name {
                    Some(n) => n.clone(),
                    None => format!("{} mm", t.diameter),
                })
                .unwrap_or_default();
            LinkEvent::Status(MachineStatus {
                state: DeviceState::NeedsOperator {
                    reason: OperatorReason::LoadTool { number, name },
                },
                detail,
                position,
                feed,
            })
        }
        ev => ev,
    }
}
