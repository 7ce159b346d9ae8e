//! The operator's commands against a running daemon: jobs, machines, watch, pause, resume, cancel.

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use machlink::client::Client;
use machlink::scheduler::Event;
use machlink::store::{JobId, JobRecord, JobState};
use std::time::Duration;

pub use super::connect::ClientArgs;

#[derive(clap::Args)]
pub struct JobsArgs {
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

#[derive(clap::Args)]
pub struct MachinesArgs {
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

#[derive(clap::Args)]
pub struct JobArgs {
    /// The job's number (as `machlink submit` and `machlink jobs` show it).
    pub job: JobId,
    /// Print the job as JSON when done.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

#[derive(clap::Args)]
pub struct ResumeArgs {
    /// The job's number.
    pub job: JobId,
    /// Restart a stopped job from this program line (1-based) instead of the first line
    /// the machine had not acknowledged.
    #[arg(long, value_name = "LINE")]
    pub from_line: Option<usize>,
    /// Print the job as JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

fn progress(j: &JobRecord) -> String {
    format!("{}/{}", j.acked_units, j.total_units)
}

pub fn jobs(a: JobsArgs) -> anyhow::Result<()> {
    let jobs = runtime()?.block_on(a.client.client().jobs())?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&jobs)?);
        return Ok(());
    }
    println!(
        "{:>5}  {:<12} {:<11} {:>13}  {:<8} {:<20} ERROR",
        "JOB", "MACHINE", "STATE", "LINES", "OP", "FILE"
    );
    for j in jobs {
        println!(
            "{:>5}  {:<12} {:<11} {:>13}  {:<8} {:<20} {}",
            j.id,
            j.machine,
            j.state.as_str(),
            progress(&j),
            j.op,
            j.file_name,
            j.error.unwrap_or_default()
        );
    }
    Ok(())
}

pub fn machines(a: MachinesArgs) -> anyhow::Result<()> {
    let ms = runtime()?.block_on(a.client.client().machines())?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&ms)?);
        return Ok(());
    }
    println!(
        "{:<12} {:<11} {:>5} {:>6}  {:<10} POSITION",
        "MACHINE", "LINK", "JOB", "QUEUED", "STATUS"
    );
    for m in ms {
        let p = m.status.position;
        println!(
            "{:<12} {:<11} {:>5} {:>6}  {:<10} X{:.3} Y{:.3} Z{:.3}",
            m.name,
            m.link,
            m.job.map(|j| j.to_string()).unwrap_or_else(|| "-".into()),
            m.queued,
            m.status.state.to_string(),
            p[0],
            p[1],
            p[2]
        )
    }
    Ok(())
}

pub fn watch(a: JobArgs) -> anyhow::Result<()> {
    let client = a.client.client();
    let j = runtime()?.block_on(watch_job(&client, a.job, false))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    }
    Ok(())
}

/// Follows a job with a progress bar (lines acknowledged / total, machine state, feed,
/// ETA) until it ends; an error unless it completed.
pub async fn watch_job(client: &Client, id: JobId, quiet: bool) -> anyhow::Result<JobRecord> {
    let first = client.job(id).await?;
    let mut events = client.events(id).await?;
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(first.total_units as u64)
    };
    // fits 80 columns: "job 12 [====>     ] 1234/2000 lines  Run F800 X118.5 Y31.3 Z-1.0  ETA 1m"
    bar.set_style(
        ProgressStyle::with_template(
            "job {prefix} [{bar:20.cyan/blue}] {pos}/{len} lines  {msg}  ETA {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_prefix(id.to_string());
    bar.set_position(first.acked_units as u64);
    bar.set_message(first.state.to_string());
    bar.enable_steady_tick(Duration::from_millis(200));
    let mut state = first.state;
    let mut status = String::new();
    let show = |state: JobState, status: &str| match (state, status.is_empty()) {
        (JobState::Running, false) => status.to_string(),
        (_, true) => state.to_string(),
        (_, false) => format!("{state} {status}"),
    };
    while let Some(ev) = events.next().await? {
        match ev {
            Event::State {
                state: s,
                acked,
                total,
                ..
            } => {
                bar.set_length(total as u64);
                bar.set_position(acked as u64);
                state = s;
                bar.set_message(show(state, &status));
            }
            Event::Progress { acked, total, .. } => {
                bar.set_length(total as u64);
                bar.set_position(acked as u64);
            }
            Event::Status { status: st, .. } => {
                let p = st.position;
                status = format!(
                    "{} F{:.0} X{:.1} Y{:.1} Z{:.1}",
                    st.state, st.feed, p[0], p[1], p[2]
                );
                bar.set_message(show(state, &status));
            }
            Event::Message { text, .. } => bar.println(format!("machine: {text}")),
        }
    }
    bar.finish_and_clear();
    let j = client.job(id).await?;
    match j.state {
        JobState::Completed => {
            if !quiet {
                eprintln!("job {id} completed: {} lines", j.total_units);
            }
            Ok(j)
        }
        s if s.is_final() => anyhow::bail!(
            "job {id} {s} after {} of {} lines{}",
            j.acked_units,
            j.total_units,
            j.error.map(|e| format!(": {e}")).unwrap_or_default()
        ),
        s => anyhow::bail!("the daemon stopped sending events while job {id} was {s}"),
    }
}

fn act(a: JobArgs, action: &str) -> anyhow::Result<()> {
    let j = runtime()?.block_on(a.client.client().act(a.job, action))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        eprintln!(
            "job {} is {} ({} lines acknowledged)",
            j.id,
            j.state,
            progress(&j)
        );
    }
    Ok(())
}

pub fn pause(a: JobArgs) -> anyhow::Result<()> {
    act(a, "pause")
}
pub fn resume(a: ResumeArgs) -> anyhow::Result<()> {
    match a.from_line {
        None => act(
            JobArgs {
                job: a.job,
                json: a.json,
                client: a.client,
            },
            "resume",
        ),
        Some(line) => {
            let j = runtime()?.block_on(a.client.client().resume_from_line(a.job, line))?;
            if a.json {
                println!("{}", serde_json::to_string_pretty(&j)?);
            } else {
                eprintln!("job {} is {} from line {line}", j.id, j.state);
            }
            Ok(())
        }
    }
}
pub fn cancel(a: JobArgs) -> anyhow::Result<()> {
    act(a, "cancel")
}
