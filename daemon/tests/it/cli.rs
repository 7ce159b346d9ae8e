//! The `machlink` binary as an operator meets it: `serve`, `submit`, `jobs`, `machines`,
//! `watch`, `demo`, and one clear sentence with a non-zero exit for every bad input.

use crate::common;
use common::cli::{machlink, run, stderr, Serve};

use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};
use std::time::Duration;

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Fails with the one-sentence error `want` (a part of it), never a panic.
fn fails_with(o: &Output, want: &str) {
    let e = stderr(o);
    assert!(!o.status.success(), "expected a failure, got success: {e}");
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(!e.contains("panicked"), "{e}");
    // the error is the one last line (a progress note such as "job 2 queued" may precede)
    let last = e.trim_end().lines().last().unwrap_or("");
    assert!(
        last.starts_with("machlink: ") && last.contains(want),
        "expected `{want}` in: {e}"
    );
    assert_eq!(e.matches("machlink: ").count(), 1, "one sentence: {e}");
}

fn sample() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/plate-with-islands.json")
}

fn serve(dir: &Path, config: &str) -> Serve {
    let cfg = dir.join("machlink.toml");
    std::fs::write(&cfg, config).unwrap();
    let socket = dir.join("ml.sock");
    let mut cmd = machlink();
    cmd.args(["serve", "--config"])
        .arg(&cfg)
        .arg("--socket")
        .arg(&socket)
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    Serve::spawn(cmd, &socket, Duration::from_secs(20))
}

fn client(s: &Serve, args: &[&str]) -> Output {
    machlink()
        .args(args)
        .arg("--socket")
        .arg(&s.socket)
        .output()
        .expect("machlink runs")
}

#[test]
fn a_missing_shape_file_is_named() {
    let o = run(&[
        "submit",
        "/no/such/plate.json",
        "--machine",
        "mill",
        "--op",
        "profile",
        "--socket",
        "/no/such.sock",
    ]);
    fails_with(&o, "cannot read /no/such/plate.json");
    fails_with(
        &run(&["demo", "--shape", "/no/such/plate.json"]),
        "cannot read /no/such/plate.json",
    );
}

#[test]
fn a_daemon_that_is_not_running_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("none.sock");
    let o = run(&["jobs", "--socket", sock.to_str().unwrap()]);
    // exit status 3: the daemon is unreachable (docs/daemon.md, Exit status)
    assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
    assert_eq!(
        stderr(&o).trim_end(),
        format!(
            "machlink: cannot reach the daemon at {}: is `machlink serve` running?",
            sock.display()
        )
    );
}

#[test]
fn a_malformed_config_names_file_line_column_machine_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("cell.toml");
    std::fs::write(
        &cfg,
        "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nprot = \"/dev/ttyUSB0\"\n",
    )
    .unwrap();
    let o = run(&["serve", "--config", cfg.to_str().unwrap()]);
    fails_with(&o, &format!("{}, line 4, column", cfg.display()));
    fails_with(&o, "machine `mill`: unknown key `prot`");
    std::fs::write(
        &cfg,
        "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = [\n",
    )
    .unwrap();
    fails_with(
        &run(&["serve", "--config", cfg.to_str().unwrap()]),
        &format!("{}, line 4", cfg.display()),
    );
    fails_with(
        &run(&["serve", "--config", "/no/such/cell.toml"]),
        "cannot read /no/such/cell.toml",
    );
}

#[test]
fn serve_submit_watch_and_list() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve(
        dir.path(),
        "[[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 100.0\n\n\
         [[machine]]\nname = \"ghost\"\nlink = \"grbl\"\nport = \"/dev/machlink-no-such-port\"\n",
    );
    let o = client(&s, &["machines", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let ms: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let names: Vec<&str> = ms
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["bench", "ghost"]);

    // an unknown machine
    let shape = sample();
    let shape = shape.to_str().unwrap();
    let o = client(
        &s,
        &["submit", shape, "--machine", "nope", "--op", "profile"],
    );
    fails_with(
        &o,
        "there is no machine `nope` (the daemon has: `bench`, `ghost`)",
    );

    // a shape file that is not one
    let bad = dir.path().join("broken.json");
    std::fs::write(&bad, "{ \"paths\": [ ").unwrap();
    let o = client(
        &s,
        &[
            "submit",
            bad.to_str().unwrap(),
            "--machine",
            "bench",
            "--op",
            "profile",
        ],
    );
    fails_with(&o, "broken.json");

    // the sample, cut inside, watched to its end
    let o = client(
        &s,
        &[
            "submit",
            shape,
            "--machine",
            "bench",
            "--op",
            "profile",
            "--side",
            "inside",
            "--watch",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    // in a pipe `--watch` prints its progress lines after the job number
    let id: i64 = stdout(&o)
        .lines()
        .next()
        .unwrap_or("")
        .trim()
        .parse()
        .expect("submit prints the job number first");
    assert!(
        stderr(&o).contains(&format!("job {id} completed")),
        "{}",
        stderr(&o)
    );

    // a port that does not exist: the job fails with the open error, the daemon stays up
    let nc = dir.path().join("square.nc");
    std::fs::write(&nc, "G21 G90\nG1 X10 F500\nY10\nX0\nY0\n").unwrap();
    let o = client(
        &s,
        &[
            "submit",
            nc.to_str().unwrap(),
            "--machine",
            "ghost",
            "--op",
            "profile",
        ],
    );
    fails_with(&o, "square.nc is a G-code program, which runs as it is");
    let o = client(
        &s,
        &[
            "submit",
            nc.to_str().unwrap(),
            "--machine",
            "ghost",
            "--watch",
        ],
    );
    fails_with(&o, "cannot open /dev/machlink-no-such-port");

    let o = client(&s, &["jobs", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let jobs: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let states: Vec<&str> = jobs
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["state"].as_str().unwrap())
        .collect();
    assert_eq!(states, ["completed", "failed"]);
    let o = client(&s, &["jobs"]);
    assert!(stdout(&o).lines().count() == 3, "{}", stdout(&o));

    // steering a job that is over is refused in a sentence
    fails_with(
        &client(&s, &["pause", &id.to_string()]),
        &format!("job {id} is completed and cannot be paused"),
    );
    fails_with(&client(&s, &["watch", "4242"]), "there is no job 4242");

    // a second daemon on the same socket is refused
    let cfg = dir.path().join("machlink.toml");
    let o = run(&[
        "serve",
        "--config",
        cfg.to_str().unwrap(),
        "--socket",
        s.socket.to_str().unwrap(),
    ]);
    fails_with(&o, "another daemon is already listening at");
}

#[test]
fn the_demo_runs_the_sample_to_the_end() {
    let o = run(&["demo", "--quiet", "--time-scale", "400"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    assert!(out.contains(": completed"), "{out}");
    assert!(out.contains("rx overflows:      0"), "{out}");
    let dev: f64 = out
        .lines()
        .find_map(|l| l.trim().strip_prefix("max deviation:"))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("the summary gives the deviation");
    assert!(dev < 0.01, "{out}");
}
