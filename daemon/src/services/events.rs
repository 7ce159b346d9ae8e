//! Every job's events as one stream: which machine each event is about (for
//! `GET /events?machine=M`, served by `faces::api::service`), and the log lines of each
//! job's start, pause, end and fault.

use crate::core::scheduler::{Event, Scheduler};
use crate::core::store::{JobId, JobState};
use std::collections::HashMap;
use tokio::sync::broadcast;

/// Which machine an event is about; progress events name only their job, whose machine is
/// remembered from its state events (or asked of the store).
pub struct MachineOf {
    pub sched: Scheduler,
    jobs: HashMap<JobId, String>,
}

impl MachineOf {
    pub fn new(sched: Scheduler) -> MachineOf {
        MachineOf {
            sched,
            jobs: HashMap::new(),
        }
    }

    pub fn of(&mut self, ev: &Event) -> Option<String> {
        match ev {
            Event::State { job, machine, .. } => {
                self.jobs.insert(*job, machine.clone());
                Some(machine.clone())
            }
            Event::Status { machine, .. } | Event::Message { machine, .. } => Some(machine.clone()),
            Event::Progress { job, .. } => {
                if let Some(m) = self.jobs.get(job) {
                    return Some(m.clone());
                }
                let m = self.sched.job(*job).ok()?.machine;
                self.jobs.insert(*job, m.clone());
                Some(m)
            }
        }
    }
}

/// Logs each job's life with its job, machine and unit: queued, started (and from which
/// unit), paused, resumed, completed, failed, cancelled, interrupted.
pub async fn log_jobs(mut rx: broadcast::Receiver<Event>) {
    let mut last: HashMap<JobId, JobState> = HashMap::new();
    loop {
        let ev = match rx.recv().await {
            Ok(ev) => ev,
            Err(broadcast::error::RecvError::Lagged(_)) => continue,
            Err(broadcast::error::RecvError::Closed) => return,
        };
        let Event::State {
            job,
            machine,
            state,
            acked,
            total,
            error,
        } = ev
        else {
            continue;
        };
        let before = last.insert(job, state);
        let unit = acked;
        match state {
            JobState::Queued => {
                tracing::info!(job, %machine, unit, total, "job queued")
            }
            JobState::Running if before == Some(JobState::Paused) => {
                tracing::info!(job, %machine, unit, total, "job resumed")
            }
            JobState::Running => tracing::info!(job, %machine, unit, total, "job started"),
            JobState::Paused => tracing::info!(job, %machine, unit, total, "job paused"),
            JobState::Completed => tracing::info!(job, %machine, unit, total, "job completed"),
            JobState::Cancelled => tracing::info!(job, %machine, unit, total, "job cancelled"),
            JobState::Failed => tracing::warn!(
                job,
                %machine,
                unit,
                total,
                error = error.as_deref().unwrap_or(""),
                "job failed"
            ),
            JobState::Interrupted => tracing::warn!(
                job,
                %machine,
                unit,
                total,
                error = error.as_deref().unwrap_or(""),
                "job interrupted"
            ),
        }
        if state.is_final() {
            last.remove(&job);
        }
    }
}
