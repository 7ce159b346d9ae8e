//! The services around the core: who may do what (`access`: roles, tokens, control locks)
//! and the log of it (`audit`), Prometheus `metrics`, the `events` stream and `webhooks`,
//! systemd readiness, the `fleet` of daemons on NATS JetStream, and the hardening that keeps
//! the daemon to itself (`tls`, `fsperm`, `memory`). Each takes the core's scheduler and
//! store as they are; none of them knows the HTTP API that faces the operator.

pub mod access;
pub mod audit;
pub mod events;
pub mod fleet;
pub mod fsperm;
pub mod memory;
pub mod metrics;
pub mod role;
pub mod systemd;
pub mod tls;
pub mod webhooks;
