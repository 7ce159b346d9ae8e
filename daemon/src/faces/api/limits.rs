//! The daemon's bounds on what a request may hold, and JSON for every refusal (docs/daemon.md,
//! "Limits"). Each limit is refused with a sentence naming it, never with a plain-text page.

use axum::extract::Request;
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use http_body_util::BodyExt;

/// A JSON request body (`POST /jobs` with its file inside, `/resume`, …).
pub const MAX_JSON_BODY: usize = 64 << 20;
/// A G-code file streamed to `POST /machines/{name}/gcode`.
pub const MAX_GCODE_BODY: u64 = 512 << 20;
/// One line of a G-code file as written (comments included).
pub const MAX_GCODE_LINE: usize = 4096;
/// Units of one program (G-code lines, motion blocks, stitches), planned or handed in.
pub const MAX_PROGRAM_UNITS: usize = 20_000_000;
/// Vertices of one job's shape, all paths together.
pub const MAX_SHAPE_VERTICES: usize = 2_000_000;
/// Jobs planned at once; more requests wait their turn.
pub const MAX_CONCURRENT_PLANS: usize = 2;

/// MiB, for messages.
pub fn mib(bytes: u64) -> String {
    format!("{} MiB", bytes >> 20)
}

/// The refusal of a body over `limit`.
pub fn too_large(what: &str, limit: u64) -> crate::faces::api::ApiError {
    crate::faces::api::ApiError(
        StatusCode::PAYLOAD_TOO_LARGE,
        format!(
            "{what} is larger than the daemon's limit of {} (docs/daemon.md, Limits)",
            mib(limit)
        ),
    )
}

/// Reads a whole JSON body of at most [`MAX_JSON_BODY`] bytes.
pub async fn json_body(req: Request) -> Result<axum::body::Bytes, crate::faces::api::ApiError> {
    let limit = MAX_JSON_BODY as u64;
    if content_length(&req).is_some_and(|n| n > limit) {
        return Err(too_large("the request body", limit));
    }
    let body = http_body_util::Limited::new(req.into_body(), MAX_JSON_BODY);
    match body.collect().await {
        Ok(c) => Ok(c.to_bytes()),
        Err(e) if e.is::<http_body_util::LengthLimitError>() => {
            Err(too_large("the request body", limit))
        }
        Err(e) => Err(crate::faces::api::ApiError(
            StatusCode::BAD_REQUEST,
            format!("the request body could not be read: {e}"),
        )),
    }
}

/// The request's declared length, if it declares one.
pub fn content_length(req: &Request) -> Option<u64> {
    req.headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse().ok())
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
    let mut r = crate::faces::api::ApiError(status, sentence).into_response();
    for (k, v) in parts.headers.iter() {
        if k != header::CONTENT_TYPE && k != header::CONTENT_LENGTH {
            r.headers_mut().insert(k, v.clone());
        }
    }
    r
}
