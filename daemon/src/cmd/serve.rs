//! `machlink serve`: run the daemon until Ctrl-C or SIGTERM.

use anyhow::Context;
use machlink::config::Config;
use machlink::daemon::{Daemon, StartOptions};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ServeArgs {
    /// The configuration file (see docs/config.md). Default: ./machlink.toml.
    #[arg(long, default_value = "machlink.toml")]
    pub config: PathBuf,
    /// Listen on this Unix socket instead of the one the config names.
    #[arg(long)]
    pub socket: Option<PathBuf>,
    /// Also listen on TCP at ADDR (e.g. 127.0.0.1:7878); needs --token.
    #[arg(long, value_name = "ADDR", requires = "token")]
    pub listen: Option<String>,
    /// The bearer token every TCP request must carry (`Authorization: Bearer TOKEN`).
    #[arg(long, requires = "listen")]
    pub token: Option<String>,
}

pub fn run(a: ServeArgs) -> anyhow::Result<()> {
    init_logging();
    let config = Config::load(&a.config)?;
    let rt = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    rt.block_on(async move {
        let opts = StartOptions {
            socket: a.socket,
            tcp: a.listen.zip(a.token),
        };
        let d = Daemon::start(config, opts).await?;
        tracing::info!(
            "machlink daemon listening at {}{} with {} machine(s)",
            d.socket.display(),
            d.tcp
                .map(|t| format!(" and on TCP {t}"))
                .unwrap_or_default(),
            d.scheduler.machines().map(|m| m.len()).unwrap_or(0)
        );
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .context("cannot watch for SIGTERM")?;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
        tracing::info!(
            "stopping: running machines are feed-held; their jobs resume with `machlink resume`"
        );
        d.shutdown().await;
        Ok(())
    })
}

/// Logs to stderr; `RUST_LOG` refines (default: info).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}
