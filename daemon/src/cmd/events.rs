//! `machlink events`: follows every job's state changes (the daemon's `GET /events`) until
//! interrupted, for scripts and dashboards.

use super::operate::ClientArgs;
use super::runtime;
use machlink::core::scheduler::Event;
use std::io::Write;

#[derive(clap::Args)]
pub struct EventsArgs {
    /// Only this machine's events.
    #[arg(long)]
    pub machine: Option<String>,
    /// Print every event (progress and status reports too) as one JSON object per line,
    /// as the API serves them.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

/// One line for people: state changes and the machines' messages.
pub fn human(ev: &Event) -> Option<String> {
    match ev {
        Event::State {
            job,
            machine,
            state,
            acked,
            total,
            error,
        } => Some(format!(
            "job {job} on {machine}: {state} ({acked}/{total}){}",
            error.as_ref().map(|e| format!(": {e}")).unwrap_or_default()
        )),
        Event::Message { machine, job, text } => Some(format!(
            "{machine}{}: {text}",
            job.map(|j| format!(" (job {j})")).unwrap_or_default()
        )),
        Event::Progress { .. } | Event::Status { .. } => None,
    }
}

pub fn run(a: EventsArgs) -> anyhow::Result<()> {
    runtime()?.block_on(async {
        let mut events = a.client.client().follow(a.machine.as_deref()).await?;
        let mut out = std::io::stdout().lock();
        while let Some(ev) = events.next().await? {
            let line = if a.json {
                Some(serde_json::to_string(&ev)?)
            } else {
                human(&ev)
            };
            if let Some(l) = line {
                // a closed pipe (`machlink events | head`) ends the command quietly
                if writeln!(out, "{l}").and_then(|_| out.flush()).is_err() {
                    return Ok(());
                }
            }
        }
        anyhow::bail!("the daemon closed the event stream (it stopped)")
    })
}
