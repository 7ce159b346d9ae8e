//! machlink run as a service: check-config on the shipped and on broken configs, shell
//! completions and man pages, the systemd unit, sd_notify readiness and watchdog, logs
//! (JSON lines, no colour off a terminal), the socket found without `--socket`, and
//! `machlink events` with a webhook receiving the same events.

use crate::common;
use common::cli::Serve;

use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

fn machlink() -> Command {
    let mut c = common::cli::machlink();
    c.env("RUST_LOG", "info")
        .env_remove("NOTIFY_SOCKET")
        .env_remove("WATCHDOG_USEC");
    c
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Whether a program is on PATH.
fn have(program: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {program}")])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

#[test]
fn check_config_passes_every_shipped_config() {
    let mut files: Vec<PathBuf> = Vec::new();
    for dir in ["docs", "contrib"] {
        for e in std::fs::read_dir(repo().join(dir)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                files.push(p);
            }
        }
    }
    assert!(files.len() >= 3, "the shipped configs: {files:?}");
    // contrib/machlink.toml names group `machlink`, which install.md makes first; where
    // there is none, a copy names this process's group instead
    let copies = tempfile::tempdir().unwrap();
    let here = nix::unistd::Group::from_gid(nix::unistd::getegid())
        .ok()
        .flatten()
        .map(|g| g.name);
    let no_machlink = nix::unistd::Group::from_name("machlink")
        .ok()
        .flatten()
        .is_none();
    for f in files {
        let body = text(&std::fs::read(&f).unwrap());
        let f = match (&here, no_machlink && body.contains("group = \"machlink\"")) {
            (Some(g), true) => {
                let copy = copies.path().join(f.file_name().unwrap());
                std::fs::write(&copy, body.replace("\"machlink\"", &format!("\"{g}\""))).unwrap();
                copy
            }
            _ => f,
        };
        let o = machlink().arg("check-config").arg(&f).output().unwrap();
        assert!(o.status.success(), "{}: {}", f.display(), text(&o.stderr));
        assert!(text(&o.stdout).contains(": ok ("), "{}", text(&o.stdout));
        // the example's /dev/ttyUSB0 is only a warning where no such port exists
        if !Path::new("/dev/ttyUSB0").exists()
            && text(&std::fs::read(&f).unwrap()).contains("\nport = \"/dev/ttyUSB0\"")
        {
            let e = text(&o.stderr);
            assert!(
                e.contains("warning")
                    && e.contains("key `port`")
                    && e.contains("/dev/ttyUSB0 does not exist"),
                "{}: {e}",
                f.display()
            );
        }
    }
}

#[test]
fn check_config_names_the_line_and_key_of_every_mistake() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/configs/broken");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let f = e.unwrap().path();
        let body = std::fs::read_to_string(&f).unwrap();
        let expected: Vec<(String, String)> = body
            .lines()
            .filter_map(|l| l.strip_prefix("# expect: "))
            .map(|l| {
                let (line, key) = l.split_once(", key ").expect("# expect: line N, key `k`");
                (line.to_string(), key.to_string())
            })
            .collect();
        assert!(!expected.is_empty(), "{} says what it expects", f.display());
        let o = machlink().arg("check-config").arg(&f).output().unwrap();
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{}: {err}", f.display());
        assert!(!err.contains("panicked"), "{err}");
        let lines: Vec<&str> = err.lines().collect();
        assert_eq!(
            lines.len(),
            expected.len(),
            "{}: one sentence per mistake: {err}",
            f.display()
        );
        for ((line, key), got) in expected.iter().zip(&lines) {
            let want_at = format!("{}, {line}, column", f.display());
            assert!(
                got.starts_with(&format!("machlink: {want_at}")) && got.contains(key.as_str()),
                "{}: expected {line} and {key} in: {got}",
                f.display()
            );
        }
        n += 1;
    }
    assert!(n >= 10, "the broken configs");
}

#[test]
fn bash_completions_load_in_a_bash_subshell() {
    assert!(have("bash"), "bash is needed to load the completions");
    let o = machlink().args(["completions", "bash"]).output().unwrap();
    assert!(o.status.success());
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("machlink.bash");
    std::fs::write(&script, &o.stdout).unwrap();
    let o = Command::new("bash")
        .arg("-c")
        .arg(format!(
            "set -e; source '{}'; complete -p machlink",
            script.display()
        ))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("machlink"), "{}", text(&o.stdout));
    // the subcommands are offered
    let s = text(&std::fs::read(&script).unwrap());
    for sub in [
        "serve",
        "submit",
        "events",
        "check-config",
        "completions",
        "man",
    ] {
        assert!(s.contains(sub), "{sub} is not completed");
    }
    for shell in ["zsh", "fish"] {
        let o = machlink().args(["completions", shell]).output().unwrap();
        assert!(
            o.status.success() && text(&o.stdout).contains("check-config"),
            "{shell}"
        );
    }
}

#[test]
fn man_pages_render_with_man() {
    let dir = tempfile::tempdir().unwrap();
    let o = machlink()
        .args(["man", "-o"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    for page in [
        "machlink.1",
        "machlink-serve.1",
        "machlink-check-config.1",
        "machlink-events.1",
    ] {
        assert!(dir.path().join(page).is_file(), "{page} written");
    }
    if !have("man") {
        eprintln!("skipped rendering: `man` is not installed here (apt-get install man-db)");
        return;
    }
    let o = Command::new("man")
        .args(["-l", "-P", "cat"])
        .arg(dir.path().join("machlink-serve.1"))
        .env("MANWIDTH", "80")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let page = text(&o.stdout);
    assert!(
        page.contains("--metrics-listen") && page.contains("--log-format"),
        "{page}"
    );
}

#[test]
fn the_unit_file_passes_systemd_analyze_verify() {
    if !have("systemd-analyze") {
        eprintln!("skipped: systemd-analyze is not installed here (no systemd)");
        return;
    }
    let unit = std::fs::read_to_string(repo().join("contrib/machlink.service")).unwrap();
    for want in [
        "Type=notify",
        "WatchdogSec=",
        "User=machlink",
        "Group=machlink",
        "RuntimeDirectory=machlink",
        "StateDirectory=machlink",
        "ProtectSystem=strict",
        "DeviceAllow=char-ttyUSB rw",
    ] {
        assert!(unit.contains(want), "the unit has {want}");
    }
    // verify needs ExecStart's program to exist: the one just built stands in for
    // /usr/bin/machlink
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("machlink.service");
    std::fs::write(
        &path,
        unit.replace("/usr/bin/machlink", env!("CARGO_BIN_EXE_machlink")),
    )
    .unwrap();
    let o = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        o.status.success() && o.stderr.is_empty(),
        "systemd-analyze verify: {}{}",
        text(&o.stdout),
        text(&o.stderr)
    );
}

fn serve(dir: &Path, extra: &str, args: &[&str], env: &[(&str, &str)]) -> Serve {
    let cfg = dir.join("machlink.toml");
    std::fs::write(
        &cfg,
        format!(
            "[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\n\n\
             [[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 50.0\n\n{extra}"
        ),
    )
    .unwrap();
    let mut c = machlink();
    c.arg("serve").arg("--config").arg(&cfg).args(args);
    for (k, v) in env {
        c.env(k, v);
    }
    c.stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("serve.log")).unwrap());
    Serve::spawn(c, &dir.join("ml.sock"), Duration::from_secs(30))
}

fn gcode(dir: &Path) -> PathBuf {
    let f = dir.join("part.nc");
    std::fs::write(&f, "G21 G90\nG1 X1 Y1 F2000\nG1 X2 Y0\nG1 X0 Y0\n").unwrap();
    f
}

fn submit(socket_env: Option<&Path>, args: &[&str]) -> Output {
    let mut c = machlink();
    c.arg("submit").args(args);
    if let Some(s) = socket_env {
        c.env("MACHLINK_SOCKET", s);
    }
    c.output().unwrap()
}

#[test]
fn readiness_and_watchdog_reach_systemd() {
    let dir = tempfile::tempdir().unwrap();
    let notify = dir.path().join("notify.sock");
    let sock = std::os::unix::net::UnixDatagram::bind(&notify).unwrap();
    sock.set_read_timeout(Some(Duration::from_secs(30)))
        .unwrap();
    let _s = serve(
        dir.path(),
        "",
        &[],
        &[
            ("NOTIFY_SOCKET", notify.to_str().unwrap()),
            ("WATCHDOG_USEC", "400000"),
        ],
    );
    let mut got = String::new();
    let mut buf = [0u8; 4096];
    while !(got.contains("READY=1") && got.contains("WATCHDOG=1")) {
        let n = sock
            .recv(&mut buf)
            .expect("the daemon notifies systemd within 30 s");
        got.push_str(&text(&buf[..n]));
    }
    assert!(got.contains("STATUS=serving 1 machine(s)"), "{got}");
}

#[test]
fn json_logs_name_job_machine_and_unit_and_carry_no_colour() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve(dir.path(), "", &["--log-format", "json"], &[]);
    let f = gcode(dir.path());
    let o = submit(
        Some(&s.socket),
        &[f.to_str().unwrap(), "--machine", "bench", "--watch"],
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    drop(s);
    let log = std::fs::read_to_string(dir.path().join("serve.log")).unwrap();
    assert!(
        !log.contains('\u{1b}'),
        "no ANSI escapes off a terminal: {log}"
    );
    let lines: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not a JSON line ({e}): {l}")))
        .collect();
    for what in ["job started", "job completed"] {
        let l = lines
            .iter()
            .find(|l| l["message"] == what)
            .unwrap_or_else(|| panic!("no `{what}` in {log}"));
        assert_eq!(l["job"], 1, "{l}");
        assert_eq!(l["machine"], "bench", "{l}");
        assert!(l["unit"].is_u64(), "{l}");
    }

    // human logs off a terminal: no colour either
    // (the socket exists a moment before the line saying so is written: wait for the line)
    let dir = tempfile::tempdir().unwrap();
    let s = serve(dir.path(), "", &[], &[]);
    let until = std::time::Instant::now() + std::time::Duration::from_secs(20);
    let log = loop {
        let log = std::fs::read_to_string(dir.path().join("serve.log")).unwrap_or_default();
        if log.contains("machlink daemon listening") || std::time::Instant::now() > until {
            break log;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    drop(s);
    assert!(log.contains("machlink daemon listening"), "{log}");
    assert!(!log.contains('\u{1b}'), "{log}");
}

#[test]
fn clients_find_the_socket_from_the_environment_then_the_config() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve(dir.path(), "", &[], &[]);
    let f = gcode(dir.path());
    // MACHLINK_SOCKET
    let o = submit(
        Some(&s.socket),
        &[f.to_str().unwrap(), "--machine", "bench"],
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    // the config's socket, by --config and by MACHLINK_CONFIG
    let cfg = dir.path().join("machlink.toml");
    let o = machlink()
        .args(["jobs", "--json", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let o = machlink()
        .args(["jobs", "--json"])
        .env("MACHLINK_CONFIG", &cfg)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let jobs: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(jobs.as_array().unwrap().len(), 1);
    // the environment wins over the config
    let o = machlink()
        .args(["jobs"])
        .env("MACHLINK_CONFIG", &cfg)
        .env("MACHLINK_SOCKET", dir.path().join("none.sock"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(text(&o.stderr).contains("none.sock"), "{}", text(&o.stderr));
}

/// A tiny HTTP receiver: answers 500 to the first POST (so the daemon retries) and 204
/// to the rest; hands each body it accepted to the test.
fn receiver() -> (u16, std::sync::mpsc::Receiver<String>) {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut first = true;
        for s in l.incoming() {
            let Ok(mut s) = s else { return };
            let mut r = BufReader::new(s.try_clone().unwrap());
            let mut len = 0;
            loop {
                let mut line = String::new();
                if r.read_line(&mut line).unwrap_or(0) == 0 {
                    break;
                }
                if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
                    len = v.trim().parse().unwrap_or(0);
                }
                if line == "\r\n" {
                    break;
                }
            }
            let mut body = vec![0; len];
            let _ = r.read_exact(&mut body);
            let status = if first {
                "500 Internal Server Error"
            } else {
                "204 No Content"
            };
            let _ = s.write_all(
                format!("HTTP/1.1 {status}\r\ncontent-length: 0\r\nconnection: close\r\n\r\n")
                    .as_bytes(),
            );
            if !first {
                let _ = tx.send(text(&body));
            }
            first = false;
        }
    });
    (port, rx)
}

#[test]
fn events_follow_every_job_and_webhooks_get_theirs_with_retries() {
    let (port, hooks) = receiver();
    let dir = tempfile::tempdir().unwrap();
    let s = serve(
        dir.path(),
        &format!(
            "[[webhook]]\nurl = \"http://127.0.0.1:{port}/machlink\"\nevents = [\"completed\", \"running\"]\ntimeout_ms = 2000\nretries = 3\n"
        ),
        &[],
        &[],
    );
    let mut events = machlink()
        .args(["events", "--json", "--machine", "bench", "--socket"])
        .arg(&s.socket)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut human = machlink()
        .args(["events", "--socket"])
        .arg(&s.socket)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // both followers are connected once a job submitted now shows in their streams;
    // give them the socket's accept first
    std::thread::sleep(Duration::from_millis(300));
    let f = gcode(dir.path());
    let o = submit(
        Some(&s.socket),
        &[f.to_str().unwrap(), "--machine", "bench", "--watch"],
    );
    assert!(o.status.success(), "{}", text(&o.stderr));

    let mut states = Vec::new();
    let mut lines = BufReader::new(events.stdout.take().unwrap()).lines();
    while !states.contains(&"completed".to_string()) {
        let l = lines.next().expect("an event line").unwrap();
        let v: serde_json::Value = serde_json::from_str(&l).expect("JSON lines");
        if v["type"] == "state" {
            assert_eq!(v["machine"], "bench");
            states.push(v["state"].as_str().unwrap().to_string());
        }
    }
    assert_eq!(states, ["queued", "running", "completed"]);
    let mut h = BufReader::new(human.stdout.take().unwrap()).lines();
    let first = h.next().unwrap().unwrap();
    assert_eq!(first, "job 1 on bench: queued (0/4)");
    let _ = events.kill();
    let _ = human.kill();
    let _ = events.wait();
    let _ = human.wait();

    // the webhook got `running` (after a 500 and a retry) and `completed`, in order
    let mut got = Vec::new();
    for _ in 0..2 {
        let body = hooks
            .recv_timeout(Duration::from_secs(30))
            .expect("a webhook delivery");
        let v: serde_json::Value = serde_json::from_str(&body).unwrap();
        got.push(v["state"].as_str().unwrap().to_string());
    }
    assert_eq!(got, ["running", "completed"]);
    // the retry and the deliveries are counted
    // (counted once the daemon has read the receiver's answer, just after the receiver
    // handed the body over)
    let want = "machlink_webhook_deliveries_total{result=\"ok\"} 2";
    let mut metrics = String::new();
    for _ in 0..200 {
        metrics = machlink_metrics(&s.socket);
        if metrics.contains(want) {
            break;
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    assert!(
        metrics.contains("machlink_webhook_deliveries_total{result=\"ok\"} 2"),
        "{metrics}"
    );
}

/// `GET /metrics` over the Unix socket, by hand.
fn machlink_metrics(socket: &Path) -> String {
    let mut s = std::os::unix::net::UnixStream::connect(socket).unwrap();
    s.write_all(b"GET /metrics HTTP/1.0\r\nHost: x\r\n\r\n")
        .unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    out
}

#[test]
fn config_md_documents_every_kind_and_its_keys() {
    let doc = std::fs::read_to_string(repo().join("docs/config.md")).unwrap();
    let registry = machlink::core::registry::standard();
    for kind in registry.kinds() {
        let link = kind.link();
        assert!(
            doc.contains(&format!("`link = \"{link}\"`")),
            "docs/config.md has no section for link = \"{link}\""
        );
        for key in kind.keys() {
            assert!(
                doc.contains(&format!("| `{key}` |")),
                "docs/config.md does not document `{key}` of link = \"{link}\""
            );
        }
    }
    for key in [
        "url",
        "name",
        "machines",
        "group",
        "credentials",
        "ack_wait_ms",
        "events",
        "timeout_ms",
        "retries",
    ] {
        assert!(
            doc.contains(&format!("| `{key}` |")),
            "[fleet]/[[webhook]] key `{key}`"
        );
    }
}
