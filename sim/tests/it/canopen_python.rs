//! Interoperability with a CANopen stack machlink did not write, the python `canopen`
//! package (with python-can's SLCAN interface), both ways:
//! (a) python LocalNodes act as three drives behind a simulated SLCAN adapter and take
//!     machlink's SDO configuration, NMT commands and set-points (sim/tests/python/canopen_drives.py);
//! (b) a python master reads and writes the objects of `machlink-sim canopen` over SLCAN
//!     (sim/tests/python/canopen_master.py).
//! These tests fail, never skip, when python3 lacks the packages (.ci/requirements.txt).

use machlink_protocols::canopen::MemoryBus;
use machlink_protocols::kind::Registry;
use machlink_protocols::{Control, StreamEnd};
use machlink_sim::canopen::spawn_adapter;
use offset_core::{Move, Toolpath, P3};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::Command;
use tokio::sync::{mpsc, watch};

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/python")
        .join(name)
}

/// Fails (never skips) when python's canopen stack is missing, saying how to install it.
fn require_python_canopen() {
    let ok = std::process::Command::new("python3")
        .args(["-c", "import canopen, can, serial"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    assert!(
        ok,
        "python3 with canopen, python-can and pyserial is needed for this test: run .ci/run, \
         or `python3 -m pip install -r .ci/requirements.txt`"
    );
}

const COUNTS: f64 = 1000.0;

fn square() -> Toolpath {
    let mut tp = Toolpath::new("square");
    tp.push(Move::Rapid {
        to: P3::new(0.0, 0.0, 2.0),
    });
    for (x, y) in [(8.0, 0.0), (8.0, 8.0), (0.0, 8.0), (0.0, 0.0)] {
        tp.push(Move::Linear {
            to: P3::new(x, y, 2.0),
            feed: 900.0,
        });
    }
    tp
}

fn on_square(p: P3) -> f64 {
    let segs = [
        (P3::new(0.0, 0.0, 0.0), P3::new(0.0, 0.0, 2.0)),
        (P3::new(0.0, 0.0, 2.0), P3::new(8.0, 0.0, 2.0)),
        (P3::new(8.0, 0.0, 2.0), P3::new(8.0, 8.0, 2.0)),
        (P3::new(8.0, 8.0, 2.0), P3::new(0.0, 8.0, 2.0)),
        (P3::new(0.0, 8.0, 2.0), P3::new(0.0, 0.0, 2.0)),
    ];
    segs.iter()
        .map(|(a, b)| {
            let d = [b.x - a.x, b.y - a.y, b.z - a.z];
            let l2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            let t = (((p.x - a.x) * d[0] + (p.y - a.y) * d[1] + (p.z - a.z) * d[2]) / l2)
                .clamp(0.0, 1.0);
            p.dist(P3::new(a.x + d[0] * t, a.y + d[1] * t, a.z + d[2] * t))
        })
        .fold(f64::INFINITY, f64::min)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_canopen_local_nodes_take_machlinks_configuration_nmt_and_setpoints() {
    require_python_canopen();
    let bus = MemoryBus::new();
    let python_port = spawn_adapter(&bus).expect("an adapter for python");
    let machlink_port = spawn_adapter(&bus).expect("an adapter for machlink");
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("drives.jsonl");
    let mut python = Command::new("python3")
        .arg(script("canopen_drives.py"))
        .args(["--port", &python_port.path, "--nodes", "1,2,3", "--trace"])
        .arg(&trace)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .expect("python3 starts");
    let mut lines = BufReader::new(python.stdout.take().unwrap()).lines();
    let ready = tokio::time::timeout(Duration::from_secs(30), lines.next_line())
        .await
        .expect("the python drives say READY within 30 s")
        .unwrap();
    assert_eq!(
        ready.as_deref(),
        Some("READY"),
        "the python drives did not start"
    );

    // the real `canopen` kind, as the daemon opens it
    let mut registry = Registry::new();
    machlink_protocols::standard_kinds(&mut registry);
    let kind = registry.kind("canopen").unwrap().clone();
    let axis = |name: &str, node: u8| {
        serde_json::json!({ "axis": name, "node": node, "counts_per_mm": COUNTS,
            "max_velocity": 40.0, "max_acceleration": 400.0, "max_jerk": 8000.0 })
    };
    let settings = kind
        .settings(serde_json::json!({
            "bus": format!("slcan:{}@1000000", machlink_port.path),
            "mode": "ip", "period_ms": 10, "heartbeat_ms": 100, "heartbeat_timeout_ms": 1500,
            "sdo_timeout_ms": 1500, "state_timeout_ms": 2000, "report_timeout_ms": 1500,
            "axes": [axis("x", 1), axis("y", 2), axis("z", 3)]
        }))
        .expect("settings");
    let device = kind.start("python", &settings).await.unwrap();
    let mut link = kind
        .open("python", &settings, &device)
        .await
        .expect("opens");
    let program = registry.post("moves").unwrap().program(&square()).unwrap();
    let (tx, mut rx) = mpsc::unbounded_channel();
    let (_ctl, ctl_rx) = watch::channel(Control::Run);
    let end = tokio::time::timeout(
        Duration::from_secs(120),
        link.stream(&program, 0, tx, ctl_rx),
    )
    .await
    .expect("the job ends within two minutes");
    assert_eq!(
        end.expect("the job runs on python drives"),
        StreamEnd::Completed
    );
    let mut last_ack = None;
    while let Ok(ev) = rx.try_recv() {
        if let machlink_protocols::LinkEvent::Acked { unit } = ev {
            last_ack = Some(unit);
        }
    }
    assert_eq!(last_ack, Some(program.len() - 1));
    drop(python.stdin.take());
    let _ = tokio::time::timeout(Duration::from_secs(10), python.wait()).await;

    let records: Vec<Value> = std::fs::read_to_string(&trace)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for node in 1..=3u64 {
        let of = |ev: &'static str| {
            records
                .iter()
                .filter(move |r| r["event"] == ev && r["node"] == node)
        };
        let nmt: Vec<u64> = of("nmt").map(|r| r["command"].as_u64().unwrap()).collect();
        assert_eq!(
            nmt.first(),
            Some(&0x82),
            "node {node}: reset communication first: {nmt:?}"
        );
        assert!(nmt.contains(&0x01), "node {node}: started: {nmt:?}");
        let writes: Vec<(u64, u64, String)> = of("sdo_write")
            .map(|r| {
                (
                    r["index"].as_u64().unwrap(),
                    r["sub"].as_u64().unwrap(),
                    r["data"].as_str().unwrap().to_string(),
                )
            })
            .collect();
        let wrote =
            |i: u64, s: u64, d: &str| writes.iter().any(|w| w.0 == i && w.1 == s && w.2 == d);
        assert!(
            wrote(0x6060, 0, "07"),
            "node {node}: interpolated position mode: {writes:?}"
        );
        assert!(
            wrote(0x60C2, 1, "0a") && wrote(0x60C2, 2, "fd"),
            "node {node}: 10 ms period"
        );
        assert!(wrote(0x1017, 0, "6400"), "node {node}: heartbeat 100 ms");
        assert!(
            wrote(0x1600, 1, "2001c160"),
            "node {node}: RPDO1 maps 0x60C1:01"
        );
        assert!(
            wrote(0x1A00, 1, "20006460") && wrote(0x1A00, 2, "2000f460"),
            "node {node}: TPDO1 maps 0x6064, 0x60F4"
        );
        assert!(
            wrote(0x1400, 1, &format!("{node:02x}020080"))
                && wrote(0x1400, 1, &format!("{node:02x}020000")),
            "node {node}: RPDO1 invalidated while mapped, then made valid: {writes:?}"
        );
        for cw in ["0600", "0700", "1f00"] {
            assert!(wrote(0x6040, 0, cw), "node {node}: controlword {cw}");
        }
    }
    // the set-points, decoded by python with the mapping machlink wrote, lie on the path
    let mut by_sync: BTreeMap<u64, [Option<f64>; 3]> = BTreeMap::new();
    for r in records.iter().filter(|r| r["event"] == "setpoint") {
        let n = r["node"].as_u64().unwrap() as usize;
        let s = r["sync"].as_u64().unwrap();
        by_sync.entry(s).or_default()[n - 1] = Some(r["value"].as_i64().unwrap() as f64 / COUNTS);
    }
    let points: Vec<P3> = by_sync
        .values()
        .filter_map(|v| Some(P3::new(v[0]?, v[1]?, v[2]?)))
        .collect();
    assert!(points.len() > 100, "{} cycles of set-points", points.len());
    for p in &points {
        assert!(on_square(*p) <= 2.0 / COUNTS, "{p:?} is off the path");
    }
    assert!(points.last().unwrap().dist(P3::new(0.0, 0.0, 2.0)) <= 1.0 / COUNTS);
    // the far corner is reached, not cut: set-points on both of its sides, close to it (a
    // set-point need not fall on the corner itself: it is passed at up to 2 mm/s, 20 µm a
    // cycle, and the planner lands on it only when the corner's cap is what binds)
    let near = |p: &P3| p.dist(P3::new(8.0, 8.0, 2.0)) <= 0.05;
    assert!(
        points
            .iter()
            .any(|p| near(p) && (p.x - 8.0).abs() <= 1.0 / COUNTS && p.y < 8.0)
            && points
                .iter()
                .any(|p| near(p) && (p.y - 8.0).abs() <= 1.0 / COUNTS && p.x < 8.0),
        "passes the far corner"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_python_canopen_master_reads_and_writes_the_simulators_objects() {
    require_python_canopen();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("can0");
    let mut sim = Command::new(env!("CARGO_BIN_EXE_machlink-sim"))
        .args(["canopen", "--slcan-pty"])
        .arg(&link)
        .args(["--nodes", "1,2,3"])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .expect("machlink-sim starts");
    let mut lines = BufReader::new(sim.stdout.take().unwrap()).lines();
    let said = tokio::time::timeout(Duration::from_secs(30), lines.next_line())
        .await
        .expect("the simulator names its pty")
        .unwrap();
    assert_eq!(said.as_deref(), Some(link.to_str().unwrap()));
    let out = tokio::time::timeout(
        Duration::from_secs(120),
        Command::new("python3")
            .arg(script("canopen_master.py"))
            .arg("--port")
            .arg(&link)
            .args(["--nodes", "1,2,3"])
            .output(),
    )
    .await
    .expect("the python master finishes within two minutes")
    .unwrap();
    assert!(
        out.status.success(),
        "the python master failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let found: Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    for node in ["1", "2", "3"] {
        let r = &found[node];
        assert_eq!(
            r["device_type"], "92010200",
            "node {node}: profile 402, servo drive"
        );
        assert!(
            r["device_name"].as_str().unwrap().contains("402"),
            "node {node}: {r}"
        );
        assert_eq!(r["mode_display"], 8, "node {node}");
        assert_eq!(r["ip_period"], 4, "node {node}");
        assert_eq!(
            r["statusword_after_shutdown"].as_u64().unwrap() & 0x6F,
            0x21,
            "node {node}: ready to switch on"
        );
        assert_eq!(
            r["statusword_after_switch_on"].as_u64().unwrap() & 0x6F,
            0x23,
            "node {node}: switched on"
        );
        assert_eq!(
            r["write_statusword"], 0x0601_0002u32,
            "node {node}: the statusword is read-only"
        );
        assert_eq!(
            r["read_missing"], 0x0602_0000u32,
            "node {node}: no object 0x5FFF"
        );
        assert_eq!(
            r["write_name"], 0x0601_0002u32,
            "node {node}: a segmented write to a read-only object"
        );
        assert_eq!(r["nmt_state"], "OPERATIONAL", "node {node}");
    }
    sim.kill().await.ok();
}
