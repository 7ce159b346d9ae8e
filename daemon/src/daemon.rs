//! The daemon put together: store, the machines' kinds started, scheduler and API listeners.

use crate::config::Config;
use crate::core::scheduler::{JournalPolicy, MachineSetup, Scheduler};
use crate::core::store::{Store, StoreError};
use crate::faces::api;
use crate::faces::api::service;
use crate::services::access::{Access, Peer};
use crate::services::audit::Audit;
use crate::services::events;
use crate::services::metrics::Metrics;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use tokio::task::JoinHandle;

/// Why the daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Socket(#[from] crate::services::fsperm::SocketError),
    #[error("{0}")]
    Access(String),
    #[error("cannot open the audit log {path}: {source}")]
    Audit {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot make the job store {path} private (0600): {source}")]
    StoreMode {
        path: String,
        #[source]
        source: std::io::Error,
    },
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
    /// Also listen on TCP at this address (TLS unless `tcp_security` says plaintext); every
    /// request there needs a bearer token.
    pub listen: Option<String>,
    /// An admin token named `command-line` besides the config's (`serve --token`); at least
    /// 32 characters.
    pub token: Option<String>,
    /// How TCP is served: TLS, or plaintext only when spelled out.
    pub tcp_security: TcpSecurity,
    /// The config file, for `POST /access/reload`.
    pub config_path: Option<PathBuf>,
    /// How jobs are planned (default: `intake::plan`), in a forked child either way; tests
    /// hand in a planner that panics or overflows its stack.
    pub planner: Option<crate::core::planner::PlanFn>,
    /// Also serve `GET /metrics` alone (read-only, no token) on this TCP address.
    pub metrics_listen: Option<String>,
}

/// How the API is served on TCP.
#[derive(Clone, Debug, Default)]
pub enum TcpSecurity {
    /// Not said: TCP is refused (the daemon needs TLS or the explicit plaintext mode).
    #[default]
    Unset,
    /// TLS with this certificate chain and private key (PEM).
    Tls { cert: PathBuf, key: PathBuf },
    /// Plaintext, when the operator spelled out `--insecure-plaintext`: warned on every start.
    InsecurePlaintext,
}

/// A running daemon. Dropping it stops it the way a crash would.
pub struct Daemon {
    pub scheduler: Scheduler,
    pub socket: PathBuf,
    /// The TCP address actually bound, when asked to listen on TCP.
    pub tcp: Option<SocketAddr>,
    /// The address `GET /metrics` is served on alone, when asked (`metrics_listen`).
    pub metrics_addr: Option<SocketAddr>,
    /// The daemon's metrics and events (`GET /metrics`, `GET /events`).
    pub service: service::Service,
    /// Who may do what, the machines' locks and the audit log.
    pub access: Arc<Access>,
    servers: Vec<JoinHandle<()>>,
}

impl Daemon {
    /// Opens the store (marking crashed jobs interrupted), starts each machine's kind (its
    /// simulator, for `sim-…` links), the machine workers and the API. Needs a tokio runtime.
    pub async fn start(config: Config, opts: StartOptions) -> Result<Daemon, DaemonError> {
        // everything about access is checked before anything is opened or started
        if let Some(t) = &opts.token {
            crate::services::access::check_token_strength(t)
                .map_err(|e| DaemonError::Access(format!("--token: {e}")))?;
        }
        let tls = match (&opts.listen, &opts.tcp_security) {
            (Some(addr), TcpSecurity::Unset) => {
                return Err(DaemonError::Access(format!(
                    "--listen {addr}: TCP needs TLS (--tls-cert FILE --tls-key FILE), or --insecure-plaintext to send tokens and jobs readable by anyone on the network"
                )))
            }
            (Some(_), TcpSecurity::Tls { cert, key }) => {
                Some(crate::services::tls::server_config(cert, key).map_err(DaemonError::Access)?)
            }
            _ => None,
        };
        // the socket's folder and path are checked before any file is touched
        let group = config.access.socket_group.as_ref().map(|g| g.0);
        let socket = opts.socket.clone().unwrap_or(config.daemon.socket.clone());
        if let Some(dir) = socket.parent().filter(|d| !d.as_os_str().is_empty()) {
            crate::services::fsperm::socket_folder(dir, group)?;
        }
        crate::services::fsperm::check_socket_path(&socket)?;
        let store_path = config.daemon.store.clone();
        let store_err = |source| DaemonError::StoreMode {
            path: store_path.display().to_string(),
            source,
        };
        crate::services::fsperm::private_store(&store_path).map_err(store_err)?;
        let audit_path = config.access.audit_log.clone().unwrap_or_else(|| {
            let mut name = store_path
                .file_stem()
                .map(|s| s.to_os_string())
                .unwrap_or_else(|| "machlink".into());
            name.push("-audit.jsonl");
            store_path.with_file_name(name)
        });
        let audit = Audit::open(&audit_path).map_err(|source| DaemonError::Audit {
            path: audit_path.display().to_string(),
            source,
        })?;
        let access = Arc::new(Access::new(
            config.access.clone(),
            opts.token.clone(),
            audit,
            opts.config_path.clone(),
        ));
        if opts.listen.is_some() && !access.has_tokens() {
            return Err(DaemonError::Access(
                "--listen: no token could reach the daemon on TCP; give --token or add [[access.token]] to the config (machlink token new)".into(),
            ));
        }
        let store = Store::open(&config.daemon.store)?;
        crate::services::fsperm::private_companions(&store_path).map_err(store_err)?;
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
        // a live daemon's socket is never taken over; a dead one's is removed
        crate::services::fsperm::clear_socket_path(&socket).await?;
        let listener = bind_unix(&socket, group)?;
        let planner = opts.planner.unwrap_or(crate::core::intake::plan);
        let mut servers = Vec::new();
        let metrics = Arc::new(Metrics::new());
        scheduler.attach_metrics(metrics.clone());
        servers.push(tokio::spawn(metrics.clone().follow(scheduler.subscribe())));
        servers.push(tokio::spawn(events::log_jobs(scheduler.subscribe())));
        let service = service::Service {
            sched: scheduler.clone(),
            metrics,
        };
        servers.extend(crate::services::webhooks::start(
            &config.webhooks,
            scheduler.subscribe(),
            service.metrics.clone(),
        ));
        if let Some(fleet) = config.fleet.clone() {
            servers.push(tokio::spawn(crate::services::fleet::node::run(
                fleet,
                scheduler.clone(),
                service.metrics.clone(),
            )));
        }
        let app = api::router_with(
            scheduler.clone(),
            access.clone(),
            planner,
            service::router(service.clone()),
        );
        servers.push(serve_api(listener, app, "the Unix socket"));
        servers.push(tokio::spawn(give_back_after_jobs(scheduler.clone())));
        let mut tcp = None;
        if let Some(addr) = opts.listen {
            let l = bind_tcp(&addr).await?;
            tcp = l.local_addr().ok();
            let app = api::router_with(
                scheduler.clone(),
                access.clone(),
                planner,
                service::router(service.clone()),
            );
            match tls {
                Some(cfg) => {
                    let l = crate::services::tls::TlsListener::new(l, cfg).map_err(|source| {
                        DaemonError::Listen {
                            what: addr.clone(),
                            source,
                        }
                    })?;
                    access.audit.daemon(&format!("listen tls {addr}"), "done");
                    servers.push(serve_api(l, app, "TCP"));
                }
                None => {
                    let warning = format!(
                        "the API listens on TCP {addr} in PLAINTEXT (--insecure-plaintext): tokens and jobs cross the network readable by anyone on it"
                    );
                    // through the log only: with --log-format json a plain line would break
                    // the stream of JSON objects
                    tracing::warn!("{warning}");
                    access
                        .audit
                        .daemon(&format!("listen plaintext {addr}"), "done: insecure");
                    servers.push(serve_api(l, app, "TCP"));
                }
            }
        }
        let mut metrics_addr = None;
        if let Some(addr) = opts.metrics_listen {
            let l = bind_tcp(&addr).await?;
            metrics_addr = l.local_addr().ok();
            let app = service::metrics_router(service.clone());
            servers.push(tokio::spawn(async move {
                if let Err(e) = axum::serve(l, app).await {
                    tracing::error!("the metrics listener stopped: {e}");
                }
            }));
        }
        access.audit.daemon("start", "done");
        Ok(Daemon {
            scheduler,
            socket,
            tcp,
            metrics_addr,
            service,
            access,
            servers,
        })
    }

    /// What machine `name`'s kind prepared at start-up (a simulator's handle), as the kind's
    /// own type: `daemon.device::<GrblSimHandle>("bench")`.
    pub fn device<T: 'static>(&self, name: &str) -> Option<&T> {
        self.scheduler.device(name)
    }

    /// Stops at once, as a crash would: no journal flush, jobs stay `running` in the
    /// store and become interrupted at the next start. The simulators keep running. Returns
    /// once its servers are gone and their sockets closed, as a killed process's are, so a
    /// daemon started next on the same socket finds it free (an aborted task lets go of its
    /// listener only when the runtime next drops it).
    pub async fn crash(mut self) {
        self.scheduler.abort();
        let servers: Vec<JoinHandle<()>> = self.servers.drain(..).collect();
        for s in &servers {
            s.abort();
        }
        for s in servers {
            let _ = s.await;
        }
    }

    /// Aborts the scheduler and every server task (what dropping the daemon does).
    fn abort_all(&mut self) {
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
        self.abort_all();
        let _ = std::fs::remove_file(&self.socket);
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        self.abort_all();
    }
}

/// Binds a TCP listener at `addr`, the error naming it.
async fn bind_tcp(addr: &str) -> Result<tokio::net::TcpListener, DaemonError> {
    tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|source| DaemonError::Listen {
            what: addr.to_string(),
            source,
        })
}

/// Serves the API on `listener` until the daemon stops, each request knowing its peer;
/// `what` names the listener in the log if it stops.
fn serve_api<L>(listener: L, app: axum::Router, what: &'static str) -> JoinHandle<()>
where
    L: axum::serve::Listener,
    L::Addr: std::fmt::Debug,
    Peer: for<'a> axum::extract::connect_info::Connected<axum::serve::IncomingStream<'a, L>>,
{
    tokio::spawn(async move {
        let app = app.into_make_service_with_connect_info::<Peer>();
        if let Err(e) = axum::serve(listener, app).await {
            tracing::error!("the API on {what} stopped: {e}");
        }
    })
}

/// Binds the Unix socket (its path cleared and its folder checked by `fsperm`) with its mode
/// set before anyone can reach it: 0600, or 0660 for a socket group.
fn bind_unix(
    path: &std::path::Path,
    group: Option<u32>,
) -> Result<tokio::net::UnixListener, DaemonError> {
    Ok(crate::services::fsperm::bind_private(path, group)?)
}

/// Gives freed memory back to the system each time a job ends (a large program is freed
/// then).
async fn give_back_after_jobs(sched: Scheduler) {
    let mut rx = sched.subscribe();
    loop {
        match rx.recv().await {
            Ok(crate::core::scheduler::Event::State { state, .. }) if state.is_final() => {
                // the worker drops the program right after it records the final state
                tokio::time::sleep(std::time::Duration::from_millis(200)).await;
                let store = sched.store().clone();
                let _ = tokio::task::spawn_blocking(move || {
                    store.release_memory();
                    crate::services::memory::give_back();
                })
                .await;
            }
            Ok(_) => {}
            Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
            Err(tokio::sync::broadcast::error::RecvError::Closed) => return,
        }
    }
}
