//! `machlink demo`: a daemon with one simulated GRBL machine streams a sample job (an
//! inside profile of a plate with islands) with a progress bar, then reports what the
//! simulated machine did. No config, no hardware, no network.

use super::operate::watch_job;
use anyhow::Context;
use machlink::config::Config;
use machlink::core::intake::{self, Input, JobSpec, Operation};
use machlink::core::machine::MachineConfig;
use machlink::daemon::{Daemon, StartOptions};
use machlink::faces::client::{Client, Endpoint};
use machlink_sim::grbl::GrblSimHandle;
use offset_core::ops::{Cutting, ProfileParams, Side};
use offset_core::Tool;
use std::path::PathBuf;
use std::time::Instant;

/// The bundled sample: a 120 × 80 mm plate with rounded corners holding a circle, a
/// rounded rectangle and a pentagon.
const SAMPLE: &[u8] = include_bytes!("../../assets/plate-with-islands.json");
const SAMPLE_NAME: &str = "plate-with-islands.json";
const MACHINE: &str = "demo-grbl";

#[derive(clap::Args)]
pub struct DemoArgs {
    /// How many times faster than real time the simulated machine moves.
    #[arg(long, default_value_t = 20.0)]
    pub time_scale: f64,
    /// Demo another shape file instead of the bundled plate.
    #[arg(long, value_name = "FILE")]
    pub shape: Option<PathBuf>,
    /// No progress bar; only the summary.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(a: DemoArgs) -> anyhow::Result<()> {
    if !(a.time_scale.is_finite() && a.time_scale > 0.0) {
        anyhow::bail!(
            "--time-scale must be a positive number, got {}",
            a.time_scale
        );
    }
    let (name, bytes) = match &a.shape {
        Some(p) => (
            p.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| p.display().to_string()),
            std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?,
        ),
        None => (SAMPLE_NAME.to_string(), SAMPLE.to_vec()),
    };
    let spec = JobSpec {
        machine: Some(MACHINE.into()),
        input: Input::from_bytes(&name, bytes),
        operation: Some(Operation::Profile(ProfileParams {
            side: Side::Inside,
            cut: Cutting {
                tool: Tool::flat(3.0),
                depth: 2.0,
                stepdown: 1.0,
                ..Cutting::default()
            },
            ..ProfileParams::default()
        })),
        tolerance: None,
        layers: Vec::new(),
        post: None,
    };
    // plan here too, as the daemon will, for the deviation check against what the machine ran
    let (shape, _) = intake::read_shape(&spec)?;
    let planned = intake::toolpath(&spec, &shape)?;

    let dir = tempfile::tempdir().context("cannot make a temporary directory")?;
    let registry = machlink::core::registry::standard();
    let mut config = Config::empty();
    config.daemon.store = dir.path().join("demo.db");
    config.daemon.socket = dir.path().join("demo.sock");
    config.machines.push(
        MachineConfig::new(
            &registry,
            MACHINE,
            "sim-grbl",
            serde_json::json!({ "time_scale": a.time_scale }),
        )
        .map_err(anyhow::Error::msg)?,
    );
    let rt = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    rt.block_on(async move {
        let d = Daemon::start(config, StartOptions::default()).await?;
        let client = Client::new(Endpoint::Unix(d.socket.clone()));
        if !a.quiet {
            eprintln!(
                "machlink demo: a simulated GRBL machine at {}× real time cuts an inside profile of {name} (3 mm tool, 2 passes)",
                a.time_scale
            );
        }
        let started = Instant::now();
        let job = client.submit(&spec).await?;
        let result = watch_job(&client, job.id, a.quiet).await;
        let wall = started.elapsed();
        let sim = d
            .device::<GrblSimHandle>(MACHINE)
            .context("the demo machine's simulator is gone")?;
        let trace = sim.trace();
        let sim_time = sim.sim_time();
        let overflows = sim.rx_overflows();
        let deviation = machlink_sim::grbl::max_deviation(&planned, &trace);
        let job = result?;
        println!("job {} on {MACHINE}: {}", job.id, job.state);
        println!(
            "  lines:             {} sent and acknowledged, {} moves executed",
            job.total_units,
            trace.len()
        );
        println!("  wall time:         {:.2} s", wall.as_secs_f64());
        println!(
            "  machine time:      {:.1} s simulated ({:.1}× faster than real time)",
            sim_time.as_secs_f64(),
            sim_time.as_secs_f64() / wall.as_secs_f64().max(1e-9)
        );
        println!("  max deviation:     {deviation:.4} mm between the planned path and the executed moves");
        println!("  rx overflows:      {overflows}");
        d.shutdown().await;
        Ok(())
    })
}
