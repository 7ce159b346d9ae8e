//! `--fleet nats://…` on `submit` and `jobs`: the fleet of daemons from any host.

use super::runtime;
use machlink::core::intake::JobSpec;
use machlink::services::fleet::client::FleetClient;
use std::path::PathBuf;

/// How to reach the fleet.
#[derive(clap::Args, Clone, Debug)]
pub struct FleetArgs {
    /// Go through the fleet's NATS server (nats://host:4222) instead of one daemon.
    #[arg(long, value_name = "URL")]
    pub fleet: Option<String>,
    /// A NATS credentials file for --fleet.
    #[arg(long, value_name = "FILE", requires = "fleet")]
    pub fleet_credentials: Option<PathBuf>,
}

pub fn submit(a: &FleetArgs, url: &str, spec: &JobSpec) -> anyhow::Result<()> {
    runtime()?.block_on(async {
        let c = FleetClient::connect(url, a.fleet_credentials.as_deref()).await?;
        let job = c.submit(spec).await?;
        eprintln!("fleet job {} queued for {}", job.id, job.machine);
        println!("{}", job.id);
        Ok(())
    })
}

pub fn jobs(a: &FleetArgs, url: &str, json: bool) -> anyhow::Result<()> {
    let jobs = runtime()?.block_on(async {
        let c = FleetClient::connect(url, a.fleet_credentials.as_deref()).await?;
        anyhow::Ok(c.jobs().await?)
    })?;
    if json {
        println!("{}", serde_json::to_string_pretty(&jobs)?);
        return Ok(());
    }
    println!(
        "{:<27} {:<12} {:<10} {:>5}  {:<11} {:>13}  ERROR",
        "FLEET JOB", "MACHINE", "DAEMON", "JOB", "STATE", "LINES"
    );
    for j in jobs {
        println!(
            "{:<27} {:<12} {:<10} {:>5}  {:<11} {:>13}  {}",
            j.id,
            j.machine,
            j.daemon.unwrap_or_else(|| "-".into()),
            j.local_id
                .map(|i| i.to_string())
                .unwrap_or_else(|| "-".into()),
            j.state,
            format!("{}/{}", j.acked, j.total),
            j.error.unwrap_or_default()
        );
    }
    Ok(())
}
