//! Roles, grants, the control lock and the audit log, through the API as each role meets it:
//! every route of the access table tried by every role.

use crate::common;

use common::*;
use machlink::core::store::{JobId, JobState};
use machlink::daemon::{Daemon, StartOptions};
use machlink::faces::client::{Client, Endpoint};
use machlink::services::access::{hex, new_token, token_hash, ROUTES};
use std::path::Path;

/// The tokens of the test cell, by name.
struct Tokens {
    viewer: String,
    op_a: String,
    op_b: String,
    boss: String,
}

const MACHINES: &str = "[[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\ntime_scale = 1.0\n\n\
                        [[machine]]\nname = \"mill\"\nlink = \"sim-grbl\"\ntime_scale = 50.0\n";

fn access_toml(t: &Tokens) -> String {
    let entry = |name: &str, role: &str, machines: Option<&str>, token: &str| {
        format!(
            "\n[[access.token]]\nname = \"{name}\"\nrole = \"{role}\"\n{}sha256 = \"{}\"\n",
            machines
                .map(|m| format!("machines = [{m}]\n"))
                .unwrap_or_default(),
            hex(&token_hash(token))
        )
    };
    [
        entry("viewer", "viewer", None, &t.viewer),
        entry("op-a", "operator", Some("\"router\""), &t.op_a),
        entry("op-b", "operator", Some("\"router\""), &t.op_b),
        entry("boss", "admin", None, &t.boss),
    ]
    .concat()
}

/// A daemon with two machines and four tokens; its config is on disk for `/access/reload`.
async fn cell(dir: &Path) -> (Daemon, Tokens) {
    let t = Tokens {
        viewer: new_token().unwrap(),
        op_a: new_token().unwrap(),
        op_b: new_token().unwrap(),
        boss: new_token().unwrap(),
    };
    let text = format!(
        "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n{MACHINES}{}",
        dir.join("jobs.db").display(),
        dir.join("ml.sock").display(),
        access_toml(&t)
    );
    let path = dir.join("machlink.toml");
    std::fs::write(&path, &text).unwrap();
    let cfg = machlink::config::Config::load(&path).expect("config");
    let d = Daemon::start(
        cfg,
        StartOptions {
            config_path: Some(path),
            ..Default::default()
        },
    )
    .await
    .expect("daemon starts");
    (d, t)
}

fn as_token(d: &Daemon, token: &str) -> Client {
    Client::new(Endpoint::UnixToken {
        path: d.socket.clone(),
        token: token.to_string(),
    })
}

/// A slow job on `machine`: 3000 short moves at F1500 (about a minute at time scale 1).
fn long_job(machine: &str) -> serde_json::Value {
    let lines = zigzag(3000);
    serde_json::json!({
        "machine": machine,
        "input": { "file_name": "long.nc", "file_text": lines.join("\n") }
    })
}

fn small_job(machine: &str) -> serde_json::Value {
    serde_json::json!({
        "machine": machine,
        "input": { "file_name": "small.nc", "file_text": "G21 G90\nG1 X1 F500\nX0\n" }
    })
}

async fn post(c: &Client, path: &str, body: Option<serde_json::Value>) -> (u16, serde_json::Value) {
    call(c, "POST", path, body).await
}

async fn call(
    c: &Client,
    method: &str,
    path: &str,
    body: Option<serde_json::Value>,
) -> (u16, serde_json::Value) {
    let m: hyper::Method = method.parse().unwrap();
    let (st, bytes) = c
        .raw(m, path, body.map(|b| b.to_string().into_bytes()))
        .await
        .expect("the daemon answers");
    (
        st.as_u16(),
        serde_json::from_slice(&bytes).unwrap_or(serde_json::Value::Null),
    )
}

/// Submits `spec` as `c`; the job's number.
async fn submit(c: &Client, spec: serde_json::Value) -> JobId {
    let (st, b) = post(c, "/jobs", Some(spec)).await;
    assert_eq!(st, 201, "{b}");
    b["id"].as_i64().unwrap()
}

/// The order the matrix tries the routes in: reads, then what makes jobs, then what steers
/// the running job, cancel last.
fn order(path: &str, method: &str) -> u8 {
    match (method, path) {
        // what a resume would do is asked of the paused job
        ("GET", "/jobs/{id}/resume") => 3,
        ("GET", _) => 0,
        (_, "/jobs") | (_, "/machines/{name}/gcode") => 1,
        (_, "/jobs/{id}/pause") => 2,
        (_, "/jobs/{id}/resume") => 4,
        (_, "/machines/{name}/lock") => 5,
        (_, "/machines/{name}/release") => 6,
        (_, "/access/reload") => 7,
        (_, "/jobs/{id}/cancel") => 9,
        // unlock, home, jog: on a machine with no job, so after the cancel
        (_, "/machines/{name}/{op}") => 10,
        _ => 8,
    }
}

/// Tries one route of the table as `c`: the running job `job`, the finished job `done`.
async fn try_route(
    c: &Client,
    method: &str,
    template: &str,
    job: JobId,
    done: JobId,
) -> (u16, serde_json::Value) {
    let path = template
        .replace(
            "{id}",
            &if template.ends_with("/events") {
                done
            } else {
                job
            }
            .to_string(),
        )
        .replace("{name}", "router")
        .replace("{op}", "unlock");
    match (method, template) {
        // the stream of every job's events never ends: its head is the answer
        ("GET", "/events") => match c.follow(None).await {
            Ok(_) => (200, serde_json::Value::Null),
            Err(e) => (0, serde_json::Value::String(e.to_string())),
        },
        ("GET", _) => call(c, "GET", &path, None).await,
        ("POST", "/jobs/{id}/override") => {
            post(c, &path, Some(serde_json::json!({ "feed": 110 }))).await
        }
        ("POST", "/jobs") => post(c, &path, Some(small_job("router"))).await,
        // the dashboard's preview of a job before it is queued
        ("POST", "/plan") => post(c, &path, Some(small_job("router"))).await,
        ("POST", "/machines/{name}/gcode") => {
            let (st, bytes) = c
                .raw(
                    hyper::Method::POST,
                    &format!("{path}?file_name=up.nc"),
                    Some(b"G21 G90\nG1 X2 F500\nX0\n".to_vec()),
                )
                .await
                .unwrap();
            (
                st.as_u16(),
                serde_json::from_slice(&bytes).unwrap_or(serde_json::Value::Null),
            )
        }
        ("POST", _) => post(c, &path, None).await,
        _ => panic!(
            "the route {method} {template} has no request in this test: add one to try_route"
        ),
    }
}

/// Every route, as `role`: the allowed ones succeed, the others are 403 with a JSON sentence.
async fn every_route_as(role: &str) {
    let dir = tempfile::tempdir().unwrap();
    let (d, t) = cell(dir.path()).await;
    let admin_socket = client(&d);
    let c = match role {
        "viewer" => as_token(&d, &t.viewer),
        "operator" => as_token(&d, &t.op_a),
        "admin" => as_token(&d, &t.boss),
        "socket-owner" => client(&d),
        _ => unreachable!(),
    };
    // a finished job on the other machine, for the event stream
    let done = submit(&admin_socket, small_job("mill")).await;
    wait_state(&admin_socket, done, JobState::Completed).await;
    // the running job is submitted by the caller (a viewer cannot: the socket's owner does)
    let owner = if role == "viewer" { &admin_socket } else { &c };
    let job = submit(owner, long_job("router")).await;
    wait_state(&admin_socket, job, JobState::Running).await;
    let mut routes: Vec<_> = ROUTES.iter().collect();
    routes.sort_by_key(|r| order(r.path, r.method));
    for r in routes {
        let allowed = match role {
            "viewer" => r.method == "GET",
            "operator" => r.path != "/access/reload",
            _ => true,
        };
        if (r.method, r.path) == ("GET", "/jobs/{id}/resume") && role == "viewer" {
            // a viewer cannot pause: the socket's owner does, so there is a resume to show
            admin_socket.act(job, "pause").await.unwrap();
            wait_state(&admin_socket, job, JobState::Paused).await;
        }
        if r.path == "/machines/{name}/{op}" {
            // unlock waits for the machine to have no job: end every job still on it
            for j in admin_socket.jobs().await.unwrap() {
                if j.machine == "router" && !j.state.is_final() {
                    admin_socket.act(j.id, "cancel").await.unwrap();
                    wait_until(&admin_socket, j.id, |j| j.state.is_final()).await;
                }
            }
        }
        let (st, b) = try_route(&c, r.method, r.path, job, done).await;
        if allowed {
            assert!(
                (200..300).contains(&st),
                "{role}: {} {} should succeed, got {st} {b}",
                r.method,
                r.path
            );
        } else {
            assert_eq!(
                st, 403,
                "{role}: {} {} should be refused: {b}",
                r.method, r.path
            );
            assert!(
                b["error"].as_str().is_some_and(|e| !e.is_empty()),
                "{role}: {} {}: a JSON error, got {b}",
                r.method,
                r.path
            );
        }
        if r.path == "/jobs/{id}/pause" && allowed {
            wait_state(&admin_socket, job, JobState::Paused).await;
        }
    }
    // the viewer's job was cancelled by the socket's owner before the machine's unlock
    wait_until(&admin_socket, job, |j| j.state.is_final()).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_reads_every_route_and_is_refused_the_rest() {
    every_route_as("viewer").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_operator_may_do_all_but_reload() {
    every_route_as("operator").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_admin_token_may_do_everything() {
    every_route_as("admin").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemons_own_user_on_the_socket_is_admin() {
    every_route_as("socket-owner").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_operator_cannot_touch_a_machine_not_granted_to_it() {
    let dir = tempfile::tempdir().unwrap();
    let (d, t) = cell(dir.path()).await;
    let admin = client(&d);
    let op = as_token(&d, &t.op_a);
    let (st, b) = post(&op, "/jobs", Some(small_job("mill"))).await;
    assert_eq!(st, 403, "{b}");
    assert!(
        b["error"]
            .as_str()
            .unwrap()
            .contains("may not act on machine `mill`"),
        "{b}"
    );
    let (st, _) = post(&op, "/machines/mill/lock", None).await;
    assert_eq!(st, 403);
    let (st, bytes) = op
        .raw(
            hyper::Method::POST,
            "/machines/mill/gcode?file_name=x.nc",
            Some(b"G1 X1 F100\n".to_vec()),
        )
        .await
        .unwrap();
    assert_eq!(st.as_u16(), 403, "{}", String::from_utf8_lossy(&bytes));
    let job = submit(&admin, long_job("mill")).await;
    let (st, _) = post(&op, &format!("/jobs/{job}/cancel"), None).await;
    assert_eq!(st, 403);
    // and the job was not touched
    assert!(!admin.job(job).await.unwrap().state.is_final());
    admin.act(job, "cancel").await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_lock_holders_job_cannot_be_cancelled_by_another_operator() {
    let dir = tempfile::tempdir().unwrap();
    let (d, t) = cell(dir.path()).await;
    let admin = client(&d);
    let a = as_token(&d, &t.op_a);
    let b = as_token(&d, &t.op_b);
    let boss = as_token(&d, &t.boss);
    // a's submit takes the lock of the router
    let job = submit(&a, long_job("router")).await;
    wait_state(&admin, job, JobState::Running).await;
    let locks = b.locks().await.unwrap();
    assert_eq!(
        (
            locks[0].machine.as_str(),
            locks[0].holder.as_str(),
            locks[0].explicit
        ),
        ("router", "op-a", false)
    );
    for action in ["cancel", "pause", "resume"] {
        let (st, e) = post(&b, &format!("/jobs/{job}/{action}"), None).await;
        assert_eq!(st, 409, "{action}: {e}");
        assert!(
            e["error"].as_str().unwrap().contains("is locked by `op-a`"),
            "{e}"
        );
    }
    let (st, _) = post(&b, "/jobs", Some(small_job("router"))).await;
    assert_eq!(st, 409);
    let (st, _) = post(&b, "/machines/router/lock", None).await;
    assert_eq!(st, 409);
    let (st, _) = post(&b, "/machines/router/release", None).await;
    assert_eq!(st, 409);
    // b watches: reads are not locked
    assert_eq!(b.job(job).await.unwrap().state, JobState::Running);
    // an operator cannot break a lock; an admin may
    let (st, _) = post(
        &b,
        "/machines/router/lock",
        Some(serde_json::json!({"break": true})),
    )
    .await;
    assert_eq!(st, 409);
    let (st, l) = post(
        &boss,
        "/machines/router/lock",
        Some(serde_json::json!({"break": true})),
    )
    .await;
    assert_eq!(st, 200, "{l}");
    assert_eq!(l["holder"], "boss");
    // now a holds nothing: its own job is the admin's to steer
    let (st, _) = post(&a, &format!("/jobs/{job}/cancel"), None).await;
    assert_eq!(st, 409);
    let (st, _) = post(&boss, "/machines/router/release", None).await;
    assert_eq!(st, 200);
    let (st, e) = post(&b, &format!("/jobs/{job}/cancel"), None).await;
    assert_eq!(st, 200, "{e}");
    let j = wait_until(&admin, job, |j| j.state.is_final()).await;
    assert_eq!(j.state, JobState::Cancelled);
    // an explicit lock stays after its holder's jobs end, until released
    let (st, _) = post(&b, "/machines/router/lock", None).await;
    assert_eq!(st, 200);
    let (st, _) = post(&a, "/jobs", Some(small_job("router"))).await;
    assert_eq!(st, 409);
    let (st, _) = post(&b, "/machines/router/release", None).await;
    assert_eq!(st, 200);
    assert!(b.locks().await.unwrap().is_empty());
    // breaking is an admin's, even of a free machine
    let (st, e) = post(
        &a,
        "/machines/router/lock",
        Some(serde_json::json!({"break": true})),
    )
    .await;
    assert_eq!(st, 403, "{e}");
    assert!(
        e["error"].as_str().unwrap().contains("needs an admin"),
        "{e}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_audit_log_names_each_action_and_its_token() {
    let dir = tempfile::tempdir().unwrap();
    let (d, t) = cell(dir.path()).await;
    let admin = client(&d);
    let a = as_token(&d, &t.op_a);
    let b = as_token(&d, &t.op_b);
    let v = as_token(&d, &t.viewer);
    let job = submit(&a, long_job("router")).await;
    wait_state(&admin, job, JobState::Running).await;
    let (st, _) = post(&b, &format!("/jobs/{job}/cancel"), None).await;
    assert_eq!(st, 409);
    let (st, _) = post(&v, &format!("/jobs/{job}/pause"), None).await;
    assert_eq!(st, 403);
    let (st, _) = post(&a, &format!("/jobs/{job}/cancel"), None).await;
    assert_eq!(st, 200);
    let _ = v.jobs().await.unwrap();
    let log = machlink::services::audit::read(d.access.audit.path()).unwrap();
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(d.access.audit.path())
        .unwrap()
        .permissions()
        .mode();
    assert_eq!(mode & 0o777, 0o600, "the audit log is private");
    let find = |token: &str, action: &str| {
        log.iter()
            .find(|r| r.token.as_deref() == Some(token) && r.action == action)
            .unwrap_or_else(|| panic!("no record of {token} {action} in {log:#?}"))
    };
    let submitted = find("op-a", "POST /jobs");
    assert_eq!(
        (
            submitted.status,
            submitted.machine.as_deref(),
            submitted.job
        ),
        (201, Some("router"), Some(job))
    );
    assert_eq!(submitted.who.as_deref(), Some("op-a"));
    assert!(
        submitted.from.starts_with("unix socket, uid "),
        "{submitted:?}"
    );
    let refused = find("op-b", &format!("POST /jobs/{job}/cancel"));
    assert_eq!(refused.status, 409);
    assert!(refused.outcome.starts_with("refused: "), "{refused:?}");
    let denied = find("viewer", &format!("POST /jobs/{job}/pause"));
    assert_eq!(denied.status, 403);
    let cancelled = find("op-a", &format!("POST /jobs/{job}/cancel"));
    assert_eq!(
        (cancelled.status, cancelled.outcome.as_str()),
        (200, "done")
    );
    // reads are not state changes
    assert!(
        log.iter().all(|r| !r.action.starts_with("GET ")),
        "{log:#?}"
    );
    assert!(log
        .iter()
        .any(|r| r.action == "start" && r.who.as_deref() == Some("daemon")));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_or_short_tokens_and_unknown_routes_are_refused_in_json() {
    let dir = tempfile::tempdir().unwrap();
    let (d, _t) = cell(dir.path()).await;
    for token in ["", "short", &new_token().unwrap()] {
        let c = Client::new(Endpoint::UnixToken {
            path: d.socket.clone(),
            token: token.to_string(),
        });
        let (st, b) = call(&c, "GET", "/machines", None).await;
        assert_eq!(st, 401, "{token:?}: {b}");
        assert!(b["error"].is_string(), "{b}");
    }
    // a method a path does not take: JSON too
    let (st, b) = call(&client(&d), "DELETE", "/jobs", None).await;
    assert!(st == 403 || st == 405, "{st} {b}");
    assert!(b["error"].is_string(), "{b}");
}
