//! Every refusal the API gives, in one place: the layers below return their own typed errors
//! (`SchedError`, `StoreError`, `IntakeError`, `PlanError`, `AccessError`, `LimitError`) and
//! this module alone says which HTTP status each one is. Every refusal is JSON,
//! `{ "error": "one sentence" }`, axum's own (404, 405, 413, …) included (`json_errors`).

use crate::core::intake::IntakeError;
use crate::core::planner::PlanError;
use crate::core::scheduler::SchedError;
use crate::core::store::StoreError;
use crate::faces::api::limits::{mib, LimitError, MAX_JSON_BODY};
use crate::services::access::AccessError;
use axum::extract::Request;
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Json;
use http_body_util::BodyExt;
use serde::{Deserialize, Serialize};

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

/// A request the API itself cannot read (400).
pub fn bad(msg: impl Into<String>) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, msg.into())
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

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string())
    }
}

impl From<IntakeError> for ApiError {
    fn from(e: IntakeError) -> Self {
        match e {
            IntakeError::Refused(m) => ApiError(StatusCode::UNPROCESSABLE_ENTITY, m),
            other => bad(other.to_string()),
        }
    }
}

impl From<PlanError> for ApiError {
    fn from(e: PlanError) -> Self {
        match e {
            PlanError::Intake(i) => i.into(),
            other @ (PlanError::Crashed(_) | PlanError::TimedOut(_)) => {
                ApiError(StatusCode::UNPROCESSABLE_ENTITY, other.to_string())
            }
            other => ApiError(StatusCode::INTERNAL_SERVER_ERROR, other.to_string()),
        }
    }
}

impl From<AccessError> for ApiError {
    fn from(e: AccessError) -> Self {
        let status = match &e {
            AccessError::Unauthenticated(_) => StatusCode::UNAUTHORIZED,
            AccessError::Forbidden(_) => StatusCode::FORBIDDEN,
            AccessError::Locked(_) => StatusCode::CONFLICT,
        };
        ApiError(status, e.to_string())
    }
}

impl From<LimitError> for ApiError {
    fn from(e: LimitError) -> Self {
        let status = match &e {
            LimitError::TooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            LimitError::Unreadable(_) => StatusCode::BAD_REQUEST,
        };
        ApiError(status, e.to_string())
    }
}

/// Middleware: any refusal that is not JSON yet (axum's own 404, 405, 413, 415 …) becomes
/// `{ "error": "one sentence" }` with the same status.
pub async fn json_errors(req: Request, next: Next) -> Response {
    let resp = next.run(req).await;
    let status = resp.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return resp;
    }
    let is_json = resp
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if is_json {
        return resp;
    }
    let (parts, body) = resp.into_parts();
    let text = match http_body_util::Limited::new(body, 4096).collect().await {
        Ok(c) => String::from_utf8_lossy(&c.to_bytes()).trim().to_string(),
        Err(_) => String::new(),
    };
    let reason = status.canonical_reason().unwrap_or("refused");
    let sentence = match (status, text.is_empty()) {
        (StatusCode::PAYLOAD_TOO_LARGE, _) => format!(
            "the request body is larger than the daemon's limit of {} (docs/daemon.md, Limits)",
            mib(MAX_JSON_BODY as u64)
        ),
        (StatusCode::METHOD_NOT_ALLOWED, _) => {
            "this path does not take that method: see docs/daemon.md for the API".to_string()
        }
        (_, true) => reason.to_string(),
        (_, false) => format!("{reason}: {text}"),
    };
    let mut r = ApiError(status, sentence).into_response();
    for (k, v) in parts.headers.iter() {
        if k != header::CONTENT_TYPE && k != header::CONTENT_LENGTH {
            r.headers_mut().insert(k, v.clone());
        }
    }
    r
}
