//! The machlink daemon as a library: configuration, the intake that turns every job into a
//! checked program, the job store, the per-machine scheduler, the HTTP API on a Unix socket
//! and its client; and the service around them: Prometheus metrics, the event stream and
//! webhooks, systemd readiness, and the fleet of daemons on NATS JetStream. The `machlink`
//! binary's subcommands and the end-to-end tests (`machlink-tests`) drive the daemon
//! through it. It knows machines only through the kind registry (`registry`); no device's
//! protocol is spoken here. Who may call the API and what each caller may do is `access`
//! (roles, tokens, peer credentials, the route table, control locks), written down by
//! `audit`; `tls`, `fsperm`, `limits` and `planner` keep the daemon unreachable to others
//! and up whatever a client sends (docs/security.md).

pub mod config;
pub mod core;
pub mod daemon;
pub mod faces;
pub mod services;
