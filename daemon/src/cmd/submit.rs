//! `machlink submit`: send a shape file and its plan parameters to the daemon, which plans
//! the job and queues it on the machine.

use super::operate::{watch_job, ClientArgs};
use crate::planning::PlanParams;
use anyhow::Context;
use base64::Engine;
use machlink::api::SubmitRequest;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct SubmitArgs {
    /// The shape file (.json geometry, or any format the planner reads), or a G-code file
    /// (.nc, .gcode, .ngc, .tap) to stream as it is (the plan options are then ignored).
    pub file: PathBuf,
    /// The machine to queue the job on (see `machlink machines`).
    #[arg(long)]
    pub machine: String,
    #[command(flatten)]
    pub params: PlanParams,
    /// Follow the job with a progress bar until it ends.
    #[arg(long)]
    pub watch: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

pub fn run(a: SubmitArgs) -> anyhow::Result<()> {
    let bytes =
        std::fs::read(&a.file).with_context(|| format!("cannot read {}", a.file.display()))?;
    let file_name = a
        .file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| a.file.display().to_string());
    let (file_text, file_base64) = match String::from_utf8(bytes) {
        Ok(t) => (Some(t), None),
        Err(e) => (
            None,
            Some(base64::engine::general_purpose::STANDARD.encode(e.into_bytes())),
        ),
    };
    let req = SubmitRequest {
        machine: a.machine,
        file_name,
        file_text,
        file_base64,
        params: Some(a.params),
    };
    let client = a.client.client();
    super::operate::runtime()?.block_on(async {
        let job = client.submit(&req).await?;
        eprintln!(
            "job {} queued on {} ({} lines)",
            job.id, job.machine, job.total_units
        );
        println!("{}", job.id);
        if a.watch {
            watch_job(&client, job.id, false).await?;
        }
        Ok(())
    })
}
