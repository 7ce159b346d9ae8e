//! Prometheus metrics of one daemon: jobs by state, units streamed and acknowledged, link
//! errors, reconnects, RX-buffer overflows, queue depth, planning time and link throughput,
//! per machine, rendered in the Prometheus text format for `GET /metrics`.
//!
//! Each daemon has its own recorder (the `metrics` crate's facade used with a local
//! recorder), so several daemons in one process — tests — never mix their figures. Facts
//! come from three places: the scheduler's event broadcast (job states, acknowledgements),
//! two hooks in the scheduler (a link opened, a link failed) and the intake (planning time).
//! Gauges that the store or the devices know (jobs by state, queue depth, RX overflows)
//! are read when the metrics are scraped.

use crate::core::scheduler::{Event, Scheduler};
use crate::core::store::{JobId, JobState};
use machlink_protocols::LinkError;
use metrics::{counter, gauge, histogram, with_local_recorder};
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusRecorder};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::broadcast;

/// Metric names, one place (docs/install.md lists them for dashboards).
pub mod name {
    pub const JOBS: &str = "machlink_jobs";
    pub const JOBS_SUBMITTED: &str = "machlink_jobs_submitted_total";
    pub const JOBS_STARTED: &str = "machlink_jobs_started_total";
    pub const JOBS_FINISHED: &str = "machlink_jobs_finished_total";
    pub const UNITS_STREAMED: &str = "machlink_units_streamed_total";
    pub const UNITS_ACKED: &str = "machlink_units_acked_total";
    pub const LINK_ERRORS: &str = "machlink_link_errors_total";
    pub const LINK_RECONNECTS: &str = "machlink_link_reconnects_total";
    pub const RX_OVERFLOWS: &str = "machlink_rx_overflows_total";
    pub const QUEUE_DEPTH: &str = "machlink_queue_depth";
    pub const PLANNING_SECONDS: &str = "machlink_planning_seconds";
    pub const LINK_UNITS_PER_SECOND: &str = "machlink_link_units_per_second";
    pub const WEBHOOK_DELIVERIES: &str = "machlink_webhook_deliveries_total";
}

/// Every state a job can be in, for the `machlink_jobs` gauge (a state with no job reads 0).
const STATES: [JobState; 7] = [
    JobState::Queued,
    JobState::Running,
    JobState::Paused,
    JobState::Completed,
    JobState::Failed,
    JobState::Cancelled,
    JobState::Interrupted,
];

/// One daemon's metrics.
pub struct Metrics {
    recorder: PrometheusRecorder,
    jobs: Mutex<HashMap<JobId, Tracked>>,
}

/// What the metrics remember of a job between its events.
struct Tracked {
    machine: String,
    state: JobState,
    /// Units acknowledged as last heard.
    acked: usize,
    /// When the current uninterrupted run began and at which unit.
    run: Option<(Instant, usize)>,
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics::new()
    }
}

/// The scheduler's counters are these metrics.
impl crate::core::scheduler::Counters for Metrics {
    fn link_opened(&self, machine: &str, reopened: bool) {
        Metrics::link_opened(self, machine, reopened)
    }
    fn link_failed(&self, machine: &str, error: &LinkError) {
        Metrics::link_failed(self, machine, error)
    }
    fn job_submitted(&self, machine: &str, planning: Duration) {
        Metrics::job_submitted(self, machine, planning)
    }
}

impl Metrics {
    pub fn new() -> Metrics {
        let planning = [
            0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0,
        ];
        let throughput = [
            1.0, 5.0, 10.0, 25.0, 50.0, 100.0, 250.0, 500.0, 1000.0, 2500.0, 5000.0,
        ];
        let builder = PrometheusBuilder::new()
            .set_buckets_for_metric(Matcher::Full(name::PLANNING_SECONDS.into()), &planning)
            .and_then(|b| {
                b.set_buckets_for_metric(
                    Matcher::Full(name::LINK_UNITS_PER_SECOND.into()),
                    &throughput,
                )
            });
        // the bucket lists above are constant and non-empty, so the builder cannot refuse them
        let builder = builder.unwrap_or_else(|_| PrometheusBuilder::new());
        Metrics {
            recorder: builder.build_recorder(),
            jobs: Mutex::new(HashMap::new()),
        }
    }

    fn record<T>(&self, f: impl FnOnce() -> T) -> T {
        with_local_recorder(&self.recorder, f)
    }

    /// A job was planned (taking `planning`) and stored on `machine`.
    pub fn job_submitted(&self, machine: &str, planning: Duration) {
        let m = machine.to_string();
        self.record(|| {
            counter!(name::JOBS_SUBMITTED, "machine" => m.clone()).increment(1);
            histogram!(name::PLANNING_SECONDS, "machine" => m).record(planning.as_secs_f64());
        });
    }

    /// The scheduler opened a machine's link; `reopened` when an earlier link had broken.
    pub fn link_opened(&self, machine: &str, reopened: bool) {
        if reopened {
            let m = machine.to_string();
            self.record(|| counter!(name::LINK_RECONNECTS, "machine" => m).increment(1));
        }
    }

    /// A machine's link could not open or failed while streaming.
    pub fn link_failed(&self, machine: &str, error: &LinkError) {
        let kind = match error {
            LinkError::Open { .. } => "open",
            LinkError::PortBusy { .. } => "port_busy",
            LinkError::Io(_) => "io",
            LinkError::Rejected { .. } => "rejected",
            LinkError::Alarm { .. } => "alarm",
            LinkError::Timeout(_) => "timeout",
            LinkError::Protocol(_) => "protocol",
            LinkError::Unsupported(_) => "unsupported",
            LinkError::Journal(_) => "journal",
            LinkError::Program(_) => "program",
        };
        let m = machine.to_string();
        self.record(|| counter!(name::LINK_ERRORS, "machine" => m, "error" => kind).increment(1));
    }

    /// A webhook delivery ended (`ok`, `failed` after its retries, or `dropped` when its
    /// queue was full).
    pub fn webhook_delivery(&self, result: &'static str) {
        self.record(|| counter!(name::WEBHOOK_DELIVERIES, "result" => result).increment(1));
    }

    /// Takes one scheduler event into account.
    pub fn observe(&self, ev: &Event) {
        let mut jobs = self.jobs.lock().unwrap_or_else(|p| p.into_inner());
        match ev {
            Event::State {
                job,
                machine,
                state,
                acked,
                total,
                ..
            } => {
                let t = jobs.entry(*job).or_insert_with(|| Tracked {
                    machine: machine.clone(),
                    state: JobState::Queued,
                    acked: *acked,
                    run: None,
                });
                let before = t.state;
                let m = machine.clone();
                self.record(|| {
                    if *state == JobState::Running && before != JobState::Paused {
                        counter!(name::JOBS_STARTED, "machine" => m.clone()).increment(1);
                        counter!(name::UNITS_STREAMED, "machine" => m.clone())
                            .increment(total.saturating_sub(*acked) as u64);
                    }
                    if state.is_final() && !before.is_final() {
                        counter!(name::JOBS_FINISHED, "machine" => m.clone(), "state" => state.as_str())
                            .increment(1);
                    }
                });
                self.units(t, *acked);
                match state {
                    JobState::Running => t.run = Some((Instant::now(), t.acked)),
                    _ => self.end_run(t),
                }
                t.state = *state;
                if state.is_final() {
                    jobs.remove(job);
                }
            }
            Event::Progress { job, acked, .. } => {
                if let Some(t) = jobs.get_mut(job) {
                    self.units(t, *acked);
                }
            }
            Event::Status { .. } | Event::Message { .. } => {}
        }
    }

    /// Counts the units acknowledged since last heard.
    fn units(&self, t: &mut Tracked, acked: usize) {
        if acked > t.acked {
            let n = (acked - t.acked) as u64;
            let m = t.machine.clone();
            self.record(|| counter!(name::UNITS_ACKED, "machine" => m).increment(n));
        }
        t.acked = t.acked.max(acked);
    }

    /// Ends an uninterrupted run: its units per second go into the throughput histogram.
    fn end_run(&self, t: &mut Tracked) {
        if let Some((start, from)) = t.run.take() {
            let secs = start.elapsed().as_secs_f64();
            let units = t.acked.saturating_sub(from);
            if units > 0 && secs > 0.0 {
                let m = t.machine.clone();
                self.record(|| {
                    histogram!(name::LINK_UNITS_PER_SECOND, "machine" => m)
                        .record(units as f64 / secs)
                });
            }
        }
    }

    /// The metrics in the Prometheus text format, with the gauges the store and the
    /// devices know read now.
    pub fn render(&self, sched: &Scheduler) -> String {
        if let Ok(machines) = sched.machines() {
            let counts = sched.store().count_by_machine_state().unwrap_or_default();
            self.record(|| {
                for m in &machines {
                    gauge!(name::QUEUE_DEPTH, "machine" => m.name.clone()).set(m.queued as f64);
                    for s in STATES {
                        let n = counts
                            .get(&(m.name.clone(), s.as_str()))
                            .copied()
                            .unwrap_or_default();
                        gauge!(name::JOBS, "machine" => m.name.clone(), "state" => s.as_str())
                            .set(n as f64);
                    }
                    if let Some(n) = sched
                        .device_any(&m.name)
                        .and_then(crate::core::registry::rx_overflows)
                    {
                        counter!(name::RX_OVERFLOWS, "machine" => m.name.clone()).absolute(n);
                    }
                }
            });
        }
        self.recorder.handle().render()
    }

    /// Follows the scheduler's events until it stops. A follower that fell behind (the
    /// broadcast dropped events) catches up from the next event of each job: acknowledged
    /// units are absolute in every event, so none is lost or counted twice.
    pub async fn follow(self: Arc<Self>, mut rx: broadcast::Receiver<Event>) {
        loop {
            match rx.recv().await {
                Ok(ev) => self.observe(&ev),
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tracing::debug!("the metrics missed {n} events; catching up");
                }
                Err(broadcast::error::RecvError::Closed) => return,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(job: JobId, state: JobState, acked: usize) -> Event {
        Event::State {
            job,
            machine: "mill".into(),
            state,
            acked,
            total: 10,
            error: None,
        }
    }

    #[test]
    fn units_are_counted_once_across_pause_and_a_lost_progress_event() {
        let m = Metrics::new();
        m.observe(&state(1, JobState::Queued, 0));
        m.observe(&state(1, JobState::Running, 0));
        m.observe(&Event::Progress {
            job: 1,
            acked: 3,
            total: 10,
        });
        m.observe(&state(1, JobState::Paused, 4));
        m.observe(&state(1, JobState::Running, 4));
        // progress 5..9 lost: the final state carries the absolute count
        m.observe(&state(1, JobState::Completed, 10));
        let text = m.recorder.handle().render();
        assert!(
            text.contains("machlink_units_acked_total{machine=\"mill\"} 10"),
            "{text}"
        );
        assert!(
            text.contains("machlink_units_streamed_total{machine=\"mill\"} 10"),
            "{text}"
        );
        assert!(
            text.contains("machlink_jobs_started_total{machine=\"mill\"} 1"),
            "{text}"
        );
        assert!(
            text.contains("machlink_jobs_finished_total{machine=\"mill\",state=\"completed\"} 1"),
            "{text}"
        );
    }
}
