//! Planning a job where it cannot take the daemon down. Each job is planned in a child
//! process forked for it, on a dedicated thread with a large, bounded stack, inside
//! `catch_unwind`: a panic, a stack overflow (which aborts a Rust process and can't be caught
//! in one), or any fatal signal ends that child only, and the job is refused with a sentence
//! saying so. A plan that runs past [`PLAN_TIME_LIMIT`] is killed the same way.
//!
//! The child returns the program through a pipe; the parent reads it back as the machine's
//! kind reads a stored program. The child takes no lock a thread of the parent could have
//! held at the fork (it allocates, which glibc keeps safe across fork, and computes); its
//! panics go through a hook installed once in the parent that stays silent in a child.

use crate::core::intake::{IntakeError, JobSpec, Planned, Target};
use crate::core::machine::MachineConfig;
use machlink_protocols::Program;
use std::io::{Read, Write};
use std::os::fd::OwnedFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// The planning thread's stack: deep enough for any sane recursion, and a bound.
pub const PLAN_STACK: usize = 256 << 20;
/// The longest a job's planning may take.
pub const PLAN_TIME_LIMIT: Duration = Duration::from_secs(300);

/// The function that plans a job for a machine: [`crate::core::intake::plan`], or a test's own.
pub type PlanFn = fn(&JobSpec, Target<'_>) -> Result<Planned, IntakeError>;

/// What the daemon keeps of a plan.
#[derive(Clone, Debug)]
pub struct PlanOutcome {
    pub program: Program,
    pub operation: String,
    pub warnings: Vec<String>,
}

/// Why planning gave no program.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// The intake refused the job (its own sentence).
    #[error(transparent)]
    Intake(#[from] IntakeError),
    /// The planner crashed: a panic, a stack overflow, a fatal signal.
    #[error("planning the job crashed ({0}); the daemon is unaffected")]
    Crashed(String),
    #[error("planning the job took longer than {0:?} and was stopped")]
    TimedOut(Duration),
    /// The child could not be started or its answer read.
    #[error("cannot plan the job: {0}")]
    Broken(String),
}

/// Set in a planning child right after the fork: its panics are reported through the pipe,
/// and the panic hook must take no lock another thread of the parent may have held.
static IN_PLANNER_CHILD: AtomicBool = AtomicBool::new(false);

/// Installs, once and in the parent, a panic hook that stays silent in a planning child and
/// hands every other panic to the hook that was there. (Setting a hook in the child could
/// wait forever on the hook's lock, held by a thread that panicked in the parent at the
/// moment of the fork.)
fn quiet_panics_in_children() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !IN_PLANNER_CHILD.load(Ordering::Relaxed) {
                previous(info);
            }
        }));
    });
}

/// Plans `spec` for `machine` with `plan` in a forked child; waits at most `limit`.
pub async fn plan_isolated(
    spec: JobSpec,
    machine: MachineConfig,
    plan: PlanFn,
    limit: Duration,
) -> Result<PlanOutcome, PlanError> {
    quiet_panics_in_children();
    let (pid_tx, pid_rx) = std::sync::mpsc::channel::<i32>();
    let (done_tx, done_rx) = tokio::sync::oneshot::channel();
    let machine2 = machine.clone();
    std::thread::Builder::new()
        .name("machlink-plan".into())
        .stack_size(PLAN_STACK)
        .spawn(move || {
            let r = fork_and_plan(&spec, &machine2, plan, &pid_tx);
            let _ = done_tx.send(r);
        })
        .map_err(|e| PlanError::Broken(format!("cannot start the planning thread: {e}")))?;
    let raw = match tokio::time::timeout(limit, done_rx).await {
        Ok(Ok(r)) => r?,
        Ok(Err(_)) => return Err(PlanError::Broken("the planning thread vanished".into())),
        Err(_) => {
            if let Ok(pid) = pid_rx.try_recv() {
                let _ = nix::sys::signal::kill(
                    nix::unistd::Pid::from_raw(pid),
                    nix::sys::signal::Signal::SIGKILL,
                );
            }
            return Err(PlanError::TimedOut(limit));
        }
    };
    decode(&raw, &machine)
}

/// Runs on the planning thread: forks, lets the child plan, reads its answer, reaps it.
fn fork_and_plan(
    spec: &JobSpec,
    machine: &MachineConfig,
    plan: PlanFn,
    pid_tx: &std::sync::mpsc::Sender<i32>,
) -> Result<Vec<u8>, PlanError> {
    let broken = |what: &str, e: nix::Error| PlanError::Broken(format!("{what}: {e}"));
    let (read_end, write_end): (OwnedFd, OwnedFd) =
        nix::unistd::pipe2(nix::fcntl::OFlag::O_CLOEXEC).map_err(|e| broken("pipe", e))?;
    // SAFETY: the child runs only the planner (pure computation and memory allocation,
    // which glibc keeps usable across fork) and writes to its pipe with write(2); it never
    // returns into the parent's code and leaves with _exit.
    match unsafe { nix::unistd::fork() }.map_err(|e| broken("fork", e))? {
        nix::unistd::ForkResult::Child => {
            drop(read_end);
            child(spec, machine, plan, write_end)
        }
        nix::unistd::ForkResult::Parent { child } => {
            drop(write_end);
            let _ = pid_tx.send(child.as_raw());
            let mut out = Vec::new();
            let read = std::fs::File::from(read_end).read_to_end(&mut out);
            let status = nix::sys::wait::waitpid(child, None).map_err(|e| broken("wait", e))?;
            use nix::sys::wait::WaitStatus;
            match status {
                WaitStatus::Exited(_, 0) if read.is_ok() && !out.is_empty() => Ok(out),
                WaitStatus::Signaled(_, sig, _) => Err(PlanError::Crashed(match sig {
                    nix::sys::signal::Signal::SIGSEGV
                    | nix::sys::signal::Signal::SIGABRT
                    | nix::sys::signal::Signal::SIGBUS => {
                        format!("stack overflow or fatal error: the planner died of {sig}")
                    }
                    nix::sys::signal::Signal::SIGKILL => {
                        "the planner was killed (out of memory, or too slow)".to_string()
                    }
                    sig => format!("the planner died of {sig}"),
                })),
                WaitStatus::Exited(_, code) => Err(PlanError::Crashed(format!(
                    "the planner exited with status {code}"
                ))),
                other => Err(PlanError::Crashed(format!("the planner ended: {other:?}"))),
            }
        }
    }
}

/// The child's whole life: plan, write the answer, `_exit`.
fn child(spec: &JobSpec, machine: &MachineConfig, plan: PlanFn, out: OwnedFd) -> ! {
    // a panic is reported through the pipe, not on the daemon's stderr
    IN_PLANNER_CHILD.store(true, Ordering::Relaxed);
    // the child ends after planning: glibc may keep what the geometry frees (offset_core::heap)
    offset_core::heap::hold_freed_memory();
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        plan(spec, Target::Machine(machine))
    }));
    let answer = match result {
        Ok(Ok(p)) => encode_ok(&p),
        Ok(Err(e)) => encode_err(&e),
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "no message".into());
            frame(b'!', &[what.as_bytes()])
        }
    };
    let mut f = std::fs::File::from(out);
    let code = if f.write_all(&answer).is_ok() { 0 } else { 3 };
    // SAFETY: _exit ends the child without running the parent's exit handlers or destructors
    unsafe { libc::_exit(code) }
}

/// A tag byte, then each part as a little-endian u64 length and its bytes.
fn frame(tag: u8, parts: &[&[u8]]) -> Vec<u8> {
    let mut v = vec![tag];
    for p in parts {
        v.extend_from_slice(&(p.len() as u64).to_le_bytes());
        v.extend_from_slice(p);
    }
    v
}

fn encode_ok(p: &Planned) -> Vec<u8> {
    match p.program.to_json() {
        Ok(units) => {
            let warnings = serde_json::to_vec(&p.warnings).unwrap_or_else(|_| b"[]".to_vec());
            frame(
                b'O',
                &[
                    p.program.post().as_bytes(),
                    p.operation.as_bytes(),
                    &warnings,
                    units.as_bytes(),
                ],
            )
        }
        Err(e) => frame(
            b'!',
            &[format!("cannot encode the program: {e}").as_bytes()],
        ),
    }
}

fn encode_err(e: &IntakeError) -> Vec<u8> {
    let (tag, m) = match e {
        IntakeError::Input(m) => (b'I', m),
        IntakeError::Plan(m) => (b'P', m),
        IntakeError::Refused(m) => (b'R', m),
    };
    frame(tag, &[m.as_bytes()])
}

fn parts(mut b: &[u8]) -> Option<Vec<&[u8]>> {
    let mut out = Vec::new();
    while !b.is_empty() {
        let len = u64::from_le_bytes(b.get(..8)?.try_into().ok()?) as usize;
        let p = b.get(8..8usize.checked_add(len)?)?;
        out.push(p);
        b = &b[8 + len..];
    }
    Some(out)
}

fn decode(raw: &[u8], machine: &MachineConfig) -> Result<PlanOutcome, PlanError> {
    let bad = || PlanError::Broken("the planner's answer is garbled".into());
    let (&tag, rest) = raw.split_first().ok_or_else(bad)?;
    let p = parts(rest).ok_or_else(bad)?;
    let text = |i: usize| -> Result<String, PlanError> {
        Ok(String::from_utf8_lossy(p.get(i).ok_or_else(bad)?).into_owned())
    };
    match tag {
        b'O' => {
            let post = text(0)?;
            let operation = text(1)?;
            let warnings: Vec<String> =
                serde_json::from_slice(p.get(2).ok_or_else(bad)?).map_err(|_| bad())?;
            let units = std::str::from_utf8(p.get(3).ok_or_else(bad)?).map_err(|_| bad())?;
            let program = machine
                .kind
                .decode(&post, units)
                .map_err(|e| PlanError::Broken(format!("the planned program: {e}")))?;
            Ok(PlanOutcome {
                program,
                operation,
                warnings,
            })
        }
        b'I' => Err(IntakeError::Input(text(0)?).into()),
        b'P' => Err(IntakeError::Plan(text(0)?).into()),
        b'R' => Err(IntakeError::Refused(text(0)?).into()),
        b'!' => Err(PlanError::Crashed(format!("it panicked: {}", text(0)?))),
        _ => Err(bad()),
    }
}
