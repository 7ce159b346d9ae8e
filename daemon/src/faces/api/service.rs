//! The service routes beside the API: `GET /metrics` (Prometheus text) and `GET /events`
//! (every job's events as newline-delimited JSON, `?machine=M` for one machine's), for
//! `machlink events` and scrapers; `serve --metrics-listen ADDR` serves `/metrics` alone.

use crate::core::scheduler::{Event, Scheduler};
use crate::faces::api::error::{ApiError, ErrorBody};
use crate::services::events::MachineOf;
use crate::services::metrics::Metrics;
use axum::body::Body;
use axum::extract::{Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use serde::Deserialize;
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

async fn events(
    State(s): State<Service>,
    query: Result<Query<EventsQuery>, axum::extract::rejection::QueryRejection>,
) -> Response {
    let Ok(Query(q)) = query else {
        return (
            StatusCode::BAD_REQUEST,
            axum::Json(ErrorBody {
                error: "GET /events takes only ?machine=NAME".into(),
            }),
        )
            .into_response();
    };
    if let Some(m) = &q.machine {
        if let Err(e) = s.sched.machine_config(m) {
            return ApiError::from(e).into_response();
        }
    }
    let rx = s.sched.subscribe();
    let stream = futures::stream::unfold(
        (
            rx,
            MachineOf::new(s.sched.clone()),
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
