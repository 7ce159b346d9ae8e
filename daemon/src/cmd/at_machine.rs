//! The operator at the machine: `unlock`, `home`, `jog` between jobs, and `override` of a
//! running job. Each is refused in a sentence when the machine's kind cannot do it.

use super::operate::ClientArgs;
use super::runtime;
use machlink::core::scheduler::OverridePatch;
use machlink::core::store::JobId;
use machlink_protocols::Operation;

#[derive(clap::Args)]
pub struct MachineArgs {
    /// The machine (as `machlink machines` names it).
    pub machine: String,
    #[command(flatten)]
    pub client: ClientArgs,
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
pub struct JogArgs {
    /// The machine (as `machlink machines` names it).
    pub machine: String,
    /// Move X by this much, mm (negative: towards X minus).
    #[arg(long)]
    pub x: Option<f64>,
    /// Move Y by this much, mm.
    #[arg(long)]
    pub y: Option<f64>,
    /// Move Z by this much, mm.
    #[arg(long)]
    pub z: Option<f64>,
    /// The jog's feed, mm/min.
    #[arg(long)]
    pub feed: f64,
    #[command(flatten)]
    pub client: ClientArgs,
}

#[derive(clap::Args)]
pub struct OverrideArgs {
    /// The job's number.
    pub job: JobId,
    /// Feed override, 50% to 200% of the programmed feed.
    #[arg(long, value_parser = percent)]
    pub feed: Option<u16>,
    /// Spindle override, 50% to 200% of the programmed speed.
    #[arg(long, value_parser = percent)]
    pub spindle: Option<u16>,
    /// Rapid override: 25%, 50% or 100%.
    #[arg(long, value_parser = percent)]
    pub rapid: Option<u16>,
    #[command(flatten)]
    pub client: ClientArgs,
}

/// "150%" or "150".
fn percent(s: &str) -> Result<u16, String> {
    s.trim()
        .trim_end_matches('%')
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a percentage such as 120%"))
}

fn operate(machine: &str, client: &ClientArgs, op: Operation) -> anyhow::Result<()> {
    let a = runtime()?.block_on(client.client().operate(machine, &op))?;
    eprintln!("machine {}: {}", a.machine, a.said);
    Ok(())
}

pub fn unlock(a: MachineArgs) -> anyhow::Result<()> {
    operate(&a.machine, &a.client, Operation::Unlock)
}

pub fn home(a: MachineArgs) -> anyhow::Result<()> {
    operate(&a.machine, &a.client, Operation::Home)
}

pub fn jog(a: JogArgs) -> anyhow::Result<()> {
    operate(
        &a.machine,
        &a.client,
        Operation::Jog {
            x: a.x,
            y: a.y,
            z: a.z,
            feed: a.feed,
        },
    )
}

pub fn override_job(a: OverrideArgs) -> anyhow::Result<()> {
    if a.feed.is_none() && a.spindle.is_none() && a.rapid.is_none() {
        anyhow::bail!("say which override to change: --feed, --spindle or --rapid");
    }
    let patch = OverridePatch {
        feed: a.feed,
        spindle: a.spindle,
        rapid: a.rapid,
    };
    let r = runtime()?.block_on(a.client.client().override_job(a.job, &patch))?;
    eprintln!(
        "job {} ({}): feed {} %, spindle {} %, rapids {} %",
        r.job.id, r.job.state, r.overrides.feed, r.overrides.spindle, r.overrides.rapid
    );
    Ok(())
}
