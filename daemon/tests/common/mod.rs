//! Helpers shared by the daemon crate's tests.
pub mod nats;
