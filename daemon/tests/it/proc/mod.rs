//! A real `machlink serve` process for tests that kill or stop it, and the simulated
//! machines (in this test's process, so they outlive the daemon) it drives.
#![allow(dead_code)]

use machlink::core::intake::{Input, JobSpec};
use machlink::core::store::JobId;
use machlink::faces::client::{Client, Endpoint};
use machlink_protocols::gcode::{post, GcodeOptions};
use offset_core::{Move, Point, Toolpath, P3};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// A `machlink serve` child on `dir/machlink.toml`, its log in `dir/daemon.log`; killed
/// (SIGKILL) when dropped.
pub struct Daemon {
    pub child: Child,
    pub socket: PathBuf,
    pub dir: PathBuf,
}

impl Daemon {
    /// Starts the daemon on the config in `dir` and waits (bounded) until it answers.
    pub async fn start(dir: &Path) -> Daemon {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.join("daemon.log"))
            .unwrap();
        let socket = dir.join("ml.sock");
        let child = Command::new(env!("CARGO_BIN_EXE_machlink"))
            .env("RUST_LOG", "info")
            .args(["serve", "--config"])
            .arg(dir.join("machlink.toml"))
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("machlink serve starts");
        let d = Daemon {
            child,
            socket,
            dir: dir.to_path_buf(),
        };
        let until = Instant::now() + Duration::from_secs(60);
        loop {
            if d.client().machines().await.is_ok() {
                return d;
            }
            assert!(
                Instant::now() < until,
                "the daemon never answered; its log:\n{}",
                d.log()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    pub fn client(&self) -> Client {
        Client::new(Endpoint::Unix(self.socket.clone()))
    }

    /// SIGKILL: the process dies at once, as in a crash.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGTERM, and waits (bounded) for the process to exit; its exit status.
    pub fn terminate(&mut self) -> std::process::ExitStatus {
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).expect("SIGTERM");
        let until = Instant::now() + Duration::from_secs(60);
        loop {
            if let Some(s) = self.child.try_wait().expect("the daemon's status") {
                return s;
            }
            assert!(Instant::now() < until, "the daemon did not stop on SIGTERM");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("daemon.log")).unwrap_or_default()
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Writes `dir/machlink.toml`: the store and socket in `dir`, and `machines`.
pub fn write_config(dir: &Path, machines: &str) {
    let text = format!(
        "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n{machines}",
        dir.join("jobs.db").display(),
        dir.join("ml.sock").display()
    );
    std::fs::write(dir.join("machlink.toml"), text).unwrap();
}

/// A simulated Modbus PLC on loopback TCP (20 times real time, a ring of 16 blocks) and
/// `dir`'s config naming it machine `press` (`modbus-tcp`, 300 ms timeout) with the TOML
/// lines `extra` (its tools, allowed M-codes).
pub async fn modbus_press(dir: &Path, extra: &str) -> machlink_sim::modbus::ModbusSim {
    let press = machlink_sim::modbus::ModbusSim::spawn_tcp(
        machlink_sim::modbus::SimConfig {
            time_scale: 20.0,
            capacity: 16,
            ..Default::default()
        },
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .unwrap();
    write_config(
        dir,
        &format!(
            "[[machine]]\nname = \"press\"\nlink = \"modbus-tcp\"\nhost = \"127.0.0.1\"\nport = {}\ntimeout_ms = 300\n{extra}",
            press.addr().port()
        ),
    );
    press
}

/// A posted G-code program: `rows` rows of 30 short feed moves joined by half circles, a
/// plunge first; `shift` moves it in X so that every job's program differs.
pub fn serpentine(rows: usize, shift: f64) -> Vec<String> {
    let mut tp = Toolpath::new("serpentine");
    tp.push(Move::Rapid {
        to: P3::new(shift, 0.0, 5.0),
    });
    tp.push(Move::Spindle { rpm: 10000.0 });
    tp.push(Move::Linear {
        to: P3::new(shift, 0.0, -1.0),
        feed: 300.0,
    });
    let mut y = 0.0;
    for row in 0..rows {
        let dir = if row % 2 == 0 { 1.0 } else { -1.0 };
        let x0 = shift + if row % 2 == 0 { 0.0 } else { 60.0 };
        for k in 1..=30 {
            tp.push(Move::Linear {
                to: P3::new(x0 + dir * k as f64 * 2.0, y, -1.0 - 0.01 * (k % 5) as f64),
                feed: 1200.0 + (k % 3) as f64 * 100.0,
            });
        }
        let xe = x0 + dir * 60.0;
        tp.push(Move::Arc {
            to: P3::new(xe, y + 3.0, -1.0),
            center: Point::new(xe, y + 1.5),
            ccw: row % 2 == 0,
            feed: 900.0,
        });
        y += 3.0;
    }
    post(&tp, &GcodeOptions::default()).expect("the serpentine posts")
}

/// A job of a file named `name` with `text`, on `machine`.
pub fn file_job(machine: &str, name: &str, text: &str) -> JobSpec {
    JobSpec {
        machine: Some(machine.into()),
        input: Input::from_bytes(name, text.as_bytes().to_vec()),
        operation: None,
        operations: Vec::new(),
        tolerance: None,
        layers: Vec::new(),
        post: None,
    }
}

/// A small deterministic random source (xorshift64*).
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    pub fn between(&mut self, lo: u64, hi: u64) -> u64 {
        lo + self.next() % (hi - lo)
    }
}

/// `machlink ARGS --socket DIR/ml.sock`, stdin from /dev/null (no terminal), to the end.
pub fn cli(dir: &Path, args: &[&str]) -> Output {
    crate::common::cli::at_socket(&dir.join("ml.sock"), args)
}

pub use crate::common::cli::stderr;

/// Waits (bounded) until job `id` satisfies `ok`; the job then.
pub async fn wait_job(
    d: &Daemon,
    id: JobId,
    what: &str,
    ok: impl Fn(&machlink::core::store::JobRecord) -> bool,
) -> machlink::core::store::JobRecord {
    let until = Instant::now() + Duration::from_secs(90);
    loop {
        if let Ok(j) = d.client().job(id).await {
            if ok(&j) {
                return j;
            }
            assert!(
                Instant::now() < until,
                "job {id} never became {what}: {j:?}\n{}",
                d.log()
            );
        }
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
}
