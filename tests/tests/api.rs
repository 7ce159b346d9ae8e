//! The API itself: bad requests answered with one sentence (tokens, TLS and roles are in
//! `access.rs` and `tls.rs`).

mod common;

use common::*;
use machlink::daemon::StartOptions;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Sends a raw HTTP/1.1 request on the Unix socket; returns the status and the body.
async fn raw(
    socket: &std::path::Path,
    method: &str,
    path: &str,
    body: &str,
) -> (u16, serde_json::Value) {
    let mut s = tokio::net::UnixStream::connect(socket).await.unwrap();
    let req = format!(
        "{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    s.write_all(req.as_bytes()).await.unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).await.unwrap();
    let status: u16 = out[9..12].parse().unwrap();
    let body = out.split("\r\n\r\n").nth(1).unwrap_or("");
    (
        status,
        serde_json::from_str(body).unwrap_or(serde_json::Value::Null),
    )
}

const MACHINE: &str = "[[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 100.0\n\
                       max_feed = 1000.0\nwork_area = { min = [-10, -10, -5], max = [50, 50, 10] }\n";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_requests_get_one_sentence() {
    let dir = tempfile::tempdir().unwrap();
    let d = start(dir.path(), MACHINE, StartOptions::default()).await;
    let sock = d.socket.clone();
    let (st, b) = raw(&sock, "POST", "/jobs", "{ not json").await;
    assert_eq!(st, 400);
    assert!(
        b["error"]
            .as_str()
            .unwrap()
            .starts_with("the request is not a valid job"),
        "{b}"
    );
    let (st, b) = raw(&sock, "GET", "/jobs/abc", "").await;
    assert_eq!(
        (st, b["error"].as_str().unwrap()),
        (400, "`abc` is not a job number")
    );
    let (st, b) = raw(&sock, "GET", "/jobs/77", "").await;
    assert_eq!(
        (st, b["error"].as_str().unwrap()),
        (404, "there is no job 77")
    );
    let (st, _) = raw(&sock, "GET", "/nowhere", "").await;
    assert_eq!(st, 400);

    let square = r#"{"units":"mm","paths":[{"closed":true,"vertices":[[0,0,0],[40,0,0],[40,40,0],[0,40,0]]}]}"#;
    // a JobSpec: the file, and the operation with only the options that differ from its
    // defaults
    let submit = |file_text: &str, operation: serde_json::Value| {
        serde_json::json!({
            "machine": "bench",
            "input": { "file_name": "square.json", "file_text": file_text },
            "operation": operation
        })
        .to_string()
    };
    let params = |feed: f64, side: &str| serde_json::json!({ "op": "profile", "side": side, "cut": { "feed": feed, "spindle_rpm": 0.0 } });
    // above the machine's feed limit
    let (st, b) = raw(
        &sock,
        "POST",
        "/jobs",
        &submit(square, params(2000.0, "inside")),
    )
    .await;
    assert_eq!(st, 422);
    assert!(
        b["error"]
            .as_str()
            .unwrap()
            .ends_with("the feed 2000 mm/min is above machine `bench`'s limit of 1000 mm/min"),
        "{b}"
    );
    // outside the work area: a 30 mm tool around the 40 mm square reaches X 55 > 50
    let mut big_tool = params(800.0, "outside");
    big_tool["cut"]["tool"] = serde_json::json!({ "diameter": 30.0 });
    let (st, b) = raw(&sock, "POST", "/jobs", &submit(square, big_tool)).await;
    assert_eq!(st, 422);
    let e = b["error"].as_str().unwrap();
    assert!(
        e.starts_with("move ") && e.contains("outside machine `bench`'s work area (X -10 to 50)"),
        "{b}"
    );
    // an option the operation does not have is named
    let mut typo = params(800.0, "inside");
    typo["cut"]["stepdwn"] = serde_json::json!(0.5);
    let (st, b) = raw(&sock, "POST", "/jobs", &submit(square, typo)).await;
    assert_eq!(st, 400);
    assert!(b["error"].as_str().unwrap().contains("stepdwn"), "{b}");
    // a shape file that is not one names the file
    let (st, b) = raw(
        &sock,
        "POST",
        "/jobs",
        &submit("{ \"paths\": 3 }", params(800.0, "inside")),
    )
    .await;
    assert_eq!(st, 400);
    assert!(b["error"].as_str().unwrap().contains("square.json"), "{b}");
    // and a good one is taken
    let (st, b) = raw(
        &sock,
        "POST",
        "/jobs",
        &submit(square, params(800.0, "inside")),
    )
    .await;
    assert_eq!(st, 201, "{b}");
    let id = b["id"].as_i64().unwrap();
    let done = wait_end(&client(&d), id).await;
    assert_eq!(
        done.state,
        machlink::core::store::JobState::Completed,
        "{:?}",
        done.error
    );
}
