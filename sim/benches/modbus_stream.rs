//! Modbus streaming throughput: blocks per second from the link into the simulated device
//! (executing at once), over TCP on loopback and over RTU on a pty whose line the device
//! models at 115200 baud, against the framing bound measured in the same run.
//! Run: cargo bench -p machlink-sim --bench modbus_stream

use machlink_protocols::modbus::{ModbusLink, ModbusSettings, MotionBlock};
use machlink_protocols::{Control, Link, StreamEnd};
use machlink_sim::modbus::{ModbusSim, SimConfig};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};

fn job(n: usize) -> Vec<MotionBlock> {
    let mut tp = offset_core::Toolpath::new("bench");
    for i in 0..n - 1 {
        let x = i as f64 * 0.01;
        tp.push(offset_core::Move::Linear {
            to: offset_core::P3::new(x, (x * 7.0).sin(), -1.0),
            feed: 1000.0,
        });
    }
    machlink_protocols::modbus::post_blocks(&tp).unwrap()
}

struct Row {
    name: String,
    blocks: usize,
    secs: f64,
    requests: u64,
    wire_bytes: u64,
    frames: u64,
    rtu_baud: Option<u32>,
}

async fn run(name: String, sim: ModbusSim, mut s: ModbusSettings, blocks: usize) -> Row {
    s.poll_interval = Duration::from_millis(2);
    let mut link = ModbusLink::new(s).unwrap();
    let program = job(blocks);
    let (tx, _rx) = mpsc::unbounded_channel();
    let (_ctl, ctl_rx) = watch::channel(Control::Run);
    let t = Instant::now();
    let end = link.stream(&program, 0, tx, ctl_rx).await.unwrap();
    let secs = t.elapsed().as_secs_f64();
    assert_eq!(end, StreamEnd::Completed);
    assert_eq!(sim.trace().len(), blocks, "every block executed");
    let st = sim.stats();
    Row {
        name,
        blocks,
        secs,
        requests: link.requests(),
        wire_bytes: st.wire_bytes,
        frames: st.frames,
        rtu_baud: None,
    }
}

fn instant() -> SimConfig {
    SimConfig {
        time_scale: 0.0,
        capacity: 64,
        ..SimConfig::default()
    }
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let mut rows = Vec::new();
    for regs in [123, 12] {
        let sim = ModbusSim::spawn_tcp(instant(), "127.0.0.1:0".parse().unwrap())
            .await
            .unwrap();
        let mut s = ModbusSettings::tcp("127.0.0.1", sim.addr().port());
        s.max_write_registers = regs;
        let name = format!("TCP loopback, {regs} registers per write, FC23");
        rows.push(run(name, sim, s, 20_000).await);
    }
    let baud = 115_200;
    let n = if quick { 1_000 } else { 3_000 };
    for (regs, fc23) in [(123, true), (123, false), (12, true), (12, false)] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rtu");
        let cfg = SimConfig {
            line_baud: Some(baud),
            read_write: fc23,
            ..instant()
        };
        let sim = ModbusSim::spawn_pty(cfg, Some(&path)).await.unwrap();
        let mut s = ModbusSettings::rtu(path.to_str().unwrap(), baud);
        s.max_write_registers = regs;
        let how = if fc23 {
            "FC23 commit + header"
        } else {
            "device without FC23: FC16 commit, FC3 header"
        };
        let name = format!("RTU pty at {baud} baud, {regs} registers per write, {how}");
        let mut row = run(name, sim, s, n).await;
        row.rtu_baud = Some(baud);
        rows.push(row);
    }
    // The anchors. The raw line: 115200 baud carries 11520 bytes/s at 10 bits a byte, so at
    // 32 bytes of registers a block no link beats 360 blocks/s. The framing bound: the same
    // run's frames back to back, each followed by the 3.5 characters of silence RTU demands
    // ((wire bytes + 3.5 × frames) × 10 / baud seconds), i.e. what this request pattern
    // could reach if no time at all were lost between frames.
    let line_blocks = baud as f64 / 10.0 / 32.0;
    println!(
        "| case | blocks | blocks/s | requests/s | wire bytes/block | framing bound (blocks/s) | measured / bound | of the raw line's {line_blocks:.0} blocks/s |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for r in &rows {
        let bps = r.blocks as f64 / r.secs;
        let (bound, of_bound, of_line) = match r.rtu_baud {
            Some(b) => {
                let busy = (r.wire_bytes as f64 + 3.5 * r.frames as f64) * 10.0 / b as f64;
                let bound = r.blocks as f64 / busy;
                (
                    format!("{bound:.0}"),
                    format!("{:.1} %", 100.0 * bps / bound),
                    format!("{:.0} %", 100.0 * bps / line_blocks),
                )
            }
            None => ("–".into(), "–".into(), "–".into()),
        };
        println!(
            "| {} | {} | {:.0} | {:.0} | {:.1} | {bound} | {of_bound} | {of_line} |",
            r.name,
            r.blocks,
            bps,
            r.requests as f64 / r.secs,
            r.wire_bytes as f64 / r.blocks as f64,
        );
    }
}
