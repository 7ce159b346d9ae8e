//! Running the `machlink` binary as an operator does, from a clean environment.

use machlink::core::store::JobRecord;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// `machlink` with quiet logs and none of the caller's `MACHLINK_*` settings (socket,
/// config, token), so a developer's shell cannot change what a test sees.
pub fn machlink() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_machlink"));
    c.env("RUST_LOG", "warn")
        .env_remove("MACHLINK_SOCKET")
        .env_remove("MACHLINK_CONFIG")
        .env_remove("MACHLINK_TOKEN");
    c
}

/// Runs `machlink ARGS` to the end.
pub fn run<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    machlink().args(args).output().expect("machlink runs")
}

/// Runs `machlink ARGS --socket SOCKET` to the end with stdin from /dev/null, as a script
/// (no terminal) runs it against a daemon.
pub fn at_socket(socket: &Path, args: &[&str]) -> Output {
    machlink()
        .args(args)
        .arg("--socket")
        .arg(socket)
        .stdin(Stdio::null())
        .output()
        .expect("machlink runs")
}

/// Job `id` as `machlink jobs --json` shows it.
pub fn job_record(socket: &Path, id: i64) -> JobRecord {
    let o = at_socket(socket, &["jobs", "--json"]);
    ok(&o, "machlink jobs --json");
    let jobs: Vec<JobRecord> = serde_json::from_slice(&o.stdout).expect("jobs as JSON");
    jobs.into_iter()
        .find(|j| j.id == id)
        .unwrap_or_else(|| panic!("job {id} is not in `machlink jobs`"))
}

/// Polls `machlink jobs --json` (bounded, 120 s) until job `id` satisfies `f`, naming `what`
/// it waited for when it never does; the job then.
pub fn wait_job_record(
    socket: &Path,
    id: i64,
    what: &str,
    f: impl Fn(&JobRecord) -> bool,
) -> JobRecord {
    let until = Instant::now() + Duration::from_secs(120);
    loop {
        let j = job_record(socket, id);
        if f(&j) {
            return j;
        }
        assert!(Instant::now() < until, "job {id} never {what}: {j:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// What the run printed on stdout, as text.
pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// What the run printed on stderr, as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Asserts the run succeeded, naming `what` and showing its stderr when it did not.
pub fn ok(o: &Output, what: &str) {
    assert!(o.status.success(), "{what} failed: {}", stderr(o));
}

/// A `machlink serve` child, killed when dropped.
pub struct Serve {
    pub child: std::process::Child,
    pub socket: std::path::PathBuf,
}

impl Serve {
    /// Spawns `cmd` (a `machlink serve …`) and waits up to `within` for it to make `socket`.
    pub fn spawn(mut cmd: Command, socket: &std::path::Path, within: std::time::Duration) -> Serve {
        let s = Serve {
            child: cmd.spawn().expect("machlink serve starts"),
            socket: socket.to_path_buf(),
        };
        let until = std::time::Instant::now() + within;
        while !s.socket.exists() {
            assert!(
                std::time::Instant::now() < until,
                "the daemon never opened its socket {}",
                s.socket.display()
            );
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        s
    }
}

impl Drop for Serve {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
