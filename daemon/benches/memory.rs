//! The daemon's resident memory around a 60 MB G-code job: before, while the file is stored,
//! while it streams, and after it is cancelled. Runs `machlink serve` as a child process with
//! one simulated GRBL machine and reads its VmRSS from /proc every 10 ms.
//!
//!     cargo bench -p machlink --bench memory            # MACHLINK_BENCH_MB=60 by default
//!
//! Prints one table; docs/BENCHMARKS.md keeps the figures with this command.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn rss(pid: u32) -> u64 {
    machlink::services::memory::resident_bytes(Some(pid)).unwrap_or(0)
}

fn mb(b: u64) -> f64 {
    b as f64 / (1024.0 * 1024.0)
}

fn machlink(socket: &Path, args: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_machlink"))
        .args(args)
        .arg("--socket")
        .arg(socket)
        .output()
        .expect("machlink runs");
    assert!(
        o.status.success(),
        "machlink {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn job_state(socket: &Path, id: &str) -> (String, u64) {
    let jobs: serde_json::Value =
        serde_json::from_str(&machlink(socket, &["jobs", "--json"])).unwrap();
    let j = jobs
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["id"].as_i64().map(|n| n.to_string()).as_deref() == Some(id))
        .expect("the job")
        .clone();
    (
        j["state"].as_str().unwrap().to_string(),
        j["acked_units"].as_u64().unwrap(),
    )
}

fn wait_for(socket: &Path, id: &str, f: impl Fn(&str, u64) -> bool) {
    let until = Instant::now() + Duration::from_secs(600);
    loop {
        let (s, a) = job_state(socket, id);
        if f(&s, a) {
            return;
        }
        assert!(Instant::now() < until, "job {id} stuck in {s}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Samples the peak RSS of `pid` until stopped.
struct Peak {
    peak: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Peak {
    fn start(pid: u32) -> Peak {
        let peak = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let (p, s) = (peak.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            while !s.load(Ordering::Relaxed) {
                p.fetch_max(rss(pid), Ordering::Relaxed);
                std::thread::sleep(Duration::from_millis(10));
            }
        });
        Peak {
            peak,
            stop,
            thread: Some(thread),
        }
    }
    fn finish(mut self) -> u64 {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.peak.load(Ordering::Relaxed)
    }
}

fn main() {
    let target_mb: u64 = std::env::var("MACHLINK_BENCH_MB")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(60);
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("big.nc");
    let mut lines = 0u64;
    {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&file).unwrap());
        writeln!(w, "G21 G90\nG1 Z-0.5 F1500").unwrap();
        let mut written = 0u64;
        let mut i = 0u64;
        while written < target_mb << 20 {
            let l = format!(
                "X{}.{:03} Y{}.{:02}\n",
                i % 97,
                i % 1000,
                (i / 97) % 89,
                i % 100
            );
            written += l.len() as u64;
            w.write_all(l.as_bytes()).unwrap();
            i += 1;
        }
        lines += i + 2;
    }
    let size = std::fs::metadata(&file).unwrap().len();
    let small = dir.path().join("small.nc");
    std::fs::write(&small, "G21 G90\nG1 X1 F1000\nX0\n").unwrap();
    let cfg = dir.path().join("machlink.toml");
    std::fs::write(
        &cfg,
        format!(
            "[daemon]\nstore = \"{}\"\n\n[[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 1.0\n",
            dir.path().join("jobs.db").display()
        ),
    )
    .unwrap();
    let socket = dir.path().join("run").join("ml.sock");
    let mut serve = Command::new(env!("CARGO_BIN_EXE_machlink"))
        .args(["serve", "--config"])
        .arg(&cfg)
        .arg("--socket")
        .arg(&socket)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("serve starts");
    let pid = serve.id();
    let until = Instant::now() + Duration::from_secs(30);
    while !socket.exists() {
        assert!(Instant::now() < until, "no socket");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    let at_start = rss(pid);
    // warm up: one small job through the whole path
    let id = machlink(
        &socket,
        &["submit", small.to_str().unwrap(), "--machine", "bench"],
    );
    let id = id.trim().to_string();
    wait_for(&socket, &id, |s, _| s == "completed");
    std::thread::sleep(Duration::from_millis(1000));
    let baseline = rss(pid);

    let peak_all = Peak::start(pid);
    let intake = Peak::start(pid);
    let t0 = Instant::now();
    let id = machlink(
        &socket,
        &["submit", file.to_str().unwrap(), "--machine", "bench"],
    );
    let stored_in = t0.elapsed();
    let id = id.trim().to_string();
    let intake_peak = intake.finish();
    let streaming = Peak::start(pid);
    wait_for(&socket, &id, |s, a| s == "running" && a >= 2000);
    std::thread::sleep(Duration::from_secs(2));
    let streaming_peak = streaming.finish();
    machlink(&socket, &["cancel", &id]);
    wait_for(&socket, &id, |s, _| s == "cancelled");
    std::thread::sleep(Duration::from_millis(1500));
    let after = rss(pid);
    let peak = peak_all.finish();
    let _ = serve.kill();
    let _ = serve.wait();

    println!(
        "memory: a {:.1} MB G-code file of {lines} lines, streamed to `machlink serve` (pid {pid})",
        size as f64 / 1e6
    );
    println!("| moment | resident memory |");
    println!("|---|---|");
    println!("| daemon started | {:.1} MiB |", mb(at_start));
    println!("| baseline (after a small job) | {:.1} MiB |", mb(baseline));
    println!(
        "| peak while the file is stored ({:.1} s) | {:.1} MiB |",
        stored_in.as_secs_f64(),
        mb(intake_peak)
    );
    println!("| peak while it streams | {:.1} MiB |", mb(streaming_peak));
    println!(
        "| peak overall | {:.1} MiB ({:.1}× the file) |",
        mb(peak),
        (peak.saturating_sub(baseline)) as f64 / size as f64
    );
    println!(
        "| after cancel | {:.1} MiB ({:+.1} % of the baseline) |",
        mb(after),
        (after as f64 / baseline as f64 - 1.0) * 100.0
    );
}
