//! Every example command of README.md and docs/*.md runs as written, through the built
//! binary, in a cell like the one the pages describe: simulated GRBL (`router`, `mill`,
//! `router-a`), Modbus (`press`), sewing (`pocket-setter`) and CANopen (`gantry`) machines,
//! a running `machlink serve --config cell.toml` (with TLS on TCP and a NATS fleet), and the
//! sample files the pages name (part.json, part.dxf, part.svg, mould.stl, probed.csv, …).
//!
//! Which lines are example commands: in a fenced block marked `sh`, `bash`, `shell`,
//! `console` or unmarked, a line (a leading `$ ` dropped, `\` continuations joined) that
//! starts with `machlink `, `machlink-sim ` or `cargo `. A line with a placeholder in capitals
//! (`FILE`, `JOB`, `OUT.svg`) or an optional `[--flag]` is a synopsis, not an example, and is
//! not run. A `# comment` is the reader's, not the shell's, and is dropped.
//!
//! Placeholders the pages cannot know are filled from the cell (`fill`): the job number `7`
//! becomes a job that is running right then, `cell-3:7878` the cell's own TCP address,
//! `nats.shop.lan:4222` the fixture's NATS server, `/tmp/…` and system paths (/etc, /usr/local)
//! folders inside the cell, and `cargo run … -p machlink --` the built `machlink`.
//!
//! A command that asks the operator (`resume` without `--yes`) runs at a terminal (`script`
//! gives it a pty) where the answer is `y`. A command fails if it exits non-zero or runs
//! longer than a minute. Commands that run until
//! stopped (`serve`, `events`, `watch`, `machlink-sim`) pass when they are still running
//! after a few seconds (half a second after their ready line, for `serve` and the
//! simulators) or ended with 0; each `serve` runs in a copy of the cell, beside the
//! fixture's daemon. Lines run in the page's order (a `plan … -o part.nc` feeds a later
//! `preview part.nc`), with `bash -e -o pipefail`, so `a ; b` and `a | jq .` fail on `a`.
//! Pages run side by side, three at a time (`DOC_EXAMPLES_JOBS`), each in its own cell.

use crate::common::{bin, nats};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Commands that cannot run in a test, each with the reason. Matched on the start of the
/// command as written (after the leading `$ `).
const SKIP: &[(&str, &str)] = &[
    // the whole workspace's tests from inside one of them: recursion, and hours on 2 cores
    ("cargo test --workspace", "runs this test itself"),
    // release builds take most of an hour here; the debug binary is what every other line runs
    (
        "cargo build --release",
        "a release build (docs/install.md): the test runs the debug build",
    ),
];

/// How long a command that runs until stopped must stay up to pass.
const STAYS_UP: Duration = Duration::from_secs(3);
/// The longest any other command may take.
const LIMIT: Duration = Duration::from_secs(60);

#[derive(Debug, Clone)]
struct Example {
    file: String,
    line: usize,
    command: String,
}

/// The example commands of one page, in order.
fn examples_of(file: &str, text: &str) -> Vec<Example> {
    let mut out = Vec::new();
    let mut in_block: Option<bool> = None; // Some(runs): inside a fence whose lines may run
    let mut pending: Option<(usize, String)> = None;
    for (i, raw) in text.lines().enumerate() {
        let t = raw.trim();
        if let Some(info) = t.strip_prefix("```") {
            in_block = match in_block {
                None => Some(matches!(
                    info.trim(),
                    "" | "sh" | "bash" | "shell" | "console"
                )),
                Some(_) => None,
            };
            pending = None;
            continue;
        }
        if in_block != Some(true) {
            continue;
        }
        let (start, mut joined) = match pending.take() {
            Some((start, so_far)) => (start, so_far + " " + t),
            None => (i + 1, t.strip_prefix("$ ").unwrap_or(t).to_string()),
        };
        if let Some(cont) = joined.strip_suffix('\\') {
            joined = cont.trim_end().to_string();
            pending = Some((start, joined));
            continue;
        }
        let command = strip_comment(&joined);
        let runs = ["machlink ", "machlink-sim ", "cargo "]
            .iter()
            .any(|p| command.starts_with(p));
        if runs && !is_synopsis(&command) {
            out.push(Example {
                file: file.to_string(),
                line: start,
                command,
            });
        }
    }
    out
}

/// The line without its `# comment`.
fn strip_comment(line: &str) -> String {
    match line.find(" #") {
        Some(at) => line[..at].trim_end().to_string(),
        None => line.trim_end().to_string(),
    }
}

/// A usage line (`machlink plan FILE --op pocket|profile [--depth Z]`), not an example.
fn is_synopsis(command: &str) -> bool {
    if command.contains("[-") || command.contains('…') {
        return true;
    }
    command
        .split(|c: char| c.is_whitespace() || "|,=[]".contains(c))
        .filter(|w| !w.is_empty())
        .any(|w| {
            let stem = w.split('.').next().unwrap_or(w);
            stem.len() == w.len().min(stem.len())
                && stem.chars().next().is_some_and(|c| c.is_ascii_uppercase())
                && stem
                    .chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
        })
}

fn pages(root: &Path) -> Vec<(String, String)> {
    let mut files = vec![root.join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    files
        .into_iter()
        .map(|p| {
            let name = p.strip_prefix(root).unwrap().display().to_string();
            (name, std::fs::read_to_string(&p).unwrap())
        })
        .collect()
}

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

/// The cell the pages assume, in a temp folder.
struct Cell {
    dir: tempfile::TempDir,
    nats: nats::Nats,
    tcp_port: u16,
    token: String,
    daemon: Option<Child>,
    /// The job last started for a `7` of the pages.
    running_job: Option<u64>,
}

impl Drop for Cell {
    fn drop(&mut self) {
        if let Some(mut d) = self.daemon.take() {
            stop(&mut d);
        }
    }
}

/// SIGTERM to the process group, then SIGKILL after a grace.
fn stop(child: &mut Child) {
    let pgid = nix::unistd::Pid::from_raw(child.id() as i32);
    let _ = nix::sys::signal::killpg(pgid, nix::sys::signal::Signal::SIGTERM);
    let until = Instant::now() + Duration::from_secs(10);
    while Instant::now() < until {
        if let Ok(Some(_)) = child.try_wait() {
            return;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = nix::sys::signal::killpg(pgid, nix::sys::signal::Signal::SIGKILL);
    let _ = child.wait();
}

/// The last line of the cell's `[fleet]` table, which ends the generated config.
const FLEET_END: &str = "machines = [\"router-a\"]\n";

fn cell_config(nats_url: &str, fleet: bool) -> String {
    let mut s = String::from(
        "[daemon]\nstore = \"jobs.db\"\nsocket = \"machlink.sock\"\n\n\
         [[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\ntime_scale = 20.0\nhoming = true\nmax_feed = 3000.0\n\
         work_area = { min = [-200.0, -200.0, -60.0], max = [600.0, 400.0, 60.0] }\n\
         tools = [ { number = 1, diameter = 3.0 }, { number = 2, diameter = 6.0 } ]\n\n\
         [[machine]]\nname = \"mill\"\nlink = \"sim-grbl\"\ntime_scale = 20.0\n\n\
         [[machine]]\nname = \"router-a\"\nlink = \"sim-grbl\"\ntime_scale = 20.0\n\n\
         [[machine]]\nname = \"pocket-setter\"\nlink = \"sim-sewing\"\ntime_scale = 50.0\n\n\
         [[machine]]\nname = \"press\"\nlink = \"sim-modbus\"\ntime_scale = 20.0\n\n\
         [[machine]]\nname = \"gantry\"\nlink = \"sim-canopen\"\ntime_scale = 10.0\n\
         axes = [\n  { axis = \"x\", node = 1, counts_per_mm = 1000, max_velocity = 60, max_acceleration = 800, max_jerk = 20000 },\n  \
         { axis = \"y\", node = 2, counts_per_mm = 1000, max_velocity = 50, max_acceleration = 600, max_jerk = 20000 },\n  \
         { axis = \"z\", node = 3, counts_per_mm = 1000, max_velocity = 15, max_acceleration = 400, max_jerk = 20000 },\n]\n",
    );
    if fleet {
        s += &format!("\n[fleet]\nurl = \"{nats_url}\"\nname = \"cell-a\"\n{FLEET_END}");
    }
    s
}

/// A small square pyramid, closed, in ASCII STL: 40 × 40 mm, 10 mm high.
fn pyramid_stl() -> String {
    let (a, b, c, d, top) = (
        [0.0, 0.0, 0.0],
        [40.0, 0.0, 0.0],
        [40.0, 40.0, 0.0],
        [0.0, 40.0, 0.0],
        [20.0, 20.0, 10.0],
    );
    let faces = [
        [a, c, b],
        [a, d, c],
        [a, b, top],
        [b, c, top],
        [c, d, top],
        [d, a, top],
    ];
    let mut s = String::from("solid mould\n");
    for f in faces {
        s += " facet normal 0 0 0\n  outer loop\n";
        for v in f {
            s += &format!("   vertex {} {} {}\n", v[0], v[1], v[2]);
        }
        s += "  endloop\n endfacet\n";
    }
    s + "endsolid mould\n"
}

/// A probed grid of a gentle bump, one point a line, rows apart by blank lines.
fn probed_csv() -> String {
    let mut s = String::from("x,y,z\n");
    for j in 0..9 {
        for i in 0..9 {
            let (x, y) = (i as f64 * 5.0, j as f64 * 5.0);
            let z = 4.0 - ((x - 20.0).powi(2) + (y - 20.0).powi(2)) / 200.0;
            s += &format!("{x},{y},{z:.3}\n");
        }
        s += "\n";
    }
    s
}

/// A G-code program that keeps a simulated router busy for a while (about a minute at
/// time scale 20): the job a `7` of the pages stands for.
fn long_program() -> String {
    let mut s = String::from("G21 G90\nG0 Z5\nG0 X0 Y0\nG1 Z-0.5 F300\n");
    for i in 0..600 {
        let x = if i % 2 == 0 { 100 } else { 0 };
        s += &format!("G1 X{x} Y{:.1} F300\n", i as f64 * 0.1);
    }
    s + "G0 Z5\nM2\n"
}

const PART_SVG: &str = r#"<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="60mm" viewBox="0 0 100 60">
  <rect x="10" y="10" width="80" height="40" fill="none" stroke="black"/>
</svg>
"#;

const PART_NC: &str =
    "G21 G90\nG0 Z5\nG0 X10 Y10\nG1 Z-1 F300\nG1 X110 F1200\nG1 Y70\nG1 X10\nG1 Y10\nG0 Z5\nM2\n";

impl Cell {
    fn new() -> Cell {
        let dir = tempfile::Builder::new()
            .prefix("mldoc")
            .tempdir()
            .expect("a temp dir");
        let nats = nats::start_nats(dir.path());
        let d = dir.path();
        let root = repo_root();
        std::fs::write(d.join("cell.toml"), cell_config(&nats.url, true)).unwrap();
        let plate = std::fs::read(root.join("docs/examples/plate.json")).unwrap();
        for name in ["part.json", "plate.json", "pocket.json", "label.json"] {
            std::fs::write(d.join(name), &plate).unwrap();
        }
        std::fs::copy(root.join("docs/examples/sign.dxf"), d.join("part.dxf")).unwrap();
        std::fs::create_dir_all(d.join("docs")).unwrap();
        copy_dir(&root.join("docs/examples"), &d.join("docs/examples"));
        // the other CAM programs docs/daemon.md names
        std::fs::create_dir_all(d.join("tests/data")).unwrap();
        copy_dir(&root.join("tests/data/gcode"), &d.join("tests/data/gcode"));
        std::fs::write(d.join("part.svg"), PART_SVG).unwrap();
        std::fs::write(d.join("part.nc"), PART_NC).unwrap();
        std::fs::write(d.join("mould.stl"), pyramid_stl()).unwrap();
        std::fs::write(d.join("probed.csv"), probed_csv()).unwrap();
        std::fs::write(d.join("long.nc"), long_program()).unwrap();
        let (ca, cert, key) = crate::tls::certificates(d, "cell");
        std::fs::rename(ca, d.join("cell-ca.pem")).unwrap();
        std::fs::rename(cert, d.join("daemon.pem")).unwrap();
        std::fs::rename(key, d.join("daemon-key.pem")).unwrap();
        for system in [
            "etc/bash_completion.d",
            "etc/fish/completions",
            "usr/local/share/zsh/site-functions",
            "usr/local/share/man/man1",
        ] {
            std::fs::create_dir_all(d.join("root").join(system)).unwrap();
        }
        let mut cell = Cell {
            dir,
            nats,
            tcp_port: free_port(),
            token: String::new(),
            daemon: None,
            running_job: None,
        };
        cell.token = cell.admin_token();
        cell.start_daemon();
        cell
    }

    fn path(&self) -> &Path {
        self.dir.path()
    }

    /// An admin token for the TCP examples, appended to cell.toml as docs/security.md shows.
    fn admin_token(&self) -> String {
        let out = self
            .command("machlink token new --role admin --name doc-examples >> cell.toml")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "token new: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let err = String::from_utf8_lossy(&out.stderr);
        let at = err
            .find("mlk_")
            .expect("token new prints the token on stderr");
        err[at..]
            .split(|c: char| c.is_whitespace())
            .next()
            .unwrap()
            .to_string()
    }

    /// `machlink serve --config cell.toml`, also on TCP with TLS for the `--connect` lines.
    fn start_daemon(&mut self) {
        let port = self.tcp_port;
        let child = self
            .command(&format!(
                "exec machlink serve --config cell.toml --listen 127.0.0.1:{port} \
                 --tls-cert daemon.pem --tls-key daemon-key.pem 2> daemon.log"
            ))
            .spawn()
            .expect("serve starts");
        self.daemon = Some(child);
        let until = Instant::now() + Duration::from_secs(60);
        loop {
            let ok = self.command("machlink machines").output().unwrap();
            if ok.status.success() {
                break;
            }
            assert!(
                Instant::now() < until,
                "the fixture daemon did not answer: {}\n{}",
                String::from_utf8_lossy(&ok.stderr),
                std::fs::read_to_string(self.path().join("daemon.log")).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(200));
        }
        // the router homes (its homing is on, as a real router's): an operator's first step
        let home = self.command("machlink home router").output().unwrap();
        assert!(
            home.status.success(),
            "the fixture could not home the router: {}",
            String::from_utf8_lossy(&home.stderr)
        );
    }

    /// A shell in the cell, with the built binaries first on PATH.
    fn command(&self, line: &str) -> Command {
        let mut c = Command::new("bash");
        c.args(["-e", "-o", "pipefail", "-c", line])
            .current_dir(self.path())
            .env("PATH", path_with(&bin::bin_dir()))
            .env("MACHLINK_CONFIG", self.path().join("cell.toml"))
            .env_remove("MACHLINK_SOCKET")
            .env_remove("MACHLINK_TOKEN")
            .stdin(Stdio::null());
        std::os::unix::process::CommandExt::process_group(&mut c, 0);
        c
    }

    /// The machine's jobs that have not ended, from `jobs --json`.
    fn open_jobs(&self) -> Vec<u64> {
        let out = self.command("machlink jobs --json").output().unwrap();
        assert!(
            out.status.success(),
            "jobs --json: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value =
            serde_json::from_slice(&out.stdout).expect("jobs --json is JSON");
        let jobs = v.as_array().cloned().unwrap_or_default();
        jobs.iter()
            .filter(|j| {
                !matches!(
                    j["state"].as_str(),
                    Some("completed" | "failed" | "cancelled")
                )
            })
            .filter_map(|j| j["id"].as_u64())
            .collect()
    }

    fn job_state(&self, id: u64) -> String {
        let out = self.command("machlink jobs --json").output().unwrap();
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_default();
        v.as_array()
            .and_then(|a| a.iter().find(|j| j["id"].as_u64() == Some(id)).cloned())
            .and_then(|j| j["state"].as_str().map(String::from))
            .unwrap_or_default()
    }

    /// A job running on `router` now (earlier ones cancelled): what `7` stands for.
    fn running_job(&mut self) -> u64 {
        if let Some(id) = self.running_job {
            if self.job_state(id) == "running" {
                return id;
            }
        }
        for id in self.open_jobs() {
            let _ = self.command(&format!("machlink cancel {id}")).output();
        }
        let out = self
            .command("machlink submit long.nc --machine router")
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "the fixture job was refused: {text}");
        let id: u64 = text
            .split_whitespace()
            .skip_while(|w| *w != "job")
            .nth(1)
            .and_then(|w| w.parse().ok())
            .unwrap_or_else(|| panic!("no job number in {text:?}"));
        let until = Instant::now() + Duration::from_secs(30);
        while self.job_state(id) != "running" {
            assert!(
                Instant::now() < until,
                "job {id} never ran: {}",
                self.job_state(id)
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        self.running_job = Some(id);
        id
    }

    /// Cancels every open job and waits until they have ended: `unlock`, `home` and `jog`
    /// are for a machine between jobs.
    fn between_jobs(&mut self) {
        for id in self.open_jobs() {
            let _ = self.command(&format!("machlink cancel {id}")).output();
        }
        let until = Instant::now() + Duration::from_secs(30);
        while !self.open_jobs().is_empty() {
            assert!(
                Instant::now() < until,
                "jobs did not end: {:?}",
                self.open_jobs()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        self.running_job = None;
    }

    /// The job a `7` stands for after `verb`: a running one to watch, pause or override, a
    /// paused one (paused here first) to resume, a cancelled one to resume from a line, any
    /// open one to cancel.
    fn job_for(&mut self, verb: &str) -> u64 {
        let cached = self.running_job.map(|id| (id, self.job_state(id)));
        match (verb, cached) {
            ("resume --from-line", _) => {
                // a stopped job: one cancelled mid-way
                let id = self.running_job();
                let out = self
                    .command(&format!("machlink cancel {id}"))
                    .output()
                    .unwrap();
                assert!(
                    out.status.success(),
                    "cancel {id}: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
                let until = Instant::now() + Duration::from_secs(30);
                while self.job_state(id) != "cancelled" {
                    assert!(Instant::now() < until, "job {id} was not cancelled");
                    std::thread::sleep(Duration::from_millis(100));
                }
                self.running_job = None;
                id
            }
            ("resume", Some((id, s))) if s == "paused" || s == "interrupted" => id,
            ("cancel", Some((id, s))) if s == "paused" || s == "running" => id,
            ("resume", _) => {
                let id = self.running_job();
                let out = self
                    .command(&format!("machlink pause {id}"))
                    .output()
                    .unwrap();
                assert!(
                    out.status.success(),
                    "pause {id}: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
                let until = Instant::now() + Duration::from_secs(30);
                while self.job_state(id) != "paused" {
                    assert!(Instant::now() < until, "job {id} did not pause");
                    std::thread::sleep(Duration::from_millis(100));
                }
                id
            }
            _ => self.running_job(),
        }
    }

    /// The command with the cell's placeholders filled in.
    fn fill(&mut self, command: &str) -> String {
        let d = self.path().display().to_string();
        let mut c = command.to_string();
        for prefix in [
            "cargo run --release -p machlink --",
            "cargo run -p machlink --",
        ] {
            if let Some(rest) = c.strip_prefix(prefix) {
                c = format!("machlink{rest}");
            }
        }
        let job_verb = |w: &str| matches!(w, "watch" | "pause" | "resume" | "cancel" | "override");
        let words: Vec<String> = c.split(' ').map(String::from).collect();
        if let Some(verb) = words
            .windows(2)
            .find(|w| job_verb(&w[0]) && w[1] == "7")
            .map(|w| w[0].clone())
        {
            let verb = if c.contains("--from-line") {
                "resume --from-line".to_string()
            } else {
                verb
            };
            let id = self.job_for(&verb).to_string();
            let mut filled = words.clone();
            for i in 1..words.len() {
                if job_verb(&words[i - 1]) && words[i] == "7" {
                    filled[i] = id.clone();
                }
            }
            c = filled.join(" ");
        }
        let at_machine = ["machlink unlock ", "machlink home ", "machlink jog "];
        if at_machine.iter().any(|p| c.starts_with(p)) {
            self.between_jobs();
        }
        c = c.replace("nats://nats.shop.lan:4222", &self.nats.url);
        c = c.replace("cell-3:7878", &format!("localhost:{}", self.tcp_port));
        if c.starts_with("machlink serve") {
            c = c.replace(":7878", &format!(":{}", free_port()));
            c = c.replace(":9464", &format!(":{}", free_port()));
        }
        c = c.replace(" /tmp/", &format!(" {d}/tmp-"));
        c = c.replace(" /etc/machlink/machlink.toml", " cell.toml");
        for system in [" /etc/", " /usr/local/"] {
            c = c.replace(system, &format!(" {d}/root{}", system.trim_start()));
        }
        c
    }

    /// A copy of the cell (its own socket and store, no fleet) for one `serve` example.
    fn serve_folder(&self, n: usize) -> PathBuf {
        let f = self.path().join(format!("serve-{n}"));
        std::fs::create_dir_all(&f).unwrap();
        // the cell's own tables after [fleet] (tokens a page appended) come along
        let own = std::fs::read_to_string(self.path().join("cell.toml")).unwrap();
        let appended = own
            .split_once(FLEET_END)
            .map(|(_, rest)| rest.to_string())
            .unwrap_or_default();
        let config = cell_config(&self.nats.url, false) + &appended;
        std::fs::write(f.join("cell.toml"), config).unwrap();
        for pem in ["daemon.pem", "daemon-key.pem", "cell-ca.pem"] {
            std::fs::copy(self.path().join(pem), f.join(pem)).unwrap();
        }
        f
    }
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        if p.is_file() {
            std::fs::copy(&p, to.join(p.file_name().unwrap())).unwrap();
        }
    }
}

fn path_with(dir: &Path) -> std::ffi::OsString {
    let mut parts = vec![dir.to_path_buf()];
    if let Some(p) = std::env::var_os("PATH") {
        parts.extend(std::env::split_paths(&p));
    }
    std::env::join_paths(parts).unwrap()
}

/// Asks the operator before it moves the machine (`resume` without `--yes`).
fn asks(command: &str) -> bool {
    command.starts_with("machlink resume") && !command.contains("--yes")
}

/// `s` as one shell word.
fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// Runs until stopped: passes when still running after `STAYS_UP`.
fn runs_until_stopped(command: &str) -> bool {
    command.starts_with("machlink serve")
        || command.starts_with("machlink-sim ")
        || command.starts_with("machlink events")
        || command.starts_with("machlink watch")
        || command.starts_with("machlink dashboard --open")
        || (command.starts_with("machlink submit") && command.contains("--watch"))
}

/// What a command that runs until stopped prints once it is up, if it prints anything: the
/// daemon once it listens, a simulator once its device is open. Such a command passes once
/// the line is out and it is still running [`READY_GRACE`] later, instead of after the whole
/// [`STAYS_UP`]; one without a mark (`events`, `watch`, `submit --watch`) waits it out.
fn ready_mark(command: &str) -> Option<&'static str> {
    if command.starts_with("machlink serve") {
        Some("machlink daemon listening at")
    } else if command.starts_with("machlink-sim modbus") {
        Some("modbus device")
    } else if command.starts_with("machlink-sim ") {
        Some("stop with Ctrl-C")
    } else {
        None
    }
}

/// How long a command must still run after printing its ready mark.
const READY_GRACE: Duration = Duration::from_millis(500);

/// How a command is expected to behave.
#[derive(Clone, Copy)]
enum Runs {
    /// It ends, with 0, within [`LIMIT`].
    ToTheEnd,
    /// It runs until stopped (or ends with 0): up for [`STAYS_UP`], or for
    /// [`READY_GRACE`] after its ready mark.
    UntilStopped { ready: Option<&'static str> },
}

/// Runs one filled command; `Err` says what went wrong.
fn run(mut cmd: Command, runs: Runs) -> Result<(), String> {
    cmd.stdout(Stdio::piped()).stderr(Stdio::piped());
    let mut child = cmd.spawn().map_err(|e| format!("cannot start: {e}"))?;
    let started = Instant::now();
    let (limit, mark) = match runs {
        Runs::ToTheEnd => (LIMIT, None),
        Runs::UntilStopped { ready } => (STAYS_UP, ready),
    };
    // drain the pipes on threads so a chatty command never blocks on a full pipe; what
    // has come so far is readable while the command runs (for its ready mark)
    let drain = |mut pipe: Box<dyn Read + Send>| {
        let got = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let to = got.clone();
        let t = std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n) = pipe.read(&mut buf) {
                if n == 0 {
                    break;
                }
                to.lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .extend_from_slice(&buf[..n]);
            }
        });
        (got, t)
    };
    let (out, out_t) = drain(Box::new(child.stdout.take().unwrap()));
    let (err, err_t) = drain(Box::new(child.stderr.take().unwrap()));
    let text = |b: &std::sync::Mutex<Vec<u8>>| {
        String::from_utf8_lossy(&b.lock().unwrap_or_else(|e| e.into_inner())).to_string()
    };
    let mut ready_at: Option<Instant> = None;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if started.elapsed() > limit || ready_at.is_some_and(|t| t.elapsed() > READY_GRACE) {
            break None;
        }
        if let (Some(mark), None) = (mark, ready_at) {
            if text(&out).contains(mark) || text(&err).contains(mark) {
                ready_at = Some(Instant::now());
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    if status.is_none() {
        stop(&mut child);
    }
    let _ = out_t.join();
    let _ = err_t.join();
    let (stdout, stderr) = (text(&out), text(&err));
    let tail = |s: &str| {
        s.split(['\n', '\r'])
            .filter(|l| !l.trim().is_empty())
            .rev()
            .take(8)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect::<Vec<_>>()
            .join("\n")
    };
    match status {
        None if matches!(runs, Runs::UntilStopped { .. }) => Ok(()),
        None => Err(format!(
            "still running after {} s\n{}",
            limit.as_secs(),
            tail(&stderr)
        )),
        Some(s) if s.success() => Ok(()),
        Some(s) => Err(format!(
            "exit {:?}\nstderr: {}\nstdout: {}",
            s.code(),
            tail(&stderr),
            tail(&stdout)
        )),
    }
}

fn skip_reason(command: &str) -> Option<&'static str> {
    SKIP.iter()
        .find(|(start, _)| command.starts_with(start))
        .map(|(_, why)| *why)
}

#[test]
fn synopses_are_told_from_examples() {
    assert!(is_synopsis(
        "machlink plan FILE --op pocket|profile [--tool-diameter D]"
    ));
    assert!(is_synopsis(
        "machlink preview FILE_OR_PROGRAM -o OUT.svg|OUT.png"
    ));
    assert!(is_synopsis(
        "machlink jobs | machines | watch JOB | pause JOB"
    ));
    assert!(!is_synopsis(
        "machlink plan part.dxf --op pocket --tool-diameter 6 -o part.nc"
    ));
    assert!(!is_synopsis(
        "machlink events --machine router --json | jq ."
    ));
    let page = "text\n```sh\n$ machlink jobs   # all\nmachlink-sim grbl --pty /tmp/g \\\n  --time-scale 10\n```\n```toml\nmachlink = 1\n```\n";
    let ex = examples_of("p.md", page);
    let cmds: Vec<_> = ex.iter().map(|e| (e.line, e.command.as_str())).collect();
    assert_eq!(
        cmds,
        [
            (3, "machlink jobs"),
            (4, "machlink-sim grbl --pty /tmp/g --time-scale 10")
        ]
    );
}

#[test]
fn every_example_command_of_the_readme_and_docs_runs_as_written() {
    let root = repo_root();
    let examples: Vec<Example> = pages(&root)
        .iter()
        .flat_map(|(name, text)| examples_of(name, text))
        .collect();
    assert!(
        examples.len() > 40,
        "only {} example commands found",
        examples.len()
    );
    // set DOC_EXAMPLES_ONLY=docs/fleet.md (a page, or a word of the command) to run a few
    let only = std::env::var("DOC_EXAMPLES_ONLY").ok();
    let mut by_page: Vec<(String, Vec<(usize, Example)>)> = Vec::new();
    for (n, ex) in examples.into_iter().enumerate() {
        if only
            .as_deref()
            .is_some_and(|o| !ex.command.contains(o) && !ex.file.contains(o))
        {
            continue;
        }
        if let Some(why) = skip_reason(&ex.command) {
            eprintln!("skip {}:{}: {} ({why})", ex.file, ex.line, ex.command);
            continue;
        }
        match by_page.last_mut() {
            Some((page, list)) if *page == ex.file => list.push((n, ex)),
            _ => by_page.push((ex.file.clone(), vec![(n, ex)])),
        }
    }
    // Each page is read on its own, in a fresh cell (its own folder, daemon, simulated
    // machines and NATS server), so pages run side by side: most of a page's time is spent
    // waiting on simulated machines and on the commands that must stay up. Within a page the
    // lines run in order. DOC_EXAMPLES_JOBS sets how many pages at once (default 3).
    let jobs: usize = std::env::var("DOC_EXAMPLES_JOBS")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&j| j > 0)
        .unwrap_or(3);
    let next = std::sync::atomic::AtomicUsize::new(0);
    let outcomes = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..jobs.min(by_page.len()) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                let Some((_, list)) = by_page.get(i) else {
                    break;
                };
                let page = run_page(list);
                outcomes
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push(page);
            });
        }
    });
    let outcomes = outcomes.into_inner().unwrap_or_else(|e| e.into_inner());
    let ran: usize = outcomes.iter().map(|(ran, _)| ran).sum();
    let mut failures: Vec<(usize, String)> = outcomes.into_iter().flat_map(|(_, f)| f).collect();
    failures.sort();
    eprintln!("{ran} example commands run");
    assert!(
        failures.is_empty(),
        "{} of {ran} example commands failed:\n\n{}",
        failures.len(),
        failures
            .into_iter()
            .map(|(_, f)| f)
            .collect::<Vec<_>>()
            .join("\n\n")
    );
}

/// Runs one page's commands in order in a fresh cell: how many ran, and each failure with
/// its place in the pages (so the report keeps the pages' order).
fn run_page(list: &[(usize, Example)]) -> (usize, Vec<(usize, String)>) {
    let mut cell = Cell::new();
    let mut failures = Vec::new();
    let mut ran = 0;
    for (n, ex) in list {
        let filled = cell.fill(&ex.command);
        let runs = if runs_until_stopped(&filled) {
            Runs::UntilStopped {
                ready: ready_mark(&filled),
            }
        } else {
            Runs::ToTheEnd
        };
        let mut cmd = cell.command(&filled);
        if asks(&filled) {
            // at a terminal, where the operator answers the question with y
            cmd = cell.command(&format!(
                "printf 'y\\n' | script -qec {} /dev/null",
                shell_quote(&filled)
            ));
        }
        if filled.starts_with("machlink serve") {
            let folder = cell.serve_folder(*n);
            cmd.current_dir(&folder)
                .env("MACHLINK_CONFIG", folder.join("cell.toml"));
        }
        if filled.contains("--connect") {
            cmd.env("MACHLINK_TOKEN", &cell.token);
        }
        eprintln!("run {}:{}: {filled}", ex.file, ex.line);
        ran += 1;
        if let Err(why) = run(cmd, runs) {
            failures.push((
                *n,
                format!(
                    "{}:{}: `{}`\n  ran `{filled}`\n  {why}",
                    ex.file, ex.line, ex.command
                ),
            ));
        }
    }
    (ran, failures)
}

#[test]
fn the_geometry_json_page_shows_the_example_file_it_plans() {
    let root = repo_root();
    let page = std::fs::read_to_string(root.join("docs/geometry.md")).unwrap();
    let block = page
        .split("```json\n")
        .nth(1)
        .and_then(|rest| rest.split("```").next())
        .expect("docs/geometry.md has a ```json block");
    let shown: serde_json::Value = serde_json::from_str(block).expect("the page's JSON parses");
    let file: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("docs/examples/bracket.json")).unwrap())
            .unwrap();
    assert_eq!(
        shown, file,
        "docs/geometry.md shows another shape than docs/examples/bracket.json"
    );
    let ex = examples_of("docs/geometry.md", &page);
    assert!(
        ex.iter().any(|e| e
            .command
            .starts_with("machlink plan docs/examples/bracket.json")),
        "docs/geometry.md plans its example (run by every_example_command_…)"
    );
}
