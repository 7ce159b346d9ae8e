//! Soak: one `machlink serve` process streams to 24 simulated machines (18 GRBL on ptys
//! paced at 115200 baud, 6 Modbus motion-block devices on loopback TCP) for at least
//! 10 minutes of simulated time; the simulators run in this process, so the daemon's CPU
//! share and resident memory (from /proc) are its own. Then each link's capacity: the
//! same program to one machine of each kind whose motion finishes at once, so only the
//! link limits it.
//!
//! `cargo bench -p machlink --bench soak` (`-- --minutes M --time-scale K` to change the
//! simulated duration and speed-up; default 10 and 5).

use machlink::core::intake::{Input, JobSpec};
use machlink::core::store::JobState;
use machlink::faces::client::{Client, Endpoint};
use machlink_sim::grbl::{GrblSim, GrblSimConfig, GrblSimHandle};
use machlink_sim::modbus::{ModbusSim, SimConfig};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const GRBL: usize = 18;
const MODBUS: usize = 6;
const BAUD: u32 = 115_200;
/// Feed and length of every move: 1 mm at 1200 mm/min, 50 ms of simulated motion.
const FEED: f64 = 1200.0;

fn arg(name: &str, default: f64) -> f64 {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// `n` 1 mm moves on a zig-zag, as a G-code file.
fn program(n: usize) -> String {
    let mut s = String::from("G21 G90\nG1 Z-0.5 F600\n");
    for i in 0..n {
        let row = i / 50;
        let col = i % 50;
        let x = if row % 2 == 0 { col } else { 49 - col } as f64;
        s.push_str(&format!("G1 X{x:.1} Y{:.1} F{FEED}\n", row as f64 * 0.5));
    }
    s
}

struct Daemon {
    child: Child,
    socket: PathBuf,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn serve(dir: &Path, machines: &str) -> Daemon {
    let cfg = dir.join("machlink.toml");
    std::fs::write(
        &cfg,
        format!("[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\n\n{machines}"),
    )
    .unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_machlink"))
        .args(["serve", "--config"])
        .arg(&cfg)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("serve.log")).unwrap())
        .spawn()
        .expect("machlink serve");
    let socket = dir.join("ml.sock");
    while !socket.exists() {
        std::thread::sleep(Duration::from_millis(20));
    }
    Daemon { child, socket }
}

/// CPU seconds (user + system) and resident kB of a process, from /proc.
fn usage(pid: u32) -> (f64, u64) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, r)| r.split_whitespace().collect())
        .unwrap_or_default();
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // utime and stime are fields 14 and 15 of stat, 12 and 13 after the name
    let hz = 100.0;
    let cpu = (ticks(11) + ticks(12)) / hz;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let rss = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or(0);
    (cpu, rss)
}

fn job(machine: &str, text: &str) -> JobSpec {
    JobSpec {
        machine: Some(machine.into()),
        input: Input::from_bytes("soak.nc", text.as_bytes().to_vec()),
        operation: None,
        tolerance: None,
        layers: Vec::new(),
        post: None,
    }
}

/// Runs one job on each machine at once; returns per machine (name, units, wall seconds).
async fn run_all(c: &Client, machines: &[String], text: &str) -> Vec<(String, usize, f64)> {
    let start = Instant::now();
    let mut ids = Vec::new();
    for m in machines {
        ids.push((
            m.clone(),
            c.submit(&job(m, text)).await.expect("submitted").id,
        ));
    }
    let mut out = Vec::new();
    for (m, id) in ids {
        let j = loop {
            let j = c.job(id).await.unwrap();
            if j.state.is_final() {
                break j;
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        };
        assert_eq!(j.state, JobState::Completed, "{j:?}");
        let secs = (j.finished_ms.unwrap_or(0) - j.started_ms.unwrap_or(0)) as f64 / 1000.0;
        let _ = start;
        out.push((m, j.total_units, secs));
    }
    out
}

fn grbl_machines(sims: &[GrblSimHandle], prefix: &str) -> (String, Vec<String>) {
    let mut toml = String::new();
    let mut names = Vec::new();
    for (i, s) in sims.iter().enumerate() {
        let name = format!("{prefix}{i:02}");
        toml.push_str(&format!(
            "[[machine]]\nname = \"{name}\"\nlink = \"grbl\"\nport = \"{}\"\n\n",
            s.port().display()
        ));
        names.push(name);
    }
    (toml, names)
}

fn modbus_machines(sims: &[ModbusSim], prefix: &str) -> (String, Vec<String>) {
    let mut toml = String::new();
    let mut names = Vec::new();
    for (i, s) in sims.iter().enumerate() {
        let name = format!("{prefix}{i:02}");
        toml.push_str(&format!(
            "[[machine]]\nname = \"{name}\"\nlink = \"modbus-tcp\"\nhost = \"127.0.0.1\"\nport = {}\n\n",
            s.addr().port()
        ));
        names.push(name);
    }
    (toml, names)
}

fn main() {
    let minutes = arg("--minutes", 10.0);
    let scale = arg("--time-scale", 5.0);
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        // soak: 50 ms of motion per line, enough lines for `minutes` of simulated time
        let lines = (minutes * 60.0 / 0.05).ceil() as usize;
        let text = program(lines);
        let bytes_per_line = text.len() as f64 / text.lines().count() as f64;
        let grbl: Vec<GrblSimHandle> = (0..GRBL)
            .map(|_| {
                GrblSim::spawn_pty(GrblSimConfig {
                    time_scale: scale,
                    baud: Some(BAUD),
                    max_feed: 5000.0,
                    ..Default::default()
                })
                .unwrap()
            })
            .collect();
        let mut modbus = Vec::new();
        for _ in 0..MODBUS {
            modbus.push(
                ModbusSim::spawn_tcp(
                    SimConfig {
                        time_scale: scale,
                        ..Default::default()
                    },
                    ([127, 0, 0, 1], 0).into(),
                )
                .await
                .unwrap(),
            );
        }
        let (mut toml, mut names) = grbl_machines(&grbl, "grbl");
        let (t2, n2) = modbus_machines(&modbus, "modbus");
        toml.push_str(&t2);
        names.extend(n2);
        let dir = tempfile::tempdir().unwrap();
        let d = serve(dir.path(), &toml);
        let pid = d.child.id();
        let c = Client::new(Endpoint::Unix(d.socket.clone()));
        let (cpu0, _) = usage(pid);
        let t0 = Instant::now();
        let sampler = {
            let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
            let s2 = stop.clone();
            let h = std::thread::spawn(move || {
                let mut peak = 0;
                while !s2.load(std::sync::atomic::Ordering::Relaxed) {
                    peak = peak.max(usage(pid).1);
                    std::thread::sleep(Duration::from_millis(500));
                }
                peak
            });
            (stop, h)
        };
        let soak = run_all(&c, &names, &text).await;
        let wall = t0.elapsed().as_secs_f64();
        let (cpu1, rss_end) = usage(pid);
        sampler.0.store(true, std::sync::atomic::Ordering::Relaxed);
        let peak = sampler.1.join().unwrap().max(rss_end);
        let sim_minutes = grbl[0].sim_time().as_secs_f64() / 60.0;
        drop(d);

        // capacity: one machine of each kind whose motion finishes at once
        let cap_grbl = vec![GrblSim::spawn_pty(GrblSimConfig {
            time_scale: f64::INFINITY,
            baud: Some(BAUD),
            ..Default::default()
        })
        .unwrap()];
        let cap_modbus = vec![ModbusSim::spawn_tcp(
            SimConfig {
                time_scale: f64::INFINITY,
                ..Default::default()
            },
            ([127, 0, 0, 1], 0).into(),
        )
        .await
        .unwrap()];
        let (mut toml, mut names) = grbl_machines(&cap_grbl, "grbl");
        let (t2, n2) = modbus_machines(&cap_modbus, "modbus");
        toml.push_str(&t2);
        names.extend(n2);
        let dir = tempfile::tempdir().unwrap();
        let d = serve(dir.path(), &toml);
        let cap_text = program(4000);
        let mut capacity = Vec::new();
        for m in &names {
            let r = run_all(&Client::new(Endpoint::Unix(d.socket.clone())), std::slice::from_ref(m), &cap_text).await;
            capacity.push(r[0].1 as f64 / r[0].2);
        }
        drop(d);

        println!("soak: {GRBL} GRBL (115200 baud) + {MODBUS} Modbus TCP machines, {lines} lines each, time scale {scale}");
        println!("  simulated time: {sim_minutes:.1} min; wall time {wall:.1} s");
        println!(
            "  daemon CPU: {:.1} s over {wall:.1} s = {:.1} % of one core; RSS peak {:.1} MB",
            cpu1 - cpu0,
            100.0 * (cpu1 - cpu0) / wall,
            peak as f64 / 1024.0
        );
        println!("  {bytes_per_line:.1} bytes per line on the wire (newline included)");
        println!("| machines | lines/s per machine (min / mean / max) | link capacity, lines/s | share |");
        println!("|---|---:|---:|---:|");
        for (prefix, cap) in [("grbl", capacity[0]), ("modbus", capacity[1])] {
            let rates: Vec<f64> = soak
                .iter()
                .filter(|(m, _, _)| m.starts_with(prefix))
                .map(|(_, n, s)| *n as f64 / s)
                .collect();
            let min = rates.iter().cloned().fold(f64::INFINITY, f64::min);
            let max = rates.iter().cloned().fold(0.0, f64::max);
            let mean = rates.iter().sum::<f64>() / rates.len() as f64;
            println!(
                "| {} × {prefix} | {min:.0} / {mean:.0} / {max:.0} | {cap:.0} | {:.0} % |",
                rates.len(),
                100.0 * mean / cap
            );
        }
    });
}
