//! Shared helpers of the end-to-end tests: an in-process daemon on a temp dir, its client,
//! programs, and what the simulator should execute from them.
#![allow(dead_code)]

pub mod bin;
/// The daemon tests' nats-server on loopback (one helper for both crates).
#[path = "../../../../daemon/tests/it/common/nats.rs"]
pub mod nats;
pub use machlink_testkit::sewing;

use machlink::config::Config;
use machlink::core::intake::{Input, JobSpec};
use machlink::core::store::{JobId, JobRecord, JobState};
use machlink::daemon::{Daemon, StartOptions};
use machlink::faces::client::{Client, Endpoint};
use machlink_sim::grbl::interp::{clean_line, Action, Interpreter};
use std::path::Path;
use std::time::Duration;

/// A daemon whose store and socket live in `dir`, with the machine tables `machines`.
pub async fn start(dir: &Path, machines: &str, opts: StartOptions) -> Daemon {
    let cfg = Config::parse(&cell_toml(dir, machines), &dir.join("machlink.toml")).expect("config");
    Daemon::start(cfg, opts).await.expect("daemon starts")
}

/// Like `start`, with machine kinds of the test's own in `registry`.
pub async fn start_with(
    dir: &Path,
    machines: &str,
    registry: &machlink_protocols::Registry,
) -> Daemon {
    let cfg = Config::parse_with(
        &cell_toml(dir, machines),
        &dir.join("machlink.toml"),
        registry,
    )
    .expect("config");
    Daemon::start(cfg, StartOptions::default())
        .await
        .expect("daemon starts")
}

fn cell_toml(dir: &Path, machines: &str) -> String {
    format!(
        "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n{machines}",
        dir.join("jobs.db").display(),
        dir.join("ml.sock").display()
    )
}

/// The config of one GRBL machine called `mill` on `port`.
pub fn machine_on(port: &Path) -> String {
    format!(
        "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"{}\"\n",
        port.display()
    )
}

/// A simulated GRBL on a pty and a daemon (store and socket in a fresh temp dir, kept
/// alive by the returned handle) with one machine `mill` on it, and its client.
pub async fn grbl_cell(
    cfg: machlink_sim::grbl::GrblSimConfig,
) -> (
    machlink_sim::grbl::GrblSimHandle,
    tempfile::TempDir,
    Daemon,
    Client,
) {
    let sim = machlink_sim::grbl::GrblSim::spawn_pty(cfg).expect("the simulator starts");
    let dir = tempfile::tempdir().expect("a temp dir");
    let d = start(
        dir.path(),
        &machine_on(&sim.port()),
        StartOptions::default(),
    )
    .await;
    let c = client(&d);
    (sim, dir, d, c)
}

pub fn client(d: &Daemon) -> Client {
    Client::new(Endpoint::Unix(d.socket.clone()))
}

/// `n` G-code lines: a zig-zag of short feed moves with lines of varied length.
pub fn zigzag(n: usize) -> Vec<String> {
    let mut lines = vec![
        "G21 G90".to_string(),
        "G0 Z1".to_string(),
        "G1 Z-0.5 F600".to_string(),
    ];
    let mut i = 0;
    while lines.len() < n {
        let x = (i % 40) as f64 * 0.5 + if i % 3 == 0 { 0.125 } else { 0.0 };
        let y = (i / 40) as f64 * 0.5 + if i % 7 == 0 { 0.0625 } else { 0.0 };
        lines.push(if i % 5 == 0 {
            format!("G1 X{x:.4} Y{y:.4} F1500")
        } else {
            format!("X{x:.3} Y{y:.3}")
        });
        i += 1;
    }
    lines
}

/// The cleaned motion lines the simulator should record for `lines`, in order.
pub fn expected_motion(lines: &[String]) -> Vec<String> {
    let mut interp = Interpreter::new();
    let mut out = Vec::new();
    for l in lines {
        let clean = clean_line(l);
        let actions = interp.execute(&clean).expect("valid G-code");
        if actions.iter().any(|a| matches!(a, Action::Move { .. })) {
            out.push(clean);
        }
    }
    out
}

/// For each line, how many motion lines the program has up to and including it.
pub fn motions_up_to(lines: &[String]) -> Vec<usize> {
    let mut interp = Interpreter::new();
    let mut n = 0;
    lines
        .iter()
        .map(|l| {
            let actions = interp.execute(&clean_line(l)).expect("valid G-code");
            if actions.iter().any(|a| matches!(a, Action::Move { .. })) {
                n += 1;
            }
            n
        })
        .collect()
}

/// A job of `file_name` with the text `text` on `machine`, with no operation (a G-code
/// file) until one is set.
pub fn job(machine: &str, file_name: &str, text: &str) -> JobSpec {
    JobSpec {
        machine: Some(machine.into()),
        input: Input::from_bytes(file_name, text.as_bytes().to_vec()),
        operation: None,
        operations: Vec::new(),
        tolerance: None,
        layers: Vec::new(),
        post: None,
    }
}

/// Submits G-code lines as a .nc file.
pub async fn submit_gcode(c: &Client, machine: &str, name: &str, lines: &[String]) -> JobRecord {
    c.submit(&job(machine, &format!("{name}.nc"), &lines.join("\n")))
        .await
        .expect("submitted")
}

/// Follows the job's events until it ends; returns the final record.
pub async fn wait_end(c: &Client, id: JobId) -> JobRecord {
    let mut ev = c.events(id).await.expect("events");
    tokio::time::timeout(Duration::from_secs(60), async {
        while ev.next().await.expect("event").is_some() {}
    })
    .await
    .expect("the job ends within a minute");
    c.job(id).await.unwrap()
}

/// Polls until the job is in `state` (bounded).
pub async fn wait_state(c: &Client, id: JobId, state: JobState) -> JobRecord {
    for _ in 0..3000 {
        let j = c.job(id).await.unwrap();
        if j.state == state {
            return j;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("job {id} never became {state}");
}

/// Polls until `f` holds of the job (bounded).
pub async fn wait_until(c: &Client, id: JobId, f: impl Fn(&JobRecord) -> bool) -> JobRecord {
    for _ in 0..3000 {
        let j = c.job(id).await.unwrap();
        if f(&j) {
            return j;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("job {id} never got there");
}

/// The program the store holds for a job, read back as units of type `U` (G-code lines,
/// motion blocks, stitch records) by its machine's kind.
pub fn stored<U: machlink_protocols::Unit>(d: &Daemon, id: JobId) -> Vec<U> {
    let job = d.scheduler.job(id).expect("the job");
    let kind = d
        .scheduler
        .machine_config(&job.machine)
        .expect("its machine")
        .kind
        .clone();
    let program = d
        .scheduler
        .store()
        .program(id)
        .expect("a stored program")
        .decode(kind.as_ref())
        .expect("its kind reads it");
    program
        .view::<U>()
        .expect("units of this type")
        .to_vec()
        .expect("its units read back")
}

/// The G-code line numbers (as the simulator counts them) of the lines a resume sent to
/// bring the tool back (they carry the comment `(resume)`).
pub fn resume_lines(sim: &machlink_sim::grbl::GrblSimHandle) -> Vec<u64> {
    sim.events()
        .into_iter()
        .filter_map(|e| match e {
            machlink_sim::grbl::TraceEvent::Received { n: Some(n), line }
                if line.contains("(resume)") =>
            {
                Some(n)
            }
            _ => None,
        })
        .collect()
}

/// The program's moves the simulator executed: its trace without the moves of resumes.
pub fn program_motion(
    sim: &machlink_sim::grbl::GrblSimHandle,
) -> Vec<machlink_sim::grbl::Executed> {
    let resume = resume_lines(sim);
    sim.trace()
        .into_iter()
        .filter(|e| !resume.contains(&e.index))
        .collect()
}
