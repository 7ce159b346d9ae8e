//! The machlink daemon as a library: configuration, the intake that turns every job into a
//! checked program, the job store, the per-machine scheduler, the HTTP API on a Unix socket
//! and its client. The `machlink` binary's subcommands and the end-to-end tests
//! (`machlink-tests`) drive the daemon through it. It knows machines only through the kind
//! registry (`registry`); no device's protocol is spoken here.

pub mod api;
pub mod check;
pub mod client;
pub mod config;
pub mod daemon;
pub mod intake;
pub mod registry;
pub mod resume;
pub mod scheduler;
pub mod store;
