//! The daemon put together: store, the machines' kinds started, scheduler and API listeners.

use crate::api;
use crate::config::Config;
use crate::scheduler::{JournalPolicy, MachineSetup, Scheduler};
use crate::store::{Store, StoreError};
use std::net::SocketAddr;
use std::path::PathBuf;
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
    #[error("cannot start machine `{machine}` (link = \"{link}\"): {source}")]
    Start {
        machine: String,
        link: String,
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
}

/// A running daemon. Dropping it stops it the way a crash would.
pub struct Daemon {
    pub scheduler: Scheduler,
    pub socket: PathBuf,
    /// The TCP address actually bound, when asked to listen on TCP.
    pub tcp: Option<SocketAddr>,
    servers: Vec<JoinHandle<()>>,
}

impl Daemon {
    /// Opens the store (marking crashed jobs interrupted), starts each machine's kind (its
    /// simulator, for `sim-…` links), the machine workers and the API. Needs a tokio runtime.
    pub async fn start(config: Config, opts: StartOptions) -> Result<Daemon, DaemonError> {
        let store = Store::open(&config.daemon.store)?;
        let mut machines = Vec::new();
        for m in &config.machines {
            let device =
                m.kind
                    .start(&m.name, &m.settings)
                    .await
                    .map_err(|source| DaemonError::Start {
                        machine: m.name.clone(),
                        link: m.link.clone(),
                        source,
                    })?;
            machines.push(MachineSetup {
                config: m.clone(),
                device,
            });
        }
        let scheduler = Scheduler::start(
            store,
            machines,
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
            servers,
        })
    }

    /// What machine `name`'s kind prepared at start-up (a simulator's handle), as the kind's
    /// own type: `daemon.device::<GrblSimHandle>("bench")`.
    pub fn device<T: 'static>(&self, name: &str) -> Option<&T> {
        self.scheduler.device(name)
    }

    /// Stops at once, as a crash would: no journal flush, jobs stay `running` in the
    /// store and become interrupted at the next start. The simulators keep running.
    pub fn crash(&mut self) {
        self.scheduler.abort();
        for s in self.servers.drain(..) {
            s.abort();
        }
    }

    /// Stops cleanly (SIGTERM): no new jobs, every running machine feed-held and its job
    /// left interrupted at its exact unit (resumable with `resume`), the socket file
    /// removed; the simulators stop when the daemon is dropped.
    pub async fn shutdown(mut self) {
        self.scheduler
            .shutdown(std::time::Duration::from_secs(10))
            .await;
        self.crash();
        let _ = std::fs::remove_file(&self.socket);
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
