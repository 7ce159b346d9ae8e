//! The binary as an operator and an administrator meet it: the socket and the files kept
//! private under any umask, a regular file or a live daemon's socket never taken over,
//! tokens made once, locks, exit statuses, and a closed stdout that is no crash.

use crate::common;
use common::cli::{machlink, stderr, Serve};

use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

const CELL: &str = "[[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 100.0\n";

fn write_config(dir: &Path, extra: &str) -> PathBuf {
    let cfg = dir.join("machlink.toml");
    std::fs::write(
        &cfg,
        format!(
            "[daemon]\nstore = \"{}\"\n\n{CELL}{extra}",
            dir.join("jobs.db").display()
        ),
    )
    .unwrap();
    cfg
}

/// Starts `serve` with `socket` under `umask`; waits for the socket.
fn serve(dir: &Path, socket: &Path, umask: u32) -> Serve {
    let cfg = write_config(dir, "");
    let mut cmd = machlink();
    cmd.args(["serve", "--config"])
        .arg(&cfg)
        .arg("--socket")
        .arg(socket)
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    // SAFETY: umask is async-signal-safe
    unsafe {
        cmd.pre_exec(move || {
            libc::umask(umask as libc::mode_t);
            Ok(())
        });
    }
    let s = Serve::spawn(cmd, socket, Duration::from_secs(30));
    let until = Instant::now() + Duration::from_secs(30);
    // the socket exists a moment before its mode is set; wait for an answer
    while !machlink()
        .args(["machines", "--socket"])
        .arg(socket)
        .output()
        .unwrap()
        .status
        .success()
    {
        assert!(Instant::now() < until, "the daemon never answered");
        std::thread::sleep(Duration::from_millis(20));
    }
    s
}

fn mode(p: &Path) -> u32 {
    std::fs::metadata(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .permissions()
        .mode()
        & 0o7777
}

#[test]
fn the_socket_folder_socket_and_every_file_the_daemon_writes_are_private_under_umask_022_and_000() {
    for umask in [0o022, 0o000] {
        let dir = tempfile::tempdir().unwrap();
        let folder = dir.path().join("run").join("machlink");
        let socket = folder.join("ml.sock");
        let s = serve(dir.path(), &socket, umask);
        assert_eq!(
            mode(&folder),
            0o700,
            "umask {umask:03o}: the socket's folder"
        );
        assert_eq!(
            mode(&socket) & 0o777,
            0o600,
            "umask {umask:03o}: the socket"
        );
        // a job runs, so that every file the daemon writes while working exists
        let part = dir.path().join("part.nc");
        std::fs::write(&part, "G21 G90\nG1 X1 Y1 F300\nG1 X0 Y0\n").unwrap();
        let o = machlink()
            .arg("submit")
            .arg(&part)
            .args(["--machine", "bench", "--watch", "--socket"])
            .arg(&socket)
            .output()
            .unwrap();
        assert!(o.status.success(), "umask {umask:03o}: {}", stderr(&o));
        // every file in the store's folder but the two this test wrote is the daemon's
        let mut seen = Vec::new();
        for e in std::fs::read_dir(dir.path()).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            if p.is_dir() || name == "machlink.toml" || name == "part.nc" {
                continue;
            }
            assert_eq!(mode(&p), 0o600, "umask {umask:03o}: {name}");
            seen.push(name);
        }
        for f in [
            "jobs.db",
            "jobs.db-wal",
            "jobs.db-shm",
            "jobs.db-progress",
            "jobs-audit.jsonl",
        ] {
            assert!(
                seen.iter().any(|s| s == f),
                "umask {umask:03o}: {f} was not written (files: {seen:?})"
            );
        }
        drop(s);
    }
}

#[test]
fn a_regular_file_at_the_socket_path_is_left_alone_and_named() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "");
    let socket = dir.path().join("ml.sock");
    std::fs::write(&socket, "precious notes").unwrap();
    let o = machlink()
        .args(["serve", "--config"])
        .arg(&cfg)
        .arg("--socket")
        .arg(&socket)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains(&format!(
            "{} exists and is not a socket (a regular file)",
            socket.display()
        )),
        "{e}"
    );
    assert_eq!(std::fs::read_to_string(&socket).unwrap(), "precious notes");
    // nothing was started: no store either
    assert!(!dir.path().join("jobs.db").exists());
}

#[test]
fn a_folder_open_to_others_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "");
    let open = dir.path().join("open");
    std::fs::create_dir(&open).unwrap();
    std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o777)).unwrap();
    let o = machlink()
        .args(["serve", "--config"])
        .arg(&cfg)
        .arg("--socket")
        .arg(open.join("ml.sock"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("has mode 0777, writable by every user"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_live_daemons_socket_is_not_stolen_and_a_dead_ones_is_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("ml.sock");
    let mut first = serve(dir.path(), &socket, 0o022);
    let second_dir = tempfile::tempdir().unwrap();
    let cfg = write_config(second_dir.path(), "");
    let o = machlink()
        .args(["serve", "--config"])
        .arg(&cfg)
        .arg("--socket")
        .arg(&socket)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("another daemon is already listening at"),
        "{}",
        stderr(&o)
    );
    // the first daemon still answers
    let o = machlink()
        .args(["jobs", "--socket"])
        .arg(&socket)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    // killed, it leaves its socket behind: the next daemon takes the path over
    first.child.kill().unwrap();
    first.child.wait().unwrap();
    assert!(socket.exists());
    let _again = serve(second_dir.path(), &socket, 0o022);
}

#[test]
fn a_closed_stdout_is_no_crash() {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("ml.sock");
    let _s = serve(dir.path(), &socket, 0o022);
    // stdout is a pipe whose reading end is already closed: every write fails with EPIPE
    let (r, w) = nix::unistd::pipe().unwrap();
    drop(r);
    for args in [&["jobs", "--json"][..], &["machines"][..], &["jobs"][..]] {
        let o = machlink()
            .args(args)
            .arg("--socket")
            .arg(&socket)
            .stdout(Stdio::from(w.try_clone().unwrap()))
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        let e = stderr(&o);
        assert!(!e.contains("panicked"), "{args:?}: {e}");
        assert_eq!(o.status.code(), Some(0), "{args:?}: {e}");
    }
}

#[test]
fn exit_statuses_say_usage_refused_or_unreachable() {
    let dir = tempfile::tempdir().unwrap();
    let nobody = dir.path().join("nobody.sock");
    let o = machlink()
        .args(["jobs", "--socket"])
        .arg(&nobody)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "unreachable: {}", stderr(&o));
    let o = machlink()
        .args(["jobs", "--no-such-flag"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "usage: {}", stderr(&o));
    let o = machlink()
        .args(["jobs", "--connect", "127.0.0.1:9"])
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(2),
        "--connect needs --ca or --insecure-plaintext: {}",
        stderr(&o)
    );
    let socket = dir.path().join("ml.sock");
    let _s = serve(dir.path(), &socket, 0o022);
    let o = machlink()
        .args(["cancel", "4242", "--socket"])
        .arg(&socket)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "refused: {}", stderr(&o));
    assert!(stderr(&o).contains("there is no job 4242"));
}

#[test]
fn a_token_is_printed_once_and_its_config_lines_work() {
    let dir = tempfile::tempdir().unwrap();
    let o = machlink()
        .args([
            "token",
            "new",
            "--role",
            "operator",
            "--machines",
            "bench",
            "--name",
            "tablet",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let toml = String::from_utf8(o.stdout.clone()).unwrap();
    let e = stderr(&o);
    let token = e
        .trim()
        .rsplit(' ')
        .next()
        .expect("the token on stderr")
        .to_string();
    assert!(token.starts_with("mlk_") && token.len() == 47, "{e}");
    assert!(
        !toml.contains(&token),
        "the config lines never hold the token"
    );
    assert!(
        toml.contains("name = \"tablet\"") && toml.contains("machines = [\"bench\"]"),
        "{toml}"
    );
    // the lines go into the config as they are; the token then works, as an operator
    let cfg = write_config(dir.path(), &toml);
    let socket = dir.path().join("ml.sock");
    let mut child = machlink()
        .args(["serve", "--config"])
        .arg(&cfg)
        .arg("--socket")
        .arg(&socket)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let until = Instant::now() + Duration::from_secs(30);
    while !socket.exists() {
        assert!(Instant::now() < until);
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(100));
    let run = |args: &[&str]| {
        machlink()
            .args(args)
            .arg("--socket")
            .arg(&socket)
            .env("MACHLINK_TOKEN", &token)
            .output()
            .unwrap()
    };
    let o = run(&["whoami"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let who: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (who["name"].as_str(), who["role"].as_str()),
        (Some("tablet"), Some("operator"))
    );
    let o = run(&["lock", "bench"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run(&["locks", "--json"]);
    let locks: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(locks[0]["holder"], "tablet");
    let o = run(&["reload"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("needs an admin"), "{}", stderr(&o));
    let o = run(&["release", "bench"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // the daemon's own user (no token) is admin
    let o = machlink()
        .args(["reload", "--socket"])
        .arg(&socket)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let _ = child.kill();
    let _ = child.wait();
}
