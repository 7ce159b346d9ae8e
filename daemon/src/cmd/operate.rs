//! The operator's commands against a running daemon: jobs, machines, watch, pause, resume, cancel.

use super::runtime;
use indicatif::{ProgressBar, ProgressStyle};
use machlink::core::scheduler::Event;
use machlink::core::store::{JobId, JobRecord, JobState};
use machlink::faces::client::Client;
use std::io::{IsTerminal, Write};
use std::time::Duration;

pub use super::connect::ClientArgs;

#[derive(clap::Args)]
pub struct JobsArgs {
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
    #[command(flatten)]
    pub fleet: super::fleet::FleetArgs,
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
pub struct WatchArgs {
    /// The job's number (as `machlink submit` and `machlink jobs` show it).
    pub job: JobId,
    /// Print every event as one JSON object per line (and nothing else).
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
    /// the machine had not run.
    #[arg(long, value_name = "LINE")]
    pub from_line: Option<usize>,
    /// Do not ask: go on without confirmation (for scripts). Without it, a resume that
    /// moves the machine shows what it will do and asks first.
    #[arg(long, short = 'y')]
    pub yes: bool,
    /// Print the job as JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

fn progress(j: &JobRecord) -> String {
    format!("{}/{}", j.acked_units, j.total_units)
}

/// A duration in the operator's words: 42s, 3m05s, 2h14m.
pub fn span(ms: i64) -> String {
    let s = (ms.max(0) + 500) / 1000;
    match s {
        s if s < 60 => format!("{s}s"),
        s if s < 3600 => format!("{}m{:02}s", s / 60, s % 60),
        s => format!("{}h{:02}m", s / 3600, (s % 3600) / 60),
    }
}

pub fn jobs(a: JobsArgs) -> anyhow::Result<()> {
    if let Some(url) = &a.fleet.fleet {
        return super::fleet::jobs(&a.fleet, url, a.json);
    }
    let jobs = runtime()?.block_on(a.client.client().jobs())?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&jobs)?);
        return Ok(());
    }
    println!(
        "{:>5}  {:<12} {:<11} {:>13}  {:>7} {:>7}  {:<8} {:<20} NOTE",
        "JOB", "MACHINE", "STATE", "LINES", "ELAPSED", "ETA", "OP", "FILE"
    );
    for j in jobs {
        let note = match (&j.error, &j.note) {
            (_, Some(n)) if !j.state.is_final() || j.state == JobState::Interrupted => n.clone(),
            (Some(e), _) => e.clone(),
            (None, Some(n)) => n.clone(),
            (None, None) => String::new(),
        };
        println!(
            "{:>5}  {:<12} {:<11} {:>13}  {:>7} {:>7}  {:<8} {:<20} {}",
            j.id,
            j.machine,
            j.state.as_str(),
            progress(&j),
            j.elapsed_ms.map(span).unwrap_or_else(|| "-".into()),
            j.eta_ms.map(span).unwrap_or_else(|| "-".into()),
            j.op,
            j.file_name,
            note
        );
    }
    Ok(())
}

/// The POSITION column's width in `machines`: room for X-1234.567 Y-1234.567 Z-123.456.
const POSITION_WIDTH: usize = 32;

pub fn machines(a: MachinesArgs) -> anyhow::Result<()> {
    let ms = runtime()?.block_on(a.client.client().machines())?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&ms)?);
        return Ok(());
    }
    // the status last, whole: an alarm's or an operator's text (the tool to load) may be
    // long, and only the last column can grow without moving the others
    println!(
        "{:<12} {:<11} {:>5} {:>6}  {:>8}  {:<POSITION_WIDTH$}  STATUS",
        "MACHINE", "LINK", "JOB", "QUEUED", "REPORTED", "POSITION"
    );
    for m in ms {
        let p = m.status.position;
        let age = match m.age_ms {
            Some(ms) => format!("{} ago", span(ms as i64)),
            None => "never".into(),
        };
        let (position, status) = match m.status.state {
            machlink_protocols::DeviceState::Offline | machlink_protocols::DeviceState::Unknown
                if !m.status.detail.is_empty() =>
            {
                (
                    "-".to_string(),
                    format!("{}: {}", m.status.state, m.status.detail),
                )
            }
            machlink_protocols::DeviceState::Offline | machlink_protocols::DeviceState::Unknown => {
                ("-".to_string(), m.status.state.to_string())
            }
            _ => (
                format!("X{:.3} Y{:.3} Z{:.3}", p[0], p[1], p[2]),
                m.status.state.to_string(),
            ),
        };
        println!(
            "{:<12} {:<11} {:>5} {:>6}  {:>8}  {:<POSITION_WIDTH$}  {}",
            m.name,
            m.link,
            m.job.map(|j| j.to_string()).unwrap_or_else(|| "-".into()),
            m.queued,
            age,
            position,
            status
        )
    }
    Ok(())
}

pub fn watch(a: WatchArgs) -> anyhow::Result<()> {
    let client = a.client.client();
    let show = if a.json {
        Show::Json
    } else if std::io::stdout().is_terminal() {
        Show::Bar
    } else {
        Show::Lines
    };
    runtime()?.block_on(watch_with(&client, a.job, show))?;
    Ok(())
}

/// How `watch` shows a job's progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Show {
    /// A progress bar on the terminal (stderr).
    Bar,
    /// One line on stdout per percent of progress, state change, status change and
    /// message: for logs and scripts reading a pipe.
    Lines,
    /// Every event as one JSON object per line on stdout.
    Json,
    /// Nothing until the end.
    Quiet,
}

/// Follows a job until it ends, as `submit --watch` and `demo` do: a progress bar on a
/// terminal (units acknowledged / total, ETA, machine state, feed), one line per step and
/// state change when stdout is not a terminal (a pipe, a log), nothing when `quiet`; an
/// error unless it completed.
pub async fn watch_job(client: &Client, id: JobId, quiet: bool) -> anyhow::Result<JobRecord> {
    let show = if quiet {
        Show::Quiet
    } else if std::io::stdout().is_terminal() {
        Show::Bar
    } else {
        Show::Lines
    };
    watch_with(client, id, show).await
}

/// The ETA as the operator reads it: `1m05s`, or `-` when the job's kind cannot tell.
fn eta_text(estimate_ms: Option<i64>, acked: usize, total: usize, state: JobState) -> String {
    machlink::core::store::eta_ms(estimate_ms, acked, total, state)
        .map(span)
        .unwrap_or_else(|| "-".into())
}

/// Follows a job the way `show` says until it ends; an error unless it completed.
pub async fn watch_with(client: &Client, id: JobId, show: Show) -> anyhow::Result<JobRecord> {
    if show == Show::Bar || show == Show::Quiet {
        return watch_bar(client, id, show == Show::Quiet).await;
    }
    let first = client.job(id).await?;
    let mut events = client.events(id).await?;
    let mut out = std::io::stdout().lock();
    let mut last_pct: Option<u64> = None;
    let mut last_state = String::new();
    let mut estimate = first.estimate_ms;
    let mut job_state = first.state;
    while let Some(ev) = events.next().await? {
        if estimate.is_none() && matches!(ev, Event::State { .. }) {
            // a G-code file's machine time is estimated when it starts
            estimate = client.job(id).await.ok().and_then(|j| j.estimate_ms);
        }
        if show == Show::Json {
            writeln!(out, "{}", serde_json::to_string(&ev)?)?;
            out.flush()?;
            continue;
        }
        let line = match &ev {
            Event::State {
                state,
                acked,
                total,
                error,
                ..
            } => {
                job_state = *state;
                Some(format!(
                    "job {id} {state} at {acked}/{total}{}",
                    error.as_ref().map(|e| format!(": {e}")).unwrap_or_default()
                ))
            }
            Event::Progress {
                acked, total: t, ..
            } => {
                let pct = *acked as u64 * 100 / (*t).max(1) as u64;
                (last_pct != Some(pct)).then(|| {
                    last_pct = Some(pct);
                    format!(
                        "job {id} {acked}/{t} ({pct} %) ETA {}",
                        eta_text(estimate, *acked, *t, job_state)
                    )
                })
            }
            Event::Status { status, .. } => {
                let s = status.state.to_string();
                (s != last_state).then(|| {
                    last_state = s.clone();
                    let p = status.position;
                    format!(
                        "job {id} machine {s} F{:.0} X{:.3} Y{:.3} Z{:.3}",
                        status.feed, p[0], p[1], p[2]
                    )
                })
            }
            Event::Message { text, .. } => Some(format!("job {id} machine: {text}")),
        };
        if let Some(l) = line {
            writeln!(out, "{l}")?;
            out.flush()?;
        }
    }
    let j = client.job(id).await?;
    end_of(id, j, show == Show::Json)
}

/// The result of watching: the job when it completed, else its reason.
fn end_of(id: JobId, j: JobRecord, quiet: bool) -> anyhow::Result<JobRecord> {
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
            j.error
                .or(j.note)
                .map(|e| format!(": {e}"))
                .unwrap_or_default()
        ),
        s => anyhow::bail!("the daemon stopped sending events while job {id} was {s}"),
    }
}

async fn watch_bar(client: &Client, id: JobId, quiet: bool) -> anyhow::Result<JobRecord> {
    let first = client.job(id).await?;
    let mut events = client.events(id).await?;
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(first.total_units as u64)
    };
    // fits 80 columns: "job 12 [====>       ] 1234/2000  ETA 1m05s  Run F800 X118.5 Y31.3 Z-1.0",
    // the machine's status last and cut to the terminal's width; the ETA from the job's
    // estimated machine time (indicatif's own {eta} guesses from the rate of acks, which
    // GRBL's planner makes run ahead of the motion)
    bar.set_style(
        ProgressStyle::with_template("job {prefix} [{bar:16.cyan/blue}] {pos}/{len}  {wide_msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix(id.to_string());
    bar.set_position(first.acked_units as u64);
    bar.enable_steady_tick(Duration::from_millis(200));
    let mut state = first.state;
    let mut status = String::new();
    let mut estimate = first.estimate_ms;
    let (mut acked_now, mut total_now) = (first.acked_units, first.total_units);
    let show =
        |estimate: Option<i64>, state: JobState, status: &str, acked: usize, total: usize| {
            let eta = eta_text(estimate, acked, total, state);
            match (state, status.is_empty()) {
                (JobState::Running, false) => format!("ETA {eta}  {status}"),
                (_, true) => format!("ETA {eta}  {state}"),
                (_, false) => format!("ETA {eta}  {state} {status}"),
            }
        };
    bar.set_message(show(estimate, first.state, "", acked_now, total_now));
    while let Some(ev) = events.next().await? {
        if estimate.is_none() && matches!(ev, Event::State { .. }) {
            // a G-code file's machine time is estimated when it starts
            estimate = client.job(id).await.ok().and_then(|j| j.estimate_ms);
        }
        match ev {
            Event::State {
                state: s,
                acked,
                total,
                ..
            } => {
                bar.set_length(total as u64);
                bar.set_position(acked as u64);
                (acked_now, total_now) = (acked, total);
                state = s;
                bar.set_message(show(estimate, state, &status, acked_now, total_now));
            }
            Event::Progress { acked, total, .. } => {
                bar.set_length(total as u64);
                bar.set_position(acked as u64);
                (acked_now, total_now) = (acked, total);
                bar.set_message(show(estimate, state, &status, acked_now, total_now));
            }
            Event::Status { status: st, .. } => {
                let p = st.position;
                status = format!(
                    "{} F{:.0} X{:.1} Y{:.1} Z{:.1}",
                    st.state, st.feed, p[0], p[1], p[2]
                );
                bar.set_message(show(estimate, state, &status, acked_now, total_now));
            }
            Event::Message { text, .. } => bar.println(format!("machine: {text}")),
        }
    }
    bar.finish_and_clear();
    let j = client.job(id).await?;
    end_of(id, j, quiet)
}

fn act(a: JobArgs, action: &str) -> anyhow::Result<()> {
    let j = runtime()?.block_on(a.client.client().act(a.job, action))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        eprintln!("{}", left_in(&j));
    }
    Ok(())
}

/// The state a request left the job in, in one sentence.
fn left_in(j: &JobRecord) -> String {
    format!(
        "job {} is {} ({} lines acknowledged){}",
        j.id,
        j.state,
        progress(j),
        j.note
            .as_ref()
            .filter(|_| !matches!(j.state, JobState::Running | JobState::Completed))
            .map(|n| format!(": {n}"))
            .unwrap_or_default()
    )
}

pub fn pause(a: JobArgs) -> anyhow::Result<()> {
    act(a, "pause")
}

/// Resumes a job; a resume that moves the machine (a stopped job's repositioning) is shown
/// first and goes on only once the operator confirms (or with `--yes`).
pub fn resume(a: ResumeArgs) -> anyhow::Result<()> {
    let client = a.client.client();
    let rt = runtime()?;
    let job = rt.block_on(client.job(a.job))?;
    let needs_plan = matches!(
        job.state,
        JobState::Paused | JobState::Interrupted | JobState::Failed | JobState::Cancelled
    );
    if needs_plan {
        let p = rt.block_on(client.resume_preview(a.job, a.from_line))?;
        eprintln!(
            "job {} goes on at line {} of {}:",
            p.job, p.from_line, p.total
        );
        for (i, step) in p.steps.iter().enumerate() {
            eprintln!("  {}. {step}", i + 1);
        }
        if let Some(n) = &p.note {
            eprintln!("  (the daemon found: {n})");
        }
        // every resume makes the machine move (a cycle start, a ring fed again, a pattern
        // sewn on): without a terminal to ask at, only --yes lets it go
        if !a.yes && !std::io::stdin().is_terminal() {
            anyhow::bail!(
                "resuming job {} moves the machine: confirm it at a terminal, or give --yes; nothing was sent",
                p.job
            );
        }
        if p.moves && !a.yes {
            eprint!("Go on? [y/N] ");
            std::io::stderr().flush()?;
            let mut answer = String::new();
            std::io::stdin().read_line(&mut answer)?;
            if !matches!(answer.trim(), "y" | "Y" | "yes" | "Yes") {
                anyhow::bail!("resume of job {} not confirmed; nothing was sent", p.job);
            }
        }
    }
    let j = match a.from_line {
        None => rt.block_on(client.act(a.job, "resume"))?,
        Some(line) => rt.block_on(client.resume_from_line(a.job, line))?,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        eprintln!("{}", left_in(&j));
    }
    Ok(())
}

pub fn cancel(a: JobArgs) -> anyhow::Result<()> {
    act(a, "cancel")
}
