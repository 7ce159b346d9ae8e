//! The subcommands, one module each, and the job options they share (`job`).

pub mod access;
pub mod at_machine;
pub mod check_config;
pub mod completions;
pub mod connect;
pub mod dashboard;
pub mod demo;
pub mod events;
pub mod fleet;
pub mod job;
pub mod offset;
pub mod operate;
pub mod plan;
pub mod preview;
pub mod serve;
pub mod simulate;
pub mod submit;

/// When `main` began, before the command line was parsed (`machlink plan --timings` counts
/// its start-up from here).
pub static STARTED: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();

/// Writes `text` to stdout; a reader that went away (`machlink jobs --json | head`) is no
/// error: see `main`, which ends such a command quietly with status 0.
pub fn out(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut o = std::io::stdout().lock();
    o.write_all(text.as_bytes())?;
    o.flush()?;
    Ok(())
}

/// The single-threaded async runtime a client command runs on.
pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    use anyhow::Context;
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}
