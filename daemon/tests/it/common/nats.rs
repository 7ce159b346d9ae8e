//! A nats-server with JetStream on loopback in a temp dir, for the fleet's test and bench.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The nats-server binary: on PATH, or where Debian's package puts it.
pub fn nats_server_binary() -> PathBuf {
    let on_path = std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .unwrap_or_default();
    on_path
        .into_iter()
        .chain([PathBuf::from("/usr/sbin"), PathBuf::from("/usr/bin")])
        .map(|d| d.join("nats-server"))
        .find(|p| p.is_file())
        .unwrap_or_else(|| {
            panic!(
                "the fleet needs nats-server, which is not installed: `apt-get install nats-server` (.ci/run does)"
            )
        })
}

/// A running nats-server, killed when dropped.
pub struct Nats {
    child: Child,
    pub url: String,
}

impl Drop for Nats {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts nats-server with JetStream storing in `dir`, on a free loopback port.
pub fn start_nats(dir: &Path) -> Nats {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let log = std::fs::File::create(dir.join("nats.log")).expect("a log file");
    let child = Command::new(nats_server_binary())
        .args(["-js", "-a", "127.0.0.1", "-p", &port.to_string(), "-sd"])
        .arg(dir.join("jetstream"))
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .expect("nats-server starts");
    let nats = Nats {
        child,
        url: format!("nats://127.0.0.1:{port}"),
    };
    let until = Instant::now() + Duration::from_secs(20);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            Instant::now() < until,
            "nats-server did not listen on port {port} (see {})",
            dir.join("nats.log").display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    nats
}
