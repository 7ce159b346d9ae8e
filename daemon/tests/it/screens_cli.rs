//! Screens that must tell the truth (issue 22), through the `machlink` binary:
//! `check-config` reports every mistake of a file in one run in an operator's words, clients
//! find the daemon the way README starts it, a socket the user may not open says so, a
//! reader that goes away ends a command quietly, progress in a pipe is a line per step with
//! an ETA every kind has, and the small sentences (a stitch job on a router, an inside
//! profile of an open contour, JSON logs, metrics of G-code files) say what is so.

use crate::common;
use common::cli::{machlink, stderr, Serve};

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

/// A config with five mistakes that do not depend on each other, and the line and key each
/// one must be reported at, with the words the operator must read.
const FIVE_MISTAKES: &str = "\
[daemon]
socket = \"ml.sock\"
colour = \"red\"

[[machine]]
name = \"router\"
link = \"sim-grbl\"
max_feed = \"fast\"

[[machine]]
name = \"router\"
link = \"sim-grbl\"

[[webhook]]
url = \"http://127.0.0.1:9/hook\"
events = [\"completed\", \"exploded\"]

[fleet]
url = \"nats://127.0.0.1:4222\"
";

#[test]
fn check_config_reports_five_independent_mistakes_in_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("cell.toml");
    std::fs::write(&f, FIVE_MISTAKES).unwrap();
    let o = machlink().arg("check-config").arg(&f).output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 5, "one sentence per mistake, all five: {err}");
    let file = f.display().to_string();
    for (line, key, words) in [
        (3, "`colour`", "unknown key `colour`"),
        (8, "`max_feed`", "must be a number of mm/min, not \"fast\""),
        (11, "`router`", "machine `router` is declared twice"),
        (16, "`events`", "unknown event `exploded`"),
        (18, "`name`", "[fleet]: key `name` is missing"),
    ] {
        let at = format!("machlink: {file}, line {line}");
        let got = lines
            .iter()
            .find(|l| l.starts_with(&format!("{at},")) || l.starts_with(&format!("{at}:")))
            .unwrap_or_else(|| panic!("nothing reported at line {line}: {err}"));
        assert!(
            got.contains(key) && got.contains(words),
            "line {line}: expected {key} and \"{words}\" in: {got}"
        );
    }
    for serde_words in [
        "invalid type",
        "expected f64",
        "missing field",
        "unknown field",
    ] {
        assert!(
            !err.contains(serde_words),
            "serde's words `{serde_words}` in: {err}"
        );
    }
}

/// `machlink serve --config cell.toml` in `dir` (its socket `ml.sock` there), as README
/// starts it.
fn serve_cell(dir: &Path) -> Serve {
    std::fs::write(
        dir.join("cell.toml"),
        "[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\n\n\
         [[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\ntime_scale = 50.0\n",
    )
    .unwrap();
    let mut c = machlink();
    c.current_dir(dir)
        .args(["serve", "--config", "cell.toml"])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    Serve::spawn(c, &dir.join("ml.sock"), Duration::from_secs(30))
}

#[test]
fn machines_in_the_folder_of_serve_config_cell_toml_finds_its_socket() {
    let dir = tempfile::tempdir().unwrap();
    let _s = serve_cell(dir.path());
    // no --socket, no --config, no MACHLINK_*: only the cell.toml beside the operator
    let o = machlink()
        .current_dir(dir.path())
        .env_remove("XDG_RUNTIME_DIR")
        .args(["machines", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "machines: {}", stderr(&o));
    let m: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(m[0]["name"], "router", "{m}");
}

#[test]
fn the_socket_default_is_the_same_in_code_help_and_docs() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let default = "$XDG_RUNTIME_DIR/machlink.sock";
    let fallback = "/tmp/machlink-$USER/machlink.sock";
    // the code: with and without XDG_RUNTIME_DIR, a client with no config tries the default
    let system = Path::new(SYSTEM_CONFIG).exists();
    if system {
        eprintln!("skipped the code's default: this host has {SYSTEM_CONFIG}, which clients read");
    }
    for (xdg, want) in [
        (
            Some("/run/user/4242"),
            "/run/user/4242/machlink.sock".to_string(),
        ),
        (None, "/tmp/machlink-alice/machlink.sock".to_string()),
    ]
    .into_iter()
    .filter(|_| !system)
    {
        let dir = tempfile::tempdir().unwrap();
        let mut c = machlink();
        c.current_dir(dir.path()).env("USER", "alice").arg("jobs");
        match xdg {
            Some(x) => c.env("XDG_RUNTIME_DIR", x),
            None => c.env_remove("XDG_RUNTIME_DIR"),
        };
        let o = c.output().unwrap();
        assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
        assert!(stderr(&o).contains(&want), "{want} in: {}", stderr(&o));
    }
    // --help of a client and of serve
    for args in [&["jobs", "--help"][..], &["serve", "--help"]] {
        let o = machlink().args(args).output().unwrap();
        let help = String::from_utf8_lossy(&o.stdout).replace(char::is_whitespace, "");
        for d in [default, fallback] {
            assert!(
                help.contains(d),
                "`machlink {}` names {d}: {help}",
                args.join(" ")
            );
        }
    }
    // every page that names a default names this one
    for page in ["README.md", "docs/config.md", "docs/daemon.md"] {
        let text = std::fs::read_to_string(repo.join(page)).unwrap();
        let flat = text.replace(char::is_whitespace, "");
        assert!(
            flat.contains(&format!("`{default}`,else`{fallback}`"))
                || flat.contains(&format!("{default}`,else`{fallback}`")),
            "{page} gives the default socket as the code does"
        );
    }
}

const SYSTEM_CONFIG: &str = "/etc/machlink/machlink.toml";

/// The uid a test runs a client as when it runs as root, for whom file modes do not bite.
const NOBODY: u32 = 65534;

#[test]
fn a_socket_the_user_may_not_open_says_permission_denied_exit_3() {
    let dir = tempfile::tempdir().unwrap();
    let root = nix::unistd::Uid::effective().is_root();
    // a folder anyone may enter (nobody must reach the socket's folder), the daemon's own
    // inside it
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    let cell = dir.path().join("cell");
    std::fs::create_dir(&cell).unwrap();
    std::fs::set_permissions(&cell, std::fs::Permissions::from_mode(0o755)).unwrap();
    let s = serve_cell(&cell);
    // the socket closed to everyone but root
    std::fs::set_permissions(&s.socket, std::fs::Permissions::from_mode(0o000)).unwrap();
    let mut c = machlink();
    c.arg("machines")
        .arg("--socket")
        .arg(&s.socket)
        .current_dir("/");
    if root {
        // root opens any socket: the client runs as nobody, as an operator would
        c.uid(NOBODY).gid(NOBODY);
    }
    let o = c.output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(
        err.contains("permission denied:")
            && err.contains(&s.socket.display().to_string())
            && err.contains("(ask for a role, docs/security.md)"),
        "{err}"
    );
    assert!(!err.contains("is `machlink serve` running"), "{err}");
}

#[test]
fn every_command_ends_quietly_when_its_reader_goes_away() {
    for args in [
        &["completions", "zsh"][..],
        &["completions", "bash"],
        &["completions", "fish"],
        &["man"],
        &["--help"],
    ] {
        let mut child = machlink()
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // the reader goes away before the first byte: every write meets a closed pipe
        drop(child.stdout.take());
        let mut err = String::new();
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        let status = child.wait().unwrap();
        assert!(
            status.success() && err.is_empty(),
            "`machlink {}` with its reader gone: {status}, {err}",
            args.join(" ")
        );
    }
}

/// A cell of every simulated kind, served from `dir` (socket `ml.sock`), its log in
/// `dir/serve.log`; `extra` goes to the `[[machine]]` of the sewing machine.
fn serve_every_kind(dir: &Path, log_args: &[&str], sewing_extra: &str) -> Serve {
    std::fs::write(
        dir.join("cell.toml"),
        format!(
            "[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\n\n\
             [[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\ntime_scale = 20.0\n\n\
             [[machine]]\nname = \"ring\"\nlink = \"sim-modbus\"\ntime_scale = 20.0\n\n\
             [[machine]]\nname = \"sewer\"\nlink = \"sim-sewing\"\ntime_scale = 20.0\n{sewing_extra}\n\n\
             [[machine]]\nname = \"drive\"\nlink = \"sim-canopen\"\ntime_scale = 20.0\n\
             axes = [{{ axis = \"x\", node = 1, counts_per_mm = 1000, max_velocity = 100, max_acceleration = 1000, max_jerk = 10000 }}, \
                     {{ axis = \"y\", node = 2, counts_per_mm = 1000, max_velocity = 100, max_acceleration = 1000, max_jerk = 10000 }}]\n"
        ),
    )
    .unwrap();
    let mut c = machlink();
    c.current_dir(dir)
        .args(["serve", "--config", "cell.toml"])
        .args(log_args)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("serve.log")).unwrap());
    Serve::spawn(c, &dir.join("ml.sock"), Duration::from_secs(60))
}

/// A G-code square of `n` laps, 40 lines each, at `feed`.
fn gcode_square(dir: &Path, laps: usize, feed: u32) -> std::path::PathBuf {
    let mut g = String::from("G21 G90\nG0 X10 Y10\n");
    for _ in 0..laps * 10 {
        g.push_str(&format!(
            "G1 X20 Y10 F{feed}\nG1 X20 Y20\nG1 X10 Y20\nG1 X10 Y10\n"
        ));
    }
    let f = dir.join("square.nc");
    std::fs::write(&f, g).unwrap();
    f
}

fn sample_shape() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/plate-with-islands.json")
}

/// The ETA a progress line shows (`job 1 12/40 (30 %) ETA 4s`).
fn eta_of(line: &str) -> Option<&str> {
    line.split(" ETA ").nth(1).map(str::trim)
}

#[test]
fn submit_watch_in_a_pipe_prints_a_line_per_step_with_an_eta_never_0_while_cutting() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve_every_kind(dir.path(), &[], "");
    let f = gcode_square(dir.path(), 4, 1200);
    // stdout is a pipe here, as in `machlink submit … --watch | cat`
    let o = machlink()
        .env("MACHLINK_SOCKET", &s.socket)
        .arg("submit")
        .arg(&f)
        .args(["--machine", "router", "--watch"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines[0], "1", "the job's id first: {out}");
    assert!(
        lines.iter().any(|l| l.starts_with("job 1 running at")),
        "the state change to running: {out}"
    );
    assert!(
        lines
            .last()
            .is_some_and(|l| l.starts_with("job 1 completed at 162/162")),
        "the last state change: {out}"
    );
    let progress: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|l| l.contains(" %) ETA "))
        .collect();
    assert!(progress.len() >= 10, "a line per step of progress: {out}");
    for l in &progress {
        let eta = eta_of(l).unwrap();
        assert!(eta != "-", "a G-code file has an ETA: {l}");
        assert!(eta != "0s", "an ETA of 0 while the machine still cuts: {l}");
    }
    // no progress bar, no terminal escapes in a pipe
    assert!(!out.contains('\u{1b}') && !out.contains('\r'), "{out:?}");
}

#[test]
fn every_kind_has_an_eta() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve_every_kind(dir.path(), &[], "");
    let f = gcode_square(dir.path(), 1, 600);
    let submit = |args: &[&str]| {
        let o = machlink()
            .env("MACHLINK_SOCKET", &s.socket)
            .arg("submit")
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success(), "submit {args:?}: {}", stderr(&o));
    };
    let gc = f.to_str().unwrap();
    let shape = sample_shape();
    let shape = shape.to_str().unwrap();
    submit(&[gc, "--machine", "router"]);
    submit(&[gc, "--machine", "ring"]);
    submit(&[gc, "--machine", "drive"]);
    submit(&[shape, "--op", "stitch", "--machine", "sewer"]);
    // each job's kind estimated its machine time (a G-code file's when it starts)
    let until = std::time::Instant::now() + Duration::from_secs(60);
    loop {
        let o = machlink()
            .env("MACHLINK_SOCKET", &s.socket)
            .args(["jobs", "--json"])
            .output()
            .unwrap();
        let jobs: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let jobs = jobs.as_array().unwrap().clone();
        let missing: Vec<String> = jobs
            .iter()
            .filter(|j| j["estimate_ms"].as_i64().is_none_or(|e| e <= 0))
            .map(|j| format!("job {} on {} ({})", j["id"], j["machine"], j["state"]))
            .collect();
        if missing.is_empty() && jobs.len() == 4 {
            break;
        }
        assert!(
            std::time::Instant::now() < until,
            "no machine time estimated for {missing:?}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn a_thread_break_is_a_line_in_a_pipe() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve_every_kind(dir.path(), &[], "thread_break_at = [40]");
    let shape = sample_shape();
    let mut child = machlink()
        .env("MACHLINK_SOCKET", &s.socket)
        .arg("submit")
        .arg(&shape)
        .args(["--op", "stitch", "--machine", "sewer", "--watch"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let out = BufReader::new(child.stdout.take().unwrap());
    let mut seen = Vec::new();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in out.lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    let until = std::time::Instant::now() + Duration::from_secs(60);
    let found = loop {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(l) => {
                let stop = l.contains("thread break");
                seen.push(l);
                if stop {
                    break true;
                }
            }
            Err(_) if std::time::Instant::now() > until => break false,
            Err(_) => {}
        }
    };
    let _ = child.kill();
    let _ = child.wait();
    assert!(found, "no line says the thread broke: {seen:#?}");
    assert!(
        seen.iter().any(|l| l.starts_with("job 1 paused at")),
        "the job's pause is a line: {seen:#?}"
    );
}

#[test]
fn the_demo_in_a_pipe_prints_its_progress_as_lines() {
    let o = machlink()
        .args(["demo", "--time-scale", "50"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let progress = out.lines().filter(|l| l.contains(" %) ETA ")).count();
    assert!(progress >= 10, "a line per step of progress: {out}");
    assert!(out.lines().any(|l| l.contains("completed at")), "{out}");
}

#[test]
fn a_stitch_job_sent_to_a_router_says_it_is_not_a_sewing_machine() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve_every_kind(dir.path(), &[], "");
    let o = machlink()
        .env("MACHLINK_SOCKET", &s.socket)
        .arg("submit")
        .arg(sample_shape())
        .args(["--op", "stitch", "--machine", "router"])
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("`router` is not a sewing machine"), "{err}");
}

#[test]
fn gcode_files_on_grbl_count_as_submitted_jobs_and_json_logs_hold_only_json() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve_every_kind(dir.path(), &["--log-format", "json"], "");
    let f = gcode_square(dir.path(), 1, 1200);
    for _ in 0..2 {
        let o = machlink()
            .env("MACHLINK_SOCKET", &s.socket)
            .arg("submit")
            .arg(&f)
            .args(["--machine", "router"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let mut c = std::os::unix::net::UnixStream::connect(&s.socket).unwrap();
    c.write_all(b"GET /metrics HTTP/1.0\r\nHost: x\r\n\r\n")
        .unwrap();
    let mut metrics = String::new();
    c.read_to_string(&mut metrics).unwrap();
    let line = metrics
        .lines()
        .find(|l| {
            l.starts_with("machlink_jobs_submitted_total{") && l.contains("machine=\"router\"")
        })
        .unwrap_or_else(|| panic!("no submitted count for router: {metrics}"));
    let n: f64 = line.rsplit(' ').next().unwrap().parse().unwrap();
    assert_eq!(n, 2.0, "{line}");
    drop(s);
    let log = std::fs::read_to_string(dir.path().join("serve.log")).unwrap();
    for l in log.lines() {
        assert!(
            serde_json::from_str::<serde_json::Value>(l).is_ok(),
            "not a JSON line: {l}"
        );
    }
    // a daemon that cannot start says why in JSON too
    std::fs::write(dir.path().join("bad.toml"), "[daemon]\njournal_every = 0\n").unwrap();
    let o = machlink()
        .current_dir(dir.path())
        .args(["serve", "--config", "bad.toml", "--log-format", "json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(!err.is_empty());
    for l in err.lines() {
        let v: serde_json::Value =
            serde_json::from_str(l).unwrap_or_else(|e| panic!("not a JSON line ({e}): {l}"));
        assert!(
            v["level"] == "ERROR" && v["error"].as_str().unwrap().contains("journal_every"),
            "{l}"
        );
    }
}

/// An open path (a seam) and, with `closed`, a closed square beside it.
fn open_contour(dir: &Path, closed: bool) -> std::path::PathBuf {
    let mut paths =
        vec![r#"{ "closed": false, "vertices": [[0,0,0], [40,0,0], [40,30,0]] }"#.to_string()];
    if closed {
        paths.push(
            r#"{ "closed": true, "vertices": [[60,0,0], [90,0,0], [90,30,0], [60,30,0]] }"#
                .to_string(),
        );
    }
    let f = dir.join(if closed { "mixed.json" } else { "seam.json" });
    std::fs::write(
        &f,
        format!(r#"{{ "units": "mm", "paths": [{}] }}"#, paths.join(", ")),
    )
    .unwrap();
    f
}

#[test]
fn an_inside_profile_of_an_open_contour_is_refused_or_warned_about() {
    let dir = tempfile::tempdir().unwrap();
    let plan = |file: &Path, side: &str| {
        machlink()
            .arg("plan")
            .arg(file)
            .args(["--op", "profile", "--side", side, "--post", "grbl", "-o"])
            .arg(dir.path().join("out.nc"))
            .output()
            .unwrap()
    };
    // only an open contour: nothing has an inside
    let o = plan(&open_contour(dir.path(), false), "inside");
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("an inside profile needs a closed contour")
            && err.contains("from (0.000, 0.000) to (40.000, 30.000)")
            && err.contains("--side on"),
        "{err}"
    );
    // beside a closed one: planned, and the open one is named as cut on its line
    let o = plan(&open_contour(dir.path(), true), "inside");
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("1 open contour (from (0.000, 0.000) to (40.000, 30.000)) has no inside")
            && err.contains("cut along its line"),
        "{err}"
    );
    // on the line: as asked, no warning
    let o = plan(&open_contour(dir.path(), false), "on");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("open contour"), "{}", stderr(&o));
}

#[test]
fn a_profile_that_leaves_no_path_says_inside_in_words() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("small.json");
    std::fs::write(
        &f,
        r#"{ "units": "mm", "paths": [{ "closed": true, "vertices": [[0,0,0], [4,0,0], [4,4,0], [0,4,0]] }] }"#,
    )
    .unwrap();
    let o = machlink()
        .arg("plan")
        .arg(&f)
        .args([
            "--op",
            "profile",
            "--side",
            "inside",
            "--tool-diameter",
            "6",
            "--post",
            "grbl",
            "-o",
        ])
        .arg(dir.path().join("out.nc"))
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("an inside profile with a 6 mm tool"), "{err}");
    assert!(!err.contains("Inside"), "{err}");
}

/// The fenced `sh` blocks of a page, their lines without comments.
fn shell_lines(page: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut inside = false;
    for l in page.lines() {
        if l.starts_with("```") {
            inside = !inside && l.trim() == "```sh";
            continue;
        }
        if inside {
            let cmd = l.split(" #").next().unwrap_or("").trim();
            if !cmd.is_empty() && !cmd.starts_with('#') {
                out.push(cmd.to_string());
            }
        }
    }
    out
}

fn repo() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn the_unit_as_install_md_installs_it_passes_systemd_analyze_verify() {
    let page = std::fs::read_to_string(repo().join("docs/install.md")).unwrap();
    let steps = shell_lines(&page);
    // the page's own line that puts the unit in place, done into a folder standing in for /
    let install = steps
        .iter()
        .find(|l| l.starts_with("install ") && l.contains("contrib/machlink.service"))
        .expect("install.md installs contrib/machlink.service");
    let dest = install.split_whitespace().last().unwrap();
    assert!(dest.starts_with("/etc/systemd/system/"), "{install}");
    let unit = std::fs::read_to_string(repo().join("contrib/machlink.service")).unwrap();
    // the documentation the unit names is installed by the page
    let doc = unit
        .lines()
        .find_map(|l| l.strip_prefix("Documentation=file:"))
        .expect("the unit names its documentation");
    let doc_step = steps
        .iter()
        .find(|l| l.starts_with("install ") && l.ends_with(doc))
        .unwrap_or_else(|| panic!("install.md installs {doc}, which the unit names"));
    let src = doc_step.split_whitespace().rev().nth(1).unwrap();
    assert!(
        repo().join(src).is_file(),
        "{doc_step}: {src} is in the repository"
    );
    // the unit and the page say SIGTERM interrupts, not cancels
    assert!(unit.contains("KillSignal=SIGTERM") && unit.contains("interrupted (not cancelled)"));
    assert!(page.contains("a stop **interrupts** (does not cancel)"));
    if Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_err()
    {
        eprintln!("skipped systemd-analyze verify: systemd-analyze is not installed here");
        return;
    }
    let root = tempfile::tempdir().unwrap();
    let installed = root.path().join(dest.trim_start_matches('/'));
    std::fs::create_dir_all(installed.parent().unwrap()).unwrap();
    // the page installs the release binary as /usr/bin/machlink; the one just built stands in
    let exec = unit
        .lines()
        .find_map(|l| l.strip_prefix("ExecStart="))
        .and_then(|l| l.split_whitespace().next())
        .unwrap()
        .to_string();
    assert!(
        steps
            .iter()
            .any(|l| l.starts_with("install ") && l.ends_with(&exec)),
        "install.md installs {exec}, the unit's ExecStart"
    );
    std::fs::write(
        &installed,
        unit.replace(&exec, env!("CARGO_BIN_EXE_machlink")),
    )
    .unwrap();
    let o = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&installed)
        .output()
        .unwrap();
    assert!(
        o.status.success() && o.stderr.is_empty(),
        "systemd-analyze verify {}: {}{}",
        installed.display(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The group of uid NOBODY, which stands in for `machlink` where that group does not exist.
const NOGROUP: u32 = 65534;

#[test]
fn a_member_of_the_shipped_socket_group_connects_as_an_operator() {
    if !nix::unistd::Uid::effective().is_root() {
        eprintln!(
            "skipped: a user other than the daemon's is needed, and only root can run a client as one"
        );
        return;
    }
    let shipped = std::fs::read_to_string(repo().join("contrib/machlink.toml")).unwrap();
    let group = nix::unistd::Group::from_gid(nix::unistd::Gid::from_raw(NOGROUP))
        .ok()
        .flatten()
        .map(|g| g.name)
        .expect("a group 65534 (nogroup)");
    let dir = tempfile::tempdir().unwrap();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    // the shipped config as it is, but for the group (the one nobody is in), the paths (in a
    // folder of the test's) and the machine (simulated)
    let store = dir.path().join("state/machlink.db");
    let socket = dir.path().join("run/machlink.sock");
    std::fs::create_dir(dir.path().join("state")).unwrap();
    let machine_at = shipped.find("[[machine]]").unwrap();
    let end = shipped[machine_at..]
        .find("\n\n")
        .map_or(shipped.len(), |n| machine_at + n);
    let cfg = format!(
        "{}[[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\n{}",
        &shipped[..machine_at],
        &shipped[end..]
    )
    .replace("/var/lib/machlink/machlink.db", store.to_str().unwrap())
    .replace("/run/machlink/machlink.sock", socket.to_str().unwrap())
    .replace("\"machlink\"", &format!("\"{group}\""));
    assert!(
        cfg.contains("socket_group") && cfg.contains("[[access.group]]"),
        "{cfg}"
    );
    let file = dir.path().join("machlink.toml");
    std::fs::write(&file, &cfg).unwrap();
    let mut c = machlink();
    c.arg("serve")
        .arg("--config")
        .arg(&file)
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    let _s = Serve::spawn(c, &socket, Duration::from_secs(30));
    let o = machlink()
        .arg("whoami")
        .arg("--socket")
        .arg(&socket)
        .current_dir("/")
        .uid(NOBODY)
        .gid(NOGROUP)
        .output()
        .unwrap();
    assert!(o.status.success(), "a member of {group}: {}", stderr(&o));
    let who: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(who["role"], "operator", "{who}");
}

#[test]
fn a_long_alarm_text_keeps_the_machines_columns_in_place() {
    let dir = tempfile::tempdir().unwrap();
    // a homing machine starts locked, its alarm's text longer than the STATUS column
    std::fs::write(
        dir.path().join("cell.toml"),
        "[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\n\n\
         [[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\nhoming = true\n\n\
         [[machine]]\nname = \"mill\"\nlink = \"sim-grbl\"\n",
    )
    .unwrap();
    let mut c = machlink();
    c.current_dir(dir.path())
        .args(["serve", "--config", "cell.toml"])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    let _s = Serve::spawn(c, &dir.path().join("ml.sock"), Duration::from_secs(30));
    let until = std::time::Instant::now() + Duration::from_secs(30);
    let table = loop {
        let o = machlink()
            .current_dir(dir.path())
            .arg("machines")
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        let t = String::from_utf8_lossy(&o.stdout).into_owned();
        if t.contains("alarm") && t.lines().all(|l| !l.contains("never")) {
            break t;
        }
        assert!(std::time::Instant::now() < until, "no alarm shown: {t}");
        std::thread::sleep(Duration::from_millis(100));
    };
    let lines: Vec<&str> = table.lines().collect();
    let col = |l: &str, word: &str| l.find(word).map(|b| l[..b].chars().count());
    let reported = col(lines[0], "REPORTED").unwrap();
    let position = col(lines[0], "POSITION").unwrap();
    let status = col(lines[0], "STATUS").unwrap();
    for l in &lines[1..] {
        // the age ("1s ago") ends where the REPORTED heading ends, the position starts under
        // POSITION and the status under STATUS, whatever the status says
        let ago = col(l, " ago").unwrap_or_else(|| panic!("{table}"));
        assert_eq!(ago + 4, reported + "REPORTED".len(), "{table}");
        let at = |c: usize| l.chars().skip(c).take(1).collect::<String>();
        assert_eq!(at(position), "X", "{table}");
        assert!(at(status - 1) == " " && at(status) != " ", "{table}");
    }
    // the whole text, not cut
    assert!(
        table.contains("alarm lock: clear the cause, then unlock ($X) or home ($H)"),
        "{table}"
    );
}

#[test]
fn a_contour_that_crosses_itself_names_its_entities_handles_and_layer() {
    let dir = tempfile::tempdir().unwrap();
    // a bow tie of four LINEs on layer CUT: the first and third cross at (20, 15)
    let mut dxf = String::from("0\nSECTION\n2\nENTITIES\n");
    for ((a, b), h) in [
        (((0, 0), (40, 30)), "2A"),
        (((40, 30), (40, 0)), "2B"),
        (((40, 0), (0, 30)), "2C"),
        (((0, 30), (0, 0)), "2D"),
    ] {
        dxf.push_str(&format!(
            "0\nLINE\n5\n{h}\n8\nCUT\n10\n{}\n20\n{}\n11\n{}\n21\n{}\n",
            a.0, a.1, b.0, b.1
        ));
    }
    dxf.push_str("0\nENDSEC\n0\nEOF\n");
    let f = dir.path().join("bowtie.dxf");
    std::fs::write(&f, dxf).unwrap();
    let o = machlink()
        .arg("plan")
        .arg(&f)
        .args(["--op", "profile", "--post", "grbl", "-o"])
        .arg(dir.path().join("out.nc"))
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("crosses itself near (20, 15)"), "{err}");
    for h in [
        "LINE (handle 2A, line 5) on layer CUT",
        "LINE (handle 2C, line 33) on layer CUT",
    ] {
        assert!(err.contains(h), "{h} in: {err}");
    }
    assert!(
        !err.contains("handle 2B") && !err.contains("handle 2D"),
        "{err}"
    );
}
