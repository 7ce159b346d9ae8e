//! Every job's events as one stream: `GET /events[?machine=M]` for `machlink events`,
//! the service routes beside the API (`/metrics`, `/events`), and the log lines of each
//! job's start, pause, end and fault.

use crate::core::scheduler::{Event, Scheduler};
use crate::core::store::{JobId, JobState};
use crate::services::metrics::Metrics;
use axum::body::Body;
use axum::extract::{Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use serde::Deserialize;
use std::collections::HashMap;
use std::sync::Arc;
use tokio::sync::broadcast;

/// What the service routes need.
#[derive(Clone)]
pub struct Service {
    pub sched: Scheduler,
    pub metrics: Arc<Metrics>,
}

/// `GET /metrics` and `GET /events`, to be served beside the API's routes.
pub fn router(service: Service) -> Router {
    Router::new()
        .route("/metrics", get(metrics))
        .route("/events", get(events))
        .with_state(service)
}

/// `GET /metrics` alone: what `serve --metrics-listen ADDR` serves (read-only).
pub fn metrics_router(service: Service) -> Router {
    Router::new()
        .route("/metrics", get(metrics))
        .fallback(|| async {
            (
                StatusCode::NOT_FOUND,
                "only /metrics is served on this address\n",
            )
        })
        .with_state(service)
}

async fn metrics(State(s): State<Service>) -> Response {
    let text = s.metrics.render(&s.sched);
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        text,
    )
        .into_response()
}

/// The query of `GET /events`.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EventsQuery {
    /// Only this machine's events.
    pub machine: Option<String>,
}

/// Which machine an event is about; progress events name only their job, whose machine is
/// remembered from its state events (or asked of the store).
struct MachineOf {
    sched: Scheduler,
    jobs: HashMap<JobId, String>,
}

impl MachineOf {
    fn of(&mut self, ev: &Event) -> Option<String> {
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

async fn events(
    State(s): State<Service>,
    query: Result<Query<EventsQuery>, axum::extract::rejection::QueryRejection>,
) -> Response {
    let Ok(Query(q)) = query else {
        return (
            StatusCode::BAD_REQUEST,
            axum::Json(crate::faces::api::ErrorBody {
                error: "GET /events takes only ?machine=NAME".into(),
            }),
        )
            .into_response();
    };
    if let Some(m) = &q.machine {
        if let Err(e) = s.sched.machine_config(m) {
            return crate::faces::api::ApiError::from(e).into_response();
        }
    }
    let rx = s.sched.subscribe();
    let stream = futures::stream::unfold(
        (
            rx,
            MachineOf {
                sched: s.sched.clone(),
                jobs: HashMap::new(),
            },
            q.machine,
            Vec::<Event>::new(),
        ),
        |(mut rx, mut of, filter, mut pending)| async move {
            loop {
                if let Some(ev) = pending.pop() {
                    return Some((line(&ev), (rx, of, filter, pending)));
                }
                let ev = match rx.recv().await {
                    Ok(ev) => ev,
                    Err(broadcast::error::RecvError::Lagged(_)) => {
                        // too slow a follower: tell it where every unfinished job is now
                        let jobs = of.sched.jobs().unwrap_or_default();
                        pending = jobs
                            .iter()
                            .rev()
                            .filter(|j| !j.state.is_final())
                            .filter(|j| filter.as_ref().is_none_or(|m| *m == j.machine))
                            .map(Event::state_of)
                            .collect();
                        continue;
                    }
                    Err(broadcast::error::RecvError::Closed) => return None,
                };
                let machine = of.of(&ev);
                if filter.is_none() || machine == filter {
                    return Some((line(&ev), (rx, of, filter, pending)));
                }
            }
        },
    );
    Response::builder()
        .header(header::CONTENT_TYPE, "application/x-ndjson")
        .body(Body::from_stream(stream))
        .unwrap_or_else(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response())
}

fn line(e: &Event) -> Result<axum::body::Bytes, std::io::Error> {
    let mut v = serde_json::to_vec(e).map_err(std::io::Error::other)?;
    v.push(b'\n');
    Ok(axum::body::Bytes::from(v))
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
