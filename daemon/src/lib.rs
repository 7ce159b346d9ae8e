//! The machlink daemon as a library: configuration, the job store, the per-machine
//! scheduler, the HTTP API on a Unix socket and its client. The `machlink` binary's
//! subcommands and the end-to-end tests (`machlink-tests`) drive the daemon through it.

pub mod api;
pub mod client;
pub mod config;
pub mod daemon;
pub mod links;
pub mod planning;
pub mod scheduler;
pub mod store;
