//! The daemon put together: store, simulated machines, scheduler and API listeners.

use crate::api;
use crate::config::{Config, LinkConfig};
use crate::links::ConfigOpener;
use crate::scheduler::{JournalPolicy, LinkOpener, Scheduler};
use crate::store::{Store, StoreError};
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use tokio::task::JoinHandle;

/// Why the daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("another daemon is already listening at {0}")]
    SocketBusy(String),
    #[error("cannot listen at {what}: {source}")]
    Listen {
        what: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot start the simulated machine `{machine}`: {source}")]
    Sim {
        machine: String,
        #[source]
        source: std::io::Error,
    },
}

/// How the daemon is reached besides its config.
#[derive(Default)]
pub struct StartOptions {
    /// Overrides the config's socket.
    pub socket: Option<PathBuf>,
    /// Also listen on TCP at this address, requiring this bearer token.
    pub tcp: Option<(String, String)>,
    /// Opens links instead of the config's opener (tests).
    pub opener: Option<Arc<dyn LinkOpener>>,
}

/// A running daemon. Dropping it stops it the way a crash would.
pub struct Daemon {
    pub scheduler: Scheduler,
    pub socket: PathBuf,
    /// The TCP address actually bound, when asked to listen on TCP.
    pub tcp: Option<SocketAddr>,
    /// The simulated GRBL machines this daemon started, by machine name.
    pub sims: BTreeMap<String, machlink_sim::grbl::GrblSimHandle>,
    /// The simulated pattern sewing machines this daemon started, by machine name.
    pub sewing_sims: BTreeMap<String, machlink_sim::sewing::SewingSim>,
    servers: Vec<JoinHandle<()>>,
}

impl Daemon {
    /// Opens the store (marking crashed jobs interrupted), starts the simulated machines
    /// of `sim-grbl` entries, the machine workers and the API. Needs a tokio runtime.
    pub async fn start(config: Config, opts: StartOptions) -> Result<Daemon, DaemonError> {
        let store = Store::open(&config.daemon.store)?;
        let mut sims = BTreeMap::new();
        let mut sewing_sims = BTreeMap::new();
        let mut opener = ConfigOpener::default();
        for m in &config.machines {
            match &m.link {
                LinkConfig::SimGrbl(s) => {
                    let cfg = machlink_sim::grbl::GrblSimConfig {
                        time_scale: s.time_scale,
                        ..Default::default()
                    };
                    let h = machlink_sim::grbl::GrblSim::spawn_pty(cfg).map_err(|source| {
                        DaemonError::Sim {
                            machine: m.name.clone(),
                            source,
                        }
                    })?;
                    opener.sim_ports.insert(m.name.clone(), h.port());
                    sims.insert(m.name.clone(), h);
                }
                LinkConfig::ModbusTcp(_) => {}
                LinkConfig::ModbusRtu(r) => {
                    if !std::path::Path::new(&r.port).exists() {
                        tracing::warn!(
                            "machine `{}`: the port {} does not exist (yet); its jobs fail until it does",
                            m.name,
                            r.port
                        );
                    }
                }
                LinkConfig::SimSewing(s) => {
                    let cfg = machlink_sim::sewing::SewingSimConfig {
                        time_scale: s.time_scale,
                        spm: s.spm,
                        noise: s.noise,
                        thread_break_at: s.thread_break_at.clone(),
                        power_loss_at: s.power_loss_at.clone(),
                        ..Default::default()
                    };
                    let h = machlink_sim::sewing::spawn_on_pty(cfg).map_err(|source| {
                        DaemonError::Sim {
                            machine: m.name.clone(),
                            source,
                        }
                    })?;
                    opener
                        .sim_ports
                        .insert(m.name.clone(), std::path::PathBuf::from(&h.path));
                    sewing_sims.insert(m.name.clone(), h);
                }
                LinkConfig::Sewing(g) => {
                    if !std::path::Path::new(&g.port).exists() {
                        tracing::warn!(
                            "machine `{}`: the port {} does not exist (yet); its jobs fail until it does",
                            m.name,
                            g.port
                        );
                    }
                }
                LinkConfig::Grbl(g) => {
                    if !std::path::Path::new(&g.port).exists() {
                        tracing::warn!(
                            "machine `{}`: the port {} does not exist (yet); its jobs fail until it does",
                            m.name,
                            g.port
                        );
                    }
                }
            }
        }
        let opener: Arc<dyn LinkOpener> = match opts.opener {
            Some(o) => o,
            None => Arc::new(opener),
        };
        let scheduler = Scheduler::start(
            store,
            config.machines.clone(),
            opener,
            JournalPolicy {
                every: config.daemon.journal_every,
                max_lag: config.daemon.journal_max_lag,
            },
        )?;
        let socket = opts.socket.unwrap_or(config.daemon.socket.clone());
        let listener = bind_unix(&socket).await?;
        let mut servers = Vec::new();
        let app = api::router(scheduler.clone(), None);
        servers.push(tokio::spawn(async move {
            if let Err(e) = axum::serve(listener, app).await {
                tracing::error!("the API on the Unix socket stopped: {e}");
            }
        }));
        let mut tcp = None;
        if let Some((addr, token)) = opts.tcp {
            let l = tokio::net::TcpListener::bind(&addr)
                .await
                .map_err(|source| DaemonError::Listen {
                    what: addr.clone(),
                    source,
                })?;
            tcp = l.local_addr().ok();
            let app = api::router(scheduler.clone(), Some(token));
            servers.push(tokio::spawn(async move {
                if let Err(e) = axum::serve(l, app).await {
                    tracing::error!("the API on TCP stopped: {e}");
                }
            }));
        }
        Ok(Daemon {
            scheduler,
            socket,
            tcp,
            sims,
            sewing_sims,
            servers,
        })
    }

    /// Stops at once, as a crash would: no journal flush, jobs stay `running` in the
    /// store and become interrupted at the next start. The simulators keep running.
    pub fn crash(&mut self) {
        self.scheduler.abort();
        for s in self.servers.drain(..) {
            s.abort();
        }
    }

    /// Stops cleanly: running jobs are cancelled (resumable later with `resume`), the
    /// socket file is removed, the simulators shut down.
    pub async fn shutdown(mut self) {
        self.scheduler.cancel_all().await;
        self.crash();
        let _ = std::fs::remove_file(&self.socket);
        for (_, s) in std::mem::take(&mut self.sims) {
            s.shutdown();
        }
        for (_, s) in std::mem::take(&mut self.sewing_sims) {
            s.task.abort();
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        self.crash();
    }
}

/// Binds the Unix socket, replacing a stale socket file but never a live daemon's.
async fn bind_unix(path: &std::path::Path) -> Result<tokio::net::UnixListener, DaemonError> {
    if path.exists() {
        if tokio::net::UnixStream::connect(path).await.is_ok() {
            return Err(DaemonError::SocketBusy(path.display().to_string()));
        }
        let _ = std::fs::remove_file(path);
    }
    let listen_err = |source| DaemonError::Listen {
        what: path.display().to_string(),
        source,
    };
    let l = tokio::net::UnixListener::bind(path).map_err(listen_err)?;
    // only the daemon's user may talk to it
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600)).map_err(listen_err)?;
    Ok(l)
}
