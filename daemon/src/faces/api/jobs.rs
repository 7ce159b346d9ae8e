//! The API's job and machine routes: list machines and jobs, plan and queue a job, steer it
//! (pause, resume, cancel, overrides), follow its events, and the operator's operations at a
//! machine between jobs (unlock, home, jog).

use crate::core::intake::JobSpec;
use crate::core::scheduler::{Event, Scheduler};
use crate::core::store::{JobId, NewJob};
use crate::faces::api::error::{bad, ApiError};
use crate::faces::api::gate::open_jobs;
use crate::faces::api::state::AppState;
use crate::services::access::{Acted, Principal};
use axum::body::Body;
use axum::extract::{Extension, Path, Request, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use tokio::sync::broadcast;

/// The job and machine routes.
pub fn routes() -> Router<AppState> {
    Router::new()
        .route("/machines", get(machines))
        .route("/jobs", get(jobs).post(submit))
        .route("/jobs/{id}", get(job))
        .route("/jobs/{id}/pause", post(pause))
        .route("/jobs/{id}/resume", post(resume).get(resume_preview))
        .route("/jobs/{id}/override", post(override_job))
        .route("/machines/{name}/{op}", post(operate))
        .route("/jobs/{id}/cancel", post(cancel))
        .route("/jobs/{id}/events", get(events))
}

async fn machines(State(st): State<AppState>) -> Result<Response, ApiError> {
    Ok(Json(st.sched.machines()?).into_response())
}

async fn jobs(State(st): State<AppState>) -> Result<Response, ApiError> {
    Ok(Json(st.sched.jobs()?).into_response())
}

fn job_id(raw: &str) -> Result<JobId, ApiError> {
    raw.parse()
        .map_err(|_| bad(format!("`{raw}` is not a job number")))
}

async fn job(State(st): State<AppState>, Path(id): Path<String>) -> Result<Response, ApiError> {
    Ok(Json(st.sched.job(job_id(&id)?)?).into_response())
}

async fn pause(State(st): State<AppState>, Path(id): Path<String>) -> Result<Response, ApiError> {
    Ok(Json(st.sched.pause(job_id(&id)?).await?).into_response())
}

/// The optional body of `POST /jobs/{id}/resume`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResumeRequest {
    /// Restart a stopped job from this program line (1-based) instead of its resume point.
    #[serde(default)]
    pub from_line: Option<usize>,
}

async fn resume(
    State(st): State<AppState>,
    Path(id): Path<String>,
    req: Request,
) -> Result<Response, ApiError> {
    let id = job_id(&id)?;
    let body = crate::faces::api::limits::json_body(req).await?;
    let req: ResumeRequest = if body.iter().all(|b| b.is_ascii_whitespace()) {
        ResumeRequest::default()
    } else {
        serde_json::from_slice(&body)
            .map_err(|e| bad(format!("the resume request is not valid: {e}")))?
    };
    let job = match req.from_line {
        Some(line) => st.sched.resume_from_line(id, line).await?,
        None => st.sched.resume(id).await?,
    };
    Ok(Json(job).into_response())
}

async fn cancel(State(st): State<AppState>, Path(id): Path<String>) -> Result<Response, ApiError> {
    Ok(Json(st.sched.cancel(job_id(&id)?).await?).into_response())
}

async fn submit(
    State(st): State<AppState>,
    Extension(who): Extension<Principal>,
    req: Request,
) -> Result<Response, ApiError> {
    let body = crate::faces::api::limits::json_body(req).await?;
    let spec: JobSpec = serde_json::from_slice(&body)
        .map_err(|e| bad(format!("the request is not a valid job: {e}")))?;
    drop(body);
    let Some(name) = spec.machine.clone() else {
        return Err(bad("the job names no machine (give \"machine\")"));
    };
    st.sched.machine_config(&name)?;
    st.access
        .check_operate(&who, &name, &open_jobs(&st.sched))?;
    submit_spec(&st, spec).await
}

/// Plans `spec` (in a forked child: a crash fails this job only), checks the program's size,
/// stores and queues it: 201 and the job.
pub async fn submit_spec(st: &AppState, spec: JobSpec) -> Result<Response, ApiError> {
    let Some(name) = spec.machine.clone() else {
        return Err(bad("the job names no machine (give \"machine\")"));
    };
    let machine = st.sched.machine_config(&name)?.clone();
    let file_name = spec.input.file_name.clone();
    let params = crate::core::intake::params_of(&spec);
    let planning = std::time::Instant::now();
    let planned = {
        let _turn = st.plans.acquire().await.map_err(|e| {
            ApiError(
                StatusCode::SERVICE_UNAVAILABLE,
                format!("the daemon is stopping: {e}"),
            )
        })?;
        crate::core::planner::plan_isolated(
            spec,
            machine,
            st.planner,
            crate::core::planner::PLAN_TIME_LIMIT,
        )
        .await
    };
    crate::services::memory::give_back();
    let planned = planned?;
    if planned.program.len() > crate::faces::api::limits::MAX_PROGRAM_UNITS {
        return Err(ApiError(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!(
                "the program has {} units, more than the daemon's limit of {}",
                planned.program.len(),
                crate::faces::api::limits::MAX_PROGRAM_UNITS
            ),
        ));
    }
    let planning = planning.elapsed();
    let rec = st.sched.submit(NewJob {
        machine: name.clone(),
        op: planned.operation,
        file_name,
        params,
        program: planned.program,
    })?;
    if let Some(m) = st.sched.metrics() {
        m.job_submitted(&rec.machine, planning);
    }
    let mut resp = (StatusCode::CREATED, Json(&rec)).into_response();
    resp.extensions_mut().insert(Acted {
        machine: Some(rec.machine.clone()),
        job: Some(rec.id),
        note: None,
    });
    Ok(resp)
}

/// `GET /jobs/{id}/events`: the job's current state first, then every event about it,
/// one JSON object per line, until it reaches a final state.
async fn events(State(st): State<AppState>, Path(id): Path<String>) -> Result<Response, ApiError> {
    let id = job_id(&id)?;
    // subscribe before reading the state, so nothing falls between them
    let rx = st.sched.subscribe();
    let j = st.sched.job(id)?;
    let first = Event::state_of(&j);
    struct S {
        rx: broadcast::Receiver<Event>,
        sched: Scheduler,
        first: Option<Event>,
        done: bool,
        id: JobId,
    }
    let s = S {
        rx,
        sched: st.sched.clone(),
        first: Some(first),
        done: false,
        id,
    };
    let line = |e: &Event| {
        let mut v = serde_json::to_vec(e).unwrap_or_default();
        v.push(b'\n');
        Ok::<_, std::io::Error>(axum::body::Bytes::from(v))
    };
    let stream = futures::stream::unfold(s, move |mut s| async move {
        if s.done {
            return None;
        }
        if let Some(f) = s.first.take() {
            // a job that is already over gets its state and the stream ends
            if matches!(&f, Event::State { state, .. } if state.is_final()) {
                s.done = true;
            }
            return Some((line(&f), s));
        }
        loop {
            match s.rx.recv().await {
                Ok(ev) if ev.job() == Some(s.id) => {
                    if let Event::State { state, .. } = &ev {
                        s.done = state.is_final();
                    }
                    return Some((line(&ev), s));
                }
                Ok(_) => continue,
                Err(broadcast::error::RecvError::Lagged(_)) => {
                    // too slow a watcher: skip ahead and tell it where the job is now
                    let j = s.sched.job(s.id).ok()?;
                    s.done = j.state.is_final();
                    let ev = Event::state_of(&j);
                    return Some((line(&ev), s));
                }
                Err(broadcast::error::RecvError::Closed) => return None,
            }
        }
    });
    Response::builder()
        .header(header::CONTENT_TYPE, "application/x-ndjson")
        .body(Body::from_stream(stream))
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))
}

/// The query of `GET /jobs/{id}/resume`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PreviewQuery {
    #[serde(default)]
    pub from_line: Option<usize>,
}

async fn resume_preview(
    State(st): State<AppState>,
    Path(id): Path<String>,
    query: Result<axum::extract::Query<PreviewQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let axum::extract::Query(q) =
        query.map_err(|e| bad(format!("the resume question is not valid: {e}")))?;
    Ok(Json(st.sched.resume_preview(job_id(&id)?, q.from_line)?).into_response())
}

/// The answer to `POST /jobs/{id}/override`: the job and the overrides now in force.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OverrideAnswer {
    pub job: crate::core::store::JobRecord,
    pub overrides: machlink_protocols::Overrides,
}

async fn override_job(
    State(st): State<AppState>,
    Path(id): Path<String>,
    body: axum::body::Bytes,
) -> Result<Response, ApiError> {
    let patch: crate::core::scheduler::OverridePatch = serde_json::from_slice(&body)
        .map_err(|e| bad(format!("the override request is not valid: {e}")))?;
    let (job, overrides) = st.sched.override_job(job_id(&id)?, patch).await?;
    Ok(Json(OverrideAnswer { job, overrides }).into_response())
}

/// The answer to `POST /machines/{name}/unlock|home|jog`: what the machine said.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OperateAnswer {
    pub machine: String,
    pub said: String,
}

async fn operate(
    State(st): State<AppState>,
    Path((name, op)): Path<(String, String)>,
    body: axum::body::Bytes,
) -> Result<Response, ApiError> {
    use machlink_protocols::Operation;
    let op = match op.as_str() {
        "unlock" => Operation::Unlock,
        "home" => Operation::Home,
        "jog" => {
            #[derive(Deserialize)]
            #[serde(deny_unknown_fields)]
            struct Jog {
                #[serde(default)]
                x: Option<f64>,
                #[serde(default)]
                y: Option<f64>,
                #[serde(default)]
                z: Option<f64>,
                feed: f64,
            }
            let j: Jog = serde_json::from_slice(&body)
                .map_err(|e| bad(format!("the jog request is not valid: {e}")))?;
            Operation::Jog {
                x: j.x,
                y: j.y,
                z: j.z,
                feed: j.feed,
            }
        }
        other => {
            return Err(bad(format!(
                "no such operation `{other}` (a machine takes unlock, home and jog)"
            )))
        }
    };
    let said = st.sched.operate(&name, op).await?;
    Ok(Json(OperateAnswer {
        machine: name,
        said,
    })
    .into_response())
}
