//! `machlink-sim grbl|modbus|sewing --trace FILE`: every simulator run from the command line
//! writes what it received and executed as JSON lines, readable while it runs, so a test or
//! an operator outside the process can check what the device did.

use machlink_protocols::grbl::{GrblLink, GrblOptions};
use machlink_protocols::modbus::{post_blocks, ModbusLink, ModbusSettings};
use machlink_protocols::sewing::link::{SewingLink, SewingTiming};
use machlink_protocols::sewing::{records, RecordLimits};
use machlink_protocols::{Control, Link, StreamEnd};
use offset_core::geom::{Point, Polyline, Shape};
use offset_core::stitch::{stitch, StitchParams};
use offset_core::{Move, Toolpath, P3};
use std::io::BufRead;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};

/// `machlink-sim ARGS`, and the first line it prints (where it listens).
fn sim(args: &[&str]) -> (Child, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_machlink-sim"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    (child, first.trim().to_string())
}

/// The trace's JSON objects, once it holds at least `n` with `"event": event`.
fn trace_with(path: &Path, event: &str, n: usize) -> Vec<serde_json::Value> {
    let until = Instant::now() + Duration::from_secs(30);
    loop {
        let text = std::fs::read_to_string(path).unwrap_or_default();
        let v: Vec<serde_json::Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).expect("one JSON object per line"))
            .collect();
        if v.iter().filter(|e| e["event"] == event).count() >= n {
            return v;
        }
        assert!(
            Instant::now() < until,
            "the trace never got {n} {event}: {text}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn channels() -> (
    mpsc::UnboundedSender<machlink_protocols::LinkEvent>,
    watch::Receiver<Control>,
    watch::Sender<Control>,
) {
    let (etx, _erx) = mpsc::unbounded_channel();
    let (ctx, crx) = watch::channel(Control::Run);
    (etx, crx, ctx)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_grbl_simulator_traces_every_line_received_and_move_executed() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("grbl0");
    let trace = dir.path().join("grbl.jsonl");
    let (mut child, _) = sim(&[
        "grbl",
        "--pty",
        port.to_str().unwrap(),
        "--time-scale",
        "inf",
        "--offset",
        "G55=5,5,0",
        "--trace",
        trace.to_str().unwrap(),
    ]);
    let lines: Vec<String> = ["G21 G90", "G55", "G0 X1 Y1", "G1 X4 F600", "G2 X6 Y3 I0 J2"]
        .iter()
        .map(|l| l.to_string())
        .collect();
    let mut link = GrblLink::open(port.to_str().unwrap(), GrblOptions::default())
        .await
        .unwrap();
    let (etx, crx, _ctx) = channels();
    assert_eq!(
        link.stream(&lines, 0, etx, crx).await.unwrap(),
        StreamEnd::Completed
    );
    let t = trace_with(&trace, "executed", 3);
    let _ = child.kill();
    let _ = child.wait();
    let received: Vec<&str> = t
        .iter()
        .filter(|e| e["event"] == "received" && !e["n"].is_null())
        .map(|e| e["line"].as_str().unwrap())
        .collect();
    assert_eq!(received, lines);
    let executed: Vec<&serde_json::Value> = t.iter().filter(|e| e["event"] == "executed").collect();
    assert_eq!(executed[1]["line"], "G1X4F600");
    assert_eq!(executed[1]["index"], 4);
    // machine coordinates: G55's zero is at (5, 5)
    assert_eq!(executed[1]["to"], serde_json::json!([9.0, 6.0, 0.0]));
    assert_eq!(executed[1]["feed"], 600.0);
    assert_eq!(executed[2]["motion"], "ArcCw");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_modbus_simulator_traces_every_block_written_and_executed() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("modbus.jsonl");
    let (mut child, first) = sim(&[
        "modbus",
        "--tcp",
        "127.0.0.1:0",
        "--time-scale",
        "inf",
        "--trace",
        trace.to_str().unwrap(),
    ]);
    let addr: std::net::SocketAddr = first.rsplit(' ').next().unwrap().parse().unwrap();
    let mut tp = Toolpath::new("square");
    for (x, y) in [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)] {
        tp.push(Move::Linear {
            to: P3::new(x, y, 0.0),
            feed: 500.0,
        });
    }
    let blocks = post_blocks(&tp).unwrap();
    let mut link = ModbusLink::new(ModbusSettings::tcp("127.0.0.1", addr.port())).unwrap();
    let (etx, crx, _ctx) = channels();
    assert_eq!(
        link.stream(&blocks, 0, etx, crx).await.unwrap(),
        StreamEnd::Completed
    );
    let t = trace_with(&trace, "executed", blocks.len());
    let _ = child.kill();
    let _ = child.wait();
    let seqs = |event: &str| -> Vec<u64> {
        t.iter()
            .filter(|e| e["event"] == event)
            .map(|e| e["seq"].as_u64().unwrap())
            .collect()
    };
    let all: Vec<u64> = (1..=blocks.len() as u64).collect();
    assert_eq!(seqs("executed"), all);
    assert_eq!(seqs("written"), all);
    assert!(t.iter().any(|e| e["event"] == "synced" && e["at"] == 0));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_sewing_simulator_traces_every_record_and_event() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("sewer");
    let trace = dir.path().join("sewing.jsonl");
    let (mut child, _) = sim(&[
        "sewing",
        "--pty",
        port.to_str().unwrap(),
        "--time-scale",
        "50",
        "--trace",
        trace.to_str().unwrap(),
    ]);
    let label = Polyline::rect(Point::new(-20.0, 0.0), Point::new(20.0, 20.0));
    let tp = stitch(&Shape::new(vec![label]), &StitchParams::default()).unwrap();
    let recs = records(&tp, RecordLimits::DST).unwrap();
    let mut link =
        SewingLink::open(port.to_str().unwrap(), 115_200, SewingTiming::default()).unwrap();
    let (etx, crx, _ctx) = channels();
    assert_eq!(
        link.stream(&recs, 0, etx, crx).await.unwrap(),
        StreamEnd::Completed
    );
    let t = trace_with(&trace, "record", recs.len());
    let _ = child.kill();
    let _ = child.wait();
    let indices: Vec<u64> = t
        .iter()
        .filter(|e| e["event"] == "record")
        .map(|e| e["index"].as_u64().unwrap())
        .collect();
    assert_eq!(indices, (0..recs.len() as u64).collect::<Vec<_>>());
    let notes: Vec<&str> = t
        .iter()
        .filter(|e| e["event"] == "note")
        .map(|e| e["text"].as_str().unwrap())
        .collect();
    assert!(
        notes.iter().any(|n| n.starts_with("upload begun")),
        "{notes:?}"
    );
    assert!(notes.contains(&"start at 0"), "{notes:?}");
}
