//! `machlink serve`: run the daemon until Ctrl-C or SIGTERM.

use anyhow::Context;
use machlink::config::Config;
use machlink::daemon::{Daemon, StartOptions};
use std::io::IsTerminal;
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
    /// Also serve the Prometheus metrics alone (`GET /metrics`, read-only, no token) on
    /// this TCP address, e.g. 127.0.0.1:9464.
    #[arg(long, value_name = "ADDR")]
    pub metrics_listen: Option<String>,
    #[command(flatten)]
    pub log: LogArgs,
}

/// How the daemon logs.
#[derive(clap::Args, Clone, Debug)]
pub struct LogArgs {
    /// `human` (coloured only on a terminal) or `json` (one JSON object per line, for
    /// journald or a log shipper). `RUST_LOG` sets the level (default: info).
    #[arg(long, value_enum, default_value_t = LogFormat::Human)]
    pub log_format: LogFormat,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogFormat {
    Human,
    Json,
}

pub fn run(a: ServeArgs) -> anyhow::Result<()> {
    init_logging(a.log.log_format);
    let config = Config::load(&a.config)?;
    let rt = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    rt.block_on(async move {
        let opts = StartOptions {
            socket: a.socket,
            tcp: a.listen.zip(a.token),
            metrics_listen: a.metrics_listen,
        };
        let d = Daemon::start(config, opts).await?;
        let machines = d.scheduler.machines().map(|m| m.len()).unwrap_or(0);
        tracing::info!(
            socket = %d.socket.display(),
            machines,
            "machlink daemon listening at {}{}{}",
            d.socket.display(),
            d.tcp
                .map(|t| format!(" and on TCP {t}"))
                .unwrap_or_default(),
            d.metrics_addr
                .map(|t| format!(", metrics on http://{t}/metrics"))
                .unwrap_or_default(),
        );
        machlink::systemd::ready(&format!(
            "serving {machines} machine(s) at {}",
            d.socket.display()
        ));
        let watchdog = tokio::spawn(machlink::systemd::watchdog(d.scheduler.clone()));
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .context("cannot watch for SIGTERM")?;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
        machlink::systemd::stopping();
        tracing::info!("stopping: running jobs are cancelled and can be resumed later");
        watchdog.abort();
        d.shutdown().await;
        Ok(())
    })
}

/// Logs to stderr in `format`; colour only when stderr is a terminal. `RUST_LOG` refines
/// (default: info).
pub fn init_logging(format: LogFormat) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = match format {
        LogFormat::Json => builder
            .json()
            .flatten_event(true)
            .with_current_span(false)
            .try_init(),
        LogFormat::Human => builder
            .with_ansi(std::io::stderr().is_terminal())
            .try_init(),
    };
}
