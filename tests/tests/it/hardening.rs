//! No single job takes the daemon down: a job whose planning panics or overflows its stack
//! fails with a sentence while another machine's job runs to completion. A G-code file
//! streamed in is stored exactly as the same file sent whole, and refused the same way.

use crate::common;

use common::*;
use machlink::core::intake::{IntakeError, JobSpec, Planned, Target};
use machlink::core::store::JobState;
use machlink::daemon::{Daemon, StartOptions};

/// The planner of this test: the real one, except for two files whose planning really
/// overflows its stack or panics (the fault a pathological shape can cause).
fn faulty_planner(spec: &JobSpec, target: Target<'_>) -> Result<Planned, IntakeError> {
    match spec.input.file_name.as_str() {
        "overflow.json" => {
            // deeper than any stack: each level keeps 4 KiB alive
            fn dive(n: u64) -> u64 {
                let pad = [n; 512];
                std::hint::black_box(&pad);
                if n == u64::MAX {
                    return 0;
                }
                dive(n + 1).wrapping_add(pad[n as usize % 512])
            }
            Err(IntakeError::Plan(format!("reached {}", dive(0))))
        }
        "panic.json" => panic!("a planner bug on purpose"),
        _ => machlink::core::intake::plan(spec, target),
    }
}

const MACHINES: &str = "[[machine]]\nname = \"a\"\nlink = \"sim-grbl\"\ntime_scale = 50.0\n\n\
                        [[machine]]\nname = \"b\"\nlink = \"sim-grbl\"\ntime_scale = 20.0\n";

const SQUARE: &str =
    r#"{"units":"mm","paths":[{"closed":true,"vertices":[[0,0,0],[40,0,0],[40,40,0],[0,40,0]]}]}"#;

fn shape_job(machine: &str, file_name: &str) -> JobSpec {
    let mut j = job(machine, file_name, SQUARE);
    j.operation = Some(machlink::core::intake::Operation::Profile(
        Default::default(),
    ));
    j
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_planner_that_overflows_or_panics_fails_its_job_and_the_daemon_serves_on() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = machlink::config::Config::parse(
        &format!(
            "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n{MACHINES}",
            dir.path().join("jobs.db").display(),
            dir.path().join("ml.sock").display()
        ),
        &dir.path().join("machlink.toml"),
    )
    .unwrap();
    let d = Daemon::start(
        cfg,
        StartOptions {
            planner: Some(faulty_planner),
            ..Default::default()
        },
    )
    .await
    .unwrap();
    let c = client(&d);
    // machine b is busy with a job of its own
    let busy = submit_gcode(&c, "b", "busy", &zigzag(600)).await;
    wait_state(&c, busy.id, JobState::Running).await;
    let e = c
        .submit(&shape_job("a", "overflow.json"))
        .await
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("planning the job crashed") && e.contains("stack overflow"),
        "{e}"
    );
    let e = c
        .submit(&shape_job("a", "panic.json"))
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("panicked: a planner bug on purpose"), "{e}");
    // the daemon serves on: a good job on a, and b's job to its end
    let good = c.submit(&shape_job("a", "square.json")).await.unwrap();
    let good = wait_end(&c, good.id).await;
    assert_eq!(good.state, JobState::Completed, "{:?}", good.error);
    let busy = wait_end(&c, busy.id).await;
    assert_eq!(busy.state, JobState::Completed, "{:?}", busy.error);
    assert_eq!(busy.acked_units, 600);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gcode_file_streamed_in_is_stored_as_the_whole_file_is() {
    let dir = tempfile::tempdir().unwrap();
    let d = start(
        dir.path(),
        "[[machine]]\nname = \"m\"\nlink = \"sim-grbl\"\ntime_scale = 100.0\n\
         max_feed = 2000.0\nwork_area = { min = [-10, -10, -5], max = [60, 60, 10] }\n",
        StartOptions::default(),
    )
    .await;
    let c = client(&d);
    let mut text = String::from("%\n(a comment)\nG21 G90 ; mm\r\n");
    for l in zigzag(500) {
        text.push_str(&l);
        text.push('\n');
    }
    text.push_str("M30\n%");
    let path = dir.path().join("part.nc");
    std::fs::write(&path, &text).unwrap();
    let streamed = c.submit_gcode_file("m", &path).await.unwrap();
    let whole = c.submit(&job("m", "part.nc", &text)).await.unwrap();
    assert_eq!(streamed.total_units, whole.total_units);
    let a: Vec<String> = stored(&d, streamed.id);
    let b: Vec<String> = stored(&d, whole.id);
    assert_eq!(a, b);
    let done = wait_end(&c, streamed.id).await;
    assert_eq!(done.state, JobState::Completed, "{:?}", done.error);
    // refusals name the file and the line, as for the whole file
    std::fs::write(&path, "G21\nG1 X10 F500\nG1 X100\n").unwrap();
    let e = c
        .submit_gcode_file("m", &path)
        .await
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("part.nc, line 3 `G1 X100`") && e.contains("outside machine `m`'s work area"),
        "{e}"
    );
    // refused early while the client is still sending megabytes: it still gets the answer
    let mut long = String::from("G21\nG1 X10 F500\nG1 X100\n");
    for _ in 0..200_000 {
        long.push_str("G1 X1 Y1\n");
    }
    std::fs::write(&path, &long).unwrap();
    let e = c
        .submit_gcode_file("m", &path)
        .await
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("part.nc, line 3 `G1 X100`"), "{e}");
    std::fs::write(&path, format!("G1 X1 F100\n({})\n", "x".repeat(5000))).unwrap();
    let e = c
        .submit_gcode_file("m", &path)
        .await
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("line 2") && e.contains("limit of 4096 bytes"),
        "{e}"
    );
    std::fs::write(&path, b"G1 X1 F100\nG1 X\xff\n").unwrap();
    let e = c
        .submit_gcode_file("m", &path)
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 2: the line is not text"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversized_body_is_refused_in_json() {
    let dir = tempfile::tempdir().unwrap();
    let d = start(
        dir.path(),
        "[[machine]]\nname = \"m\"\nlink = \"sim-grbl\"\n",
        StartOptions::default(),
    )
    .await;
    // declared larger than the limit: refused before a byte of it is read. The request's
    // head only, on the socket: a client that wrote the 64 MiB body first would race the
    // daemon, which answers and closes the connection under the body it will not read
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut s = tokio::net::UnixStream::connect(&d.socket).await.unwrap();
    let head = format!(
        "POST /jobs HTTP/1.1\r\nhost: machlink\r\ncontent-type: application/json\r\ncontent-length: {}\r\n\r\n",
        machlink::faces::api::limits::MAX_JSON_BODY + 1
    );
    s.write_all(head.as_bytes()).await.unwrap();
    let mut reply = Vec::new();
    let read = tokio::time::timeout(std::time::Duration::from_secs(30), async {
        let mut buf = [0u8; 4096];
        loop {
            let n = s.read(&mut buf).await.unwrap_or(0);
            if n == 0 {
                break;
            }
            reply.extend_from_slice(&buf[..n]);
            // the head and as many body bytes as it declares
            let text = String::from_utf8_lossy(&reply).to_string();
            if let Some((head, body)) = text.split_once("\r\n\r\n") {
                let len = head
                    .lines()
                    .find_map(|l| {
                        l.to_ascii_lowercase()
                            .strip_prefix("content-length:")
                            .map(|v| v.trim().to_string())
                    })
                    .and_then(|v| v.parse::<usize>().ok());
                if len.is_some_and(|len| body.len() >= len) {
                    break;
                }
            }
        }
    })
    .await;
    assert!(
        read.is_ok(),
        "no answer within 30 s: {:?}",
        String::from_utf8_lossy(&reply)
    );
    let text = String::from_utf8_lossy(&reply).to_string();
    let (head, body) = text.split_once("\r\n\r\n").expect("an HTTP answer");
    let st = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse::<hyper::StatusCode>().ok())
        .expect("a status line");
    let body = body.as_bytes().to_vec();
    assert_eq!(st.as_u16(), 413);
    let v: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert!(
        v["error"].as_str().unwrap().contains("limit of 64 MiB"),
        "{v}"
    );
}
