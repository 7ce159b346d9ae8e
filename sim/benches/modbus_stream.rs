//! Modbus streaming throughput: blocks per second from the link into the simulated device
//! (executing at once), over TCP on loopback and over RTU on a pty paced as a 115200-baud
//! line, against what the line could carry. Run: cargo bench -p machlink-sim --bench modbus_stream

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
}

async fn run(name: &str, sim: ModbusSim, mut s: ModbusSettings, blocks: usize, regs: u16) -> Row {
    s.max_write_registers = regs;
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
    Row {
        name: format!("{name}, {regs} registers per write"),
        blocks,
        secs,
        requests: link.requests,
        wire_bytes: sim.stats().wire_bytes,
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
    let mut rows = Vec::new();
    for regs in [123, 12] {
        let sim = ModbusSim::spawn_tcp(instant(), "127.0.0.1:0".parse().unwrap())
            .await
            .unwrap();
        let s = ModbusSettings::tcp("127.0.0.1", sim.addr().port());
        rows.push(run("TCP loopback", sim, s, 20_000, regs).await);
    }
    let baud = 115_200;
    for regs in [123, 12] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rtu");
        let cfg = SimConfig {
            line_baud: Some(baud),
            ..instant()
        };
        let sim = ModbusSim::spawn_pty(cfg, Some(&path)).await.unwrap();
        let s = ModbusSettings::rtu(path.to_str().unwrap(), baud);
        rows.push(run("RTU pty at 115200 baud", sim, s, 1_500, regs).await);
    }
    // The anchor: a 115200-baud line carries 11520 bytes/s at 10 bits per byte, and a block
    // is 32 bytes of registers, so no RTU link can beat 360 blocks/s on it.
    let line_blocks = baud as f64 / 10.0 / 32.0;
    println!(
        "| case | blocks | blocks/s | requests/s | wire bytes/block | of the line's 360 blocks/s |"
    );
    println!("|---|---|---|---|---|---|");
    for r in &rows {
        let bps = r.blocks as f64 / r.secs;
        let of_line = if r.name.starts_with("RTU") {
            format!("{:.0} %", 100.0 * bps / line_blocks)
        } else {
            "-".into()
        };
        println!(
            "| {} | {} | {:.0} | {:.0} | {:.1} | {} |",
            r.name,
            r.blocks,
            bps,
            r.requests as f64 / r.secs,
            r.wire_bytes as f64 / r.blocks as f64,
            of_line
        );
    }
}
