//! docs/canopen.md's start-up rules against drives machlink did not write: python `canopen`
//! LocalNodes (sim/tests/python/canopen_drives.py) behind a simulated SLCAN adapter, one of
//! them stuck in ready to switch on. machlink writes controlword 0x0006 to every node before
//! the first reset communication and 0x605A := 2 at configuration; when the stuck node fails
//! its power-up after the others reached operation enabled, each of the others is shut down
//! (ready to switch on) and every node is sent NMT enter pre-operational.
//! Fails, never skips, when python3 lacks the packages (.ci/requirements.txt).

use machlink_protocols::canopen::MemoryBus;
use machlink_protocols::kind::Registry;
use machlink_protocols::Control;
use machlink_sim::canopen::spawn_adapter;
use offset_core::{Move, Toolpath, P3};
use serde_json::Value;
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::Command;
use tokio::sync::{mpsc, watch};

/// The power states the python drives trace (statusword bits 0–6).
const READY: u64 = 0x21;
const ENABLED: u64 = 0x27;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_drives_are_shut_down_and_pre_operational_after_one_fails_its_power_up() {
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
    let bus = MemoryBus::new();
    let python_port = spawn_adapter(&bus).expect("an adapter for python");
    let machlink_port = spawn_adapter(&bus).expect("an adapter for machlink");
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("drives.jsonl");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/canopen_drives.py");
    let mut python = Command::new("python3")
        .arg(script)
        .args([
            "--port",
            &python_port.path,
            "--nodes",
            "1,2,3",
            "--stuck",
            "3",
            "--trace",
        ])
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

    let mut registry = Registry::new();
    machlink_protocols::standard_kinds(&mut registry);
    let kind = registry.kind("canopen").unwrap().clone();
    let axis = |name: &str, node: u8| {
        serde_json::json!({ "axis": name, "node": node, "counts_per_mm": 1000.0,
            "max_velocity": 40.0, "max_acceleration": 400.0, "max_jerk": 8000.0 })
    };
    let settings = kind
        .settings(serde_json::json!({
            "bus": format!("slcan:{}@1000000", machlink_port.path),
            "mode": "ip", "period_ms": 10, "heartbeat_ms": 100, "heartbeat_timeout_ms": 1500,
            "sdo_timeout_ms": 1500, "state_timeout_ms": 500, "report_timeout_ms": 1500,
            "axes": [axis("x", 1), axis("y", 2), axis("z", 3)]
        }))
        .expect("settings");
    let device = kind.start("python", &settings).await.unwrap();
    let mut link = kind
        .open("python", &settings, &device)
        .await
        .expect("opens");
    let mut tp = Toolpath::new("line");
    tp.push(Move::Linear {
        to: P3::new(5.0, 5.0, 1.0),
        feed: 600.0,
    });
    let program = registry.post("moves").unwrap().program(&tp).unwrap();
    let (tx, _rx) = mpsc::unbounded_channel();
    let (_ctl, ctl_rx) = watch::channel(Control::Run);
    let end = tokio::time::timeout(
        Duration::from_secs(60),
        link.stream(&program, 0, tx, ctl_rx),
    )
    .await
    .expect("the start-up ends within a minute");
    let e = end.expect_err("node 3 never reaches switched on");
    assert!(e.to_string().contains("node 3"), "{e}");
    // let the last frames reach python, then stop it
    tokio::time::sleep(Duration::from_millis(500)).await;
    drop(python.stdin.take());
    let _ = tokio::time::timeout(Duration::from_secs(10), python.wait()).await;

    let records: Vec<Value> = std::fs::read_to_string(&trace)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for node in 1..=3u64 {
        let at = |pred: &dyn Fn(&Value) -> bool| {
            records.iter().position(|r| r["node"] == node && pred(r))
        };
        let cw = |d: &'static str| {
            move |r: &Value| r["event"] == "sdo_write" && r["index"] == 0x6040 && r["data"] == d
        };
        let nmt = |c: u64| move |r: &Value| r["event"] == "nmt" && r["command"] == c;
        let shutdown = at(&cw("0600")).unwrap_or_else(|| panic!("node {node}: no 0x0006"));
        let reset = at(&nmt(0x82)).unwrap_or_else(|| panic!("node {node}: no reset communication"));
        assert!(
            shutdown < reset,
            "node {node}: shutdown before the reset communication"
        );
        assert!(
            at(&|r: &Value| r["event"] == "sdo_write"
                && r["index"] == 0x605A
                && r["data"] == "0200")
            .is_some(),
            "node {node}: 0x605A := 2"
        );
        let start = at(&nmt(0x01)).unwrap_or_else(|| panic!("node {node}: never started"));
        let pre_op = records
            .iter()
            .skip(start)
            .any(|r| r["node"] == node && nmt(0x80)(r));
        assert!(
            pre_op,
            "node {node}: enter pre-operational after the failed start-up"
        );
        let states: Vec<u64> = records
            .iter()
            .filter(|r| r["node"] == node && r["event"] == "state")
            .map(|r| r["state"].as_u64().unwrap())
            .collect();
        if node < 3 {
            assert!(
                states.contains(&ENABLED),
                "node {node} reached operation enabled: {states:?}"
            );
        }
        assert_eq!(
            states.last(),
            Some(&READY),
            "node {node} is left ready to switch on: {states:?}"
        );
    }
}
