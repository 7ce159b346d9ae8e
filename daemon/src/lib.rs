//! The machlink daemon as a library: configuration, the intake that turns every job into a
//! checked program, the job store, the per-machine scheduler, the HTTP API on a Unix socket
//! and its client; and the service around them: Prometheus metrics, the event stream and
//! webhooks, systemd readiness, and the fleet of daemons on NATS JetStream. The `machlink`
//! binary's subcommands and the end-to-end tests (`machlink-tests`) drive the daemon
//! through it. It knows machines only through the kind
//! registry (`registry`); no device's protocol is spoken here.

pub mod api;
pub mod check;
pub mod client;
pub mod config;
pub mod daemon;
pub mod events;
pub mod fleet;
pub mod intake;
pub mod locate;
pub mod metrics;
pub mod registry;
pub mod scheduler;
pub mod store;
pub mod systemd;
pub mod webhooks;
