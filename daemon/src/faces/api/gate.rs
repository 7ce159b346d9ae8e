//! The API's gate: two middlewares around every route. `authenticate` (outermost) finds who
//! is calling, from the bearer token or the socket's peer; `authorize` (on the matched route)
//! asks the route table of `services::access` whether they may, checks the machine's control
//! lock, and writes every state change, allowed or refused, to the audit log.

use crate::core::scheduler::Scheduler;
use crate::core::store::{now_ms, JobId};
use crate::faces::api::error::ApiError;
use crate::services::access::{
    route_of, Access, AccessError, Acted, Need, Peer, Principal, Role, Route, Scope,
};
use crate::services::audit::Record;
use axum::extract::{ConnectInfo, MatchedPath, Request, State};
use axum::http::{header, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::sync::Arc;

/// Whether a job is still open (not ended), as the access layer's locks ask it.
pub fn open_jobs(sched: &Scheduler) -> impl Fn(JobId) -> bool + '_ {
    |id| sched.job(id).map(|j| !j.state.is_final()).unwrap_or(false)
}

/// The bearer token of a request, if it carries an `Authorization` header at all: any such
/// header is an attempt at a token (one that is not `Bearer TOKEN` reads as empty, and is
/// refused), never a fall-back to the socket's peer.
fn bearer(req: &Request) -> Option<&str> {
    let v = req.headers().get(header::AUTHORIZATION)?;
    Some(
        v.to_str()
            .ok()
            .and_then(|v| v.strip_prefix("Bearer"))
            .map(str::trim)
            .unwrap_or(""),
    )
}

/// The segment of `path` where `template` has `{param}`.
fn path_param<'a>(template: &str, path: &'a str, param: &str) -> Option<&'a str> {
    let want = format!("{{{param}}}");
    let i = template.split('/').position(|s| s == want)?;
    path.split('/').nth(i)
}

/// Middleware (outermost): who is calling. Puts the [`Principal`] into the request; refuses
/// with 401 (no or bad token on TCP) or 403 (an unknown local user).
pub async fn authenticate(
    State(access): State<Arc<Access>>,
    mut req: Request,
    next: Next,
) -> Response {
    let peer = req
        .extensions()
        .get::<ConnectInfo<Peer>>()
        .map(|c| c.0.clone())
        .unwrap_or(Peer::UnixUnknown);
    if route_of(req.method(), req.uri().path()).is_some_and(|r| r.need == Need::Page) {
        return next.run(req).await;
    }
    match access.authenticate(&peer, bearer(&req)) {
        Ok(p) => {
            req.extensions_mut().insert(p);
            next.run(req).await
        }
        Err(d) => {
            let d = ApiError::from(d);
            if req.method() != Method::GET {
                access.audit.write(&Record {
                    at_ms: now_ms(),
                    who: None,
                    role: None,
                    token: None,
                    from: peer.describe(),
                    action: format!("{} {}", req.method(), req.uri().path()),
                    machine: None,
                    job: None,
                    status: d.0.as_u16(),
                    outcome: format!("refused: {}", d.1),
                });
            }
            d.into_response()
        }
    }
}

/// The state [`authorize`] needs.
#[derive(Clone)]
pub struct Gate {
    pub access: Arc<Access>,
    pub sched: Scheduler,
}

/// Middleware (on the matched route): the route table decides. Refuses with 403 (role,
/// machine not granted, route not in the table) or 409 (someone else's lock); writes every
/// state change, allowed or refused, to the audit log.
pub async fn authorize(State(gate): State<Gate>, req: Request, next: Next) -> Response {
    if route_of(req.method(), req.uri().path()).is_some_and(|r| r.need == Need::Page) {
        return next.run(req).await;
    }
    let Some(p) = req.extensions().get::<Principal>().cloned() else {
        return ApiError::from(AccessError::Forbidden("the caller is unknown".into()))
            .into_response();
    };
    let template = req
        .extensions()
        .get::<MatchedPath>()
        .map(|m| m.as_str().to_string())
        .unwrap_or_default();
    let path = req.uri().path().to_string();
    let action = format!("{} {path}", req.method());
    let route = route_of(req.method(), &template);
    let audited = !matches!(route.map(|r| r.need), Some(Need::Read));
    let (decision, machine, job) = decide(&gate, &p, route, &template, &path);
    let audit = |status: StatusCode, outcome: String, acted: &Acted| {
        if audited {
            gate.access.audit.write(&Record {
                at_ms: now_ms(),
                who: Some(p.name.clone()),
                role: Some(p.role),
                token: p.token.clone(),
                from: p.from.clone(),
                action: action.clone(),
                machine: acted.machine.clone().or_else(|| machine.clone()),
                job: acted.job.or(job),
                status: status.as_u16(),
                outcome,
            });
        }
    };
    if let Err(d) = decision.map_err(ApiError::from) {
        audit(d.0, format!("refused: {}", d.1), &Acted::default());
        return d.into_response();
    }
    let resp = next.run(req).await;
    let acted = resp
        .extensions()
        .get::<Acted>()
        .cloned()
        .unwrap_or_default();
    let status = resp.status();
    if status.is_success() {
        if let Some(r) = route {
            if r.takes_lock {
                if let Some(m) = acted.machine.as_ref().or(machine.as_ref()) {
                    gate.access
                        .note_job(&p, m, acted.job.or(job), &open_jobs(&gate.sched));
                }
            }
        }
        let outcome = match &acted.note {
            Some(n) => format!("done: {n}"),
            None => "done".into(),
        };
        audit(status, outcome, &acted);
    } else {
        audit(status, "failed".into(), &acted);
    }
    resp
}

/// The route table's verdict on a request, and the machine and job it is about.
fn decide(
    gate: &Gate,
    p: &Principal,
    route: Option<&Route>,
    template: &str,
    path: &str,
) -> (Result<(), AccessError>, Option<String>, Option<JobId>) {
    let Some(route) = route else {
        return (
            Err(AccessError::Forbidden(format!("`{template}` is not in the daemon's access table (daemon/src/services/access.rs ROUTES): refused for everyone"),
            )),
            None,
            None,
        );
    };
    match route.need {
        Need::Read | Need::Page => (Ok(()), None, None),
        Need::Admin if p.role == Role::Admin => (Ok(()), None, None),
        Need::Admin => (
            Err(AccessError::Forbidden(format!(
                "{} may not do this: it needs an admin",
                p.describe()
            ))),
            None,
            None,
        ),
        Need::Operate(_) if p.role < Role::Operator => (
            Err(AccessError::Forbidden(format!(
                "{} may only read; this needs an operator or an admin",
                p.describe()
            ))),
            None,
            None,
        ),
        Need::Operate(Scope::Body) => (Ok(()), None, None),
        Need::Operate(Scope::Machine) => match path_param(template, path, "name") {
            Some(m) => {
                let m = m.to_string();
                (
                    gate.access.check_operate(p, &m, &open_jobs(&gate.sched)),
                    Some(m),
                    None,
                )
            }
            None => (Ok(()), None, None),
        },
        Need::Operate(Scope::Job) => {
            let id = path_param(template, path, "id").and_then(|s| s.parse::<JobId>().ok());
            // a job that is not there: the handler answers (400, 404)
            match id.and_then(|id| gate.sched.job(id).ok()) {
                Some(j) => (
                    gate.access
                        .check_operate(p, &j.machine, &open_jobs(&gate.sched)),
                    Some(j.machine),
                    Some(j.id),
                ),
                None => (Ok(()), None, id),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_params_come_from_the_matched_template() {
        assert_eq!(
            path_param("/jobs/{id}/cancel", "/jobs/17/cancel", "id"),
            Some("17")
        );
        assert_eq!(
            path_param("/machines/{name}/lock", "/machines/router/lock", "name"),
            Some("router")
        );
        assert_eq!(path_param("/jobs", "/jobs", "id"), None);
    }
}
