//! The daemon's bounds on what a request may hold, and JSON for every refusal (docs/daemon.md,
//! "Limits"). Each limit is refused with a sentence naming it (`LimitError`, which the API
//! answers with 413 or 400 in `error`), never with a plain-text page.

use axum::extract::Request;
use axum::http::header;
use http_body_util::BodyExt;

/// A JSON request body (`POST /jobs` with its file inside, `/resume`, …).
pub const MAX_JSON_BODY: usize = 64 << 20;
/// A G-code file streamed to `POST /machines/{name}/gcode`.
pub const MAX_GCODE_BODY: u64 = 512 << 20;
/// One line of a G-code file as written (comments included).
pub const MAX_GCODE_LINE: usize = 4096;
/// Units of one program (G-code lines, motion blocks, stitches), planned or handed in.
pub const MAX_PROGRAM_UNITS: usize = 20_000_000;
/// Vertices of one job's shape, all paths together (the intake's own bound).
pub use crate::core::intake::MAX_SHAPE_VERTICES;
/// Jobs planned at once; more requests wait their turn.
pub const MAX_CONCURRENT_PLANS: usize = 2;

/// MiB, for messages.
pub fn mib(bytes: u64) -> String {
    format!("{} MiB", bytes >> 20)
}

/// A request over one of the bounds, or one whose body could not be read.
#[derive(Debug, thiserror::Error)]
pub enum LimitError {
    #[error("{what} is larger than the daemon's limit of {} (docs/daemon.md, Limits)", mib(*.limit))]
    TooLarge { what: String, limit: u64 },
    #[error("the request body could not be read: {0}")]
    Unreadable(String),
}

/// The refusal of a body over `limit`.
pub fn too_large(what: &str, limit: u64) -> LimitError {
    LimitError::TooLarge {
        what: what.to_string(),
        limit,
    }
}

/// Reads a whole JSON body of at most [`MAX_JSON_BODY`] bytes.
pub async fn json_body(req: Request) -> Result<axum::body::Bytes, LimitError> {
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
        Err(e) => Err(LimitError::Unreadable(e.to_string())),
    }
}

/// The request's declared length, if it declares one.
pub fn content_length(req: &Request) -> Option<u64> {
    req.headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse().ok())
}
