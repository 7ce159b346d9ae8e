//! `machlink serve`: run the daemon until Ctrl-C or SIGTERM.

use anyhow::Context;
use machlink::config::Config;
use machlink::daemon::{Daemon, StartOptions, TcpSecurity};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ServeArgs {
    /// The configuration file (see docs/config.md). Default: ./machlink.toml.
    #[arg(long, default_value = "machlink.toml")]
    pub config: PathBuf,
    /// Listen on this Unix socket instead of the one the config names.
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
}

pub fn run(a: ServeArgs) -> anyhow::Result<()> {
    init_logging();
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
