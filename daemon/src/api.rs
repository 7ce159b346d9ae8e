//! The daemon's HTTP API (JSON), served on a Unix socket, or on TCP behind a bearer token.
//!
//! | request | does |
//! |---|---|
//! | `GET /machines` | the machines, their queues and last status |
//! | `GET /jobs`, `GET /jobs/{id}` | jobs as the store holds them |
//! | `POST /jobs` | plan a job and queue it on its machine (body: a [`JobSpec`] naming the machine) |
//! | `POST /jobs/{id}/pause`, `/resume`, `/cancel` | steer a job |
//! | `GET /jobs/{id}/resume` | what a resume would do (`?from_line=N`), to confirm first |
//! | `POST /jobs/{id}/override` | feed, spindle and rapid overrides of a running job |
//! | `POST /machines/{name}/unlock`, `/home`, `/jog` | the operator at the machine, between jobs |
//! | `GET /jobs/{id}/events` | newline-delimited JSON events until the job ends |
//! | `POST /machines/{name}/gcode?file_name=F` | a G-code file streamed into the store (`upload`) |
//! | `POST /machines/{name}/lock`, `/release`, `GET /locks` | the control lock (`access_api`) |
//! | `GET /whoami`, `POST /access/reload` | the caller's role; reload the access table |
//!
//! Who may call what is the route table of `access` (`access::ROUTES`); every route added
//! here needs its line there. Refusals are 4xx with `{ "error": "one sentence" }`.

use crate::access::{Access, Acted, Gate, Principal};
use crate::intake::{IntakeError, JobSpec};
use crate::planner::{PlanError, PlanFn};
use crate::scheduler::{Event, SchedError, Scheduler};
use crate::store::{JobId, NewJob};
use axum::body::Body;
use axum::extract::{Extension, Path, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use tokio::sync::broadcast;

/// A refusal: status and one sentence.
#[derive(Debug)]
pub struct ApiError(pub StatusCode, pub String);

#[derive(Serialize, Deserialize)]
pub struct ErrorBody {
    pub error: String,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.0, Json(ErrorBody { error: self.1 })).into_response()
    }
}

impl From<SchedError> for ApiError {
    fn from(e: SchedError) -> Self {
        let status = match &e {
            SchedError::NoSuchJob(_) => StatusCode::NOT_FOUND,
            SchedError::NoSuchMachine { .. } => StatusCode::BAD_REQUEST,
            SchedError::Conflict(_) => StatusCode::CONFLICT,
            SchedError::Refused(_) => StatusCode::UNPROCESSABLE_ENTITY,
            SchedError::Store(_) => StatusCode::INTERNAL_SERVER_ERROR,
        };
        ApiError(status, e.to_string())
    }
}

fn bad(msg: impl Into<String>) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, msg.into())
}

/// What every handler shares.
#[derive(Clone)]
pub struct AppState {
    pub sched: Scheduler,
    pub access: Arc<Access>,
    /// How a job is planned (in a forked child, see `planner`).
    pub planner: PlanFn,
    /// Jobs planned at once (`limits::MAX_CONCURRENT_PLANS`).
    pub plans: Arc<tokio::sync::Semaphore>,
}

/// The API's routes over `sched`, guarded by `access` (who may call what: `access::ROUTES`),
/// planning jobs with `planner`.
pub fn router(sched: Scheduler, access: Arc<Access>, planner: PlanFn) -> Router {
    router_with(sched, access, planner, Router::new())
}

/// The API's routes, and the service routes `GET /metrics` and `GET /events` of `service`
/// (`events::router`), behind the same route table.
pub fn router_with(
    sched: Scheduler,
    access: Arc<Access>,
    planner: PlanFn,
    service: Router,
) -> Router {
    let state = AppState {
        sched: sched.clone(),
        access: access.clone(),
        planner,
        plans: Arc::new(tokio::sync::Semaphore::new(
            crate::limits::MAX_CONCURRENT_PLANS,
        )),
    };
    let gate = Gate {
        access: access.clone(),
        sched,
    };
    Router::new()
        .route_service("/metrics", service.clone())
        .route_service("/events", service)
        .route("/machines", get(machines))
        .route("/jobs", get(jobs).post(submit))
        .route("/jobs/{id}", get(job))
        .route("/jobs/{id}/pause", post(pause))
        .route("/jobs/{id}/resume", post(resume).get(resume_preview))
        .route("/jobs/{id}/override", post(override_job))
        .route("/machines/{name}/{op}", post(operate))
        .route("/jobs/{id}/cancel", post(cancel))
        .route("/jobs/{id}/events", get(events))
        .route("/machines/{name}/gcode", post(crate::upload::gcode))
        .merge(crate::access_api::routes())
        .merge(crate::dashboard::routes())
        .route_layer(middleware::from_fn_with_state(
            gate,
            crate::access::authorize,
        ))
        .fallback(|| async { bad("no such request: see docs/daemon.md for the API") })
        .layer(middleware::from_fn_with_state(
            access,
            crate::access::authenticate,
        ))
        .layer(middleware::from_fn(crate::limits::json_errors))
        .layer(axum::extract::DefaultBodyLimit::max(
            crate::limits::MAX_JSON_BODY,
        ))
        .with_state(state)
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
    let body = crate::limits::json_body(req).await?;
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
    let body = crate::limits::json_body(req).await?;
    let spec: JobSpec = serde_json::from_slice(&body)
        .map_err(|e| bad(format!("the request is not a valid job: {e}")))?;
    drop(body);
    let Some(name) = spec.machine.clone() else {
        return Err(bad("the job names no machine (give \"machine\")"));
    };
    st.sched.machine_config(&name)?;
    st.access
        .check_operate(&who, &name, &st.sched)
        .map_err(|d| ApiError(d.0, d.1))?;
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
    let params = params_of(&spec);
    let planning = std::time::Instant::now();
    let planned = {
        let _turn = st.plans.acquire().await.map_err(|e| {
            ApiError(
                StatusCode::SERVICE_UNAVAILABLE,
                format!("the daemon is stopping: {e}"),
            )
        })?;
        crate::planner::plan_isolated(spec, machine, st.planner, crate::planner::PLAN_TIME_LIMIT)
            .await
    };
    crate::memory::give_back();
    let planned = planned.map_err(|e| match e {
        PlanError::Intake(IntakeError::Refused(m)) => ApiError(StatusCode::UNPROCESSABLE_ENTITY, m),
        PlanError::Intake(other) => bad(other.to_string()),
        other @ (PlanError::Crashed(_) | PlanError::TimedOut(_)) => {
            ApiError(StatusCode::UNPROCESSABLE_ENTITY, other.to_string())
        }
        other => ApiError(StatusCode::INTERNAL_SERVER_ERROR, other.to_string()),
    })?;
    if planned.program.len() > crate::limits::MAX_PROGRAM_UNITS {
        return Err(ApiError(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!(
                "the program has {} units, more than the daemon's limit of {}",
                planned.program.len(),
                crate::limits::MAX_PROGRAM_UNITS
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

/// What the store keeps of a job's spec: everything but the file's bytes.
pub fn params_of(spec: &JobSpec) -> serde_json::Value {
    let mut v = serde_json::to_value(spec).unwrap_or_default();
    if let Some(input) = v.get_mut("input").and_then(|i| i.as_object_mut()) {
        input.remove("file_text");
        input.remove("file_base64");
    }
    v
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
    pub job: crate::store::JobRecord,
    pub overrides: machlink_protocols::Overrides,
}

async fn override_job(
    State(st): State<AppState>,
    Path(id): Path<String>,
    body: axum::body::Bytes,
) -> Result<Response, ApiError> {
    let patch: crate::scheduler::OverridePatch = serde_json::from_slice(&body)
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
