//! The API's access routes: the control lock (`POST /machines/{name}/lock`, `/release`,
//! `GET /locks`), who the caller is (`GET /whoami`), and reloading the access table
//! (`POST /access/reload`). Their lines in the route table are in `access::ROUTES`.

use crate::faces::api::error::ApiError;
use crate::faces::api::gate::open_jobs;
use crate::faces::api::state::AppState;
use crate::services::access::{Acted, Principal, Role};
use axum::extract::{Extension, Path, Request, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::{Deserialize, Serialize};

pub fn routes() -> Router<AppState> {
    Router::new()
        .route("/machines/{name}/lock", post(lock))
        .route("/machines/{name}/release", post(release))
        .route("/locks", get(locks))
        .route("/whoami", get(whoami))
        .route("/access/reload", post(reload))
}

/// The optional body of `POST /machines/{name}/lock`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LockRequest {
    /// Admins: take the lock over from whoever holds it.
    #[serde(default, rename = "break")]
    pub take_over: bool,
}

fn acted(resp: Response, machine: &str, note: Option<String>) -> Response {
    let mut resp = resp;
    resp.extensions_mut().insert(Acted {
        machine: Some(machine.to_string()),
        job: None,
        note,
    });
    resp
}

async fn lock(
    State(st): State<AppState>,
    Extension(who): Extension<Principal>,
    Path(name): Path<String>,
    req: Request,
) -> Result<Response, ApiError> {
    st.sched.machine_config(&name)?;
    let body = crate::faces::api::limits::json_body(req).await?;
    let r: LockRequest = if body.iter().all(|b| b.is_ascii_whitespace()) {
        LockRequest::default()
    } else {
        serde_json::from_slice(&body).map_err(|e| {
            ApiError(
                StatusCode::BAD_REQUEST,
                format!("the lock request is not valid: {e}"),
            )
        })?
    };
    if r.take_over && who.role != Role::Admin {
        return Err(ApiError(
            StatusCode::FORBIDDEN,
            format!("`{}` may not break a lock: it needs an admin", who.name),
        ));
    }
    let from = st
        .access
        .take(&who, &name, r.take_over, &open_jobs(&st.sched))?;
    let info = st.access.holder(&name, &open_jobs(&st.sched));
    let note = from.map(|h| format!("broke the lock `{h}` held"));
    Ok(acted(Json(info).into_response(), &name, note))
}

async fn release(
    State(st): State<AppState>,
    Extension(who): Extension<Principal>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    st.sched.machine_config(&name)?;
    let from = st.access.release(&who, &name, &open_jobs(&st.sched))?;
    let note = match from {
        Some(h) if h != who.name => Some(format!("broke the lock `{h}` held")),
        Some(_) => None,
        None => Some("it was not locked".into()),
    };
    Ok(acted(
        Json(serde_json::json!({ "machine": name, "released": true })).into_response(),
        &name,
        note,
    ))
}

async fn locks(State(st): State<AppState>) -> Response {
    Json(st.access.locks(&open_jobs(&st.sched))).into_response()
}

async fn whoami(Extension(who): Extension<Principal>) -> Response {
    Json(who).into_response()
}

/// Rereads the config file's `[access]` table (tokens, users, groups); machines and the
/// socket stay as the daemon started with them.
async fn reload(State(st): State<AppState>) -> Result<Response, ApiError> {
    let Some(path) = st.access.config_path.clone() else {
        return Err(ApiError(
            StatusCode::CONFLICT,
            "this daemon was started without a config file: there is nothing to reload".into(),
        ));
    };
    let cfg = crate::config::Config::load(&path)
        .map_err(|e| ApiError(StatusCode::UNPROCESSABLE_ENTITY, e.to_string()))?;
    let tokens = cfg.access.tokens.len();
    st.access.reload(cfg.access);
    Ok(Json(serde_json::json!({
        "reloaded": path.display().to_string(),
        "tokens": tokens,
        "note": "the [access] table is in force; machines and the socket change only with a restart"
    }))
    .into_response())
}
