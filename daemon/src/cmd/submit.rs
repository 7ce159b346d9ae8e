//! `machlink submit`: send a job (its file and options) to the daemon, which plans it
//! through the same intake as `plan`, checks it against the machine and queues it.

use super::job::JobArgs;
use super::operate::{watch_job, ClientArgs};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct SubmitArgs {
    /// The shape file (.json geometry JSON, .dxf, .svg) or the mesh (.stl) or point grid
    /// (.csv) planned with --op or --recipe; or a G-code file (.nc, .gcode, .ngc, .tap, .gc,
    /// .cnc) that runs as it is once checked against the machine.
    pub file: PathBuf,
    /// The machine to queue the job on (see `machlink machines`).
    #[arg(long)]
    pub machine: String,
    #[command(flatten)]
    pub job: JobArgs,
    /// The post to write the program with (default: the machine's first; a sewing machine
    /// takes dst or jef).
    #[arg(long)]
    pub post: Option<String>,
    /// Follow the job with a progress bar until it ends.
    #[arg(long)]
    pub watch: bool,
    #[command(flatten)]
    pub client: ClientArgs,
    #[command(flatten)]
    pub fleet: super::fleet::FleetArgs,
}

pub fn run(a: SubmitArgs) -> anyhow::Result<()> {
    if let Some(url) = &a.fleet.fleet {
        if a.watch {
            anyhow::bail!("--watch follows a job of one daemon; follow a fleet job with `machlink jobs --fleet {url}`");
        }
        let spec = a
            .job
            .spec(&a.file, Some(a.machine.clone()), a.post.clone())?;
        return super::fleet::submit(&a.fleet, url, &spec);
    }
    let client = a.client.client();
    // a G-code file with nothing to plan is streamed from disk as it is
    let stream_gcode = machlink::core::intake::is_gcode_file(&a.file.to_string_lossy())
        && a.job.op.is_none()
        && a.post.is_none();
    let spec = if stream_gcode {
        None
    } else {
        Some(a.job.spec(&a.file, Some(a.machine.clone()), a.post)?)
    };
    super::runtime()?.block_on(async {
        let job = match &spec {
            Some(spec) => client.submit(spec).await?,
            None => client.submit_gcode_file(&a.machine, &a.file).await?,
        };
        eprintln!(
            "job {} queued on {} ({} units)",
            job.id, job.machine, job.total_units
        );
        super::out(&format!("{}\n", job.id))?;
        if a.watch {
            watch_job(&client, job.id, false).await?;
        }
        Ok(())
    })
}
