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
//! | `POST /machines/{name}/lock`, `/release`, `GET /locks` | the control lock (`api::access`) |
//! | `GET /whoami`, `POST /access/reload` | the caller's role; reload the access table |
//!
//! Who may call what is the route table of `access` (`access::ROUTES`); every route added
//! here needs its line there. Refusals are 4xx with `{ "error": "one sentence" }`.

pub mod access;
pub mod error;
pub mod gate;
pub mod jobs;
pub mod limits;
pub mod service;
pub mod state;
pub mod upload;

use crate::core::planner::PlanFn;
use crate::core::scheduler::Scheduler;
use crate::faces::api::gate::Gate;
use crate::services::access::Access;
use axum::middleware;
use axum::routing::post;
use axum::Router;
use std::sync::Arc;

/// The API's routes over `sched`, guarded by `access` (who may call what: `access::ROUTES`),
/// planning jobs with `planner`.
pub fn router(sched: Scheduler, access: Arc<Access>, planner: PlanFn) -> Router {
    router_with(sched, access, planner, Router::new())
}

/// The API's routes, and the service routes `GET /metrics` and `GET /events` of `service`
/// (`service::router`), behind the same route table.
pub fn router_with(
    sched: Scheduler,
    access: Arc<Access>,
    planner: PlanFn,
    service: Router,
) -> Router {
    let state = crate::faces::api::state::AppState {
        sched: sched.clone(),
        access: access.clone(),
        planner,
        plans: Arc::new(tokio::sync::Semaphore::new(
            crate::faces::api::limits::MAX_CONCURRENT_PLANS,
        )),
    };
    let gate = Gate {
        access: access.clone(),
        sched,
    };
    Router::new()
        .route_service("/metrics", service.clone())
        .route_service("/events", service)
        .merge(crate::faces::api::jobs::routes())
        .route(
            "/machines/{name}/gcode",
            post(crate::faces::api::upload::gcode),
        )
        .merge(crate::faces::api::access::routes())
        .merge(crate::faces::dashboard::routes())
        .route_layer(middleware::from_fn_with_state(
            gate,
            crate::faces::api::gate::authorize,
        ))
        .fallback(|| async {
            crate::faces::api::error::bad("no such request: see docs/daemon.md for the API")
        })
        .layer(middleware::from_fn_with_state(
            access,
            crate::faces::api::gate::authenticate,
        ))
        .layer(middleware::from_fn(crate::faces::api::error::json_errors))
        .layer(axum::extract::DefaultBodyLimit::max(
            crate::faces::api::limits::MAX_JSON_BODY,
        ))
        .with_state(state)
}
