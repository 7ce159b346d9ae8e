//! Interoperability: the Modbus link streams a job into a device written with pymodbus
//! (tests/python/modbus_device.py), over TCP and over RTU on a pty, and the blocks the Python
//! device recorded are the job's blocks, once each, in order; at a tool change block the
//! device holds (docs/modbus.md, rule 10a) and the link reports the tool and resumes it only
//! after the operator's hold and run.

use machlink_protocols::modbus::{post_blocks, ModbusLink, ModbusSettings, MotionBlock};
use machlink_protocols::{Control, Link, StreamEnd};
use offset_core::{Move, Point, Toolpath, P3};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};
use tokio::sync::{mpsc, watch};

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("python/modbus_device.py")
}

/// Fails (never skips) when pymodbus is missing, saying how to install it.
fn require_pymodbus() {
    let ok = std::process::Command::new("python3")
        .args(["-c", "import pymodbus, serial"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    assert!(
        ok,
        "python3 with pymodbus and pyserial is needed for this test: run .ci/run, or \
         `python3 -m pip install -r .ci/requirements.txt`"
    );
}

/// Starts the Python device and waits for its READY line.
async fn start_device(args: &[&str], trace: &Path) -> Child {
    let mut child = Command::new("python3")
        .arg(script())
        .args(args)
        .arg("--trace")
        .arg(trace)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .expect("python3 starts");
    let stdout = child.stdout.take().expect("piped stdout");
    let mut lines = BufReader::new(stdout).lines();
    let ready = tokio::time::timeout(Duration::from_secs(20), lines.next_line())
        .await
        .expect("the Python device says READY within 20 s")
        .expect("the Python device's stdout is readable");
    assert_eq!(
        ready.as_deref(),
        Some("READY"),
        "the Python device did not start"
    );
    child
}

fn job(n: usize) -> Vec<MotionBlock> {
    let mut tp = Toolpath::new("interop");
    tp.push(Move::Rapid {
        to: P3::new(-5.0, -5.0, 3.0),
    });
    for i in 1..n {
        let a = i as f64 * 0.01;
        let to = P3::new(-5.0 + a, -5.0 + (a * 3.0).sin(), -1.25);
        if i % 7 == 0 {
            tp.push(Move::Arc {
                to,
                center: Point::new(to.x - 1.0, to.y),
                ccw: i % 2 == 0,
                feed: 1234.5,
            });
        } else {
            tp.push(Move::Linear { to, feed: 700.0 });
        }
    }
    tp.push(Move::Dwell { seconds: 0.25 });
    post_blocks(&tp).unwrap()
}

async fn stream(settings: ModbusSettings, blocks: &[MotionBlock]) -> StreamEnd {
    let mut link = ModbusLink::new(settings).unwrap();
    let program = blocks.to_vec();
    let (tx, _rx) = mpsc::unbounded_channel();
    let (_ctl, ctl_rx) = watch::channel(Control::Run);
    tokio::time::timeout(
        Duration::from_secs(60),
        link.stream(&program, 0, tx, ctl_rx),
    )
    .await
    .expect("the stream ends within a minute")
    .expect("the stream succeeds")
}

/// The Python device's trace is exactly the job, in order.
fn assert_recorded(trace: &Path, blocks: &[MotionBlock]) {
    let text = std::fs::read_to_string(trace).unwrap();
    let rec: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    assert_eq!(
        rec.len(),
        blocks.len(),
        "recorded {} of {} blocks",
        rec.len(),
        blocks.len()
    );
    for (i, (r, b)) in rec.iter().zip(blocks).enumerate() {
        let want = serde_json::json!({
            "seq": i + 1,
            "kind": b.kind as u16,
            "target": b.target,
            "feed": b.feed,
            "center": b.center,
        });
        assert_eq!(r, &want, "block {i} as pymodbus recorded it");
    }
}

fn settings(mut s: ModbusSettings) -> ModbusSettings {
    s.timeout = Duration::from_secs(2);
    s.poll_interval = Duration::from_millis(5);
    s
}

#[tokio::test]
async fn pymodbus_tcp_device_records_the_job() {
    require_pymodbus();
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("trace.jsonl");
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let _dev = start_device(&["--tcp", &port.to_string(), "--capacity", "24"], &trace).await;
    let blocks = job(1500);
    let mut s = settings(ModbusSettings::tcp("127.0.0.1", port));
    s.max_write_registers = 120;
    assert_eq!(stream(s, &blocks).await, StreamEnd::Completed);
    assert_recorded(&trace, &blocks);
}

#[tokio::test]
async fn pymodbus_rtu_device_records_the_job() {
    require_pymodbus();
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("trace.jsonl");
    // Two pty pairs joined master to master, like a null-modem cable: the link opens one
    // slave end, pymodbus the other. The slave ends stay open here so that neither master
    // sees a hang-up when a side reopens its port.
    use tokio_serial::SerialPort;
    let (mut ma, sa) = tokio_serial::SerialStream::pair().unwrap();
    let (mut mb, sb) = tokio_serial::SerialStream::pair().unwrap();
    let (link_port, dev_port) = (sa.name().unwrap(), sb.name().unwrap());
    let cable = tokio::spawn(async move {
        let _ = tokio::io::copy_bidirectional(&mut ma, &mut mb).await;
    });
    let _dev = start_device(
        &[
            "--rtu",
            &dev_port,
            "--unit",
            "5",
            "--base",
            "200",
            "--word-order",
            "low-first",
        ],
        &trace,
    )
    .await;
    let blocks = job(600);
    let mut s = settings(ModbusSettings::rtu(&link_port, 115_200));
    s.unit_id = 5;
    s.base_address = 200;
    s.word_order = machlink_protocols::modbus::WordOrder::LowFirst;
    s.max_write_registers = 12;
    assert_eq!(stream(s, &blocks).await, StreamEnd::Completed);
    assert_recorded(&trace, &blocks);
    cable.abort();
    drop((sa, sb));
}

/// A job with a tool change in the middle, into the pymodbus device: the device holds at the
/// tool block, the link reports the tool to load and does not resume it on its own (the
/// device records nothing more while the control stays at run), and after the operator's
/// hold and resume every block is recorded once, in order.
#[tokio::test]
async fn pymodbus_device_holds_at_a_tool_change_until_the_operator_resumes() {
    require_pymodbus();
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("trace.jsonl");
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let _dev = start_device(&["--tcp", &port.to_string(), "--capacity", "8"], &trace).await;
    let mut tp = Toolpath::new("tools");
    for (k, tool) in [1u32, 2].into_iter().enumerate() {
        tp.push(Move::ToolChange {
            tool,
            name: String::new(),
            geometry: None,
        });
        for i in 0..20 {
            tp.push(Move::Linear {
                to: P3::new(k as f64 * 10.0 + i as f64 * 0.5, 1.0, -0.5),
                feed: 600.0,
            });
        }
    }
    let blocks = post_blocks(&tp).unwrap();
    let at = |tool: u32| {
        blocks
            .iter()
            .position(|b| {
                b.kind == machlink_protocols::modbus::map::BlockKind::ToolChange && b.feed == tool
            })
            .unwrap()
    };
    let mut link = ModbusLink::new(settings(ModbusSettings::tcp("127.0.0.1", port))).unwrap();
    let (tx, mut rx) = mpsc::unbounded_channel();
    let (ctl, ctl_rx) = watch::channel(Control::Run);
    let program = blocks.clone();
    let run = tokio::spawn(async move { link.stream(&program, 0, tx, ctl_rx).await });
    let recorded = |trace: &Path| {
        std::fs::read_to_string(trace)
            .unwrap_or_default()
            .lines()
            .count()
    };
    for tool in [1u32, 2] {
        // the link says which tool to load
        let want = machlink_protocols::DeviceState::NeedsOperator {
            reason: machlink_protocols::OperatorReason::LoadTool {
                number: tool,
                name: String::new(),
            },
        };
        tokio::time::timeout(Duration::from_secs(20), async {
            loop {
                match rx.recv().await.expect("the link reports") {
                    machlink_protocols::LinkEvent::Status(s) if s.state == want => break,
                    _ => {}
                }
            }
        })
        .await
        .unwrap_or_else(|_| panic!("the link never asked for T{tool}"));
        // held before the tool block: nothing more runs while the control stays at run
        let before = recorded(&trace);
        assert_eq!(before, at(tool), "blocks run before the change to T{tool}");
        tokio::time::sleep(Duration::from_millis(400)).await;
        assert_eq!(
            recorded(&trace),
            before,
            "the device ran on past the change to T{tool}"
        );
        // the operator's pause, then resume
        ctl.send(Control::Hold).unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert_eq!(recorded(&trace), before);
        ctl.send(Control::Run).unwrap();
    }
    let end = tokio::time::timeout(Duration::from_secs(30), run)
        .await
        .expect("the stream ends")
        .unwrap()
        .expect("the stream succeeds");
    assert_eq!(end, StreamEnd::Completed);
    assert_recorded(&trace, &blocks);
}
