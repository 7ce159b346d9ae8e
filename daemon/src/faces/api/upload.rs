//! `POST /machines/{name}/gcode?file_name=part.nc`: a G-code file streamed into the store.
//!
//! The body is the file as it is. Each line is checked as it arrives (the checks of
//! `check::gcode_program`, one line at a time) and, for a machine whose kind takes a G-code
//! file's lines as its units (GRBL), appended to the stored program's pages: the file is
//! never held whole, neither as text nor as moves nor as JSON; a page of
//! [`PAGE_UNITS`](crate::core::store::PAGE_UNITS) lines at a time goes into the store. Other kinds
//! get the whole file planned as a `POST /jobs` would (bounded by the JSON body limit).

use crate::core::check::GcodeCheck;
use crate::core::store::NewJobUnits;
use crate::faces::api::error::ApiError;
use crate::faces::api::limits::{
    too_large, LimitError, MAX_GCODE_BODY, MAX_GCODE_LINE, MAX_JSON_BODY, MAX_PROGRAM_UNITS,
};
use crate::faces::api::state::AppState;
use crate::services::access::Acted;
use axum::extract::{Path, Query, Request, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use futures::StreamExt;
use machlink_protocols::kind::GCODE_FILE;
use serde::Deserialize;

/// The query of the upload.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadQuery {
    /// The file's name as the operator knows it (shown in `jobs`, named in refusals).
    pub file_name: String,
}

fn bad(m: String) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, m)
}

/// The handler.
pub async fn gcode(
    State(st): State<AppState>,
    Path(name): Path<String>,
    Query(q): Query<UploadQuery>,
    req: Request,
) -> Result<Response, ApiError> {
    let machine = st.sched.machine_config(&name)?.clone();
    let file = q.file_name.clone();
    if !crate::core::intake::is_gcode_file(&file) {
        return Err(bad(format!(
            "{file} is not named as a G-code file (.nc, .gcode, .ngc, .tap, .gc, .cnc)"
        )));
    }
    let declared = crate::faces::api::limits::content_length(&req);
    if declared.is_some_and(|n| n > MAX_GCODE_BODY) {
        return Err(too_large(&file, MAX_GCODE_BODY).into());
    }
    if !machine.kind.gcode_lines_are_units() {
        return whole_file(st, name, file, req).await;
    }
    let checking = std::time::Instant::now();
    let mut check = GcodeCheck::new(&file, &machine);
    let mut pages = st.sched.store().page_writer()?;
    let mut json: Vec<u8> = Vec::new();
    let mut count = 0usize;
    let mut received = 0u64;
    let mut partial: Vec<u8> = Vec::new();
    let mut n = 0usize;
    let mut take = |raw: &[u8],
                    n: usize,
                    pages: &mut crate::core::store::PageWriter,
                    count: &mut usize|
     -> Result<(), ApiError> {
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        if raw.len() > MAX_GCODE_LINE {
            return Err(ApiError(
                StatusCode::PAYLOAD_TOO_LARGE,
                format!("{file}, line {n}: the line is longer than the daemon's limit of {MAX_GCODE_LINE} bytes"),
            ));
        }
        let text = std::str::from_utf8(raw)
            .map_err(|_| bad(format!("{file}, line {n}: the line is not text (UTF-8)")))?;
        let checked = check
            .line(n, text)
            .map_err(|m| ApiError(StatusCode::UNPROCESSABLE_ENTITY, m))?;
        if let Some(c) = checked {
            if *count == MAX_PROGRAM_UNITS {
                return Err(ApiError(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    format!("{file} has more than the daemon's limit of {MAX_PROGRAM_UNITS} program lines"),
                ));
            }
            json.clear();
            serde_json::to_writer(&mut json, &c.line)
                .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
            pages
                .push_json(&json)
                .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
            *count += 1;
        }
        Ok(())
    };
    let mut body = req.into_body().into_data_stream();
    let read = async {
    while let Some(chunk) = body.next().await {
        let chunk = chunk.map_err(|e| bad(format!("{file} could not be received: {e}")))?;
        received += chunk.len() as u64;
        if received > MAX_GCODE_BODY {
            return Err(too_large(&file, MAX_GCODE_BODY).into());
        }
        let mut rest: &[u8] = &chunk;
        while let Some(i) = rest.iter().position(|&b| b == b'\n') {
            n += 1;
            if partial.is_empty() {
                take(&rest[..i], n, &mut pages, &mut count)?;
            } else {
                partial.extend_from_slice(&rest[..i]);
                let line = std::mem::take(&mut partial);
                take(&line, n, &mut pages, &mut count)?;
            }
            rest = &rest[i + 1..];
        }
        if partial.len() + rest.len() > MAX_GCODE_LINE + 1 {
            return Err(ApiError(
                StatusCode::PAYLOAD_TOO_LARGE,
                format!("{file}, line {}: the line is longer than the daemon's limit of {MAX_GCODE_LINE} bytes", n + 1),
            ));
        }
        partial.extend_from_slice(rest);
    }
    if !partial.is_empty() {
        n += 1;
        let line = std::mem::take(&mut partial);
        take(&line, n, &mut pages, &mut count)?;
    }
    Ok::<(), ApiError>(())
    }
    .await;
    if let Err(e) = read {
        // the client is still sending: read (and drop) a bounded rest of the file, so it
        // gets this answer rather than a connection cut while it writes
        drain(&mut body).await;
        return Err(e);
    }
    drop(body);
    let pages = pages.finish()?;
    let rec = st.sched.submit_units(NewJobUnits {
        machine: name.clone(),
        op: "gcode".into(),
        file_name: file.clone(),
        params: serde_json::json!({ "machine": name, "input": { "file_name": file } }),
        post: GCODE_FILE.into(),
        pages,
    });
    st.sched.store().release_memory();
    crate::services::memory::give_back();
    let rec = rec?;
    if let Some(m) = st.sched.metrics() {
        m.job_submitted(&rec.machine, checking.elapsed());
    }
    let mut resp = (StatusCode::CREATED, Json(&rec)).into_response();
    resp.extensions_mut().insert(Acted {
        machine: Some(rec.machine.clone()),
        job: Some(rec.id),
        note: None,
    });
    Ok(resp)
}

/// Reads what is left of a refused upload, up to [`DRAIN_LIMIT`] bytes and
/// [`DRAIN_TIME`], then gives up (the connection closes on the rest).
async fn drain<S, E>(body: &mut S)
where
    S: futures::Stream<Item = Result<axum::body::Bytes, E>> + Unpin,
{
    let mut left = DRAIN_LIMIT;
    let _ = tokio::time::timeout(DRAIN_TIME, async {
        while let Some(Ok(chunk)) = body.next().await {
            left = left.saturating_sub(chunk.len() as u64);
            if left == 0 {
                break;
            }
        }
    })
    .await;
}

/// The most of a refused upload read to let the client finish sending.
const DRAIN_LIMIT: u64 = 16 << 20;
/// The longest a refused upload is read on.
const DRAIN_TIME: std::time::Duration = std::time::Duration::from_secs(2);

/// A machine whose kind makes its units from the file's moves: the file is taken whole (up
/// to the JSON body limit) and planned as `POST /jobs` plans it.
async fn whole_file(
    st: AppState,
    machine: String,
    file: String,
    req: Request,
) -> Result<Response, ApiError> {
    let bytes = crate::faces::api::limits::json_body(req)
        .await
        .map_err(|e| match e {
            LimitError::TooLarge { .. } => too_large(&file, MAX_JSON_BODY as u64),
            e => e,
        })?;
    let spec = crate::core::intake::JobSpec {
        machine: Some(machine),
        input: crate::core::intake::Input::from_bytes(&file, bytes.to_vec()),
        operation: None,
        operations: Vec::new(),
        tolerance: None,
        layers: Vec::new(),
        post: None,
    };
    drop(bytes);
    crate::faces::api::jobs::submit_spec(&st, spec).await
}
