//! The daemon's HTTP API (JSON), served on a Unix socket, or on TCP behind a bearer token.
//!
//! | request | does |
//! |---|---|
//! | `GET /machines` | the machines, their queues and last status |
//! | `GET /jobs`, `GET /jobs/{id}` | jobs as the store holds them |
//! | `POST /jobs` | plan a shape file and queue it ([`SubmitRequest`]) |
//! | `POST /jobs/{id}/pause`, `/resume`, `/cancel` | steer a job |
//! | `GET /jobs/{id}/events` | newline-delimited JSON events until the job ends |
//!
//! Refusals are 4xx with `{ "error": "one sentence" }`.

use crate::config::MachineConfig;
use crate::planning::{self, PlanParams, Post};
use crate::scheduler::{Event, SchedError, Scheduler};
use crate::store::{JobId, NewJob};
use axum::body::Body;
use axum::extract::{Path, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use base64::Engine;
use machlink_protocols::Program;
use offset_core::Toolpath;
use serde::{Deserialize, Serialize};
use tokio::sync::broadcast;

/// What `POST /jobs` takes: the shape file itself (its name picks the reader), the
/// planning parameters and the machine. A G-code file (.nc, .gcode, .ngc, .tap) is
/// streamed as it is, without planning.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SubmitRequest {
    pub machine: String,
    pub file_name: String,
    /// The file's bytes as text (geometry JSON, DXF, SVG) …
    #[serde(default)]
    pub file_text: Option<String>,
    /// … or as base64, for binary files.
    #[serde(default)]
    pub file_base64: Option<String>,
    /// How to plan a shape file (ignored for a G-code file).
    #[serde(default)]
    pub params: Option<PlanParams>,
}

/// Whether a file name says G-code, to be streamed as it is.
pub fn is_gcode_file(name: &str) -> bool {
    let ext = std::path::Path::new(name)
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    matches!(ext.as_deref(), Some("nc" | "gcode" | "ngc" | "tap" | "gc"))
}

/// The program lines of a G-code file: comments, blank lines and `%` marks dropped;
/// a byte GRBL cannot take is refused, naming the line.
pub fn gcode_lines(file_name: &str, text: &str) -> Result<Vec<String>, ApiError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let mut line = String::new();
        let mut in_paren = false;
        for c in raw.chars() {
            match c {
                _ if in_paren => in_paren = c != ')',
                '(' => in_paren = true,
                ';' => break,
                c => line.push(c),
            }
        }
        let line = line.trim();
        if line.is_empty() || line == "%" {
            continue;
        }
        if let Some(c) = line
            .chars()
            .find(|&c| !c.is_ascii() || c.is_ascii_control() || matches!(c, '?' | '!' | '~'))
        {
            return Err(bad(format!(
                "{file_name}, line {}: the character {c:?} cannot be sent to the machine",
                i + 1
            )));
        }
        out.push(line.to_string());
    }
    Ok(out)
}

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
            SchedError::Store(_) => StatusCode::INTERNAL_SERVER_ERROR,
        };
        ApiError(status, e.to_string())
    }
}

fn bad(msg: impl Into<String>) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, msg.into())
}

#[derive(Clone)]
struct AppState {
    sched: Scheduler,
    token: Option<String>,
}

/// The API's routes over `sched`; with `token`, every request must carry
/// `Authorization: Bearer TOKEN`.
pub fn router(sched: Scheduler, token: Option<String>) -> Router {
    let state = AppState { sched, token };
    Router::new()
        .route("/machines", get(machines))
        .route("/jobs", get(jobs).post(submit))
        .route("/jobs/{id}", get(job))
        .route("/jobs/{id}/pause", post(pause))
        .route("/jobs/{id}/resume", post(resume))
        .route("/jobs/{id}/cancel", post(cancel))
        .route("/jobs/{id}/events", get(events))
        .fallback(|| async { bad("no such request: see docs/daemon.md for the API") })
        .layer(middleware::from_fn_with_state(state.clone(), auth))
        .layer(axum::extract::DefaultBodyLimit::max(64 << 20))
        .with_state(state)
}

async fn auth(State(st): State<AppState>, req: Request, next: Next) -> Response {
    if let Some(token) = &st.token {
        let given = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        if given != Some(token.as_str()) {
            return ApiError(
                StatusCode::UNAUTHORIZED,
                "this daemon needs `Authorization: Bearer TOKEN` (the token given to serve --token)"
                    .into(),
            )
            .into_response();
        }
    }
    next.run(req).await
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
    body: axum::body::Bytes,
) -> Result<Response, ApiError> {
    let id = job_id(&id)?;
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

async fn submit(State(st): State<AppState>, body: axum::body::Bytes) -> Result<Response, ApiError> {
    let req: SubmitRequest = serde_json::from_slice(&body)
        .map_err(|e| bad(format!("the request is not a valid job submission: {e}")))?;
    let machine = st.sched.machine_config(&req.machine)?.clone();
    let bytes = match (&req.file_text, &req.file_base64) {
        (Some(t), None) => t.clone().into_bytes(),
        (None, Some(b)) => base64::engine::general_purpose::STANDARD
            .decode(b)
            .map_err(|e| {
                bad(format!(
                    "file_base64 of {} is not base64: {e}",
                    req.file_name
                ))
            })?,
        _ => {
            return Err(bad(
                "give the file as exactly one of file_text and file_base64",
            ))
        }
    };
    let (op, params, program) = if is_gcode_file(&req.file_name) {
        let text = String::from_utf8(bytes)
            .map_err(|_| bad(format!("{} is not a text file", req.file_name)))?;
        let lines = gcode_lines(&req.file_name, &text)?;
        (
            "gcode".to_string(),
            serde_json::Value::Null,
            Program::Gcode(lines),
        )
    } else {
        let Some(params) = req.params.clone() else {
            return Err(bad(format!(
                "{} is a shape file: give the planning parameters (at least the operation)",
                req.file_name
            )));
        };
        let name = req.file_name.clone();
        let p2 = params.clone();
        let program = tokio::task::spawn_blocking(move || plan(&machine, &name, &bytes, &p2))
            .await
            .map_err(|e| {
                ApiError(
                    StatusCode::INTERNAL_SERVER_ERROR,
                    format!("planning crashed: {e}"),
                )
            })??;
        let op = serde_json::to_value(params.op)
            .ok()
            .and_then(|v| v.as_str().map(String::from))
            .unwrap_or_default();
        (
            op,
            serde_json::to_value(&params).unwrap_or_default(),
            program,
        )
    };
    let rec = st.sched.submit(NewJob {
        machine: req.machine,
        op,
        file_name: req.file_name,
        params,
        program,
    })?;
    Ok((StatusCode::CREATED, Json(rec)).into_response())
}

/// Plans the job and checks it against the machine: feed limit, work area.
pub fn plan(
    machine: &MachineConfig,
    file_name: &str,
    bytes: &[u8],
    params: &PlanParams,
) -> Result<Program, ApiError> {
    let sentence = |e: anyhow::Error| {
        bad(e
            .chain()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(": "))
    };
    if let Some(max) = machine.max_feed {
        for (what, f) in [("feed", params.feed), ("plunge feed", params.plunge_feed)] {
            if f > max {
                return Err(bad(format!(
                    "the {what} {f} mm/min is above machine `{}`'s limit of {max} mm/min",
                    machine.name
                )));
            }
        }
    }
    let shape = offset_core::io::read_shape(bytes, file_name).map_err(|e| sentence(e.into()))?;
    let tp = planning::plan_toolpath(&shape, params).map_err(sentence)?;
    check_work_area(machine, &tp)?;
    planning::post(&tp, post_for(machine)).map_err(sentence)
}

/// The program format a machine's link speaks.
pub fn post_for(machine: &MachineConfig) -> Post {
    match machine.link {
        crate::config::LinkConfig::Grbl(_) | crate::config::LinkConfig::SimGrbl(_) => Post::Grbl,
        crate::config::LinkConfig::ModbusTcp(_) | crate::config::LinkConfig::ModbusRtu(_) => {
            Post::Modbus
        }
        crate::config::LinkConfig::Sewing(_) | crate::config::LinkConfig::SimSewing(_) => Post::Dst,
    }
}

fn check_work_area(machine: &MachineConfig, tp: &Toolpath) -> Result<(), ApiError> {
    let (Some(w), Some(b)) = (&machine.work_area, tp.bounds()) else {
        return Ok(());
    };
    let lo = [b.min.x, b.min.y, b.min.z];
    let hi = [b.max.x, b.max.y, b.max.z];
    for (i, axis) in ["X", "Y", "Z"].iter().enumerate() {
        if lo[i] < w.min[i] - 1e-9 || hi[i] > w.max[i] + 1e-9 {
            return Err(bad(format!(
                "the path leaves machine `{}`'s work area: {axis} runs {:.3} to {:.3}, the machine allows {} to {}",
                machine.name, lo[i], hi[i], w.min[i], w.max[i]
            )));
        }
    }
    Ok(())
}

/// `GET /jobs/{id}/events`: the job's current state first, then every event about it,
/// one JSON object per line, until it reaches a final state.
async fn events(State(st): State<AppState>, Path(id): Path<String>) -> Result<Response, ApiError> {
    let id = job_id(&id)?;
    // subscribe before reading the state, so nothing falls between them
    let rx = st.sched.subscribe();
    let j = st.sched.job(id)?;
    let first = Event::State {
        job: j.id,
        machine: j.machine.clone(),
        state: j.state,
        acked: j.acked_units,
        total: j.total_units,
        error: j.error.clone(),
    };
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
                    let ev = Event::State {
                        job: j.id,
                        machine: j.machine,
                        state: j.state,
                        acked: j.acked_units,
                        total: j.total_units,
                        error: j.error,
                    };
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
