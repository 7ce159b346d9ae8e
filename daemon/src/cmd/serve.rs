//! `machlink serve`: run the daemon until Ctrl-C or SIGTERM.

use anyhow::Context;
use machlink::config::Config;
use machlink::daemon::{Daemon, StartOptions, TcpSecurity};
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ServeArgs {
    /// The configuration file (see docs/config.md). Default: ./machlink.toml.
    #[arg(long, default_value = "machlink.toml")]
    pub config: PathBuf,
    /// Listen on this Unix socket instead of the one the config names (the config's
    /// default: $XDG_RUNTIME_DIR/machlink.sock, else /tmp/machlink-$USER/machlink.sock).
    #[arg(long)]
    pub socket: Option<PathBuf>,
    /// Also listen on TCP at ADDR (e.g. 0.0.0.0:7878): with TLS (--tls-cert, --tls-key) or,
    /// spelled out, --insecure-plaintext. Every TCP request needs a token.
    #[arg(long, value_name = "ADDR")]
    pub listen: Option<String>,
    /// An admin token (at least 32 characters; `machlink token new` makes one) besides the
    /// config's [[access.token]]s. Also $MACHLINK_SERVE_TOKEN.
    #[arg(long, env = "MACHLINK_SERVE_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// The daemon's certificate chain (PEM) for TLS on --listen.
    #[arg(long, value_name = "FILE", requires_all = ["listen", "tls_key"])]
    pub tls_cert: Option<PathBuf>,
    /// The certificate's private key (PEM).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Serve --listen in plaintext: tokens and jobs cross the network readable by anyone on
    /// it. Warned about on every start.
    #[arg(long, requires = "listen", conflicts_with = "tls_cert")]
    pub insecure_plaintext: bool,
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
    let format = a.log.log_format;
    init_logging(format);
    let result = serve(a);
    if let (Err(e), LogFormat::Json) = (&result, format) {
        // the reason the daemon stops is one more JSON object on the log, not a plain line
        let msg = e
            .chain()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(": ");
        tracing::error!(error = %msg, "machlink serve stopped: {msg}");
        std::process::exit(1);
    }
    result
}

fn serve(a: ServeArgs) -> anyhow::Result<()> {
    let config = Config::load(&a.config)?;
    let rt = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    rt.block_on(async move {
        let tcp_security = match (a.tls_cert, a.tls_key, a.insecure_plaintext) {
            (Some(cert), Some(key), _) => TcpSecurity::Tls { cert, key },
            (_, _, true) => TcpSecurity::InsecurePlaintext,
            _ => TcpSecurity::Unset,
        };
        let opts = StartOptions {
            socket: a.socket,
            listen: a.listen,
            token: a.token,
            tcp_security,
            config_path: Some(a.config.clone()),
            planner: None,
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
        machlink::services::systemd::ready(&format!(
            "serving {machines} machine(s) at {}",
            d.socket.display()
        ));
        let watchdog = tokio::spawn(machlink::services::systemd::watchdog(d.scheduler.clone()));
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .context("cannot watch for SIGTERM")?;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
        machlink::services::systemd::stopping();
        tracing::info!(
            "stopping: running machines are feed-held; their jobs resume with `machlink resume`"
        );
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
