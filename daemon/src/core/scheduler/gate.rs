//! Whether a queued job may start: never on a machine that holds another job stopped
//! mid-program (the machine stands where that job left it, and the store says so) or that
//! is held or waits for the operator. Such a job waits in the queue, in order, with a note
//! saying why, and starts by itself once the machine is free; a resume of a job that ran
//! before is the operator's word and goes at once.

use super::run::{self, Mode, StatusKeeper};
use super::{lock, Inner, Machine};
use crate::core::store::{JobId, JobState};
use machlink_protocols::kind::MachineLink;
use machlink_protocols::DeviceState;
use std::collections::VecDeque;

/// The jobs a machine's worker took off its queue that could not start yet, oldest first.
#[derive(Default)]
pub(super) struct Waiting {
    jobs: VecDeque<JobId>,
}

impl Waiting {
    /// Takes job `id` off the queue: runs it when the machine may start it, else keeps it.
    pub(super) async fn take(
        &mut self,
        inner: &Inner,
        m: &Machine,
        link: &mut Option<Box<dyn MachineLink>>,
        status: &mut StatusKeeper,
        id: JobId,
    ) {
        let Ok(Some(job)) = inner.store.job(id) else {
            return;
        };
        if job.state != JobState::Queued {
            return;
        }
        // an operator's resume of a job that ran before (it asks the device first)
        if job.started_ms.is_some() {
            run::run_job(inner, m, link, id, Mode::Run).await;
            return;
        }
        self.jobs.push_back(id);
        self.retry(inner, m, link, status).await;
    }

    /// Starts the waiting jobs, in order, while the machine may start them.
    pub(super) async fn retry(
        &mut self,
        inner: &Inner,
        m: &Machine,
        link: &mut Option<Box<dyn MachineLink>>,
        status: &mut StatusKeeper,
    ) {
        while let Some(&id) = self.jobs.front() {
            match inner.store.job(id) {
                Ok(Some(j)) if j.state == JobState::Queued => {}
                // cancelled while it waited
                _ => {
                    self.jobs.pop_front();
                    continue;
                }
            }
            match why_not_now(inner, m, link, status, id).await {
                Some(why) => {
                    inner.note(id, Some(&why));
                    return;
                }
                None => {
                    self.jobs.pop_front();
                    run::run_job(inner, m, link, id, Mode::Run).await;
                }
            }
        }
    }
}

/// Why job `id` may not start on machine `m` now, in the operator's words; None when it may.
async fn why_not_now(
    inner: &Inner,
    m: &Machine,
    link: &mut Option<Box<dyn MachineLink>>,
    status: &mut StatusKeeper,
    id: JobId,
) -> Option<String> {
    let name = &m.config.name;
    for state in [JobState::Interrupted, JobState::Paused] {
        let stopped = inner.store.jobs_in(state).unwrap_or_default();
        if let Some(j) = stopped.iter().find(|j| j.machine == *name && j.id != id) {
            return Some(format!(
                "waits: machine `{name}` holds job {} ({}, {} of {} units done), and stands where it left off; `machlink resume {}` or `machlink cancel {}` first",
                j.id, j.state, j.acked_units, j.total_units, j.id, j.id
            ));
        }
    }
    // what the device says now (kinds that cannot be asked keep their last report)
    status.keep(inner, m, link).await;
    let seen = lock(&m.status).status.clone();
    match seen.state {
        DeviceState::Held => Some(format!(
            "waits: machine `{name}` is held ({}); it starts once the machine is released",
            seen.detail
        )),
        DeviceState::NeedsOperator { reason } => Some(format!(
            "waits: machine `{name}` needs the operator ({reason}); it starts once that is cleared"
        )),
        _ => None,
    }
}
